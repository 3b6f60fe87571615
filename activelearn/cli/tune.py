"""`activelearn tune`: an Optuna study of the model's hyperparameters, tracked in MLflow."""

from __future__ import annotations

import argparse
import sys

from activelearn.cli.common import EXIT_INTERRUPTED, output_path, red, ui_hint, yellow

# --- tune -----------------------------------------------------------------------------------------

BEST_COLUMNS = {
    "trial": "trial",
    "val_nll": "val NLL",
    "val_rmse": "val RMSE",
    "arch": "arch",
    "activation": "act",
    "posterior": "posterior",
    "kl": "kl",
    "prior_scale": "prior",
    "lr": "lr",
    "optimizer": "opt",
    "loss": "loss",
    "batch_size": "batch",
    "epochs": "epochs",
    "best_epoch": "best ep",
}


# Mirrors activelearn.studies.tuning.DEFAULT_STORAGE / PRUNERS: importing that module (Optuna, torch) here
# would slow down every command; tests check the copies agree.
TUNE_STORAGE = "sqlite:///mlruns/optuna.db"
TUNE_PRUNERS = ("median", "hyperband", "none")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "tune", help="tune the model's hyperparameters with Optuna (tracked in MLflow)",
        description="Optuna study over the config's [tuning.space]: minimise the validation NLL (and "
                    "optionally RMSE) on operating points held out whole. Same --study-name continues.",
    )  # fmt: skip
    p.add_argument("config", metavar="CONFIG",
                   help="campaign config (TOML) with an optional [tuning] section")
    p.add_argument("--n-trials", type=int, required=True, metavar="N",
                   help="trials this command adds to the study (shared by its workers)")
    p.add_argument("--storage", default=TUNE_STORAGE, metavar="URL",
                   help=f"Optuna storage (default {TUNE_STORAGE}); postgresql://user:pass@host/db "
                        "lets workers on many machines join one study")
    p.add_argument("--study-name", default=None, metavar="NAME",
                   help="study name (default: the config's name)")
    p.add_argument("--workers", type=int, default=1, metavar="K", help="worker processes (default 1)")
    p.add_argument("--timeout", type=float, default=None, metavar="SEC",
                   help="start no new trial after SEC seconds")
    p.add_argument("--tracking-uri", default=None, metavar="URI",
                   help="MLflow tracking URI (default: the config's, sqlite:///mlruns/mlflow.db)")
    p.add_argument("--no-tracking", action="store_true", help="do not log to MLflow")
    p.add_argument("--data", nargs="+", default=None, metavar="PATH",
                   help="train on these tables (.parquet) or AutoDRIVE logs (.csv) instead of simulating "
                        "the config's pool")
    p.add_argument("--objectives", default="nll", metavar="nll|nll,rmse",
                   help="validation NLL, or NLL and RMSE (multi-objective: no pruning)")
    p.add_argument("--pruner", default="median", choices=TUNE_PRUNERS, help="trial pruner (default median)")
    p.add_argument("--seed", type=int, default=None, metavar="N", help="sampler seed (default: the config's)")
    p.add_argument("--out", default=None, metavar="TOML",
                   help="best params file (default <output_dir>/tuning/<study>/best.toml, <output_dir> being "
                        "the config's, default runs); figures go beside it")
    p.set_defaults(handler=_tune)


