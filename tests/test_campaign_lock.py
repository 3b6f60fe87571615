"""One writer per campaign directory: real CLI processes racing for one campaign.

The two writers of a race start behind a barrier: each is forked from a server that has imported the CLI
and what its commands load (tests/racers.py), says it is ready, and waits for a go-file the test makes once
both are; then both call the CLI's `main` at once. Each race runs RACES times (ACTIVELEARN_RACES, default
5; the issue's check is 20 in a row). A race records every log exactly once, or the command that lost
exits non-zero and says to retry; at least one wins.
The lease tests stall a holder whose OS lock does not reach the other process (as on a file system
whose locks stay on one host) and check that a takeover stops it without writing; they follow the
processes by the lines those print (and a flag in a shared file), never by sleeps.
Only the races and the tests that start the CLI are slow: the lock's own tests run in `make test-fast`.
"""

from __future__ import annotations

import fcntl
import hashlib
import itertools
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

from activelearn.cli import main
from activelearn.data import read_recorded_log
from activelearn.loop.lock import HOLDER_FILE, LOCK_FILE, DirectoryLock, lease_file, read_holder
from activelearn.loop.state import CampaignState
from activelearn.studies.tracking import Tracker
from tests import racers
from tests.test_asktell import _drive

RACES = int(os.environ.get("ACTIVELEARN_RACES", "5"))
OUTCOMES = os.environ.get("ACTIVELEARN_RACES_LOG")  # a file to append each race's outcome to


def _outcome(test: str, race: int, codes: list[int]) -> None:
    if OUTCOMES:
        with open(OUTCOMES, "a") as f:
            f.write(json.dumps({"test": test, "race": race, "codes": codes, "t": time.time()}) + "\n")


