"""A surrogate that knows the car: Nigel's single track from its datasheet plus a bounded Bayesian correction.

The physics core steps the rates y = (v, ω) over the Δ = `history_step` / 30 Hz between a dynamic
model's newest past rate and its target, from the newest control u = (τ, δ):

    v_ss = g(τ) · table(|τ|) · sign(τ) / (1 + scrub · tan² δ)    g: speed_gain (τ > 0), reverse_gain (τ < 0)
    v'   = v_ss + (v − v_ss) · exp(−Δ / speed_lag)                (τ = 0 brakes: |v| falls by brake_decel · Δ)
    ω_ss = v' · tan δ / (L · understeer),  |ω_ss| ≤ 1.25 × the datasheet's yaw-rate limit
    ω'   = ω_ss + (ω − ω_ss) · exp(−Δ / yaw_lag)

`table` is the datasheet's throttle → speed table (mirrored in reverse). The seven physical
parameters start at the datasheet (`PARAMETERS`) and are identified before every fit: by the free
runs of the training logs where the caller gives them (`identify_from_logs`, what campaigns do),
else from one-step rows (`identify`), MAP with the datasheet as the prior, so a parameter the data
do not touch (say the reverse gain, trained forward only) stays at the datasheet's value.

The Bayesian part (a deep ensemble or hybrid PBNN of `config.correction`, on the same inputs)
learns only what the physics misses, every output squashed into a physical range:
  * a residual on each steady state, |Δv_ss| ≤ b · v_max, |Δω_ss| ≤ b · ω_max (b = `residual_bound`);
  * a factor on each lag in [1/3, 3];
  * the aleatoric variance of each rate, at most one standard deviation of the training rates and
    `NOISE_CAP` (3 %) of the rate's limit.
Each step's rate is then a convex combination of the previous rate and a bounded target, so a free
run cannot leave the bounded targets' range (plus the noise the rollout adds), whatever the inputs.
Its last layer starts at a tenth of the usual scale, so before training the model is the datasheet
with the correction's prior spread; where the data end, each member (or posterior draw) keeps its own
bounded correction, which is the epistemic band there.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from scipy.optimize import least_squares
from torch import Tensor

from activelearn.config import ModelConfig
from activelearn.errors import InputError
from activelearn.numerics import buffers, counter_noise, native
from activelearn.numerics.lags import N_CONTROLS, N_RATES, Lags, model_lags
from activelearn.numerics.models.base import Model, column_scalers, draw_spread
from activelearn.numerics.models.networks import NETWORK_CLASSES
from simulator import datasheet

N_CORRECTIONS = 4  # steady-state residuals (v, ω) and lag factors (v, ω)
# Under the mirror (δ, ω → −δ, −ω) the steady yaw-rate residual changes sign; the speed residual, both
# lag factors and the aleatoric variances do not.
MIRROR_PARITY = (1.0, -1.0, 1.0, 1.0)
LAG_FACTOR = 3.0  # the correction scales each lag within [1/3, 3]
YAW_CAP = 1.25 * datasheet.MAX_YAW_RATE  # rad/s: a steady yaw rate beyond the datasheet's limit + 25 %
LAST_LAYER_SCALE = 0.1  # the correction starts near zero: an untrained model is the datasheet's physics
# The aleatoric std of each rate is at most this fraction of its limit (speed, yaw rate). MuJoCo's
# logged rates carry 0.2 % / 1.8 % of the limits; without a physical cap (the old one: the training
# rates' std, 0.27 rad/s) the noise of a free run at full lock carried ω past 1.5x the limit (3 of
# 608 sweep runs, experiments/results/physics.txt). With ≤ 3 %, five sigma over the 1.25x yaw cap
# stays below 1.5x.
NOISE_CAP = 0.03
_RATE_LIMITS = torch.tensor([datasheet.MAX_SPEED, datasheet.MAX_YAW_RATE])  # float32, as y_std
THETA_SEED_SALT = 0x7E7A  # the parameter draws' normals differ from the correction's of the same seed
PRIOR_ROWS = 1e4  # the first pass of `_map_fit` weighs the datasheet prior this much less


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


def _nominal_understeer() -> float:
    """The datasheet's linear single track at its top speed: L·f = L + K·v_max²."""
    return 1.0 + datasheet.understeer_gradient() * datasheet.MAX_SPEED**2 / datasheet.WHEELBASE


