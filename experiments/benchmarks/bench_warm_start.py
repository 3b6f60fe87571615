"""Warm-started rounds against retraining from scratch: campaigns per hour and final error, paired seeds.

Runs one strategy on each config twice over the same seeds, once as configured (a fresh model every
round) and once with `[training] warm_start = true` (each round starts from the last round's weights
and trains `warm_epochs` epochs), and prints, per config:
  - wall seconds per campaign (mean over seeds) and campaigns per hour, and their ratio;
  - the final value of the config's ranking metric ([test] metric), mean ± s.e.m., and the paired
    difference warm − scratch ± its s.e.m., with the number of seeds where warm is better.
The rule for making warm starts a config's default: at least 2x the campaigns per hour and a final
error no worse (the paired difference warm - scratch at most +1 s.e.m.).

Per seed, both modes' finals; for dynamic models, the fans' coverage of the test set by round.

Usage: python experiments/benchmarks/bench_warm_start.py [--configs odd_expansion,dynamics]
       [--strategy uniform] [--seeds 10] [--first-seed 0] [--workers 2] [--warm-epochs N]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from quick import shrink

from activelearn.config import load_config
from activelearn.names import ROLLOUT_COVERAGE_95, WALL_SECONDS
from activelearn.studies.compare import compare

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _sem(values: np.ndarray) -> float:
    return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else float("nan")


COVERAGE = ROLLOUT_COVERAGE_95  # the fans' share of the test set's 95 % bands (dynamic models)


def run(
    config: str, strategy: str, seeds: list[int], workers: int, warm_epochs: int | None, out: Path,
    quick: bool = False,
) -> None:  # fmt: skip
    """Both modes of one config, then its printout."""
    base = load_config(CONFIGS / f"{config}.toml")
    if quick:
        base = shrink(base, out / "runs")
    metric = base.test.metric
    finals, walls, fans = {}, {}, {}
    for mode, warm in (("scratch", False), ("warm", True)):
        training = {"warm_start": warm, **({"warm_epochs": warm_epochs} if warm and warm_epochs else {})}
        cfg = base.model_copy(update={"training": base.training.model_copy(update=training)})
        result = compare(cfg, [strategy], seeds, directory=out / config / mode, workers=workers,
                         tracking=False)  # fmt: skip
        curves = result.curves.sort_values("round")
        last = curves.groupby("seed").last()
        finals[mode], walls[mode] = last[metric], last[WALL_SECONDS]
        if COVERAGE in curves:
            fans[mode] = curves.groupby("round")[COVERAGE].mean()
    scratch, warm = finals["scratch"], finals["warm"]
    diff = (warm - scratch).to_numpy()
    speed = walls["scratch"].mean() / walls["warm"].mean()
    epochs = warm_epochs or max(1, base.training.epochs // 4)
    print(f"\n{config}: {strategy}, seeds {seeds[0]}-{seeds[-1]}, metric {metric}; "
          f"warm rounds train {epochs} of {base.training.epochs} epochs")  # fmt: skip
    table = pd.DataFrame(
        {
            "wall s / campaign": [walls["scratch"].mean(), walls["warm"].mean()],
            "campaigns / hour": [3600 / walls["scratch"].mean(), 3600 / walls["warm"].mean()],
            f"final {metric}": [scratch.mean(), warm.mean()],
            "± s.e.m.": [_sem(scratch.to_numpy()), _sem(warm.to_numpy())],
        },
        index=["scratch", "warm"],
    )
    print(table.to_string(float_format="%.4g"))
    for mode in finals:
        print(f"  {mode} final by seed: " + " ".join(f"{v:.4g}" for v in finals[mode].to_numpy()))
        if mode in fans:
            by_round = " ".join(f"{v:.3f}" for v in fans[mode])
            print(f"  {mode} {COVERAGE} by round, mean over seeds: {by_round}")
    print(f"  speed-up x{speed:.2f}; paired difference warm - scratch {diff.mean():+.4g} ± {_sem(diff):.2g} "
          f"(warm better on {int((diff < 0).sum())}/{len(diff)} seeds)")  # fmt: skip
    no_worse = diff.mean() <= _sem(diff)
    verdict = "meets" if speed >= 2 and no_worse else "does not meet"
    print(f"  {verdict} the rule for a default (>= 2x faster, final error no worse by more than 1 s.e.m.)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", default="odd_expansion,dynamics")
    parser.add_argument("--strategy", default="uniform")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument(
        "--first-seed", type=int, default=0, help="seeds first-seed .. first-seed + seeds - 1"
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--warm-epochs", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None, help="keep the campaigns (default: a temp dir)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes: checks every part still runs (tests/test_benchmarks.py)")
    args = parser.parse_args()
    if args.quick:  # one config unless named, two seeds (a paired difference needs two)
        args.seeds, args.workers = 2, 1
        if args.configs == "odd_expansion,dynamics":
            args.configs = "odd_expansion"
    with tempfile.TemporaryDirectory() as scratch:
        out = args.out or Path(scratch)
        for config in args.configs.split(","):
            seeds = list(range(args.first_seed, args.first_seed + args.seeds))
            run(config, args.strategy, seeds, args.workers, args.warm_epochs, out, args.quick)


if __name__ == "__main__":
    main()
