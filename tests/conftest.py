"""Shared fixtures."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import settings

# Under pytest-xdist (`make test`: three workers on two cores, each starting CLI subprocesses), torch's
# default of one intra-op thread per core puts several busy threads on each core, which only fight:
# one thread per process, the rule compare's and tune's own workers follow, cut the CPU time of a
# two-file slice by 15 %. Set before anything imports torch; inherited by every subprocess. The tests of the
# threaded paths set their thread counts themselves.
if "PYTEST_XDIST_WORKER" in os.environ:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)

CACHE_ENV = "ACTIVELEARN_CACHE_DIR"  # activelearn.loop.collection.CACHE_ENV (not imported here: torch)
POSTGRES_ENV = "ACTIVELEARN_TEST_POSTGRES_URL"
MLFLOW_POSTGRES_ENV = "ACTIVELEARN_TEST_MLFLOW_POSTGRES_URL"

# Property tests (tests/test_fuzz.py) try the same examples on every run: derived from each test's
# source (derandomize), with no example database, so CI and every machine see identical inputs.
# `HYPOTHESIS_PROFILE=explore` draws fresh random examples, twenty times as many, to hunt locally.
_COMMON = dict(database=None, deadline=None, print_blob=True)
settings.register_profile("ci", derandomize=True, max_examples=100, **_COMMON)
settings.register_profile("explore", max_examples=2000, **_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


# `make test` runs the files on three pytest-xdist workers, a whole file at a time, in collection order.
# The longest files go first (longest-processing-time-first scheduling), so that no worker is left
# running one of them alone at the end; measured on 2 cores (three workers, `--durations=0` summed by
# file, 2026-11-30: 201 s down to 30 s), longest first.
LONGEST_FILES = (
    "test_benchmarks.py", "test_tuning.py", "test_ray.py", "test_benchmarks_campaigns.py",
    "test_dynamic_physics.py", "test_dynamics.py", "test_calibration.py", "test_tracking_outage.py",
    "test_campaign_lock.py", "test_campaign.py", "test_surrogate.py", "test_physics.py",
    "test_checkpoint_faults.py", "test_training.py", "test_safety.py", "test_asktell.py", "test_fuzz.py",
)  # fmt: skip


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Long files first (stable: each file keeps its own order, the others theirs)."""
    rank = {name: i for i, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


@pytest.fixture(scope="session", autouse=True)
def shared_simulation_cache(tmp_path_factory):
    """One simulation cache for the whole run, both xdist workers and every CLI subprocess included
    (`ACTIVELEARN_CACHE_DIR`): the suite simulates each maneuver once, not once per test directory.
    Tests of where the cache goes by default take the `default_cache` fixture."""
    base = tmp_path_factory.getbasetemp()
    root = (base.parent if "PYTEST_XDIST_WORKER" in os.environ else base) / "simulation-cache"
    os.environ[CACHE_ENV] = str(root)
    yield root
    os.environ.pop(CACHE_ENV, None)


@pytest.fixture
def default_cache(monkeypatch: pytest.MonkeyPatch) -> None:
    """Simulated logs cached where a user's would be (`<output_dir>/cache`), not in the suite's one."""
    monkeypatch.delenv(CACHE_ENV, raising=False)


SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"
PROJECT_STORE = Path(__file__).resolve().parents[1] / "mlruns"  # the README's tracking store


def _store_snapshot() -> dict[str, tuple[int, int]]:
    """Every file of the project's own MLflow store with its size and modification time."""
    if not PROJECT_STORE.exists():
        return {}
    return {
        str(path.relative_to(PROJECT_STORE)): (path.stat().st_size, path.stat().st_mtime_ns)
        for path in PROJECT_STORE.rglob("*")
        if path.is_file()
    }


@pytest.fixture(scope="session", autouse=True)
def project_store_untouched():
    """The suite tracks into temporary stores only: it fails if the project's `mlruns/` changed."""
    before = _store_snapshot()
    yield
    after = _store_snapshot()
    changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
    assert not changed, f"the test suite wrote into the project's tracking store mlruns/: {changed[:5]}"


def smoke_file(tmp_path: Path, max_maneuvers: int = 7) -> Path:
    """The smoke config writing under tmp_path (output_dir runs/), with `max_maneuvers` new maneuvers."""
    text = SMOKE.read_text().replace("max_maneuvers = 7", f"max_maneuvers = {max_maneuvers}")
    path = tmp_path / "smoke.toml"
    path.write_text(f'output_dir = "{tmp_path / "runs"}"\n' + text)
    return path


def predict_slalom_fan(model: Path, cwd: Path) -> subprocess.CompletedProcess:
    """`activelearn predict` with a campaign's (or a saved) model on a 6-s slalom (0.6, 0.3 rad), 8
    samples, its fan figure written to cwd/fan.png."""
    return subprocess.run(
        [sys.executable, "-m", "activelearn.cli", "predict", "--model", str(model), "--maneuver", "slalom",
         "--throttle", "0.6", "--steering", "0.3", "--duration", "6", "--samples", "8",
         "--out", str(cwd / "fan.png")],
        capture_output=True, text=True, timeout=300, cwd=cwd,
    )  # fmt: skip


# What the README promises for an unreachable tracking server or storage: one error within 5 s, the
# client's one timeout. On top of it a command spends time of its own (config, imports, the error),
# which on a loaded machine takes seconds, not one: 4 s of slack. That stays below two timeouts, so a
# client that retries (5 + 5 s) still fails the check.
UNREACHABLE_SECONDS = 5.0 + 4.0


@pytest.fixture
def silent_server():
    """A loopback port where connections open and then hear nothing (a server hung or firewalled).

    Unlike a closed port, which refuses at once, every client has to time out here.
    """
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(64)  # the kernel completes handshakes into the backlog; nobody ever accepts
        yield server.getsockname()[1]


@pytest.fixture(scope="session")
def postgres_url() -> str:
    """URL of a PostgreSQL database the tests may write to (set up by .ci/run).

    Without it the test is skipped on a developer machine, but fails in CI (`CI` set): there the
    server is part of the job, and a silently skipped test would hide that it did not start.
    """
    return _database_url(POSTGRES_ENV)


@pytest.fixture(scope="session")
def mlflow_postgres_url() -> str:
    """URL of a second PostgreSQL database, for an MLflow tracking server (set up by .ci/run)."""
    return _database_url(MLFLOW_POSTGRES_ENV)


def _database_url(variable: str) -> str:
    url = os.environ.get(variable)
    if not url:
        skip_or_fail(f"{variable} is not set: run the suite through .ci/run, which starts PostgreSQL")
    return url


@pytest.fixture(scope="session")
def c_kernels():
    """The compiled C kernels (activelearn/numerics/native), for every test that runs or compares them.

    The one rule for a machine without a C compiler (cc, gcc or clang): such a test is skipped on a
    developer machine, with the reason, and fails in CI (`CI` set), where the compiler is part of the
    set-up; everything else runs on the torch path, as activelearn itself does there.
    """
    from activelearn.numerics import native  # here, not at the top: conftest imports no torch

    lib = native.library()
    if lib is None:
        skip_or_fail("no working C compiler (cc, gcc or clang): the compiled kernels cannot be built")
    return lib


@pytest.fixture
def failing_compiler(monkeypatch: pytest.MonkeyPatch, tmp_path: Path):
    """`within(owner, library)`: a context in which `library()` is built by a compiler that fails every
    compile (`false`, on every machine) into an empty cache, `owner` being the module whose `CACHE_DIR`
    and `COMPILERS` it reads; the real ones and a fresh `library()` after."""

    @contextlib.contextmanager
    def within(owner, library):
        monkeypatch.setattr(owner, "CACHE_DIR", tmp_path / "failing-build")
        monkeypatch.setattr(owner, "COMPILERS", ("false",))
        library.cache_clear()
        try:
            yield
        finally:
            monkeypatch.undo()
            library.cache_clear()

    return within


def flat_weights(model):
    """Every parameter of a torch model, flattened into one vector (a tensor)."""
    import torch

    return torch.cat([p.detach().reshape(-1) for p in model.parameters()])


def skip_or_fail(message: str, *, allow_module_level: bool = False) -> None:
    """Skip on a developer machine what CI (`CI` set) must run: there a missing part fails the test."""
    if os.environ.get("CI"):
        pytest.fail(message)
    pytest.skip(message, allow_module_level=allow_module_level)
