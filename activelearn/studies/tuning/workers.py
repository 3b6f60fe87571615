"""Worker processes of a study: the objective, the trial loop, and the local supervisor.

`tune` adds exactly `n_trials` finished trials however the work is spread and whichever worker dies.
Tickets are what makes it exact: a worker takes one before it starts a trial. Optuna's own
`MaxTrialsCallback` cannot replace them: it counts after a trial ends, so K workers overshoot by up to
K - 1, and it counts the whole study, not this command's share of it. A worker that dies mid-trial
(SIGKILL, the OOM killer) gives its ticket back, its trial is marked FAIL and queued again with the
same parameters (`storage.fail_lost_trial`), and a fresh worker takes its place. Across machines, where
no supervisor sees the death, Optuna's heartbeats do the same after the grace period (and the next
`tune` fails a trial lost before its first heartbeat: `storage.fail_silent_trials`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import math
import os
import queue as queue_module
import signal
import socket
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from optuna.trial import FrozenTrial

from activelearn.config import CampaignConfig, TuningConfig
from activelearn.numerics.models import build_model
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from activelearn.studies.processes import with_environment, worker_context
from activelearn.studies.tuning.data import Progress, Split
from activelearn.studies.tuning.space import make_pruner, make_sampler, sample_params, trial_configs
from activelearn.studies.tuning.storage import (
    await_first_heartbeat,
    fail_lost_trial,
    fail_orphans,
    open_storage,
)

# Exceptions that fail one trial (recorded as FAIL) without stopping the study: numerical trouble
# of an absurd configuration. Anything else (a lost storage, a bug) stops the worker.
TRIAL_ERRORS: tuple[type[Exception], ...] = (ArithmeticError, RuntimeError, ValueError)

# MLflow tag naming the `tune` command (its Job.run_token) that created a trial's run.
RUN_TOKEN_TAG = "activelearn.tune_run"


def close_lost_run(tracker: Any, run_token: str, trial: FrozenTrial) -> None:
    """Mark the MLflow run of a trial whose worker died KILLED, with the reason as a tag.

    The worker records the run's id on the trial right after creating the run; a worker killed
    between the two left a run nobody knows the id of, so it is found by its tags instead: this
    `tune` command's token and the trial's number (a study name alone is not unique in a store).
    """
    run_id = trial.user_attrs.get("mlflow_run_id")
    if run_id:
        run_ids = [run_id]
    else:
        tags = {RUN_TOKEN_TAG: run_token, "optuna.trial": str(trial.number)}
        run_ids = tracker.runs_tagged(tags, status="RUNNING")
    for run_id in run_ids:
        tracker.set_tags(run_id, {"optuna.state": "FAIL", "lost": trial.user_attrs.get("lost")})
        tracker.end_run(run_id, "KILLED")


@dataclass(frozen=True)
class Job:
    """Everything a worker process needs (pickled to the worker processes)."""

    study_name: str
    storage_url: str
    cfg: CampaignConfig
    tuning: TuningConfig
    # The data travel in a file to the worker processes (`split_file`): the pickled job stays small, so
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


class Objective:
    """Train one sampled configuration; report val NLL per epoch; log the trial as a nested MLflow run."""

    def __init__(
        self,
        job: Job,
        storage: optuna.storages.RDBStorage,
        tracker: Any,
        worker: int,
        started: Callable[[int], None] = lambda trial_id: None,
    ) -> None:
        self.job, self.tracker, self.worker, self.started = job, tracker, worker, started
        self.storage = storage  # the study's RDB storage (under Optuna's cache), for the first heartbeat
        self.split = job.data()

    def __call__(self, trial: optuna.Trial) -> float | tuple[float, ...]:
        job, split = self.job, self.split
        self.started(trial._trial_id)  # first: the supervisor must know which trial a dead worker held
        await_first_heartbeat(self.storage, trial._trial_id)  # before `run`: see its docstring
        multi = len(job.objectives) > 1
        trial.set_user_attr("run", job.run_token)
        for key in ("lost", "fail_reason", "mlflow_run_id"):  # a retried trial inherits its original's
            if trial.user_attrs.get(key) is not None:
                trial.set_user_attr(key, None)
        trial.set_user_attr("worker", self.worker)
        trial.set_user_attr("host", socket.gethostname())
        trial.set_user_attr("pid", os.getpid())
        model, training = sample_params(trial, job.tuning.space)
        trial.set_user_attr("model", model)
        trial.set_user_attr("training", training)
        run_id = None
        if self.tracker is not None:
            run_id = self.tracker.start_run(
                f"trial-{trial.number}",
                parent_run_id=job.parent_run_id,
                tags={
                    "optuna.study": job.study_name,
                    "optuna.trial": str(trial.number),
                    RUN_TOKEN_TAG: job.run_token,
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
            # a model that identifies itself on whole logs reads them (`Model.identify`)
            data = TrainingData(split.x_train, split.y_train, split.groups_train, logs=split.training_logs())
            validation = TrainingData(split.x_val, split.y_val, split.groups_val)
            history = fit(net, data, training_cfg, validation=validation, seed=job.seed, callback=callback)
            if parameters := net.physical_parameters():  # what the kind identified, if anything
                trial.set_user_attr("physical_parameters", parameters)
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


def run_worker(
    job: Job,
    worker: int,
    take: Callable[[], bool],
    emit: Progress,
    started: Callable[[int], None] = lambda trial_id: None,
    release: Callable[[], None] = lambda: None,
) -> None:
    """One worker: load the study with its own seeded sampler and run one trial per ticket it takes.

    `started(trial_id)` is called first thing in every trial and `release()` after it, so a
    supervisor can tell which trial a dead worker held.
    """
    optuna.logging.set_verbosity(optuna.logging.ERROR)  # trial results reach the CLI as events
    storage = open_storage(job.storage_url, job.tuning)
    study = optuna.load_study(
        study_name=job.study_name,
        storage=storage,
        sampler=make_sampler(job.tuning, job.seed, job.n_existing, worker),
        pruner=make_pruner(job.pruner, job.tuning, len(job.objectives) > 1),
    )
    tracker = None
    if job.tracking is not None:
        from activelearn.studies.tracking import Tracker

        tracker = Tracker(*job.tracking)
    objective = Objective(job, storage, tracker, worker, started)

    def done(_: optuna.Study, trial: FrozenTrial) -> None:
        emit(_trial_event(trial, worker))

    while take():
        try:
            study.optimize(objective, n_trials=1, catch=TRIAL_ERRORS, callbacks=[done], gc_after_trial=False)
        finally:
            release()


class Tickets:
    """Trials left to start, shared by one command's workers, and the trial each worker holds.

    One lock guards all three fields, so taking a ticket, finishing a trial and the supervisor's look
    at a dead worker never interleave. It is a plain Lock, not an RLock: a worker killed while holding
    it (a microsecond window) cannot release it, so the supervisor may (`locked`).
    """

    def __init__(self, ctx: Any, n_trials: int, slots: int) -> None:
        self.lock = ctx.Lock()
        self.left = ctx.Value("i", n_trials, lock=False)
        self.holding = ctx.Array("b", slots, lock=False)  # 1 while a worker holds a ticket
        self.trial = ctx.Array("q", [-1] * slots, lock=False)  # the trial id it runs, -1 before it starts

    def take(self, slot: int, deadline: float | None) -> bool:
        """Take a ticket for worker `slot` (False when none is left or the deadline passed)."""
        if deadline is not None and time.time() >= deadline:
            return False
        with self.lock:
            if self.left.value <= 0:
                return False
            self.left.value -= 1
            self.holding[slot], self.trial[slot] = 1, -1
            return True

    def release(self, slot: int) -> None:
        """Worker `slot` has finished its trial (whatever its state)."""
        with self.lock:
            self.holding[slot], self.trial[slot] = 0, -1

    def stop(self) -> None:
        """No new trials."""
        with self.locked():
            self.left.value = 0

    @contextlib.contextmanager
    def locked(self, patience: float = 5.0) -> Iterator[None]:
        """The supervisor's hold on the lock; one held for `patience` s belongs to a dead worker."""
        if not self.lock.acquire(timeout=patience):
            with contextlib.suppress(ValueError):  # released meanwhile after all
                self.lock.release()  # live workers hold it for microseconds
            self.lock.acquire()
        try:
            yield
        finally:
            self.lock.release()


