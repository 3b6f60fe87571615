"""`compare --executor ray` on a real local Ray cluster: the process executor's numbers, lost workers retried.

One head node (`ray start --head --block`, this machine's CPUs) serves the module; it is stopped by
killing its process group afterwards, so no other Ray cluster on the machine is touched.
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import pytest

from activelearn.cli import main
from activelearn.config import load_config
from activelearn.data import read_table
from activelearn.loop.state import SAMPLES_FILE, CampaignState
from activelearn.studies.compare import compare
from tests.conftest import skip_or_fail, smoke_file

pytestmark = pytest.mark.slow  # a local Ray cluster in every test

try:
    import ray  # noqa: F401
except ImportError:  # skipped on a developer machine without Ray; in CI (`CI` set) the module fails
    skip_or_fail("Ray is in the dev extra; install it with pip install -e '.[dev]'", allow_module_level=True)

ACTIVELEARN = Path(sys.executable).with_name("activelearn")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ray_head():
    """The address of a Ray head node started for these tests (2 CPUs, no dashboard)."""
    # Ray >= 2.59 authenticates clients with a token: the head, this process and every `compare` it
    # starts share one through the environment, as the nodes of a real cluster would.
    saved = {k: os.environ.get(k) for k in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN")}
    os.environ.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(16))
    port = _free_port()
    temp_dir = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths have a length limit
    head = subprocess.Popen(
        [str(Path(sys.executable).with_name("ray")), "start", "--head", "--block", f"--port={port}",
         "--num-cpus=2", "--include-dashboard=false", "--disable-usage-stats", f"--temp-dir={temp_dir}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    address = f"127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:  # the head is up once a driver can join it
            if head.poll() is not None:
                pytest.fail(f"ray start exited with {head.returncode}")
            probe = subprocess.run(
                [sys.executable, "-c", f"import ray; ray.init(address={address!r}); ray.shutdown()"],
                capture_output=True, timeout=60,
            )  # fmt: skip
            if probe.returncode == 0:
                break
            if time.monotonic() > deadline:
                pytest.fail(f"the Ray head did not come up: {probe.stderr.decode()[-500:]}")
            time.sleep(2)
        yield address
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        try:  # `ray start --block` took the whole 30 s it was once given here: the suite's slowest step
            head.wait(timeout=5)
        except subprocess.TimeoutExpired:
            os.killpg(head.pid, signal.SIGKILL)
            head.wait()
        subprocess.run(["rm", "-rf", temp_dir], check=False)
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _rounds(directory: Path, strategy: str, seeds: range) -> dict[int, list[float]]:
    return {
        seed: [r["test_rmse"] for r in CampaignState.load(directory / strategy / f"seed{seed}").rounds]
        for seed in seeds
    }


@pytest.fixture(scope="module")
def process_reference(tmp_path_factory):
    """Per-round test RMSE of uniform, seeds 0-1, 3 rounds, run by two local processes."""
    tmp_path = tmp_path_factory.mktemp("process")
    cfg = load_config(smoke_file(tmp_path, max_maneuvers=7))
    compare(cfg, ["uniform"], [0, 1], directory=tmp_path / "out", workers=2, tracking=False)
    return cfg, _rounds(tmp_path / "out", "uniform", range(2))


def _ray_compare(tmp_path: Path, address: str, out: Path, seeds: int = 2) -> list[str]:
    """The CLI command comparing uniform over seeds 0-1 (3 rounds) on the Ray cluster at `address`."""
    config = smoke_file(tmp_path, max_maneuvers=7)
    return [str(ACTIVELEARN), "compare", str(config), "--strategies", "uniform", "--seeds", str(seeds),
            "--no-tracking", "--executor", "ray", "--ray-address", address, "--out", str(out)]


def test_ray_executor_gives_the_process_executors_numbers(tmp_path, ray_head, process_reference):
    _, reference = process_reference
    out = tmp_path / "ray"
    done = subprocess.run(
        _ray_compare(tmp_path, ray_head, out),
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert _rounds(out, "uniform", range(2)) == reference
    assert len(reference[0]) == 3


def test_ray_address_local_starts_an_in_process_cluster_with_the_same_numbers(tmp_path, process_reference):
    """`--ray-address local`: no cluster to join, Ray started inside the command (one seed: small)."""
    _, reference = process_reference
    out = tmp_path / "local"
    command = [*_ray_compare(tmp_path, "local", out, seeds=1), "--workers", "1"]
    environment = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}  # no cluster known
    done = subprocess.run(command, capture_output=True, text=True, timeout=600, env=environment)
    assert done.returncode == 0, done.stderr[-2000:]
    assert _rounds(out, "uniform", range(1)) == {0: reference[0]}


def _ray_job_pids(address: str) -> list[int]:
    """Processes of Ray workers running a campaign (Ray titles them after the task's function) in the
    cluster at `address` alone: those whose parent chain reaches the `ray start --head --port=PORT` this
    test process started (the fixture's head), never the workers of another cluster on the machine."""
    port = f"--port={address.rsplit(':', 1)[1]}".encode()
    parents, heads, jobs = {}, set(), []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmdline = (entry / "cmdline").read_bytes()
                stat = (entry / "stat").read_text()
            except OSError:  # it ended while being read
                continue
            pid = int(entry.name)
            # "pid (comm) state ppid ...", where comm may hold spaces and ")"
            parents[pid] = int(stat.rsplit(")", 1)[1].split()[1])
            args = cmdline.split(b"\0")
            if b"--head" in args and port in args and parents[pid] == os.getpid():
                heads.add(pid)
            if cmdline.startswith(b"ray::_run_job"):
                jobs.append(pid)

    def ours(pid: int) -> bool:
        while pid > 1:
            if pid in heads:
                return True
            pid = parents.get(pid, 0)
        return False

    return [pid for pid in jobs if ours(pid)]


def test_a_killed_ray_worker_is_retried_and_its_campaign_resumes(tmp_path, ray_head, process_reference):
    _, reference = process_reference
    out = tmp_path / "ray"
    driver = subprocess.Popen(
        _ray_compare(tmp_path, ray_head, out),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    # Kill every worker running a campaign once seed 0 has checkpointed a round but not finished.
    state_file = out / "uniform" / "seed0" / "state.json"
    killed: list[int] = []
    deadline = time.monotonic() + 600
    while not killed and time.monotonic() < deadline and driver.poll() is None:
        if state_file.exists():
            state = CampaignState.load(state_file.parent)
            if state.finished:
                break
            if state.rounds:
                # What the killed worker had checkpointed: a resumed campaign keeps it, a restart
                # from scratch would redo it (same numbers, but round 0's wall_seconds would differ).
                checkpointed_round = state.rounds[0]
                checkpointed_batches = len(state.batches)
                checkpointed_samples = _committed_samples(state_file.parent, checkpointed_batches)
                for pid in _ray_job_pids(ray_head):
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except ProcessLookupError:  # it ended between the listing and the kill
                        continue
                    killed.append(pid)
        time.sleep(0.05)
    _, stderr = driver.communicate(timeout=600)
    assert killed, "the campaign finished before a worker could be killed: nothing was tested"
    assert driver.returncode == 0, stderr[-2000:]
    assert _rounds(out, "uniform", range(2)) == reference
    final = CampaignState.load(state_file.parent)
    # Round 0's record may since have gained the next batch's calibration checks, nothing else.
    kept_round = {key: final.rounds[0].get(key) for key in checkpointed_round}
    assert json.dumps(kept_round, sort_keys=True) == json.dumps(checkpointed_round, sort_keys=True)
    kept = _committed_samples(state_file.parent, checkpointed_batches)
    assert _hash(kept) == _hash(checkpointed_samples)


def _committed_samples(directory: Path, n_batches: int) -> pd.DataFrame:
    """The sample rows of a campaign directory's first `n_batches` batches."""
    samples = read_table(directory / SAMPLES_FILE)
    return samples[samples["batch"] < n_batches].reset_index(drop=True)


def _hash(frame: pd.DataFrame) -> int:
    return int(pd.util.hash_pandas_object(frame).sum())


def test_ray_missing_or_unknown_executor_is_one_clear_error(tmp_path, monkeypatch, capsys, default_cache):
    path = smoke_file(tmp_path)
    common = ["compare", str(path), "--no-tracking", "--out"]
    assert main([*common, str(tmp_path / "a"), "--executor", "dask"]) == 2
    assert "--executor" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "ray", None)  # what a machine without Ray sees on import
    assert main([*common, str(tmp_path / "b"), "--executor", "ray"]) == 2
    err = capsys.readouterr().err
    assert "Ray is not installed" in err and "activelearn[cluster]" in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    assert not (tmp_path / "runs").exists()  # nothing simulated either


@pytest.mark.parametrize(
    ("token_env", "says"),
    [
        ({"RAY_AUTH_MODE": None, "RAY_AUTH_TOKEN": None}, "this command sent none"),
        ({"RAY_AUTH_TOKEN": None}, "none was found"),
        ({"RAY_AUTH_TOKEN": "0" * 32}, "refused this one"),
    ],
)
def test_a_head_that_wants_a_token_says_so_and_how_to_pass_it(tmp_path, ray_head, token_env, says):
    """The module's head authenticates with a token (Ray >= 2.59): a command without it, or with another,
    is one line saying the head wants a token and how to give it, not Ray's bare "Failed to connect"."""
    env = {**os.environ, "HOME": str(tmp_path), "RAY_gcs_server_port_wait_time_s": "2"}  # no ~/.ray token
    for key, value in token_env.items():
        env.pop(key) if value is None else env.update({key: value})
    done = subprocess.run(
        _ray_compare(tmp_path, ray_head, tmp_path / "out", seeds=1),
        capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr[-2000:]
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, done.stderr[-2000:]
    line = errors[0]
    assert line.startswith("error: --ray-address: cannot join the Ray cluster: the head wants an auth token")
    assert says in line and "export RAY_AUTH_MODE=token and RAY_AUTH_TOKEN=" in line
    assert "ray get-auth-token" in line and ray_head in line
