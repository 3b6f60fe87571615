"""Screenshot MLflow's own page of a comparison: the latest `compare` parent run's metric charts.

Starts `mlflow ui` on the store, finds the newest run tagged kind = comparison, loads the run's
overview (its description draws the comparison figure) in headless Chromium (the OS package:
`apt-get install chromium`, driven by Playwright: `pip install playwright`) and writes a PNG; then
stops the server. It makes the tutorial's screenshot from `make demo`'s own store:

    .venv/bin/python experiments/docs/mlflow_screenshot.py sqlite:///mlruns/mlflow.db \\
        docs/img/mlflow-comparison.png

`--page metrics` takes the run's *Model metrics* charts instead, `--page runs` the experiment's
list of runs and `--page chart` its chart view of every run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

from activelearn.studies.tracking import DEFAULT_EXPERIMENT, Tracker

PAGES = {
    "metrics": "#/experiments/{experiment}/runs/{run}/model-metrics",
    "overview": "#/experiments/{experiment}/runs/{run}",
    "chart": "#/experiments/{experiment}/runs?compareRunsMode=CHART",
    "runs": "#/experiments/{experiment}/runs",
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


def click(locator: Any) -> bool:
    """Click the first visible element `locator` finds; False where none shows within 5 s."""
    for i in range(locator.count()):
        try:
            locator.nth(i).click(timeout=5000)
            return True
        except Exception:  # not visible or not clickable: try the next one
            continue
    return False


def screenshot(url: str, out: Path, size: str, wait_s: float) -> None:
    """Load `url` in headless Chromium (driven by Playwright) and write what it shows to `out` (PNG).

    MLflow 3 opens on its GenAI pages with its assistant's panel open: the page is switched to *Model
    training* and the panel closed, as a user does once; then the run's page is loaded again, its
    description expanded (*Show more*: the comparison figure) and its charts given time to draw.
    """
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        sys.exit("needs Playwright's Python package: .venv/bin/pip install playwright (it drives the OS "
                 "package's Chromium; no browser is downloaded)")  # fmt: skip
    browser = next((shutil.which(b) for b in BROWSERS if shutil.which(b)), None)
    if browser is None:
        sys.exit("no Chromium found: apt-get install chromium")
    width, height = (int(v) for v in size.split(","))
    flags = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync"]  # fmt: skip
    with sync_playwright() as driver:
        chromium = driver.chromium.launch(executable_path=browser, args=flags)
        page = chromium.new_page(viewport={"width": width, "height": height})
        page.goto(url, wait_until="load", timeout=120_000)
        page.wait_for_timeout(wait_s * 1000)
        click(page.get_by_text("Model training", exact=True))
        click(page.locator("[aria-label=Close]"))
        page.goto(url, wait_until="load", timeout=120_000)
        page.wait_for_timeout(wait_s * 1000)
        if click(page.get_by_text("Show more", exact=True)):
            page.wait_for_timeout(2000)
        page.screenshot(path=str(out))
        chromium.close()
    if not out.exists() or out.stat().st_size == 0:
        sys.exit(f"Chromium wrote no screenshot to {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("store", help="the tracking store, e.g. sqlite:///mlruns/mlflow.db")
    parser.add_argument("out", type=Path, help="the PNG to write")
    parser.add_argument("--experiment", default=DEFAULT_EXPERIMENT)
    parser.add_argument("--run", default=None, help="a parent run id (default: the newest comparison)")
    parser.add_argument("--page", choices=tuple(PAGES), default="overview")
    parser.add_argument("--port", type=int, default=5077)
    parser.add_argument("--size", default="1700,1250", help="browser window, width,height in pixels")
    parser.add_argument("--wait", type=float, default=10.0, help="seconds a page may take to draw")
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
        args.out.parent.mkdir(parents=True, exist_ok=True)
        page = PAGES[args.page].format(experiment=experiment, run=run)
        screenshot(f"{url}/{page}", args.out, args.size, args.wait)
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
