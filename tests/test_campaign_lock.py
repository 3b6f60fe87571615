"""One writer per campaign directory: real CLI processes racing for one campaign.

Each race runs RACES times (ACTIVELEARN_RACES, default 2; the issue's check is 20 in a row). A race
either records every log exactly once, or the command that lost exits non-zero and says to retry.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from activelearn.cli import main
from activelearn.data import read_recorded_log
from activelearn.loop.lock import HOLDER_FILE, LOCK_FILE, read_holder
from activelearn.loop.state import CampaignState
from activelearn.studies.tracking import Tracker
from tests.test_asktell import _drive

pytestmark = pytest.mark.slow  # processes racing for one campaign directory

RACES = int(os.environ.get("ACTIVELEARN_RACES", "2"))
OUTCOMES = os.environ.get("ACTIVELEARN_RACES_LOG")  # a file to append each race's outcome to


def _outcome(test: str, race: int, codes: list[int]) -> None:
    if OUTCOMES:
        with open(OUTCOMES, "a") as f:
            f.write(json.dumps({"test": test, "race": race, "codes": codes, "t": time.time()}) + "\n")

CONFIG = """
name = "race"
strategy = "max_epistemic"
[pool]
kinds = ["straight", "skidpad"]
throttles = [0.3, 0.6, 0.9]
steerings = [0.15, 0.35]
duration = 8.0
[data]
stride = 10
[design]
initial = 2
per_round = 2
max_maneuvers = 4
[acquisition]
n_samples = 8
grid_throttles = 4
grid_steerings = 4
[training]
epochs = 10
[test]
throttles = [0.45]
steerings = [0.25]
duration = 6.0
"""

_HOLD = """
import sys, time
from activelearn.loop.lock import hold
with hold(sys.argv[1]):
    print("held", flush=True)
    time.sleep(float(sys.argv[2]))
