"""Hyperparameter tuning: Optuna studies over the model and training config, tracked in MLflow.

The only module of activelearn that imports Optuna. A study minimises the validation NLL (optionally
also the RMSE) of a model trained on one dataset, split by whole operating points. Storage is any
SQLAlchemy URL Optuna's RDBStorage accepts: a SQLite file for one machine, PostgreSQL for workers on
many. `tune` runs K worker processes against one storage; a shared ticket counter makes the run add
exactly `n_trials` finished trials (complete, pruned or failed) however the work is spread.
MLflow gets one parent run per `tune` call and one nested run per trial (params, per-epoch curve,
final metrics, state); the best parameters are written as a `--params` TOML snippet.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import multiprocessing
import queue as queue_module
import tempfile
import time
import uuid
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import pandas as pd
import sqlalchemy
from optuna.trial import FrozenTrial, TrialState

from activelearn.config import (
    SPACE_PARAMS,
    CampaignConfig,
    ModelConfig,
    Range,
    SearchSpace,
    TrainingConfig,
    TuningConfig,
)
from activelearn.data import atomic_write_bytes, read_autodrive_log, read_table, write_table
from activelearn.errors import ActiveLearnError, DataFormatError, InputError
from activelearn.loop.collection import (
    SimulationCache,
    arrays,
    noisy_logs,
    simulator_fingerprint,
    training_rows,
)
from activelearn.loop.pool import pool_maneuvers
from activelearn.numerics.models import build_model
from activelearn.numerics.training import fit

DEFAULT_STORAGE = "sqlite:///mlruns/optuna.db"
OBJECTIVES: tuple[str, ...] = ("nll", "rmse")
PRUNERS: tuple[str, ...] = ("median", "hyperband", "none")
CONNECT_TIMEOUT = 5  # s: an unreachable database server fails fast instead of hanging
# Exceptions that fail one trial (recorded as FAIL) without stopping the study: numerical trouble
# of an absurd configuration. Anything else (a lost storage, a bug) stops the worker.
TRIAL_ERRORS: tuple[type[Exception], ...] = (ArithmeticError, RuntimeError, ValueError)
# Params of the [model] and [training] tables a trial sets (the rest come from the config).
MODEL_KEYS: tuple[str, ...] = ("arch", "activation", "posterior", "kl", "prior_scale")
TRAINING_KEYS: tuple[str, ...] = ("lr", "epochs", "batch_size", "optimizer", "loss")
_DATA_VERSION = 1  # bump when the way a dataset is assembled changes (invalidates cached tables)

Progress = Callable[[dict[str, Any]], None]


class TuningError(ActiveLearnError):
    """A study could not run: incompatible existing study, failed workers or no completed trial."""


class TuningInterrupted(ActiveLearnError):
    """The user stopped the study; finished trials stay in the storage and the study can continue."""


# ------------------------------------------------------------------------------------------ data
@dataclass(frozen=True)
class TuningData:
    """Samples of a study: inputs, targets and the operating point (group) of every row."""

    x: np.ndarray
    y: np.ndarray
    groups: np.ndarray  # operating-point key per row (str)
    key: str  # content hash: a study only continues on the same data
    source: str  # where the rows came from, for humans

    @property
    def n_groups(self) -> int:
        """Number of distinct operating points."""
        return len(np.unique(self.groups))


@dataclass(frozen=True)
class Split:
    """Training and validation rows; no operating point appears on both sides."""

    x_train: np.ndarray
    y_train: np.ndarray
    groups_train: np.ndarray  # integer group ids
    x_val: np.ndarray
    y_val: np.ndarray
    groups_val: np.ndarray
    val_points: tuple[str, ...]  # the held-out operating points

    def describe(self) -> dict[str, int]:
        """Row and operating-point counts of both sides."""
        return {
            "train_rows": len(self.x_train),
            "val_rows": len(self.x_val),
            "train_points": len(np.unique(self.groups_train)),
            "val_points": len(self.val_points),
        }


def operating_points(rows: pd.DataFrame) -> np.ndarray:
    """Operating-point key of every row: maneuver kind, direction, throttle and steering amplitude.

    Logs without a known direction (AutoDRIVE imports) take it from the sign of their median steering,
    so cw and ccw runs at the same amplitude stay distinct points.
    """
    direction = rows["direction"].astype(str).to_numpy(copy=True)
    unknown = ~np.isin(direction, ("ccw", "cw"))
    if unknown.any():
        sign = rows.groupby("run_id")["steering"].transform("median").to_numpy()
        direction[unknown] = np.where(sign[unknown] < 0, "cw", "ccw")
    parts = [
        rows["maneuver"].astype(str).to_numpy(),
        direction,
        np.char.mod("%.4f", rows["op_throttle"].to_numpy(dtype=float)),
        np.char.mod("%.4f", rows["op_steering"].to_numpy(dtype=float)),
    ]
    return np.array(["|".join(p) for p in zip(*parts, strict=True)], dtype=object)


def group_split(groups: np.ndarray, val_fraction: float, seed: int) -> np.ndarray:
    """Boolean mask of validation rows: a seeded share of whole groups (never single rows)."""
    names = np.unique(groups)
    if len(names) < 2:
        raise InputError("data", len(names), "needs at least 2 operating points to hold one out")
    n_val = min(max(1, round(val_fraction * len(names))), len(names) - 1)
    held = np.random.default_rng(seed).permutation(len(names))[:n_val]
    return np.isin(groups, names[held])


def split_data(data: TuningData, val_fraction: float, seed: int) -> Split:
    """Hold out whole operating points for validation (seeded)."""
    is_val = group_split(data.groups, val_fraction, seed)
    _, codes = np.unique(data.groups, return_inverse=True)
    return Split(
        x_train=data.x[~is_val],
        y_train=data.y[~is_val],
        groups_train=codes[~is_val],
        x_val=data.x[is_val],
        y_val=data.y[is_val],
        groups_val=codes[is_val],
        val_points=tuple(sorted(np.unique(data.groups[is_val]))),
    )


def _hash(payload: Any) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _assemble(rows: pd.DataFrame, cfg: CampaignConfig, key: str, source: str) -> TuningData:
    x, y = arrays(rows, cfg.data)
    return TuningData(x=x, y=y, groups=rows["point"].to_numpy(dtype=object), key=key, source=source)


def dataset_key(cfg: CampaignConfig) -> str:
    """Hash of everything that determines the data collected from a config's pool."""
    return _hash(
        {
            "version": _DATA_VERSION,
            "simulator": simulator_fingerprint(),
            "seed": cfg.seed,
            "pool": cfg.pool.model_dump(mode="json"),
            "simulation": cfg.simulation.model_dump(mode="json"),
            "data": cfg.data.model_dump(mode="json"),
        }
    )


