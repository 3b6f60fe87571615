"""`tune`: check everything, open the storage, assemble the data, run the workers, summarise.

The only room of activelearn that imports Optuna is this package (activelearn.studies.tuning).
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import optuna
import sqlalchemy
from optuna.trial import FrozenTrial

from activelearn.config import CampaignConfig
from activelearn.errors import ActiveLearnError, InputError
from activelearn.studies.tuning.data import Progress, collect_dataset, content_hash, load_dataset, split_data
from activelearn.studies.tuning.report import TuningResult, summarise
from activelearn.studies.tuning.space import PRUNERS, describe_space, space_signature
from activelearn.studies.tuning.storage import DEFAULT_STORAGE, fail_silent_trials, open_storage, redact
from activelearn.studies.tuning.workers import Job, Supervision, close_lost_run, run_processes, run_worker

OBJECTIVES: tuple[str, ...] = ("nll", "rmse")


class TuningError(ActiveLearnError):
    """A study could not run: incompatible existing study, failed workers or no completed trial."""


class TuningInterrupted(ActiveLearnError):
    """The user stopped the study; finished trials stay in the storage and the study can continue."""


def parse_objectives(text: str | Sequence[str]) -> tuple[str, ...]:
    """`nll` or `nll,rmse` → a tuple of objective names (NLL always first)."""
    names = tuple(s.strip() for s in (text.split(",") if isinstance(text, str) else text) if s.strip())
    if names not in (("nll",), ("nll", "rmse")):
        raise InputError("--objectives", text, "must be 'nll' or 'nll,rmse'")
    return names



def check_study(study: optuna.Study, directions: int, space: str, data: str) -> None:
    """Refuse to continue a study whose objectives, search space or dataset differ."""
    if len(study.directions) != directions:
        raise InputError(
            "--objectives", directions,
            f"study {study.study_name!r} has {len(study.directions)} objective(s); use another --study-name",
        )  # fmt: skip
    attrs = study.user_attrs
    if attrs.get("space", space) != space:
        raise InputError(
            "tuning.space",
            study.study_name,
            "the study was created with another search space; use another --study-name",
        )
    if attrs.get("dataset", data) != data:
        raise InputError(
            "--data",
            study.study_name,
            "the study was created on other data or another split; use another --study-name",
        )



def tune(
    cfg: CampaignConfig,
    *,
    n_trials: int,
    storage: str = DEFAULT_STORAGE,
    study_name: str | None = None,
    workers: int = 1,
    timeout: float | None = None,
    data: Sequence[str | Path] | None = None,
    objectives: str | Sequence[str] = "nll",
    pruner: str = "median",
    seed: int | None = None,
    out: str | Path | None = None,
    tracking: bool = True,
    enqueue: Sequence[Mapping[str, Any]] = (),
    progress: Progress | None = None,
) -> TuningResult:
    """Run (or continue) an Optuna study over the config's search space and add `n_trials` trials.

    Everything is checked before anything is created: arguments, data files, then the storage
    (connect timeout), then simulated data. `workers` > 1 runs that many worker processes sharing
    the trials; `timeout` (s) stops starting new trials. `enqueue` lists params (Optuna names) to try first.
    The best params go to `out` (default `<output_dir>/tuning/<study>/best.toml`) with the figures.
    """
    emit = progress or (lambda event: None)
    objectives = parse_objectives(objectives)
    multi = len(objectives) > 1
    if n_trials < 1:
        raise InputError("--n-trials", n_trials, "must be at least 1")
    if workers < 1:
        raise InputError("--workers", workers, "must be at least 1")
    if timeout is not None and not timeout > 0:
        raise InputError("--timeout", timeout, "must be > 0 seconds")
    if pruner not in PRUNERS:
        raise InputError("--pruner", pruner, f"choose from {', '.join(PRUNERS)}")
    if len(enqueue) > n_trials:
        raise InputError("enqueue", len(enqueue), f"more enqueued trials than --n-trials ({n_trials})")
    seed = cfg.seed if seed is None else seed
    if seed < 0:
        raise InputError("--seed", seed, "must be >= 0")
    for path in data or ():
        if not Path(path).is_file():
            raise InputError("--data", str(path), "no such file")
    study_name = study_name or cfg.name
    workers = min(workers, n_trials)
    notes: list[str] = []
    if multi and pruner != "none":
        notes.append(
            "multi-objective study: pruning is disabled (Optuna cannot prune multi-objective studies)"
        )
        emit({"event": "note", "message": notes[-1]})
    optuna.logging.set_verbosity(optuna.logging.ERROR)

    if tracking and cfg.tracking.enabled:
        from activelearn.studies.tracking import check_server

        check_server(cfg.tracking.uri)  # before anything is simulated or created
    # Data files are read before the storage is opened (which creates a SQLite file): a malformed file
    # then leaves nothing behind. Simulated data come after it, so an unreachable server fails first.
    dataset = load_dataset(data, cfg) if data else None
    rdb = open_storage(storage, cfg.tuning)
    if dataset is None:
        dataset = collect_dataset(cfg, progress=progress)
    split = split_data(dataset, cfg.tuning.val_fraction, cfg.seed)
    space = space_signature(cfg.tuning.space)
    data_signature = content_hash({"data": dataset.key, "val": split.val_points})
    directions = ["minimize"] * len(objectives)
    try:
        existing: optuna.Study | None = optuna.load_study(study_name=study_name, storage=rdb)
    except KeyError:
        existing = None
    if existing is not None:
        check_study(existing, len(directions), space, data_signature)
    n_existing = len(existing.trials) if existing is not None else 0

    tracker, parent_run_id = None, None
    if tracking and cfg.tracking.enabled:
        from activelearn.studies.tracking import Tracker

        tracker = Tracker(cfg.tracking.uri, cfg.tracking.experiment)
        # One parent run per call: a resumed study gets a new parent run with the same study tag,
        # since each call has its own settings (trials, workers, pruner) and its own trial runs.
        parent_run_id = tracker.start_run(
            f"tune-{study_name}",
            tags={"kind": "tuning", "optuna.study": study_name, "optuna.storage": redact(storage),
                  "resumed": str(existing is not None)},
        )  # fmt: skip
        tracker.log_params(parent_run_id, {
            "config": cfg.name, "study": study_name, "storage": redact(storage), "n_trials": n_trials,
            "workers": workers, "timeout": timeout, "objectives": ",".join(objectives),
            "pruner": "none" if multi else pruner, "seed": seed, "data": dataset.source[:500],
            **split.describe(), "val_fraction": cfg.tuning.val_fraction,
            "space": describe_space(cfg.tuning.space),
        })  # fmt: skip
    try:
        study = optuna.create_study(
            storage=rdb, study_name=study_name, directions=directions, load_if_exists=True
        )
        if existing is None:
            study.set_user_attr("space", space)
            study.set_user_attr("dataset", data_signature)
            study.set_user_attr("config", cfg.name)
            study.set_user_attr("objectives", list(objectives))
        for params in enqueue:
            study.enqueue_trial(dict(params), skip_if_exists=False)
        silent = fail_silent_trials(study, rdb, "its machine was lost before the trial's first heartbeat")
        for number in silent:
            notes.append(f"trial {number} was lost before its first heartbeat: marked FAIL and queued again")
            emit({"event": "warning", "message": notes[-1]})

        job = Job(
            study_name=study_name, storage_url=storage, cfg=cfg, tuning=cfg.tuning, split=split,
            objectives=objectives, pruner=pruner, seed=seed, n_existing=n_existing,
            run_token=uuid.uuid4().hex, parent_run_id=parent_run_id,
            tracking=(cfg.tracking.uri, cfg.tracking.experiment) if tracker is not None else None,
            deadline=None if timeout is None else time.time() + timeout,
        )  # fmt: skip
        emit({"event": "start", "study": study_name, "existing_trials": n_existing, **split.describe()})

        def on_lost(trial: FrozenTrial) -> None:
            if tracker is not None:
                close_lost_run(tracker, job.run_token, trial)

        started = time.perf_counter()
        if workers == 1:
            remaining = [n_trials]

            def take() -> bool:
                if job.deadline is not None and time.time() >= job.deadline:
                    return False
                remaining[0] -= 1
                return remaining[0] >= 0

            seen = Supervision()
            try:
                run_worker(job, 0, take, emit)
            except KeyboardInterrupt:
                raise
            except (ActiveLearnError, sqlalchemy.exc.SQLAlchemyError) as exc:
                seen.errors.append(f"{type(exc).__name__}: {exc}")
        else:
            seen = run_processes(job, workers, n_trials, emit, on_lost)
        wall = time.perf_counter() - started
        if seen.errors:
            raise TuningError("; ".join(seen.errors))
        result = summarise(study, job, tracker, out, wall, notes, seen)
    except KeyboardInterrupt:
        if tracker is not None and parent_run_id is not None:
            tracker.end_run(parent_run_id, "KILLED")
        raise TuningInterrupted(
            f"study {study_name!r} stopped; run the same command to continue it"
        ) from None
    except BaseException:
        if tracker is not None and parent_run_id is not None:
            tracker.end_run(parent_run_id, "FAILED")
        raise
    if tracker is not None and parent_run_id is not None:
        tracker.end_run(parent_run_id, "FINISHED")
    return result
