"""The sections that judge a campaign and carry its answers: the target region, the test set, the oracle
and the tracking store."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator

from activelearn.config.base import (
    Direction,
    Kind,
    Positive,
    Seed,
    Steering,
    Throttle,
    _Section,
    _unique,
)
from activelearn.config.vehicle import DEFAULT_CAR, test_steerings
from activelearn.names import RANKING_METRICS


class TargetConfig(_Section):
    """Where the model must be good: integrated variance and error-reduction scores integrate here.

    region = "test" (default): the controls the test maneuvers apply, i.e. where the error is measured;
    "pool": a throttle × signed-steering grid spanning the pool (the generic evaluation grid);
    "box": a grid over `throttle_range` × `steering_range` (unsigned; `directions` give the signs).
    """

    region: Literal["test", "pool", "box"] = Field(
        "test",
        description="`test`: the controls the test maneuvers apply; `pool`: the evaluation grid spanning "
        "the pool; `box`: a grid over `throttle_range` × `steering_range`",
    )
    throttle_range: tuple[Throttle, Throttle] | None = Field(
        None, description="region = 'box': [low, high] throttle"
    )
    steering_range: tuple[Steering, Steering] | None = Field(
        None, description="region = 'box': [low, high] unsigned steering (rad)"
    )
    directions: list[Direction] = Field(
        ["ccw", "cw"], description="region = 'box': the steering signs the box covers"
    )
    # Integrated variance costs O(points x draws^2).
    max_points: Annotated[int, Field(ge=4)] = Field(
        400,
        description="region = 'test': most target points kept (a seeded subset weighted by time held; along "
        "predicted paths, shared evenly by the test maneuvers)",
    )
    grid_size: Annotated[int, Field(ge=2)] = Field(
        12, description="region = 'box': values per axis of the box grid"
    )

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

    kinds: list[Kind] = Field(["skidpad"], description="Maneuver kinds of the test grid")
    directions: list[Direction] = Field(["ccw", "cw"], description="Turn directions of the test grid")
    throttles: list[Throttle] = Field(
        [0.3, 0.5, 0.7, 0.9], description="Throttle values of the test grid (share of full throttle)"
    )
    steerings: list[Steering] = Field(
        test_steerings(DEFAULT_CAR),
        description="Unsigned steering amplitudes of the test grid (rad); default: the car's, full lock × "
        "(0.1 to 2 decimals, 0.3, 0.5, 0.7, 0.9) (Nigel's shown)",
    )
    full_lock: Steering | None = Field(
        None, description="Steering (rad) a test fishhook ramps to; unset: the car's full lock ([vehicle])"
    )
    duration: Positive = Field(30.0, description="Seconds each test maneuver lasts")
    noise_seed: Seed = Field(
        1_000_003, description="Seed of the test logs' sensor noise, the same for every campaign seed"
    )
    logs: list[str] | None = Field(
        None,
        description="Recorded logs (a folder or files) to test on instead of the simulated grid: a real "
        "car's test set",
    )
    metric: str = Field(
        "test_rmse",
        description="What `compare` ranks by (`--metric` overrides): a one-step error (static maps, e.g. "
        "`test_rmse`) or a free-run error (dynamics models, e.g. `rollout_pos_err_30s`)",
    )
    rollout_samples: Annotated[int, Field(ge=0)] = Field(
        32,
        description="Posterior draws per free-running rollout of the test maneuvers every round; 0: no "
        "rollouts",
    )

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

    kind: OracleKind = Field(
        "simulator",
        description="`simulator`: nominal MuJoCo; `twin`: MuJoCo with `overrides`; `external`: a person or "
        "script drives and hands back logs; `logs`: recorded logs under `path` are the pool",
    )
    overrides: dict[str, float] = Field(
        {},
        description="kind = 'twin': simulator parameters to change, by name (`simulator.twin."
        "TWIN_PARAMETERS` gives meaning, unit and range)",
    )
    path: str | None = Field(
        None,
        description="kind = 'logs': the folder of recorded logs in the AutoDRIVE layout "
        "(`<maneuver>_30_hz/<variation> Log.csv`)",
    )
    test_fraction: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.25,
        description="kind = 'logs': share of the recorded maneuvers held out as the test set when [test] "
        "logs is not given",
    )
    throttle_tolerance: Positive = Field(
        0.05,
        description="kind = 'external': how far a log's median throttle may be from a proposal's and still "
        "answer it",
    )
    steering_tolerance: Positive = Field(
        0.05,
        description="kind = 'external': how far a log's steering amplitude may be from a proposal's (rad); "
        "below it a log does not steer",
    )
    duration_tolerance: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.1,
        description="kind = 'external': share of the proposed duration a log may fall short before it "
        "counts as cut off",
    )

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

    uri: str = Field(
        "sqlite:///mlruns/mlflow.db",
        description="MLflow tracking URI: a local store (`sqlite:///...`) or a tracking server (`http://...`)",
    )
    experiment: str = Field("activelearn", description="MLflow experiment the runs are recorded under")
    enabled: bool = Field(True, description="Record runs in MLflow; false: no tracking at all")