def collect_dataset(
    cfg: CampaignConfig, cache_dir: str | Path | None = None, progress: Progress | None = None
) -> TuningData:
    """All of the config's pool maneuvers, simulated with its noise and seed, as training rows.

    Cached as Parquet under `<output_dir>/cache` keyed by `dataset_key`; the noise-free logs go
    through the same `SimulationCache` as campaigns, so tuning and campaigns simulate each maneuver once.
    """
    root = Path(cache_dir) if cache_dir is not None else Path(cfg.output_dir) / "cache"
    key = dataset_key(cfg)
    path = root / f"tuning-data-{key}.parquet"
    if path.exists():
        return _assemble(read_table(path), cfg, key, str(path))
    maneuvers = pool_maneuvers(cfg.pool)

    def sim_progress(done: int, total: int) -> None:
        if progress is not None:
            progress({"event": "sim_progress", "done": done, "total": total})

    clean = SimulationCache(root, cfg.simulation).get(maneuvers, progress=sim_progress)
    frames = noisy_logs(clean, maneuvers, cfg.simulation.noise, cfg.seed)
    rows = pd.concat([training_rows(f, cfg.data) for f in frames], ignore_index=True)
    rows["point"] = operating_points(rows)
    write_table(rows, path)
    return _assemble(rows, cfg, key, str(path))


_REQUIRED_COLUMNS = ("time", "throttle", "steering", "speed", "angZ")


