"""CLI processes that race: forked from one server that has imported the CLI already.

A race needs two real processes that reach a lock at the same moment. Started with `python -c`, each
spends ~5 s importing the CLI and what its commands load (torch, MLflow, matplotlib) before the race,
and a race runs many times. Here a forkserver (`multiprocessing`'s own) imports all of it once per test
worker; every racer is a fresh process forked from it, with its own pid and file locks, that calls the
CLI's `main` exactly as `python -m activelearn.cli` does. Each says it is ready (a file), waits for the
go-file, then runs its command; its stdout and stderr go to files, its exit status is the CLI's.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time
from pathlib import Path

# What a racer imports before the race: the CLI and the modules its commands load on demand.
PRELOAD = ["activelearn.cli", "activelearn.loop.asktell", "activelearn.plots", "activelearn.studies.tracking"]

_CONTEXT = multiprocessing.get_context("forkserver")
_CONTEXT.set_forkserver_preload([*PRELOAD, __name__])


def _run(argv: list[str], go: str, ready: str, out: str, err: str) -> None:
    """In the racer: stdout and stderr to files, say ready, wait for the go-file, run the CLI."""
    for stream, path in ((sys.stdout, out), (sys.stderr, err)):
        stream.flush()
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(fd, stream.fileno())
        os.close(fd)
    from activelearn.cli import main

    Path(ready).touch()
    while not os.path.exists(go):
        time.sleep(0.001)
    sys.exit(main(argv))


class Racer:
    """One CLI command in a forked process, held back until `go` exists."""

    def __init__(self, argv: list[str], go: Path, folder: Path) -> None:
        self.ready = folder / "ready"
        self.out = folder / "stdout"
        self.err = folder / "stderr"
        folder.mkdir(parents=True)
        args = (list(argv), str(go), str(self.ready), str(self.out), str(self.err))
        self.process = _CONTEXT.Process(target=_run, args=args)
        self.process.start()

    def wait_ready(self, timeout: float = 120.0) -> None:
        """Until the racer waits at the barrier; AssertionError with its stderr if it died before."""
        deadline = time.monotonic() + timeout
        while not self.ready.exists():
            if not self.process.is_alive() or time.monotonic() > deadline:
                raise AssertionError(f"a racer never got ready: {self.stderr()[-2000:]}")
            time.sleep(0.005)

    def finish(self, timeout: float = 600.0) -> tuple[int, str]:
        """Its exit status and stderr once it ends (killed after `timeout` s); a traceback fails."""
        self.process.join(timeout)
        if self.process.is_alive():
            self.kill()
            raise AssertionError(f"a racer ran past {timeout} s: {self.stderr()[-2000:]}")
        err = self.stderr()
        assert "Traceback" not in err, err
        return self.process.exitcode, err

    def kill(self) -> None:
        if self.process.is_alive():
            self.process.kill()
            self.process.join()

    def stderr(self) -> str:
        return self.err.read_text() if self.err.exists() else ""


def race(go: Path, *commands: list[str]) -> list[tuple[int, str]]:
    """Start a racer per command, release them together once all are ready, and finish them."""
    racers = [Racer(argv, go, go.parent / f"racer{i}") for i, argv in enumerate(commands)]
    try:
        for racer in racers:
            racer.wait_ready()
        go.touch()
        return [racer.finish() for racer in racers]
    finally:
        for racer in racers:
            racer.kill()
