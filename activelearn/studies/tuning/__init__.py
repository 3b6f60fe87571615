"""Hyperparameter tuning: Optuna studies over the model and training config, tracked in MLflow.

The only package of activelearn that imports Optuna. A study minimises the validation NLL (optionally
also the RMSE) of a model trained on one dataset, split by whole operating points. One module per job:

- `data`: the tuning dataset (collected from the config's pool and cached, or loaded) and its split;
- `space`: the search space, what a trial samples, the sampler and the pruner;
- `storage`: storage URLs and connections (SQLite, PostgreSQL) with heartbeats, lost trials;
- `workers`: the objective, worker processes, tickets and the supervisor that survives dead workers;
- `report`: best trials, the `--params` TOML, figures and the summary of a call;
- `study`: `tune`, which puts them together.

MLflow gets one parent run per `tune` call and one nested run per trial (params, per-epoch curve,
final metrics, state); the best parameters are written as a `--params` TOML snippet.
"""

from __future__ import annotations

from activelearn.studies.tuning.data import (
    Progress,
    Split,
    TuningData,
    collect_dataset,
    dataset_key,
    group_split,
    load_dataset,
    operating_points,
    split_data,
)
from activelearn.studies.tuning.report import TuningResult, best_trials, params_toml, study_trials
from activelearn.studies.tuning.space import (
    MODEL_KEYS,
    PRUNERS,
    TRAINING_KEYS,
    describe_space,
    max_epochs,
    sample_params,
    space_signature,
    trial_configs,
    worker_seed,
)
from activelearn.studies.tuning.storage import (
    CONNECT_TIMEOUT,
    DEFAULT_STORAGE,
    open_storage,
    redact,
    storage_url,
)
from activelearn.studies.tuning.study import (
    OBJECTIVES,
    TuningError,
    TuningInterrupted,
    parse_objectives,
    tune,
)
from activelearn.studies.tuning.workers import TRIAL_ERRORS

__all__ = [
    "CONNECT_TIMEOUT",
    "DEFAULT_STORAGE",
    "MODEL_KEYS",
    "OBJECTIVES",
    "PRUNERS",
    "TRAINING_KEYS",
    "TRIAL_ERRORS",
    "Progress",
    "Split",
    "TuningData",
    "TuningError",
    "TuningInterrupted",
    "TuningResult",
    "best_trials",
    "collect_dataset",
    "dataset_key",
    "describe_space",
    "group_split",
    "load_dataset",
    "max_epochs",
    "open_storage",
    "operating_points",
    "params_toml",
    "parse_objectives",
    "redact",
    "sample_params",
    "space_signature",
    "split_data",
    "storage_url",
    "study_trials",
    "trial_configs",
    "tune",
    "worker_seed",
]
