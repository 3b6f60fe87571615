"""Thread helpers: blocks cover every row once, the pool keeps order and restores torch's threads."""

from __future__ import annotations

import pytest
import torch

from activelearn.numerics.threads import even_blocks, intra_op_threads, parallel_map


@pytest.mark.parametrize(("n", "block"), [(2700, 1024), (10, 4), (1, 1024), (4096, 4096), (4097, 4096)])
def test_even_blocks_cover_every_row_once_in_equal_blocks(n, block):
    blocks = even_blocks(n, block)
    rows = [i for b in blocks for i in range(n)[b]]
    assert rows == list(range(n))
    sizes = [b.stop - b.start for b in blocks]
    assert max(sizes) <= block and len(blocks) == -(-n // block)
    assert max(sizes) - min(sizes) <= len(blocks)
    assert even_blocks(0, block) == [slice(0, 0)]


def test_parallel_map_keeps_order_and_restores_the_thread_count():
    before = torch.get_num_threads()
    seen: list[int] = []

    def task(i: int) -> int:
        seen.append(torch.get_num_threads())
        return i * i

    assert parallel_map(task, range(9), workers=2) == [i * i for i in range(9)]
    assert torch.get_num_threads() == before
    # Inside the pool, torch ops run on one intra-op thread each.
    assert set(seen) == {1}
    with intra_op_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before


def test_parallel_map_restores_threads_when_a_task_fails():
    before = torch.get_num_threads()

    def task(i: int) -> int:
        if i == 3:
            raise ValueError("boom")
        return i

    with pytest.raises(ValueError, match="boom"):
        parallel_map(task, range(6), workers=2)
    assert torch.get_num_threads() == before
