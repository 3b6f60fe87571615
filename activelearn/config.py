"""Configuration models: one place for every default.

Each section is a pydantic v2 model that rejects unknown keys (`extra="forbid"`) and validates its
values with messages that name the offending field. This module holds the model and training
sections; campaign sections are added beside them.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from activelearn.errors import ConfigError
from activelearn.numerics.arch import ACTIVATIONS, parse_arch

ModelKind = Literal["hybrid", "pbnn", "pnn", "bnn", "dnn", "ensemble", "recurrent", "physics"]
Activation = Literal[ACTIVATIONS]  # type: ignore[valid-type]
MAX_STEERING = 0.5236  # rad, Nigel's steering limit
POSE_LEVER_ARM = 0.07929  # m, Nigel's CG (where its pose is logged) ahead of the rear axle


class _Section(BaseModel):
    """Base of every config section: unknown keys are errors, values are re-validated on assignment."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class ModelConfig(_Section):
    """Which network to build and how its Bayesian layers are parameterised."""

    kind: ModelKind = "hybrid"
    # Spec string (e.g. "V8-D32-D32-D8-V") or a preset name from ARCH_PRESETS. Baselines reuse the
    # widths: pbnn/bnn turn every layer variational, pnn/dnn/ensemble turn every layer dense.
    arch: str = "default"
    # Activation of tokens that do not name their own.
    activation: Activation = "relu"
    posterior: Literal["mean_field", "full_cov"] = "mean_field"
    kl: Literal["exact", "mc"] = "exact"
    kl_samples: int = Field(1, description="weight draws per step for the Monte Carlo KL")
    prior_scale: float = 1.0
    prior_trainable: bool = False
    # Initial posterior std of every variational weight (weight units, inputs are standardised).
    posterior_init_std: float = 0.01
    ensemble_size: int = 5
    # Floor of the Gaussian head's std, in standardised output units.
    min_std: float = 1e-3
    n_inputs: int = 2
    n_outputs: int = 2
    # Log steps between the lagged inputs of a dynamic model (`activelearn.numerics.lags`); a campaign
    # sets it from [data] history_step. The forward simulation reads it from the saved model.
    history_step: int = 1
    # Metres the logged position lies ahead of the rear axle; free runs place their paths there
    # (`activelearn.numerics.surrogate`). A campaign sets it from [data] pose_lever_arm.
    pose_lever_arm: Annotated[float, Field(ge=-1.0, le=1.0)] = POSE_LEVER_ARM
    # Width of the recurrent model's GRU trunk (kind = "recurrent"): it reads the history window as a
    # sequence of (controls, rates) tokens, oldest first; the layers of `arch` form its head.
    hidden_size: int = 32
    # Also feed the network the kinematic yaw-rate proxy, a speed times tan(steering): throttle ×
    # tan(steering) for a static map, the newest past speed × tan(current steering) for a dynamic one.
    # A steady turn's ω is about v·tan(δ)/L: with the product as an input the net need not build it
    # from few operating points (measured: half the static map's free-run error on eights, see the
    # README's "Dynamics"). Derived inside the model, so data, rollouts and kernels are unchanged.
    kinematic_feature: bool = False
    # kind = "physics" (`activelearn.numerics.models.physics`): Nigel's single track from its datasheet,
    # its physical parameters identified from the training logs, plus a Bayesian correction of this kind
    # (same arch, activation and ensemble_size) that learns only what the physics misses.
    # The correction's defaults (hybrid, bound 0.05) beat the ensemble with bound 0.2 and the bare identified
    # single track on 4 of 4 fresh seeds after 4 cold-start signals (experiments/results/physics.txt).
    correction: Literal["ensemble", "hybrid"] = Field(
        "hybrid", description="kind = 'physics': the Bayesian correction's kind"
    )
    identify: bool = Field(
        True, description="kind = 'physics': fit the physical parameters to the training logs before training"
    )
    residual_bound: Annotated[float, Field(ge=0.0, le=0.5)] = Field(
        0.05,
        description="kind = 'physics': largest learnt change of a steady rate, times its limit",
    )
    correction_inputs: Literal["control", "history"] = Field(
        "history",
        description="kind = 'physics': what the correction reads: the newest control (the operating "
        "point; free runs then evaluate it once per distinct control) or the whole input window",
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

    @model_validator(mode="after")
    def _check_kinematic_feature(self) -> ModelConfig:
        if self.kinematic_feature and self.kind in ("recurrent", "physics"):
            why = "its trunk reads tokens" if self.kind == "recurrent" else "its physics knows the kinematics"
            raise ValueError(f"kinematic_feature: not for kind = {self.kind!r} ({why})")
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
    def _check_positive(cls, value: float, info) -> float:
        if not value > 0:
            raise ValueError(f"{info.field_name} must be > 0, got {value!r}")
        return value

    @field_validator("kl_samples", "n_inputs", "n_outputs", "history_step", "hidden_size")
    @classmethod
    def _check_count(cls, value: int, info) -> int:
        if value < 1:
            raise ValueError(f"{info.field_name} must be >= 1, got {value!r}")
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

    # Data term of the ELBO. "nll" = Gaussian NLL (the head's variance is learnt); "mse"/"mae" fit the
    # mean only, as the reference study did (the head's scale then receives no gradient).
    loss: Literal["nll", "mse", "mae"] = "nll"
    optimizer: Literal["adam", "rmsprop", "sgd"] = "adam"
    lr: float = 1e-3
    # "cosine" anneals the learning rate to 1% of `lr` over `epochs`: the final weights then stop
    # wandering with the minibatch noise, which makes fits on a fixed budget far less seed-dependent.
    lr_schedule: Literal["constant", "cosine"] = "constant"
    momentum: float = 0.9
    weight_decay: float = 0.0
    epochs: int = 400
    batch_size: int = 64
    # Epochs without a better validation NLL before stopping; None trains all epochs.
    patience: int | None = 60
    # N in KL/N: "rows" = training rows, "maneuvers" = distinct `groups`, "sqrt" = √(rows × maneuvers),
    # or a positive number used as is (without groups every row is its own maneuver). Default "sqrt",
    # measured (experiments/model_selection.py klsize): held-out z spread before recalibration stays
    # in 0.8-1.6 from 8 to 40 operating points and 60 to 600 rows per point, where "rows" drifts from
    # 1.4 to 5.1 (overconfident as rows per maneuver grow) and "maneuvers" to 0.7 (underconfident).
    kl_count: KLCount | float = "sqrt"
    # Extra multiplier on KL/N (cold/warm posterior tempering); 1 is the plain ELBO.
    kl_weight: float = 1.0
    # Posterior samples used for the per-epoch validation metrics.
    n_eval_samples: int = 16
    # Fit `epistemic_scale` on the validation set after training ("validation"), or leave it at 1.
    recalibrate: Literal["none", "validation"] = "none"
    # Re-initialise the weights from `seed` before training (reproducible); False continues training.
    reinit: bool = True
    # Compile the whole training step (forward, backward, update) with torch.compile: ~5x faster per
    # step, after a one-off compile of ~5-20 s. "auto" compiles fits of >= 40,000 steps.
    compile: bool | Literal["auto"] = "auto"
    # torch intra-op threads during fit (restored afterwards); these layers are too small to gain
    # from more threads, and one thread avoids contention. None leaves torch's setting alone.
    num_threads: int | None = 1
    # Campaigns: start each round from the previous round's weights (and scalers) and train
    # `warm_epochs` epochs (default a quarter of `epochs`) instead of a fresh model for `epochs`.
    warm_start: bool = False
    warm_epochs: int | None = None
    # Multi-step training of dynamic models: beside the one-step loss, the Gaussian NLL of free runs
    # of `rollout_horizon` log steps (the model fed its own mean predictions, back-propagated through
    # the whole window), `rollout_batch` windows on every `rollout_every`-th step, weighted by
    # `rollout_weight` (times `rollout_every`, so the weight per epoch does not depend on it). 0: off.
    rollout_horizon: Annotated[int, Field(ge=0, le=900)] = 0
    rollout_weight: Annotated[float, Field(gt=0)] = 1.0
    rollout_batch: Annotated[int, Field(ge=1)] = 32
    # The window loss joins every n-th optimiser step: a window of H steps costs H small forward and
    # backward passes (measured ~0.2 s per step on a busy 2-core machine at H = 30, batch 32).
    rollout_every: Annotated[int, Field(ge=1)] = 8
    # Largest global gradient norm of a step while windows train (0: no clipping). Back-propagation
    # through a free run can explode: unclipped, the Markov model trained on 30-step windows ran free
    # to infinity on every kind; clipped at 1 its free runs stayed within 0.12-0.16 m at 30 s.
    rollout_clip: Annotated[float, Field(ge=0)] = 1.0

    @field_validator("lr")
    @classmethod
    def _check_lr(cls, value: float) -> float:
        if not value > 0:
            raise ValueError(f"lr must be > 0, got {value!r}")
        return value

    @field_validator("momentum", "weight_decay", "kl_weight")
    @classmethod
    def _check_non_negative(cls, value: float, info) -> float:
        if not value >= 0:
            raise ValueError(f"{info.field_name} must be >= 0, got {value!r}")
        return value

    @field_validator("epochs", "batch_size", "n_eval_samples")
    @classmethod
    def _check_count(cls, value: int, info) -> int:
        if value < 1:
            raise ValueError(f"{info.field_name} must be >= 1, got {value!r}")
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


# ----------------------------------------------------------------------------------- campaign sections
# Shared constrained types: pydantic names the key and the bound in its error message.
Count = Annotated[int, Field(ge=1)]
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]
# Seeds reach numpy's SeedSequence (non-negative only) and torch's manual_seed (scaled per round by
# the campaign; below 2**64): 32 bits keep every derived seed in range.
Seed = Annotated[int, Field(ge=0, lt=2**32)]
Throttle = Annotated[float, Field(ge=-1.0, le=1.0)]
Steering = Annotated[float, Field(ge=0.0, le=MAX_STEERING)]
Kind = Literal["straight", "skidpad", "fishhook", "slalom", "eight"]
# The families of simulator.families.FAMILIES (tests/test_families.py keeps the two lists equal).
FamilyName = Literal[
    "slalom", "fishhook", "throttle_step", "chirp", "multisine", "prbs", "staircase", "figure_eight"
]
Direction = Literal["ccw", "cw"]