def _tune(args: argparse.Namespace) -> int:
    import math

    from tqdm import tqdm

    from activelearn.config import load_config
    from activelearn.errors import InputError
    from activelearn.studies.tuning import TuningInterrupted, parse_objectives, tune

    # Argument checks first: a mistake never creates a study, a run or a file.
    if args.n_trials < 1:
        raise InputError("--n-trials", args.n_trials, "must be at least 1")
    if args.workers < 1:
        raise InputError("--workers", args.workers, "must be at least 1")
    if args.timeout is not None and not args.timeout > 0:
        raise InputError("--timeout", args.timeout, "must be > 0 seconds")
    if args.out is not None:
        output_path("--out", args.out)
    objectives = parse_objectives(args.objectives)
    overrides: dict[str, object] = {}
    if args.tracking_uri is not None:
        overrides["tracking"] = {"uri": args.tracking_uri}
    cfg = load_config(args.config, overrides=overrides)
    study_name = args.study_name or cfg.name
    bars: dict[str, tqdm] = {}
    counts = {"COMPLETE": 0, "PRUNED": 0, "FAIL": 0}
    best = [math.inf]

    def progress(event: dict) -> None:
        kind = event["event"]
        if kind == "note":
            tqdm.write(f"note: {event['message']}", file=sys.stderr)
        elif kind == "warning":  # a worker was lost; the study goes on without losing a trial
            tqdm.write(yellow(f"warning: {event['message']}"), file=sys.stderr)
        elif kind == "sim_progress":
            bar = bars.setdefault("sim", tqdm(total=event["total"], unit="sample", desc="simulating pool",
                                              leave=False, disable=None))
            bar.update(event["done"] - bar.n)
        elif kind == "start":
            if "sim" in bars:
                bars.pop("sim").close()
            if event["existing_trials"]:
                tqdm.write(f"continuing study {event['study']!r} ({event['existing_trials']} trials so far)",
                           file=sys.stderr)
            tqdm.write(f"data: {event['train_rows']} training rows at {event['train_points']} operating "
                       f"points, {event['val_rows']} validation rows at {event['val_points']} held-out "
                       "points", file=sys.stderr)
            bars["trials"] = tqdm(total=args.n_trials, unit="trial", desc=f"tune {study_name}", disable=None)
        elif kind == "trial":
            counts[event["state"]] = counts.get(event["state"], 0) + 1
            if event["state"] == "COMPLETE" and event["values"]:
                best[0] = min(best[0], event["values"][0])
            if event["state"] == "FAIL" and event.get("fail_reason"):
                tqdm.write(f"trial {event['number']} failed: {event['fail_reason']}", file=sys.stderr)
            bar = bars.get("trials")
            if bar is not None:
                bar.update(1)
                bar.set_postfix(best_nll=f"{best[0]:.4g}", pruned=counts["PRUNED"], failed=counts["FAIL"])

    try:
        result = tune(cfg, n_trials=args.n_trials, storage=args.storage, study_name=args.study_name,
                      workers=args.workers, timeout=args.timeout, data=args.data, objectives=objectives,
                      pruner=args.pruner, seed=args.seed, out=args.out, tracking=not args.no_tracking,
                      progress=progress)  # fmt: skip
    except TuningInterrupted as exc:
        print(red(f"interrupted: {exc}"), file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        for bar in bars.values():
            bar.close()
    states = ", ".join(f"{n.lower()} {c}" for n, c in result.states.items() if c)
    print(f"study {result.study_name!r}: {result.n_trials} trials this run ({states}), "
          f"{result.study_trials} finished in all; {result.trials_per_minute:.2f} trials/min")
    for note in result.notes:
        print(f"note: {note}")
    if result.best.empty:
        print("no completed trial yet")
        return 1
    title = "Pareto front (val NLL, val RMSE)" if len(result.objectives) > 1 else "best trials"
    table = result.best[[c for c in BEST_COLUMNS if c in result.best]].rename(columns=BEST_COLUMNS)
    print(f"{title}:")
    print(table.to_string(index=False, float_format="%.4g"))
    print(f"best params: {result.best_path}  "
          f"(activelearn campaign run {args.config} --params {result.best_path})")
    if result.figures:
        print("figures: " + ", ".join(str(f) for f in result.figures))
    print(f"storage: {result.storage}  (optuna-dashboard {result.storage})")
    if result.parent_run_id is not None:
        print(f"MLflow parent run {result.parent_run_id} ({ui_hint(cfg.tracking.uri)})")
    return 0

