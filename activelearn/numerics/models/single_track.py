"""A car's kinematic single track from its vehicle file, and its physical parameters identified from logs.

The step (`single_track_step`) moves the rates y = (v, ω) over Δ from the newest control u = (τ, δ):

    v_ss = g(τ) · table(|τ|) · sign(τ) / (1 + scrub · tan² δ)    g: speed_gain (τ > 0), reverse_gain (τ < 0)
    v'   = v_ss + (v − v_ss) · exp(−Δ / speed_lag)                (τ = 0 brakes: |v| falls by brake_decel · Δ)
    ω_ss = v' · tan δ / (L · understeer),  |ω_ss| ≤ 1.25 × the car's yaw-rate limit
    ω'   = ω_ss + (ω − ω_ss) · exp(−Δ / yaw_lag)

`table` is the car's throttle → speed map (mirrored in reverse). The seven parameters start at the
car's prior (`CarPrior`: the vehicle file's figures, "the datasheet") and are identified (MAP, that
prior) from whole logs by their free runs (`identify_from_logs`) or from one-step rows (`identify`),
with a cluster-robust covariance. `activelearn.numerics.models.physics` adds the bounded Bayesian
correction. Every function takes the car (`car`, default the default car, Nigel).
"""

from __future__ import annotations

import functools
import hashlib
import math
import pickle
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from scipy.optimize import least_squares
from torch import Tensor

from activelearn.numerics import native
from activelearn.numerics.models.base import kernels_for
from simulator.vehicles import GRAVITY, VehicleSpec, load_vehicle

LAG_FACTOR = 3.0  # the correction scales each lag within [1/3, 3]
YAW_CAP_FACTOR = 1.25  # a steady yaw rate is capped at the car's yaw-rate limit + 25 %
PRIOR_ROWS = 1e4  # the first pass of `_map_fit` weighs the datasheet prior this much less
THROTTLE_LIMIT = 1.0  # every car's normalised throttle


@dataclass(frozen=True)
class PhysicalParameter:
    """One physical parameter of the single track: its datasheet value, physical range and prior width."""

    name: str
    nominal: float
    low: float
    high: float
    width: float
    unit: str
    meaning: str


def _reference_speed(spec: VehicleSpec) -> float:
    """The speed the understeer prior is taken at: the top speed, or below it the speed where the
    kinematic turn at full lock reaches the tyres' grip μ g (faster, no car follows L / tan δ there)."""
    kinematic = math.tan(spec.steering.limit.value) / spec.wheelbase
    return min(spec.max_speed, math.sqrt(spec.tyres.friction.value * GRAVITY / kinematic))


