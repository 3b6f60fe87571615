"""The physics-structured model against the datasheet, its own bare core and the shipped black box.

For the nominal simulator and for the twin (`sim_to_real`'s weaker motor and less grip, where the
datasheet is wrong), each training seed draws `--train-maneuvers` maneuvers at random from
`dynamics.toml`'s family pool (slaloms, fishhooks, throttle steps, chirps, PRBS, both ways; forward
and reverse), collects them from that oracle, and scores free runs of `dynamics.toml`'s test set (72
maneuvers, 30 s, noise-free truth of the same oracle) for:
  * datasheet     Nigel's single track from its datasheet, no data at all;
  * core          the single track identified on the training logs, no learnt correction;
  * physics       the physics kind with its defaults (identified core + bounded hybrid correction);
  * gated         the same with `[model] correction_gate`: a probe without a quarter of the training
                  maneuvers decides how much of the correction's mean to keep;
  * black box     the best black box (history ensemble of 5 + kinematic feature + 30-step windows,
                  `dynamics.toml`'s model before it moved to the physics kind);
all trained as `dynamics.toml` trains. Prints the 30-s position error of the mean path per test kind
and over all, mean ± s.e.m. over training seeds, the 95 % fan's share of true positions, and the
paired ratio physics / black box per seed.

Usage: python experiments/benchmarks/bench_physics.py [--seeds 5] [--train-maneuvers 40]
       [--oracles nominal,twin] [--epochs 150] [--params P.toml] [--quick]
`--quick` (what the test runs): 1 seed, 4 training maneuvers, 3 epochs, the test set at quick.py's sizes.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from quick import shrink

from activelearn.config import load_config
from activelearn.errors import ActiveLearnError
from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import arrays, control_rate_logs, training_rows, training_windows
from activelearn.numerics.diagnostics import free_run_metrics, free_runs, relative_pose
from activelearn.numerics.models import build_model
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from simulator.datasheet import LOG_RATE_HZ

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
# dynamics.toml, and the same answered by sim_to_real.toml's twin (tests/test_twin.py keeps them equal)
ORACLE_CONFIGS = {"nominal": CONFIGS / "dynamics.toml", "twin": CONFIGS / "dynamics_twin.toml"}
VARIANTS = ("datasheet", "core", "physics", "gated", "black box")
PHYSICS = {"kind": "physics", "kinematic_feature": False}
BLACK_BOX = {"kind": "ensemble", "ensemble_size": 5, "kinematic_feature": True}


def campaign_for(
    oracle: str, scratch: Path, epochs: int | None, quick: bool = False, params: str | None = None
) -> Campaign:
    """dynamics.toml against the nominal simulator or the twin (its test set cached in runs/cache; at
    quick.py's sizes with `quick`: a few short test maneuvers instead of 72 of 30 s), with `params`'
    [model] and [training] tables over it (as `campaign run --params`)."""
    overrides = {} if epochs is None else {"training": {"epochs": epochs}}
    cfg = load_config(ORACLE_CONFIGS[oracle], params=params, overrides=overrides)
    if quick:
        cfg = shrink(cfg).model_copy(update={"training": cfg.training})
    return Campaign(cfg, scratch / oracle, cache_dir=Path("runs/cache"))


def trained(campaign: Campaign, variant: str, frames: list[pd.DataFrame], seed: int):
    """One variant fitted to the training logs as dynamics.toml trains."""
    cfg = campaign.cfg
    update = BLACK_BOX if variant == "black box" else PHYSICS
    if variant in ("physics", "gated"):
        update = {**update, "correction_gate": variant == "gated"}
    model_cfg = cfg.model.model_copy(update=update)
    model = build_model(model_cfg, seed=seed)
    rows = pd.concat([training_rows(frame, cfg.data) for frame in frames])
    x, y = arrays(rows, cfg.data)
    logs = control_rate_logs(frames)
    if variant in ("datasheet", "core"):
        model.set_scalers(x, y)
        if variant == "core":
            model.identify(TrainingData(x, y, logs=logs))
        model.corrected = False
        return model
    horizon = cfg.training.rollout_horizon
    windows = training_windows(frames, cfg.data, horizon) if horizon else None
    groups = rows["run_id"].to_numpy() if "run_id" in rows else None
    log_groups = [int(frame["run_id"].iloc[0]) for frame in frames]
    fit(
        model,
        TrainingData(x, y, groups=groups, windows=windows, logs=logs, log_groups=log_groups),
        cfg.training,
        seed=seed,
    )  # fmt: skip
    return model


def errors_by_maneuver(model, logs, truth_logs) -> np.ndarray:
    """30-s position error of each test maneuver's mean path."""
    rollout = free_runs(model, logs, rate_hz=LOG_RATE_HZ)
    mean_x, mean_y = rollout.mean_path()
    out = []
    for i, table in enumerate(truth_logs):
        n = int(rollout.lengths[i])
        truth = {c: table[c].to_numpy(dtype=np.float64) for c in ("posX", "posY", "yaw")}
        tx, ty, _ = relative_pose(truth, n)
        k = min(round(30.0 / rollout.dt), n - 1)
        out.append(float(np.nan_to_num(np.hypot(mean_x[i, k] - tx[k], mean_y[i, k] - ty[k]), nan=np.inf)))
    return np.array(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--train-maneuvers", type=int, default=40)
    parser.add_argument("--oracles", default="nominal,twin")
    parser.add_argument("--epochs", type=int, default=None, help="default: dynamics.toml's")
    parser.add_argument("--test-maneuvers", type=int, default=None, help="default: all 72")
    parser.add_argument("--variants", default=",".join(VARIANTS), help=f"a subset of {', '.join(VARIANTS)}")
    parser.add_argument(
        "--params",
        default=None,
        help="a TOML file of [model]/[training] tables over dynamics.toml (as `campaign run --params`): "
        "what the physics variants inherit",
    )
    parser.add_argument("--quick", action="store_true", help="a few seconds per oracle: checks it runs")
    args = parser.parse_args()
    if args.quick:
        args.seeds, args.train_maneuvers, args.epochs, args.test_maneuvers = 1, 4, 3, 4
    oracles = [o for o in args.oracles.split(",") if o]
    if set(oracles) - set(ORACLE_CONFIGS) or not oracles:
        parser.error("--oracles: nominal and/or twin")
    variants = [v for v in args.variants.split(",") if v]
    if set(variants) - set(VARIANTS) or not variants:
        parser.error(f"--variants: a subset of {', '.join(VARIANTS)}")
    if args.seeds < 1 or args.train_maneuvers < 1:
        parser.error("--seeds and --train-maneuvers: at least 1")
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    pd.set_option("display.width", 160)
    with tempfile.TemporaryDirectory() as scratch:
        for oracle in oracles:
            try:
                campaign = campaign_for(oracle, Path(scratch), args.epochs, args.quick, args.params)
            except ActiveLearnError as error:
                parser.error(str(error))
            test = campaign.test_set
            kinds = [m.kind for m in campaign.oracle.test_maneuvers()]
            n_test = args.test_maneuvers or len(test.logs)
            keep = np.linspace(0, len(test.logs) - 1, n_test).round().astype(int)  # every kind, both ways
            logs, truth = [test.logs[i] for i in keep], [test.truth_logs[i] for i in keep]
            kinds = [kinds[i] for i in keep]
            candidates = campaign.oracle.candidates()
            rows = []
            for seed in seeds:
                rng = np.random.default_rng(seed)
                chosen = rng.choice(len(candidates), size=args.train_maneuvers, replace=False)
                chosen = sorted(chosen.tolist())
                frames = campaign.oracle.answer([candidates[i] for i in chosen], seed)
                for i, frame in enumerate(frames):
                    frame["run_id"] = i
                for variant in variants:
                    started = time.perf_counter()
                    model = trained(campaign, variant, frames, seed)
                    seconds = time.perf_counter() - started
                    errors = errors_by_maneuver(model, logs, truth)
                    metrics = free_run_metrics(model, logs, truth, rate_hz=LOG_RATE_HZ)
                    coverage = metrics["rollout_coverage_95"]
                    print(f"{oracle} seed {seed} {variant:10s} 30-s error {errors.mean():.4f} m, fan holds "
                          f"{coverage:.2f} (trained in {seconds:.0f} s)", flush=True)  # fmt: skip
                    for kind, error in zip(kinds, errors, strict=True):
                        rows.append({"seed": seed, "variant": variant, "kind": kind, "error": error,
                                     "coverage": coverage})  # fmt: skip
            report(pd.DataFrame(rows), oracle, args.train_maneuvers, len(seeds), variants)


def report(frame: pd.DataFrame, oracle: str, n_train: int, n_seeds: int, variants: list[str]) -> None:
    """Per-kind and overall 30-s errors, mean ± s.e.m. over seeds, and paired ratios (physics and gated
    over the black box, gated over physics) where both were run."""
    per_seed = frame.groupby(["seed", "variant", "kind"])["error"].mean().unstack("kind")
    per_seed["all"] = frame.groupby(["seed", "variant"])["error"].mean()
    mean = per_seed.groupby("variant").mean().reindex(variants)
    sem = per_seed.groupby("variant").sem().reindex(variants).fillna(0.0)
    cells = mean.map(lambda v: f"{v:.4f}") + " ± " + sem.map(lambda v: f"{v:.4f}")
    coverage = frame.groupby("variant")["coverage"].mean().reindex(variants)
    cells["fan holds"] = coverage.map(lambda v: f"{v:.2f}")
    print(f"\n{oracle}: 30-s position error of the mean path (m), {n_train} training maneuvers, "
          f"mean ± s.e.m. over {n_seeds} seeds:")  # fmt: skip
    print(cells.to_string())
    for top, bottom in (("physics", "black box"), ("gated", "black box"), ("gated", "physics")):
        if top in variants and bottom in variants:
            ratio = per_seed.xs(top, level="variant") / per_seed.xs(bottom, level="variant")
            print(f"\n{oracle}: {top} / {bottom} per seed (paired):")
            print(ratio.to_string(float_format="%.3f"))


if __name__ == "__main__":
    main()
