"""The search space: what a trial samples (model and training values, the architecture string), how it
is described and compared between runs, and the sampler and pruner that search it."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
import optuna

from activelearn.config import (
    OPTIONAL_SPACE_PARAMS,
    SPACE_PARAMS,
    CampaignConfig,
    ModelConfig,
    Range,
    SearchSpace,
    TrainingConfig,
    TuningConfig,
)

# Params of the [model] and [training] tables a trial sets (the rest come from the config).
MODEL_KEYS: tuple[str, ...] = (
    "arch", "activation", "posterior", "kl", "prior_scale", "hidden_size",
    "correction", "correction_inputs", "correction_symmetry", "residual_bound",
)  # fmt: skip

TRAINING_KEYS: tuple[str, ...] = ("lr", "epochs", "batch_size", "optimizer", "loss")
PRUNERS: tuple[str, ...] = ("median", "hyperband", "none")


def _suggest(trial: optuna.Trial, name: str, spec: Any, kind: str) -> Any:
    """Sample one parameter from its spec: a Range, a list of choices, or a fixed value."""
    if isinstance(spec, Range):
        if kind == "int":
            step = int(spec.step or 1)
            return trial.suggest_int(name, int(spec.low), int(spec.high), step=step, log=spec.log)
        return trial.suggest_float(name, float(spec.low), float(spec.high), step=spec.step, log=spec.log)
    if isinstance(spec, list):
        return trial.suggest_categorical(name, spec)
    return spec


def sample_params(trial: optuna.Trial, space: SearchSpace) -> tuple[dict[str, Any], dict[str, Any]]:
    """Draw one configuration: the [model] and [training] values a trial trains with.

    The architecture is a spec string built from `n_layers` hidden layers, each variational (`V`)
    or dense (`D`) with its width, and the head token (`V` or `D`), e.g. `D32-D32-V16-V`.
    """

    def draw(key: str, name: str | None = None) -> Any:
        return _suggest(trial, name or key, getattr(space, key), SPACE_PARAMS[key][0])

    training = {k: draw(k) for k in TRAINING_KEYS}
    # unset optional keys (the physics correction's) keep the config's [model] values
    model = {k: draw(k) for k in MODEL_KEYS if k != "arch" and getattr(space, k) is not None}
    tokens = []
    for i in range(draw("n_layers")):
        if draw("variational", f"variational_{i}"):
            tokens.append(f"V{draw('variational_width', f'variational_width_{i}')}")
        else:
            tokens.append(f"D{draw('width', f'width_{i}')}")
    tokens.append("V" if draw("variational_head") else "D")
    model["arch"] = "-".join(tokens)
    return {k: model[k] for k in MODEL_KEYS if k in model}, training


def max_epochs(space: SearchSpace) -> int:
    """The largest number of epochs a trial can run (Hyperband's maximum resource)."""
    spec = space.epochs
    if isinstance(spec, Range):
        return int(spec.high)
    return int(max(spec)) if isinstance(spec, list) else int(spec)


def space_signature(space: SearchSpace) -> str:
    """The search space as canonical JSON (stored with the study: a study continues on the same space)."""
    # Unset optional keys are left out, so a study stored before they existed continues.
    dumped = space.model_dump(mode="json")
    dumped = {k: v for k, v in dumped.items() if v is not None or k not in OPTIONAL_SPACE_PARAMS}
    return json.dumps(dumped, sort_keys=True)


def describe_space(space: SearchSpace) -> dict[str, str]:
    """Human-readable form of every parameter's spec (for MLflow params and tables)."""
    out = {}
    for name, spec in space.model_dump().items():
        if spec is None:  # an unset optional key: the config's value
            continue
        if isinstance(spec, dict):
            text = f"{spec['low']:g}..{spec['high']:g}"
            text += " log" if spec["log"] else (f" step {spec['step']:g}" if spec["step"] else "")
        elif isinstance(spec, list):
            text = "{" + ", ".join(map(str, spec)) + "}"
        else:
            text = str(spec)
        out[name] = text
    return out


def trial_configs(
    cfg: CampaignConfig, model: Mapping[str, Any], training: Mapping[str, Any]
) -> tuple[ModelConfig, TrainingConfig]:
    """The config's [model]/[training] with a trial's values merged in, validated."""
    model_cfg = ModelConfig.model_validate({**cfg.model.model_dump(), **model})
    # Trials train eagerly (each is a new architecture) and skip recalibration: the objective is
    # measured before it, and fitting it on the validation set would only cost time.
    training_cfg = TrainingConfig.model_validate(
        {**cfg.training.model_dump(), **training, "compile": cfg.tuning.compile, "recalibrate": "none"}
    )
    return model_cfg, training_cfg


def make_pruner(name: str, tuning: TuningConfig, multi_objective: bool) -> optuna.pruners.BasePruner:
    """The pruner a `--pruner` name asks for (none for multi-objective studies: Optuna cannot prune them)."""
    if multi_objective or name == "none":
        return optuna.pruners.NopPruner()
    if name == "hyperband":
        return optuna.pruners.HyperbandPruner(
            min_resource=min(tuning.hyperband_min_epochs, max_epochs(tuning.space)),
            max_resource=max_epochs(tuning.space),
        )
    return optuna.pruners.MedianPruner(
        n_startup_trials=tuning.pruner_startup_trials, n_warmup_steps=tuning.pruner_warmup_epochs
    )


def worker_seed(seed: int, n_existing: int, worker: int) -> int:
    """Sampler seed of one worker: fixed by the seed, the study's trial count at start and the index.

    Same seed and storage state → same suggestions (one worker); a resumed study does not replay
    the random start-up trials of its first run.
    """
    return int(np.random.SeedSequence([seed, n_existing, worker]).generate_state(1)[0])


def make_sampler(
    tuning: TuningConfig, seed: int, n_existing: int, worker: int
) -> optuna.samplers.BaseSampler:
    """One worker's seeded TPE sampler."""
    return optuna.samplers.TPESampler(
        seed=worker_seed(seed, n_existing, worker),
        n_startup_trials=tuning.sampler_startup_trials,
        constant_liar=True,  # workers running side by side avoid proposing the same point
    )
