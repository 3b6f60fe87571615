"""When does active learning pay? Strategies against uniform (greedy maximin) on cold and warm pools.

Runs `activelearn compare` on each pool (10 seeds by default; the same seed gives every strategy the
same initial design, prior, test set and noise streams, so differences are paired) and prints, per
pool and strategy:
  * the final value of the pool config's `[test] metric` ± s.e.m. (test RMSE, standardised, with v in
    m/s and ω in rad/s beside it; or a free-run error such as `rollout_pos_err_30s` in metres);
  * new maneuvers and track seconds to reach uniform's final value: median and quartiles of the ratio
    to uniform's budget (inf = not reached within the budget);
  * wins at the final budget (paired, out of seeds);
  * paired differences against uniform at every budget (mean ± s.e.m., wins), and for `auto` the
    check "never worse than uniform by more than one s.e.m. at any budget >= 8 maneuvers";
  * the room: the benchmark-only lookahead oracle (each round, among a handful of candidate batches,
    the one whose retrained model has the lowest true test error) on `--lookahead-seeds` seeds, and
    the share of uniform-to-lookahead room each strategy captures at the final budget;
  * the epistemic calibration at each round and where the picks land.

Usage: python experiments/benchmarks/bench_sample_efficiency.py [--seeds 10] [--workers 2]
       [--pools skidpad,all_maneuvers,...] [--strategies A,B] [--lookahead-seeds 5] [--out DIR] [--resume]
The comparisons are tracked in MLflow (sqlite:///mlruns/mlflow.db) and resumable (--resume).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd
from quick import shrink

from activelearn.config import CampaignConfig, load_config
from activelearn.loop.campaign import STATE_FILE, CampaignState
from activelearn.loop.pool import pool_maneuvers
from activelearn.studies.compare import compare

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
LOOKAHEAD = "oracle_lookahead"
# The cold start's comparison (issue 35): the uncertainty rules, a saturating information score along the
# path (bald: OpAx), diversity in predicted behaviour (igs), LCMD (bmdal_reg) and maximin-then-bald (switch).
COLD_START = (
    "uniform", "random", "max_epistemic", "integrated_variance", "auto", "bald", "igs", "lcmd", "switch",
)  # fmt: skip
# At the handling limit (issue 57, the 1:10 and the full-size car on the dynamic core): space filled in the
# model's own terms (regressor_maximin; with uniform's design gap, joint_maximin), the epistemic rule, auto.
HANDLING_LIMIT = ("uniform", "regressor_maximin", "joint_maximin", "max_epistemic", "auto")
# What each pool compares (uniform is the control everywhere; grid and random for reference).
POOLS: dict[str, tuple[str, ...]] = {
    "skidpad": ("uniform", "random", "max_epistemic", "integrated_variance", "auto"),
    "all_maneuvers": ("uniform", "max_epistemic", "integrated_variance", "auto"),
    "all_maneuvers_markov": ("uniform", "max_epistemic", "integrated_variance", "auto"),
    "odd_expansion": ("uniform", "grid", "random", "max_epistemic", "integrated_variance", "auto"),
    "odd_costs": ("uniform", "integrated_variance", "auto"),
    "sim_to_real": ("uniform", "max_epistemic", "integrated_variance", "auto"),
    "dynamics": COLD_START,
    "dynamics_twin": COLD_START,
    "dynamics_warm": ("uniform", "random", "max_epistemic", "integrated_variance", "auto"),
    "dynamics_f1tenth": HANDLING_LIMIT,
    "dynamics_f1tenth_twin": HANDLING_LIMIT,
    "dynamics_f1tenth_warm": HANDLING_LIMIT,
    "dynamics_bmw320i": HANDLING_LIMIT,
    "dynamics_bmw320i_twin": HANDLING_LIMIT,
    "dynamics_bmw320i_warm": HANDLING_LIMIT,
    "dynamics_bmw320i_warm_twin": HANDLING_LIMIT,
}


def _sem(values: np.ndarray) -> float:
    return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else float("nan")


def finals(curves: pd.DataFrame) -> pd.DataFrame:
    """The last round of every (strategy, seed)."""
    return curves.sort_values("round").groupby(["strategy", "seed"]).last().reset_index()


def reach_table(curves: pd.DataFrame, reference: str = "uniform", metric: str = "test_rmse") -> pd.DataFrame:
    """Per strategy: maneuvers and track seconds to reach the reference's mean final `metric`, as ratios."""
    last = finals(curves)
    ref = last[last["strategy"] == reference]
    target = ref[metric].mean()
    budget, seconds = ref["n_maneuvers"].mean(), ref["track_seconds"].mean()
    rows = []
    for strategy, part in curves.groupby("strategy", sort=False):
        need_n, need_s = [], []
        for _, run in part.groupby("seed"):
            run = run.sort_values("round")
            hit = run[run[metric] <= target]
            need_n.append(float(hit["n_maneuvers"].iloc[0]) if len(hit) else np.inf)
            need_s.append(float(hit["track_seconds"].iloc[0]) if len(hit) else np.inf)
        ratio_n, ratio_s = np.array(need_n) / budget, np.array(need_s) / seconds

        def q(values: np.ndarray, p: float, how: str) -> float:
            # order statistics, not interpolation: "never reached" (inf) stays inf
            return float(np.quantile(values, p, method=how))

        rows.append(
            {
                "strategy": strategy,
                "reached": f"{int(np.isfinite(ratio_n).sum())}/{len(ratio_n)}",
                "maneuvers_median": q(np.array(need_n), 0.5, "lower"),
                "ratio_median": q(ratio_n, 0.5, "lower"),
                "ratio_q25": q(ratio_n, 0.25, "lower"),
                "ratio_q75": q(ratio_n, 0.75, "higher"),
                "seconds_median": q(np.array(need_s), 0.5, "lower"),
                "s_ratio_median": q(ratio_s, 0.5, "lower"),
                "s_ratio_q25": q(ratio_s, 0.25, "lower"),
                "s_ratio_q75": q(ratio_s, 0.75, "higher"),
            }
        )
    table = pd.DataFrame(rows)
    table.attrs["target"] = target
    return table


