"""The campaign benchmarks' quick modes (tests/test_benchmarks.py says what a quick run checks)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.test_benchmarks import CAMPAIGN_BENCHMARKS, run_quick


@pytest.mark.slow
@pytest.mark.parametrize("name", CAMPAIGN_BENCHMARKS)
def test_a_campaign_benchmark_runs_in_its_quick_mode(name: str, tmp_path: Path) -> None:
    run_quick(name, tmp_path)
