"""Campaigns per hour on this machine: local processes against Ray tasks, 1 and 2 workers, in one run.

Then where one campaign's time goes (simulation, training, acquisition, tracking), from a profile of
one campaign run in this process: the numbers behind the scale-out estimate in
experiments/results/bench_scaleout.txt.

    python experiments/benchmarks/bench_scaleout.py [--config experiments/configs/smoke.toml]
        [--campaigns 4] [--out DIR]
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import tempfile
import time
from pathlib import Path

import pandas as pd
from quick import shrink

from activelearn.config import load_config
from activelearn.loop.campaign import Campaign
from activelearn.studies.compare import compare
from activelearn.studies.tracking import Tracker

SMOKE = Path(__file__).resolve().parents[1] / "configs" / "smoke.toml"
# Functions whose cumulative time is one phase of a campaign (matched on "file:function").
PHASES = {
    "simulation": ("simulator/collect.py:collect",),
    "training": ("numerics/training.py:fit",),
    "acquisition": tuple(f"loop/{m}.py:select" for m in ("space_filling", "function_space", "acquisition")),
    "evaluation": ("loop/evaluation.py:evaluate",),
    "tracking": ("studies/tracking.py:log_", "studies/tracking.py:start_run", "studies/tracking.py:end_run"),
}


def throughput(cfg, executor: str, workers: int, campaigns: int, root: Path) -> float:
    """Campaigns per hour of `compare` (uniform, `campaigns` seeds) on an executor, warm cache."""
    started = time.perf_counter()
    compare(
        cfg, ["uniform"], list(range(campaigns)), directory=root / f"{executor}{workers}",
        workers=workers, tracking=False, executor=executor,
        ray_address="local" if executor == "ray" else None,
    )  # fmt: skip
    return campaigns * 3600 / (time.perf_counter() - started)


def phase_split(cfg, root: Path) -> pd.DataFrame:
    """Seconds of one tracked campaign (cold cache for its own maneuvers) spent per phase."""
    tracker = Tracker(f"sqlite:///{root}/mlruns/mlflow.db", "bench-scaleout")
    campaign = Campaign(cfg.model_copy(update={"seed": 99}), root / "profiled", tracker=tracker,
                        cache_dir=root / "cache-profile")
    profile = cProfile.Profile()
    started = time.perf_counter()
    profile.runcall(campaign.run, figures=True, log_model=True)
    total = time.perf_counter() - started
    stats = pstats.Stats(profile).stats  # {(file, line, function): (cc, nc, tt, ct, callers)}
    rows = []
    for phase, patterns in PHASES.items():
        seconds = 0.0
        for (file, _, function), (_, _, _, cumulative, callers) in stats.items():
            name = f"{file}:{function}"
            # Count only outermost calls (no caller inside the same phase) so recursion is not double-counted.
            if any(name.endswith(p) or (p.endswith("_") and p in name) for p in patterns):
                outer = [c for c in callers if not any(f"{c[0]}:{c[2]}".endswith(p) for p in patterns)]
                if outer:
                    seconds += cumulative
        rows.append({"phase": phase, "seconds": seconds, "share": seconds / total})
    rows.append({"phase": "total", "seconds": total, "share": 1.0})
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(SMOKE))
    parser.add_argument("--campaigns", type=int, default=4, help="campaigns per measurement")
    parser.add_argument("--out", default=None)
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes: checks every part still runs (tests/test_benchmarks.py)")
    args = parser.parse_args()
    root = Path(args.out or tempfile.mkdtemp(prefix="bench-scaleout-"))
    cfg = load_config(args.config).model_copy(update={"output_dir": str(root / "runs")})
    executors = ("process", "ray")
    if args.quick:  # one campaign, one worker, local processes only
        args.campaigns, cfg = 1, shrink(cfg, root / "runs")
        # Starting Ray costs ~30 s on 2 cores; tests/test_ray.py runs this very call (compare with
        # executor "ray", address "local") and checks its numbers against the process executor's.
        executors = ("process",)
    # Warm the simulation cache first: every measurement below then times campaigns, not MuJoCo.
    compare(cfg, ["uniform"], [0], directory=root / "warm", workers=1, tracking=False)

    rows = []
    for executor in executors:
        for workers in (1,) if args.quick else (1, 2):
            rate = throughput(cfg, executor, workers, args.campaigns, root)
            rows.append({"executor": executor, "workers": workers, "campaigns_per_hour": rate})
            print(f"{executor:8s} {workers} worker(s): {rate:7.1f} campaigns/hour", flush=True)
    table = pd.DataFrame(rows)
    base = table.loc[(table.executor == "process") & (table.workers == 1), "campaigns_per_hour"].item()
    table["ratio_to_process_1"] = table["campaigns_per_hour"] / base
    print(f"\n{args.campaigns} campaigns of {Path(args.config).name} per measurement, warm cache:")
    print(table.to_string(index=False, float_format="%.3g"))

    split = phase_split(cfg, root)
    print("\nwhere one campaign's time goes (profiled in this process, tracking to SQLite):")
    print(split.to_string(index=False, float_format="%.3g"))


if __name__ == "__main__":
    main()
