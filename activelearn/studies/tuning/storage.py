"""Optuna storages: URLs (SQLite or PostgreSQL), a fast-failing connection with heartbeats, and the
bookkeeping of trials whose worker died (marked FAIL and queued again, never left RUNNING)."""

from __future__ import annotations

import datetime
import time
import warnings
from pathlib import Path
from typing import Any

import optuna
import sqlalchemy
from optuna.storages import RetryHeartbeatStaleTrialCallback
from optuna.trial import FrozenTrial, TrialState

from activelearn.config import TuningConfig
from activelearn.errors import InputError

DEFAULT_STORAGE = "sqlite:///mlruns/optuna.db"
CONNECT_TIMEOUT = 5  # s: an unreachable database server fails fast instead of hanging


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


def open_storage(
    url: str, tuning: TuningConfig | None = None, connect_timeout: float = CONNECT_TIMEOUT
) -> optuna.storages.RDBStorage:
    """Open (creating its tables if needed) an Optuna RDB storage; fail fast with a clear error.

    SQLite: the parent directory is created and writers wait up to 30 s for the file lock (several
    local workers). PostgreSQL: a connect timeout, so an unreachable server fails within seconds.
    With `tuning`, running trials record heartbeats, and a trial whose heartbeat stops (its worker or
    machine died) is marked FAIL by the next worker that starts a trial and queued again.
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
            heartbeat: dict[str, Any] = {}
            if tuning is not None:
                heartbeat = {
                    "heartbeat_interval": tuning.heartbeat_interval,
                    "grace_period": tuning.grace_period,
                    "heartbeat_stale_trial_callback": RetryHeartbeatStaleTrialCallback(tuning.retry_lost),
                }
            storage = optuna.storages.RDBStorage(url, engine_kwargs=engine_kwargs, **heartbeat)
        if backend == "sqlite":
            _serialise_sqlite_transactions(storage.engine)
        return storage
    except Exception as exc:  # driver errors come in many types (OperationalError, ImportError, ...)
        reason = str(getattr(exc, "orig", None) or exc).strip().splitlines()
        raise InputError(
            "--storage", shown, f"cannot open the Optuna storage: {reason[0] if reason else exc}"
        ) from None


def _serialise_sqlite_transactions(engine: sqlalchemy.engine.Engine) -> None:
    """Make every SQLite transaction take the write lock at its start (BEGIN IMMEDIATE).

    pysqlite starts a transaction only at the first write, so Optuna's read-then-update of a WAITING
    trial (`Study._pop_waiting_trial_id`; its row lock is a no-op in SQLite) let two workers take the
    same queued trial: 4 processes popping 300 queued trials got 319-324 pops. The second to finish
    then failed with "Cannot tell a COMPLETE trial". SQLAlchemy's documented pysqlite recipe.
    """

    @sqlalchemy.event.listens_for(engine, "connect")
    def _no_implicit_begin(dbapi_connection: Any, _record: Any) -> None:
        dbapi_connection.isolation_level = None  # pysqlite emits no BEGIN of its own

    @sqlalchemy.event.listens_for(engine, "begin")
    def _begin_immediate(connection: Any) -> None:
        connection.exec_driver_sql("BEGIN IMMEDIATE")

    engine.dispose()  # connections opened while Optuna created the tables predate the hooks


# How long a trial waits for Optuna's heartbeat thread to record its first beat (see below).
FIRST_HEARTBEAT_TIMEOUT = 30.0  # s: SQLite writers wait up to 30 s for the file lock
# A RUNNING trial with no heartbeat this old lost its machine before the first beat: a live one has
# one within FIRST_HEARTBEAT_TIMEOUT, since its objective waits for it.
SILENT_TRIAL_AGE = 2 * FIRST_HEARTBEAT_TIMEOUT


def _beating(storage: Any, trial_ids: list[int]) -> set[int]:
    """The ids among `trial_ids` with a heartbeat in the storage (read-only, Optuna's own table).

    Read-only on purpose: a write of our own could collide with the heartbeat thread's first insert
    (a unique trial id) and kill the thread, which would stop the trial's heartbeats while it runs.
    """
    if not trial_ids:
        return set()
    query = sqlalchemy.text("SELECT trial_id FROM trial_heartbeats WHERE trial_id IN :ids").bindparams(
        sqlalchemy.bindparam("ids", expanding=True)
    )
    with storage.engine.connect() as connection:
        return {row[0] for row in connection.execute(query, {"ids": list(trial_ids)})}


def _heartbeats_on(storage: Any) -> bool:
    return bool(getattr(storage, "get_heartbeat_interval", lambda: None)())


def await_first_heartbeat(storage: Any, trial_id: int, timeout: float = FIRST_HEARTBEAT_TIMEOUT) -> bool:
    """Wait until the trial's first heartbeat is in the storage; False if heartbeats are off or it never came.

    Optuna starts a trial's heartbeat thread just before the objective and never waits for its first
    write, and its stale check skips a RUNNING trial that has no heartbeat at all. A machine lost
    before that write would leave the trial RUNNING forever (measured: 3 of 150 trials still had no
    heartbeat after the objective's first six writes; the thread loses the SQLite lock to them).
    Waiting here, first thing in the objective, shrinks that window to the thread's start-up, and
    `fail_silent_trials` closes what is left of it.
    """
    if not _heartbeats_on(storage):
        return False
    deadline = time.monotonic() + timeout
    while not _beating(storage, [trial_id]):
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


def fail_silent_trials(
    study: optuna.Study, storage: Any, reason: str, older_than: float = SILENT_TRIAL_AGE
) -> list[int]:
    """Fail (and queue again) RUNNING trials with no heartbeat that started over `older_than` s ago.

    Optuna's stale check never sees them: their machine was lost between Optuna creating the trial
    and its heartbeat thread's first write. Returns the numbers of the trials failed.
    """
    if not _heartbeats_on(storage):
        return []
    cutoff = datetime.datetime.now() - datetime.timedelta(seconds=older_than)
    old = [
        t
        for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
        if t.datetime_start is not None and t.datetime_start < cutoff
    ]
    beating = _beating(storage, [t._trial_id for t in old])
    return [
        t.number
        for t in old
        if t._trial_id not in beating and fail_lost_trial(study, t._trial_id, reason) is not None
    ]


def fail_lost_trial(study: optuna.Study, trial_id: int, reason: str) -> FrozenTrial | None:
    """Mark the trial of a worker known to be dead FAIL and queue it again; None if it had finished.

    The local supervisor sees a worker die at once (its exit code), so it need not wait for the
    heartbeat's grace period; it then does what Optuna's own stale-trial check does (the storage's
    retry callback), and the two cannot both fail one trial (the storage refuses the second).
    """
    storage = study._storage
    try:
        storage.set_trial_user_attr(trial_id, "lost", reason)
        if not storage.set_trial_state_values(trial_id, state=TrialState.FAIL):
            return None
    except optuna.exceptions.UpdateFinishedTrialError:
        return None
    failed = storage.get_trial(trial_id)
    retry = getattr(storage, "get_heartbeat_stale_trial_callback", lambda: None)()
    if retry is not None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            retry(study, failed)
    return failed


def fail_orphans(study: optuna.Study, started_before: datetime.datetime, reason: str) -> list[int]:
    """Fail RUNNING trials that no objective ever picked up (no `run` attribute) started before a time.

    A worker killed between Optuna creating its trial and the objective's first line leaves such a
    trial: it has no parameters and no heartbeat yet, so Optuna's stale check never sees it.
    """
    failed = []
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        if "run" in trial.user_attrs or trial.datetime_start is None or trial.datetime_start > started_before:
            continue
        if fail_lost_trial(study, trial._trial_id, reason) is not None:
            failed.append(trial.number)
    return failed


def replaced(trials: list[FrozenTrial]) -> set[int]:
    """Numbers of trials that were lost with their worker (failed and queued again, or marked lost)."""
    # The retry callback records in each retry the numbers of the trials it replaces.
    numbers = {n for t in trials for n in t.system_attrs.get("retry_history", ())}
    return numbers | {t.number for t in trials if t.state == TrialState.FAIL and t.user_attrs.get("lost")}