def load_dataset(paths: Sequence[str | Path], cfg: CampaignConfig) -> TuningData:
    """Rows from sample tables (.parquet, or .csv as written by `simulate`) or AutoDRIVE CSV logs."""
    if not paths:
        raise InputError("--data", [], "give at least one file")
    parts, digest = [], hashlib.sha256()
    for index, raw in enumerate(paths):
        path = Path(raw)
        if not path.is_file():
            raise InputError("--data", str(path), "no such file")
        suffix = path.suffix.lower()
        if suffix == ".parquet":
            table = read_table(path)
        elif suffix == ".csv":
            table = read_autodrive_log(path)
        else:
            raise InputError("--data", str(path), "must be a .parquet table or a .csv log")
        missing = [c for c in _REQUIRED_COLUMNS if c not in table.columns]
        if missing:
            raise DataFormatError(f"{path}: lacks column(s) {', '.join(missing)}")
        table = table.copy()
        for column, default in (("maneuver", "unknown"), ("direction", "unknown"), ("run_id", path.stem)):
            if column not in table.columns:
                table[column] = default
        for column, values in (("op_throttle", table["throttle"]), ("op_steering", table["steering"].abs())):
            if column not in table.columns:
                table[column] = table.groupby("run_id")[values.name].transform("median")
        table["run_id"] = f"{index}:" + table["run_id"].astype(str)
        for _, run in table.groupby("run_id", sort=False):
            parts.append(training_rows(run, cfg.data))
        digest.update(path.read_bytes())
    rows = pd.concat(parts, ignore_index=True)
    if rows.empty:
        raise InputError("--data", [str(p) for p in paths], "no rows left after data.skip_seconds/stride")
    rows["point"] = operating_points(rows)
    key = _hash(
        {"version": _DATA_VERSION, "files": digest.hexdigest(), "data": cfg.data.model_dump(mode="json")}
    )
    return _assemble(rows, cfg, key, ", ".join(str(p) for p in paths))


# --------------------------------------------------------------------------------- search space
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
    model = {k: draw(k) for k in MODEL_KEYS if k != "arch"}
    tokens = []
    for i in range(draw("n_layers")):
        if draw("variational", f"variational_{i}"):
            tokens.append(f"V{draw('variational_width', f'variational_width_{i}')}")
        else:
            tokens.append(f"D{draw('width', f'width_{i}')}")
    tokens.append("V" if draw("variational_head") else "D")
    model["arch"] = "-".join(tokens)
    return {k: model[k] for k in MODEL_KEYS}, training


def max_epochs(space: SearchSpace) -> int:
    """The largest number of epochs a trial can run (Hyperband's maximum resource)."""
    spec = space.epochs
    if isinstance(spec, Range):
        return int(spec.high)
    return int(max(spec)) if isinstance(spec, list) else int(spec)


def space_signature(space: SearchSpace) -> str:
    """The search space as canonical JSON (stored with the study: a study continues on the same space)."""
    return json.dumps(space.model_dump(mode="json"), sort_keys=True)


def describe_space(space: SearchSpace) -> dict[str, str]:
    """Human-readable form of every parameter's spec (for MLflow params and tables)."""
    out = {}
    for name, spec in space.model_dump().items():
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


# -------------------------------------------------------------------------------------- storage
def redact(url: str) -> str:
    """The storage URL with its password hidden (safe to print, tag and log)."""
    try:
        return sqlalchemy.engine.make_url(url).render_as_string(hide_password=True)
    except sqlalchemy.exc.ArgumentError:
        return url


def storage_url(url: str) -> str:
    """Check a storage URL and name its driver: a bare postgresql:// means psycopg2.

    SQLAlchemy 2.1 maps a bare postgresql:// to psycopg 3; this project ships psycopg2-binary.
    """
    try:
        parsed = sqlalchemy.engine.make_url(url)
    except sqlalchemy.exc.ArgumentError:
        raise InputError(
            "--storage", url, "not a database URL (e.g. sqlite:///mlruns/optuna.db, postgresql://u:p@host/db)"
        ) from None
    if parsed.drivername == "postgresql":
        return parsed.set(drivername="postgresql+psycopg2").render_as_string(hide_password=False)
    return url


