"""MLflow tracking: the only module of activelearn that imports MLflow.

Runs are addressed by id through an `MlflowClient`, never through MLflow's global "active run", so
nested runs written from several processes (a comparison's workers) cannot get mixed up.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import logging
import os
import shutil
import sqlite3
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import mlflow
import mlflow.pytorch
from mlflow.entities import Metric, Param, RunStatus
from mlflow.exceptions import MlflowException
from mlflow.tracking import MlflowClient

from activelearn.errors import ConfigError, TrackingUnavailable

# No usage reports from a research tool on a closed network (they would only time out).
os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
# A tracking server that went away costs seconds, not MLflow's four minutes of retries per call: the
# campaign goes on without it and logs what it missed once the server is back (Tracker._call).
os.environ.setdefault("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "3")
os.environ.setdefault("MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR", "1")

DEFAULT_TRACKING_URI = "sqlite:///mlruns/mlflow.db"
DEFAULT_EXPERIMENT = "activelearn"
_MAX_PARAM_LENGTH = 6000  # MLflow's limit on a param value
_MAX_TAG_LENGTH = 8000  # and on a tag value
NOTE_TAG = "mlflow.note.content"  # the tag MLflow's UI shows as a run's description
_BATCH = 100  # MLflow accepts at most 100 params per log_batch call
_METRIC_BATCH = 1000  # and at most 1000 metrics
SERVER_TIMEOUT = 5.0  # s: an unreachable tracking server is one clear error, not minutes of retries
# MLflow >= 3 records an experiment's type (GenAI or model training) in this tag and otherwise infers
# it; its assistant reads it. Set on the experiments this module creates, added to existing ones without
# it. It does not choose the page the UI opens on: in MLflow 3.17 the browser's "GenAI | Model training"
# switch (top left, GenAI until clicked, then remembered) does; the README says to click it.
EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
EXPERIMENT_KIND = "custom_model_development"

T = TypeVar("T")

# MLflow's migrations and store notices are noise for a user watching a progress bar.
# The pickle-format and "+cpu" version-label warnings of model logging are expected here.
logging.getLogger("mlflow").setLevel(logging.ERROR)
logging.getLogger("alembic").setLevel(logging.WARNING)


# What a logged model needs to load: the packages MLflow's own inference finds for it (it loads the
# model in a subprocess to see what gets imported, ~10 s per campaign), named here instead.
MODEL_PACKAGES = ("mlflow", "activelearn", "cloudpickle", "numpy", "pandas", "scipy", "torch")
# Imported by torch itself whenever installed (its data pipes), so MLflow's inference lists them then;
# the set-up installs dill for bmdal_reg (the `lcmd` strategy).
IMPORTED_WHEN_INSTALLED = ("dill",)


def model_packages() -> tuple[str, ...]:
    """What MLflow's inference finds for a logged model here: `MODEL_PACKAGES` and those of
    `IMPORTED_WHEN_INSTALLED` that are installed."""
    present = tuple(name for name in IMPORTED_WHEN_INSTALLED if importlib.util.find_spec(name) is not None)
    return MODEL_PACKAGES + present


def model_requirements() -> list[str]:
    """`model_packages()` pinned to the installed versions, as the logged model's requirements.txt."""
    return [f"{name}=={importlib.metadata.version(name)}" for name in model_packages()]


