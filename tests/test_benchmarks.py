"""Every maintained benchmark (experiments/benchmarks/) still runs end to end: its `--quick` mode.

A quick run measures little; it drives the same code as a full one (MuJoCo, training, campaigns,
comparisons, studies) on a handful of maneuvers and epochs, so a change that breaks a benchmark fails
here rather than on the day someone measures. Each runs as `python bench_x.py --quick` would, in a
process of its own and a scratch folder; the process is forked from the fork server that the
comparisons' workers come from (`activelearn.studies.processes`), which has torch, MuJoCo and the loop
imported already: about 4 CPU-s a benchmark less than a fresh interpreter. One figure of its printout
must be finite and within a stated range: a quick run that prints nonsense (a NaN, an error off by
orders of magnitude, a violation where there was none) fails too. The ranges hold the quick runs'
figures on a loaded 2-core machine with room to spare (timings by a factor of 20); they are not the
benchmarks' targets, which only full runs measure.
"""

from __future__ import annotations

import math
import os
import re
import runpy
import sys
import traceback
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import NamedTuple

import pytest

from activelearn.studies.processes import with_environment, worker_context

BENCHMARKS = Path(__file__).resolve().parents[1] / "experiments" / "benchmarks"


class Figure(NamedTuple):
    """One number of a quick run's printout: the first match of `pattern` (group 1), in [low, high]."""

    what: str
    pattern: str
    low: float
    high: float


NUMBER = r"([-+]?(?:\d[\d.]*(?:e[-+]?\d+)?|nan|inf))"  # as printed; nan or inf fail the test

# benchmark -> (a line its printout must hold, whether it takes --out, the figure checked)
EXPECTED = {
    "bench_simulator": ("ratio collect / raw", False, Figure(
        "the simulator's steady speeds against the reference, max error in %",
        rf"max error {NUMBER} %", 0.0, 5.0)),  # the benchmark's own limit; quick 0.05
    "bench_models": ("## 4. Accuracy and epistemic calibration", False, Figure(
        "the default hybrid's RMSE on held-out operating points",
        rf"\| hybrid default \(kl_count=sqrt\) \| {NUMBER} \|", 0.0, 0.2)),  # quick 0.05
    "bench_physics": ("gated / physics per seed (paired)", False, Figure(
        "the physics kind's 30-s position error on Nigel, m (the black box's: 1.4)",
        rf"nominal seed 0 physics\s+30-s error {NUMBER} m", 0.0, 0.1)),  # quick 0.0096
    "bench_surrogate": ("speed against MuJoCo", False, Figure(
        "the physics kind's 30-s error on the slalom as a ratio of the static map's",
        rf"^slalom\s+{NUMBER}\s+{NUMBER}\s+{NUMBER}", 0.0, 0.5)),  # columns history, markov, physics
    "bench_tuning": ("ratio 2 workers / 1 worker", True, Figure(
        "trials per minute of one worker",
        rf"^1 worker\(s\): .* = {NUMBER} trials/min", 0.5, 1e4)),  # quick 24 (2 epochs a trial)
    "bench_warm_start": ("the rule for a default", True, Figure(
        "the scratch campaigns' final test_rmse on odd_expansion",
        rf"^scratch\s+\S+\s+\S+\s+{NUMBER}", 0.0, 10.0)),  # quick 2.8
    "bench_safety": ("violations", True, Figure(
        "violations of the safe campaigns",
        rf"^safe \(delta [\d.]+\): violations {NUMBER}", 0.0, 0.0)),
    "bench_sample_efficiency": ("paired test_rmse differences against uniform", True, Figure(
        "uniform's final test_rmse on the skidpad",
        rf"^\s+uniform\s+1\s+{NUMBER}", 0.0, 50.0)),  # quick 7.05
    "bench_campaign": ("wall s by round", True, Figure(
        "the dynamics campaign's share of wall time in its fits, %",
        rf"^fit\s+{NUMBER}\s+{NUMBER}%", 1.0, 100.0)),  # quick 69
    "bench_vehicles": ("## Summary, one row per car", False, Figure(
        "the 1:10 car's throttle map against its file's steady speeds, max error in %",
        rf"^f1tenth throttle map: max error {NUMBER} %", 0.0, 2.0)),  # quick 0.03
    "bench_vehicle_baselines": ("## Baselines: uniform", True, Figure(
        "the 1:10 car's physics kind, 30-s error of its free runs after the last round, m",
        rf"^f1tenth\s+physics\s+1\s+{NUMBER}", 0.0, 1e3)),  # quick 3.6
    "bench_dynamic_speed": ("beside the truth simulator", True, Figure(
        "the 1:10 car's dynamic-core free runs, sample-steps per second",
        rf"^f1tenth dynamic: free runs x\S+ the truth's speed, {NUMBER} sample-steps/s", 1e3, 1e12)),
    "bench_transfer": ("## Transfer:", True, Figure(
        "the 1:10 twin's file arm, 30-s error of its free runs after the last round, m",
        rf"^file\s+4\s+{NUMBER}", 0.0, 1e3)),  # quick 0.108
    "bench_scaleout": ("where one campaign's time goes", True, Figure(
        "smoke campaigns per hour on one process worker",
        rf"process\s+1 worker\(s\):\s+{NUMBER} campaigns/hour", 10.0, 1e5)),  # quick 238
}  # fmt: skip