def _unique(values: list[Any], field: str) -> list[Any]:
    if not values:
        raise ValueError(f"{field} must not be empty")
    if len(set(values)) != len(values):
        raise ValueError(f"{field} has duplicates: {values}")
    return values


class PoolConfig(_Section):
    """Candidate maneuvers: kinds × directions × an operating-point grid or a continuous range.

    Give `throttles` and `steerings` for a grid, or `throttle_range`, `steering_range` and `size` for
    a scrambled-Sobol set of operating points (seeded by `seed`, the same for every campaign seed).
    Steering is the unsigned amplitude; `directions` carries the sign. Straight maneuvers have no
    steering; fishhooks ramp to full lock, so they vary in throttle and direction only.

    Or give `families` (simulator.families) and `size`: a scrambled-Sobol set of `size` parameter
    vectors per family over `ranges` ({family = {parameter = [low, high]}}, default each family's own
    pool range; low = high fixes a parameter), times `directions`. It replaces kinds and the grid.
    """

    kinds: list[Kind] = ["skidpad"]
    directions: list[Direction] = ["ccw", "cw"]
    throttles: list[Throttle] | None = [0.2, 0.4, 0.6, 0.8, 1.0]
    steerings: list[Steering] | None = [0.1047, 0.2094, 0.3142, 0.4189, 0.5236]
    throttle_range: tuple[Throttle, Throttle] | None = None
    steering_range: tuple[Steering, Steering] | None = None
    size: Annotated[int, Field(ge=2)] | None = None
    seed: Seed = 0
    duration: Positive = 90.0
    # Seconds per maneuver kind, overriding `duration` (e.g. {straight = 20, eight = 90}): maneuvers
    # differ in what they cost on a track, and a seconds budget (design.max_sim_seconds) counts it.
    durations: dict[Kind | FamilyName, Positive] = {}
    # Distance added between candidates of different kinds, in units of the [0, 1] operating-point cube
    # (of the normalised family-parameter cube for a family pool).
    kind_distance: NonNegative = 0.5
    families: list[FamilyName] = []
    ranges: dict[FamilyName, dict[str, tuple[float, float]]] = {}

    def duration_of(self, kind: str) -> float:
        """Seconds a maneuver of `kind` lasts in this pool."""
        return float(self.durations.get(kind, self.duration))  # type: ignore[call-overload]

    @field_validator("kinds", "directions", "throttles", "steerings")
    @classmethod
    def _non_empty_unique(cls, value: list[Any] | None, info: ValidationInfo) -> list[Any] | None:
        return value if value is None else _unique(value, info.field_name)

    @field_validator("families")
    @classmethod
    def _unique_families(cls, value: list[str]) -> list[str]:
        if len(set(value)) != len(value):
            raise ValueError(f"families has duplicates: {value}")
        return value

    def family_range(self, family: str, parameter: str) -> tuple[float, float]:
        """[low, high] of a family parameter in this pool: `ranges`, else the family's default."""
        from simulator.families import FAMILIES

        given = self.ranges.get(family, {})  # type: ignore[call-overload]
        if parameter in given:
            return given[parameter]
        return FAMILIES[family].parameter(parameter).pool

    def _check_families(self) -> None:
        from simulator.families import FAMILIES

        for name in ("throttle_range", "steering_range"):
            if getattr(self, name) is not None:
                raise ConfigError(
                    name, getattr(self, name), "applies to an operating-point pool, not to families"
                )
        if self.kinds != ["skidpad"]:
            raise ConfigError(
                "kinds", self.kinds, "applies to a reference pool: a family pool is set by families"
            )
        if self.size is None:
            raise ConfigError("size", None, "a family pool needs size (Sobol draws per family)")
        for family, bounds in self.ranges.items():
            if family not in self.families:
                raise ConfigError(f"ranges.{family}", family, f"is not in families {self.families}")
            spec = FAMILIES[family]
            for parameter, (low, high) in bounds.items():
                field = f"ranges.{family}.{parameter}"
                if parameter not in spec.names:
                    raise ConfigError(
                        field, parameter, f"unknown parameter; choose from {', '.join(spec.names)}"
                    )
                p = spec.parameter(parameter)
                if not (math.isfinite(low) and math.isfinite(high) and low <= high):
                    raise ConfigError(field, [low, high], "must be [low, high] with low <= high")
                if low < p.low or high > p.high:
                    unit = f" {p.unit}" if p.unit else ""
                    raise ConfigError(field, [low, high], f"must lie within [{p.low:g}, {p.high:g}]{unit}")
        object.__setattr__(self, "throttles", None)
        object.__setattr__(self, "steerings", None)

    @model_validator(mode="after")
    def _grid_or_range(self) -> PoolConfig:
        if self.families:
            self._check_families()
            return self
        if self.ranges:
            raise ConfigError("ranges", sorted(self.ranges), "applies to a family pool: give families too")
        ranged = (self.throttle_range, self.steering_range, self.size)
        if any(v is not None for v in ranged):
            if any(v is None for v in ranged):
                raise ValueError("a continuous pool needs throttle_range, steering_range and size together")
            for name in ("throttle_range", "steering_range"):
                low, high = getattr(self, name)
                if not low < high:
                    raise ValueError(f"{name} must be [low, high] with low < high, got {[low, high]}")
            # A continuous pool replaces the default grid.
            object.__setattr__(self, "throttles", None)
            object.__setattr__(self, "steerings", None)
        elif self.throttles is None or self.steerings is None:
            raise ValueError("give throttles and steerings (a grid), or throttle_range, steering_range, size")
        return self