def _worker_main(job: Job, slot: int, tickets: Tickets, events: Any) -> None:
    """Entry point of a worker process (`studies.processes`)."""
    import torch

    torch.set_num_threads(1)  # one busy process per core: intra-op threads would only fight

    def started(trial_id: int) -> None:
        tickets.trial[slot] = trial_id

    try:
        run_worker(job, slot, lambda: tickets.take(slot, job.deadline), events.put, started,
                   lambda: tickets.release(slot))  # fmt: skip
    except KeyboardInterrupt:
        events.put({"event": "worker_error", "worker": slot, "message": "interrupted"})
        return
    except BaseException as exc:
        events.put({"event": "worker_error", "worker": slot, "message": f"{type(exc).__name__}: {exc}"})
        return
    events.put({"event": "worker_done", "worker": slot})


@dataclass
class Supervision:
    """What the supervisor saw: workers' errors, trials lost with their worker, one line per loss."""

    errors: list[str] = dataclasses.field(default_factory=list)
    lost_trials: list[int] = dataclasses.field(default_factory=list)
    warnings: list[str] = dataclasses.field(default_factory=list)


def run_processes(
    job: Job, workers: int, n_trials: int, progress: Progress, on_lost: Callable[[FrozenTrial], None]
) -> Supervision:
    """Run `workers` worker processes sharing `n_trials` tickets; replace workers that die."""
    assert job.split is not None
    with tempfile.TemporaryDirectory(prefix="activelearn-tune-") as tmp:
        split_file = Path(tmp) / "split.npz"
        split = dataclasses.asdict(job.split)
        split["val_points"] = np.array(split["val_points"], dtype=str)
        np.savez(split_file, **split)
        job = dataclasses.replace(job, split=None, split_file=str(split_file))
        return _supervise(job, workers, n_trials, progress, on_lost)