def car_parameters(spec: VehicleSpec) -> tuple[PhysicalParameter, ...]:
    """The seven parameters' prior for a car: nominal values from its vehicle file, ranges and widths
    scaled with them (Nigel's: speed lag 0.1 s in [0.01, 1] ± 0.2, yaw lag 0.05 s in [0.005, 1] ± 0.2).

    speed lag: the file's `drivetrain.speed_time_constant`, else the motor law's v_top / a_max; yaw lag:
    the file's `steering.yaw_time_constant`, else the linear single track's I_z v / (lf² C_f + lr² C_r)
    at the reference speed; understeer: L·f = L + K·v² at the reference speed (`_reference_speed`);
    reverse gain: the reverse top speed over the forward one; brake: the file's deceleration, at most μ g.
    """
    d, s, g = spec.drivetrain, spec.steering, spec.geometry
    reverse = 1.0
    if d.reverse_top_speed is not None and d.top_speed is not None:
        reverse = d.reverse_top_speed.value / d.top_speed.value
    if d.speed_time_constant is not None:
        t_v = d.speed_time_constant.value
    else:
        t_v = d.top_speed.value / d.max_acceleration.value  # type: ignore[union-attr]
    v_ref = _reference_speed(spec)
    if s.yaw_time_constant is not None:
        t_w = s.yaw_time_constant.value
    else:
        front, rear = spec.tyres.cornering_stiffness_front.value, spec.tyres.cornering_stiffness_rear.value
        damping = g.lf.value**2 * front + g.lr.value**2 * rear
        t_w = spec.inertia.yaw_inertia.value * v_ref / damping
    grip = spec.tyres.friction.value * GRAVITY
    brake = grip if d.brake_deceleration is None else min(d.brake_deceleration.value, grip)
    understeer = 1.0 + spec.understeer_gradient() * v_ref**2 / spec.wheelbase
    p = PhysicalParameter
    return (
        p("speed_gain", 1.0, 0.25, 1.25, 0.5, "-", "scale of the table's forward steady speed"),
        p("reverse_gain", reverse, 0.25 * reverse, 1.25 * reverse, 0.5 * reverse, "-",
          "scale of the mirrored table in reverse"),
        p("speed_lag", t_v, t_v / 10, t_v * 10, 2 * t_v, "s", "time constant of the speed's response"),
        p("scrub", 0.0, 0.0, 3.0, 1.0, "-", "steady speed / (1 + scrub tan² δ): tyre scrub"),
        p("understeer", understeer, 0.7, 2.0, 0.5, "-", "turning radius over the kinematic L / tan δ"),
        p("yaw_lag", t_w, t_w / 10, t_w * 20, 4 * t_w, "s", "time constant of the yaw rate's response"),
        p("brake_decel", brake, 0.5, 20.0, 3.0, "m/s²", "deceleration at throttle 0 (the brake); file: μ g"),
    )  # fmt: skip


