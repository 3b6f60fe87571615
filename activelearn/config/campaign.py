"""The whole campaign config and how it is read: TOML, `--params` tables and command-line overrides."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from activelearn.config.base import Seed, _Section
from activelearn.config.evaluation import OracleConfig, TargetConfig, TestSetConfig, TrackingConfig
from activelearn.config.model import ModelConfig, TrainingConfig
from activelearn.config.safety import SafetyConfig, braking_distance, car_braking
from activelearn.config.sections import (
    AcquisitionConfig,
    DataConfig,
    DesignConfig,
    PoolConfig,
    SimulationConfig,
)
from activelearn.config.tuning import TuningConfig
from activelearn.config.vehicle import VehicleConfig, car_defaults
from activelearn.errors import ConfigError
from activelearn.names import STRATEGY_NAMES
from simulator.families import FAMILIES


class CampaignConfig(_Section):
    """A whole campaign: pool, simulation, data, design, acquisition, model, training, test set, tracking."""

    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")] = Field(
        "campaign",
        description="Name of the campaign: its folder under `output_dir` and the name of its MLflow runs and "
        "tuning studies; `load_config` defaults it to the TOML file's stem",
    )
    seed: Seed = Field(
        0,
        description="Campaign seed (`--seed` overrides): seeds the initial design, the oracle's sensor "
        "noise, the fits and the strategies' draws; the run folder is `seed<N>`",
    )
    strategy: str = Field(
        "max_epistemic",
        description="Acquisition strategy that picks each round's maneuvers (`--strategy` overrides), "
        "e.g. `uniform`, `max_epistemic`, `bald`, `integrated_variance`, `auto`",
    )
    output_dir: str = Field(
        "runs",
        description="Root folder of the outputs: campaigns in `<output_dir>/<name>/<strategy>/seed<N>`, "
        "comparisons, tuning results and the simulation cache (`<output_dir>/cache`)",
    )
    vehicle: VehicleConfig = Field(
        VehicleConfig(), description="The car: a shipped vehicle's name or a vehicle file (default Nigel)"
    )
    pool: PoolConfig = Field(PoolConfig(), description="The candidate maneuvers strategies choose from")
    simulation: SimulationConfig = Field(
        SimulationConfig(), description="How maneuvers are simulated and logged (rate, threads, sensor noise)"
    )
    data: DataConfig = Field(
        DataConfig(), description="Which logged rows become training samples and what the model reads"
    )
    design: DesignConfig = Field(
        DesignConfig(), description="Warm start, initial design, batch size, budget and stop rule"
    )
    acquisition: AcquisitionConfig = Field(
        AcquisitionConfig(), description="How uncertainty strategies score and batch candidates"
    )
    model: ModelConfig = Field(ModelConfig(), description="The surrogate model: kind, architecture, priors")
    training: TrainingConfig = Field(TrainingConfig(), description="How each round's model is trained")
    test: TestSetConfig = Field(
        TestSetConfig(), description="The fixed test set every round is measured on, and the ranking metric"
    )
    target: TargetConfig = Field(
        TargetConfig(), description="Where the model must be good: the region target-aware scores integrate"
    )
    oracle: OracleConfig = Field(
        OracleConfig(), description="Who answers the proposed maneuvers: simulator, twin, person or logs"
    )
    tracking: TrackingConfig = Field(TrackingConfig(), description="Where MLflow records runs")
    safety: SafetyConfig | None = Field(
        None,
        description="The arena, the car's limits and the risk a proposal may carry on a track day; "
        "absent: no walls and no limits",
    )
    # [tuning] (issue 5) is read by `activelearn tune` only; excluded from dumps, so campaign hashes,
    # logged params and the configs sent to workers do not depend on it.
    tuning: TuningConfig = Field(
        default_factory=lambda: TuningConfig(),
        exclude=True,
        description="What `activelearn tune` searches and how; read by it only, left out of config dumps",
    )

    @field_validator("strategy")
    @classmethod
    def _check_strategy(cls, value: str) -> str:
        if value not in STRATEGY_NAMES:
            raise ValueError(f"unknown strategy {value!r}; choose from {', '.join(STRATEGY_NAMES)}")
        return value

    @model_validator(mode="before")
    @classmethod
    def _raw_defaults(cls, value: Any) -> Any:
        # The car's defaults ([vehicle]) after `pose_lever_arm` has found its section.
        value = cls._lever_arm_in_model(value)
        return car_defaults(value) if isinstance(value, dict) else value

    @classmethod
    def _lever_arm_in_model(cls, value: Any) -> Any:
        # `pose_lever_arm` lives in [model]. Configs and stored campaigns that set it in [data], where it
        # lived before, are read with it moved to [model]; set in both with two values, it is an error.
        if not (isinstance(value, dict) and isinstance(value.get("data"), dict)):
            return value
        if "pose_lever_arm" not in value["data"]:
            return value
        data = dict(value["data"])
        arm = data.pop("pose_lever_arm")
        model = value.get("model") or {}
        if isinstance(model, BaseModel):
            model = model.model_dump(exclude_unset=True)
        if "pose_lever_arm" in model and model["pose_lever_arm"] != arm:
            raise ValueError(
                f"data.pose_lever_arm = {arm!r} and model.pose_lever_arm = {model['pose_lever_arm']!r}: "
                "pose_lever_arm belongs in [model] only"
            )
        return {**value, "data": data, "model": {**model, "pose_lever_arm": arm}}

    @model_validator(mode="after")
    def _fisher_needs_identified_physics(self) -> CampaignConfig:
        # `fisher` weighs candidates by what they tell the dynamic core's identified scales
        switched = self.strategy == "switch" and self.acquisition.switch_to == "fisher"
        identified = self.model.kind == "physics" and self.model.core == "dynamic"
        if (self.strategy == "fisher" or switched) and not identified:
            reason = 'fisher needs [model] kind = "physics" with core = "dynamic" (its identified scales)'
            raise ConfigError("strategy", self.strategy, reason)
        return self

    @model_validator(mode="after")
    def _another_cars_model_needs_physics(self) -> CampaignConfig:
        # another car's model carries its identified core across; a network has none to carry
        prior = self.design.prior
        of_another_car = prior is not None and not prior.same_car and prior.model is not None
        if of_another_car and self.model.kind != "physics":
            assert prior is not None
            reason = ('another car\'s model (same_car = false) needs [model] kind = "physics": a network '
                      "carries no core across cars (fine-tune it as this car's with same_car = true)")
            raise ConfigError("design.prior.model", prior.model, reason)
        return self

    @model_validator(mode="after")
    def _within_the_cars_lock(self) -> CampaignConfig:
        lock = self.vehicle.spec.steering.limit.value
        if self.model.vehicle != self.vehicle.name:
            name = self.vehicle.name
            raise ConfigError("model.vehicle", self.model.vehicle, f"must be [vehicle]'s {name!r}")
        grid = self.design.prior.grid if self.design.prior is not None else None
        checks = {
            "pool.steerings": self.pool.steerings, "pool.steering_range": self.pool.steering_range,
            "pool.full_lock": [self.pool.full_lock], "test.steerings": self.test.steerings,
            "test.full_lock": [self.test.full_lock], "target.steering_range": self.target.steering_range,
            "design.prior.grid.steerings": grid.steerings if grid is not None else None,
        }
        for family in self.pool.families:
            for p in FAMILIES[family].continuous:
                if p.unit == "rad":
                    checks[f"pool.ranges.{family}.{p.name}"] = list(self.pool.family_range(family, p.name))
        for field, values in checks.items():
            worst = max((v for v in values or () if v is not None), default=0.0)
            if worst > lock + 1e-12:
                raise ConfigError(field, worst, f"is beyond the car's full lock {lock:g} rad ([vehicle])")
        return self

    def stopping_deceleration(self) -> float | None:
        """What the car the oracle drives brakes at in a live stop (m/s²; `safety.car_braking`)."""
        return car_braking(self.vehicle.spec, self.oracle.overrides if self.oracle.kind == "twin" else None)

    @model_validator(mode="after")
    def _live_stop_within_braking(self) -> CampaignConfig:
        # a live stop's buffer must hold the braking distance from max_speed of the car the oracle drives
        safety = self.safety
        if safety is None or safety.stop != "live":
            return self
        spec = self.vehicle.spec
        deceleration = self.stopping_deceleration()
        if deceleration is None:
            raise ConfigError("safety.stop_buffer", safety.stop_buffer, f"cannot be checked: the vehicle "
                              f"{spec.name!r} gives no braking (set its limits.stopping_deceleration)")
        latency = 1.0 / spec.log_rate_hz
        need = braking_distance(safety.max_speed, deceleration, latency)
        if safety.stop_buffer < need:
            reason = (f"is below the {need:.3f} m the car needs to stop from max_speed = "
                      f"{safety.max_speed:g} m/s (one {spec.log_rate_hz:g}-Hz pose of latency, then braking "
                      f"at {deceleration:.3g} m/s², {spec.name})")
            raise ConfigError("safety.stop_buffer", safety.stop_buffer, reason)
        return self

    @model_validator(mode="after")
    def _inputs_match_model(self) -> CampaignConfig:
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
    field = ".".join(str(p) for p in error["loc"])
    cause = (error.get("ctx") or {}).get("error")
    if isinstance(getattr(cause, "field", None), str) and hasattr(cause, "reason"):
        # a validator's own field-naming error (e.g. the simulator's OverrideError) names a sub-key
        name = f"{field}.{cause.field}" if field else cause.field  # type: ignore[union-attr]
        return ConfigError(name, cause.value, cause.reason)  # type: ignore[union-attr]
    field = field or "config"
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
