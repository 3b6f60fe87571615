"""Screenshot MLflow's own page of a comparison: the latest `compare` parent run's metric charts.

Starts `mlflow ui` on the store, finds the newest run tagged kind = comparison, loads the run's
"Model metrics" page in headless Chromium (the OS package: `apt-get install chromium`) and writes a
PNG; then stops the server. It makes the tutorial's screenshot from `make demo`'s own store:

    .venv/bin/python experiments/docs/mlflow_screenshot.py sqlite:///mlruns/mlflow.db \\
        docs/img/mlflow-comparison.png

`--page overview` takes the run's overview (its description, params and artifacts) instead, and
`--page chart` the experiment's chart view of every run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

from activelearn.studies.tracking import DEFAULT_EXPERIMENT, Tracker

PAGES = {
    "metrics": "#/experiments/{experiment}/runs/{run}/model-metrics",
    "overview": "#/experiments/{experiment}/runs/{run}",
    "chart": "#/experiments/{experiment}/runs?compareRunsMode=CHART",
}
BROWSERS = ("chromium", "chromium-browser", "google-chrome")


def latest_comparison(uri: str, experiment: str) -> tuple[str, str]:
    """(experiment id, run id) of the newest parent run of `activelearn compare` in the store."""
    tracker = Tracker(uri, experiment)
    runs = tracker.runs_tagged({"kind": "comparison"})  # newest first (MLflow orders by start time)
    if not runs:
        sys.exit(f"no comparison in experiment {experiment!r} of {uri}: run `activelearn compare` first")
    return tracker.experiment_id, runs[0]


def wait_for(url: str, seconds: float) -> None:
    """Wait until the server at `url` answers its health check."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            with urllib.request.urlopen(f"{url}/health", timeout=2):
                return
        except (urllib.error.URLError, OSError):
            time.sleep(0.5)
    sys.exit(f"mlflow ui did not answer at {url} within {seconds:g} s")


def screenshot(url: str, out: Path, size: str, budget_ms: int) -> None:
    """Load `url` in headless Chromium and write what it shows to `out` (PNG)."""
    browser = next((b for b in BROWSERS if shutil.which(b)), None)
    if browser is None:
        sys.exit("no Chromium found: apt-get install chromium")
    with tempfile.TemporaryDirectory(prefix="mlflow-shot-") as profile:
        command = [
            browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync",
            f"--user-data-dir={profile}", f"--window-size={size}", f"--virtual-time-budget={budget_ms}",
            f"--screenshot={out.resolve()}", url,
        ]  # fmt: skip
        subprocess.run(command, check=True, capture_output=True, timeout=300)
    if not out.exists() or out.stat().st_size == 0:
        sys.exit(f"Chromium wrote no screenshot to {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", help="the tracking store, e.g. sqlite:///mlruns/mlflow.db")
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("--experiment", default=DEFAULT_EXPERIMENT)
    parser.add_argument("--run", default=None, help="a parent run id (default: the newest comparison)")
    parser.add_argument("--page", choices=tuple(PAGES), default="metrics")
    parser.add_argument("--port", type=int, default=5077)
    parser.add_argument("--settle", type=float, default=30.0, help="seconds to wait after the server answers")
    parser.add_argument("--size", default="1400,1100", help="browser window, width,height in pixels")
    parser.add_argument("--wait-ms", type=int, default=60000, help="how long the page may render (virtual)")
    args = parser.parse_args()

    experiment, run = latest_comparison(args.store, args.experiment)
    run = args.run or run
    try:  # a server already on the port would answer in place of ours (and show another store)
        urllib.request.urlopen(f"http://127.0.0.1:{args.port}/health", timeout=2)
        sys.exit(f"port {args.port} is taken: stop what serves it or pass --port")
    except (urllib.error.URLError, OSError):
        pass
    mlflow = Path(sys.executable).with_name("mlflow")
    url = f"http://127.0.0.1:{args.port}"
    server = subprocess.Popen(
        [str(mlflow), "ui", "--backend-store-uri", args.store, "--host", "127.0.0.1", "--port",
         str(args.port), "--workers", "1"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    try:
        wait_for(url, 120.0)
        time.sleep(args.settle)  # its workers answer /health before they answer chart queries quickly
        args.out.parent.mkdir(parents=True, exist_ok=True)
        page = PAGES[args.page].format(experiment=experiment, run=run)
        # Twice: a cold server answers the first load's chart queries after Chromium has drawn spinners.
        for _ in range(2):
            screenshot(f"{url}/{page}", args.out, args.size, args.wait_ms)
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()
    print(f"{args.out}: run {run}, {url}/{page}")


if __name__ == "__main__":
    main()