"""


def _cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "activelearn.cli", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip


def _finish(proc: subprocess.Popen) -> tuple[int, str]:
    _, err = proc.communicate(timeout=600)
    assert "Traceback" not in err, err
    return proc.returncode, err


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _proposed(root: Path, oracle: str) -> tuple[Path, Path, list[Path]]:
    """A config, a campaign directory with its first batch proposed, and a log of each proposal."""
    root.mkdir()
    config = root / "race.toml"
    config.write_text(f'output_dir = "{root / "runs"}"\n' + CONFIG + f'[oracle]\nkind = "{oracle}"\n')
    template = root / "template"
    assert main(["campaign", "propose", str(config), "--out", str(template), "--no-tracking"]) == 0
    proposals = pd.read_csv(template / "proposals" / "round-000.csv")
    logs = [_drive(row, root / f"log{i}.csv") for i, row in proposals.iterrows()]
    return config, template, logs


@pytest.fixture(scope="module")
def external(tmp_path_factory):
    return _proposed(tmp_path_factory.mktemp("lock") / "external", "external")


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    return _proposed(tmp_path_factory.mktemp("lock") / "simulated", "simulator")


@pytest.mark.parametrize("race", range(RACES))
def test_two_ingests_of_one_batch_record_both_logs(external, tmp_path, race, capsys):
    _, template, logs = external
    directory = tmp_path / "campaign"
    shutil.copytree(template, directory)
    procs = [_cli("campaign", "ingest", str(directory), str(log), "--no-tracking") for log in logs]
    results = [_finish(p) for p in procs]
    _outcome("ingest+ingest", race, [code for code, _ in results])
    state = CampaignState.load(directory)
    recorded = state.ingested + list(state.staged.values())
    for log, (code, err) in zip(logs, results, strict=True):
        if code == 0:
            assert recorded.count(_digest(log)) == 1, (race, results)
        else:
            assert code == 2 and "retry" in err and err.count("\n") == 1, (race, err)
            assert _digest(log) not in recorded
    if all(code == 0 for code, _ in results):  # the batch is complete: trained on, next batch proposed
        assert len(state.batches) == 1 and len(state.rounds) == 1 and state.pending
        samples = pd.read_parquet(directory / "samples.parquet")
        assert sorted(samples["pool_index"].unique()) == sorted(state.batches[0])
    assert not (directory / HOLDER_FILE).exists()


@pytest.mark.parametrize("race", range(RACES))
def test_an_ingest_during_campaign_run_resume(simulated, tmp_path, race):
    config, template, logs = simulated
    directory = tmp_path / "campaign"
    shutil.copytree(template, directory)
    pending = CampaignState.load(directory).pending
    run = _cli("campaign", "run", str(config), "--out", str(directory), "--resume", "--no-tracking")
    ingest = _cli("campaign", "ingest", str(directory), str(logs[0]), "--no-tracking", "--wait", "1")
    (run_code, run_err), (code, err) = _finish(run), _finish(ingest)
    _outcome("run+ingest", race, [run_code, code])
    assert run_code == 0, run_err
    state = CampaignState.load(directory)
    assert state.finished and len(state.taken) == 4
    samples = pd.read_parquet(directory / "samples.parquet")
    first = samples[(samples["batch"] == 0) & (samples["pool_index"] == pending[0])]
    log = read_recorded_log(logs[0])
    took_log = len(first) == len(log) and (first["speed"].to_numpy() == log["speed"].to_numpy()).all()
    if code == 0:  # it came first: the run took its log instead of simulating that maneuver
        assert state.ingested.count(_digest(logs[0])) == 1 and took_log
    else:  # the run came first and held the directory: the ingest waited 1 s, then said to retry
        assert code == 2 and "retry" in err and "pid" in err, err
        assert _digest(logs[0]) not in state.ingested and not took_log


@pytest.mark.parametrize("race", range(RACES))
def test_two_proposes_make_one_campaign_and_one_mlflow_run(simulated, tmp_path, race):
    config = tmp_path / "race.toml"
    uri = f"sqlite:///{tmp_path}/mlruns/mlflow.db"
    runs_dir = simulated[0].parent / "runs"  # the simulation cache of the fixture's campaign
    config.write_text(f'output_dir = "{runs_dir}"\n' + CONFIG + f'[tracking]\nuri = "{uri}"\n')
    tracker = Tracker(uri)  # the store exists before the race (its schema is not what is raced for)
    directory = tmp_path / "campaign"
    procs = [_cli("campaign", "propose", str(config), "--out", str(directory)) for _ in range(2)]
    results = [_finish(p) for p in procs]
    _outcome("propose+propose", race, [code for code, _ in results])
    # One starts the campaign; the other, let in after it, finds the campaign and says so (exit 2, one
    # error line naming --resume, after a warning if it waited for the lock); a --resume on a directory
    # with no campaign is refused before the race.
    assert sorted(code for code, _ in results) == [0, 2], results
    loser = next(err for code, err in results if code == 2).strip().splitlines()
    assert all(line.startswith("warning:") for line in loser[:-1]), loser  # waiting for the lock
    assert loser[-1].startswith("error:") and "holds a campaign already" in loser[-1], loser
    assert "--resume" in loser[-1], loser
    state = CampaignState.load(directory)
    runs = tracker.runs_tagged({"config": "race"})
    assert runs == [state.run_id]
    assert len(state.pending) == 2 and not (directory / HOLDER_FILE).exists()


def test_a_second_writer_waits_names_the_holder_then_exits_2(tmp_path):
    directory = tmp_path / "campaign"
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(directory), "60"], stdout=subprocess.PIPE,
                              text=True)  # fmt: skip
    try:
        assert holder.stdout.readline() == "held\n"
        config = tmp_path / "race.toml"
        config.write_text(f'output_dir = "{tmp_path / "runs"}"\n' + CONFIG)
        started = time.monotonic()
        code, err = _finish(_cli("campaign", "propose", str(config), "--out", str(directory), "--no-tracking",
                                 "--wait", "2"))  # fmt: skip
        waited = time.monotonic() - started
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 2, err  # one warning while it waits, one error
        assert "waiting up to 2 s" in lines[0]
        for part in (f"host {socket.gethostname()}", f"pid {holder.pid}", "since", "retry"):
            assert part in lines[1], err
        assert waited >= 2
        assert sorted(p.name for p in directory.iterdir()) == [LOCK_FILE, HOLDER_FILE]
    finally:
        holder.kill()
        holder.wait()


def test_a_lock_left_by_a_dead_process_or_an_expired_lease_is_taken_over(tmp_path):
    directory = tmp_path / "d"
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(directory), "600"], stdout=subprocess.PIPE,
                              text=True)  # fmt: skip
    assert holder.stdout.readline() == "held\n"
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait()
    assert read_holder(directory).pid == holder.pid  # its record stays behind
    taker = f"""
from activelearn.loop.lock import hold
with hold({str(directory)!r}, wait=0):
    print("taken")
"""
    assert subprocess.run([sys.executable, "-c", taker], capture_output=True, text=True).stdout == "taken\n"
    # A record of a holder on another host: a live lease blocks, an expired one is taken over.
    record = {
        "host": "other-host", "pid": 4242, "command": "activelearn campaign run x.toml", "since": time.time(),
        "renewed": time.time(), "lease": 60.0, "token": "feedfacefeedface",
    }  # fmt: skip
    (directory / HOLDER_FILE).write_text(json.dumps(record))
    blocked = subprocess.run([sys.executable, "-c", taker], capture_output=True, text=True)
    assert blocked.returncode != 0 and "other-host" in blocked.stderr and "pid 4242" in blocked.stderr
    record["renewed"] = time.time() - 61
    (directory / HOLDER_FILE).write_text(json.dumps(record))
    assert subprocess.run([sys.executable, "-c", taker], capture_output=True, text=True).stdout == "taken\n"
