"""Every model kind by its `[model] kind` name, and `build_model`."""

from __future__ import annotations

import torch

from activelearn.config import ModelConfig
from activelearn.numerics.models.base import Model
from activelearn.numerics.models.dynamic_physics import DynamicPhysicsModel
from activelearn.numerics.models.networks import NETWORK_CLASSES
from activelearn.numerics.models.physics import PhysicsModel

MODEL_CLASSES: dict[str, type[Model]] = {**NETWORK_CLASSES, PhysicsModel.kind: PhysicsModel}


def model_class(cfg: ModelConfig) -> type[Model]:
    """The class of the model `cfg.kind` describes (its class attributes say what the kind does); the
    physics kind's class follows its `core`."""
    if cfg.kind == PhysicsModel.kind and cfg.core == "dynamic":
        return DynamicPhysicsModel
    return MODEL_CLASSES[cfg.kind]


def build_model(cfg: ModelConfig, *, seed: int | None = 0) -> Model:
    """Build the model `cfg.kind` describes, its weights initialised from `seed` (None: global RNG)."""
    gen = torch.Generator().manual_seed(seed) if seed is not None else None
    return model_class(cfg)(cfg, generator=gen)  # type: ignore[call-arg]