def open_storage(url: str, connect_timeout: float = CONNECT_TIMEOUT) -> optuna.storages.RDBStorage:
    """Open (creating its tables if needed) an Optuna RDB storage; fail fast with a clear error.

    SQLite: the parent directory is created and writers wait up to 30 s for the file lock (several
    local workers). PostgreSQL: a connect timeout, so an unreachable server fails within seconds.
    """
    url = storage_url(url)
    parsed = sqlalchemy.engine.make_url(url)
    shown = redact(url)
    backend = parsed.get_backend_name()
    engine_kwargs: dict[str, Any] = {}
    if backend == "sqlite":
        database = parsed.database or ""
        if database and database != ":memory:" and not database.startswith("file:"):
            try:
                Path(database).parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise InputError("--storage", shown, f"cannot create the database directory: {exc}") from None
        engine_kwargs = {"connect_args": {"timeout": 30}}
    elif backend == "postgresql":
        engine_kwargs = {
            "connect_args": {"connect_timeout": max(1, round(connect_timeout))},
            "pool_pre_ping": True,
        }
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return optuna.storages.RDBStorage(url, engine_kwargs=engine_kwargs)
    except Exception as exc:  # driver errors come in many types (OperationalError, ImportError, ...)
        reason = str(getattr(exc, "orig", None) or exc).strip().splitlines()
        raise InputError(
            "--storage", shown, f"cannot open the Optuna storage: {reason[0] if reason else exc}"
        ) from None


def _pruner(name: str, tuning: TuningConfig, multi_objective: bool) -> optuna.pruners.BasePruner:
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


# ---------------------------------------------------------------------------------------- study
@dataclass(frozen=True)
class _Job:
    """Everything a worker process needs (pickled to spawned processes)."""

    study_name: str
    storage_url: str
    cfg: CampaignConfig
    tuning: TuningConfig
    # The data travel in a file to spawned workers (`split_file`): the pickled job stays small, so
    # starting a worker never blocks on a pipe the worker is not reading yet (or never will).
    split: Split | None
    objectives: tuple[str, ...]
    pruner: str
    seed: int
    n_existing: int
    run_token: str
    tracking: tuple[str, str] | None
    parent_run_id: str | None
    deadline: float | None  # wall-clock time.time() after which no trial starts
    split_file: str | None = None

    def data(self) -> Split:
        """The training/validation split, from the job itself or from its file."""
        if self.split is not None:
            return self.split
        assert self.split_file is not None
        with np.load(self.split_file, allow_pickle=False) as npz:
            loaded = {k: npz[k] for k in npz.files}
        return Split(**{k: v for k, v in loaded.items() if k != "val_points"},
                     val_points=tuple(loaded["val_points"].tolist()))  # fmt: skip


class _Objective:
    """Train one sampled configuration; report val NLL per epoch; log the trial as a nested MLflow run."""

    def __init__(self, job: _Job, tracker: Any, worker: int) -> None:
        self.job, self.tracker, self.worker = job, tracker, worker
        self.split = job.data()

    def __call__(self, trial: optuna.Trial) -> float | tuple[float, ...]:
        job, split = self.job, self.split
        multi = len(job.objectives) > 1
        model, training = sample_params(trial, job.tuning.space)
        trial.set_user_attr("model", model)
        trial.set_user_attr("training", training)
        trial.set_user_attr("run", job.run_token)
        trial.set_user_attr("worker", self.worker)
        run_id = None
        if self.tracker is not None:
            run_id = self.tracker.start_run(
                f"trial-{trial.number}",
                parent_run_id=job.parent_run_id,
                tags={
                    "optuna.study": job.study_name,
                    "optuna.trial": str(trial.number),
                    "kind": "tuning-trial",
                },
            )
            trial.set_user_attr("mlflow_run_id", run_id)
            self.tracker.log_params(
                run_id, {"model": model, "training": training, "trial": trial.number, "worker": self.worker}
            )
        curve: list[tuple[int, dict[str, float]]] = []

        def callback(epoch: int, metrics: dict[str, float]) -> None:
            curve.append(
                (epoch, {k: metrics[k] for k in ("val_nll", "val_rmse", "train_loss") if k in metrics})
            )
            if not multi:  # Optuna cannot prune multi-objective studies
                trial.report(metrics["val_nll"], epoch)
                if trial.should_prune():
                    raise optuna.TrialPruned(f"validation NLL {metrics['val_nll']:.4g} at epoch {epoch}")

        state, started, final = "FAIL", time.perf_counter(), {}
        try:
            model_cfg, training_cfg = trial_configs(job.cfg, model, training)
            net = build_model(model_cfg, seed=job.seed)
            history = fit(
                net, split.x_train, split.y_train, training_cfg,
                x_val=split.x_val, y_val=split.y_val, groups=split.groups_train,
                groups_val=split.groups_val, seed=job.seed, callback=callback,
            )  # fmt: skip
            best = history.best_epoch
            # A diverged fit has no finite NLL: +inf ranks it last (NaN would mark the trial FAIL).
            values = [_finite_or_inf(history.val_nll[best]), _finite_or_inf(history.val_rmse[best])]
            trial.set_user_attr("best_epoch", best)
            trial.set_user_attr("epochs_run", history.n_epochs)
            final = {"objective_nll": values[0], "objective_rmse": values[1], "best_epoch": best}
            state = "COMPLETE"
        except optuna.TrialPruned:
            state = "PRUNED"
            raise
        except Exception as exc:
            trial.set_user_attr("fail_reason", f"{type(exc).__name__}: {exc}"[:500])
            raise
        finally:
            if self.tracker is not None and run_id is not None:
                final.update({"epochs_run": len(curve), "fit_seconds": time.perf_counter() - started})
                self.tracker.log_metric_series(run_id, [*curve, (len(curve), final)])
                self.tracker.set_tags(run_id, {"optuna.state": state, "arch": model["arch"]})
                self.tracker.end_run(run_id, "FAILED" if state == "FAIL" else "FINISHED")
        return tuple(values) if multi else values[0]