class NoiseSettings(_Section):
    """Sensor noise of the simulated logs (passed to `simulator.NoiseConfig`; None keeps its default)."""

    enabled: bool = True
    heteroscedastic: bool = True
    speed: NonNegative | None = None
    yaw_rate: NonNegative | None = None


class SimulationConfig(_Section):
    """How maneuvers are simulated and logged."""

    rate_hz: Annotated[float, Field(gt=0, le=500)] = 30.0
    threads: Count | None = None  # None: all cores
    noise: NoiseSettings = NoiseSettings()


class DataConfig(_Section):
    """Which logged rows become training samples."""

    # Keep every `stride`-th logged row: neighbouring rows at 30 Hz carry nearly the same information.
    stride: Count = 10
    # Drop each maneuver's first seconds: the start-up transient is not a function of the controls.
    skip_seconds: NonNegative = 2.0
    # Model inputs: the controls (a static map), the controls and the previous rates (the Markov-state
    # variant), or "history": the last `history` steps of controls and rates, `history_step` log steps
    # apart (a delay embedding, `activelearn.numerics.lags`; "controls+rates" is history 1, step 1).
    inputs: Literal["controls", "controls+rates", "history"] = "controls"
    history: Annotated[int, Field(ge=1, le=64)] = 4
    history_step: Annotated[int, Field(ge=1, le=300)] = 3
    # Where the logged pose (posX, posY) lies, in metres ahead of the rear axle: a kinematic car's
    # rear axle does not slip sideways, so a point `a` ahead of it moves sideways at a·ω in a turn.
    # Free runs integrate v along the heading at the axle and place the path there. Nigel's IMU sits
    # at the CG, l_r = 0.0793 m ahead (0 integrates v along the heading at the logged point itself).
    pose_lever_arm: Annotated[float, Field(ge=-1.0, le=1.0)] = POSE_LEVER_ARM

    @model_validator(mode="after")
    def _history_knobs_need_history(self) -> DataConfig:
        # Values other than the defaults (a dumped config repeats the defaults; those are harmless).
        fields = type(self).model_fields
        given = [k for k in ("history", "history_step") if getattr(self, k) != fields[k].default]
        if given and self.inputs != "history":
            raise ValueError(f"{', '.join(sorted(given))} apply to inputs = 'history' only")
        return self


class PriorGridConfig(_Section):
    """A maneuver grid already driven: simulated once by the nominal simulator (cached), fixed noise."""

    kinds: list[Kind] = ["skidpad"]
    directions: list[Direction] = ["ccw", "cw"]
    throttles: list[Throttle]
    steerings: list[Steering] = [0.0]
    duration: Positive = 30.0
    # The prior is data already in hand: the same rows for every campaign seed and strategy.
    noise_seed: Seed = 2_000_003

    @field_validator("kinds", "directions", "throttles", "steerings")
    @classmethod
    def _non_empty_unique(cls, value: list[Any], info: ValidationInfo) -> list[Any]:
        return _unique(value, info.field_name)


PriorUse = Literal["data", "finetune", "residual"]


class PriorConfig(_Section):
    """Warm start: what is known before the campaign spends its budget.

    Sources (any mix): `grid`, a maneuver grid simulated once and cached; `paths`, earlier campaign
    directories, sample tables (.parquet/.csv in the sample schema) and AutoDRIVE logs (.csv).
    `use` says what the prior rows do: "data" trains every round beside the new maneuvers (the same
    system); "finetune" trains a prior model once, and every round starts from its weights and trains
    on the new maneuvers only; "residual" keeps the prior model fixed and learns the new system's
    difference from it (sim-to-real). `model` starts from trained weights (a model.pt or a campaign
    directory) instead of fitting the prior model on the prior rows.
    """

    grid: PriorGridConfig | None = None
    paths: list[str] = []
    use: PriorUse = "data"
    model: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, value: Any) -> Any:
        # `prior = "runs/x/seed0"` or `prior = ["a.parquet", "logs/"]` name paths only.
        if isinstance(value, str):
            return {"paths": [value]}
        if isinstance(value, list):
            return {"paths": value}
        return value

    @model_validator(mode="after")
    def _has_a_source(self) -> PriorConfig:
        if self.grid is None and not self.paths and self.model is None:
            raise ValueError("a prior needs a grid, paths or a model")
        if self.use == "data" and self.grid is None and not self.paths:
            raise ValueError("use = 'data' needs prior rows: give a grid or paths")
        if self.use != "data" and self.model is None and self.grid is None and not self.paths:
            raise ValueError(f"use = {self.use!r} needs a model, or rows (grid, paths) to train one")
        return self


