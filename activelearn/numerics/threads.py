"""Thread control for torch work: a scoped intra-op thread count and a thread-pool map.

Independent elementwise work over many blocks (sampled trajectories: noise, pose integration)
scales better on a pool of Python threads, each running its torch ops on one intra-op thread, than
when every op splits itself (measured on 2 cores: pose integration of 32 × 256 × 2 700 steps 78 ms
against 135 ms). Torch releases the GIL inside its ops, so the threads run in parallel. GEMM-heavy
work does not gain: matmuls in concurrent Python threads contended (two threads took longer than
one doing both), so torch's network evaluation stays on its own intra-op threads. The compiled
kernels (`activelearn.numerics.native`) start threads of their own.
"""

from __future__ import annotations

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


def parallel_map(task: Callable[[T], R], items: Iterable[T], workers: int | None = None) -> list[R]:
    """`[task(i) for i in items]` on `workers` threads (default: torch's thread count), in order.

    With more than one worker, torch ops inside the tasks run on one intra-op thread each.
    """
    items = list(items)
    workers = min(workers or torch.get_num_threads(), len(items))
    if workers <= 1:
        return [task(item) for item in items]
    with intra_op_threads(1), ThreadPoolExecutor(workers) as pool:
        return list(pool.map(task, items))


def even_blocks(n: int, block: int) -> list[slice]:
    """Slices covering range(n) in the fewest blocks of at most `block` rows, all of about equal size.

    Equal sizes avoid a tiny last block (a per-block cost paid for a few rows).
    """
    if n <= 0:
        return [slice(0, 0)]
    count = -(-n // block)
    size = -(-n // count)
    return [slice(start, min(start + size, n)) for start in range(0, n, size)]