def _finite_or_inf(value: float) -> float:
    return float(value) if math.isfinite(value) else math.inf


def _trial_event(trial: FrozenTrial, worker: int) -> dict[str, Any]:
    return {
        "event": "trial",
        "number": trial.number,
        "state": trial.state.name,
        "values": list(trial.values) if trial.values is not None else None,
        "worker": worker,
        "arch": trial.user_attrs.get("model", {}).get("arch"),
        "fail_reason": trial.user_attrs.get("fail_reason"),
        "seconds": trial.duration.total_seconds() if trial.duration is not None else None,
    }


def _run_worker(job: _Job, worker: int, take: Callable[[], bool], emit: Progress) -> None:
    """One worker: load the study with its own seeded sampler and run trials while tickets last."""
    optuna.logging.set_verbosity(optuna.logging.ERROR)  # trial results reach the CLI as events
    multi = len(job.objectives) > 1
    sampler = optuna.samplers.TPESampler(
        seed=worker_seed(job.seed, job.n_existing, worker),
        n_startup_trials=job.tuning.sampler_startup_trials,
        constant_liar=True,  # workers running side by side avoid proposing the same point
    )
    study = optuna.load_study(
        study_name=job.study_name,
        storage=open_storage(job.storage_url),
        sampler=sampler,
        pruner=_pruner(job.pruner, job.tuning, multi),
    )
    tracker = None
    if job.tracking is not None:
        from activelearn.studies.tracking import Tracker

        tracker = Tracker(*job.tracking)
    objective = _Objective(job, tracker, worker)

    def done(_: optuna.Study, trial: FrozenTrial) -> None:
        emit(_trial_event(trial, worker))

    while take():
        study.optimize(objective, n_trials=1, catch=TRIAL_ERRORS, callbacks=[done], gc_after_trial=False)


def _worker_main(job: _Job, worker: int, tickets: Any, events: Any) -> None:
    """Entry point of a spawned worker process: tickets come from a counter shared by all workers."""
    import torch

    torch.set_num_threads(1)  # one busy process per core: intra-op threads would only fight

    def take() -> bool:
        if job.deadline is not None and time.time() >= job.deadline:
            return False
        with tickets.get_lock():
            if tickets.value <= 0:
                return False
            tickets.value -= 1
            return True

    try:
        _run_worker(job, worker, take, events.put)
    except KeyboardInterrupt:
        events.put({"event": "worker_error", "worker": worker, "message": "interrupted"})
        return
    except BaseException as exc:
        events.put({"event": "worker_error", "worker": worker, "message": f"{type(exc).__name__}: {exc}"})
        return
    events.put({"event": "worker_done", "worker": worker})