# As small as the races allow: two maneuvers a batch (two logs to ingest at once), two batches (a run
# with a batch after the raced one), a few epochs; a race costs the two processes' start-up and one step.
CONFIG = """
name = "race"
strategy = "max_epistemic"
[pool]
kinds = ["straight", "skidpad"]
throttles = [0.3, 0.6, 0.9]
steerings = [0.15, 0.35]
duration = 5.0
[data]
stride = 10
[design]
initial = 2
per_round = 2
max_maneuvers = 4
[acquisition]
n_samples = 4
grid_throttles = 3
grid_steerings = 3
[training]
epochs = 3
[test]
throttles = [0.45]
steerings = [0.25]
duration = 4.0
rollout_samples = 4
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


@pytest.mark.slow  # processes racing for one campaign directory
@pytest.mark.parametrize("race", range(RACES))
def test_two_ingests_of_one_batch_record_both_logs(external, tmp_path, race, capsys):
    _, template, logs = external
    directory = tmp_path / "campaign"
    shutil.copytree(template, directory)
    results = racers.race(tmp_path / "go", *(["campaign", "ingest", str(directory), str(log), "--no-tracking"]
                                       for log in logs))  # fmt: skip
    _outcome("ingest+ingest", race, [code for code, _ in results])
    assert any(code == 0 for code, _ in results), results  # one of them got in, at least
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


@pytest.mark.slow
@pytest.mark.parametrize("race", range(RACES))
def test_an_ingest_during_campaign_run_resume(simulated, tmp_path, race):
    config, template, logs = simulated
    directory = tmp_path / "campaign"
    shutil.copytree(template, directory)
    pending = CampaignState.load(directory).pending
    (run_code, run_err), (code, err) = racers.race(
        tmp_path / "go",
        ["campaign", "run", str(config), "--out", str(directory), "--resume", "--no-tracking"],
        ["campaign", "ingest", str(directory), str(logs[0]), "--no-tracking", "--wait", "1"],
    )
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


@pytest.mark.slow
@pytest.mark.parametrize("race", range(RACES))
def test_two_proposes_make_one_campaign_and_one_mlflow_run(simulated, tmp_path, race):
    config = tmp_path / "race.toml"
    uri = f"sqlite:///{tmp_path}/mlruns/mlflow.db"
    runs_dir = simulated[0].parent / "runs"  # the simulation cache of the fixture's campaign
    config.write_text(f'output_dir = "{runs_dir}"\n' + CONFIG + f'[tracking]\nuri = "{uri}"\n')
    tracker = Tracker(uri)  # the store exists before the race (its schema is not what is raced for)
    directory = tmp_path / "campaign"
    results = racers.race(tmp_path / "go", *(["campaign", "propose", str(config), "--out", str(directory)]
                                       for _ in range(2)))  # fmt: skip
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


@pytest.mark.slow  # the CLI in a subprocess, and a 2-s wait
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
    # Its renewals live in a lease file of its token: a fresh one keeps the record alive ...
    lease = lease_file(directory, record["token"])
    record["renewed"] = time.time() - 61
    (directory / HOLDER_FILE).write_text(json.dumps(record))
    lease.write_text(json.dumps({"renewed": time.time()}))
    blocked = subprocess.run([sys.executable, "-c", taker], capture_output=True, text=True)
    assert blocked.returncode != 0 and "other-host" in blocked.stderr
    # ... an expired one does not, and the taker clears it away with the record
    lease.write_text(json.dumps({"renewed": time.time() - 61}))
    assert subprocess.run([sys.executable, "-c", taker], capture_output=True, text=True).stdout == "taken\n"
    assert not lease.exists() and not (directory / HOLDER_FILE).exists()


# A process holding DIR's lock with a short lease, for the lease tests. It drops its OS lock first: on a
# file system whose locks stay on one host (sshfs, SMB without byte-range locks, FUSE object stores) a
# writer on another host gets the flock too, and only the lease record keeps it out. Dropping this
# process's flock (`local`) makes every other process here such a writer. With `renewals` it prints a
# line at each renewal of its lease (the lock's own method, observed). It then waits for a line on stdin:
# empty, it commits a campaign state at once; a file's name, it says "computing" and computes (spins,
# holding the GIL, as in a training step) until the file's first byte is no longer 0, then commits.
# Taken over meanwhile, it exits 3 with the message.
_LEASED = """
import fcntl, mmap, sys, threading
from pathlib import Path
from activelearn.loop.lock import CampaignLocked, DirectoryLock, hold
from activelearn.loop.state import CampaignState
directory, lease, name, wait, local, renewals = Path(sys.argv[1]), float(sys.argv[2]), *sys.argv[3:]
lines = threading.Lock()  # the renewer thread prints too: whole lines, one at a time

def say(*words):
    with lines:
        sys.stdout.write(" ".join(map(str, words)) + "\\n")
        sys.stdout.flush()

if renewals == "renewals":
    renew = DirectoryLock._renew_lease

    def renew_and_say(lock):
        renew(lock)
        say("renewed", repr(lock._written))

    DirectoryLock._renew_lease = renew_and_say
with hold(directory, wait=float(wait), lease=lease, on_wait=lambda h: say("waiting", h.pid)) as held:
    if local == "local":
        fcntl.flock(held._fd, fcntl.LOCK_UN)  # a file system whose locks do not reach other hosts
    say("holds", held._holder.token)
    flag = sys.stdin.readline().strip()
    if flag:
        with open(flag, "rb") as f, mmap.mmap(f.fileno(), 1, access=mmap.ACCESS_READ) as raised:
            say("computing")
            while raised[0] == 0:  # busy: the lock's renewer runs only between (a read, no system call)
                pass
    try:
        CampaignState(config_hash=name, strategy="uniform", seed=0).save(directory)
    except CampaignLocked as exc:
        say(exc)
        sys.exit(3)
    say("wrote")
"""

_TAKE = """
import sys
from activelearn.loop.lock import CampaignLocked, hold
tell = (lambda holder: print("waiting", holder.pid, flush=True)) if sys.argv[3:] == ["tell"] else None
try:
    with hold(sys.argv[1], wait=float(sys.argv[2]), on_wait=tell):
        print("taken", flush=True)
except CampaignLocked as exc:
    print(exc, flush=True)
    sys.exit(3)
