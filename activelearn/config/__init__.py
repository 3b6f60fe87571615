"""Configuration models: one place for every default.

Each section is a pydantic v2 model that rejects unknown keys (`extra="forbid"`) and validates its
values with messages that name the offending field. One module per part, every name importable from
the package as before the split (`from activelearn.config import CampaignConfig, load_config`):

- `base`: the strict section base, Nigel's limits, constrained types shared by the sections;
- `model`: [model] and [training];
- `sections`: pool, simulation, data, prior, design, acquisition, target, test, oracle, tracking;
- `campaign`: the whole `CampaignConfig` and how it is loaded (TOML, --params, overrides);
- `tuning`: [tuning], the search space of `activelearn tune`;
- `safety`: [safety], and `geometry`, the arena's polygon helpers.

The ground floor: imports nothing of the loop, the studies or the CLI (strategy and metric names come
from `activelearn.names`).
"""

from __future__ import annotations

from activelearn.config.base import (
    MAX_STEERING,
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
)
from activelearn.config.campaign import CampaignConfig, load_config, read_toml, validate_config
from activelearn.config.evaluation import (
    OracleConfig,
    OracleKind,
    TargetConfig,
    TestSetConfig,
    TrackingConfig,
)
from activelearn.config.geometry import (
    boundary_distance,
    polygon_area,
    polygon_clearance,
    polygon_self_crossing,
)
from activelearn.config.model import Activation, KLCount, ModelConfig, ModelKind, TrainingConfig
from activelearn.config.safety import SafetyConfig
from activelearn.config.sections import (
    AcquisitionConfig,
    DataConfig,
    DesignConfig,
    NoiseSettings,
    PoolConfig,
    PriorConfig,
    PriorGridConfig,
    PriorUse,
    SimulationConfig,
)
from activelearn.config.tuning import (
    OPTIONAL_SPACE_PARAMS,
    SPACE_PARAMS,
    Range,
    SearchSpace,
    SpaceKind,
    TuningConfig,
    check_space_param,
)
from activelearn.errors import ConfigError
from activelearn.names import RANKING_METRICS
from activelearn.numerics.arch import ACTIVATIONS, parse_arch

__all__ = [
    "ACTIVATIONS",
    "MAX_STEERING",
    "OPTIONAL_SPACE_PARAMS",
    "POSE_LEVER_ARM",
    "RANKING_METRICS",
    "SPACE_PARAMS",
    "AcquisitionConfig",
    "Activation",
    "CampaignConfig",
    "ConfigError",
    "Count",
    "DataConfig",
    "DesignConfig",
    "Direction",
    "FamilyName",
    "KLCount",
    "Kind",
    "ModelConfig",
    "ModelKind",
    "NoiseSettings",
    "NonNegative",
    "OracleConfig",
    "OracleKind",
    "PoolConfig",
    "Positive",
    "PriorConfig",
    "PriorGridConfig",
    "PriorUse",
    "Range",
    "SafetyConfig",
    "SearchSpace",
    "Seed",
    "SimulationConfig",
    "SpaceKind",
    "Steering",
    "TargetConfig",
    "TestSetConfig",
    "Throttle",
    "TrackingConfig",
    "TrainingConfig",
    "TuningConfig",
    "boundary_distance",
    "check_space_param",
    "load_config",
    "parse_arch",
    "polygon_area",
    "polygon_clearance",
    "polygon_self_crossing",
    "read_toml",
    "validate_config",
]
