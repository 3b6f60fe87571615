"""A surrogate that knows the car: its single track from its vehicle file plus a bounded Bayesian correction.

The physics core is Nigel's single track (`activelearn.numerics.models.single_track`: the step, the
seven `PARAMETERS`, their identification), stepping the rates y = (v, ω) over the Δ = `history_step`
/ 30 Hz between a dynamic model's newest past rate and its target, from the newest control. Its
parameters are identified before every fit: by the free runs of the training logs where the caller
gives them (what campaigns do), else from one-step rows, MAP with the datasheet as the prior, so a
parameter the data do not touch (say the reverse gain, trained forward only) stays at the datasheet's
value. With `parameter_uncertainty = "by_log"` each posterior draw has its own parameters, drawn from
their cluster-robust covariance (`parameter_draws`). With `discrepancy` the identification also measures
the core's misfit of its logs (`single_track.misfit_of_logs`) and the free runs' pose fans carry it
(`activelearn.numerics.models.discrepancy`), about the mean path: computed in NumPy from the kernel's
rates, not in the kernel.

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

import math

import numpy as np
import torch
from torch import Tensor

from activelearn.config import ModelConfig
from activelearn.errors import InputError
from activelearn.names import CORRECTION_WEIGHT
from activelearn.numerics import buffers, counter_noise, native
from activelearn.numerics.lags import N_CONTROLS, N_RATES, Lags, model_lags
from activelearn.numerics.models.base import Model, column_scalers, draw_spread
from activelearn.numerics.models.discrepancy import CORRELATION_TIME, discrepancy_sizes, widened_pose
from activelearn.numerics.models.networks import NETWORK_CLASSES
from activelearn.numerics.models.single_track import (
    LAG_FACTOR,
    NIGEL,
    PARAMETER_NAMES,
    PARAMETERS,
    THROTTLE_LIMIT,
    CarPrior,
    Identified,
    another_cars_prior,
    car_prior,
    cholesky_factor,
    identify,
    identify_from_logs,
    identify_on_another_car,
    misfit_of_logs,
    single_track_step,
    split_inputs,
    widened,
)
from activelearn.numerics.pose import integrate_pose
from activelearn.numerics.training_data import TrainingData

N_CORRECTIONS = 4  # steady-state residuals (v, ω) and lag factors (v, ω)
# Under the mirror (δ, ω → −δ, −ω) the steady yaw-rate residual changes sign; the speed residual, both
# lag factors and the aleatoric variances do not.
MIRROR_PARITY = (1.0, -1.0, 1.0, 1.0)
LAST_LAYER_SCALE = 0.1  # the correction starts near zero: an untrained model is the datasheet's physics
# The aleatoric std of each rate is at most this fraction of its limit (speed, yaw rate). MuJoCo's
# logged rates carry 0.2 % / 1.8 % of the limits; without a physical cap (the old one: the training
# rates' std, 0.27 rad/s) the noise of a free run at full lock carried ω past 1.5x the limit (3 of
# 608 sweep runs, experiments/results/physics.txt). With ≤ 3 %, five sigma over the 1.25x yaw cap
# stays below 1.5x.
NOISE_CAP = 0.03
THETA_SEED_SALT = 0x7E7A  # the parameter draws' normals differ from the correction's of the same seed


class PhysicsModel(Model):
    """A car's single track (identified) plus a bounded Bayesian correction: see the module docstring.
    The car is `config.vehicle` (its vehicle file: the prior, the limits, the throttle → speed map)."""

    kind = "physics"
    compilable = False  # the step reads the model's own scalers and parameters, which compiled templates lack
    # Maneuvers per task of a torch free run (fixed, so the numbers do not depend on the thread count):
    # its step is ~30 small ops, which wider blocks amortise (64 maneuvers x 30 s, S = 32, on a busy
    # 2-core machine: 16 per block 6.0 s, 32 per block 3.7 s; one lone block runs on the calling
    # thread, whose torch ops then spin their intra-op threads: 19 s).
    rollout_block = 32
    identifies_on_logs = True
    # Whether the core's parameters are shares of the vehicle file's figures, which carry to another
    # file (`start_from_another_car`); the kinematic core's are the car's own gains, lags and scrub.
    core_in_scales = False

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
        self.car: CarPrior = car_prior(config.vehicle)
        self.dt = lags.step / self.car.log_rate_hz
        # float32, as y_std: the rates' limits (speed, yaw rate) the aleatoric cap is a share of
        self.rate_limits = torch.tensor([self.car.max_speed, self.car.max_yaw_rate])
        # the core's parameters: their names and physical ranges (the kinematic core's seven here)
        self.parameter_names: tuple[str, ...] = PARAMETER_NAMES
        self.parameter_bounds: tuple[np.ndarray, np.ndarray] = (self.car.low, self.car.high)
        self.parameter_widths: np.ndarray = self.car.width  # the file's prior widths
        # the prior this car's identification runs under where another car's model gave one (its
        # identified core, `widened`); None: the vehicle file's. Not saved: `Fitting` sets it every round.
        self.core_prior: Identified | None = None
        self.register_buffer("theta", torch.as_tensor(self.car.nominal, dtype=torch.float32).clone())
        # Lower Cholesky factor of the identified parameters' covariance (`parameter_uncertainty =
        # "by_log"`; zeros: every draw shares `theta`). Models saved before it existed load with zeros.
        self.register_buffer("theta_scale", torch.zeros(len(PARAMETERS), len(PARAMETERS)))
        # The share of the correction's posterior mean a prediction keeps (`[model] correction_gate`,
        # chosen by `training.fit`); each draw's deviation from that mean is kept whole. Models saved
        # before it existed load with 1 (the whole correction).
        self.register_buffer("correction_weight", torch.ones(()))
        self.register_load_state_dict_pre_hook(_default_correction_weight)
        # the core's misfit of its logs (v, r) that `discrepancy` widens the fans by (None: "none"), and
        # the number of logs it was measured on (0: unknown, a file saved before it; `discrepancy_sizes`)
        self.register_buffer("discrepancy", torch.zeros(2) if config.discrepancy != "none" else None)
        self.register_buffer("discrepancy_logs", torch.zeros(()) if config.discrepancy != "none" else None)
        self.register_load_state_dict_pre_hook(_unknown_discrepancy_logs)
        # False: the bare single track (the correction's outputs held at zero), for comparisons
        self.corrected = True
        self._shrink_last_layer()

    # ----- the physical parameters ------------------------------------------------------------
    def physical_parameters(self) -> dict[str, float]:
        """The identified parameters by name (physical units)."""
        return dict(zip(self.parameter_names, self.theta.tolist(), strict=True))

    @torch.no_grad()
    def identify(self, data: TrainingData, *, warm: bool = False) -> None:
        """Fit the physical parameters: to whole logs by their free runs (`identify_from_logs`) where
        given, else to one-step rows (`identify`). Logs flagged in `of_another_car` (a simulated prior
        grid) only centre the prior the others are identified under (`identify_on_another_car`). `warm`:
        the search starts from `theta` (the last round's solution; the prior is unchanged). A no-op
        with `identify = false`."""
        if not self.config.identify:
            return
        logs, of_another_car = data.logs, data.of_another_car
        search_from = self.theta.double().numpy() if warm else None
        if not logs and self.core_prior is not None:
            self.set_identified(self.core_prior)  # no log of this car yet: the other car's core stands
            return
        own, prior = list(logs or []), self.core_prior
        if logs and of_another_car is not None and any(of_another_car):
            flags = list(of_another_car)
            own = [log for log, other in zip(logs, flags, strict=True) if not other]
            others = [log for log, other in zip(logs, flags, strict=True) if other]
            found = identify_on_another_car(own, others, search_from=search_from, car=self.car)
            if self.discrepancy is not None:  # the prior `own` was identified under (cached)
                prior = another_cars_prior(others, car=self.car)
        elif logs:
            found = identify_from_logs(logs, search_from=search_from, car=self.car, prior=self.core_prior)
        else:
            found = identify(np.asarray(data.x), np.asarray(data.y), self.dt, self.rate_at, self.car)
        self.set_identified(found)
        if self.discrepancy is not None and own:
            cross = self.config.discrepancy == "cross_validated"
            misfit = misfit_of_logs(own, found.values, horizon=CORRELATION_TIME, cross_validated=cross,
                                    prior=prior, car=self.car)  # fmt: skip
            self.discrepancy.copy_(torch.as_tensor(misfit, dtype=torch.float32))
            self.discrepancy_logs.fill_(float(sum(len(u) > 1 for u, _ in own)))

    @torch.no_grad()
    def set_identified(self, found: Identified) -> None:
        """The core's parameters `found` and, with `parameter_uncertainty = "by_log"`, their covariance."""
        self.theta.copy_(torch.as_tensor(found.values, dtype=torch.float32))
        self.theta_scale.zero_()
        if self.config.parameter_uncertainty == "by_log":
            self.theta_scale.copy_(torch.as_tensor(cholesky_factor(found.covariance), dtype=torch.float32))

    def start_from_another_car(self, other: Model, *, correction: bool) -> None:
        """Another car's identified core, with its covariance widened by the file's widths
        (`single_track.widened`: how far two cars of one datasheet may differ), becomes the prior this
        car's logs are identified under; with `correction`, this model starts from the other's core and
        correction weights (its scalers are refitted to this car's rows)."""
        names = getattr(other, "parameter_names", None)
        if not isinstance(other, PhysicsModel) or names != self.parameter_names:
            core = "no core" if names is None else f"a core of {', '.join(names)}"
            ours = ", ".join(self.parameter_names)
            raise InputError("design.prior.model", other.kind, f"has {core}; this model's identifies {ours}")
        if not self.core_in_scales and other.config.vehicle != self.config.vehicle:
            reason = f"is another vehicle's: its core's {', '.join(names)} are not {self.config.vehicle!r}'s"
            raise InputError("design.prior.model", other.config.vehicle, reason)
        scale = other.theta_scale.double()
        found = Identified(other.theta.double().numpy(), (scale @ scale.T).numpy())
        self.core_prior = widened(found, self.parameter_widths)
        if not correction:
            return
        try:
            self.correction.load_state_dict(other.correction.state_dict())
        except RuntimeError as exc:
            raise InputError("design.prior.model", other.config.arch,
                             f"its correction does not fit [model]'s ({exc})") from None  # fmt: skip
        with torch.no_grad():
            self.theta.copy_(other.theta)

    # ----- the correction gate (`activelearn.numerics.correction_gate`) -------------------------
    def gates_correction(self, data: TrainingData) -> bool:
        """With `[model] correction_gate`, where `data` has maneuver ids for its rows and logs."""
        has_ids = data.groups is not None and data.log_groups is not None
        return bool(self.config.correction_gate and has_ids and data.logs)

    @torch.no_grad()
    def set_correction_weight(self, weight: float) -> None:
        """Keep this share of the correction's posterior mean (each draw's deviation from it stays whole)."""
        self.correction_weight.fill_(weight)

    def round_metrics(self) -> dict[str, float]:
        """The share of its correction's mean the model keeps (`correction_weight`)."""
        return {CORRECTION_WEIGHT: float(self.correction_weight)}

    @property
    def _carries_discrepancy(self) -> bool:
        """Whether the free runs' fans carry a measured model discrepancy (`[model] discrepancy`)."""
        return self.discrepancy is not None and bool(self.discrepancy.any())

    def discrepancy_sizes(self, n_samples: int, seed: int) -> np.ndarray:
        """(S, 2) each draw's discrepancy size (v, r), drawn from the measured misfit's posterior
        (`discrepancy.discrepancy_sizes`)."""
        misfit = self.discrepancy.double().numpy()
        return discrepancy_sizes(misfit, float(self.discrepancy_logs), n_samples, seed)

    @property
    def has_parameter_spread(self) -> bool:
        """Whether the draws have parameters of their own (`parameter_uncertainty`, once identified)."""
        return bool(self.theta_scale.any())

    def identified_covariance(self) -> np.ndarray | None:
        """The identification's covariance (`parameter_uncertainty = "by_log"`: kept as its Cholesky
        factor), None where the draws have no parameter spread."""
        if not self.has_parameter_spread:
            return None
        factor = self.theta_scale.double().numpy()
        return factor @ factor.T

    def parameter_draws(self, n_samples: int, seed: int) -> Tensor:
        """(S, 7) physical parameters of S posterior draws: `theta` plus its covariance's spread (the
        same normals for one seed), inside the parameters' physical ranges; `theta` itself S times
        where the model has no parameter spread."""
        if not self.has_parameter_spread:
            return self.theta.expand(n_samples, -1)
        generator = torch.Generator().manual_seed(int(seed) ^ THETA_SEED_SALT)
        normals = torch.randn(n_samples, len(self.parameter_names), generator=generator)
        draws = self.theta + normals @ self.theta_scale.T
        low, high = (torch.as_tensor(bound, dtype=draws.dtype) for bound in self.parameter_bounds)
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
        car = self.car
        values = [self.dt, *self.theta.tolist(), car.wheelbase, THROTTLE_LIMIT]
        values += [bound * car.max_speed, bound * car.max_yaw_rate, car.yaw_cap, math.log(LAG_FACTOR)]
        values += [*self.y_std.tolist(), *self._variance_cap().tolist(), spread]
        mirror = 1.0 / car.steering_limit if self.even_features else 0.0
        values += [float(self.correction_weight), mirror, *car.speed_table]
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
        correction, spread, keys, controls = self._free_run_setup(n_samples, seed, controls, lags, backend)
        rate_lag = lags.rate_lags[0]
        n_maneuvers, n_steps, _ = controls.shape
        # The kernel reads one parameter set: draws with their own parameters step in torch.
        if correction.kernel is not None and not self.has_parameter_spread:
            # the kernel applies the gated correction and the pose (without the model discrepancy)
            # Reused memory (`buffers`): first-touch page faults of the fans cost a third of a run.
            rates = buffers.empty((n_samples, 2, n_maneuvers, n_steps))
            moments = tuple(buffers.empty((n_maneuvers, n_steps, 2)) for _ in range(3))
            paths = native_pose = None
            if pose is not None and not self._carries_discrepancy:
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
            rates, moments = torch.from_numpy(rates), tuple(torch.from_numpy(m) for m in moments)
        else:
            rates = torch.empty((n_samples, 2, n_maneuvers, n_steps))
            moments = tuple(torch.empty((n_maneuvers, n_steps, 2)) for _ in range(3))
            theta = self.parameter_draws(n_samples, seed)[:, None]  # (S, 1, 7) against (S, M)
            self._torch_free_runs(correction, controls, start, keys, rate_lag, spread, rates, moments, theta)
            paths = None
        if pose is not None and self._carries_discrepancy:
            paths = self._discrepancy_pose(rates, pose, keys, seed)
        return rates, moments, paths

    def _discrepancy_pose(
        self, rates: Tensor, pose: tuple[float, np.ndarray, float], keys: list[int], seed: int
    ) -> tuple[np.ndarray, ...]:
        """Each draw's pose (x, y, ψ) from its sampled rates (S, 2, M, T), the fan widened by the model
        discrepancy about their mean path (`discrepancy.widened_pose`)."""
        dt, yaw0, arm = pose
        v, w = rates[:, 0], rates[:, 1]
        yaw0 = torch.as_tensor(np.asarray(yaw0, np.float32))[:, None]
        plain = integrate_pose(v, w, dt, yaw0, lever_arm=arm)
        sizes = self.discrepancy_sizes(len(keys), seed)
        return tuple(part.numpy() for part in widened_pose(plain, (v, w), (dt, yaw0, arm, None), sizes, keys))

    def _free_run_setup(self, n_samples: int, seed: int, controls: np.ndarray, lags: Lags, backend: str):
        """What every free run of a control-only correction starts from: its S draws of `seed`, their
        spread, each draw's noise key, and the control each step reads (M, T, 2, float32)."""
        correction = self.correction.draw(n_samples, seed=seed, backend=backend)
        spread = draw_spread(self.epistemic_scale, n_samples)
        keys = torch.randint(2**62, (n_samples,), generator=torch.Generator().manual_seed(seed)).tolist()
        newest = np.maximum(np.arange(controls.shape[1]) - lags.control_lags[0], 0)  # each step's control
        return correction, spread, keys, np.ascontiguousarray(controls[:, newest], dtype=np.float32)

    def _torch_free_runs(
        self, correction, controls, start, keys, rate_lag, spread, rates, moments, theta: Tensor
    ) -> None:
        """`open_loop_free_runs` in torch: the reference physics_rollout.c is tested against."""
        n_steps = rates.shape[-1]
        z, noise_std, index, noise = self._free_run_draws(correction, controls, keys)
        u = torch.as_tensor(controls)
        for k in range(n_steps):
            rows = index[:, k]
            past = rates[..., k - rate_lag] if k >= rate_lag else start
            zs = z[..., rows].unbind(1)
            tau, delta, bound = u[:, k, 0], u[:, k, 1], self.config.residual_bound
            v1, w1 = single_track_step(
                tau, delta, past[:, 0], past[:, 1], theta, self.dt, zs, bound, car=self.car
            )
            means = torch.stack([v1, w1], dim=1)  # (S, 2, M)
            if spread != 1.0:  # widen each draw's correction, not its past (surrogate.widened_step)
                common = past.mean(dim=0)
                vc, wc = single_track_step(
                    tau, delta, common[0], common[1], theta, self.dt, zs, bound, car=self.car
                )
                at_common = torch.stack([vc, wc], dim=1)
                means = means + (spread - 1.0) * (at_common - at_common.mean(dim=0))
            centre = means.mean(dim=0)
            deviation = means - centre
            std = noise_std[..., rows]
            rates[..., k] = centre + deviation + std * noise[..., k]
            moments[0][:, k] = centre.t()
            moments[1][:, k] = std.square().mean(dim=0).t()
            moments[2][:, k] = deviation.square().mean(dim=0).t()

    def _free_run_draws(self, correction, controls: np.ndarray, keys: list[int], noise: bool = True):
        """A control-only correction's draws for free runs of `controls` (M, T, 2): its raw outputs (S, 4,
        U) at the U distinct control rows, each draw's aleatoric std (S, 2, U), each step's row (M, T),
        and the counter-based noise (S, 2, M, T) of each draw's key (None without `noise`: a kernel that
        draws it itself)."""
        n_maneuvers, n_steps, _ = controls.shape
        unique, index = distinct_rows(controls.reshape(-1, N_CONTROLS))
        rows = torch.as_tensor(unique.T.copy())  # (2, U)
        if self.even_features:
            z, z_var = correction.columns(torch.stack([rows[0], rows[1].square()]))
            z = _odd_yaw(z, rows[1], -2, self.car.steering_limit)
        else:
            z, z_var = correction.columns(rows)  # (S, 4, U)
        z = self._gate(z)
        cap = self._variance_cap()[None, :, None]
        noise_std = torch.minimum(z_var[:, :N_RATES], cap).sqrt_() * self.y_std[None, :, None]
        index = torch.as_tensor(index.reshape(n_maneuvers, n_steps))
        if not noise:
            return z, noise_std, index, None
        normals = [counter_noise.step_noise(key, n_maneuvers, n_steps) for key in keys]
        return z, noise_std, index, torch.as_tensor(np.stack([np.stack(pair) for pair in normals]))

    # ----- the step ---------------------------------------------------------------------------
    def _physical_step(
        self, x: Tensor, dim: int, z_mean: Tensor, z_var: Tensor, theta: Tensor
    ) -> tuple[Tensor, Tensor]:
        """Standardised (mean, variance) of the next rates, stacked along `dim`, from standardised x, with
        physical parameters `theta` (7,) or one set per draw (S, 1, 7) against columns (S, d, N)."""
        shape = [1] * x.dim()
        shape[dim] = -1
        phys = x * self.x_std.view(shape) + self.x_mean.view(shape)
        zs = z_mean.unbind(dim) if self.corrected else torch.zeros_like(z_mean).unbind(dim)
        mean = torch.stack(self._core_step(phys, dim, zs, theta), dim=dim)
        y_shape = [1] * mean.dim()
        y_shape[dim] = -1
        mean = (mean - self.y_mean.view(y_shape)) / self.y_std.view(y_shape)
        var = torch.minimum(z_var.narrow(dim, 0, N_RATES), self._variance_cap().view(y_shape))
        return mean, var

    def _core_step(
        self, phys: Tensor, dim: int, zs: tuple[Tensor, ...], theta: Tensor
    ) -> tuple[Tensor, Tensor]:
        """The next (v, ω) of physical inputs (along `dim`) under the correction's raw outputs `zs`."""
        tau, delta, v, w = split_inputs(phys, dim, self.rate_at)
        bound = self.config.residual_bound
        return single_track_step(tau, delta, v, w, theta, self.dt, zs, bound, car=self.car)

    def _variance_cap(self) -> Tensor:
        """The largest standardised aleatoric variance of (v, ω): one training std, and at most
        `NOISE_CAP` of the rate's limit."""
        return (NOISE_CAP * self.rate_limits / self.y_std).square().clamp(max=1.0)

    def train_forward(self, x: Tensor) -> tuple[Tensor, Tensor | None]:
        """Stochastic pass on standardised x (N, d) or (K, N, d): the correction, then the physics."""
        inputs = x.narrow(-1, 0, self.n_correction_inputs)
        if self.even_features:
            features, delta = self._even_features(inputs, -1)
            z_mean, z_var = self.correction.train_forward(features)
            z_mean = _odd_yaw(z_mean, delta, -1, self.car.steering_limit)
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
            z_mean = _odd_yaw(z_mean, delta, -2, self.car.steering_limit)
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


def _odd_yaw(z: Tensor, delta: Tensor, dim: int, lock: float) -> Tensor:
    """Raw outputs (along `dim`) with the yaw residual's times δ / δ_max (the car's `lock`): odd in δ."""
    yaw = z.select(dim, 1) * (delta / lock)
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


def _unknown_discrepancy_logs(module, state_dict, prefix, *args) -> None:
    """Load hook: a state dict saved before `discrepancy_logs` existed takes its misfit as known (0)."""
    if module.discrepancy_logs is not None:
        state_dict.setdefault(prefix + "discrepancy_logs", torch.zeros(()))


def _default_correction_weight(module, state_dict, prefix, *args) -> None:
    """Load hook: a state dict saved before `correction_weight` (`theta_scale`) existed keeps the whole
    correction (no parameter spread)."""
    state_dict.setdefault(prefix + "correction_weight", torch.ones(()))
    state_dict.setdefault(prefix + "theta_scale", torch.zeros(len(PARAMETERS), len(PARAMETERS)))


def distinct_rows(pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`np.unique(pairs, axis=0, return_inverse=True)` of float32 (n, 2) rows, the same rows in the same
    (lexicographic) order, through one sort of 64-bit keys: each float's bits mapped to an unsigned
    integer in its order, the two joined (a 90-s maneuver set's 0.04 s became a few ms). -0.0 is 0.0."""
    values = np.ascontiguousarray(pairs, dtype=np.float32) + np.float32(0.0)  # -0.0 + 0.0 is 0.0
    bits = values.view(np.uint32).astype(np.uint64)
    ordered = np.where(bits >= 0x80000000, 0xFFFFFFFF - bits, bits + 0x80000000)  # negatives reversed
    _, first, index = np.unique((ordered[:, 0] << 32) | ordered[:, 1], return_index=True, return_inverse=True)
    return values[first], index.reshape(-1)


def control_box_sweep(
    duration: float = 60.0, rate_hz: float | None = None, car: CarPrior = NIGEL
) -> list[np.ndarray]:
    """Control sequences (T, 2) over a car's whole control box: constants at its corners, edges and
    centre (throttle 0, the brake, included) and steps across it halfway through."""
    n = round(duration * (car.log_rate_hz if rate_hz is None else rate_hz))
    half = n // 2
    lock = car.steering_limit
    out = [np.tile([t, d], (n, 1)) for t in (-1.0, -0.5, 0.0, 0.5, 1.0) for d in (-lock, 0.0, lock)]
    for (t0, d0), (t1, d1) in (
        ((1.0, lock), (-1.0, -lock)),
        ((-1.0, lock), (0.0, 0.0)),
        ((0.0, -lock), (1.0, lock)),
        ((0.3, 0.0), (-1.0, lock)),
    ):
        out.append(np.vstack([np.tile([t0, d0], (half, 1)), np.tile([t1, d1], (n - half, 1))]))
    return out


def runs_out_of_bounds(v: np.ndarray, w: np.ndarray, factor: float = 1.5, car: CarPrior = NIGEL) -> int:
    """How many sampled free runs (rates (S, M, T)) are not finite or leave `factor` x the car's speed or
    yaw-rate limit at some step."""
    bad = ~(np.isfinite(v) & np.isfinite(w))
    bad |= np.abs(np.nan_to_num(v)) > factor * car.max_speed
    bad |= np.abs(np.nan_to_num(w)) > factor * car.max_yaw_rate
    return int(bad.any(axis=-1).sum())