class DesignConfig(_Section):
    """Initial design, batch size, budget and stop rule of the outer loop."""

    # Warm start (see PriorConfig); prior maneuvers count against no budget. Declared first: the
    # checks of `initial` read it.
    prior: PriorConfig | None = None
    # Maneuvers of the strategy-independent initial design (greedy maximin); 0 only with a prior,
    # whose model then chooses from the first round on.
    initial: Annotated[int, Field(ge=0)] = 4
    per_round: Count = 2
    # Budget: the loop stops at the first limit reached (at least one must be given).
    max_maneuvers: Count | None = 24
    max_rounds: Count | None = None
    max_sim_seconds: Positive | None = None
    # Stop once the largest epistemic std over the pool falls below this (standardised units).
    stop_epistemic_std: Positive | None = None
    # "prequential": scale each round's epistemic variance by what calibrated the last two models on
    # the maneuvers collected after them (held-out operating points the loop gets for free). Off by
    # default: strategies pick where the model errs most, so those points overstate its error
    # (measured: scales of 40-60 that left the test set 3-6x underconfident).
    recalibrate: Literal["none", "prequential"] = "none"
    # "prequential" (the default): widen (or narrow) each round's free-run fans by the factor under
    # which 95 % of the true positions of the maneuvers collected after the last two models lay inside
    # their fans (`numerics.surrogate.fan_scale_needed`); the saved model carries it as `fan_scale`, so
    # `predict` draws the calibrated fans too. Uncalibrated fans held 0.12-0.49 of the true positions
    # (physics kind, dynamics.toml), calibrated 0.90-0.99 from round 1 on (10 seeds,
    # experiments/results/physics.txt). Round 0 has nothing to calibrate on. "none": the posterior's
    # and the noise's own fans. The safety fan ignores it ([safety] fan_scale is its margin).
    fan_calibration: Literal["none", "prequential"] = "prequential"
    # Seconds of set-up per maneuver (drive to the start, reset, check): part of each maneuver's cost.
    setup_seconds: NonNegative = 0.0

    @field_validator("initial")
    @classmethod
    def _initial_needs_data(cls, value: int, info: ValidationInfo) -> int:
        prior = info.data.get("prior")
        if value == 0 and prior is None:
            raise ValueError("initial = 0 needs a prior (design.prior): a cold start has no model to ask")
        if value == 0 and prior is not None and prior.use == "residual":
            raise ValueError("initial = 0 with prior.use = 'residual': the residual needs new maneuvers")
        return value

    @model_validator(mode="after")
    def _needs_budget(self) -> DesignConfig:
        if self.max_maneuvers is None and self.max_rounds is None and self.max_sim_seconds is None:
            raise ValueError("give a budget: max_maneuvers, max_rounds or max_sim_seconds")
        if self.max_maneuvers is not None and self.max_maneuvers < self.initial:
            raise ValueError(f"max_maneuvers ({self.max_maneuvers}) is below initial ({self.initial})")
        return self


class AcquisitionConfig(_Section):
    """How uncertainty strategies score and batch candidates, and the evaluation grid."""

    batch: Literal["fantasy", "penalty", "topk"] = "fantasy"
    n_samples: Annotated[int, Field(ge=2)] = 64
    fantasy_weight: Positive = 1.0
    penalty_length: Positive = 0.15
    # Points along each candidate's control sequence at which it is scored.
    score_points: Count = 24
    # Where a dynamic model (history or Markov inputs) scores a candidate: "steady_state", at the rates
    # it settles to under each control point held; "path", at the inputs it would see along its own
    # free run of the candidate's whole control signal (`activelearn.numerics.paths`); the target
    # region "test" then holds the inputs along the test maneuvers' predicted paths.
    dynamic_points: Literal["steady_state", "path"] = "steady_state"
    # Evaluation grid (throttle × signed steering): uncertainty metrics and maps.
    grid_throttles: Annotated[int, Field(ge=2)] = 15
    grid_steerings: Annotated[int, Field(ge=2)] = 15
    # Score information per second of track time (score / (duration + design.setup_seconds)).
    cost_aware: bool = False


class TargetConfig(_Section):
    """Where the model must be good: integrated variance and error-reduction scores integrate here.

    region = "test" (default): the controls the test maneuvers apply, i.e. where the error is measured;
    "pool": a throttle × signed-steering grid spanning the pool (the generic evaluation grid);
    "box": a grid over `throttle_range` × `steering_range` (unsigned; `directions` give the signs).
    """

    region: Literal["test", "pool", "box"] = "test"
    throttle_range: tuple[Throttle, Throttle] | None = None
    steering_range: tuple[Steering, Steering] | None = None
    directions: list[Direction] = ["ccw", "cw"]
    # Most target points kept (evenly thinned): integrated variance costs O(points x draws^2).
    max_points: Annotated[int, Field(ge=4)] = 400
    grid_size: Annotated[int, Field(ge=2)] = 12

    @model_validator(mode="after")
    def _box(self) -> TargetConfig:
        boxed = self.throttle_range is not None or self.steering_range is not None
        if self.region == "box":
            if self.throttle_range is None or self.steering_range is None:
                raise ValueError("region = 'box' needs throttle_range and steering_range")
            for name in ("throttle_range", "steering_range"):
                low, high = getattr(self, name)
                if not low <= high:
                    raise ValueError(f"{name} must be [low, high] with low <= high, got {[low, high]}")
        elif boxed:
            raise ValueError(f"throttle_range and steering_range need region = 'box', got {self.region!r}")
        _unique(self.directions, "directions")
        return self


# Metrics a comparison can rank strategies by (lower is better): one-step test errors, and the
# free-running rollouts of the test maneuvers (`activelearn.numerics.surrogate.free_run_metrics`).
RANKING_METRICS: tuple[str, ...] = (
    "test_rmse",
    "test_rmse_v",
    "test_rmse_w",
    "test_nll",
    "test_crps",
    "rollout_pos_err_10s",
    "rollout_pos_err_30s",
    "rollout_heading_err_30s",
    "rollout_rmse_v",
    "rollout_rmse_w",
)


