"""Trained on forward driving only, how far off is each model in reverse and at full lock?

Fits, on `dynamics_warm.toml`'s prior alone (the forward reference grid: straights and skidpads), the
configs' black box (history ensemble + kinematic feature + 30-step windows) and the physics-structured
model (`[model] kind = "physics"`, its defaults), each from training seeds 0..N-1, and prints the 30-s
position error of the free runs of `dynamics.toml`'s 72 test maneuvers (noise-free truth): all, the
reverse ones (throttle < 0) and the fishhooks (steering ramps to full lock), with the 95 % fans' share
of true positions.

With `--figure PNG`, draws the seed-0 models' free runs (95 % fans as their sampled paths) beside
MuJoCo's on a reverse skidpad and a fishhook to full lock.

Usage: python experiments/investigations/physics_forward_only.py [--seeds 3] [--figure PNG] [--params P.toml]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from activelearn.config import load_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.prior import load_prior
from activelearn.numerics.diagnostics import free_runs, relative_pose
from activelearn.numerics.models import build_model
from activelearn.numerics.training import fit
from simulator.datasheet import LOG_RATE_HZ

PHYSICS = {"model": {"kind": "physics", "kinematic_feature": False}}
# dynamics_warm.toml's model before it moved to the physics kind (it ships the physics kind now)
BLACK_BOX = {"model": {"kind": "ensemble", "ensemble_size": 5, "kinematic_feature": True}}


def errors(model, logs, truth) -> tuple[np.ndarray, np.ndarray]:
    """Per test maneuver: the 30-s position error of the mean path and the fan's share of true positions."""
    rollout = free_runs(model, logs, rate_hz=LOG_RATE_HZ)
    mean_x, mean_y = rollout.mean_path()
    band_x, band_y = (np.quantile(getattr(rollout, a), (0.025, 0.975), axis=0) for a in ("x", "y"))
    err, cover = [], []
    for i, table in enumerate(truth):
        n = int(rollout.lengths[i])
        columns = {c: table[c].to_numpy() for c in ("speed", "angZ", "posX", "posY", "yaw")}
        tx, ty, _ = relative_pose(columns, n)
        k = min(900, n - 1)
        err.append(float(np.nan_to_num(np.hypot(mean_x[i, k] - tx[k], mean_y[i, k] - ty[k]), nan=np.inf)))
        inside = (band_x[0, i, :n] <= tx) & (tx <= band_x[1, i, :n])
        inside &= (band_y[0, i, :n] <= ty) & (ty <= band_y[1, i, :n])
        cover.append(float(inside.mean()))
    return np.array(err), np.array(cover)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--figure", type=Path, default=None, metavar="PNG")
    parser.add_argument("--params", default=None, metavar="TOML",
                        help="[model]/[training] tables over the physics model's settings")  # fmt: skip
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        warm = "experiments/configs/dynamics_warm.toml"
        configs = {
            "black box": load_config(warm, overrides=BLACK_BOX),
            "physics": load_config(warm, params=args.params, overrides=PHYSICS),
        }
        test_cfg = load_config("experiments/configs/dynamics.toml")
        tester = Campaign(test_cfg, Path(tmp) / "test", cache_dir=Path("runs/cache"))
        test, maneuvers = tester.test_set, tester.oracle.test_maneuvers()
        reverse = np.array([m.throttle < 0 for m in maneuvers])
        fishhook = np.array([m.kind == "fishhook" for m in maneuvers])
        rows, drawn = [], {}
        cases = [
            (f"{m.kind} {m.direction}, throttle {m.throttle:g}, steering {m.steering:g}", i)
            for i, m in enumerate(maneuvers)
            if (m.kind == "skidpad" and m.throttle < 0 and m.steering > 0.3)
            or (m.kind == "fishhook" and m.throttle > 0.8)
        ]
        cases = [next(c for c in cases if "skidpad" in c[0]), next(c for c in cases if "fishhook" in c[0])]
        for name, cfg in configs.items():
            campaign = Campaign(cfg, Path(tmp) / name.replace(" ", "_"), cache_dir=Path("runs/cache"))
            campaign.prior = load_prior(cfg, campaign.nominal)  # the forward reference grid, simulated once
            empty = campaign.fitting.with_prior(pd.DataFrame()).iloc[:0]
            data = campaign.fitting.data(empty)  # the grid's rows, windows and (physics kind) logs
            for seed in range(args.seeds):
                model = build_model(cfg.model)
                fit(model, data, cfg.training, seed=seed)
                err, cover = errors(model, test.logs, test.truth_logs)
                if seed == 0:
                    drawn[name] = free_runs(model, [test.logs[i] for _, i in cases], rate_hz=LOG_RATE_HZ)
                rows.append({"model": name, "seed": seed, "all": err.mean(), "reverse": err[reverse].mean(),
                             "fishhook": err[fishhook].mean(), "fan_all": cover.mean()})  # fmt: skip
                print(rows[-1], flush=True)
        table = pd.DataFrame(rows).drop(columns="seed").groupby("model")
        print("\n30-s position error (m), mean ± s.e.m. over training seeds; fan: share of true positions in")
        cells = table.mean().round(4).astype(str) + " ± " + table.sem().round(4).astype(str)
        print(cells.to_string())
        if args.figure is not None:
            from activelearn.plots import paths_figure

            title = "trained on the forward reference grid only (straights, skidpads): free runs, 30 s"
            figure = paths_figure(
                {f"{name} (seed 0)": rollout for name, rollout in drawn.items()},
                [(label, k) for k, (label, _) in enumerate(cases)],
                [test.truth_logs[i] for _, i in cases],
                title=title,
            )
            figure.savefig(args.figure, dpi=100)
            print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()