def _run_processes(job: _Job, workers: int, n_trials: int, progress: Progress) -> list[str]:
    """Run `workers` spawned processes sharing `n_trials` tickets; return the workers' error messages."""
    assert job.split is not None
    with tempfile.TemporaryDirectory(prefix="activelearn-tune-") as tmp:
        split_file = Path(tmp) / "split.npz"
        split = dataclasses.asdict(job.split)
        split["val_points"] = np.array(split["val_points"], dtype=str)
        np.savez(split_file, **split)
        job = dataclasses.replace(job, split=None, split_file=str(split_file))
        return _supervise(job, workers, n_trials, progress)


def _supervise(job: _Job, workers: int, n_trials: int, progress: Progress) -> list[str]:
    """Start the worker processes, relay their events, and collect their errors."""
    ctx = multiprocessing.get_context("spawn")
    tickets = ctx.Value("i", n_trials)
    events = ctx.Queue()
    procs = [
        ctx.Process(target=_worker_main, args=(job, i, tickets, events), name=f"tune-{i}")
        for i in range(workers)
    ]
    for p in procs:
        p.start()
    pending, errors = set(range(workers)), []

    def handle(event: dict[str, Any]) -> None:
        if event["event"] == "worker_done":
            pending.discard(event["worker"])
        elif event["event"] == "worker_error":
            pending.discard(event["worker"])
            errors.append(f"worker {event['worker']}: {event['message']}")
        else:
            progress(event)

    try:
        while pending:
            try:
                handle(events.get(timeout=0.5))
                continue
            except queue_module.Empty:
                pass
            for i in sorted(pending):
                if procs[i].exitcode is not None:  # died without saying so (killed, crashed)
                    try:  # its last words may still be in the pipe
                        while True:
                            handle(events.get(timeout=1.0))
                    except queue_module.Empty:
                        pass
                    if i in pending:
                        pending.discard(i)
                        errors.append(
                            f"worker {i}: exited with code {procs[i].exitcode} (see its traceback; a script "
                            "that runs tune(workers > 1) needs an `if __name__ == '__main__':` guard)"
                        )
    except KeyboardInterrupt:
        with tickets.get_lock():
            tickets.value = 0  # no new trials; running ones end as FAIL in their workers
        raise
    finally:
        for p in procs:
            p.join(timeout=30)
            if p.is_alive():
                p.terminate()
                p.join()
    return errors


@dataclass(frozen=True)
class TuningResult:
    """What a `tune` call did and found."""

    study_name: str
    storage: str  # password hidden
    objectives: tuple[str, ...]
    states: dict[str, int]  # finished trials of this call, by state
    study_trials: int  # finished trials of the whole study
    best: pd.DataFrame  # best trials of the study (the Pareto front when multi-objective)
    best_params: dict[str, dict[str, Any]] | None
    best_values: tuple[float, ...] | None
    best_number: int | None
    best_path: Path | None
    figures: tuple[Path, ...]
    parent_run_id: str | None
    wall_seconds: float  # optimisation only (after the data are ready)
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def n_trials(self) -> int:
        """Finished trials of this call."""
        return sum(self.states.values())

    @property
    def trials_per_minute(self) -> float:
        """Finished trials of this call per minute of optimisation."""
        return 60.0 * self.n_trials / self.wall_seconds if self.wall_seconds > 0 else math.nan


def parse_objectives(text: str | Sequence[str]) -> tuple[str, ...]:
    """`nll` or `nll,rmse` → a tuple of objective names (NLL always first)."""
    names = tuple(s.strip() for s in (text.split(",") if isinstance(text, str) else text) if s.strip())
    if names not in (("nll",), ("nll", "rmse")):
        raise InputError("--objectives", text, "must be 'nll' or 'nll,rmse'")
    return names


def _check_study(study: optuna.Study, directions: int, space: str, data: str) -> None:
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


def best_trials(study: optuna.Study, limit: int = 5) -> list[FrozenTrial]:
    """Best complete trials: lowest NLL first, or the Pareto front (by NLL) when multi-objective."""
    if len(study.directions) > 1:
        front = study.best_trials
        return sorted(front, key=lambda t: t.values[0])
    done = [t for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)) if t.values]
    return sorted(done, key=lambda t: (t.values[0], t.number))[:limit]