"""


def _leased(directory: Path, lease: float, name: str, wait: float = 0.0, local: bool = False,
            renewals: bool = False) -> subprocess.Popen:  # fmt: skip
    argv = [str(directory), str(lease), name, str(wait), "local" if local else "shared",
            "renewals" if renewals else "quiet"]  # fmt: skip
    return subprocess.Popen([sys.executable, "-c", _LEASED, *argv],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip


def _line(proc: subprocess.Popen, prefix: str) -> list[str]:
    """The next stdout line of `proc`, which must start with `prefix`, split into words."""
    line = proc.stdout.readline()
    if not line.startswith(prefix):
        proc.kill()
        pytest.fail(f"expected {prefix!r}, got {line!r}: {proc.communicate(timeout=60)[1][-2000:]}")
    return line.split()


def _tell(proc: subprocess.Popen, line: str) -> None:
    proc.stdin.write(f"{line}\n")
    proc.stdin.flush()


def _raise(flag: Path) -> None:
    """End a `_LEASED` computation: its flag's first byte, written in place (the holder maps the file)."""
    with open(flag, "r+b") as f:
        f.write(b"\1")


def _stall(proc: subprocess.Popen) -> None:
    """Stop `proc` (SIGSTOP) and return once it is stopped: the record then holds the last it wrote."""
    os.kill(proc.pid, signal.SIGSTOP)
    while Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "T":
        time.sleep(0.01)