def final_table(curves: pd.DataFrame, reference: str = "uniform", metric: str = "test_rmse") -> pd.DataFrame:
    """Per strategy: final `metric` ± s.e.m. (one-step RMSE beside it), paired wins against the reference."""
    last = finals(curves).set_index(["strategy", "seed"])
    ref = last.loc[reference, metric]
    rows = []
    for strategy in dict.fromkeys(curves["strategy"]):
        part = last.loc[strategy]
        paired = part[metric] - ref.reindex(part.index)
        rows.append(
            {
                "strategy": strategy,
                "seeds": len(part),
                f"final_{metric}": part[metric].mean(),
                "sem": _sem(part[metric].to_numpy()),
                **({} if metric == "test_rmse" else {"test_rmse": part["test_rmse"].mean()}),
                "rmse_v_mps": part["test_rmse_v"].mean(),
                "rmse_w_radps": part["test_rmse_w"].mean(),
                "diff_vs_uniform": paired.mean(),
                "diff_sem": _sem(paired.dropna().to_numpy()),
                "wins": f"{int((paired < 0).sum())}/{int(paired.notna().sum())}",
                "maneuvers": part["n_maneuvers"].mean(),
                "track_seconds": part["track_seconds"].mean(),
            }
        )
    return pd.DataFrame(rows)


