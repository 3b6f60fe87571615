"""`activelearn compare`: strategies x seeds on one config, ranked against uniform."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from activelearn.cli.common import (
    EXIT_INTERRUPTED,
    add_config_options,
    load_campaign_config,
    output_path,
    red,
    ui_hint,
)
from activelearn.names import STRATEGY_NAMES, TEST_RMSE

# The comparison table's columns as printed.
SUMMARY_COLUMNS = {
    "strategy": "strategy",
    "seeds": "seeds",
    "final_rmse": "final RMSE",
    "final_rmse_sem": "± s.e.",
    "final_rmse_v": "v (m/s)",
    "final_rmse_w": "ω (rad/s)",
    "final_nll": "final NLL",
    "rmse_auc": "RMSE AUC",
    "final_metric": "final metric",
    "final_metric_sem": "± s.e. ",
    "metric_auc": "metric AUC",
    "reached": "reached",
    "maneuvers_to_target": "maneuvers to target",
    "ratio_to_reference": "ratio",
    "seconds_to_target": "seconds to target",
    "seconds_ratio": "s ratio",
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help="compare strategies over seeds under one MLflow parent run",
                       description="Run strategies x seeds on one config and compare them with uniform.")
    add_config_options(p, "<output_dir>/<name>/compare")
    p.add_argument("--strategies", default="uniform,max_epistemic", metavar="A,B,...",
                   help="comma-separated strategies (default: uniform,max_epistemic), from "
                        f"{', '.join(STRATEGY_NAMES)}")
    p.add_argument("--seeds", type=int, default=3, metavar="N",
                   help="how many seeds: FIRST..FIRST+N-1 (default 3)")
    p.add_argument("--first-seed", type=int, default=0, metavar="FIRST",
                   help="the first seed (default 0): fresh seeds confirm what others decided")
    p.add_argument("--workers", type=int, default=None, metavar="K",
                   help="parallel processes, or CPUs of a local Ray cluster (default: number of cores)")
    p.add_argument("--executor", default="process", metavar="NAME",
                   help="process (default: local processes) or ray (one task per campaign on a Ray cluster)")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="with --executor ray: auto (the cluster this machine belongs to), HOST:PORT, "
                        "or local (an in-process cluster; the default)")
    p.add_argument("--metric", default=None, metavar="NAME",
                   help="what the table, the 'to reach uniform' columns and the figure rank by: test_rmse, "
                        "rollout_pos_err_30s, ... (default: the config's [test] metric)")
    p.set_defaults(handler=_compare)


def _compare(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from activelearn.errors import InputError

    strategies = [s.strip() for s in args.strategies.split(",") if s.strip()]
    if args.seeds < 1:
        raise InputError("--seeds", args.seeds, "must be at least 1")
    if args.first_seed < 0:
        raise InputError("--first-seed", args.first_seed, "must be at least 0")
    if args.workers is not None and args.workers < 1:
        raise InputError("--workers", args.workers, "must be at least 1")
    cfg = load_campaign_config(args)
    directory = output_path("--out", args.out or Path(cfg.output_dir) / cfg.name / "compare", folder=True)
    if args.resume and not (directory / "compare.json").is_file():
        raise InputError("--resume", str(directory),
                         "holds no comparison to resume (no compare.json): check --out, or drop --resume")
    from activelearn.studies.compare import compare  # torch and the loop: after the input is checked

    n_jobs = len(strategies) * args.seeds
    bars: dict[str, tqdm] = {}

    def progress(event: dict) -> None:
        if event["event"] == "sim_progress":
            bar = bars.setdefault("sim", tqdm(total=event["total"], unit="sample", desc="simulating pool",
                                              leave=False, disable=None))
            bar.update(event["done"] - bar.n)
        elif event["event"] == "dashboard":
            tqdm.write(f"Ray dashboard: {event['url']}", file=sys.stderr)
        elif event["event"] == "job":
            bar = bars.setdefault("jobs", tqdm(total=n_jobs, unit="campaign", desc="campaigns", disable=None))
            bar.update(1)
            bar.set_postfix(last=f"{event['strategy']}/seed{event['seed']}", rmse=f"{event[TEST_RMSE]:.4f}")

    try:
        seeds = list(range(args.first_seed, args.first_seed + args.seeds))
        result = compare(cfg, strategies, seeds, directory=directory, workers=args.workers,
                         tracking=cfg.tracking.enabled and not args.no_tracking, resume=args.resume,
                         progress=progress, executor=args.executor, ray_address=args.ray_address,
                         metric=args.metric, lock_wait=args.wait)
    except KeyboardInterrupt:
        print(red("interrupted: finished rounds are checkpointed; rerun the same command with --resume"),
              file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        for bar in bars.values():
            bar.close()
    table = result.table
    metric = table.attrs["metric"]
    if metric == TEST_RMSE:
        print(f"target: {table.attrs['reference']}'s final RMSE {table.attrs['target_rmse']:.4g} "
              "(standardised; RMSE of v in m/s and ω in rad/s beside it)")
    else:
        print(f"target: {table.attrs['reference']}'s final {metric} {table.attrs['target_rmse']:.4g} "
              "(final metric; one-step RMSE beside it)")
    summary = table[[c for c in SUMMARY_COLUMNS if c in table]].rename(columns=SUMMARY_COLUMNS)
    print(summary.to_string(index=False, float_format="%.4g"))
    print(f"figure: {result.figure_path}")
    print(f"curves and table: {result.directory}")
    if result.parent_run_id is not None:
        print(f"MLflow parent run {result.parent_run_id} ({ui_hint(cfg.tracking.uri)})")
    return 0