class TestSetConfig(_Section):
    """The fixed test set: one grid of maneuvers shared by every strategy and seed of a config."""

    __test__ = False  # not a pytest class

    kinds: list[Kind] = ["skidpad"]
    directions: list[Direction] = ["ccw", "cw"]
    throttles: list[Throttle] = [0.3, 0.5, 0.7, 0.9]
    steerings: list[Steering] = [0.05, 0.1571, 0.2618, 0.3665, 0.4712]
    duration: Positive = 30.0
    noise_seed: Seed = 1_000_003
    # Recorded logs (a folder or files) to test on instead of the simulated grid: a real car's test set.
    logs: list[str] | None = None
    # What `compare` ranks by (its table, "to reach uniform" columns and figure): a one-step error
    # (static maps) or a free-running rollout error (dynamics models); `compare --metric` overrides.
    metric: str = "test_rmse"
    # Free-running rollouts of the test maneuvers every round (posterior draws per rollout; 0: off).
    rollout_samples: Annotated[int, Field(ge=0)] = 32

    @field_validator("metric")
    @classmethod
    def _known_metric(cls, value: str) -> str:
        if value not in RANKING_METRICS:
            raise ValueError(f"unknown metric {value!r}; choose from {', '.join(RANKING_METRICS)}")
        return value

    @field_validator("rollout_samples")
    @classmethod
    def _bands_need_two(cls, value: int) -> int:
        if value == 1:
            raise ValueError("rollout_samples must be 0 (off) or >= 2 (a fan needs two draws)")
        return value

    @model_validator(mode="after")
    def _rollout_metric_needs_rollouts(self) -> TestSetConfig:
        if self.metric.startswith("rollout_") and self.rollout_samples == 0:
            raise ValueError(f"metric = {self.metric!r} needs rollouts: rollout_samples must be >= 2")
        return self

    @field_validator("kinds", "directions", "throttles", "steerings")
    @classmethod
    def _non_empty_unique(cls, value: list[Any], info: ValidationInfo) -> list[Any]:
        return _unique(value, info.field_name)

    @field_validator("logs", mode="before")
    @classmethod
    def _one_or_many(cls, value: Any) -> Any:
        return [value] if isinstance(value, str) else value


OracleKind = Literal["simulator", "twin", "external", "logs"]


class OracleConfig(_Section):
    """Who answers the maneuvers a campaign proposes.

    "simulator" (default): the nominal MuJoCo model. "twin": MuJoCo with parameter `overrides` (a
    stand-in for the real car while rehearsing, validated by the simulator). "external": a person or
    script drives the proposals and hands back logs (`activelearn campaign propose` / `ingest`).
    "logs": a folder of recorded logs in the AutoDRIVE layout (`<maneuver>_30_hz/<variation> Log.csv`)
    is the finite pool; strategies choose among the recorded maneuvers.
    """

    kind: OracleKind = "simulator"
    overrides: dict[str, float] = {}
    path: str | None = None
    # logs: share of the recorded maneuvers held out as the test set when [test] logs is not given.
    test_fraction: Annotated[float, Field(gt=0, lt=1)] = 0.25
    # external: how far a log's controls may be from a proposal's and still be that maneuver, and how
    # much shorter than proposed a log may be before it counts as cut off.
    throttle_tolerance: Positive = 0.05
    steering_tolerance: Positive = 0.05
    duration_tolerance: Annotated[float, Field(gt=0, lt=1)] = 0.1

    @field_validator("overrides", mode="before")
    @classmethod
    def _overrides_known(cls, value: Any) -> Any:
        # the simulator owns the parameter table; its OverrideError names the parameter, and
        # _as_config_error turns that into the field oracle.overrides.<name>
        from simulator.twin import check_overrides

        return check_overrides(value) if isinstance(value, dict) else value

    @model_validator(mode="after")
    def _fields_of_kind(self) -> OracleConfig:
        if self.overrides and self.kind != "twin":
            raise ValueError(f"overrides apply to kind = 'twin' only, got kind = {self.kind!r}")
        if self.kind == "logs" and self.path is None:
            raise ValueError("kind = 'logs' needs path: the folder of recorded logs")
        if self.path is not None and self.kind != "logs":
            raise ValueError(f"path applies to kind = 'logs' only, got kind = {self.kind!r}")
        return self


class TrackingConfig(_Section):
    """Where MLflow writes."""

    uri: str = "sqlite:///mlruns/mlflow.db"
    experiment: str = "activelearn"
    enabled: bool = True


class CampaignConfig(_Section):
    """A whole campaign: pool, simulation, data, design, acquisition, model, training, test set, tracking."""

    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")] = "campaign"
    seed: Seed = 0
    strategy: str = "max_epistemic"
    output_dir: str = "runs"
    pool: PoolConfig = PoolConfig()
    simulation: SimulationConfig = SimulationConfig()
    data: DataConfig = DataConfig()
    design: DesignConfig = DesignConfig()
    acquisition: AcquisitionConfig = AcquisitionConfig()
    model: ModelConfig = ModelConfig()
    training: TrainingConfig = TrainingConfig()
    test: TestSetConfig = TestSetConfig()
    target: TargetConfig = TargetConfig()
    oracle: OracleConfig = OracleConfig()
    tracking: TrackingConfig = TrackingConfig()
    # [safety] (issue 23): the arena and limits of a track day; None = no walls. Defined at the end.
    safety: SafetyConfig | None = None
    # [tuning] (issue 5) is read by `activelearn tune` only; excluded from dumps, so campaign hashes,
    # logged params and the configs sent to workers do not depend on it. Defined at the end of the file.
    tuning: TuningConfig = Field(default_factory=lambda: TuningConfig(), exclude=True)

    @field_validator("strategy")
    @classmethod
    def _check_strategy(cls, value: str) -> str:
        from activelearn.loop.acquisition import STRATEGIES  # acquisition does not import this module's users

        if value not in STRATEGIES:
            raise ValueError(f"unknown strategy {value!r}; choose from {', '.join(STRATEGIES)}")
        return value

    @model_validator(mode="after")
    def _inputs_match_model(self) -> CampaignConfig:
        if self.model.pose_lever_arm != self.data.pose_lever_arm:
            # The data section says where the pose is logged; the saved model carries it to free runs.
            update = {"pose_lever_arm": self.data.pose_lever_arm}
            object.__setattr__(self, "model", self.model.model_copy(update=update))
        if self.data.inputs == "history":
            # The data section owns the layout; the model follows it (its saved config then carries
            # what the forward simulation needs).
            layout = {"n_inputs": 4 * self.data.history, "history_step": self.data.history_step}
            if any(getattr(self.model, k) != v for k, v in layout.items()):
                object.__setattr__(self, "model", self.model.model_copy(update=layout))
            return self
        expected = 4 if self.data.inputs == "controls+rates" else 2
        if self.model.n_inputs != expected:
            raise ValueError(f"model.n_inputs must be {expected} for data.inputs = {self.data.inputs!r}")
        if self.model.kind in ("recurrent", "physics") and self.data.inputs == "controls":
            kind = self.model.kind
            raise ValueError(f"model.kind = {kind!r} needs data.inputs = 'history' or 'controls+rates'")
        return self


