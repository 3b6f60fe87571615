"""Thread control for torch work: a scoped intra-op thread count and a thread-pool map.

Independent elementwise work over many blocks (sampled trajectories: noise, pose integration)
scales better on a pool of Python threads, each running its torch ops on one intra-op thread, than
when every op splits itself (measured on 2 cores: pose integration of 32 × 256 × 2 700 steps 78 ms
against 135 ms). Torch releases the GIL inside its ops, so the threads run in parallel. GEMM-heavy
work does not gain: matmuls in concurrent Python threads contended (two threads took longer than
one doing both), so torch's network evaluation stays on its own intra-op threads. The compiled
kernels (`activelearn.native`) release the GIL and run one task per pool thread.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import TypeVar

import torch

T = TypeVar("T")
R = TypeVar("R")


@contextmanager
def intra_op_threads(n: int | None) -> Iterator[None]:
    """Set torch's intra-op thread count for the block (None: leave it), then restore it.

    The setting is process-wide: do not run other torch work concurrently from other threads.
    """
    old = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


# Pools live for the process: starting threads cost ~0.7 ms a call, a third of a 2 700-row
# `predict`. One pool per worker count; a forked child starts without them (their threads do not
# survive a fork, and a task queued on such a pool would never run).
_pools: dict[int, ThreadPoolExecutor] = {}
_pools_lock = threading.Lock()
_worker = threading.local()


def _mark_worker() -> None:
    _worker.active = True


def _reset_pools() -> None:
    global _pools_lock
    _pools.clear()
    _pools_lock = threading.Lock()


os.register_at_fork(after_in_child=_reset_pools)


def _pool(workers: int) -> ThreadPoolExecutor:
    with _pools_lock:
        if workers not in _pools:
            _pools[workers] = ThreadPoolExecutor(
                workers, thread_name_prefix="activelearn", initializer=_mark_worker
            )
        return _pools[workers]


def parallel_map(task: Callable[[T], R], items: Iterable[T], workers: int | None = None) -> list[R]:
    """`[task(i) for i in items]` on `workers` threads (default: torch's thread count), in order.

    With more than one worker, torch ops inside the tasks run on one intra-op thread each. Called
    from inside a task, it runs sequentially (a nested wait on the same pool could deadlock).
    """
    items = list(items)
    workers = min(workers or torch.get_num_threads(), len(items))
    if workers <= 1 or getattr(_worker, "active", False):
        return [task(item) for item in items]
    with intra_op_threads(1):
        return list(_pool(workers).map(task, items))


def even_blocks(n: int, block: int) -> list[slice]:
    """Slices covering range(n) in the fewest blocks of at most `block` rows, all of about equal size.

    Equal sizes avoid a tiny last block (a per-block cost paid for a few rows).
    """
    if n <= 0:
        return [slice(0, 0)]
    count = -(-n // block)
    size = -(-n // count)
    return [slice(start, min(start + size, n)) for start in range(0, n, size)]