def flatten_params(params: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Flatten nested mappings into dotted keys with string values, as MLflow params want."""
    flat: dict[str, str] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten_params(value, prefix=f"{name}."))
        else:
            text = ",".join(map(str, value)) if isinstance(value, list | tuple) else str(value)
            flat[name] = text[:_MAX_PARAM_LENGTH]
    return flat


def artifact_root_for(tracking_uri: str) -> str | None:
    """Artifact root beside a SQLite store (`<db dir>/artifacts`), or None to let MLflow decide."""
    if not tracking_uri.startswith("sqlite:///"):
        return None
    db_path = Path(tracking_uri.removeprefix("sqlite:///"))
    return (db_path.parent.resolve() / "artifacts").as_uri()


def _store_template() -> Path:
    """An empty SQLite store migrated by this MLflow version, made once per machine in the user's cache.

    MLflow builds a new SQLite store by running its schema migrations (68 in 3.17: seconds); a copy of
    an empty store it built takes milliseconds. Keyed by MLflow's version: an upgrade migrates afresh.
    """
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "activelearn"
    template = cache / f"mlflow-{mlflow.__version__}-empty.db"
    if not template.exists():
        cache.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=cache) as scratch:
            built = Path(scratch) / "mlflow.db"
            MlflowClient(f"sqlite:///{built}").search_experiments()  # MLflow creates and migrates it
            os.replace(built, template)  # atomic: concurrent builders leave one complete template
    return template


def create_sqlite_store(db_path: Path) -> None:
    """Make the empty MLflow store `db_path` as a copy of the migrated template; keep one that exists.

    The copy is what MLflow would have built, down to its "Default" experiment (artifacts under the
    working directory's mlruns/0, created now). Anything unusual (no writable cache, no hard links)
    leaves the path alone and MLflow builds the store itself.
    """
    if db_path.exists():
        return
    try:
        template = _store_template()
        partial = db_path.with_name(f".{db_path.name}.{os.getpid()}.partial")
        shutil.copyfile(template, partial)
        try:
            now = int(time.time() * 1000)
            default_artifacts = str(Path.cwd().resolve() / "mlruns" / "0")
            connection = sqlite3.connect(partial)
            with connection:
                connection.execute(
                    "UPDATE experiments SET artifact_location = ?, creation_time = ?, last_update_time = ?"
                    " WHERE experiment_id = 0",
                    (default_artifacts, now, now),
                )
            connection.close()
            os.link(partial, db_path)  # never over a store another process made meanwhile
        finally:
            partial.unlink(missing_ok=True)
    except (OSError, sqlite3.Error, MlflowException):
        return


def check_server(tracking_uri: str, timeout: float = SERVER_TIMEOUT) -> None:
    """Fail within `timeout` s with one clear error when an http(s) tracking server does not answer.

    MLflow's own client retries a dead server with back-off for minutes before it gives up.
    """
    if not tracking_uri.startswith(("http://", "https://")):
        return
    try:
        with urllib.request.urlopen(tracking_uri.rstrip("/") + "/health", timeout=timeout):
            return
    except urllib.error.HTTPError:  # it answered (an older server without /health, or auth)
        return
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        message = f"no MLflow server answers there ({reason})"
        raise ConfigError("tracking.uri", tracking_uri, message) from None


def _retry(call: Callable[[], T], attempts: int = 8) -> T:
    """Retry a store call that SQLite refused because another process held its lock."""
    delay = 0.05
    for attempt in range(attempts):
        try:
            return call()
        except MlflowException as exc:
            if "locked" not in str(exc).lower() or attempt == attempts - 1:
                raise
            time.sleep(delay)
            delay *= 2
    raise AssertionError("unreachable")


class Tracker:
    """Write runs, params, metrics, figures and models to one MLflow store and experiment."""

    def __init__(
        self, tracking_uri: str = DEFAULT_TRACKING_URI, experiment: str = DEFAULT_EXPERIMENT
    ) -> None:
        if tracking_uri.startswith("sqlite:///"):
            db_path = Path(tracking_uri.removeprefix("sqlite:///"))
            db_path.parent.mkdir(parents=True, exist_ok=True)
            create_sqlite_store(db_path)
        self.tracking_uri = tracking_uri
        self._down = False  # the server stopped answering; each call checks it is back first
        check_server(tracking_uri)
        try:
            self.client = MlflowClient(tracking_uri)
            self.experiment_id = self._experiment_id(experiment)
        except MlflowException as exc:
            raise ConfigError("tracking.uri", tracking_uri, f"cannot open the MLflow store: {exc}") from exc

    def _call(self, call: Callable[[], T]) -> T:
        """`_retry(call)`; a tracking server that does not answer is TrackingUnavailable (nothing logged)."""
        if self._down:
            self._check()
        try:
            return _retry(call)
        except Exception:
            self._check()  # a server that answers: the error is the call's own
            raise

    def _check(self) -> None:
        try:
            check_server(self.tracking_uri)
        except ConfigError as exc:
            self._down = True
            raise TrackingUnavailable(
                f"the MLflow tracking server at {self.tracking_uri} does not answer ({exc.reason})"
            ) from None
        self._down = False

    def _experiment_id(self, name: str) -> str:
        found = _retry(lambda: self.client.get_experiment_by_name(name))
        if found is None:
            try:
                return _retry(
                    lambda: self.client.create_experiment(
                        name,
                        artifact_location=artifact_root_for(self.tracking_uri),
                        tags={EXPERIMENT_KIND_TAG: EXPERIMENT_KIND},
                    )
                )
            except MlflowException:  # another process created it first
                found = self.client.get_experiment_by_name(name)
                if found is None:
                    raise
        if EXPERIMENT_KIND_TAG not in found.tags:  # made by an older version, or by MLflow itself
            try:
                _retry(lambda: self.client.set_experiment_tag(found.experiment_id, EXPERIMENT_KIND_TAG,
                                                              EXPERIMENT_KIND))
            except MlflowException:  # a store that refuses (read-only, permissions): only the UI's page
                pass
        return found.experiment_id

    def start_run(
        self,
        name: str,
        *,
        parent_run_id: str | None = None,
        tags: Mapping[str, str] | None = None,
        resume_run_id: str | None = None,
    ) -> str:
        """Create a run (nested under `parent_run_id` if given) or reopen `resume_run_id`; return its id."""
        if resume_run_id is not None:
            self._call(lambda: self.client.update_run(resume_run_id, status="RUNNING"))
            return resume_run_id
        all_tags = dict(tags or {})
        if parent_run_id is not None:
            all_tags["mlflow.parentRunId"] = parent_run_id
        run = self._call(lambda: self.client.create_run(self.experiment_id, run_name=name, tags=all_tags))
        return run.info.run_id

    def log_params(self, run_id: str, params: Mapping[str, Any]) -> None:
        """Log a (possibly nested) mapping of params, flattened to dotted keys."""
        items = [Param(k, v) for k, v in flatten_params(params).items()]
        existing = self._call(lambda: self.client.get_run(run_id)).data.params
        items = [p for p in items if p.key not in existing]  # params are immutable; resume re-logs nothing
        for start in range(0, len(items), _BATCH):
            chunk = items[start : start + _BATCH]
            self._call(lambda chunk=chunk: self.client.log_batch(run_id, params=chunk))

    def set_tags(self, run_id: str, tags: Mapping[str, Any]) -> None:
        """Set string tags on a run."""
        for key, value in tags.items():
            self._call(lambda key=key, value=value: self.client.set_tag(run_id, key, str(value)))

    def set_note(self, run_id: str, text: str) -> None:
        """Set a run's description (MLflow's note, shown as Markdown on the run's page)."""
        self._call(lambda: self.client.set_tag(run_id, NOTE_TAG, text[:_MAX_TAG_LENGTH]))

    def note(self, run_id: str) -> str | None:
        """A run's description (None when it has none)."""
        return self._call(lambda: self.client.get_run(run_id)).data.tags.get(NOTE_TAG)

    def log_metrics(
        self, run_id: str, metrics: Mapping[str, float], step: int, timestamp: int | None = None
    ) -> None:
        """Log one step of metrics in a single batch.

        With a fixed `timestamp` (ms) logging the same values again adds nothing: MLflow's store keeps
        one copy of a metric with the same key, value, step and timestamp (a retry after a lost reply).
        """
        now = int(time.time() * 1000) if timestamp is None else timestamp
        items = [Metric(k, float(v), now, int(step)) for k, v in metrics.items()]
        self._call(lambda: self.client.log_batch(run_id, metrics=items))

    def log_metric_series(self, run_id: str, rows: Sequence[tuple[int, Mapping[str, float]]]) -> None:
        """Log many steps of metrics (e.g. a per-epoch curve) in as few store calls as MLflow allows."""
        now = int(time.time() * 1000)
        items = [Metric(k, float(v), now, int(step)) for step, values in rows for k, v in values.items()]
        for start in range(0, len(items), _METRIC_BATCH):
            chunk = items[start : start + _METRIC_BATCH]
            self._call(lambda chunk=chunk: self.client.log_batch(run_id, metrics=chunk))

    def log_figure(self, run_id: str, figure: Any, artifact_file: str) -> None:
        """Log a matplotlib figure as a PNG artifact."""
        self._call(lambda: self.client.log_figure(run_id, figure, artifact_file))

    def log_artifact(self, run_id: str, path: str | Path, artifact_path: str | None = None) -> None:
        """Log a local file as an artifact."""
        self._call(lambda: self.client.log_artifact(run_id, str(path), artifact_path))

    def log_text(self, run_id: str, text: str, artifact_file: str) -> None:
        """Log a text artifact."""
        self._call(lambda: self.client.log_text(run_id, text, artifact_file))

    def log_model(self, run_id: str, model: Any, name: str = "model") -> str:
        """Log a torch model through `mlflow.pytorch`; return its model URI."""
        def log() -> Any:
            with self._active(run_id):
                # pickle: MLflow 3's default "pt2" format needs a traced input example and drops our methods
                return mlflow.pytorch.log_model(
                    model, name=name, serialization_format="pickle", pip_requirements=model_requirements()
                )

        return self._call(log).model_uri

    def end_run(self, run_id: str, status: str = "FINISHED") -> None:
        """Mark a run FINISHED, FAILED or KILLED."""
        RunStatus.from_string(status)  # raises on a typo
        self._call(lambda: self.client.set_terminated(run_id, status))

    def run_status(self, run_id: str) -> str:
        """Return the status of a run (RUNNING, FINISHED, KILLED, FAILED)."""
        return self._call(lambda: self.client.get_run(run_id)).info.status

    def metric_history(self, run_id: str, key: str) -> list[tuple[int, float]]:
        """Return (step, value) pairs of a metric, in step order."""
        history = self._call(lambda: self.client.get_metric_history(run_id, key))
        return sorted((m.step, m.value) for m in history)

    def child_runs(self, parent_run_id: str) -> list[str]:
        """Ids of the runs nested under a parent run."""
        runs = self.client.search_runs(
            [self.experiment_id], filter_string=f"tags.mlflow.parentRunId = '{parent_run_id}'"
        )
        return [r.info.run_id for r in runs]

    def runs_tagged(self, tags: Mapping[str, str], status: str | None = None) -> list[str]:
        """Ids of the runs of this experiment carrying all `tags` (and in `status`, if given)."""
        clauses = [f"tags.`{key}` = '{value}'" for key, value in tags.items()]
        if status is not None:
            clauses.append(f"attributes.status = '{RunStatus.to_string(RunStatus.from_string(status))}'")
        runs = _retry(
            lambda: self.client.search_runs([self.experiment_id], filter_string=" and ".join(clauses))
        )
        return [r.info.run_id for r in runs]

    @contextmanager
    def _active(self, run_id: str) -> Iterator[None]:
        """Make `run_id` MLflow's active run for fluent-only APIs (model logging)."""
        mlflow.set_tracking_uri(self.tracking_uri)
        with mlflow.start_run(run_id=run_id):
            yield
        # leaving the fluent context marks the run FINISHED; put it back to RUNNING for later rounds
        self.client.update_run(run_id, status="RUNNING")


def load_model(model_uri: str, tracking_uri: str = DEFAULT_TRACKING_URI) -> Any:
    """Load a model logged with `Tracker.log_model` (an MLflow model URI such as runs:/<id>/model)."""
    mlflow.set_tracking_uri(tracking_uri)
    # The model's files are only a stepping stone: the loaded module lives in memory.
    with tempfile.TemporaryDirectory(prefix="activelearn-model-") as scratch:
        try:
            return mlflow.pytorch.load_model(model_uri, dst_path=scratch)
        except MlflowException as exc:
            raise ConfigError("--model", model_uri, f"cannot load the MLflow model: {exc}") from exc
