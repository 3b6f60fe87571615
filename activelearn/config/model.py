"""The [model] and [training] sections: what a surrogate is and how `numerics.training.fit` trains it."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from activelearn.config.base import POSE_LEVER_ARM, _Section
from activelearn.numerics.arch import ACTIVATIONS, parse_arch

ModelKind = Literal["hybrid", "pbnn", "pnn", "bnn", "dnn", "ensemble", "recurrent", "physics"]
Activation = Literal[ACTIVATIONS]  # type: ignore[valid-type]


class ModelConfig(_Section):
    """Which network to build and how its Bayesian layers are parameterised."""

    kind: ModelKind = Field(
        "hybrid",
        description="Model kind: `hybrid` (layers as `arch` says), `pbnn`/`bnn` (all variational), "
        "`pnn`/`dnn` (all dense), `ensemble` (of pnns), `recurrent` (GRU trunk), `physics` (single track "
        "plus a correction)",
    )
    # Baselines reuse the widths: pbnn/bnn turn every layer variational, pnn/dnn/ensemble every layer dense.
    arch: str = Field(
        "default",
        description="Layer spec, e.g. `V8-D32-D32-D8-V` (V variational, D dense, width, optional "
        "`:activation`; the last token is the head), or a preset name (`default`, `reference`)",
    )
    activation: Activation = Field("relu", description="Activation of the `arch` tokens that name none")
    posterior: Literal["mean_field", "full_cov"] = Field(
        "mean_field",
        description="Gaussian posterior of each variational layer: independent weights (`mean_field`) "
        "or a full covariance over the layer's weights (`full_cov`, cost O(p²) in its parameter count)",
    )
    kl: Literal["exact", "mc"] = Field(
        "exact", description="KL term of the ELBO: closed form (`exact`) or Monte Carlo (`mc`)"
    )
    kl_samples: int = Field(1, description="weight draws per step for the Monte Carlo KL")
    prior_scale: float = Field(
        1.0, description="Std s of the N(0, s²) prior of every variational weight (standardised units)"
    )
    prior_trainable: bool = Field(
        False, description="Learn the prior's std s along with the weights; false keeps `prior_scale`"
    )
    posterior_init_std: float = Field(
        0.01,
        description="Initial posterior std of every variational weight (weight units; inputs are "
        "standardised)",
    )
    ensemble_size: int = Field(
        5, description="Members of kind = 'ensemble' (and of the physics kind's ensemble correction)"
    )
    min_std: float = Field(1e-3, description="Floor of the Gaussian head's std, in standardised output units")
    n_inputs: int = Field(
        2,
        description="Inputs the model reads: 2 for [data] inputs = 'controls', 4 for 'controls+rates'; "
        "a campaign sets it to 4 × history for 'history'",
    )
    n_outputs: int = Field(
        2, description="Outputs the model predicts: forward speed v (m/s) and yaw rate ω (rad/s)"
    )
    history_step: int = Field(
        1,
        description="Log steps between the lagged inputs of a dynamic model (`activelearn.numerics.lags`); "
        "a campaign sets it from [data] history_step and the saved model carries it to free runs",
    )
    # A kinematic car's rear axle does not slip sideways, so a point `a` ahead of it moves sideways at a·ω
    # in a turn; free runs integrate v along the heading at the axle and place the path there. It lives
    # here, not in [data], because the saved model carries it to every free run.
    vehicle: str = Field(
        "nigel",
        description="The car the model is of: [vehicle]'s name, which a campaign sets here so that the saved "
        "model carries its car (the physics kind's prior, its limits) to every free run",
    )
    pose_lever_arm: Annotated[float, Field(ge=-10.0, le=10.0)] = Field(
        POSE_LEVER_ARM,
        description="Metres the logged pose (posX, posY) lies ahead of the rear axle, where free runs place "
        "their paths (`activelearn.numerics.surrogate`): default the car's CG to rear axle, lr (the logs' "
        "pose is the CG's); 0 integrates v along the heading at the logged point itself",
    )
    hidden_size: int = Field(
        32,
        description="kind = 'recurrent': width of the GRU trunk that reads the history window as "
        "(controls, rates) tokens, oldest first; the layers of `arch` form its head",
    )
    # A steady turn's ω is about v·tan(δ)/L: with the product as an input the net need not build it
    # from few operating points (measured: half the static map's free-run error on eights, see the
    # docs/results/models.md). Derived inside the model, so data, rollouts and kernels are unchanged.
    kinematic_feature: bool = Field(
        False,
        description="Also feed the network the kinematic yaw-rate proxy: throttle × tan(steering) for a "
        "static map, newest past speed × tan(current steering) for a dynamic one (not recurrent, physics)",
    )
    # kind = "physics" (`activelearn.numerics.models.physics`): Nigel's single track from its datasheet,
    # its physical parameters identified from the training logs, plus a Bayesian correction of this kind
    # (same arch, activation and ensemble_size) that learns only what the physics misses.
    # The correction's defaults (hybrid, bound 0.05) beat the ensemble with bound 0.2 and the bare identified
    # single track on 4 of 4 fresh seeds after 4 cold-start signals (experiments/results/physics.txt).
    correction: Literal["ensemble", "hybrid"] = Field(
        "hybrid",
        description="kind = 'physics': the kind of the Bayesian correction that learns what the single "
        "track misses (with this section's `arch`, `activation` and `ensemble_size`)",
    )
    # The kinematic core is nearly exact where a car stays below ~0.3 g (Nigel's whole range); the dynamic
    # one (tyre slip, saturating tyres, load transfer) holds where a car is driven to its limit.
    core: Literal["kinematic", "dynamic"] = Field(
        "kinematic",
        description="kind = 'physics': the physics under the correction: 'kinematic' (the single track's "
        "steady states and lags) or 'dynamic' (the single track with tyre slip, saturating tyres and load "
        "transfer, blended into the kinematic one at low speed; needs correction_inputs = 'control')",
    )
    identify: bool = Field(
        True, description="kind = 'physics': fit the physical parameters to the training logs before training"
    )
    # The fans carried the correction's posterior but not the identified core's: where the single track
    # misses the car and the data hold no example (full lock past the prior's 0.31 rad, a steering step
    # at speed), they were ~1 % wide and 1-11 % off (experiments/results/bench_safety.txt, session 20).
    parameter_uncertainty: Literal["none", "by_log"] = Field(
        "none",
        description="kind = 'physics': 'by_log' gives each posterior draw its own physical parameters, "
        "drawn from the identification's cluster-robust covariance (each training log a cluster), so the "
        "fans carry the identified core's uncertainty as well as the correction's",
    )
    # The identified scales' covariance is small once a few logs excite them, while the core still misses
    # what it cannot express (a spin, the truth's four tyres): after a cold start's first 4 signals the
    # 1:10 car's fans held a quarter of the true positions. The discrepancy is that misfit, carried.
    discrepancy: Literal["none", "identification", "cross_validated"] = Field(
        "none",
        description="kind = 'physics' (either core): 'identification' widens the free-run fans by the "
        "core's model discrepancy: each draw's speed and yaw rate take a random error (an "
        "Ornstein-Uhlenbeck process from zero, its size the identified core's rms misfit of its own "
        "logs, each draw's size drawn from that estimate's uncertainty over the n logs it was measured "
        "on (√(n / χ²(n)) times it: Student-t fans), its correlation time the misfit's restart horizon, "
        "3 s) that moves the pose fan about the core's mean path, not the path; 'cross_validated' takes "
        "the misfit out of sample (4 folds of the logs, each at the parameters identified without it)",
    )
    # A live stop brakes at the grip limit with the steering held: the truth keeps no lateral grip, a core
    # without combined slip all of it (experiments/results/bench_safety.txt, session 34).
    combined_slip: bool = Field(
        False,
        description="core = 'dynamic': each axle's lateral force within what its share of the longitudinal "
        "force leaves of its friction circle (the drive's shares under throttle, the brake's by load at "
        "throttle 0); false: the rear axle's drive share alone",
    )
    # The truth's tyres are four wheels, each in its own friction circle, on a chassis whose loads shift
    # left and right: at the limit it spins where an axle's circle holds (docs/results/vehicles.md,
    # session 35).
    wheel_forces: bool = Field(
        False,
        description="core = 'dynamic': the forces of four wheels on the single track's states: each "
        "wheel's load with the longitudinal and the lateral transfer (a rigid chassis on four equal "
        "contacts), its own friction circle (Kamm's: where the drive or brake and the lateral force "
        "exceed μ F_z both are scaled back, their direction kept), the yaw moment of unequal wheel "
        "forces, and the kinematic blend weighed by the speed over ground; false: an axle's circle "
        "(`combined_slip`)",
    )
    # At the 0.1-s step's 25-ms substeps the linear damping holds a saturated tyre back: the full-size
    # twin's core at its own figures ends 30 m off above 0.6 μg, 4.5 m with the tangent
    # (experiments/investigations/limit_core_numerics.py).
    tyre_damping: Literal["linear", "tangent"] = Field(
        "linear",
        description="core = 'dynamic': the implicit step's exponential damping of the lateral speed and "
        "yaw rate at the tyres' linear cornering stiffness ('linear'), or at each axle's local slope "
        "∂F_y/∂α at its slip angle, 0 past the peak ('tangent': a saturated tyre damps nothing)",
    )
    # A spin at the 0.1-s step's 25-ms substeps: the wheels' loads converge in 5 passes (3 start from the
    # demand and v_x r, far from a spin's), and a car spinning down through 2.5 m/s (full size) was pulled
    # onto its wheels' heading at the blend of ½ √(g L); with the tangent damping the full-size core at its
    # own figures ends a held-out test set 3.5 m off after 30 s, not 14.5 (docs/results/vehicles.md).
    wheel_passes: Literal[3, 5] = Field(
        3,
        description="wheel_forces: the fixed-point passes of the wheels' loads on the accelerations their "
        "forces give in each substep (3 or 5: each a compiled variant of the kernel)",
    )
    blend_share: float = Field(
        0.5,
        gt=0.0,
        le=2.0,
        description="core = 'dynamic': the speed below which the state is blended into the kinematic one, "
        "as a share of √(g L) (L the wheelbase): 0.5 puts Nigel's whole range in the blend, the 1:10 car's "
        "at 0.90 m/s, the full-size car's at 2.5 m/s",
    )
    # Nigel's whole range sits below the blend speed, where the plain blend's turn is L / tan δ with no
    # scrub: its identified core ended the test set 0.32 m off at 30 s, the kinematic core 0.031; with the
    # kinematic core's understeer (forward, reverse), scrub and yaw lag 0.019 (cores alone, 10 seeds;
    # experiments/investigations/nigel_blend.py). In dynamics.toml's campaigns 0.0178 m against the kinematic
    # core's 0.0299 after 16 signals (seeds 0-9; fresh 10-19: 0.0175), with
    # experiments/params/nigel_dynamic_core.toml.
    kinematic_blend: Literal["plain", "core"] = Field(
        "plain",
        description="core = 'dynamic': below the blend speed the kinematic turn r = v_x tan δ / L ('plain'), "
        "or the kinematic core's ('core'): its understeer (its own in reverse) and yaw lag, the scrub's drag "
        "on v_x, and v_x's tyre terms weighed by the blend; four more scales identified (not with "
        "wheel_forces)",
    )
    # A spinning car's logs hold rows that no scale fits to the second (a spin a little early or late):
    # by squares they pulled the full-size car's scales to their bounds (docs/results/vehicles.md).
    identification_loss: Literal["squares", "cauchy"] = Field(
        "squares",
        description="core = 'dynamic': the identification's loss: 'squares' (Gaussian errors), or "
        "'cauchy', each error weighing 1 / (1 + (e / (0.3 × the rate's rms error))²), so that the few "
        "rows no parameter set fits (a spin a little off the truth's) do not pull the rest",
    )
    # Warm training searches from the last round's scales; on 2 of 30 designs of the full-size twin that
    # search stayed where earlier logs had put it (yaw inertia 2.7-3.0) while the prior's centre led to a
    # lower objective and a third of the 30-s error. Not shipped: on 40 fresh designs it changed nothing
    # (docs/results/vehicles.md, session 46).
    identification_starts: Literal["last", "last_and_prior"] = Field(
        "last",
        description="core = 'dynamic' with warm training ([training] reinit = false): where the "
        "identification searches: from the last round's scales ('last'), or from them and from the prior's "
        "centre, keeping the lower MAP objective ('last_and_prior': the search takes 1.5-2.4 times as long)",
    )
    residual_bound: Annotated[float, Field(ge=0.0, le=0.5)] = Field(
        0.05,
        description="kind = 'physics': largest learnt change of a steady rate, as a share of its limit "
        "(Nigel's top speed, its largest yaw rate)",
    )
    correction_inputs: Literal["control", "history"] = Field(
        "history",
        description="kind = 'physics': what the correction reads: the newest control (the operating "
        "point; free runs then evaluate it once per distinct control) or the whole input window",
    )
    # Nigel is mirror-symmetric: steering the other way (δ, ω → −δ, −ω) mirrors the yaw rate and leaves
    # the speed. The identified core is; a free correction is not, and with 40 maneuvers its yaw residual
    # at δ = 0 bent the straights (30-s error 0.013 m → 0.056 with it, experiments/results/physics.txt).
    correction_symmetry: Literal["none", "mirror"] = Field(
        "none",
        description="kind = 'physics': 'mirror' makes the correction mirror-symmetric, as the car is: its "
        "yaw-rate residual odd and every other output even under steering the other way (a control-only "
        "correction reads (throttle, steering²) and its yaw residual is multiplied by the steering; a "
        "window correction is averaged with its output at the mirrored window)",
    )
    # Where the logs allow, a probe trained without a quarter of the training maneuvers decides how
    # much of the correction's mean to keep (0, 1/2 or all) by free runs of the held-out ones; its
    # posterior spread (the epistemic band) is kept whatever the choice. The correction fits one-step
    # targets and, with little data, drags free runs away from the identified core
    # (experiments/results/physics.txt).
    correction_gate: bool = Field(
        False,
        description="kind = 'physics': keep the correction's mean only as far as it beats the identified "
        "core on held-out maneuvers (a probe fit without a quarter of them)",
    )
    # One held-out maneuver is a noisy judge: in the cold start's first round (4 maneuvers, 1 held out)
    # the probe kept a correction that dragged the free runs to 0.05-0.07 m where the core alone ended
    # at 0.04 (experiments/results/physics.txt, session 13).
    correction_gate_min_held_out: int = Field(
        1,
        ge=1,
        le=100,
        description="kind = 'physics' with correction_gate: the fewest held-out maneuvers the gate judges "
        "on; with fewer (a quarter of the training maneuvers, rounded) the correction's mean is left out "
        "and only its epistemic band kept",
    )

    @model_validator(mode="after")
    def _check_kinematic_feature(self) -> ModelConfig:
        if self.kinematic_feature and self.kind in ("recurrent", "physics"):
            why = "its trunk reads tokens" if self.kind == "recurrent" else "its physics knows the kinematics"
            raise ValueError(f"kinematic_feature: not for kind = {self.kind!r} ({why})")
        return self

    @model_validator(mode="after")
    def _check_core(self) -> ModelConfig:
        if self.core == "dynamic" and self.kind != "physics":
            raise ValueError(f"core: 'dynamic' is the physics kind's core, not kind = {self.kind!r}'s")
        if self.core == "dynamic" and self.correction_inputs != "control":
            raise ValueError(
                "core: 'dynamic' needs correction_inputs = 'control' (its free runs carry the lateral speed "
                "an input window does not hold)"
            )
        dynamic_only = {"combined_slip": self.combined_slip, "wheel_forces": self.wheel_forces,
                        "identification_loss": self.identification_loss != "squares",
                        "identification_starts": self.identification_starts != "last",
                        "tyre_damping": self.tyre_damping != "linear",
                        "blend_share": self.blend_share != 0.5,
                        "kinematic_blend": self.kinematic_blend != "plain"}  # fmt: skip
        for name, set_here in dynamic_only.items():
            if set_here and self.core != "dynamic":
                raise ValueError(f"{name}: the dynamic core's (core = 'dynamic'), not core {self.core!r}")
        if self.wheel_passes != 3 and not self.wheel_forces:
            raise ValueError("wheel_passes: the passes of the wheels' loads; wheel_forces is off")
        if self.combined_slip and self.wheel_forces:
            raise ValueError("wheel_forces: each wheel's own circle replaces combined_slip's axles; set one")
        if self.kinematic_blend == "core" and self.wheel_forces:
            raise ValueError("kinematic_blend: 'core' is the axles' step's, not wheel_forces'")
        if self.discrepancy != "none" and self.kind != "physics":
            raise ValueError(f"discrepancy: {self.discrepancy!r} is the physics kind's, not {self.kind!r}'s")
        if self.discrepancy != "none" and self.correction_inputs != "control":
            raise ValueError("discrepancy: its fans are free runs computed whole, which needs "
                             f"correction_inputs = 'control', not {self.correction_inputs!r}")  # fmt: skip
        return self

    @field_validator("arch")
    @classmethod
    def _check_arch(cls, value: str) -> str:
        try:
            parse_arch(value)
        except ValueError as exc:
            raise ValueError(f"arch: {exc}") from None
        return value

    @field_validator("prior_scale", "posterior_init_std", "min_std")
    @classmethod
    def _check_positive(cls, value: float) -> float:
        if not value > 0:
            raise ValueError("must be > 0")
        return value

    @field_validator("kl_samples", "n_inputs", "n_outputs", "history_step", "hidden_size")
    @classmethod
    def _check_count(cls, value: int) -> int:
        if value < 1:
            raise ValueError("must be >= 1")
        return value

    @field_validator("ensemble_size")
    @classmethod
    def _check_ensemble(cls, value: int) -> int:
        if value < 2:
            raise ValueError(f"ensemble_size must be >= 2, got {value!r}")
        return value


KLCount = Literal["rows", "maneuvers", "sqrt"]


class TrainingConfig(_Section):
    """How `activelearn.numerics.training.fit` trains a model."""

    loss: Literal["nll", "mse", "mae"] = Field(
        "nll",
        description="Data term of the ELBO: `nll`, Gaussian NLL (the head's variance is learnt); `mse`/`mae` "
        "fit the mean only, as the reference study did (the head's scale then gets no gradient)",
    )
    optimizer: Literal["adam", "rmsprop", "sgd"] = Field(
        "adam", description="Optimiser: Adam, RMSprop or SGD (with `momentum`), each with L2 `weight_decay`"
    )
    lr: float = Field(1e-3, description="Learning rate (the starting one under `lr_schedule = 'cosine'`)")
    # Cosine: the final weights then stop wandering with the minibatch noise, which makes fits on a fixed
    # budget far less seed-dependent.
    lr_schedule: Literal["constant", "cosine"] = Field(
        "constant",
        description="`cosine` anneals the learning rate to 1 % of `lr` over `epochs`; `constant` keeps `lr`",
    )
    momentum: float = Field(0.9, description="Momentum of SGD (optimizer = 'sgd' only)")
    weight_decay: float = Field(0.0, description="L2 weight decay of the optimiser; 0: none")
    epochs: int = Field(400, description="Training epochs (passes over the rows) of a fresh fit")
    batch_size: int = Field(64, description="Rows per minibatch (at most the number of training rows)")
    patience: int | None = Field(
        60,
        description="Epochs without a better validation NLL before training stops and the best epoch's "
        "weights return (fits given validation data, e.g. `activelearn tune`); none trains all epochs",
    )
    # Default "sqrt", measured (experiments/investigations/model_selection.py klsize): held-out z spread
    # before recalibration stays in 0.8-1.6 from 8 to 40 operating points and 60 to 600 rows per point,
    # where "rows" drifts from 1.4 to 5.1 (overconfident as rows per maneuver grow) and "maneuvers" to 0.7
    # (underconfident).
    kl_count: KLCount | float = Field(
        "sqrt",
        description="N in KL/N: `rows` (training rows), `maneuvers` (distinct maneuvers), `sqrt` "
        "(√(rows × maneuvers)) or a positive number used as is (without groups each row is a maneuver)",
    )
    kl_weight: float = Field(
        1.0, description="Extra multiplier on KL/N (cold or warm posterior tempering); 1 is the plain ELBO"
    )
    n_eval_samples: int = Field(16, description="Posterior draws for the per-epoch validation metrics")
    recalibrate: Literal["none", "validation"] = Field(
        "none",
        description="`validation`: after training, fit the scale of the epistemic variance on the "
        "validation data (fits given validation data only); `none` leaves the scale at 1",
    )
    reinit: bool = Field(
        True,
        description="Re-initialise the weights from the fit's seed before training (reproducible); "
        "false continues from the current weights",
    )
    compile: bool | Literal["auto"] = Field(
        "auto",
        description="Compile the whole training step with torch.compile: ~5x faster per step after a "
        "one-off compile of ~5-20 s; `auto` compiles fits of 40,000 steps or more. The dynamic core's "
        "step (windows and free runs) compiles with `true`, and with `auto` where windows train",
    )
    # These layers are too small to gain from more threads, and one thread avoids contention.
    num_threads: int | None = Field(
        1, description="torch intra-op threads during a fit (restored afterwards); none: torch's own setting"
    )
    warm_start: bool = Field(
        False,
        description="Campaigns: start each round from the previous round's weights (and scalers) and train "
        "`warm_epochs` epochs, instead of a fresh model for `epochs`; a kind that identifies physical "
        "parameters searches from the previous round's (same prior, same objective)",
    )
    warm_epochs: int | None = Field(
        None, description="Epochs of a warm-started round (`warm_start`); none: a quarter of `epochs`"
    )
    rollout_horizon: Annotated[int, Field(ge=0, le=900)] = Field(
        0,
        description="Dynamic models: log steps of the free-run windows whose Gaussian NLL joins the one-step "
        "loss (the model fed its own mean predictions, back-propagated through the window); 0: off",
    )
    rollout_weight: Annotated[float, Field(gt=0)] = Field(
        1.0,
        description="Weight of the window loss, times `rollout_every` (so the weight per epoch does not "
        "depend on it)",
    )
    rollout_batch: Annotated[int, Field(ge=1)] = Field(
        32, description="Free-run windows in each step that trains them (`rollout_horizon` > 0)"
    )
    # A window of H steps costs H small forward and backward passes (measured ~0.2 s per step on a busy
    # 2-core machine at H = 30, batch 32).
    rollout_every: Annotated[int, Field(ge=1)] = Field(
        8, description="The window loss joins every n-th optimiser step (`rollout_horizon` > 0)"
    )
    # Back-propagation through a free run can explode: unclipped, the Markov model trained on 30-step
    # windows ran free to infinity on every kind; clipped at 1 its free runs stayed within 0.12-0.16 m
    # at 30 s.
    rollout_clip: Annotated[float, Field(ge=0)] = Field(
        1.0, description="Largest global gradient norm of a step while windows train; 0: no clipping"
    )

    @field_validator("lr")
    @classmethod
    def _check_lr(cls, value: float) -> float:
        if not value > 0:
            raise ValueError(f"lr must be > 0, got {value!r}")
        return value

    @field_validator("momentum", "weight_decay", "kl_weight")
    @classmethod
    def _check_non_negative(cls, value: float) -> float:
        if not value >= 0:
            raise ValueError("must be >= 0")
        return value

    @field_validator("epochs", "batch_size", "n_eval_samples")
    @classmethod
    def _check_count(cls, value: int) -> int:
        if value < 1:
            raise ValueError("must be >= 1")
        return value

    @field_validator("warm_epochs")
    @classmethod
    def _check_warm_epochs(cls, value: int | None) -> int | None:
        if value is not None and value < 1:
            raise ValueError(f"warm_epochs must be >= 1 or None, got {value!r}")
        return value

    @field_validator("num_threads")
    @classmethod
    def _check_threads(cls, value: int | None) -> int | None:
        if value is not None and value < 1:
            raise ValueError(f"num_threads must be >= 1 or None, got {value!r}")
        return value

    @field_validator("patience")
    @classmethod
    def _check_patience(cls, value: int | None) -> int | None:
        if value is not None and value < 1:
            raise ValueError(f"patience must be >= 1 or None, got {value!r}")
        return value

    @field_validator("kl_count")
    @classmethod
    def _check_kl_count(cls, value: str | float) -> str | float:
        if isinstance(value, str):
            return value
        if not value > 0:
            raise ValueError(f"kl_count must be 'rows', 'maneuvers', 'sqrt' or a number > 0, got {value!r}")
        return float(value)

