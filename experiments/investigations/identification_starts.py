"""Is a campaign's last identification the optimiser's path or its objective's minimum?

The dynamic core's campaigns train warm, so each round's identification searches from the last round's
scales (`[model] identification_starts = "last"`): where the search ends can depend on which logs came
first. For every seed of a finished campaign (`OUT/<strategy>/seedK`, a dynamic-core config), this
re-identifies the last round's logs two ways: from the scales the round before ended at ("last", which
reproduces the campaign's own) and from the file's centre ("prior"). It prints each solution's scales,
its MAP objective (`_map_fit`'s loss, at the noise the "last" solution measures, plus the prior) and
the 30-s test error of the last model with each solution as its core (the mean path of the config's
draws, as the campaign measures it). Where "prior" has the lower objective and the lower error, the
campaign's identification was stuck in a basin; where both meet, it was not.
`identification_starts = "last_and_prior"` keeps the lower objective of the two searches.

Usage: python experiments/investigations/identification_starts.py --runs OUT/dynamics_bmw320i_twin
       [--strategy uniform] [--seeds 0,1,...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_vehicle_baselines import mean_path_errors

from activelearn.config import validate_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import control_rate_logs
from activelearn.loop.state import CONFIG_FILE, CampaignState
from activelearn.names import IDENTIFIED_PREFIX
from activelearn.numerics.models import load_model
from activelearn.numerics.models.dynamic_fit import _restart_errors
from activelearn.numerics.models.dynamic_physics import IDENTIFICATION, before_a_stop
from activelearn.numerics.models.dynamic_scales import DYNAMIC_PARAMETERS, dynamic_bounds
from activelearn.numerics.models.single_track import CAUCHY_SCALE, usable_logs
from activelearn.numerics.training_data import TrainingData

NAMES = [p.name for p in DYNAMIC_PARAMETERS]


def objective(errors_of, theta: np.ndarray, noise: np.ndarray, loss: str) -> float:
    """`_map_fit`'s second-pass objective at `theta`: the errors over `noise` and the prior's rows, by
    scipy's loss (`loss` "squares" or "cauchy" at `CAUCHY_SCALE`)."""
    bounds = dynamic_bounds()
    errors = errors_of(np.asarray(theta)[None])[0] / noise
    residuals = np.concatenate([errors.ravel(), (theta - bounds.prior.values) / bounds.width])
    if loss == "squares":
        return float(0.5 * np.sum(residuals**2))
    scale = CAUCHY_SCALE
    return float(0.5 * np.sum(scale**2 * np.log1p(residuals**2 / scale**2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", required=True, type=Path, help="a comparison's directory (one config)")
    parser.add_argument("--strategy", default="uniform")
    parser.add_argument("--seeds", default=None, help="default: every finished seed")
    args = parser.parse_args()
    stored = sorted((args.runs / args.strategy).glob(f"seed*/{CONFIG_FILE}"))
    if not stored:
        parser.error(f"--runs: no {args.strategy}/seed*/{CONFIG_FILE} under {args.runs}")
    cfg = validate_config(json.loads(stored[0].read_text()))
    if cfg.model.core != "dynamic":
        parser.error(f"--runs: {cfg.name} is not a dynamic-core config")
    seeds = ([int(s) for s in args.seeds.split(",")] if args.seeds else
             sorted(int(p.parent.name.removeprefix("seed")) for p in stored))  # fmt: skip
    test = Campaign(cfg, args.runs / "probe").evaluation.test_set
    rows = []
    for seed in seeds:
        directory = args.runs / args.strategy / f"seed{seed}"
        rounds = CampaignState.load(directory).rounds
        samples = pd.read_parquet(directory / "samples.parquet")
        logs = control_rate_logs([part for _, part in samples.groupby("pool_index", sort=False)])
        data = TrainingData(x=np.zeros((0, 1)), y=np.zeros((0, 2)), logs=logs)
        model = load_model(directory / "model.pt")  # each search alone, whatever the campaign's setting
        model.config = model.config.model_copy(update={"identification_starts": "last"})
        dt = 1.0 / model.car.log_rate_hz
        own = usable_logs([before_a_stop(log) for log in logs])
        errors_of, _, _ = _restart_errors(own, model.dynamic_car, dt, **IDENTIFICATION)
        before = [rounds[-2][IDENTIFIED_PREFIX + name] for name in NAMES]
        found = {}
        for start in ("last", "prior"):
            if start == "last":
                model.theta.copy_(torch.as_tensor(before, dtype=torch.float32))
            model.identify(data, warm=start == "last")
            found[start] = model.theta.double().numpy().copy()
            error = float(np.mean(mean_path_errors(model, cfg, test)))
            rows.append({"seed": seed, "start": start, **dict(zip(NAMES, found[start].round(3), strict=True)),
                         "error_30s": error, "logged_30s": rounds[-1]["rollout_pos_err_30s"]})  # fmt: skip
        noise = np.sqrt(np.mean(errors_of(found["last"][None])[0] ** 2, axis=0))
        for row in rows[-2:]:
            row["objective"] = objective(errors_of, found[row["start"]], noise, cfg.model.identification_loss)
        print(pd.DataFrame(rows[-2:]).to_string(index=False), flush=True)
    frame = pd.DataFrame(rows)
    pd.set_option("display.width", 200)
    print("\n" + frame.to_string(index=False))
    by_seed = frame.pivot(index="seed", columns="start", values="objective")
    stuck = by_seed.index[by_seed["prior"] < by_seed["last"] - 1e-3 * by_seed["last"].abs()].tolist()
    print(f"\nseeds whose search from the file finds a lower objective (by more than 0.1 %): {stuck}")


if __name__ == "__main__":
    main()
