"""Local worker processes (activelearn.studies.processes): fresh processes from a preloaded fork server
that still see what the parent sees when a job is handed out (environment, working directory)."""

from __future__ import annotations

import os
import signal
import sys

import pytest

from activelearn.studies import processes
from activelearn.studies.executors import run_jobs
from activelearn.studies.processes import PRELOAD


def _what_a_worker_sees(name: str) -> tuple[int, str | None, str, bool]:
    return os.getpid(), os.environ.get(name), os.getcwd(), all(module in sys.modules for module in PRELOAD)


def test_a_worker_sees_the_environment_and_directory_of_when_its_job_was_handed_out(tmp_path, monkeypatch):
    name = "ACTIVELEARN_TEST_WORKER_ENV"
    monkeypatch.setenv(name, "first")
    first = dict(run_jobs(_what_a_worker_sees, [(k, (name,)) for k in range(2)], workers=2))
    assert {seen[1] for seen in first.values()} == {"first"}
    assert all(seen[0] != os.getpid() for seen in first.values())  # not this process
    assert all(seen[3] for seen in first.values())  # the heavy imports came with the process
    # The fork server started with the first call and kept that call's environment and directory: a
    # later change here must still reach the next call's workers, as with freshly spawned processes.
    monkeypatch.setenv(name, "second")
    monkeypatch.chdir(tmp_path)
    second = dict(run_jobs(_what_a_worker_sees, [(k, (name,)) for k in range(2)], workers=2))
    assert {seen[1:3] for seen in second.values()} == {("second", str(tmp_path))}
    monkeypatch.delenv(name)
    third = dict(run_jobs(_what_a_worker_sees, [(k, (name,)) for k in range(2)], workers=2))
    assert {seen[1] for seen in third.values()} == {None}


@pytest.mark.parametrize("workers", [1, 2])
def test_a_jobs_error_reaches_the_caller(workers):
    with pytest.raises(ValueError, match="invalid literal"):
        dict(run_jobs(int, [(0, ("1",)), (1, ("x",))], workers=workers))


def test_the_fork_server_ignores_ctrl_c_while_it_imports_and_its_workers_do_not(tmp_path, monkeypatch):
    module = tmp_path / "interrupts_on_import.py"
    module.write_text("import os, signal\nos.kill(os.getpid(), signal.SIGINT)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(processes, "PRELOAD", ("interrupts_on_import",))
    before = signal.getsignal(signal.SIGINT)
    processes.preload_quietly()  # a Ctrl-C mid-import: no KeyboardInterrupt, no traceback
    assert "interrupts_on_import" in sys.modules
    assert signal.getsignal(signal.SIGINT) is before  # what the workers inherit: Ctrl-C stops them


def test_a_worker_orphaned_at_its_start_exits_quietly_and_other_errors_are_printed(tmp_path, monkeypatch):
    """A worker that unpickles its pool's queues after the command removed its semaphores (a Ctrl-C as the
    fork server forks it) fails in SemLock.__setstate__: the fork server's hook prints nothing for that
    one failure and prints every other error as before."""
    import multiprocessing.synchronize

    lock = multiprocessing.synchronize.Lock.__new__(multiprocessing.synchronize.Lock)
    name = f"/activelearn-gone-{os.getpid()}"  # no semaphore of that name exists
    with pytest.raises(FileNotFoundError) as raised:
        lock.__setstate__((0, 1, 1, name))
    gone = raised.value
    with pytest.raises(FileNotFoundError) as raised:
        open(tmp_path / "missing")
    missing_file = raised.value
    with pytest.raises(ValueError) as raised:
        int("x")
    other = raised.value
    assert processes.orphaned(gone, gone.__traceback__)
    assert not processes.orphaned(missing_file, missing_file.__traceback__)
    assert not processes.orphaned(other, other.__traceback__)
    printed: list[BaseException] = []
    monkeypatch.setattr(sys, "excepthook", lambda kind, error, trace: printed.append(error))
    processes.quiet_orphans()
    for error in (gone, missing_file, other):
        sys.excepthook(type(error), error, error.__traceback__)
    assert printed == [missing_file, other]
