"""A new SQLite store is a copy of an empty store MLflow migrated once: the same store MLflow builds."""

from __future__ import annotations

import sqlite3

from mlflow.tracking import MlflowClient

from activelearn.studies.tracking import Tracker, create_sqlite_store


def _schema(db) -> tuple[dict, list]:
    """Each table's and index's definition, line by line (MLflow's own migrations order a table's
    constraints differently from one run to the next), and the schema version."""
    connection = sqlite3.connect(db)
    try:
        rows = connection.execute("SELECT name, sql FROM sqlite_master").fetchall()
        version = connection.execute("SELECT version_num FROM alembic_version").fetchall()
    finally:
        connection.close()
    parts = {name: sorted(ln.strip().rstrip(",") for ln in (sql or "").splitlines()) for name, sql in rows}
    return parts, version


def test_a_store_from_the_template_is_the_store_mlflow_builds(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # the template is built here, now
    monkeypatch.chdir(tmp_path)  # MLflow puts the Default experiment's artifacts under the working dir
    copied = tmp_path / "copied" / "mlflow.db"
    tracker = Tracker(f"sqlite:///{copied}")
    assert list((tmp_path / "cache" / "activelearn").glob("mlflow-*-empty.db"))
    native = tmp_path / "native" / "mlflow.db"
    native.parent.mkdir()
    built = MlflowClient(f"sqlite:///{native}")
    built.search_experiments()  # MLflow builds and migrates the store itself

    assert _schema(copied) == _schema(native)
    default_copied = tracker.client.get_experiment("0")
    default_native = built.get_experiment("0")
    assert (default_copied.name, default_copied.artifact_location) == (
        default_native.name,
        default_native.artifact_location,
    )
    assert abs(default_copied.creation_time - default_native.creation_time) < 60_000  # made now, not then

    run = tracker.start_run("a run")
    tracker.client.log_metric(run, "test_rmse", 0.5, step=1)
    reopened = Tracker(f"sqlite:///{copied}")
    assert reopened.client.get_run(run).data.metrics == {"test_rmse": 0.5}


def test_an_existing_store_is_never_replaced(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    db = tmp_path / "mlflow.db"
    tracker = Tracker(f"sqlite:///{db}")
    run = tracker.start_run("kept")
    create_sqlite_store(db)
    assert Tracker(f"sqlite:///{db}").client.get_run(run).info.run_name == "kept"
    assert not list(tmp_path.glob(".*.partial"))