def study_trials(storage: str, study_name: str) -> list[dict[str, Any]]:
    """Trials of a stored study as plain dicts, by number (state, values, params, attrs, steps, seconds)."""
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    study = optuna.load_study(study_name=study_name, storage=open_storage(storage))
    return [
        {
            "number": t.number,
            "state": t.state.name,
            "values": list(t.values) if t.values is not None else None,
            "params": dict(t.params),
            "user_attrs": dict(t.user_attrs),
            "last_step": t.last_step,
            "seconds": t.duration.total_seconds() if t.duration is not None else None,
        }
        for t in sorted(study.get_trials(deepcopy=False), key=lambda t: t.number)
    ]


def _best_table(trials: Sequence[FrozenTrial], objectives: Sequence[str]) -> pd.DataFrame:
    rows = []
    for t in trials:
        model, training = t.user_attrs.get("model", {}), t.user_attrs.get("training", {})
        row: dict[str, Any] = {"trial": t.number}
        row.update({f"val_{name}": value for name, value in zip(objectives, t.values, strict=False)})
        row.update({"arch": model.get("arch"), "activation": model.get("activation"),
                    "posterior": model.get("posterior"), "kl": model.get("kl"),
                    "prior_scale": model.get("prior_scale"), "lr": training.get("lr"),
                    "optimizer": training.get("optimizer"), "loss": training.get("loss"),
                    "batch_size": training.get("batch_size"), "epochs": training.get("epochs"),
                    "best_epoch": t.user_attrs.get("best_epoch")})  # fmt: skip
        rows.append(row)
    return pd.DataFrame(rows)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return (
            repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf" if value < 0 else "nan")
        )
    return json.dumps(str(value))


def params_toml(model: Mapping[str, Any], training: Mapping[str, Any], header: Sequence[str] = ()) -> str:
    """A TOML snippet with [model] and [training] tables (what `campaign run --params` merges)."""
    lines = [f"# {h}" for h in header]
    for table, values in (("model", model), ("training", training)):
        lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in values.items()]
    return "\n".join(lines).lstrip("\n") + "\n"


def _figures(study: optuna.Study, directory: Path) -> tuple[list[Path], list[str]]:
    """Optimisation history and parameter importances as PNGs (skipped with a note when impossible)."""
    import matplotlib.pyplot as plt
    from optuna.visualization import matplotlib as ovm

    kwargs: dict[str, Any] = {}
    if len(study.directions) > 1:
        kwargs = {"target": lambda t: t.values[0], "target_name": "validation NLL"}
    else:
        kwargs = {"target_name": "validation NLL"}
    paths, notes = [], []
    for name, plot in (("optimization_history", ovm.plot_optimization_history),
                       ("param_importances", ovm.plot_param_importances)):  # fmt: skip
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # Optuna marks its matplotlib plots experimental
                ax = plot(study, **kwargs)
        except (ValueError, RuntimeError, ZeroDivisionError) as exc:
            notes.append(f"no {name.replace('_', ' ')} figure: {exc}")
            continue
        fig = ax.figure
        fig.set_size_inches(8, 5)
        fig.tight_layout()
        path = directory / f"{name}.png"
        tmp = path.with_name(f".{path.name}.tmp.png")
        fig.savefig(tmp, dpi=110)
        tmp.replace(path)
        plt.close(fig)
        paths.append(path)
    return paths, notes


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
    (connect timeout), then simulated data. `workers` > 1 runs that many spawned processes sharing
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

    # Data files are read before the storage is opened (which creates a SQLite file): a malformed file
    # then leaves nothing behind. Simulated data come after it, so an unreachable server fails first.
    dataset = load_dataset(data, cfg) if data else None
    rdb = open_storage(storage)
    if dataset is None:
        dataset = collect_dataset(cfg, progress=progress)
    split = split_data(dataset, cfg.tuning.val_fraction, cfg.seed)
    space = space_signature(cfg.tuning.space)
    data_signature = _hash({"data": dataset.key, "val": split.val_points})
    directions = ["minimize"] * len(objectives)
    try:
        existing: optuna.Study | None = optuna.load_study(study_name=study_name, storage=rdb)
    except KeyError:
        existing = None
    if existing is not None:
        _check_study(existing, len(directions), space, data_signature)
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

        job = _Job(
            study_name=study_name, storage_url=storage, cfg=cfg, tuning=cfg.tuning, split=split,
            objectives=objectives, pruner=pruner, seed=seed, n_existing=n_existing,
            run_token=uuid.uuid4().hex, parent_run_id=parent_run_id,
            tracking=(cfg.tracking.uri, cfg.tracking.experiment) if tracker is not None else None,
            deadline=None if timeout is None else time.time() + timeout,
        )  # fmt: skip
        emit({"event": "start", "study": study_name, "existing_trials": n_existing, **split.describe()})
        started = time.perf_counter()
        if workers == 1:
            remaining = [n_trials]

            def take() -> bool:
                if job.deadline is not None and time.time() >= job.deadline:
                    return False
                remaining[0] -= 1
                return remaining[0] >= 0

            try:
                _run_worker(job, 0, take, emit)
                errors: list[str] = []
            except KeyboardInterrupt:
                raise
            except (ActiveLearnError, sqlalchemy.exc.SQLAlchemyError) as exc:
                errors = [f"{type(exc).__name__}: {exc}"]
        else:
            errors = _run_processes(job, workers, n_trials, emit)
        wall = time.perf_counter() - started
        if errors:
            raise TuningError("; ".join(errors))
        result = _finish(study, job, tracker, out, wall, notes)
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


