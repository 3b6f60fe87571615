"""Sample efficiency of acquisition strategies against uniform (greedy maximin) sampling.

Runs `activelearn compare` on the skidpad and the all-maneuvers configs with >= 10 seeds each and
prints, per strategy:
  * the sample-efficiency ratio: maneuvers needed to reach uniform's final test RMSE (per seed, with
    its spread), divided by uniform's budget (goal: <= 0.5 for max_epistemic);
  * paired differences of test RMSE against uniform at each budget (same seed = same initial design,
    test set and noise streams): mean ± s.e.m. and wins out of seeds;
  * the epistemic calibration diagnostic at each round (z spread, Spearman(std, |err|), std / RMSE);
  * where each strategy's picks land: the share on the edge of the operating range and per kind.

Usage: python experiments/benchmarks/bench_sample_efficiency.py [--seeds 10] [--workers 2]
       [--configs skidpad,all_maneuvers] [--strategies uniform,max_epistemic,...] [--out DIR]
The comparisons are tracked in MLflow (sqlite:///mlruns/mlflow.db) and resumable (--resume).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from activelearn.config import CampaignConfig, load_config
from activelearn.loop.campaign import STATE_FILE, CampaignState
from activelearn.loop.pool import pool_maneuvers
from activelearn.studies.compare import compare

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _sem(values: np.ndarray) -> float:
    return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else float("nan")


def reach_table(curves: pd.DataFrame, reference: str = "uniform") -> pd.DataFrame:
    """Per strategy: maneuvers to reach the reference's mean final RMSE, per seed, and its ratio."""
    ref = curves[curves["strategy"] == reference]
    finals = ref.sort_values("n_maneuvers").groupby("seed").last()
    target, budget = finals["test_rmse"].mean(), finals["n_maneuvers"].mean()
    rows = []
    for strategy, part in curves.groupby("strategy", sort=False):
        needed = []
        for _, run in part.groupby("seed"):
            run = run.sort_values("n_maneuvers")
            hit = run.loc[run["test_rmse"] <= target, "n_maneuvers"]
            needed.append(float(hit.iloc[0]) if len(hit) else np.inf)
        ratio = np.array(needed) / budget
        finite = ratio[np.isfinite(ratio)]
        rows.append(
            {
                "strategy": strategy,
                "reached": f"{len(finite)}/{len(ratio)}",
                # order statistics, not interpolation: "never reached" (inf) stays inf
                "ratio_median": float(np.quantile(ratio, 0.5, method="lower")),
                "ratio_q25": float(np.quantile(ratio, 0.25, method="lower")),
                "ratio_q75": float(np.quantile(ratio, 0.75, method="higher")),
                "ratio_mean_reached": float(finite.mean()) if len(finite) else float("nan"),
            }
        )
    table = pd.DataFrame(rows)
    table.attrs["target"] = target
    return table


def paired_table(curves: pd.DataFrame, reference: str = "uniform", metric: str = "test_rmse") -> pd.DataFrame:
    """Paired differences (strategy - reference) per budget: mean ± s.e.m. and wins out of seeds."""
    ref = curves[curves["strategy"] == reference].set_index(["seed", "n_maneuvers"])[metric]
    rows = []
    for strategy, part in curves.groupby("strategy", sort=False):
        if strategy == reference:
            continue
        diff = part.set_index(["seed", "n_maneuvers"])[metric] - ref
        for n, values in diff.dropna().groupby(level="n_maneuvers"):
            v = values.to_numpy()
            rows.append(
                {
                    "strategy": strategy,
                    "maneuvers": int(n),
                    "mean_diff": v.mean(),
                    "sem": _sem(v),
                    "wins": f"{int((v < 0).sum())}/{len(v)}",
                }
            )
    return pd.DataFrame(rows)


def calibration_table(curves: pd.DataFrame) -> pd.DataFrame:
    """Epistemic calibration diagnostic per strategy and budget (means over seeds)."""
    cols = [
        c for c in ("calib_z_spread", "calib_spearman", "calib_std_to_rmse", "coverage_95") if c in curves
    ]
    return curves.groupby(["strategy", "n_maneuvers"])[cols].mean().reset_index()


def pick_table(directory: Path, cfg: CampaignConfig) -> pd.DataFrame:
    """Where the picks after the initial design land, per strategy, beside the pool's own shares.

    A maneuver is on the edge when its throttle is the pool's lowest or highest, or its steering
    magnitude the pool's smallest or largest non-zero one (the boundary of the throttle x |steering|
    grid). The kind columns count picks per maneuver kind.
    """
    pool = pool_maneuvers(cfg.pool)
    throttles = np.array([m.throttle for m in pool])
    steerings = np.array([m.steering for m in pool])
    turning = steerings[steerings > 0]
    edge = (throttles == throttles.min()) | (throttles == throttles.max())
    if len(turning):
        edge |= (steerings > 0) & ((steerings == turning.min()) | (steerings == turning.max()))
    kinds = np.array([m.kind for m in pool])

    def shares(picks: np.ndarray) -> dict:
        row = {"picks": len(picks), "edge_share": float(edge[picks].mean())}
        if len(set(kinds)) > 1:
            row.update({kind: int((kinds[picks] == kind).sum()) for kind in cfg.pool.kinds})
        return row

    rows = [{"strategy": "(pool)", **shares(np.arange(len(pool)))}]
    for strategy_dir in sorted(p for p in directory.iterdir() if p.is_dir()):
        picks = [
            i
            for state in strategy_dir.glob(f"seed*/{STATE_FILE}")
            for batch in CampaignState.load(state.parent).batches[1:]
            for i in batch
        ]
        if picks:
            rows.append({"strategy": strategy_dir.name, **shares(np.array(picks))})
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--configs", default="skidpad,all_maneuvers")
    parser.add_argument("--strategies", default="uniform,random,max_epistemic,bald,integrated_variance")
    parser.add_argument("--out", default="runs/bench_sample_efficiency")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--no-tracking", action="store_true")
    args = parser.parse_args()
    strategies = args.strategies.split(",")
    pd.set_option("display.width", 160)
    for name in args.configs.split(","):
        cfg = load_config(CONFIGS / f"{name}.toml")
        started = time.perf_counter()
        result = compare(
            cfg,
            strategies,
            list(range(args.seeds)),
            directory=Path(args.out) / name,
            workers=args.workers,
            tracking=not args.no_tracking,
            resume=args.resume,
        )
        curves = result.curves
        print(
            f"\n=== {name}: {args.seeds} seeds, {len(strategies)} strategies, "
            f"{time.perf_counter() - started:.0f} s wall ==="
        )
        print(result.table.to_string(index=False, float_format="%.4g"))
        reach = reach_table(curves)
        print(
            f"\nsample-efficiency ratio (maneuvers to reach uniform's final RMSE {reach.attrs['target']:.4g}"
            " / uniform's budget; inf = never reached):"
        )
        print(reach.to_string(index=False, float_format="%.3g"))
        print("\npaired test-RMSE differences against uniform (negative = better):")
        print(paired_table(curves).to_string(index=False, float_format="%.4f"))
        print("\nepistemic calibration at each round (mean over seeds):")
        print(calibration_table(curves).to_string(index=False, float_format="%.3f"))
        print("\nwhere the picks after the initial design land (all seeds):")
        print(pick_table(Path(args.out) / name, cfg).to_string(index=False, float_format="%.2f"))
        print(f"\nfigure: {result.figure_path}")


if __name__ == "__main__":
    main()
