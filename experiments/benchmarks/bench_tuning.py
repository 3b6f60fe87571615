"""Benchmark `activelearn tune`: trials per minute with 1 and 2 workers on SQLite, and a real study.

Part 1 (throughput) runs the same fixed-cost study twice on the skidpad config's data, into fresh
SQLite storages with MLflow tracking on: once with 1 worker (in-process), once with 2 worker
processes. Every parameter but the learning rate is fixed and pruning is off, so every trial does
the same work and the ratio measures what the second process buys (process start-up, storage and
MLflow contention included). Part 2 runs a real study with the default search space on
experiments/configs/skidpad.toml and prints the best parameters as the TOML snippet `tune` writes.

    python experiments/benchmarks/bench_tuning.py                       # both parts
    python experiments/benchmarks/bench_tuning.py --study-trials 0      # throughput only
    python experiments/benchmarks/bench_tuning.py --trials 0            # real study only

The load average is printed beside the timings: on a shared machine other jobs take cores too.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from quick import shrink

from activelearn.config import load_config
from activelearn.studies.tuning import collect_dataset, split_data, study_trials, tune

ROOT = Path(__file__).resolve().parents[2]
SKIDPAD = ROOT / "experiments" / "configs" / "skidpad.toml"

# Fixed-cost space for the throughput part: only lr varies (it does not change the work per epoch).
FIXED_SPACE = {
    "lr": {"low": 1e-3, "high": 1e-2, "log": True},
    "batch_size": 64,
    "optimizer": "adam",
    "loss": "nll",
    "posterior": "mean_field",
    "kl": "exact",
    "activation": "softplus",
    "prior_scale": 1.0,
    "n_layers": 2,
    "width": 32,
    "variational": False,
}


QUICK = False  # `--quick`: the skidpad config at quick sizes (see quick.py)


def skidpad(overrides: dict | None = None):
    """The skidpad config with `overrides` (at quick sizes with `--quick`, its [tuning] kept)."""
    cfg = load_config(SKIDPAD, overrides=overrides)
    return shrink(cfg).model_copy(update={"tuning": cfg.tuning, "tracking": cfg.tracking}) if QUICK else cfg


def load() -> str:
    """The 1-minute load average and the core count."""
    return f"load {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores"


def throughput(n_trials: int, epochs: int, workers: int, directory: Path) -> tuple[float, float, float]:
    """Trials per minute, wall seconds and mean seconds per trial of one fixed-cost study."""
    cfg = skidpad(
        overrides={
            "tracking": {"uri": f"sqlite:///{directory}/mlflow.db"},
            # patience above epochs: every trial runs all its epochs
            "training": {"patience": epochs + 1},
            "tuning": {"space": {**FIXED_SPACE, "epochs": epochs}},
        },
    )
    storage = f"sqlite:///{directory}/optuna-{workers}.db"
    result = tune(
        cfg,
        n_trials=n_trials,
        storage=storage,
        study_name=f"throughput-{workers}",
        workers=workers,
        pruner="none",
        out=directory / f"best-{workers}.toml",
    )
    assert result.n_trials == n_trials, result.states
    seconds = [t["seconds"] for t in study_trials(storage, f"throughput-{workers}")]
    return result.trials_per_minute, result.wall_seconds, sum(seconds) / len(seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=12, help="trials per throughput run (0: skip)")
    parser.add_argument("--epochs", type=int, default=25, help="epochs per throughput trial (default 25)")
    parser.add_argument("--study-trials", type=int, default=40, help="trials of the real study (0: skip)")
    parser.add_argument("--study-workers", type=int, default=2, help="workers of the real study")
    parser.add_argument("--study-timeout", type=float, default=1200, help="seconds: no new trial after this")
    parser.add_argument("--out", default=str(ROOT / "runs" / "bench_tuning"),
                        help="directory of the real study")
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes: checks every part still runs (tests/test_benchmarks.py)")
    args = parser.parse_args()
    if args.quick:  # two trials of two epochs each way, a two-trial study
        global QUICK
        QUICK = True
        args.trials, args.epochs, args.study_trials, args.study_workers = 2, 2, 2, 1

    cfg = skidpad()
    t0 = time.perf_counter()
    data = collect_dataset(cfg)  # simulated once, then read from runs/cache
    split = split_data(data, cfg.tuning.val_fraction, cfg.seed)
    print(f"skidpad data: {split.describe()} ({time.perf_counter() - t0:.1f} s to load or simulate)")

    if args.trials > 0:
        with tempfile.TemporaryDirectory(prefix="bench-tuning-") as tmp:
            rates = {}
            for workers in (1, 2):
                before = load()
                rate, wall, per_trial = throughput(args.trials, args.epochs, workers, Path(tmp))
                rates[workers] = rate
                print(f"{workers} worker(s): {args.trials} trials x {args.epochs} epochs in {wall:.1f} s = "
                      f"{rate:.2f} trials/min, {per_trial:.2f} s per trial "
                      f"({before} before, {load()} after)")  # fmt: skip
            print(f"ratio 2 workers / 1 worker: {rates[2] / rates[1]:.2f}")

    if args.study_trials > 0:
        out = Path(args.out)
        overrides = {"tracking": {"uri": f"sqlite:///{out}/mlflow.db"}}
        if args.quick:  # the default space but for its epochs (up to 200: most of the quick run)
            overrides["tuning"] = {"space": {"epochs": args.epochs}}
        study_cfg = skidpad(overrides)
        quick = f" but {args.epochs} epochs" if args.quick else ""
        name = f"skidpad-{time.strftime('%Y%m%d-%H%M%S')}"
        print(f"real study {name!r}: {args.study_trials} trials, {args.study_workers} workers, "
              f"timeout {args.study_timeout:g} s, default search space{quick} ({load()})")  # fmt: skip
        result = tune(
            study_cfg,
            n_trials=args.study_trials,
            storage=f"sqlite:///{out}/optuna.db",
            study_name=name,
            workers=args.study_workers,
            timeout=args.study_timeout,
            out=out / name / "best.toml",
        )
        states = ", ".join(f"{k.lower()} {v}" for k, v in result.states.items())
        print(f"{result.n_trials} trials ({states}) in {result.wall_seconds:.0f} s = "
              f"{result.trials_per_minute:.2f} trials/min ({load()})")  # fmt: skip
        print(result.best.head(5).to_string(index=False, float_format="%.4g"))
        if result.best_path is not None:
            print(f"\n{result.best_path}:\n{result.best_path.read_text()}")


if __name__ == "__main__":
    main()
