"""The campaign's sections: pool, simulation, data, warm start, design, acquisition, target, test set,
oracle and tracking."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator

from activelearn.config.base import (
    POSE_LEVER_ARM,
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
from activelearn.errors import ConfigError
from activelearn.names import RANKING_METRICS


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
    # their fans (`numerics.diagnostics.fan_scale_needed`); the saved model carries it as `fan_scale`, so
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

