"""Save and load models as a config + state-dict file (no pickled code, `weights_only` safe)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from activelearn.config import ModelConfig
from activelearn.data import write_atomically
from activelearn.errors import DataFormatError
from activelearn.numerics.models.base import Model
from activelearn.numerics.models.registry import build_model
from activelearn.numerics.models.residual import ResidualModel

FORMAT_VERSION = 1


def _payload(model: Model | ResidualModel) -> dict[str, Any]:
    if isinstance(model, ResidualModel):
        return {"kind": model.kind, "base": _payload(model.base), "residual": _payload(model.residual)}
    return {
        "kind": model.kind,
        "config": model.config.model_dump(mode="json"),
        "state_dict": {k: v.detach().clone() for k, v in model.state_dict().items()},
    }


def _rebuild(payload: dict[str, Any]) -> Model | ResidualModel:
    if payload.get("kind") == ResidualModel.kind:
        return ResidualModel(_rebuild(payload["base"]), _rebuild(payload["residual"]))  # type: ignore[arg-type]
    model = build_model(ModelConfig(**payload["config"]))  # weights replaced below
    state = payload["state_dict"]
    state.setdefault("fan_scale", torch.tensor(1.0))  # files written before free-run fans were calibrated
    model.load_state_dict(state)
    model.eval()
    return model


def save_model(model: Model | ResidualModel, path: str | Path) -> None:
    """Write the model's config, scalers, epistemic scale and weights to `path` atomically.

    A `ResidualModel` is written as its base and its residual, each in the same form.
    """
    payload = {"format_version": FORMAT_VERSION, **_payload(model)}
    write_atomically(path, lambda tmp: torch.save(payload, tmp))


def load_model(path: str | Path) -> Model | ResidualModel:
    """Rebuild a model written by `save_model`."""
    try:
        payload = torch.load(Path(path), map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise
    except Exception as exc:
        raise DataFormatError(f"{path}: not a saved activelearn model ({exc})") from exc
    if not isinstance(payload, dict) or payload.get("format_version") != FORMAT_VERSION:
        raise DataFormatError(f"{path}: unknown model file format")
    return _rebuild(payload)
