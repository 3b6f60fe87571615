"""Reusable large float32 arrays, so repeated surrogate rollouts do not pay fresh page faults each time.

A rollout of 256 maneuvers of 90 s with S = 32 writes 440 MB of sampled paths. Fresh memory costs
a page fault per 4 KiB page on first touch: 0.16 s on two cores here, a third of the rollout.
`empty` hands out arrays whose memory goes back to a bounded cache once the last view of them is
dropped (numpy views, torch tensors made from them, slices: all of them), and a later request of
the same size reuses it, already mapped. Memory in use is never shared: an array is only reused
after nothing refers to it any more. The cache keeps at most `MAX_CACHED_BYTES`, most recently
returned first; `release()` empties it.

Huge pages would also cut the faults, but with this kernel's THP setting (defrag on madvise) a
first allocation sometimes stalled for 0.6-0.9 s on compaction, so the memory comes from torch's
allocator (4 KiB pages, no madvise) as before.
"""

from __future__ import annotations

import math
import os
import threading
import weakref
from collections import OrderedDict

import numpy as np
import torch

MAX_CACHED_BYTES = 1 << 30  # idle memory the cache may hold
MIN_CACHED_BYTES = 1 << 20  # smaller arrays come from the allocator's own free lists just as fast


class ArrayCache:
    """Hands out float32 arrays and takes their memory back for reuse when they are dropped."""

    def __init__(self, max_bytes: int = MAX_CACHED_BYTES) -> None:
        self.max_bytes = max_bytes
        self._idle: OrderedDict[int, tuple[int, torch.Tensor]] = OrderedDict()  # id → (numel, storage)
        self._idle_bytes = 0
        self._lock = threading.Lock()

    @property
    def idle_bytes(self) -> int:
        """Bytes held for reuse right now."""
        return self._idle_bytes

    def empty(self, shape: tuple[int, ...]) -> np.ndarray:
        """An uninitialised C-contiguous float32 array of `shape`, on reused memory when some is idle."""
        numel = math.prod(shape)
        if numel * 4 < MIN_CACHED_BYTES:
            return torch.empty(shape).numpy()
        storage = self._take(numel)
        array = storage.view(shape).numpy()
        # The array's base is a tensor object of its own that every view of the array keeps alive:
        # when it goes, nothing refers to this memory any more.
        weakref.finalize(array.base, self._give_back, storage)
        return array

    def clear(self) -> None:
        """Drop every idle buffer (their memory goes back to the system)."""
        with self._lock:
            self._idle.clear()
            self._idle_bytes = 0

    def _take(self, numel: int) -> torch.Tensor:
        with self._lock:
            for key, (size, storage) in reversed(self._idle.items()):  # most recently returned first
                if size == numel:
                    del self._idle[key]
                    self._idle_bytes -= numel * 4
                    return storage
        return torch.empty(numel)

    def _give_back(self, storage: torch.Tensor) -> None:
        size = storage.numel() * 4
        if size > self.max_bytes:
            return
        with self._lock:
            self._idle[id(storage)] = (storage.numel(), storage)
            self._idle_bytes += size
            while self._idle_bytes > self.max_bytes:  # evict the longest idle
                _, (numel, _) = self._idle.popitem(last=False)
                self._idle_bytes -= numel * 4

    def _after_fork(self) -> None:
        self._lock = threading.Lock()  # a lock held by another thread at fork time would never be released


_cache = ArrayCache()
os.register_at_fork(after_in_child=_cache._after_fork)


def empty(shape: tuple[int, ...]) -> np.ndarray:
    """An uninitialised float32 array from the process-wide cache (see the module docstring)."""
    return _cache.empty(shape)


def release() -> None:
    """Return the idle cached memory to the system."""
    _cache.clear()


def idle_bytes() -> int:
    """Bytes the process-wide cache holds for reuse."""
    return _cache.idle_bytes
