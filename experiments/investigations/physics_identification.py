"""The physics-structured model's core on `dynamics.toml`'s test set: the datasheet, then identified.

Reads a campaign's samples (e.g. `activelearn campaign run experiments/configs/dynamics.toml --params
PHYSICS.toml --strategy uniform --seed 0 --out DIR`, where PHYSICS.toml sets `[model] kind = "physics"`
and `kinematic_feature = false`) and, for the first N signals it collected, prints the 30-s position
error of the free runs of the 72 test maneuvers (noise-free truth) with:
  * the datasheet's single track (no data at all);
  * the single track identified on those signals' logs (`identify_from_logs`), no learnt correction.
The campaign's own `rollout_pos_err_30s` per round (state.json) is the model with its correction.

Usage: python experiments/investigations/physics_identification.py DIR [--signals 4,8,16] [--config TOML]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd
import torch

from activelearn.config import load_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import control_rate_logs
from activelearn.numerics.diagnostics import free_run_metrics
from activelearn.numerics.models import build_model
from activelearn.numerics.models.single_track import identify_from_logs
from simulator.datasheet import LOG_RATE_HZ


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a physics campaign directory")
    parser.add_argument("--signals", default="4,8,16")
    parser.add_argument("--config", default="experiments/configs/dynamics.toml",
                        help="the campaign's config (its oracle drives the test set)")  # fmt: skip
    args = parser.parse_args()
    params = args.run / "physics_params.toml"
    # The window correction: its free runs step `_physical_step`, which the bare core below replaces (a
    # control-only correction's free runs are computed whole, by the compiled kernel, and would not see it).
    params.write_text('[model]\nkind = "physics"\nkinematic_feature = false\ncorrection_inputs = "history"\n')
    cfg = load_config(args.config, params=str(params))
    campaign = Campaign(cfg, args.run / "identification", cache_dir=Path("runs/cache"))
    test = campaign.test_set
    samples = pd.read_parquet(args.run / "samples.parquet")
    order = list(dict.fromkeys(samples["pool_index"]))
    model = build_model(cfg.model)
    model.set_scalers(*campaign.fitting.training_data(samples)[:2])
    # the bare single track: the correction's outputs held at zero
    step = model._physical_step
    model._physical_step = lambda x, dim, z, var, theta: step(x, dim, torch.zeros_like(z), var, theta)

    def error() -> float:
        return free_run_metrics(model, test.logs, test.truth_logs, rate_hz=LOG_RATE_HZ)["rollout_pos_err_30s"]

    print(f"datasheet (no data): {error():.4f} m")
    for n in (int(s) for s in args.signals.split(",")):
        taken = samples[samples["pool_index"].isin(order[:n])]
        logs = control_rate_logs([g for _, g in taken.groupby("pool_index", sort=False)])
        values, _ = identify_from_logs(logs)
        with torch.no_grad():
            model.theta.copy_(torch.as_tensor(values, dtype=torch.float32))
        fitted = ", ".join(f"{k} {v:.3f}" for k, v in model.physical_parameters().items())
        print(f"identified on {n} signals: {error():.4f} m  ({fitted})")


if __name__ == "__main__":
    main()