PARAMETERS: tuple[PhysicalParameter, ...] = (
    PhysicalParameter("speed_gain", 1.0, 0.25, 1.25, 0.5, "-", "scale of the table's forward steady speed"),
    PhysicalParameter("reverse_gain", 1.0, 0.25, 1.25, 0.5, "-", "scale of the mirrored table in reverse"),
    PhysicalParameter("speed_lag", 0.1, 0.01, 1.0, 0.2, "s", "time constant of the speed's response"),
    PhysicalParameter("scrub", 0.0, 0.0, 3.0, 1.0, "-", "steady speed / (1 + scrub tan² δ): tyre scrub"),
    PhysicalParameter(
        "understeer", _nominal_understeer(), 0.7, 2.0, 0.5, "-", "turning radius over the kinematic L / tan δ"
    ),
    PhysicalParameter("yaw_lag", 0.05, 0.005, 1.0, 0.2, "s", "time constant of the yaw rate's response"),
    PhysicalParameter(
        "brake_decel",
        datasheet.FRICTION * datasheet.GRAVITY,
        0.5,
        20.0,
        3.0,
        "m/s²",
        "deceleration at throttle 0 (the brake); datasheet: μ g",
    ),
)
PARAMETER_NAMES = tuple(p.name for p in PARAMETERS)
NOMINAL = np.array([p.nominal for p in PARAMETERS])
LOW = np.array([p.low for p in PARAMETERS])
HIGH = np.array([p.high for p in PARAMETERS])
WIDTH = np.array([p.width for p in PARAMETERS])


Array = Tensor | np.ndarray  # the step serves training and free runs (torch) and identification (NumPy)


def _namespace(a: Array):
    """torch for tensors, NumPy for arrays: the functions the step calls exist under one name in both."""
    return torch if isinstance(a, Tensor) else np


@functools.lru_cache(maxsize=4)
def _table(dtype: torch.dtype) -> tuple[Tensor, Tensor]:
    """The datasheet's speed table (m/s at throttle 0, 0.1, ..., 1) and its slope per 0.1 of throttle."""
    speed = torch.as_tensor(datasheet.REFERENCE_SPEED, dtype=dtype)
    return speed, torch.diff(speed)


def _table_speed(throttle: Array) -> Array:
    """The datasheet's steady forward speed at |throttle| (m/s), interpolated linearly (τ in [0, 1])."""
    xp = _namespace(throttle)
    x = xp.clip(xp.abs(throttle), 0.0, datasheet.THROTTLE_LIMIT) * 10.0
    i = xp.clip(xp.floor(x), 0.0, 9.0)
    if xp is torch:
        speed, slope = _table(throttle.dtype)
        index = i.long()
    else:
        speed, slope = datasheet.REFERENCE_SPEED, np.diff(datasheet.REFERENCE_SPEED)
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
) -> tuple[Array, Array]:
    """Next (v, ω) after `dt` s of the control (throttle, steering) from rates (v, ω), broadcast.

    `theta` holds the seven `PARAMETERS` along its last axis; `corrections` the network's raw outputs
    (steady speed, steady yaw rate, speed lag, yaw lag), each squashed into its range (None: pure
    physics). Tensors (training, free runs) or NumPy arrays (identification, several times faster on
    its small arrays), not mixed.
    """
    xp = _namespace(throttle)
    gain_f, gain_r, t_v, scrub, understeer, t_w, brake = (theta[..., i] for i in range(len(PARAMETERS)))
    tan_d = xp.tan(steering)
    gain = xp.where(throttle >= 0, gain_f, gain_r)
    v_ss = xp.sign(throttle) * gain * _table_speed(throttle) / (1.0 + scrub * tan_d * tan_d)
    if corrections is not None:
        z_v, z_w, z_tv, z_tw = corrections
        v_ss = v_ss + residual_bound * datasheet.MAX_SPEED * xp.tanh(z_v)
        t_v = t_v * xp.exp(math.log(LAG_FACTOR) * xp.tanh(z_tv))
        t_w = t_w * xp.exp(math.log(LAG_FACTOR) * xp.tanh(z_tw))
    v_next = v_ss + (v - v_ss) * xp.exp(-dt / t_v)
    braked = v - xp.sign(v) * xp.minimum(xp.abs(v), brake * dt)
    v_next = xp.where(throttle == 0, braked, v_next)
    w_ss = v_next * tan_d / (datasheet.WHEELBASE * understeer)
    if corrections is not None:
        w_ss = w_ss + residual_bound * datasheet.MAX_YAW_RATE * xp.tanh(z_w)
    w_ss = xp.clip(w_ss, -YAW_CAP, YAW_CAP)
    w_next = w_ss + (w - w_ss) * xp.exp(-dt / t_w)
    return v_next, w_next


