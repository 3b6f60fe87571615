"""Every maintained benchmark (experiments/benchmarks/) still runs end to end: its `--quick` mode.

A quick run measures nothing; it drives the same code as a full one (MuJoCo, training, campaigns,
comparisons, studies) on a handful of maneuvers and epochs, so a change that breaks a benchmark fails
here rather than on the day someone measures. Each runs in a process of its own, in a scratch folder.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "experiments" / "benchmarks"

# benchmark -> what its printout must hold (and whether it takes --out)
EXPECTED = {
    "bench_simulator": ("ratio collect / raw", False),
    "bench_models": ("## 4. Accuracy and epistemic calibration", False),
    "bench_physics": ("gated / physics per seed (paired)", False),
    "bench_surrogate": ("speed against MuJoCo", False),
    "bench_tuning": ("ratio 2 workers / 1 worker", True),
    "bench_warm_start": ("the rule for a default", True),
    "bench_safety": ("violations", True),
    "bench_sample_efficiency": ("paired test_rmse differences against uniform", True),
    "bench_scaleout": ("where one campaign's time goes", True),
}


def test_every_benchmark_is_listed():
    assert {p.stem for p in BENCHMARKS.glob("bench_*.py")} == set(EXPECTED)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_a_benchmark_runs_in_its_quick_mode(name: str, tmp_path: Path) -> None:
    text, takes_out = EXPECTED[name]
    command = [sys.executable, str(BENCHMARKS / f"{name}.py"), "--quick"]
    if takes_out:
        command += ["--out", str(tmp_path / "out")]
    done = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert text in done.stdout, done.stdout[-3000:]
