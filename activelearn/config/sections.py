"""The campaign's sections: pool, simulation, data, warm start, design and acquisition (the target, test
set, oracle and tracking are in `activelearn.config.evaluation`)."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, ValidationInfo, field_validator, model_validator

from activelearn.config.base import (
    Count,
    Direction,
    FamilyName,
    Kind,
    NonNegative,
    Positive,
    Seed,
    Steering,
    Throttle,
    _Section,
    _unique,
)
from activelearn.config.vehicle import DEFAULT_CAR, pool_steerings
from activelearn.errors import ConfigError
from activelearn.names import SWITCH_RULES


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

    kinds: list[Kind] = Field(
        ["skidpad"], description="Maneuver kinds of the candidates, each driven at every operating point"
    )
    directions: list[Direction] = Field(
        ["ccw", "cw"], description="Turn directions: `ccw` (left, positive steering) and/or `cw` (right)"
    )
    throttles: list[Throttle] | None = Field(
        [0.2, 0.4, 0.6, 0.8, 1.0],
        description="Throttle values of the grid (share of full throttle, negative reverses; 0 is skipped)",
    )
    steerings: list[Steering] | None = Field(
        pool_steerings(DEFAULT_CAR),
        description="Unsigned steering amplitudes of the grid (rad, at most the car's full lock); default: "
        "the car's reference grid, full lock × (0.2, 0.4, 0.6, 0.8, 1) to 4 decimals (Nigel's shown)",
    )
    throttle_range: tuple[Throttle, Throttle] | None = Field(
        None, description="Continuous pool: [low, high] throttle of the Sobol operating points"
    )
    steering_range: tuple[Steering, Steering] | None = Field(
        None, description="Continuous pool: [low, high] unsigned steering (rad) of the Sobol operating points"
    )
    size: Annotated[int, Field(ge=2)] | None = Field(
        None,
        description="Scrambled-Sobol operating points of a continuous pool, or parameter vectors per family "
        "of a family pool; unset: the grid",
    )
    seed: Seed = Field(
        0, description="Seed of the pool's Sobol draws (the same pool for every campaign seed)"
    )
    duration: Positive = Field(
        90.0, description="Seconds each candidate maneuver lasts, unless `durations` names its kind"
    )
    # Maneuvers differ in what they cost on a track, and a seconds budget (design.max_sim_seconds) counts it.
    durations: dict[Kind | FamilyName, Positive] = Field(
        {}, description="Seconds per maneuver kind or family, overriding `duration` (e.g. {straight = 20})"
    )
    kind_distance: NonNegative = Field(
        0.5,
        description="Distance added between candidates of different kinds (or families), in units of the "
        "[0, 1] operating-point (or normalised family-parameter) cube",
    )
    families: list[FamilyName] = Field(
        [], description="Maneuver families (`simulator.families`) of a family pool; empty: kinds and the grid"
    )
    full_lock: Steering | None = Field(
        None, description="Steering (rad) a fishhook ramps to; unset: the car's full lock ([vehicle])"
    )
    ranges: dict[FamilyName, dict[str, tuple[float, float]]] = Field(
        {},
        description="Family pool: [low, high] per family parameter ({family = {parameter = [low, high]}}); "
        "unset parameters take the family's own pool range",
    )

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

    enabled: bool = Field(
        True, description="Add seeded Gaussian sensor noise to the logs; false logs the true signals"
    )
    heteroscedastic: bool = Field(
        True,
        description="Scale every noise std by 1 + 2 × speed / reference_speed (the simulator's speed_gain: "
        "three times the noise at full speed); false: the same std at every speed",
    )
    reference_speed: Positive | None = Field(
        None, description="Speed (m/s) of heteroscedastic noise's scale; unset: the car's top speed"
    )
    speed: NonNegative | None = Field(
        None, description="Std of the forward-speed noise (m/s); unset: the car's ([sensors]), else 0.002"
    )
    yaw_rate: NonNegative | None = Field(
        None, description="Std of the noise on the three gyro axes (rad/s); unset: the car's, else 0.005"
    )
    acceleration: NonNegative | None = Field(
        None, description="Std of the accelerometer noise (m/s²); unset: the car's, else 0.02"
    )
    position: NonNegative | None = Field(
        None, description="Std of the pose's position noise (m); unset: the car's, else 0.002"
    )
    angle: NonNegative | None = Field(
        None, description="Std of the roll, pitch and yaw noise (rad); unset: the car's, else 0.002"
    )


class SimulationConfig(_Section):
    """How maneuvers are simulated and logged."""

    rate_hz: Annotated[float, Field(gt=0, le=500)] = Field(
        30.0, description="Log rate (Hz): rows per second of the simulated logs"
    )
    threads: Count | None = Field(
        None, description="Parallel simulation workers; unset: all cores (the logs do not depend on it)"
    )
    noise: NoiseSettings = Field(NoiseSettings(), description="Sensor noise added to the simulated logs")


class DataConfig(_Section):
    """Which logged rows become training samples."""

    stride: Count = Field(
        10,
        description="Keep every n-th logged row: neighbouring rows at 30 Hz carry nearly the same "
        "information (also the spacing of multi-step training windows)",
    )
    skip_seconds: NonNegative = Field(
        2.0,
        description="Seconds dropped at each maneuver's start: the start-up transient is not a function of "
        "the controls",
    )
    inputs: Literal["controls", "controls+rates", "history"] = Field(
        "controls",
        description="Model inputs: the controls (a static map), the controls and the previous rates "
        "(Markov state), or the last `history` steps of both (`controls+rates` is history 1, step 1)",
    )
    history: Annotated[int, Field(ge=1, le=64)] = Field(
        4, description="inputs = 'history': past steps of controls and rates the model reads"
    )
    history_step: Annotated[int, Field(ge=1, le=300)] = Field(
        3,
        description="inputs = 'history': log steps between those past steps (a delay embedding, "
        "`activelearn.numerics.lags`)",
    )

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

    kinds: list[Kind] = Field(["skidpad"], description="Maneuver kinds of the prior grid")
    directions: list[Direction] = Field(["ccw", "cw"], description="Turn directions of the prior grid")
    throttles: list[Throttle] = Field(
        description="Throttle values of the prior grid (share of full throttle)"
    )
    steerings: list[Steering] = Field(
        [0.0], description="Unsigned steering amplitudes of the prior grid (rad)"
    )
    duration: Positive = Field(30.0, description="Seconds each prior maneuver lasts")
    # The prior is data already in hand: the same rows for every campaign seed and strategy.
    noise_seed: Seed = Field(
        2_000_003, description="Seed of the prior logs' sensor noise, fixed across campaign seeds"
    )

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

    grid: PriorGridConfig | None = Field(
        None, description="A maneuver grid simulated once by the nominal simulator and cached"
    )
    paths: list[str] = Field(
        [],
        description="Earlier campaign directories, sample tables (.parquet/.csv in the sample schema) and "
        "AutoDRIVE logs (.csv) whose rows the prior holds",
    )
    use: PriorUse = Field(
        "data",
        description="`data`: the prior rows train every round; `finetune`: each round starts from the prior "
        "model and trains on new maneuvers; `residual`: learn the difference from the fixed prior model",
    )
    model: str | None = Field(
        None,
        description="Trained prior model (a model.pt or a campaign directory) instead of fitting one on "
        "the prior rows",
    )
    same_car: bool = Field(
        True,
        description="Whether the prior's logs or model are of the car the campaign drives: a physics model "
        "(`[model] kind = \"physics\"`) then identifies its parameters on them beside the collected "
        "logs; false (another car, e.g. a grid simulated on nominal Nigel for a twin or a real car): "
        "they only centre the identification's prior, widened by the datasheet's widths, and train the "
        "correction only until the first collected log (after it, the car's own logs alone). With "
        "`model` (another car's trained physics model, any vehicle), its identified core centres the "
        "prior the same way; `use = \"finetune\"` also starts every round from its correction",
    )

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
        rows = self.grid is not None or bool(self.paths)
        if not self.same_car and self.model is not None:
            if rows:
                raise ValueError("same_car = false takes another car's logs (grid, paths) or its trained "
                                 "model (model), not both")  # fmt: skip
            if self.use == "residual":
                raise ValueError("same_car = false with a model takes use = 'data' (its identified "
                                 "core centres this car's) or 'finetune' (its correction too), not "
                                 "'residual'")  # fmt: skip
        elif self.use == "data" and not rows:
            raise ValueError("use = 'data' needs prior rows: give a grid or paths")
        if self.use != "data" and self.model is None and self.grid is None and not self.paths:
            raise ValueError(f"use = {self.use!r} needs a model, or rows (grid, paths) to train one")
        return self


class DesignConfig(_Section):
    """Initial design, batch size, budget and stop rule of the outer loop."""

    # Declared first: the checks of `initial` read it.
    prior: PriorConfig | None = Field(
        None, description="Warm start: what is known before the budget is spent; its maneuvers cost nothing"
    )
    initial: Annotated[int, Field(ge=0)] = Field(
        4,
        description="Maneuvers of the strategy-independent initial design (greedy maximin); 0 only with a "
        "prior, whose model then chooses from the first round on",
    )
    # "centre" gives every seed the same initial design, up to the mirror (greedy maximin is deterministic
    # but for ties, and the pool is one Sobol draw), so a comparison's spread holds no design luck
    initial_start: Literal["centre", "random"] = Field(
        "centre",
        description="Where the initial greedy-maximin design of an empty design starts: `centre`, the "
        "candidate nearest the pool's centre (one design for every seed, up to the mirror); `random`, a "
        "candidate drawn by the seed (a design of its own per seed)",
    )
    per_round: Count = Field(2, description="Maneuvers each round collects after the initial design")
    max_maneuvers: Count | None = Field(
        24,
        description="Budget: maneuvers collected in all, the initial design included; the loop stops at "
        "the first limit reached (give at least one)",
    )
    max_rounds: Count | None = Field(None, description="Budget: rounds after the initial design")
    max_sim_seconds: Positive | None = Field(
        None,
        description="Budget: seconds of track time, the maneuvers' durations as driven plus `setup_seconds` "
        "each; candidates that no longer fit are left out",
    )
    stop_epistemic_std: Positive | None = Field(
        None,
        description="Stop once the largest epistemic std over the pool falls below this (standardised "
        "units); unset: no such stop",
    )
    # Off by default: strategies pick where the model errs most, so those points overstate its error
    # (measured: scales of 40-60 that left the test set 3-6x underconfident).
    recalibrate: Literal["none", "prequential"] = Field(
        "none",
        description="`prequential`: scale each round's epistemic variance by what calibrated the last two "
        "models on the maneuvers collected after them; `none`: the model's own",
    )
    # Uncalibrated fans held 0.12-0.49 of the true positions (physics kind, dynamics.toml), calibrated
    # 0.90-0.99 from round 1 on (10 seeds, experiments/results/physics.txt). Round 0 has nothing to
    # calibrate on. The safety fan ignores it ([safety] fan_scale is its margin). A first need from 2 easy
    # signals narrowed the full-size car's fans to 0.66 of the true positions, so narrowing waits for 6
    # maneuvers (`loop.evaluation.MIN_TRIM_MANEUVERS`, experiments/results/fan_trim.txt).
    fan_calibration: Literal["none", "prequential"] = Field(
        "prequential",
        description="`prequential`: widen or narrow each round's free-run fans by the geometric mean of "
        "the widenings every earlier model needed to hold 95 % of the true positions of the maneuvers "
        "collected after it (narrowing only once 6 maneuvers were measured); `none`: the model's own",
    )
    setup_seconds: NonNegative = Field(
        0.0,
        description="Seconds of set-up per maneuver (drive to the start, reset, check), part of its cost",
    )

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

    batch: Literal["fantasy", "penalty", "topk"] = Field(
        "fantasy",
        description="How a round picks several: `fantasy` conditions the posterior on each pick before the "
        "next, `penalty` damps scores near earlier picks, `topk` takes the best scores",
    )
    n_samples: Annotated[int, Field(ge=2)] = Field(
        64, description="Posterior draws evaluated at the candidates' scoring points"
    )
    fantasy_weight: Positive = Field(
        1.0, description="`fantasy` batches: factor on the training rows each scoring point stands for"
    )
    penalty_length: Positive = Field(
        0.15,
        description="`penalty` batches: length of the Gaussian damping around earlier picks, in the pool's "
        "design distance (the [0, 1] operating-point cube plus `kind_distance`)",
    )
    score_points: Count = Field(
        24, description="Points along each candidate's control sequence at which it is scored"
    )
    dynamic_points: Literal["steady_state", "path"] = Field(
        "steady_state",
        description="Where a dynamic model scores a candidate: at the rates it settles to under each control "
        "held (`steady_state`), or along its own free run (`path`; a `test` target then follows those too)",
    )
    grid_throttles: Annotated[int, Field(ge=2)] = Field(
        15, description="Throttle values of the evaluation grid spanning the pool (uncertainty metrics, maps)"
    )
    grid_steerings: Annotated[int, Field(ge=2)] = Field(
        15, description="Signed steering values of the evaluation grid spanning the pool"
    )
    cost_aware: bool = Field(
        False,
        description="Score information per second of track time: score / (duration + "
        "design.setup_seconds)",
    )
    fisher_criterion: Literal["determinant", "prediction"] = Field(
        "determinant",
        description="`fisher`: what a batch maximises. `determinant`: log det of the identified scales' "
        "information, starting from their prior's precision and the collected candidates' (greedy "
        "D-optimal: every scale alike). `prediction`: how much it lowers trace(mean information of the "
        "pool's candidates x the scales' covariance), starting from the identification's own covariance, "
        "every log so far included (greedy I-optimal: the scales the envelope's free runs follow)",
    )
    switch_after: Annotated[int, Field(ge=0, strict=True)] = Field(
        10,
        description="`switch`: maneuvers collected, the initial design included, that `switch_first` picks "
        "before `switch_to` takes over",
    )
    switch_first: Literal[SWITCH_RULES] = Field(  # type: ignore[valid-type]
        "uniform",
        description="`switch`: the strategy that picks until `switch_after` maneuvers are collected "
        "(greedy maximin, or a model-based rule)",
    )
    switch_to: Literal[SWITCH_RULES] = Field(  # type: ignore[valid-type]
        "bald",
        description="`switch`: the strategy that picks once `switch_after` maneuvers are collected "
        "(a model-based rule, or greedy maximin); must differ from `switch_first`",
    )

    @model_validator(mode="after")
    def _switch_changes_rule(self) -> AcquisitionConfig:
        if self.switch_first == self.switch_to:
            reason = "must differ from switch_first: a switch changes the rule"
            raise ConfigError("switch_to", self.switch_to, reason)
        return self

    def updated(self, **options: Any) -> AcquisitionConfig:
        """A copy with `options` changed, validated as the TOML's [acquisition] is (a ConfigError names
        the key, e.g. `acquisition.n_samples`): how a strategy built in Python changes single options."""
        try:
            return AcquisitionConfig.model_validate({**self.model_dump(), **options})
        except ValidationError as exc:
            error = exc.errors()[0]
            cause = (error.get("ctx") or {}).get("error")
            if isinstance(cause, ConfigError):
                raise ConfigError(f"acquisition.{cause.field}", cause.value, cause.reason) from None
            field = ".".join(str(part) for part in error["loc"])
            raise ConfigError(f"acquisition.{field}", error.get("input"), error["msg"]) from None