def _as_config_error(exc: ValidationError) -> ConfigError:
    error = exc.errors()[0]
    field = ".".join(str(p) for p in error["loc"]) or "config"
    cause = (error.get("ctx") or {}).get("error")
    if isinstance(getattr(cause, "field", None), str) and hasattr(cause, "reason"):
        # a validator's own field-naming error (e.g. the simulator's OverrideError) names a sub-key
        return ConfigError(f"{field}.{cause.field}", cause.value, cause.reason)  # type: ignore[union-attr]
    return ConfigError(field, error.get("input"), error["msg"].removeprefix("Value error, "))


def _merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in override.items():
        both_tables = isinstance(value, dict) and isinstance(merged.get(key), dict)
        merged[key] = _merge(merged[key], value) if both_tables else value
    return merged


def read_toml(path: str | Path, field: str = "config") -> dict[str, Any]:
    """Parse a TOML file; a missing file or a syntax error is a ConfigError naming `field`."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(field, str(path), "no such file")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(field, str(path), f"invalid TOML: {exc}") from None


def validate_config(data: dict[str, Any]) -> CampaignConfig:
    """Validate a config mapping, raising a ConfigError that names the first offending key."""
    try:
        return CampaignConfig.model_validate(data)
    except ValidationError as exc:
        raise _as_config_error(exc) from None


def load_config(
    path: str | Path, *, params: str | Path | None = None, overrides: dict[str, Any] | None = None
) -> CampaignConfig:
    """Load and validate a campaign config.

    `params` is a TOML file of [model] and [training] tables (as `activelearn tune` writes them);
    `overrides` (nested values from the command line) take precedence over both.
    """
    data = read_toml(path)
    if params is not None:
        extra = read_toml(params, "--params")
        unknown = sorted(set(extra) - {"model", "training"})
        if unknown:
            raise ConfigError("--params", unknown, "only [model] and [training] tables are accepted")
        data = _merge(data, extra)
    data = _merge(data, overrides or {})
    data.setdefault("name", Path(path).stem)
    return validate_config(data)


# ------------------------------------------------------------------------------------- tuning section
# `activelearn tune` (issue 5): the search space and the study's settings. Appended after
# CampaignConfig, which refers to TuningConfig by name (resolved by the model_rebuild at the end).

SpaceKind = Literal["float", "int", "bool", "choice"]
# Every tunable parameter: its kind and, for choices, the allowed values. Widths apply per hidden
# layer: dense layers draw from `width`, variational ones from `variational_width` (a full-covariance
# posterior costs O(p²) in a layer's parameter count p, so variational layers stay narrow by default).
SPACE_PARAMS: dict[str, tuple[SpaceKind, tuple[Any, ...] | None]] = {
    "lr": ("float", None),
    "epochs": ("int", None),
    "batch_size": ("int", None),
    "activation": ("choice", ACTIVATIONS),
    "optimizer": ("choice", ("sgd", "rmsprop", "adam")),
    "loss": ("choice", ("nll", "mse", "mae")),
    "posterior": ("choice", ("mean_field", "full_cov")),
    "kl": ("choice", ("exact", "mc")),
    "prior_scale": ("float", None),
    "n_layers": ("int", None),
    "width": ("int", None),
    "variational_width": ("int", None),
    "variational": ("bool", None),
    "variational_head": ("bool", None),
    "hidden_size": ("int", None),
    # the physics kind's correction (read by kind = "physics" only)
    "correction": ("choice", ("ensemble", "hybrid")),
    "correction_inputs": ("choice", ("control", "history")),
    "residual_bound": ("float", None),
}
# Search-space parameters that may be left unset: trials then keep the config's [model] value.
OPTIONAL_SPACE_PARAMS = ("correction", "correction_inputs", "residual_bound")
# Upper bounds that keep a sampled network buildable and trainable in reasonable time (and the
# physics correction's bound within ModelConfig's range).
_SPACE_MAX = {"n_layers": 8, "width": 1024, "variational_width": 1024, "hidden_size": 512}
_SPACE_MAX["residual_bound"] = 0.5


class Range(_Section):
    """A numeric interval of the search space: [low, high], optionally log-uniform or stepped."""

    low: int | float
    high: int | float
    log: bool = False
    step: float | None = None


def _check_space_value(name: str, kind: SpaceKind, allowed: tuple[Any, ...] | None, value: Any) -> Any:
    """Validate one fixed value or choice of parameter `name`; return it in its canonical type."""
    if kind == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"takes true/false, got {value!r}")
        return value
    if kind == "choice":
        if value not in allowed:  # type: ignore[operator]
            raise ValueError(f"unknown value {value!r}; choose from {', '.join(allowed)}")  # type: ignore[arg-type]
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"takes a number, got {value!r}")
    if not math.isfinite(value):  # int(inf) would overflow; an infinite range cannot be sampled
        raise ValueError(f"must be finite, got {value!r}")
    if kind == "int":
        if value != int(value):
            raise ValueError(f"takes whole numbers, got {value!r}")
        value = int(value)
        if value < 1:
            raise ValueError(f"must be >= 1, got {value!r}")
        if name in _SPACE_MAX and value > _SPACE_MAX[name]:
            raise ValueError(f"must be <= {_SPACE_MAX[name]}, got {value!r}")
        return value
    if not value > 0:
        raise ValueError(f"must be > 0, got {value!r}")
    if name in _SPACE_MAX and value > _SPACE_MAX[name]:
        raise ValueError(f"must be <= {_SPACE_MAX[name]}, got {value!r}")
    return float(value)


def check_space_param(name: str, value: Any) -> Range | list[Any] | Any:
    """Validate one search-space entry: a fixed value, a list of choices or a {low, high} range."""
    kind, allowed = SPACE_PARAMS[name]
    if isinstance(value, list | tuple):
        if not value:
            raise ValueError("empty list of choices")
        choices = [_check_space_value(name, kind, allowed, v) for v in value]
        if len(set(choices)) != len(choices):
            raise ValueError(f"duplicate choices {choices}")
        return choices
    if isinstance(value, dict | Range):
        if kind not in ("float", "int"):
            raise ValueError("takes a value or a list of choices, not a range")
        try:
            rng = Range.model_validate(value if isinstance(value, dict) else value.model_dump())
        except ValidationError as exc:
            error = exc.errors()[0]
            where = ".".join(str(p) for p in error["loc"])
            raise ValueError(f"range {where}: {error['msg']}") from None
        low = _check_space_value(name, kind, allowed, rng.low)
        high = _check_space_value(name, kind, allowed, rng.high)
        if low > high:
            raise ValueError(f"empty range: low ({low!r}) > high ({high!r})")
        if rng.step is not None:
            if not rng.step > 0:
                raise ValueError(f"step must be > 0, got {rng.step!r}")
            if rng.log:
                raise ValueError("a range is either log or stepped, not both")
            if kind == "int" and rng.step != int(rng.step):
                raise ValueError(f"step must be a whole number, got {rng.step!r}")
        return Range(low=low, high=high, log=rng.log, step=rng.step)
    return _check_space_value(name, kind, allowed, value)


class SearchSpace(_Section):
    """What `activelearn tune` samples: per parameter a fixed value, a list of choices or a range.

    TOML forms: `optimizer = "adam"` (fixed), `activation = ["relu", "elu"]` (choices),
    `lr = { low = 1e-4, high = 1e-1, log = true }` or `epochs = { low = 20, high = 200, step = 10 }`.
    The network has `n_layers` hidden layers; each is variational or dense (`variational`), with a
    width from `variational_width` or `width`; `variational_head` makes the output layer variational.
    """

    model_config = ConfigDict(extra="forbid", validate_assignment=True, validate_default=True)

    lr: Any = Range(low=1e-4, high=1e-1, log=True)
    epochs: Any = Range(low=20, high=200, step=10)
    batch_size: Any = [16, 32, 64, 128, 256]
    activation: Any = list(ACTIVATIONS)
    optimizer: Any = ["sgd", "rmsprop", "adam"]
    loss: Any = ["nll", "mse", "mae"]
    posterior: Any = ["mean_field", "full_cov"]
    kl: Any = ["exact", "mc"]
    prior_scale: Any = Range(low=0.1, high=10.0, log=True)
    n_layers: Any = Range(low=1, high=4)
    width: Any = [8, 16, 32, 64]
    variational_width: Any = [4, 8, 16]
    variational: Any = [False, True]
    # The read-out is variational by default: the model then always has epistemic uncertainty.
    variational_head: Any = True
    # Width of the recurrent model's GRU trunk (read by kind = "recurrent" only). A history model's
    # layout ([data] history, history_step) shapes the study's data: one study per layout.
    hidden_size: Any = 32
    # The physics kind's correction (read by kind = "physics" only): its kind, what it reads, and the
    # bound on its steady-state residuals. Unset (None): the config's [model] value, not searched.
    correction: Any = None
    correction_inputs: Any = None
    residual_bound: Any = None

    @field_validator("*")
    @classmethod
    def _check_param(cls, value: Any, info: ValidationInfo) -> Any:
        if value is None and info.field_name in OPTIONAL_SPACE_PARAMS:
            return None
        return check_space_param(info.field_name, value)  # type: ignore[arg-type]


class TuningConfig(_Section):
    """`activelearn tune`: the search space, the validation split and the pruner/sampler settings."""

    space: SearchSpace = SearchSpace()
    # Share of operating points (whole maneuvers) held out for validation.
    val_fraction: Annotated[float, Field(gt=0, lt=1)] = 0.2
    # TPE samples at random for its first trials of each run, then models the good region.
    sampler_startup_trials: Annotated[int, Field(ge=0)] = 10
    # MedianPruner: prune only once this many trials completed, and never before this epoch.
    pruner_startup_trials: Annotated[int, Field(ge=0)] = 5
    pruner_warmup_epochs: Annotated[int, Field(ge=0)] = 10
    # HyperbandPruner: the fewest epochs a trial runs before it can be stopped.
    hyperband_min_epochs: Count = 5
    # Every trial is a new architecture: compiling would cost more than it saves (see training.py).
    compile: bool = False
    # Optuna heartbeats: a running trial records one every `heartbeat_interval` s; one silent for
    # `grace_period` s (its worker or machine is gone) is marked FAIL and queued again, at most
    # `retry_lost` times. Every machine joining a study should use the same values (same config).
    heartbeat_interval: Annotated[int, Field(ge=1)] = 10
    grace_period: Annotated[int, Field(ge=2)] = 60
    retry_lost: Annotated[int, Field(ge=0)] = 2

    @model_validator(mode="after")
    def _grace_exceeds_heartbeat(self) -> TuningConfig:
        if self.grace_period <= self.heartbeat_interval:
            raise ValueError("grace_period must exceed heartbeat_interval")
        return self


# ------------------------------------------------------------------------------------- safety section
# [safety] (issue 23): the arena a track day happens in, the car's limits and the risk level. The
# admissibility of candidates is computed in activelearn/loop/safety.py; the polygon helpers live
# here so that the config can check an arena without importing the loop.


def polygon_area(vertices: Any) -> float:
    """Signed area of a polygon (positive when counter-clockwise), shoelace formula."""
    import numpy as np

    xy = np.asarray(vertices, dtype=np.float64)
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _segments_cross(p1: Any, p2: Any, q1: Any, q2: Any) -> bool:
    """Whether closed segments p1-p2 and q1-q2 share a point (touching counts)."""

    def orient(a: Any, b: Any, c: Any) -> float:
        return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])

    def on(a: Any, b: Any, c: Any) -> bool:  # c on segment a-b, given collinear
        return min(a[0], b[0]) <= c[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])

    d1, d2, d3, d4 = orient(q1, q2, p1), orient(q1, q2, p2), orient(p1, p2, q1), orient(p1, p2, q2)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and 0 not in (d1, d2, d3, d4):
        return True
    return (
        (d1 == 0 and on(q1, q2, p1)) or (d2 == 0 and on(q1, q2, p2))
        or (d3 == 0 and on(p1, p2, q1)) or (d4 == 0 and on(p1, p2, q2))
    )  # fmt: skip


def polygon_self_crossing(vertices: Any) -> tuple[int, int] | None:
    """Indices (i, j) of two non-adjacent edges of a closed polygon that cross, or None."""
    n = len(vertices)
    edges = [(vertices[i], vertices[(i + 1) % n]) for i in range(n)]
    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:  # the closing edge meets the first one at vertex 0
                continue
            if _segments_cross(*edges[i], *edges[j]):
                return i, j
    return None


def boundary_distance(vertices: Any, x: Any, y: Any) -> Any:
    """Signed distance (m) of points (x, y) to a polygon's boundary: positive inside, negative outside."""
    import numpy as np

    xy = np.asarray(vertices, dtype=np.float64)
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    nearest = np.full(np.broadcast(x, y).shape, np.inf)
    inside = np.zeros(nearest.shape, dtype=bool)
    for (ax, ay), (bx, by) in zip(xy, np.roll(xy, -1, axis=0), strict=True):
        ex, ey = bx - ax, by - ay
        t = np.clip(((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey), 0.0, 1.0)
        np.minimum(nearest, np.hypot(x - ax - t * ex, y - ay - t * ey), out=nearest)
        # even-odd rule: count edges crossed by a ray towards +x
        straddles = (ay > y) != (by > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_cross = ax + (y - ay) * ex / np.where(ey == 0, 1.0, ey)
        inside ^= straddles & (x < x_cross)
    return np.where(inside, nearest, -nearest)


def polygon_clearance(vertices: Any, x: Any, y: Any) -> Any:
    """Like `boundary_distance` where it is >= 0, faster for a convex polygon; negative outside.

    Inside a convex polygon the distance to the boundary is the smallest distance to an edge's line,
    one multiply-add per edge and point (outside it is negative, though not the Euclidean distance).
    Other polygons take `boundary_distance`.
    """
    import numpy as np

    xy = np.asarray(vertices, dtype=np.float64)
    edges = np.roll(xy, -1, axis=0) - xy
    turns = edges[:, 0] * np.roll(edges[:, 1], -1) - edges[:, 1] * np.roll(edges[:, 0], -1)
    if not ((turns >= 0).all() or (turns <= 0).all()):
        return boundary_distance(vertices, x, y)
    inward = np.sign(polygon_area(vertices)) * np.column_stack([-edges[:, 1], edges[:, 0]])
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    offset = (inward * xy).sum(axis=1)
    clearance = None
    for (nx, ny), c in zip(inward, offset, strict=True):
        distance = nx * x + ny * y - c
        clearance = distance if clearance is None else np.minimum(clearance, distance, out=clearance)
    return clearance


class SafetyConfig(_Section):
    """A bounded arena, the car's limits and the risk a proposal may carry (`activelearn.loop.safety`).

    arena: the polygon the car must stay in, vertices [x, y] in metres (closed implicitly; repeating
        the first vertex at the end is allowed). start: the pose [x, y, yaw] every maneuver starts
        from. A candidate is admissible when the model's rollout fan gives it a probability of at
        most `delta` of leaving the arena (its centre closer than `margin` to a wall) or exceeding a
        limit; one whose risk reaches delta later than `min_duration` is cut short there.
    """

    arena: list[tuple[float, float]]
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Defaults a little above what Nigel can do (0.267 m/s, 0.805 rad/s, about 0.17 m/s² at full
    # throttle and full lock), so the arena binds and the limits only where set lower.
    max_speed: Positive = 0.3  # |v|, m/s
    max_yaw_rate: Positive = 0.9  # |ω|, rad/s
    max_lateral_acceleration: Positive = 0.2  # |v·ω|, m/s²
    delta: float = 0.05
    margin: NonNegative = 0.16  # m: half the car's length, so its body stays inside too
    # m, fans only: what a free run's path may still miss of the car's. Free runs integrate the rear
    # axle and place the logged point `pose_lever_arm` ahead of it, so the CG's side slip is in the
    # fan (true rates retrace the logged path to ~1 cm). Measured on safe_track.toml
    # (experiments/safety_guards.py, results/safety.txt): beside the kinematic guard no admitted true
    # path hit a wall at 0 either, but the nearest came within 8 mm (fan_scale 1) and 28 mm (3) of
    # the margin in the first round; at 0.04, within 43 mm there and 10 mm after 8 maneuvers (a
    # trusted fan 1-2 % off a 2.9-m circle), for 0.4 % fewer admitted seconds (0.16: 1.5 %).
    path_tolerance: NonNegative = 0.04
    min_duration: Positive = 5.0  # s: a candidate cut shorter than this is not admissible
    n_samples: Annotated[int, Field(ge=8)] = 64  # trajectories of the fan
    # Widens the fan's epistemic spread (a std factor) over the model's own: its epistemic std ranks
    # errors but is 2-4x too small on campaign designs (README, calibration; z spread 2.9-5.6 on
    # safe_track.toml), and a fan too narrow drives the car into the wall.
    fan_scale: Annotated[float, Field(ge=1)] = 3.0
    # The fan is trusted alone where the model's own epistemic std of the speed stays within this
    # share of the speed along the maneuver; beyond, the kinematic worst case must hold as well
    # (activelearn/loop/safety.py). Measured on safe_track.toml's prior model: 0.001-0.013 on the
    # prior's forward operating points, 0.03-0.08 in reverse, where the fan missed the true speed.
    trust_std: Positive = 0.02
    limit_window: NonNegative = 0.5  # s: rates are averaged over this window before the limits apply
    # The kinematic worst case takes the speed the car kept in its own logged steady turns (the
    # prior's and the campaign's skidpads and straights, `activelearn.loop.safety.turn_speed`) instead
    # of assuming none is lost in turns; false: none is.
    measured_turn_speed: bool = True
    # How the walls are kept: "planned" (each proposal is admitted, or cut short in advance, by its fan's
    # risk of meeting a wall or breaking a limit) or "live" (the car brakes as soon as its measured pose
    # comes within `margin + stop_buffer` of a wall, so only the limits are judged by the fan; the log
    # ends there). Nigel stops within 1.7 cm and 0.17 s from any speed in MuJoCo (results/safety.txt).
    stop: Literal["planned", "live"] = "planned"
    # m, live stop only: what the car travels between the pose that triggers the stop and standing still
    # (braking plus the pose's latency: ~0.27 m/s x latency); 0.05 m is an automatic stop on a 30-Hz pose.
    stop_buffer: NonNegative = 0.05
    enforce: bool = True  # false: measure risk and violations only, pick from every candidate

    @field_validator("arena", mode="after")
    @classmethod
    def _check_arena(cls, value: list[tuple[float, float]]) -> list[tuple[float, float]]:
        if len(value) > 1 and value[0] == value[-1]:
            value = value[:-1]
        if any(not math.isfinite(c) for vertex in value for c in vertex):
            raise ValueError("vertices must be finite")
        if len(value) < 3 or len(set(value)) < 3:
            raise ValueError("the polygon is open: it needs 3 or more distinct vertices")
        crossing = polygon_self_crossing(value)
        if crossing is not None:
            i, j = crossing
            raise ValueError(f"the polygon crosses itself (edge {i} and edge {j})")
        if abs(polygon_area(value)) < 1e-9:
            raise ValueError("the polygon is open: its vertices enclose no area")
        return value

    @field_validator("delta")
    @classmethod
    def _check_delta(cls, value: float) -> float:
        if not 0.0 < value < 1.0:
            raise ValueError("delta must lie in (0, 1)")
        return value

    @model_validator(mode="after")
    def _start_inside(self) -> SafetyConfig:
        if not all(math.isfinite(c) for c in self.start):
            raise ConfigError("start", list(self.start), "must be finite")
        room = float(boundary_distance(self.arena, self.start[0], self.start[1]))
        if room <= self.margin:
            where = "outside the arena" if room <= 0 else f"within margin = {self.margin} m of a wall"
            raise ConfigError("start", list(self.start), f"the start lies {where}")
        return self


CampaignConfig.model_rebuild()
