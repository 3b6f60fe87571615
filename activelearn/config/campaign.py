"""The whole campaign config and how it is read: TOML, `--params` tables and command-line overrides."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, ValidationError, field_validator, model_validator

from activelearn.config.base import Seed, _Section
from activelearn.config.model import ModelConfig, TrainingConfig
from activelearn.config.safety import SafetyConfig
from activelearn.config.sections import (
    AcquisitionConfig,
    DataConfig,
    DesignConfig,
    OracleConfig,
    PoolConfig,
    SimulationConfig,
    TargetConfig,
    TestSetConfig,
    TrackingConfig,
)
from activelearn.config.tuning import TuningConfig
from activelearn.errors import ConfigError
from activelearn.names import STRATEGY_NAMES


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
    # [safety] (issue 23): the arena and limits of a track day; None = no walls.
    safety: SafetyConfig | None = None
    # [tuning] (issue 5) is read by `activelearn tune` only; excluded from dumps, so campaign hashes,
    # logged params and the configs sent to workers do not depend on it.
    tuning: TuningConfig = Field(default_factory=lambda: TuningConfig(), exclude=True)

    @field_validator("strategy")
    @classmethod
    def _check_strategy(cls, value: str) -> str:
        if value not in STRATEGY_NAMES:
            raise ValueError(f"unknown strategy {value!r}; choose from {', '.join(STRATEGY_NAMES)}")
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
