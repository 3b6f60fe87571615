"""The array cache reuses memory only once nothing refers to it, within its budget."""

from __future__ import annotations

import gc

import numpy as np
import torch

from activelearn.numerics import buffers
from activelearn.numerics.buffers import ArrayCache

BIG = (3, 256, 1024)  # 3 MiB of float32: above the cache's lower size limit


def _address(array: np.ndarray) -> int:
    return array.__array_interface__["data"][0]


def test_memory_is_reused_only_after_every_view_is_gone():
    cache = ArrayCache(max_bytes=64 << 20)
    first = cache.empty(BIG)
    address = _address(first)
    view = torch.from_numpy(first[1:])  # a tensor over a slice keeps the memory in use
    del first
    gc.collect()
    second = cache.empty(BIG)
    assert _address(second) != address and cache.idle_bytes == 0
    del view
    gc.collect()
    assert cache.idle_bytes == 3 << 20
    third = cache.empty(BIG)
    assert _address(third) == address and cache.idle_bytes == 0
    assert third.shape == BIG and third.dtype == np.float32 and third.flags.c_contiguous
    other_shape = cache.empty((3 * 256, 1024))  # same size, other shape: a fresh block is fine too
    assert not np.shares_memory(other_shape, third)


def test_budget_evicts_the_longest_idle_and_small_arrays_bypass_the_cache():
    cache = ArrayCache(max_bytes=7 << 20)
    arrays = [cache.empty(BIG) for _ in range(3)]  # 9 MiB
    addresses = [_address(a) for a in arrays]
    while arrays:  # returned in order: 0, 1, 2
        arrays.pop(0)
        gc.collect()
    assert cache.idle_bytes == 6 << 20  # two of three fit; the first returned was evicted
    kept = [cache.empty(BIG) for _ in range(2)]
    assert {_address(a) for a in kept} == set(addresses[1:])
    small = cache.empty((10, 10))
    del small
    gc.collect()
    assert cache.idle_bytes == 0
    cache.empty(BIG)
    cache.clear()
    assert cache.idle_bytes == 0


def test_module_cache_release():
    a = buffers.empty(BIG)
    del a
    gc.collect()
    assert buffers.idle_bytes() >= 3 << 20
    buffers.release()
    assert buffers.idle_bytes() == 0