def paired_table(curves: pd.DataFrame, reference: str = "uniform", metric: str = "test_rmse") -> pd.DataFrame:
    """Paired differences (strategy - reference) per round: mean ± s.e.m. and wins out of seeds."""
    ref = curves[curves["strategy"] == reference].set_index(["seed", "round"])[metric]
    rows = []
    for strategy, part in curves.groupby("strategy", sort=False):
        if strategy == reference:
            continue
        indexed = part.set_index(["seed", "round"])
        diff = indexed[metric] - ref
        for r, values in diff.dropna().groupby(level="round"):
            v = values.to_numpy()
            maneuvers = indexed.loc[values.index, "n_maneuvers"].mean()
            rows.append(
                {
                    "strategy": strategy,
                    "round": int(r),
                    "maneuvers": float(maneuvers),
                    "mean_diff": v.mean(),
                    "sem": _sem(v),
                    "worse_by_sem": v.mean() / _sem(v) if _sem(v) > 0 else (0.0 if v.mean() == 0 else np.inf),
                    "wins": f"{int((v < 0).sum())}/{len(v)}",
                }
            )
    return pd.DataFrame(rows)


def room_table(
    curves: pd.DataFrame, reference: str = "uniform", metric: str = "test_rmse"
) -> pd.DataFrame | None:
    """Share of the room (reference minus lookahead oracle, final budget) each strategy captures."""
    if LOOKAHEAD not in set(curves["strategy"]):
        return None
    last = finals(curves).set_index(["strategy", "seed"])[metric]
    seeds = last.loc[LOOKAHEAD].index
    ref = last.loc[reference].reindex(seeds).mean()
    room = ref - last.loc[LOOKAHEAD].mean()
    rows = []
    for strategy in dict.fromkeys(curves["strategy"]):
        value = last.loc[strategy].reindex(seeds).mean()
        rows.append({"strategy": strategy, "final_on_lookahead_seeds": value,
                     "share_of_room": (ref - value) / room if room > 0 else np.nan})  # fmt: skip
    table = pd.DataFrame(rows)
    table.attrs["room"] = room
    table.attrs["seeds"] = len(seeds)
    return table


def calibration_table(curves: pd.DataFrame) -> pd.DataFrame:
    """Epistemic calibration diagnostic per strategy and round (means over seeds)."""
    cols = [
        c for c in ("calib_z_spread", "calib_spearman", "prequential_spearman", "coverage_95") if c in curves
    ]
    return curves.groupby(["strategy", "round"])[["n_maneuvers", *cols]].mean().reset_index()