def _finish(
    study: optuna.Study, job: _Job, tracker: Any, out: str | Path | None, wall: float, notes: list[str]
) -> TuningResult:
    """Summarise the study: counts, best trials, best.toml, figures; log them to the parent run."""
    finished_states = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
    trials = study.get_trials(deepcopy=False, states=finished_states)
    mine = [t for t in trials if t.user_attrs.get("run") == job.run_token]
    states = {s.name: sum(t.state == s for t in mine) for s in finished_states}
    best = best_trials(study)
    table = _best_table(best, job.objectives)
    out_path = (
        Path(out) if out is not None else Path(job.cfg.output_dir) / "tuning" / job.study_name / "best.toml"
    )
    best_params = best_values = best_number = best_path = None
    figures: list[Path] = []
    if best:
        top = best[0]
        best_params = {"model": dict(top.user_attrs["model"]), "training": dict(top.user_attrs["training"])}
        best_values, best_number = tuple(top.values), top.number
        header = [
            f"Best trial {top.number} of Optuna study {job.study_name!r} ({redact(job.storage_url)}):",
            "validation "
            + ", ".join(f"{n.upper()} {v:.6g}" for n, v in zip(job.objectives, top.values, strict=True)),
            "Use: activelearn campaign run CONFIG --params " + out_path.name,
        ]
        atomic_write_bytes(
            out_path, params_toml(best_params["model"], best_params["training"], header).encode()
        )
        best_path = out_path
        figures, fig_notes = _figures(study, out_path.parent)
        notes.extend(fig_notes)
    else:
        notes.append("no trial completed: no best parameters to write")
    result = TuningResult(
        study_name=job.study_name, storage=redact(job.storage_url), objectives=job.objectives,
        states=states, study_trials=len(trials), best=table, best_params=best_params,
        best_values=best_values, best_number=best_number, best_path=best_path, figures=tuple(figures),
        parent_run_id=job.parent_run_id, wall_seconds=wall, notes=tuple(notes),
    )  # fmt: skip
    if tracker is not None and job.parent_run_id is not None:
        run = job.parent_run_id
        metrics = {f"n_{k.lower()}": float(v) for k, v in states.items()}
        metrics.update({"study_trials": float(len(trials)), "trials_per_minute": result.trials_per_minute})
        if best_values is not None:
            metrics.update({f"best_val_{n}": v for n, v in zip(job.objectives, best_values, strict=True)})
            tracker.set_tags(run, {"best_trial": best_number})
        tracker.log_metrics(run, metrics, step=0)
        for path in [best_path, *figures]:
            if path is not None:
                tracker.log_artifact(run, path)
        if not table.empty:
            tracker.log_text(run, table.to_csv(index=False), "best_trials.csv")
    return result
