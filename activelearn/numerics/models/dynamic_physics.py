"""The physics kind with the dynamic single track as its core (`[model] core = "dynamic"`).

The core is `dynamic_track`'s bicycle (tyre slip, saturating tyres, load transfer, the drivetrain,
the kinematic blend at low speed; its tyre damping exponential, in 25-ms substeps) with its five scales
(`DYNAMIC_PARAMETERS`; nine with `[model] kinematic_blend = "core"`, `parameters_of`) identified under
the vehicle file's prior from whole logs, the free runs restarted every `IDENTIFY_HORIZON` s
(`identify_dynamic`), with their cluster-robust covariance (`parameter_uncertainty = "by_log"` draws them
per posterior draw).
The bounded Bayesian correction of the physics kind stays on top, reading the control alone: its
steady residuals (at most `residual_bound` of the speed and yaw-rate limits) are reached at the car's
lags (the kinematic prior's, each scaled within [1/3, 3] by the correction), so a step's change is
bounded whatever the inputs, and the yaw rate is held within 1.25 x the car's limit as the kinematic
core's is.

The logs hold speed and yaw rate, not the lateral speed v_y nor the wheels' angle δ_w. Free runs carry
both as the core's own state (`open_loop_free_runs`), and integrate the pose with the sideslip. A
one-step row (training, `predict`) starts the step from v_y of a steady turn at its (v, ω)
(`quasi_static_lateral`) and δ_w at the window's previous steering: the lateral mode settles in about
m v / (C_f + C_r), a tenth of a second on the 1:10 car, so a row's step of `history_step` log steps
mostly forgets its start, and the correction trained on rows sees nearly the step free runs take.

With `discrepancy` the identification also measures the core's rms misfit of its logs (`"identification"`:
in sample; `"cross_validated"`: each of 4 folds at the scales identified without it), and each free-run
draw's rates carry an Ornstein-Uhlenbeck error of that size (`discrepancy.discrepancy_paths`): the pose
fan widens by what no scale explains, about the core's own mean path (the kinematic core does the same).

A step is written once as pure functions (`corrected_step`, `free_run_step`) that `compile_steps` has
torch.compile fuse (`compiled_step`): eagerly each is a few hundred small operations. Free runs take the
compiled kernel (`native.dynamic_free_runs`, dynamic_rollout.c: the whole recurrence, every draw and
step, in float, and the pose with the discrepancy) where it builds, and those steps in torch elsewhere.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor

from activelearn.config import ModelConfig
from activelearn.names import IDENTIFIED_PREFIX
from activelearn.numerics import native
from activelearn.numerics.lags import Lags
from activelearn.numerics.models.base import kernels_for
from activelearn.numerics.models.discrepancy import CORRELATION_TIME, widened_pose
from activelearn.numerics.models.dynamic_fit import (
    cross_validated_misfit,
    identify_dynamic,
    log_information,
    misfit,
)
from activelearn.numerics.models.dynamic_scales import dynamic_bounds, parameters_of, scaled, with_scales
from activelearn.numerics.models.dynamic_track import (
    DynamicCar,
    dynamic_step,
    native_car,
    native_sets,
    quasi_static_lateral,
    rate_runs,
)
from activelearn.numerics.models.physics import PhysicsModel
from activelearn.numerics.models.single_track import (
    LAG_FACTOR,
    Identified,
    others_estimate,
    split_inputs,
    widened,
)
from activelearn.numerics.pose import integrate_pose
from activelearn.numerics.training_data import TrainingData

# s: free runs restart from the logged rates (a spinning car's 30 s are chaotic); the misfit's restarts too,
# so it is the discrepancy's correlation time
IDENTIFY_HORIZON = CORRELATION_TIME
IDENTIFY_EVERY = 3  # log steps between the compared points of an identification's free runs
# how the model identifies its scales and measures their misfit: the restarts, spacing and step above
IDENTIFICATION = {"every": IDENTIFY_EVERY, "horizon": IDENTIFY_HORIZON, "implicit": True}
FALLBACK_NOISE = 0.01  # `parameter_information`'s rate errors without a measured misfit: share of the limits


def identify_scales(
    logs: list[tuple[np.ndarray, np.ndarray]],
    car: DynamicCar,
    dt: float,
    search_from: np.ndarray | None = None,
    prior: Identified | None = None,
    loss: str = "squares",
    also_from_prior: bool = False,
) -> Identified:
    """The car's scales from logs as the model identifies them (`identify_dynamic`: free runs of the step it
    takes, restarted every `IDENTIFY_HORIZON` s, compared every `IDENTIFY_EVERY` log steps), under `prior`
    (default the file's), by `loss` (`[model] identification_loss`); `also_from_prior`: a search from
    `search_from` also searches from the prior's centre (`[model] identification_starts`)."""
    return identify_dynamic(logs, car, dt, search_from=search_from, prior=prior, loss=loss,
                            also_from_prior=also_from_prior, **IDENTIFICATION)  # fmt: skip


def scales_of_another_car(
    others: list[tuple[np.ndarray, np.ndarray]], car: DynamicCar, dt: float, loss: str = "squares"
) -> Identified:
    """The prior this car's logs are identified under where `others` are another car's logs of the same
    file (a grid of the nominal simulator for a twin or a real car): the scales they give alone
    (`identify_scales` by `loss`, as this car's own, once per set of logs), their covariance widened by
    the scales' widths."""
    estimate = others_estimate(others, identify_scales, car=car, dt=dt, loss=loss)
    return widened(estimate, dynamic_bounds(car).width)


def before_a_stop(log: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """A log (controls (T, 2), rates (T, 2)) up to a live stop's trigger: the trailing block of throttle
    exactly 0 after a nonzero throttle is the stop's braking (`simulator.stop`), an intervention, not the
    maneuver. With neither `combined_slip` nor `wheel_forces` the core cannot follow it (braking at the
    grip limit with the steering held leaves a car no lateral grip, the core all of it): identified on,
    those rows bent a 1:10 safe campaign's scales to their bounds. Other logs whole."""
    throttle = log[0][:, 0]
    driven = np.flatnonzero(throttle != 0.0)
    if len(driven) == 0 or driven[-1] == len(throttle) - 1:
        return log
    end = int(driven[-1]) + 1
    return log[0][:end], log[1][:end]


def identification_misfit(
    logs: list[tuple[np.ndarray, np.ndarray]], car: DynamicCar, dt: float, theta: np.ndarray,
    cross_validated: bool = False, loss: str = "squares",
) -> np.ndarray:  # fmt: skip
    """(2,) the rms misfit (v, r) of `identify_scales`' own free runs at scales `theta` (`misfit`), or
    out of sample (`cross_validated_misfit`: each of 4 folds at the scales identified without it, by
    `loss`)."""
    if cross_validated:
        return cross_validated_misfit(logs, car, dt, theta, loss=loss, **IDENTIFICATION)
    return misfit(logs, car, dt, theta, **IDENTIFICATION)


@dataclass(frozen=True)
class CorrectionLimits:
    """What bounds the correction on top of the core: its steady residuals' share of the car's speed and
    yaw-rate limits (`residual_bound`), the lags they are reached at (s: speed, yaw; each scaled within
    e^±`log_factor`), the yaw rate's cap and the model step (s)."""

    bound: float
    max_speed: float
    max_yaw_rate: float
    yaw_cap: float
    speed_lag: float
    yaw_lag: float
    log_factor: float
    dt: float
    substeps: int


def corrected_step(
    car: DynamicCar, state: Tensor, tau: Tensor, delta: Tensor, zs, limits: CorrectionLimits
) -> Tensor:
    """The state (..., 4) = (v_x, v_y, r, δ_w) after one model step, the correction's residuals (raw
    outputs `zs`: speed, yaw rate, their lags) added to v_x and r."""
    nxt = dynamic_step(car, state, tau, delta, limits.dt, limits.substeps, implicit=True)
    z_v, z_w, z_tv, z_tw = zs
    lag_v = limits.speed_lag * torch.exp(limits.log_factor * torch.tanh(z_tv))
    lag_w = limits.yaw_lag * torch.exp(limits.log_factor * torch.tanh(z_tw))
    share_v, share_w = 1.0 - torch.exp(-limits.dt / lag_v), 1.0 - torch.exp(-limits.dt / lag_w)
    v = nxt[..., 0] + share_v * limits.bound * limits.max_speed * torch.tanh(z_v)
    w = nxt[..., 2] + share_w * limits.bound * limits.max_yaw_rate * torch.tanh(z_w)
    w = w.clamp(-limits.yaw_cap, limits.yaw_cap)
    return torch.stack([v, nxt[..., 1], w, nxt[..., 3]], dim=-1)


def free_run_step(
    car: DynamicCar, state: Tensor, tau: Tensor, delta: Tensor, zs, limits: CorrectionLimits, std: Tensor,
    noise: Tensor, spread: Tensor, widen: bool,
) -> tuple[Tensor, ...]:  # fmt: skip
    """One step of S draws' free runs (state (S, M, 4)): each draw's rates (S, 2, M) without and with the
    sensors' noise (`std` × `noise`), its v_y and δ_w, and the moments over draws (centre, aleatoric and
    epistemic variance, each (2, M)). `widen`: each draw's correction spread by `spread` about the
    draws' mean (`surrogate.widened_step`), not its past."""
    nxt = corrected_step(car, state, tau, delta, zs, limits)
    means = torch.stack([nxt[..., 0], nxt[..., 2]], dim=1)
    if widen:
        common = corrected_step(car, state.mean(dim=0).expand_as(state), tau, delta, zs, limits)
        common = torch.stack([common[..., 0], common[..., 2]], dim=1)
        means = means + (spread - 1.0) * (common - common.mean(dim=0))
    centre = means.mean(dim=0)
    deviation = means - centre
    noisy = means + std * noise
    aleatoric, epistemic = std.square().mean(dim=0), deviation.square().mean(dim=0)
    return means, noisy, nxt[..., 1], nxt[..., 3], centre, aleatoric, epistemic


_EAGER: dict[str, Callable] = {"corrected": corrected_step, "free_run": free_run_step}
_COMPILED: dict[str, Callable] = {}


def compiled_step(name: str) -> Callable:
    """`corrected_step` or `free_run_step` compiled (torch.compile, inductor): a model step becomes a few
    fused kernels instead of some 400 small ops, forward and backward (1:10 car: a 30-step window of 32
    rows 0.16 s eagerly, 0.008 s compiled). Compiled on first use (~25 s, a few s from torch's on-disk
    cache), each with its own dynamo cache (the shapes of rows, windows and free runs each compile)."""
    if name not in _COMPILED:
        _COMPILED[name] = torch.compile(_EAGER[name], isolate_recompiles=True, recompile_limit=32)
    return _COMPILED[name]


class DynamicPhysicsModel(PhysicsModel):
    """The physics kind on the dynamic single track: see the module docstring."""

    core_in_scales = True  # its parameters scale the vehicle file's figures

    def __init__(self, config: ModelConfig, *, generator: torch.Generator | None = None) -> None:
        super().__init__(config, generator=generator)  # the config checked correction_inputs (`core`)
        self.dynamic_car = replace(
            DynamicCar.of(self.car.spec), combined_slip=config.combined_slip,
            wheel_forces=config.wheel_forces, tangent_damping=config.tyre_damping == "tangent",
            wheel_passes=config.wheel_passes, blend_share=config.blend_share,
            kinematic_core=config.kinematic_blend == "core",
        )
        self.substeps = self.dynamic_car.implicit_substeps(self.dt)
        bounds = dynamic_bounds(self.dynamic_car)
        self.parameter_names = tuple(p.name for p in parameters_of(self.dynamic_car))
        self.parameter_bounds = (bounds.low, bounds.high)
        self.parameter_widths = bounds.width
        self.register_buffer("theta", torch.as_tensor(bounds.prior.values, dtype=torch.float32).clone())
        self.register_buffer("theta_scale", torch.zeros(len(self.parameter_names), len(self.parameter_names)))
        # the lags the correction's residuals are reached at: the kinematic prior's (speed, yaw)
        names = [p.name for p in self.car.parameters]
        self.lags = (
            float(self.car.nominal[names.index("speed_lag")]),
            float(self.car.nominal[names.index("yaw_lag")]),
        )
        self.compiled = False  # whether the model's steps run compiled (`compile_steps`)
        # the correction's bounds on this car, fixed with it: built once, not per step
        self.limits = CorrectionLimits(
            bound=config.residual_bound, max_speed=self.car.max_speed, max_yaw_rate=self.car.max_yaw_rate,
            yaw_cap=self.car.yaw_cap, speed_lag=self.lags[0], yaw_lag=self.lags[1],
            log_factor=math.log(LAG_FACTOR), dt=self.dt, substeps=self.substeps,
        )  # fmt: skip

    # ----- identification ---------------------------------------------------------------------
    @torch.no_grad()
    def identify(self, data: TrainingData, *, warm: bool = False) -> None:
        """The scales from the logs of this car (`identify_dynamic`, restarts every
        `IDENTIFY_HORIZON` s) under the file's prior, or under another car's: its logs' scales where the
        data flag logs as another car's (`scales_of_another_car`), or its model's (`core_prior`). With no
        log of this car that prior stands, its width in the fans; rows without logs leave the file's
        values. A no-op with `identify = false`."""
        if not self.config.identify:
            return
        logs = list(data.logs or [])
        flags = list(data.of_another_car) if data.of_another_car is not None else [False] * len(logs)
        own = [before_a_stop(log) for log, other in zip(logs, flags, strict=True) if not other]
        others = [log for log, other in zip(logs, flags, strict=True) if other]
        dt = 1.0 / self.car.log_rate_hz
        loss = self.config.identification_loss
        prior = scales_of_another_car(others, self.dynamic_car, dt, loss) if others else self.core_prior
        if not own:
            if prior is not None:
                self.set_identified(prior)
            return
        search_from = self.theta.double().numpy() if warm else None
        also_from_prior = self.config.identification_starts == "last_and_prior"
        found = identify_scales(own, self.dynamic_car, dt, search_from, prior, loss, also_from_prior)
        self.set_identified(found)
        if self.discrepancy is not None:
            cross = self.config.discrepancy == "cross_validated"
            misfit_of_logs = identification_misfit(own, self.dynamic_car, dt, found.values, cross, loss)
            self.discrepancy.copy_(torch.as_tensor(misfit_of_logs, dtype=torch.float32))
            self.discrepancy_logs.fill_(float(len(own)))

    def parameter_information(
        self, controls: list[np.ndarray], rate_hz: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Each control sequence's Fisher information about the scales (`log_information`): the
        sensitivities of the core's rates along the identification's own restarted free runs, taken along
        the core's path from rest at the current scales, each rate weighted by the misfit of the logs
        (`discrepancy`; without one `FALLBACK_NOISE` of the car's limits); and the scales' prior precision.
        The controls must be at the car's log rate, the rate the identification runs at."""
        if not math.isclose(rate_hz, self.car.log_rate_hz):
            raise ValueError(f"controls at {rate_hz} Hz: identification runs at {self.car.log_rate_hz} Hz")
        theta, dt = self.theta.double().numpy(), 1.0 / self.car.log_rate_hz
        paths: list[np.ndarray] = [np.empty(0)] * len(controls)
        for length in sorted({len(u) for u in controls}):  # the core's own paths, a length at a time
            group = [i for i, u in enumerate(controls) if len(u) == length]
            u = np.stack([np.asarray(controls[i], np.float64) for i in group])
            start = np.column_stack([np.zeros((len(group), 3)), u[:, 0, 1]])  # at rest, wheels at the command
            rates = rate_runs(scaled(self.dynamic_car, theta), u, start, dt, implicit=True)[0]
            for row, i in enumerate(group):
                paths[i] = rates[row]
        noise = FALLBACK_NOISE * np.array([self.car.max_speed, self.car.max_yaw_rate])
        if self.discrepancy is not None and bool((self.discrepancy > 0).all()):
            noise = self.discrepancy.double().numpy()
        logs = [(np.asarray(u, np.float64), path) for u, path in zip(controls, paths, strict=True)]
        info = log_information(logs, self.dynamic_car, dt, theta, noise, **IDENTIFICATION)
        return info, np.diag(1.0 / dynamic_bounds(self.dynamic_car).width ** 2)

    def round_metrics(self) -> dict[str, float]:
        """The kept share of the correction and the identified scales (`identified_friction`, ...): a
        campaign's curves show what the core learnt of the car round by round."""
        scales = {IDENTIFIED_PREFIX + name: value for name, value in self.physical_parameters().items()}
        return {**super().round_metrics(), **scales}

    # ----- the step ---------------------------------------------------------------------------
    def compile_steps(self) -> None:
        """Windows, rows and free runs step compiled from now on (`compiled_step`)."""
        self.compiled = True

    def _step(self, name: str) -> Callable:
        """`corrected_step` or `free_run_step`, compiled where asked and where compiling works."""
        if not self.compiled:
            return _EAGER[name]

        def guarded(*args):
            try:
                return compiled_step(name)(*args)
            except Exception as exc:  # torch.compile's failures share no type
                warnings.warn(f"torch.compile failed ({exc}); the dynamic core steps eagerly", RuntimeWarning,
                              stacklevel=3)  # fmt: skip
                self.compiled = False
                return self._step(name)(*args)

        return guarded

    def _scaled_car(self, theta: Tensor) -> DynamicCar:
        """The file's car under scales `theta` (P,) or one set per draw (S, 1, P)."""
        return with_scales(self.dynamic_car, *(theta[..., i] for i in range(len(self.parameter_names))))

    def _core_step(
        self, phys: Tensor, dim: int, zs: tuple[Tensor, ...], theta: Tensor
    ) -> tuple[Tensor, Tensor]:
        """One row's step: v_y of a steady turn at its (v, ω), δ_w at the window's previous steering."""
        tau, delta, v, w = split_inputs(phys, dim, self.rate_at)
        previous = phys.select(dim, 3) if self.rate_at > 2 else delta  # the second control lag's steering
        car = self._scaled_car(theta)
        state = torch.stack(torch.broadcast_tensors(v, quasi_static_lateral(car, v, w), w, previous), dim=-1)
        if torch.is_grad_enabled():
            # A window's first step sees data only, its later ones predicted rates: the same tensors' grad
            # flags on every step (controls detached, the state tracked) let the compiled step compile
            # once, not twice (a cold compile: 68-76 s before, 60-62 s). Numbers and gradients are unchanged.
            tau, delta = tau.detach(), delta.detach()
            if not state.requires_grad:
                state = state.detach().requires_grad_()
        nxt = self._step("corrected")(car, state, tau, delta, zs, self.limits)
        return nxt[..., 0], nxt[..., 2]

    # ----- free runs, the lateral speed and wheel angle carried -------------------------------
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
    ) -> tuple[Tensor, tuple[Tensor, Tensor, Tensor], tuple[np.ndarray, ...] | None]:
        """`PhysicsModel.open_loop_free_runs` on the dynamic core: each draw carries its own
        (v_x, v_y, r, δ_w) from step to step, and the pose is integrated with the sideslip where asked.
        The recurrence runs in C (dynamic_rollout.c) where `backend` allows, else in torch
        (`_torch_free_runs`), drawing the same numbers to float rounding.
        The aleatoric noise is the sensors': it is added to the rates returned, not carried by the state
        nor the pose (carried, 3 % of the speed limit per step random-walked the 1:10 car's free runs:
        its file's core 9.9 m off at 30 s against 2.3 m). The bare core (`corrected` False) holds the
        correction's outputs at zero."""
        correction, spread, keys, controls = self._free_run_setup(n_samples, seed, controls, lags, backend)
        rate_lag = lags.rate_lags[0]
        lib = kernels_for(backend)
        z, noise_std, index, noise = self._free_run_draws(correction, controls, keys, noise=lib is None)
        if not self.corrected:
            z = torch.zeros_like(z)
        theta = self.parameter_draws(n_samples, seed)
        car = self._scaled_car(theta[:, None])  # (S, 1) figures
        u = torch.as_tensor(controls)
        start_hidden = torch.stack(
            [quasi_static_lateral(car, start[:, 0], start[:, 1]), u[:, 0, 1].expand(n_samples, -1)], dim=1
        )
        if lib is None:
            states, rates, hidden, moments = self._torch_free_runs(
                car, u, (start, start_hidden), z, noise_std, index, noise, rate_lag, spread
            )
            return rates, moments, self._free_run_pose(states, hidden, pose, (keys, seed))
        # the whole recurrence and the pose in C (dynamic_rollout.c), its noise drawn there
        sets = native_sets(scaled(self.dynamic_car, theta.double().numpy()), (n_samples, 1))
        native_pose = None
        if pose is not None:  # (dt, lever arm, headings, the discrepancy's sizes and correlation time)
            discrepancy = None
            if self._carries_discrepancy:
                discrepancy = (self.discrepancy_sizes(n_samples, seed), IDENTIFY_HORIZON)
            native_pose = (*pose[::2], pose[1], discrepancy)
        outputs = native.dynamic_free_runs(
            lib, native_car(self.dynamic_car), sets, (self.dynamic_car.table_throttle,
            self.dynamic_car.table_speed), self.native_limits(), self.dt, self.substeps,
            (z.numpy(), noise_std.numpy(), np.array(keys, dtype=np.uint64), index.numpy()), controls,
            (start.numpy(), start_hidden.numpy()), rate_lag, spread, pose=native_pose,
            threads=torch.get_num_threads(),
        )  # fmt: skip
        rates, *moments = (torch.from_numpy(a) for a in outputs[:4])
        return rates, tuple(moments), outputs[4:] or None

    def native_limits(self) -> np.ndarray:
        """The correction's bounds as dynamic_rollout.c reads them (its L_ enum)."""
        q = self.limits
        return np.array([q.bound * q.max_speed, q.bound * q.max_yaw_rate, q.yaw_cap, q.speed_lag, q.yaw_lag,
                         q.log_factor])  # fmt: skip

    def _torch_free_runs(
        self, car: DynamicCar, u: Tensor, start: tuple[Tensor, Tensor], z: Tensor, noise_std: Tensor,
        index: Tensor, noise: Tensor, rate_lag: int, spread: float,
    ) -> tuple[Tensor, Tensor, Tensor, tuple[Tensor, Tensor, Tensor]]:  # fmt: skip
        """`open_loop_free_runs`' recurrence in torch, a step at a time (`free_run_step`, compiled where
        the model is): the reference dynamic_rollout.c is tested against. Returns each draw's rates
        without and with the noise and its (v_y, δ_w), each (S, 2, M, T), and the moments over draws."""
        n_samples, _, n_maneuvers, n_steps = noise.shape
        start, start_hidden = start
        rates = torch.empty((n_samples, 2, n_maneuvers, n_steps))
        states = torch.empty((n_samples, 2, n_maneuvers, n_steps))  # each draw's rates without the noise
        hidden = torch.empty((n_samples, 2, n_maneuvers, n_steps))  # v_y, δ_w after each step
        moments = tuple(torch.empty((n_maneuvers, n_steps, 2)) for _ in range(3))
        step, limits = self._step("free_run"), self.limits
        widen, spread_t = spread != 1.0, torch.tensor(spread)
        for k in range(n_steps):
            rows = index[:, k]
            past, past_hidden = start, start_hidden
            if k >= rate_lag:
                past, past_hidden = states[..., k - rate_lag], hidden[..., k - rate_lag]
            state = torch.stack([past[:, 0], past_hidden[:, 0], past[:, 1], past_hidden[:, 1]], dim=-1)
            means, noisy, lateral, wheel, centre, aleatoric, epistemic = step(
                car, state, u[:, k, 0], u[:, k, 1], z[..., rows].unbind(1), limits, noise_std[..., rows],
                noise[..., k], spread_t, widen,
            )  # fmt: skip
            states[..., k], rates[..., k] = means, noisy
            hidden[:, 0, :, k], hidden[:, 1, :, k] = lateral, wheel
            moments[0][:, k], moments[1][:, k], moments[2][:, k] = centre.t(), aleatoric.t(), epistemic.t()
        return states, rates, hidden, moments

    def _free_run_pose(
        self, states: Tensor, hidden: Tensor, pose: tuple[float, np.ndarray, float] | None,
        draws: tuple[list[int], int],
    ) -> tuple[np.ndarray, ...] | None:
        """Each draw's pose (x, y, ψ) from its rates and sideslip, widened by the discrepancy, where
        `pose` = (dt, headings, lever arm) asks for it."""
        paths = None
        if pose is not None:
            dt, yaw0, arm = pose
            slip = hidden[:, 0] - self.dynamic_car.lr * states[:, 1]  # the rear axle's lateral speed
            yaw0 = torch.as_tensor(yaw0, dtype=states.dtype)[:, None]
            pose = integrate_pose(states[:, 0], states[:, 1], dt, yaw0, lever_arm=arm, lateral=slip)
            if self._carries_discrepancy:
                keys, seed = draws
                sizes = self.discrepancy_sizes(len(keys), seed)
                pose = widened_pose(pose, (states[:, 0], states[:, 1]), (dt, yaw0, arm, slip), sizes, keys)
            paths = tuple(part.numpy() for part in pose)
        return paths