def figure(printout: str, figure: Figure) -> float:
    """The figure's value in a printout (the last group of its pattern's first match)."""
    match = re.search(figure.pattern, printout, flags=re.MULTILINE)
    assert match is not None, f"{figure.what}: no line matches {figure.pattern!r}"
    return float(match.groups()[-1])


def test_every_benchmark_is_listed():
    assert {p.stem for p in BENCHMARKS.glob("bench_*.py")} == set(EXPECTED)


def test_a_figure_is_read_and_a_nan_is_not_finite():
    check = EXPECTED["bench_physics"][2]
    assert figure("nominal seed 0 physics    30-s error 0.0096 m, fan", check) == 0.0096
    assert not math.isfinite(figure("nominal seed 0 physics    30-s error nan m, fan", check))
    with pytest.raises(AssertionError, match="no line matches"):
        figure("nominal seed 0 black box  30-s error 1.43 m", check)


# The campaign benchmarks run from tests/test_benchmarks_campaigns.py: a file of their own, so that
# `make test`'s workers (a file each at a time) share the quick runs instead of one worker taking all.
CAMPAIGN_BENCHMARKS = ("bench_warm_start", "bench_safety", "bench_sample_efficiency", "bench_scaleout",
                       "bench_transfer")


def run_script(script: str, arguments: list[str], directory: str, stdout: str, stderr: str) -> int:
    """In a fresh worker: what `python script arguments` does in `directory` (the script as `__main__`,
    its folder first on sys.path), its output written to the files `stdout` and `stderr`; the exit code."""
    os.chdir(directory)
    sys.argv = [script, *arguments]
    sys.path.insert(0, str(Path(script).parent))
    with open(stdout, "w") as out, open(stderr, "w") as err:
        os.dup2(out.fileno(), 1), os.dup2(err.fileno(), 2)  # its child processes' output too
        try:
            runpy.run_path(script, run_name="__main__")
            code = 0
        except SystemExit as exit_:
            code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
            if isinstance(exit_.code, str):
                print(exit_.code, file=sys.stderr)
        except BaseException:  # the traceback is the test's message
            traceback.print_exc()
            code = 1
        sys.stdout.flush(), sys.stderr.flush()
    return code


def run_quick(name: str, tmp_path: Path) -> None:
    """Run benchmark `name` in its quick mode; check its printout's line and figure."""
    text, takes_out, check = EXPECTED[name]
    arguments = ["--quick", *(["--out", str(tmp_path / "out")] if takes_out else [])]
    stdout, stderr = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with ProcessPoolExecutor(1, mp_context=worker_context(), max_tasks_per_child=1) as pool:
        # this process's environment as it is now: the fork server's was fixed when it started
        job = pool.submit(with_environment, dict(os.environ), run_script, str(BENCHMARKS / f"{name}.py"),
                          arguments, str(tmp_path), str(stdout), str(stderr))  # fmt: skip
        code = job.result(timeout=1200)
    printout = stdout.read_text()
    assert code == 0, printout[-3000:] + stderr.read_text()[-3000:]
    assert text in printout, printout[-3000:]
    value = figure(printout, check)
    assert math.isfinite(value) and check.low <= value <= check.high, (check.what, value, printout[-3000:])


def test_the_two_files_run_every_benchmark_once():
    assert set(CAMPAIGN_BENCHMARKS) <= set(EXPECTED)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(EXPECTED) - set(CAMPAIGN_BENCHMARKS)))
def test_a_benchmark_runs_in_its_quick_mode(name: str, tmp_path: Path) -> None:
    run_quick(name, tmp_path)