def _split(x: Tensor, dim: int, rate_at: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
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


def identify(x: np.ndarray, y: np.ndarray, dt: float, rate_at: int) -> Identified:
    """Least-squares physical parameters for rows x (N, 4k) → y (N, 2), with their covariance.

    MAP under the datasheet prior (`_map_fit`): a parameter the rows do not excite stays near the
    datasheet. The covariance is the sandwich with each row its own cluster (rows are one-step
    errors, roughly independent).
    """
    x = torch.as_tensor(np.asarray(x, dtype=np.float64))
    y = np.asarray(y, dtype=np.float64)
    if len(x) == 0:
        return Identified(NOMINAL.copy(), np.diag(WIDTH**2))
    tau, delta, v, w = _split(x, -1, rate_at)

    def errors_of(sets: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            v1, w1 = single_track_step(tau, delta, v, w, torch.as_tensor(sets)[:, None], dt)
        return np.stack([v1.numpy(), w1.numpy()], axis=-1) - y

    return _map_fit(errors_of, y.std(axis=0), np.arange(len(y)))


def run_single_track(controls: np.ndarray, start: np.ndarray, theta: np.ndarray, dt: float) -> np.ndarray:
    """Free runs of the bare single track (`single_track_step`, no correction): controls (M, T, 2), start
    rates (M, 2), parameter sets (P, 7) → rates (P, M, T, 2), the first step being `start`. NumPy,
    every parameter set at once."""
    sets = np.atleast_2d(theta)[:, None]  # (P, 1, 7) against (M,)
    n_runs, n_steps = controls.shape[:2]
    out = np.empty((len(sets), n_runs, n_steps, 2))
    v, w = (np.broadcast_to(start[:, j], (len(sets), n_runs)) for j in range(2))
    out[:, :, 0, 0], out[:, :, 0, 1] = v, w
    for k in range(1, n_steps):
        v, w = single_track_step(controls[:, k, 0], controls[:, k, 1], v, w, sets, dt)
        out[:, :, k, 0], out[:, :, k, 1] = v, w
    return out


def identify_from_logs(
    logs: list[tuple[np.ndarray, np.ndarray]],
    *,
    dt: float = 1.0 / datasheet.LOG_RATE_HZ,
    every: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Output-error least squares: the parameters whose free runs along each log's controls, from its
    first recorded rates, come closest to its recorded rates. Logs are (controls (T, 2), rates (T, 2))
    at `dt`; `every` > 1 fits every n-th step of the runs (they are still simulated at `dt`).

    MAP under the datasheet prior (`_map_fit`), with each log a cluster of the covariance (a free
    run's errors are correlated along it). Free runs weigh the steady states and lags as a free run
    of the model uses them; one-step errors over noisy past rates bias the lags.
    """
    logs = [(np.asarray(u, np.float64), np.asarray(y, np.float64)) for u, y in logs if len(u) > 1]
    if not logs:
        return Identified(NOMINAL.copy(), np.diag(WIDTH**2))
    length = max(len(u) for u, _ in logs)
    controls = np.zeros((len(logs), length, 2))
    rates = np.zeros((len(logs), length, 2))
    valid = np.zeros((len(logs), length), dtype=bool)
    for i, (u, y) in enumerate(logs):
        controls[i, : len(u)], rates[i, : len(u)], valid[i, : len(u)] = u, y, True
        controls[i, len(u) :] = u[-1]
    keep = np.zeros_like(valid)
    keep[:, ::every] = valid[:, ::every]
    start = rates[:, 0]

    def errors_of(sets: np.ndarray) -> np.ndarray:  # (P, n, 2) errors of each parameter set's runs
        return (run_single_track(controls, start, sets, dt) - rates)[:, keep]

    return _map_fit(errors_of, rates[valid].std(axis=0), np.nonzero(keep)[0])


def _map_fit(errors_of, spread: np.ndarray, clusters: np.ndarray) -> Identified:
    """MAP parameters under the datasheet prior: Gaussian errors of unknown size per rate, found in two
    passes (the first, with the prior at 1/`PRIOR_ROWS` of its weight, measures the error size), and
    their cluster-robust covariance. `errors_of` maps parameter sets (P, 7) to errors (P, n, 2);
    `clusters` (n,) labels the error rows whose errors may be correlated (one log's steps)."""
    x0 = np.clip(NOMINAL, LOW + 1e-9, HIGH - 1e-9)
    noise = np.maximum(spread, 1e-3)
    for prior_weight in (1.0 / PRIOR_ROWS, 1.0):

        def residuals_of(sets: np.ndarray, noise=noise, prior_weight=prior_weight) -> np.ndarray:
            err = errors_of(sets) / noise
            prior = (sets - NOMINAL) / WIDTH * math.sqrt(prior_weight)
            return np.concatenate([err.reshape(len(sets), -1), prior], axis=1)

        def fun(p: np.ndarray, residuals_of=residuals_of) -> np.ndarray:
            return residuals_of(p[None])[0]

        def jac(p: np.ndarray, residuals_of=residuals_of) -> np.ndarray:
            # one batched run for every forward difference, stepping inwards at an upper bound
            step = 1e-5 * WIDTH
            step = np.where(p + step > HIGH, -step, step)
            res = residuals_of(np.vstack([p, p + np.diag(step)]))
            return ((res[1:] - res[0]) / step[:, None]).T

        sol = least_squares(fun, x0, jac=jac, bounds=(LOW, HIGH), x_scale=WIDTH, method="trf", max_nfev=100)
        x0 = sol.x
        err = errors_of(sol.x[None])[0]
        noise = np.maximum(np.sqrt(np.mean(err**2, axis=0)), 1e-6 * np.maximum(spread, 1e-3))
    return Identified(sol.x, _sandwich(sol.jac, sol.fun, clusters))


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
    n_clusters = len(np.unique(labels))
    if n_clusters < 2:
        return bread
    scores = errors * residuals[:-n_params, None]  # (n, 7): each row's score
    _, index = np.unique(labels, return_inverse=True)
    per_cluster = np.zeros((n_clusters, n_params))
    np.add.at(per_cluster, index, scores)
    meat = per_cluster.T @ per_cluster * n_clusters / (n_clusters - 1) + prior.T @ prior
    return bread @ meat @ bread


class PhysicsModel(Model):
    """Nigel's single track (identified) plus a bounded Bayesian correction: see the module docstring."""

    kind = "physics"
    compilable = False  # the step reads the model's own scalers and parameters, which compiled templates lack
    # Maneuvers per task of a torch free run (fixed, so the numbers do not depend on the thread count):
    # its step is ~30 small ops, which wider blocks amortise (64 maneuvers x 30 s, S = 32, on a busy
    # 2-core machine: 16 per block 6.0 s, 32 per block 3.7 s; one lone block runs on the calling
    # thread, whose torch ops then spin their intra-op threads: 19 s).
    rollout_block = 32

    def __init__(self, config: ModelConfig, *, generator: torch.Generator | None = None) -> None:
        if config.n_inputs == N_CONTROLS or config.n_inputs % (N_CONTROLS + N_RATES):
            raise InputError("model.kind", "physics", "needs [data] inputs = 'controls+rates' or 'history'")
        super().__init__(config)
        # The correction reads the newest control (τ, δ) alone, or every input of the window.
        self.n_correction_inputs = N_CONTROLS if config.correction_inputs == "control" else config.n_inputs
        self.mirror = config.correction_symmetry == "mirror"
        # A control-only correction is mirror-symmetric by construction, in one network pass: it reads
        # (τ, δ²) and its yaw residual is multiplied by δ / δ_max. A window correction is averaged with
        # its output at the mirrored window (two passes): its inputs' parities are not one feature's.
        self.even_features = self.mirror and config.correction_inputs == "control"
        inner = config.model_copy(
            update={
                "kind": config.correction,
                "n_inputs": self.n_correction_inputs,
                "n_outputs": N_CORRECTIONS,
                "kinematic_feature": False,
            }
        )
        self.correction = NETWORK_CLASSES[config.correction](inner, generator=generator)
        self.n_members = self.correction.n_members
        self.has_epistemic = self.correction.has_epistemic
        lags = model_lags(self)
        self.rate_at = N_CONTROLS * lags.history
        self.dt = lags.step / datasheet.LOG_RATE_HZ
        self.register_buffer("theta", torch.as_tensor(NOMINAL, dtype=torch.float32).clone())
        # Lower Cholesky factor of the identified parameters' covariance (`parameter_uncertainty =
        # "by_log"`; zeros: every draw shares `theta`). Models saved before it existed load with zeros.
        self.register_buffer("theta_scale", torch.zeros(len(PARAMETERS), len(PARAMETERS)))
        # The share of the correction's posterior mean a prediction keeps (`[model] correction_gate`,
        # chosen by `training.fit`); each draw's deviation from that mean is kept whole. Models saved
        # before it existed load with 1 (the whole correction).
        self.register_buffer("correction_weight", torch.ones(()))
        self.register_load_state_dict_pre_hook(_default_correction_weight)
        # False: the bare single track (the correction's outputs held at zero), for comparisons
        self.corrected = True
        self._shrink_last_layer()

    # ----- the physical parameters ------------------------------------------------------------
    def physical_parameters(self) -> dict[str, float]:
        """The identified parameters by name (physical units)."""
        return dict(zip(PARAMETER_NAMES, self.theta.tolist(), strict=True))

    @torch.no_grad()
    def identify(
        self, x: np.ndarray, y: np.ndarray, logs: list[tuple[np.ndarray, np.ndarray]] | None = None
    ) -> None:
        """Fit the physical parameters: to whole logs by their free runs (`identify_from_logs`) where
        given, else to one-step rows (`identify`). A no-op with `identify = false`."""
        if not self.config.identify:
            return
        if logs:
            found = identify_from_logs(logs)
        else:
            found = identify(x, y, self.dt, self.rate_at)
        self.theta.copy_(torch.as_tensor(found.values, dtype=torch.float32))
        self.theta_scale.zero_()
        if self.config.parameter_uncertainty == "by_log":
            self.theta_scale.copy_(torch.as_tensor(_cholesky(found.covariance), dtype=torch.float32))

    def parameter_draws(self, n_samples: int, seed: int) -> Tensor:
        """(S, 7) physical parameters of S posterior draws: `theta` plus its covariance's spread (the
        same normals for one seed), inside the parameters' physical ranges; `theta` itself S times
        where the model has no parameter spread."""
        if not bool(self.theta_scale.any()):
            return self.theta.expand(n_samples, -1)
        normals = torch.randn(
            n_samples, len(PARAMETERS), generator=torch.Generator().manual_seed(int(seed) ^ THETA_SEED_SALT)
        )
        draws = self.theta + normals @ self.theta_scale.T
        low, high = (torch.as_tensor(bound, dtype=draws.dtype) for bound in (LOW, HIGH))
        return torch.clamp(draws, low, high)

    @torch.no_grad()
    def set_scalers(self, x: np.ndarray | Tensor, y: np.ndarray | Tensor) -> None:
        """The model's standardisation, shared by its correction: so the correction, drawn on its own
        (`open_loop_free_runs`), reads physical inputs as the model hands them to it."""
        super().set_scalers(x, y)
        n = self.n_correction_inputs
        self.correction.x_mean.copy_(self.x_mean[:n])
        self.correction.x_std.copy_(self.x_std[:n])
        if self.even_features:  # the correction reads δ², standardised as itself
            square = torch.as_tensor(x, dtype=torch.float32)[:, 1:2].square()
            self.correction.x_mean[1:2], self.correction.x_std[1:2] = column_scalers(square)

    # ----- free runs computed whole (correction_inputs = "control") ---------------------------
    def native_parameters(self, spread: float) -> np.ndarray:
        """The physics as physics_rollout.c reads it (its enum's order)."""
        bound = self.config.residual_bound
        values = [self.dt, *self.theta.tolist(), datasheet.WHEELBASE, datasheet.THROTTLE_LIMIT]
        values += [bound * datasheet.MAX_SPEED, bound * datasheet.MAX_YAW_RATE, YAW_CAP, math.log(LAG_FACTOR)]
        values += [*self.y_std.tolist(), *self._variance_cap().tolist(), spread]
        mirror = 1.0 / datasheet.STEERING_LIMIT if self.even_features else 0.0
        values += [float(self.correction_weight), mirror, *datasheet.REFERENCE_SPEED]
        return np.array(values, dtype=np.float32)

    @torch.no_grad()
    def open_loop_free_runs(
        self,
        n_samples: int,
        seed: int,
        controls: np.ndarray,
        start: Tensor,
        lags: Lags,
        backend: str,
        pose: tuple[float, np.ndarray, float] | None = None,
    ) -> tuple[Tensor, tuple[Tensor, Tensor, Tensor], tuple[np.ndarray, ...] | None] | None:
        """Free runs of a model whose correction reads the control alone (else None).

        The correction is then a function of the operating point: its S draws of `seed` (those of
        `draw(n_samples, seed=seed)`) are evaluated once per distinct control row, and each step is
        the single track's recurrence from the rates of the newest lag of `lags` (`start`, (S, 2, M),
        before that), with the control of its newest control lag, from the log's controls (M, T, 2).
        Each draw's counter-based noise (`counter_noise`) has a key drawn from `seed`. Returns the
        sampled rates (S, 2, M, T), the moments over draws per step, each (M, T, 2), and the pose
        (x, y, yaw), each (S, M, T), where the compiled kernel (physics_rollout.c) integrated it for
        `pose` = (dt, headings (M,), lever arm), else None (the caller integrates). The kernel runs
        where `backend` allows, else torch, drawing the same numbers.
        """
        if self.config.correction_inputs != "control" or not self.corrected:
            return None
        correction = self.correction.draw(n_samples, seed=seed, backend=backend)
        spread = draw_spread(self.epistemic_scale, n_samples)
        keys = torch.randint(2**62, (n_samples,), generator=torch.Generator().manual_seed(seed)).tolist()
        rate_lag, n_steps = lags.rate_lags[0], controls.shape[1]
        newest = np.maximum(np.arange(n_steps) - lags.control_lags[0], 0)  # the control each step reads
        controls = np.ascontiguousarray(controls[:, newest], dtype=np.float32)
        n_maneuvers, n_steps, _ = controls.shape
        # The kernel reads one parameter set: draws with their own parameters step in torch.
        if correction.kernel is not None and not bool(self.theta_scale.any()):
            # the kernel applies the gated correction and the pose
            # Reused memory (`buffers`): first-touch page faults of the fans cost a third of a run.
            rates = buffers.empty((n_samples, 2, n_maneuvers, n_steps))
            moments = tuple(buffers.empty((n_maneuvers, n_steps, 2)) for _ in range(3))
            paths = native_pose = None
            if pose is not None:
                dt, yaw0, arm = pose
                paths = tuple(buffers.empty((n_samples, n_maneuvers, n_steps)) for _ in range(3))
                native_pose = (dt, arm, np.ascontiguousarray(yaw0, dtype=np.float32), paths)
            native.physics_rollout(
                correction.kernel,
                self.native_parameters(spread),
                controls,
                start.contiguous().numpy(),
                np.array(keys, dtype=np.uint64),
                rate_lag,
                rates,
                moments,
                pose=native_pose,
                threads=torch.get_num_threads(),
            )
            return torch.from_numpy(rates), tuple(torch.from_numpy(m) for m in moments), paths
        rates = torch.empty((n_samples, 2, n_maneuvers, n_steps))
        moments = tuple(torch.empty((n_maneuvers, n_steps, 2)) for _ in range(3))
        theta = self.parameter_draws(n_samples, seed)[:, None]  # (S, 1, 7) against (S, M)
        self._torch_free_runs(correction, controls, start, keys, rate_lag, spread, rates, moments, theta)
        return rates, moments, None

    def _torch_free_runs(
        self, correction, controls, start, keys, rate_lag, spread, rates, moments, theta: Tensor
    ) -> None:
        """`open_loop_free_runs` in torch: the reference physics_rollout.c is tested against."""
        _, _, n_maneuvers, n_steps = rates.shape
        flat = controls.reshape(-1, N_CONTROLS)
        unique, index = np.unique(flat, axis=0, return_inverse=True)
        rows = torch.as_tensor(unique.T.copy())  # (2, U)
        if self.even_features:
            z, z_var = correction.columns(torch.stack([rows[0], rows[1].square()]))
            z = _odd_yaw(z, rows[1], -2)
        else:
            z, z_var = correction.columns(rows)  # (S, 4, U)
        z = self._gate(z)
        cap = self._variance_cap()[None, :, None]
        noise_std = torch.minimum(z_var[:, :N_RATES], cap).sqrt_() * self.y_std[None, :, None]
        index = torch.as_tensor(index.reshape(n_maneuvers, n_steps))
        noise = [counter_noise.step_noise(key, n_maneuvers, n_steps) for key in keys]
        noise = torch.as_tensor(np.stack([np.stack(pair) for pair in noise]))  # (S, 2, M, T)
        u = torch.as_tensor(controls)
        for k in range(n_steps):
            rows = index[:, k]
            past = rates[..., k - rate_lag] if k >= rate_lag else start
            zs = z[..., rows].unbind(1)
            tau, delta, bound = u[:, k, 0], u[:, k, 1], self.config.residual_bound
            v1, w1 = single_track_step(tau, delta, past[:, 0], past[:, 1], theta, self.dt, zs, bound)
            means = torch.stack([v1, w1], dim=1)  # (S, 2, M)
            if spread != 1.0:  # widen each draw's correction, not its past (surrogate.widened_step)
                common = past.mean(dim=0)
                vc, wc = single_track_step(tau, delta, common[0], common[1], theta, self.dt, zs, bound)
                at_common = torch.stack([vc, wc], dim=1)
                means = means + (spread - 1.0) * (at_common - at_common.mean(dim=0))
            centre = means.mean(dim=0)
            deviation = means - centre
            std = noise_std[..., rows]
            rates[..., k] = centre + deviation + std * noise[..., k]
            moments[0][:, k] = centre.t()
            moments[1][:, k] = std.square().mean(dim=0).t()
            moments[2][:, k] = deviation.square().mean(dim=0).t()

    # ----- the step ---------------------------------------------------------------------------
    def _physical_step(
        self, x: Tensor, dim: int, z_mean: Tensor, z_var: Tensor, theta: Tensor
    ) -> tuple[Tensor, Tensor]:
        """Standardised (mean, variance) of the next rates, stacked along `dim`, from standardised x, with
        physical parameters `theta` (7,) or one set per draw (S, 1, 7) against columns (S, d, N)."""
        shape = [1] * x.dim()
        shape[dim] = -1
        phys = x * self.x_std.view(shape) + self.x_mean.view(shape)
        tau, delta, v, w = _split(phys, dim, self.rate_at)
        zs = z_mean.unbind(dim) if self.corrected else torch.zeros_like(z_mean).unbind(dim)
        v1, w1 = single_track_step(tau, delta, v, w, theta, self.dt, zs, self.config.residual_bound)
        mean = torch.stack([v1, w1], dim=dim)
        y_shape = [1] * mean.dim()
        y_shape[dim] = -1
        mean = (mean - self.y_mean.view(y_shape)) / self.y_std.view(y_shape)
        var = torch.minimum(z_var.narrow(dim, 0, N_RATES), self._variance_cap().view(y_shape))
        return mean, var

    def _variance_cap(self) -> Tensor:
        """The largest standardised aleatoric variance of (v, ω): one training std, and at most
        `NOISE_CAP` of the rate's limit."""
        return (NOISE_CAP * _RATE_LIMITS / self.y_std).square().clamp(max=1.0)

    def train_forward(self, x: Tensor) -> tuple[Tensor, Tensor | None]:
        """Stochastic pass on standardised x (N, d) or (K, N, d): the correction, then the physics."""
        inputs = x.narrow(-1, 0, self.n_correction_inputs)
        if self.even_features:
            features, delta = self._even_features(inputs, -1)
            z_mean, z_var = self.correction.train_forward(features)
            z_mean = _odd_yaw(z_mean, delta, -1)
        elif self.mirror:  # both halves in one pass: one weight draw for a row and its mirror image
            both = torch.cat([inputs, self._mirrored(inputs, -1)], dim=-2)
            z_mean, z_var = _symmetrise(*self.correction.train_forward(both), -1)
        else:
            z_mean, z_var = self.correction.train_forward(inputs)
        if z_var is None:
            z_var = torch.ones_like(z_mean)
        return self._physical_step(x, -1, z_mean, z_var, self.theta)

    def kl(self) -> Tensor:
        """The correction's KL divergence."""
        return self.correction.kl()

    def sample_params(self, n_samples: int, seed: int) -> list:
        """The correction's posterior draws and each draw's physical parameters (S, 1, 7)."""
        thetas = self.parameter_draws(n_samples, seed)[:, None]
        return [self.correction.sample_params(n_samples, seed), thetas]

    def mean_params(self) -> tuple[list, int]:
        """The correction's posterior-mean weights and the identified parameters."""
        params, n = self.correction.mean_params()
        return [params, self.theta], n

    def columns_params(self, params: list) -> list:
        """The correction's column-layout weights and the physical parameters."""
        return [self.correction.columns_params(params[0]), params[1]]

    def columns_forward(self, x: Tensor, params: list, n_samples: int) -> tuple[Tensor, Tensor]:
        """Standardised (S, 2, N) means and variances for standardised x (d, N) or (S, d, N)."""
        params, theta = params
        inputs = x.narrow(-2, 0, self.n_correction_inputs)
        if self.even_features:
            features, delta = self._even_features(inputs, -2)
            z_mean, z_var = self.correction.columns_forward(features, params, n_samples)
            z_mean = _odd_yaw(z_mean, delta, -2)
        elif self.mirror:
            both = torch.cat([inputs, self._mirrored(inputs, -2)], dim=-1)
            z_mean, z_var = _symmetrise(*self.correction.columns_forward(both, params, n_samples), -2)
        else:
            z_mean, z_var = self.correction.columns_forward(inputs, params, n_samples)
        z_mean = self._gate(z_mean)
        if x.dim() == 2:
            x = x.expand(n_samples, *x.shape)
        return self._physical_step(x, -2, z_mean, z_var, theta)

    def _even_features(self, x: Tensor, dim: int) -> tuple[Tensor, Tensor]:
        """A control-only correction's standardised inputs (τ, δ²) from the model's standardised (τ, δ)
        along `dim`, and the physical steering δ."""
        delta = x.select(dim, 1) * self.x_std[1] + self.x_mean[1]
        square = (delta.square() - self.correction.x_mean[1]) / self.correction.x_std[1]
        return torch.stack([x.select(dim, 0), square], dim=dim), delta

    def _mirrored(self, x: Tensor, dim: int) -> Tensor:
        """Standardised correction inputs (along `dim`) of the mirror image: every steering and yaw rate
        negated in physical units, x' = sign x + (sign - 1) mean / std."""
        n = self.n_correction_inputs
        # Inputs alternate (τ, δ) pairs then (v, ω) pairs, so every odd one is a steering or a yaw rate.
        sign = torch.ones(n)
        sign[1::2] = -1.0
        offset = (sign - 1.0) * self.x_mean[:n] / self.x_std[:n]
        shape = [1] * x.dim()
        shape[dim] = -1
        return x * sign.view(shape) + offset.view(shape)

    def _gate(self, z: Tensor) -> Tensor:
        """Draws (S, 4, N) of the correction with `correction_weight` of their mean over draws kept."""
        weight = float(self.correction_weight)
        if weight == 1.0:
            return z
        centre = z.mean(dim=0, keepdim=True)
        return z - (1.0 - weight) * centre

    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """Re-initialise the correction (last layer shrunk); physical parameters are identified, not drawn."""
        self.correction.reset_parameters(generator)
        self._shrink_last_layer()

    @torch.no_grad()
    def _shrink_last_layer(self) -> None:
        last = self.correction.layers[-1]
        for name in ("weight", "bias", "weight_mu", "bias_mu"):
            if hasattr(last, name):
                getattr(last, name).mul_(LAST_LAYER_SCALE)


def _odd_yaw(z: Tensor, delta: Tensor, dim: int) -> Tensor:
    """Raw outputs (along `dim`) with the yaw residual's times δ / δ_max: odd in the steering δ."""
    yaw = z.select(dim, 1) * (delta / datasheet.STEERING_LIMIT)
    return torch.cat([z.narrow(dim, 0, 1), yaw.unsqueeze(dim), z.narrow(dim, 2, z.shape[dim] - 2)], dim=dim)


def _symmetrise(z: Tensor, z_var: Tensor | None, dim: int) -> tuple[Tensor, Tensor | None]:
    """Outputs at rows then their mirror images (two halves along the last axis, outputs along `dim`)
    made mirror-symmetric: the yaw-rate residual's odd part, every other output's even part."""
    shape = [1] * z.dim()
    shape[dim] = -1
    parity = torch.tensor(MIRROR_PARITY, dtype=z.dtype).view(shape)
    axis = -2 if dim == -1 else -1  # rows: the batch axis of (N, 4) rows, the last of (S, 4, N) columns
    half = z.shape[axis] // 2
    a, b = z.narrow(axis, 0, half), z.narrow(axis, half, half)
    z = 0.5 * (a + parity * b)
    if z_var is not None:
        z_var = 0.5 * (z_var.narrow(axis, 0, half) + z_var.narrow(axis, half, half))
    return z, z_var


def _default_correction_weight(module, state_dict, prefix, *args) -> None:
    """Load hook: a state dict saved before `correction_weight` (`theta_scale`) existed keeps the whole
    correction (no parameter spread)."""
    state_dict.setdefault(prefix + "correction_weight", torch.ones(()))
    state_dict.setdefault(prefix + "theta_scale", torch.zeros(len(PARAMETERS), len(PARAMETERS)))


def _cholesky(covariance: np.ndarray) -> np.ndarray:
    """Lower Cholesky factor of a covariance that may be singular (a parameter fixed at the prior's
    bound): through its eigen-decomposition, negative round-off eigenvalues set to 0."""
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    root = vectors * np.sqrt(np.clip(values, 0.0, None))
    return np.linalg.cholesky(root @ root.T + 1e-12 * np.eye(len(covariance)))


def control_box_sweep(duration: float = 60.0, rate_hz: float = datasheet.LOG_RATE_HZ) -> list[np.ndarray]:
    """Control sequences (T, 2) over Nigel's whole control box: constants at its corners, edges and
    centre (throttle 0, the brake, included) and steps across it halfway through."""
    n = round(duration * rate_hz)
    half = n // 2
    lock = datasheet.STEERING_LIMIT
    out = [np.tile([t, d], (n, 1)) for t in (-1.0, -0.5, 0.0, 0.5, 1.0) for d in (-lock, 0.0, lock)]
    for (t0, d0), (t1, d1) in (
        ((1.0, lock), (-1.0, -lock)),
        ((-1.0, lock), (0.0, 0.0)),
        ((0.0, -lock), (1.0, lock)),
        ((0.3, 0.0), (-1.0, lock)),
    ):
        out.append(np.vstack([np.tile([t0, d0], (half, 1)), np.tile([t1, d1], (n - half, 1))]))
    return out


def runs_out_of_bounds(v: np.ndarray, w: np.ndarray, factor: float = 1.5) -> int:
    """How many sampled free runs (rates (S, M, T)) are not finite or leave `factor` x Nigel's speed or
    yaw-rate limit at some step."""
    bad = ~(np.isfinite(v) & np.isfinite(w))
    bad |= np.abs(np.nan_to_num(v)) > factor * datasheet.MAX_SPEED
    bad |= np.abs(np.nan_to_num(w)) > factor * datasheet.MAX_YAW_RATE
    return int(bad.any(axis=-1).sum())