def test_a_holder_renews_its_short_lease_and_keeps_another_process_out(tmp_path):
    """Renewed every lease / 3 (0.5 s), the lease keeps a taker waiting two leases out; the holder's
    renewer would have to miss two renewals in a row on a loaded machine for the taker to get in."""
    directory, lease = tmp_path / "d", 1.5
    directory.mkdir()
    holder = _leased(directory, lease, "holder", local=True, renewals=True)  # no flock: only the lease holds
    try:
        token = _line(holder, "holds")[1]
        taker = subprocess.Popen([sys.executable, "-c", _TAKE, str(directory), str(2 * lease), "tell"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
        assert _line(taker, "waiting")[1] == str(holder.pid)  # it found the holder's lease live ...
        out, err = taker.communicate(timeout=120)
        # ... waited its 2 leases and gave up, naming the holder
        assert taker.returncode == 3 and f"pid {holder.pid}" in out and "retry" in out, (out, err)
        assert read_holder(directory).token == token
        _tell(holder, "")
        renewals = []
        while (words := _line(holder, ""))[0] == "renewed":
            renewals.append(float(words[1]))
        assert words == ["wrote"], words  # its lease held throughout: it still commits
        # renewed throughout the taker's wait of two leases, never a lease apart (the lease never lapsed).
        # Not "spanning 2 leases": renewals every lease / 3 or a little more seen in a 2-lease window span
        # less (six spanned 2.5 s of a 3-s wait on a loaded machine).
        gaps = [b - a for a, b in itertools.pairwise(renewals)]
        assert len(renewals) >= 5 and max(gaps) < lease and renewals[-1] - renewals[0] >= lease, renewals
        assert holder.wait(timeout=60) == 0
        assert json.loads((directory / "state.json").read_text())["config_hash"] == "holder"
        assert not (directory / HOLDER_FILE).exists()
    finally:
        holder.kill()
        holder.wait()


def test_a_stalled_holder_taken_over_stops_without_writing(tmp_path):
    directory, lease = tmp_path / "d", 0.6
    directory.mkdir()
    stalled = _leased(directory, lease, "stalled", local=True)
    taker = None
    try:
        stalled_token = _line(stalled, "holds")[1]
        taker = _leased(directory, 60.0, "taker", wait=60)
        assert _line(taker, "waiting")[1] == str(stalled.pid)  # the fresh lease keeps it out (no flock)
        flag = tmp_path / "flag"
        flag.write_bytes(b"\0")
        _tell(stalled, str(flag))
        _line(stalled, "computing")  # it computes until the flag is raised ...
        _stall(stalled)  # ... and is stalled in the middle, for longer than its lease
        last = read_holder(directory)
        assert last.token == stalled_token
        taker_token = _line(taker, "holds")[1]
        taken = read_holder(directory)
        assert taken.token == taker_token and taken.since - last.renewed > lease  # once the lease ran out
        # Resumed, the stalled holder finishes its step at once and commits, before its renewer thread
        # gets a turn: it must find out itself that it was taken over.
        _raise(flag)
        os.kill(stalled.pid, signal.SIGCONT)
        message = " ".join(_line(stalled, f"{directory}:"))
        assert "took this campaign over" in message and "stops without writing" in message, message
        assert stalled.wait(timeout=60) == 3
        assert not (directory / "state.json").exists()
        # Its renewer woke with it and did not write its record back, nor did its release remove the taker's.
        record = read_holder(directory)
        assert (record.token, record.pid, record.since) == (taker_token, taker.pid, taken.since), record
        _tell(taker, "")
        _line(taker, "wrote")  # the taker still holds the directory and commits
        assert taker.wait(timeout=60) == 0
        assert json.loads((directory / "state.json").read_text())["config_hash"] == "taker"
    finally:
        for proc in (stalled, taker):
            if proc is not None:
                proc.kill()
                proc.wait()


def test_a_stalled_holder_whose_taker_came_and_went_stops_without_writing(tmp_path):
    """No record to read once the taker has released the directory: the lease the stalled holder let run
    out is what tells it that it no longer holds the lock."""
    directory, lease = tmp_path / "d", 0.6
    directory.mkdir()
    stalled = _leased(directory, lease, "stalled", local=True)
    try:
        _line(stalled, "holds")
        _stall(stalled)
        taker = subprocess.run([sys.executable, "-c", _TAKE, str(directory), "60"], capture_output=True,
                               text=True, timeout=120)  # fmt: skip
        assert taker.stdout == "taken\n", taker.stderr  # it took the stale lease over, and released it
        assert not (directory / HOLDER_FILE).exists()
        _tell(stalled, "")
        os.kill(stalled.pid, signal.SIGCONT)
        message = " ".join(_line(stalled, f"{directory}:"))
        assert "took this campaign over" in message and "stops without writing" in message, message
        assert stalled.wait(timeout=60) == 3
        assert not (directory / "state.json").exists() and not (directory / HOLDER_FILE).exists()
    finally:
        stalled.kill()
        stalled.wait()


def test_a_renewer_stalled_between_its_check_and_its_write_leaves_the_takers_record(tmp_path):
    """The stall falls where no check can see it: the renewer has found its record its own and is stopped
    before it writes. Woken after a taker has taken the stale lease over, its write must not replace the
    taker's record, and its release must not remove it."""
    directory, lease = tmp_path / "d", 0.3
    stalled = DirectoryLock(directory, lease=lease)
    stalled.acquire(wait=0)
    fcntl.flock(stalled._fd, fcntl.LOCK_UN)  # a file system whose locks do not reach the taker
    checked, wake = threading.Event(), threading.Event()
    really_held = stalled.held

    def held_then_stall() -> bool:
        answer = really_held()
        if threading.current_thread() is stalled._renewer and not checked.is_set():
            checked.set()  # the renewer's check passed ...
            wake.wait(60)  # ... and it stalls before its write
        return answer

    stalled.held = held_then_stall  # type: ignore[method-assign]
    taker = DirectoryLock(directory, lease=60.0)
    try:
        assert checked.wait(60) and really_held()
        taker.acquire(wait=10 * lease)  # its lease runs out while the renewer is stopped
        taken = read_holder(directory)
        assert taken is not None and taken.token == taker._holder.token
        wake.set()
        stalled._stop.set()
        stalled._renewer.join(60)  # it renewed once more, and found out at its next turn, or not at all
        assert read_holder(directory).token == taken.token and taker.held() and not really_held()
        stalled.release()
        record = read_holder(directory)
        assert record is not None and (record.token, record.since) == (taken.token, taken.since)
        assert not lease_file(directory, stalled._holder.token).exists()
    finally:
        wake.set()
        stalled.release()
        taker.release()
    assert sorted(p.name for p in directory.iterdir()) == [LOCK_FILE]