def _load_study(job: Job) -> optuna.Study:
    return optuna.load_study(study_name=job.study_name, storage=open_storage(job.storage_url, job.tuning))


def _death(exitcode: int) -> str:
    if exitcode < 0:
        try:
            return f"killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"killed by signal {-exitcode}"
    return f"exit code {exitcode}"


def _supervise(
    job: Job, workers: int, n_trials: int, progress: Progress, on_lost: Callable[[FrozenTrial], None]
) -> Supervision:
    """Start the workers, relay their events, and handle the ones that die without a word.

    A worker that dies holding a trial is replaced (at most `workers` times in all, so a trial that
    kills every worker it meets cannot loop forever); its trial is failed and queued again.
    """
    ctx = worker_context()
    max_restarts = workers
    tickets = Tickets(ctx, n_trials, workers + max_restarts)
    events = ctx.Queue()
    procs: dict[int, Any] = {}
    seen = Supervision()
    orphans_before: datetime.datetime | None = None
    study: optuna.Study | None = None

    def start(slot: int) -> None:
        args = (dict(os.environ), _worker_main, job, slot, tickets, events)
        procs[slot] = ctx.Process(target=with_environment, args=args, name=f"tune-{slot}")
        procs[slot].start()

    for slot in range(workers):
        start(slot)
    pending = set(procs)

    def handle(event: dict[str, Any]) -> None:
        if event["event"] == "worker_done":
            pending.discard(event["worker"])
        elif event["event"] == "worker_error":
            pending.discard(event["worker"])
            seen.errors.append(f"worker {event['worker']}: {event['message']}")
        else:
            progress(event)

    def lost(slot: int) -> None:
        """A worker died without a word: give its ticket back and queue its trial again."""
        nonlocal study, orphans_before
        proc = procs[slot]
        with tickets.locked():
            held, trial_id = tickets.holding[slot], tickets.trial[slot]
            tickets.holding[slot], tickets.trial[slot] = 0, -1
            what = f"worker {slot} (pid {proc.pid}) was lost ({_death(proc.exitcode)})"
            if not held:
                if proc.exitcode == 0:  # finished; its last words were lost
                    return
                if proc.exitcode > 0:  # a crash outside any trial, e.g. at start-up: it would recur
                    seen.errors.append(
                        f"worker {slot}: exited with code {proc.exitcode} (see its traceback; a script "
                        "that runs tune(workers > 1) needs an `if __name__ == '__main__':` guard)"
                    )
                    return
                message = f"{what} between trials"
            elif trial_id < 0:  # between taking its ticket and its trial's first line
                tickets.left.value += 1
                orphans_before = datetime.datetime.now()
                message = f"{what} as its trial started; the ticket went back"
            else:
                study = study or _load_study(job)
                failed = fail_lost_trial(study, trial_id, what)
                if failed is None:
                    message = f"{what} just after its trial finished"
                else:
                    tickets.left.value += 1
                    seen.lost_trials.append(failed.number)
                    on_lost(failed)
                    message = f"{what} during trial {failed.number}: marked FAIL and queued again"
            restart = tickets.left.value > 0 and len(procs) < workers + max_restarts
        if restart:
            start(len(procs))
            pending.add(len(procs) - 1)
            message += f"; worker {len(procs) - 1} took its place"
        elif tickets.left.value > 0 and not pending:
            seen.errors.append(f"{message}; no worker left to run the remaining trials")
            return
        seen.warnings.append(message)
        progress({"event": "warning", "message": message})

    try:
        while pending:
            try:
                handle(events.get(timeout=0.5))
                continue
            except queue_module.Empty:
                pass
            for slot in sorted(pending):
                if procs[slot].exitcode is not None:  # died without saying so (killed, crashed)
                    try:  # its last words may still be in the pipe
                        while True:
                            handle(events.get(timeout=1.0))
                    except queue_module.Empty:
                        pass
                    if slot in pending:
                        pending.discard(slot)
                        lost(slot)
    except KeyboardInterrupt:
        tickets.stop()  # no new trials; running ones end as FAIL in their workers
        raise
    finally:
        for proc in procs.values():
            proc.join(timeout=30)
            if proc.is_alive():
                proc.terminate()
                proc.join()
    if orphans_before is not None:
        fail_orphans(study or _load_study(job), orphans_before, "its worker died before the trial started")
    return seen
