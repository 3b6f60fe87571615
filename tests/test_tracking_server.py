"""Campaigns logging to an MLflow tracking server backed by PostgreSQL, as on a cluster.

The server (`mlflow server`, PostgreSQL backend store, proxied artifact root) runs in its own process;
the campaigns reach it only through its http:// URI, as campaigns on other machines would.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
import uuid
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from activelearn.config import load_config
from activelearn.studies.compare import compare

pytestmark = pytest.mark.slow  # an MLflow server on PostgreSQL

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def tracking_server(tmp_path, mlflow_postgres_url):
    """http:// URI of an MLflow server on PostgreSQL with artifacts under tmp_path/artifacts."""
    port = _free_port()
    backend = mlflow_postgres_url.replace("postgresql://", "postgresql+psycopg2://", 1)
    server = subprocess.Popen(
        [str(Path(sys.executable).with_name("mlflow")), "server", "--backend-store-uri", backend,
         "--artifacts-destination", str(tmp_path / "artifacts"), "--host", "127.0.0.1",
         "--port", str(port), "--workers", "1"],
        stdout=subprocess.DEVNULL, stderr=open(tmp_path / "server.log", "w"), start_new_session=True,
    )  # fmt: skip
    uri = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180  # the first start migrates the database's schema
        while True:
            if server.poll() is not None:
                pytest.fail(f"mlflow server exited: {(tmp_path / 'server.log').read_text()[-2000:]}")
            try:
                with urllib.request.urlopen(uri + "/health", timeout=2):
                    break
            except OSError:
                if time.monotonic() > deadline:
                    pytest.fail("mlflow server did not answer within 180 s")
                time.sleep(1)
        yield uri
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=60)


def test_a_comparison_logs_nested_runs_figures_and_models_to_the_server(tmp_path, tracking_server):
    text = SMOKE.read_text().replace("max_maneuvers = 7", "max_maneuvers = 5")
    # An experiment of its own: the server's database may hold the runs of earlier test sessions.
    name = f"server-test-{uuid.uuid4().hex[:12]}"
    path = tmp_path / "smoke.toml"
    path.write_text(
        f'output_dir = "{tmp_path / "runs"}"\n' + text
        + f'\n[tracking]\nuri = "{tracking_server}"\nexperiment = "{name}"\n'
    )  # fmt: skip
    cfg = load_config(path)
    result = compare(cfg, ["uniform"], [0], directory=tmp_path / "out", workers=1, tracking=True)

    client = MlflowClient(tracking_server)
    experiment = client.get_experiment_by_name(name)
    runs = client.search_runs([experiment.experiment_id])
    parent = next(r for r in runs if r.info.run_id == result.parent_run_id)
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == result.parent_run_id]
    assert parent.info.status == "FINISHED" and len(children) == 1
    child = children[0]
    assert child.info.status == "FINISHED"
    history = client.get_metric_history(child.info.run_id, "test_rmse")
    assert len(history) == 2  # 3 -> 5 maneuvers: two rounds
    assert "comparison.png" in {a.path for a in client.list_artifacts(parent.info.run_id)}
    child_artifacts = {a.path for a in client.list_artifacts(child.info.run_id)}
    assert any(p.startswith("figures") for p in child_artifacts)
    # The artifacts live where the server keeps them, not in the campaign's directory.
    stored = [p for p in (tmp_path / "artifacts").rglob("*") if p.is_file()]
    assert any(p.name == "comparison.png" for p in stored)
    # A model logged by a campaign lands on the server as well.
    from activelearn.loop.campaign import Campaign
    from activelearn.studies.tracking import Tracker

    campaign_cfg = cfg.model_copy(update={"strategy": "uniform", "seed": 1})
    tracker = Tracker(tracking_server, name)
    Campaign(campaign_cfg, tmp_path / "single", tracker=tracker).run(figures=False, log_model=True)
    runs = client.search_runs([experiment.experiment_id])
    single = [r for r in runs if r.info.run_id != parent.info.run_id]
    models = client.search_logged_models(experiment_ids=[experiment.experiment_id])
    assert any(m.source_run_id not in {parent.info.run_id, child.info.run_id} for m in models), (
        "no model logged by the single campaign on the server"
    )
    assert len(single) == 2  # the comparison's child and the single campaign
    # ... and its files are in the server's artifact store.
    after = {p for p in (tmp_path / "artifacts").rglob("*") if p.is_file()}
    assert any(p.name == "data.pkl" or p.suffix in {".pth", ".pt"} for p in after - set(stored))