def pick_table(directories: list[Path], cfg: CampaignConfig) -> pd.DataFrame:
    """Where the picks after the initial design land, per strategy, beside the pool's own shares.

    A maneuver is on the edge when its throttle is the pool's lowest or highest, or its steering
    magnitude the pool's smallest or largest non-zero one; `reverse` counts negative throttles.
    """
    pool = pool_maneuvers(cfg.pool)
    throttles = np.array([m.throttle for m in pool])
    steerings = np.array([m.steering for m in pool])
    turning = steerings[steerings > 0]
    edge = (throttles == throttles.min()) | (throttles == throttles.max())
    if len(turning):
        edge |= (steerings > 0) & ((steerings == turning.min()) | (steerings == turning.max()))
    kinds = np.array([m.kind for m in pool])
    kind_names = list(dict.fromkeys(kinds))  # a family pool's kinds are its families

    def shares(picks: np.ndarray) -> dict:
        row = {"picks": len(picks), "edge_share": float(edge[picks].mean()),
               "reverse_share": float((throttles[picks] < 0).mean())}  # fmt: skip
        if len(set(kinds)) > 1:
            row.update({kind: int((kinds[picks] == kind).sum()) for kind in kind_names})
        return row

    rows = [{"strategy": "(pool)", **shares(np.arange(len(pool)))}]
    first = 1 if cfg.design.initial > 0 else 0
    for directory in directories:
        for strategy_dir in sorted(p for p in directory.iterdir() if p.is_dir()):
            picks = [
                i
                for state in strategy_dir.glob(f"seed*/{STATE_FILE}")
                for batch in CampaignState.load(state.parent).batches[first:]
                for i in batch
            ]
            if picks:
                rows.append({"strategy": strategy_dir.name, **shares(np.array(picks))})
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0,
                        help="run seeds first-seed .. first-seed + seeds - 1 (fresh seeds to check a "
                             "rule chosen on others)")  # fmt: skip
    parser.add_argument(
        "--lookahead-seeds", type=int, default=5, help="seeds of the lookahead oracle (0: none)"
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--executor", default="process", help="process or ray (see docs/how-to/scale-out.md)")
    parser.add_argument("--ray-address", default=None, help="with --executor ray: auto, HOST:PORT or local")
    parser.add_argument("--pools", default=",".join(POOLS))
    parser.add_argument("--strategies", default=None, help="override every pool's strategy list")
    parser.add_argument("--out", default="runs/bench_sample_efficiency")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--no-tracking", action="store_true")
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes: checks every part still runs (tests/test_benchmarks.py)")
    args = parser.parse_args()
    if args.quick:  # one pool unless named, one seed of each strategy and of the lookahead oracle
        args.seeds, args.lookahead_seeds, args.workers, args.no_tracking = 1, 1, 1, True
        if args.pools == ",".join(POOLS):
            args.pools = "skidpad"
    pd.set_option("display.width", 200)
    pd.set_option("display.max_columns", 30)
    for name in args.pools.split(","):
        cfg = load_config(CONFIGS / f"{name}.toml")
        if args.quick:
            cfg = shrink(cfg, Path(args.out) / "runs")
        metric = cfg.test.metric  # what the config ranks by: test_rmse, or a free-run error
        strategies = args.strategies.split(",") if args.strategies else list(POOLS[name])
        started = time.perf_counter()
        runs = [(Path(args.out) / name, strategies, args.seeds)]
        if args.lookahead_seeds:
            runs.append((Path(args.out) / f"{name}_lookahead", [LOOKAHEAD], args.lookahead_seeds))
        parts = []
        for directory, names, seeds in runs:
            seed_list = list(range(args.first_seed, args.first_seed + seeds))
            result = compare(cfg, names, seed_list, directory=directory, workers=args.workers,
                             tracking=not args.no_tracking, resume=args.resume,
                             executor=args.executor, ray_address=args.ray_address)  # fmt: skip
            parts.append(result.curves)
        curves = pd.concat(parts, ignore_index=True)
        print(
            f"\n=== {name}: {args.seeds} seeds ({args.lookahead_seeds} for the lookahead oracle), "
            f"{len(strategies)} strategies, {time.perf_counter() - started:.0f} s wall ==="
        )
        print(final_table(curves, metric=metric).to_string(index=False, float_format="%.4g"))
        reach = reach_table(curves, metric=metric)
        print(
            f"\nto reach uniform's final {metric} {reach.attrs['target']:.4g}: new maneuvers and track "
            "seconds, as ratios to uniform's budget (median, quartiles; inf = not reached):"
        )
        print(reach.to_string(index=False, float_format="%.3g"))
        room = room_table(curves, metric=metric)
        if room is not None:
            print(f"\nroom: uniform - lookahead = {room.attrs['room']:.4g} at the final budget "
                  f"({room.attrs['seeds']} seeds); share each strategy captures:")  # fmt: skip
            print(room.to_string(index=False, float_format="%.3g"))
        paired = paired_table(curves, metric=metric)
        print(f"\npaired {metric} differences against uniform per round (negative = better):")
        print(paired.to_string(index=False, float_format="%.4f"))
        auto = paired[(paired["strategy"] == "auto") & (paired["maneuvers"] >= 8)]
        if len(auto):
            worst = auto["worse_by_sem"].replace(np.inf, np.nan).max()
            print(f"\nauto against uniform at budgets >= 8: worst mean difference = {worst:.2f} s.e.m. "
                  f"({'within' if not worst > 1 else 'BEYOND'} one s.e.m.)")  # fmt: skip
        print("\nepistemic calibration at each round (mean over seeds):")
        print(calibration_table(curves).to_string(index=False, float_format="%.3f"))
        print("\nwhere the picks land (all seeds, after any initial design):")
        print(pick_table([d for d, _, _ in runs], cfg).to_string(index=False, float_format="%.2f"))


if __name__ == "__main__":
    main()
