"""Local worker processes that start with the heavy imports already done.

Comparisons and tuning studies run their campaigns and trials in fresh processes (never forked from
the parent: its torch may already hold OpenMP threads). A spawned process imports torch, pandas,
scipy, MuJoCo and the loop again, and its first optimizer imports `torch._dynamo`: about 6 CPU-s
before its first job. Here the workers come from a fork server that did those imports once
(`multiprocessing`'s "forkserver", preloaded), so each worker starts as a fresh, single-threaded copy
of it. A worker gets the parent's current working directory and `sys.path` from multiprocessing, and
its current environment from `with_environment` (the fork server's own was fixed when it started).
The server ignores Ctrl-C while it imports (`preload_quietly`): it has nothing to stop, and its
traceback would only bury the command's one line; its workers stop on Ctrl-C as spawned ones do. A
worker forked just as a Ctrl-C ends the command finds the command's semaphores already removed when it
unpickles its pool's queues; it exits without a traceback (`quiet_orphans`), as its job never started.
"""

from __future__ import annotations

import importlib
import multiprocessing
import multiprocessing.synchronize
import os
import signal
import sys
from collections.abc import Callable, Mapping
from multiprocessing.context import BaseContext
from types import TracebackType
from typing import Any

QUIET_PRELOAD = "activelearn.studies.preload"  # what the fork server imports: it runs preload_quietly

# What a worker imports before its first job: a comparison's campaign and a study's trial (torch,
# pandas, scipy, MuJoCo, the loop), MLflow and matplotlib (tracking, figures), and the part of torch
# that an optimizer imports on first use.
PRELOAD = (
    "activelearn.studies.compare", "activelearn.studies.tuning.workers", "activelearn.studies.tracking",
    "activelearn.plots", "torch._dynamo",
)  # fmt: skip


def worker_context() -> BaseContext:
    """The multiprocessing context of every local worker: a fork server with PRELOAD imported."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([QUIET_PRELOAD])
    return context


def preload_quietly() -> None:
    """Import PRELOAD with Ctrl-C ignored, then restore Python's own handler (the fork server's
    workers inherit the handler it finds after its preload)."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        for module in PRELOAD:
            importlib.import_module(module)
    finally:
        signal.signal(signal.SIGINT, previous)


def orphaned(error: BaseException, trace: TracebackType | None) -> bool:
    """Whether `error` is a worker's failure to rebuild a semaphore of its parent's, which exists only
    while the parent does: the parent has gone (a Ctrl-C) before the worker unpickled its queues."""
    if not isinstance(error, FileNotFoundError) or trace is None:
        return False
    while trace.tb_next is not None:
        trace = trace.tb_next
    code = trace.tb_frame.f_code
    return code.co_name == "__setstate__" and code.co_filename == multiprocessing.synchronize.__file__


def quiet_orphans() -> None:
    """In the fork server: a worker orphaned at its start (`orphaned`) exits without a traceback; any
    other error is printed as before."""
    hook = sys.excepthook

    def excepthook(kind: type[BaseException], error: BaseException, trace: TracebackType | None) -> None:
        if not orphaned(error, trace):
            hook(kind, error, trace)

    sys.excepthook = excepthook


def with_environment(environment: Mapping[str, str], target: Callable[..., Any], *args: Any) -> Any:
    """Run `target(*args)` under `environment` (the parent's `os.environ` when the job was handed out)."""
    os.environ.clear()
    os.environ.update(environment)
    return target(*args)