class CarPrior:
    """What the single track knows of one car before any log: its vehicle file's figures (wheelbase,
    limits, throttle → speed map, log rate) and the seven parameters' prior (`car_parameters`)."""

    def __init__(self, spec: VehicleSpec) -> None:
        self.spec = spec
        self.name = spec.name
        self.wheelbase = spec.wheelbase
        self.max_speed = spec.max_speed
        self.max_yaw_rate = spec.max_yaw_rate
        self.steering_limit = spec.steering.limit.value
        self.log_rate_hz = spec.log_rate_hz
        self.yaw_cap = YAW_CAP_FACTOR * self.max_yaw_rate  # rad/s
        grid, speed = spec.speed_map
        if len(grid) != 11 or not np.allclose(grid, np.arange(11) / 10.0):
            raise ValueError(f"{spec.name}: the single track reads the speed map at throttle 0, 0.1, …, 1")
        self.speed_table = np.array(speed, dtype=np.float64)
        self.slope = np.diff(self.speed_table)  # per 0.1 of throttle
        self.parameters = car_parameters(spec)
        self.nominal = np.array([p.nominal for p in self.parameters])
        self.low = np.array([p.low for p in self.parameters])
        self.high = np.array([p.high for p in self.parameters])
        self.width = np.array([p.width for p in self.parameters])
        self.prior = Identified(self.nominal, np.diag(self.width**2))  # what the file says before any log
        self._tables: dict[torch.dtype, tuple[Tensor, Tensor]] = {}

    def table(self, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
        """The speed map as a tensor (m/s at throttle 0, 0.1, ..., 1) and its slope per 0.1 of throttle."""
        if dtype not in self._tables:
            speed = torch.as_tensor(self.speed_table, dtype=dtype)
            self._tables[dtype] = (speed, torch.diff(speed))
        return self._tables[dtype]


@functools.lru_cache(maxsize=16)
def _car_prior(key: str) -> CarPrior:
    return CarPrior(load_vehicle(key))


def car_prior(vehicle: VehicleSpec | str | None = None) -> CarPrior:
    """The single track's prior of a car (a spec, a shipped name or a path; None: the default car)."""
    if isinstance(vehicle, VehicleSpec):
        return _car_prior(str(vehicle.path)) if vehicle.path is not None else CarPrior(vehicle)
    return _car_prior(str(load_vehicle(vehicle or "nigel").path))


Array = Tensor | np.ndarray  # the step serves training and free runs (torch) and identification (NumPy)


def _namespace(a: Array):
    """torch for tensors, NumPy for arrays: the functions the step calls exist under one name in both."""
    return torch if isinstance(a, Tensor) else np


def _table_speed(throttle: Array, car: CarPrior) -> Array:
    """The car's steady forward speed at |throttle| (m/s), interpolated linearly (τ in [0, 1])."""
    xp = _namespace(throttle)
    x = xp.clip(xp.abs(throttle), 0.0, THROTTLE_LIMIT) * 10.0
    i = xp.clip(xp.floor(x), 0.0, 9.0)
    if xp is torch:
        speed, slope = car.table(throttle.dtype)
        index = i.long()
    else:
        speed, slope = car.speed_table, car.slope
        index = i.astype(np.intp)
    return speed[index] + (x - i) * slope[index]


def single_track_step(
    throttle: Array,
    steering: Array,
    v: Array,
    w: Array,
    theta: Array,
    dt: float,
    corrections: tuple[Tensor, Tensor, Tensor, Tensor] | None = None,
    residual_bound: float = 0.0,
    table_speed: Array | None = None,
    car: CarPrior | None = None,
) -> tuple[Array, Array]:
    """Next (v, ω) after `dt` s of the control (throttle, steering) from rates (v, ω), broadcast.

    `theta` holds the seven `PARAMETERS` along its last axis; `corrections` the network's raw outputs
    (steady speed, steady yaw rate, speed lag, yaw lag), each squashed into its range (None: pure
    physics). Tensors (training, free runs) or NumPy arrays (identification, several times faster on
    its small arrays), not mixed. `table_speed`: `_table_speed(throttle)`, where the caller has it
    (a free run over many parameter sets computes it once per step of the controls). `car`: whose
    single track (None: the default car).
    """
    car = car or NIGEL
    xp = _namespace(throttle)
    gain_f, gain_r, t_v, scrub, understeer, t_w, brake = (theta[..., i] for i in range(len(PARAMETERS)))
    tan_d = xp.tan(steering)
    gain = xp.where(throttle >= 0, gain_f, gain_r)
    table = _table_speed(throttle, car) if table_speed is None else table_speed
    v_ss = xp.sign(throttle) * gain * table / (1.0 + scrub * tan_d * tan_d)
    if corrections is not None:
        z_v, z_w, z_tv, z_tw = corrections
        v_ss = v_ss + residual_bound * car.max_speed * xp.tanh(z_v)
        t_v = t_v * xp.exp(math.log(LAG_FACTOR) * xp.tanh(z_tv))
        t_w = t_w * xp.exp(math.log(LAG_FACTOR) * xp.tanh(z_tw))
    v_next = v_ss + (v - v_ss) * xp.exp(-dt / t_v)
    braked = v - xp.sign(v) * xp.minimum(xp.abs(v), brake * dt)
    v_next = xp.where(throttle == 0, braked, v_next)
    w_ss = v_next * tan_d / (car.wheelbase * understeer)
    if corrections is not None:
        w_ss = w_ss + residual_bound * car.max_yaw_rate * xp.tanh(z_w)
    w_ss = xp.clip(w_ss, -car.yaw_cap, car.yaw_cap)
    w_next = w_ss + (w - w_ss) * xp.exp(-dt / t_w)
    return v_next, w_next


def split_inputs(x: Tensor, dim: int, rate_at: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The newest control (τ, δ) and the newest past rate (v, ω) of physical inputs along `dim`."""
    return x.select(dim, 0), x.select(dim, 1), x.select(dim, rate_at), x.select(dim, rate_at + 1)


class Identified(NamedTuple):
    """Identified physical parameters (`PARAMETERS`' order) and their covariance."""

    values: np.ndarray
    covariance: np.ndarray

    @property
    def stderr(self) -> np.ndarray:
        """The standard error of each parameter."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))


NIGEL = car_prior()  # the default car's prior; its arrays keep their module names below
PARAMETERS: tuple[PhysicalParameter, ...] = NIGEL.parameters
PARAMETER_NAMES = tuple(p.name for p in PARAMETERS)
NOMINAL, LOW, HIGH, WIDTH = NIGEL.nominal, NIGEL.low, NIGEL.high, NIGEL.width
YAW_CAP = NIGEL.yaw_cap
DATASHEET_PRIOR = NIGEL.prior


def identify(
    x: np.ndarray, y: np.ndarray, dt: float, rate_at: int, car: CarPrior | None = None
) -> Identified:
    """Least-squares physical parameters for rows x (N, 4k) → y (N, 2), with their covariance.

    MAP under the datasheet prior (`_map_fit`): a parameter the rows do not excite stays near the
    datasheet. The covariance is the sandwich with each row its own cluster (rows are one-step
    errors, roughly independent).
    """
    car = car or NIGEL
    x = torch.as_tensor(np.asarray(x, dtype=np.float64))
    y = np.asarray(y, dtype=np.float64)
    if len(x) == 0:
        return Identified(car.nominal.copy(), car.prior.covariance.copy())
    tau, delta, v, w = split_inputs(x, -1, rate_at)

    def errors_of(sets: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            v1, w1 = single_track_step(tau, delta, v, w, torch.as_tensor(sets)[:, None], dt, car=car)
        return np.stack([v1.numpy(), w1.numpy()], axis=-1) - y

    return _map_fit(errors_of, y.std(axis=0), np.arange(len(y)), car=car)


def run_single_track(
    controls: np.ndarray, start: np.ndarray, theta: np.ndarray, dt: float, car: CarPrior | None = None,
    backend: str = "auto",
) -> np.ndarray:  # fmt: skip
    """Free runs of the bare single track (`single_track_step`, no correction): controls (M, T, 2), start
    rates (M, 2), parameter sets (P, 7) → rates (P, M, T, 2), the first step being `start`. `backend`:
    the compiled kernel (`"native"`, physics_rollout.c's `al_kinematic_rate_runs`: an identification's
    runs are too small for NumPy's per-call cost), this NumPy loop over every parameter set at once
    (`"reference"`), or the kernel where it builds (`"auto"`). Both agree to float64 rounding."""
    car = car or NIGEL
    lib = kernels_for(backend)
    if lib is not None:
        figures = np.array([car.wheelbase, car.yaw_cap, *car.speed_table])
        return native.kinematic_rate_runs(lib, figures, np.atleast_2d(theta), controls, start, dt)
    sets = np.atleast_2d(theta)[:, None]  # (P, 1, 7) against (M,)
    n_runs, n_steps = controls.shape[:2]
    out = np.empty((len(sets), n_runs, n_steps, 2))
    v, w = (np.broadcast_to(start[:, j], (len(sets), n_runs)) for j in range(2))
    out[:, :, 0, 0], out[:, :, 0, 1] = v, w
    table = _table_speed(controls[:, :, 0], car)  # (M, T): elementwise, the same numbers as step by step
    for k in range(1, n_steps):
        u = controls[:, k]
        v, w = single_track_step(u[:, 0], u[:, 1], v, w, sets, dt, table_speed=table[:, k], car=car)
        out[:, :, k, 0], out[:, :, k, 1] = v, w
    return out


def identify_from_logs(
    logs: list[tuple[np.ndarray, np.ndarray]],
    *,
    dt: float | None = None,
    every: int = 1,
    prior: Identified | None = None,
    search_from: np.ndarray | None = None,
    car: CarPrior | None = None,
) -> Identified:
    """Output-error least squares: the parameters whose free runs along each log's controls, from its
    first recorded rates, come closest to its recorded rates. Logs are (controls (T, 2), rates (T, 2))
    at `dt`; `every` > 1 fits every n-th step of the runs (they are still simulated at `dt`).

    MAP under a Gaussian prior (`_map_fit`): the datasheet's (`NOMINAL` ± `WIDTH`) or `prior`'s values
    and the standard errors of its covariance, with each log a cluster of the covariance (a free run's
    errors are correlated along it). Free runs weigh the steady states and lags as a free run of the
    model uses them; one-step errors over noisy past rates bias the lags. `search_from`: where the
    search begins (default the prior's centre), e.g. the last round's solution. `car`: whose single
    track (default the default car); `dt` defaults to its log step.
    """
    car = car or NIGEL
    dt = 1.0 / car.log_rate_hz if dt is None else dt
    prior = prior or car.prior
    logs = usable_logs(logs)
    if not logs:
        return Identified(prior.values.copy(), prior.covariance.copy())
    controls, rates, valid, keep = stacked_logs(logs, every)
    start = rates[:, 0]

    def errors_of(sets: np.ndarray) -> np.ndarray:  # (P, n, 2) errors of each parameter set's runs
        return (run_single_track(controls, start, sets, dt, car) - rates)[:, keep]

    return _map_fit(errors_of, rates[valid].std(axis=0), np.nonzero(keep)[0], prior, search_from, car)


def misfit_of_logs(
    logs: list[tuple[np.ndarray, np.ndarray]],
    theta: np.ndarray,
    *,
    horizon: float,
    cross_validated: bool = False,
    prior: Identified | None = None,
    car: CarPrior | None = None,
    folds: int = 4,
) -> np.ndarray:
    """(2,) the rms rate errors (v m/s, ω rad/s) of the single track's free runs of `logs` at `theta`,
    restarted from the logged rates every `horizon` s: what the identified core still misses of them (the
    sensors' noise included); zeros without logs. `cross_validated`: out of sample, the logs in
    min(`folds`, logs) folds (in their order), each at the parameters identified on the others (under
    `prior`, searched from `theta`); one log: in sample."""
    car = car or NIGEL
    logs = usable_logs(logs)
    if not logs:
        return np.zeros(2)

    def squared(some: list[tuple[np.ndarray, np.ndarray]], at: np.ndarray) -> tuple[np.ndarray, int]:
        return _squared_misfit(some, at, horizon, car)

    if not cross_validated:
        return rms_of(*squared(logs, theta))

    def refit(rest: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
        return identify_from_logs(rest, prior=prior, search_from=theta, car=car).values

    return cross_validated_rms(logs, theta, refit, squared, folds)


def usable_logs(logs: list[tuple[np.ndarray, np.ndarray]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The logs (controls (T, 2), rates (T, 2)) of at least two steps, as float64 arrays."""
    return [(np.asarray(u, np.float64), np.asarray(y, np.float64)) for u, y in logs if len(u) > 1]


def rms_of(squares: np.ndarray, count: int) -> np.ndarray:
    """The root mean of summed squared errors over their count."""
    return np.sqrt(squares / count)


def cross_validated_rms(
    logs: list[tuple[np.ndarray, np.ndarray]],
    theta: np.ndarray,
    refit: Callable[[list[tuple[np.ndarray, np.ndarray]]], np.ndarray],
    squared: Callable[[list[tuple[np.ndarray, np.ndarray]], np.ndarray], tuple[np.ndarray, int]],
    folds: int = 4,
) -> np.ndarray:
    """(2,) a core's rms rate misfit out of sample: the logs in min(`folds`, logs) folds (in their order),
    each fold's summed squared errors (`squared(fold, parameters)`) at the parameters `refit` finds on
    the other logs. One log: in sample, at `theta`. Both cores' `discrepancy = "cross_validated"`."""
    if len(logs) < 2:
        return rms_of(*squared(logs, theta))
    squares, count = np.zeros(2), 0
    for held in np.array_split(np.arange(len(logs)), min(folds, len(logs))):
        rest = [log for i, log in enumerate(logs) if i not in held]
        fold_squares, fold_count = squared([logs[i] for i in held], refit(rest))
        squares, count = squares + fold_squares, count + fold_count
    return rms_of(squares, count)


def _squared_misfit(
    logs: list[tuple[np.ndarray, np.ndarray]], theta: np.ndarray, horizon: float, car: CarPrior
) -> tuple[np.ndarray, int]:
    """The summed squared rate errors (2,) of `misfit_of_logs`' restarted free runs, and their count."""
    steps = max(2, round(horizon * car.log_rate_hz))
    pieces = [(u[k : k + steps + 1], y[k : k + steps + 1])
              for u, y in logs for k in range(0, len(u) - 1, steps)]  # fmt: skip
    controls, rates, valid, _ = stacked_logs([piece for piece in pieces if len(piece[0]) > 1])
    valid[:, 0] = False  # a run's first step is its logged start
    errors = run_single_track(controls, rates[:, 0], theta, 1.0 / car.log_rate_hz, car)[0] - rates
    return (errors[valid] ** 2).sum(axis=0), int(valid.sum())


def stacked_logs(
    logs: list[tuple[np.ndarray, np.ndarray]], every: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Logs (controls (T, 2), rates (T, 2)) of different lengths as arrays (M, T_max, 2) for one batched
    free run: controls held at their last value past a log's end; `valid` marks each log's own steps and
    `keep` every `every`-th of them (the steps an output-error fit compares)."""
    length = max(len(u) for u, _ in logs)
    controls = np.zeros((len(logs), length, 2))
    rates = np.zeros((len(logs), length, 2))
    valid = np.zeros((len(logs), length), dtype=bool)
    for i, (u, y) in enumerate(logs):
        controls[i, : len(u)], rates[i, : len(u)], valid[i, : len(u)] = u, y, True
        controls[i, len(u) :] = u[-1]
    keep = np.zeros_like(valid)
    keep[:, ::every] = valid[:, ::every]
    return controls, rates, valid, keep


def identify_on_another_car(
    logs: list[tuple[np.ndarray, np.ndarray]],
    others: list[tuple[np.ndarray, np.ndarray]],
    search_from: np.ndarray | None = None,
    **kwargs,
) -> Identified:
    """The parameters of the car that drove `logs`, where `others` are logs of another car (the nominal
    simulator's prior grid, for a car that is not the simulator): `others` are identified alone first,
    and their estimate, with the datasheet's widths added to its covariance (how far two cars of one
    datasheet may differ), is the prior `logs` are identified under. Without `logs`, `others`' estimate
    stands. So the other car's logs say where to start, not what this car is: pooled with this car's
    few logs as data, 35 simulated logs outvote them (the twin's motor: 0.994 against its 0.9). A
    parameter neither car's logs excite ends at √2 × the datasheet's width (the two widths add: the
    reverse gain after forward logs, 0.71): conservative, and what `safe_track_twin.toml` was measured
    with; capping it at the datasheet's width is not measured. `search_from`: where the search for this
    car's parameters begins (the other car's is always searched from the datasheet)."""
    if not any(len(u) > 1 for u, _ in logs):
        return others_estimate(others, **kwargs)
    prior = another_cars_prior(others, **kwargs)
    return identify_from_logs(logs, prior=prior, search_from=search_from, **kwargs)


def another_cars_prior(others: list[tuple[np.ndarray, np.ndarray]], **kwargs) -> Identified:
    """The prior this car's logs are identified under where `others` are another car's logs: their
    estimate (`others_estimate`, cached) widened by the datasheet's widths (`widened`)."""
    return widened(others_estimate(others, **kwargs), (kwargs.get("car") or NIGEL).width)


_OTHERS: dict[str, Identified] = {}  # the other car's estimate by its logs' digest (a few kept)


def others_estimate(
    others: list[tuple[np.ndarray, np.ndarray]], identify_logs: Callable[..., Identified] | None = None,
    **kwargs,
) -> Identified:  # fmt: skip
    """`identify_logs(others, **kwargs)` (default `identify_from_logs`), computed once per set of logs and
    arguments: a campaign's prior grid is the same every round (35 logs of 30 s, as dynamics_warm's
    grid: about 1 s a round)."""
    identify_logs = identify_logs or identify_from_logs
    named = {k: (v.name if isinstance(v, CarPrior) else v) for k, v in kwargs.items()}
    digest = hashlib.sha256(f"{identify_logs.__module__}.{identify_logs.__qualname__}".encode())
    digest.update(pickle.dumps(sorted(named.items())))
    for u, y in others:
        digest.update(np.ascontiguousarray(u, np.float64).tobytes())
        digest.update(np.ascontiguousarray(y, np.float64).tobytes())
    key = digest.hexdigest()
    if key not in _OTHERS:
        while len(_OTHERS) >= 4:
            _OTHERS.pop(next(iter(_OTHERS)))
        _OTHERS[key] = identify_logs(others, **kwargs)
    found = _OTHERS[key]
    return Identified(found.values.copy(), found.covariance.copy())


def widened(found: Identified, width: np.ndarray) -> Identified:
    """Another car's estimate as this car's prior: its covariance plus the datasheet's widths squared (how
    far two cars of one datasheet may differ)."""
    return Identified(found.values.copy(), found.covariance + np.diag(np.asarray(width, np.float64) ** 2))


# `_map_fit(loss="cauchy")`: the error size, as a share of the rates' rms error, beyond which a row's
# weight falls off (a pilot on the full-size car's spinning logs: 0.3 and 1 gave the same scales)
CAUCHY_SCALE = 0.3


def _map_fit(
    errors_of,
    spread: np.ndarray,
    clusters: np.ndarray,
    prior: Identified | None = None,
    search_from: np.ndarray | None = None,
    car: CarPrior | None = None,
    loss: str = "squares",
    also_from_prior: bool = False,
) -> Identified:
    """MAP parameters under a Gaussian prior (default the car's; independent parameters, its
    covariance's diagonal): Gaussian errors of unknown size per rate, found in two passes (the first,
    with the prior at 1/`PRIOR_ROWS` of its weight, measures the error size), and their
    cluster-robust covariance. `errors_of` maps parameter sets (P, 7) to errors (P, n, 2); `clusters`
    (n,) labels the error rows whose errors may be correlated (one log's steps). The first pass searches
    from `search_from` (default the prior's centre), the second from the first's solution.
    `loss = "cauchy"`: each error row weighs 1 / (1 + (e / (`CAUCHY_SCALE` × the rate's rms error))²)
    (scipy's Cauchy loss), so the few rows no parameter set fits (a spin a second off the truth's) do not
    pull the rest; the covariance is then the sandwich of that weighted fit at its weights.
    `also_from_prior`: where `search_from` is given, each pass also searches from the prior's centre (the
    second from both first solutions) and keeps the lower objective: a search from the last round's
    solution can stay in a basin its new logs have left (docs/results/vehicles.md, session 46)."""
    car = car or NIGEL
    low, high, scale = car.low, car.high, car.width
    prior = prior or car.prior
    centre, width = prior.values, np.maximum(prior.stderr, 1e-9)
    firsts = [centre] if search_from is None else [search_from, centre] if also_from_prior else [search_from]
    starts = [np.clip(x, low + 1e-9, high - 1e-9) for x in firsts]
    noise = np.maximum(spread, 1e-3)
    for prior_weight in (1.0 / PRIOR_ROWS, 1.0):

        def residuals_of(sets: np.ndarray, noise=noise, prior_weight=prior_weight) -> np.ndarray:
            err = errors_of(sets) / noise
            prior = (sets - centre) / width * math.sqrt(prior_weight)
            return np.concatenate([err.reshape(len(sets), -1), prior], axis=1)

        def fun(p: np.ndarray, residuals_of=residuals_of) -> np.ndarray:
            return residuals_of(p[None])[0]

        def jac(p: np.ndarray, residuals_of=residuals_of) -> np.ndarray:
            # one batched run for every forward difference, stepping inwards at an upper bound
            step = 1e-5 * scale
            step = np.where(p + step > high, -step, step)
            res = residuals_of(np.vstack([p, p + np.diag(step)]))
            return ((res[1:] - res[0]) / step[:, None]).T

        robust = {} if loss == "squares" else {"loss": loss, "f_scale": CAUCHY_SCALE}
        found = [least_squares(fun, x, jac=jac, bounds=(low, high), x_scale=scale, method="trf",
                               max_nfev=100, **robust) for x in starts]  # fmt: skip
        sol = min(found, key=lambda candidate: candidate.cost)  # the first of equals: the last round's
        starts = [candidate.x for candidate in found]
        err = errors_of(sol.x[None])[0]
        noise = np.maximum(np.sqrt(np.mean(err**2, axis=0)), 1e-6 * np.maximum(spread, 1e-3))
    if loss == "squares":
        return Identified(sol.x, _sandwich(sol.jac, sol.fun, clusters))
    # the weighted least-squares fit the robust one is at its solution (scipy's `jac` is modified)
    residuals, jacobian = fun(sol.x), jac(sol.x)
    weight = np.ones_like(residuals)
    weight[: -len(sol.x)] = 1.0 / (1.0 + (residuals[: -len(sol.x)] / CAUCHY_SCALE) ** 2)
    root = np.sqrt(weight)
    return Identified(sol.x, _sandwich(jacobian * root[:, None], residuals * root, clusters))


def _sandwich(jac: np.ndarray, residuals: np.ndarray, clusters: np.ndarray) -> np.ndarray:
    """Cluster-robust covariance H⁻¹ (Σ_g s_g s_gᵀ + P) H⁻¹ of a MAP fit (Liang & Zeger 1986).

    `jac` and `residuals` are the fit's, error rows (n × 2, rate fastest) then the prior's 7 rows;
    s_g sums the scores Jᵀr of cluster g's rows; P is the prior's information. The Gauss-Newton
    covariance H⁻¹ assumes every error independent: a free run's errors are correlated along the
    whole log, and where the single track misses the car (tyres at full lock, a steering step at
    speed) different logs want different parameters. That disagreement is what the sandwich
    measures (on the twin, scrub's standard error 0.054 against Gauss-Newton's 0.0025). With G
    clusters, the meat is scaled by G / (G - 1) (CR1); one cluster alone gives Gauss-Newton's.
    """
    n_params = jac.shape[1]
    errors, prior = jac[:-n_params], jac[-n_params:]
    bread = np.linalg.pinv(jac.T @ jac)
    labels = np.repeat(clusters, errors.shape[0] // len(clusters))  # both rates of a row share it
    _, index = np.unique(labels, return_inverse=True)
    n_clusters = int(index.max()) + 1
    if n_clusters < 2:
        return bread
    scores = errors * residuals[:-n_params, None]  # (n, 7): each row's score
    per_cluster = np.zeros((n_clusters, n_params))
    np.add.at(per_cluster, index, scores)
    meat = per_cluster.T @ per_cluster * n_clusters / (n_clusters - 1) + prior.T @ prior
    return bread @ meat @ bread


def cholesky_factor(covariance: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of a covariance that may be singular (a parameter fixed at the prior's
    bound): through its eigen-decomposition, negative round-off eigenvalues set to 0."""
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    root = vectors * np.sqrt(np.clip(values, 0.0, None))
    return np.linalg.cholesky(root @ root.T + 1e-12 * np.eye(len(covariance)))
