"""The MLflow tracking server goes away while a campaign runs: a real `mlflow server` process is killed.

The campaign keeps its data and goes on with one warning, logs what it missed once the server is back,
and where it cannot finish logging it stops, resumable, with one line; after --resume MLflow holds
every round's metrics exactly once. Never a traceback.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from activelearn.loop.campaign import CampaignState
from activelearn.studies.tracking import Tracker, create_sqlite_store

pytestmark = pytest.mark.slow  # an MLflow server killed and restarted mid-campaign

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"

# The real CLI; when its campaign reports an event named in argv (every event passes the CLI's notice
# printer) it asks the test to stop or start the server (a file in CONTROL) and waits until that is
# done, so the outage lands at exactly that point of the campaign.
_AT_EVENTS = """
import sys, time
from pathlib import Path

from activelearn import cli
from activelearn.cli import common

control, plan, *argv = sys.argv[1:]
actions = {(e, int(r)): a for e, r, a in (item.split(":") for item in plan.split(","))}
notice = common.notice


def at_event(event):
    action = actions.get((event["event"], event.get("round")))
    if action:
        request = Path(control) / action
        request.touch()
        deadline = time.monotonic() + 300
        while request.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
    return notice(event)


common.notice = at_event
raise SystemExit(cli.main(argv))
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """`mlflow server` on SQLite in its own process group, stopped with SIGKILL (a fault, not a goodbye)."""

    def __init__(self, root: Path) -> None:
        self.root, self.port, self.proc = root, _free_port(), None
        self.uri = f"http://127.0.0.1:{self.port}"

    def start(self) -> None:
        create_sqlite_store(self.root / "mlflow.db")  # migrated once per machine, as Tracker makes stores
        self.proc = subprocess.Popen(
            [str(Path(sys.executable).with_name("mlflow")), "server", "--backend-store-uri",
             f"sqlite:///{self.root}/mlflow.db", "--artifacts-destination", str(self.root / "artifacts"),
             "--host", "127.0.0.1", "--port", str(self.port), "--workers", "1"],
            stdout=subprocess.DEVNULL, stderr=open(self.root / "server.log", "a"), start_new_session=True,
        )  # fmt: skip
        deadline = time.monotonic() + 180
        while True:
            assert self.proc.poll() is None, (self.root / "server.log").read_text()[-2000:]
            try:
                with urllib.request.urlopen(self.uri + "/health", timeout=2):
                    return
            except OSError:
                assert time.monotonic() < deadline, "mlflow server did not answer within 180 s"
                time.sleep(0.5)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=60)


@pytest.fixture
def server(tmp_path):
    server = Server(tmp_path)
    server.start()
    yield server
    server.stop()


def _serve(server: Server, control: Path, done: threading.Event) -> None:
    """Carry out the campaign's requests to stop or start the server."""
    while not done.is_set():
        for action in ("stop", "start"):
            request = control / action
            if request.exists():
                getattr(server, action)()
                request.unlink()
        time.sleep(0.1)


def test_a_server_lost_mid_campaign_costs_no_round_and_logs_each_once(tmp_path, server):
    out, control = tmp_path / "c", tmp_path / "control"
    control.mkdir()
    # the smoke campaign's three rounds, each cheaper (what is tested is the outages, not the fit)
    small = tmp_path / "smoke.toml"
    cheaper = SMOKE.read_text().replace("epochs = 60", "epochs = 15")
    small.write_text(cheaper.replace("duration = 20.0", "duration = 10.0"))
    common = ["campaign", "run", str(small), "--out", str(out), "--tracking-uri", server.uri]
    done = threading.Event()
    serving = threading.Thread(target=_serve, args=(server, control, done), daemon=True)
    serving.start()
    try:
        # down from round 1 to round 2 (caught up while running), down again after the last round
        plan = "fit:1:stop,fit:2:start,round:2:stop"
        # MLflow's client gives a dead server no retries (the CLI's own default, 3 with back-off, costs
        # ~7 s per outage): the campaign's handling of an unanswered call is the same either way.
        env = {**os.environ, "MLFLOW_HTTP_REQUEST_MAX_RETRIES": "0"}
        proc = subprocess.run([sys.executable, "-c", _AT_EVENTS, str(control), plan, *common],
                              capture_output=True, text=True, timeout=900, env=env)  # fmt: skip
    finally:
        done.set()
        serving.join()
    err = proc.stderr
    assert "Traceback" not in err, err
    assert proc.returncode == 75, err
    lines = [line for line in err.splitlines() if line.startswith(("warning:", "error:"))]
    assert [line.split(":")[0] for line in lines] == ["warning", "warning", "error"], err
    assert all("does not answer" in line for line in lines), err
    assert "--resume" in lines[-1] and "rerun" in lines[-1]
    state = CampaignState.load(out)
    assert state.finished and len(state.rounds) == 3  # the data is complete
    assert state.logged == 3 and not state.model_logged  # rounds 1-2 caught up while it ran; not the model

    server.start()
    resumed = subprocess.run([sys.executable, "-m", "activelearn.cli", *common, "--resume"],
                             capture_output=True, text=True, timeout=600)  # fmt: skip
    assert resumed.returncode == 0 and "Traceback" not in resumed.stderr, resumed.stderr
    assert f"open {server.uri} in a browser" in resumed.stdout
    state = CampaignState.load(out)
    tracker = Tracker(server.uri)
    assert tracker.run_status(state.run_id) == "FINISHED" and state.model_logged
    for record in state.rounds:  # every metric of every round (prequential checks included), once
        for key, value in record.items():
            history = tracker.metric_history(state.run_id, key)
            history = [v for step, v in history if step == record["n_maneuvers"]]
            assert history == [pytest.approx(value, nan_ok=True)], (key, record["round"], history)
    steps = [step for step, _ in tracker.metric_history(state.run_id, "test_rmse")]
    assert steps == [r["n_maneuvers"] for r in state.rounds]
