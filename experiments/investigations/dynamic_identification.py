"""Can the dynamic single track's parameters be identified from a few signals, and does it then beat
the file's models? A pilot for issue 56 (the core is not yet inside a model: no correction, no fans).

For each fast car and seed: `--signals` maneuvers drawn at random from its dynamics config's pool,
answered by the nominal truth or by its twin (`bench_vehicle_baselines.TWIN`: grip × 0.8, motor × 0.9),
with sensor noise; the dynamic core's five scales (`dynamic_scales.DYNAMIC_PARAMETERS`: friction, front
and rear stiffness, drive, yaw inertia) identified from those logs by free runs
(`identify_dynamic`); then the 30-s error of the CG's path on the config's test set of that truth,
for the file's kinematic and dynamic single track and the identified dynamic one. The criterion of
issue 56 for the twin: the identified friction and motor within 10 % of the change (0.8, 0.9).

Usage: python experiments/investigations/dynamic_identification.py [--cars f1tenth,bmw320i] [--seeds 3]
       [--signals 16] [--out runs/dynamic_identification] [--horizon S] [--wheel-forces] [--loss cauchy]
`--wheel-forces`: the core with the forces of four wheels (`[model] wheel_forces`), identified and run;
`--loss`: the identification's (`[model] identification_loss`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_vehicle_baselines import config_of, test_errors, twin_of

from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import control_rate_logs
from activelearn.numerics.models.dynamic_fit import identify_dynamic
from activelearn.numerics.models.dynamic_scales import DYNAMIC_PARAMETERS, scaled
from activelearn.numerics.models.dynamic_track import DynamicCar


def campaign_of(car: str, twin: bool, out: Path) -> Campaign:
    cfg = config_of(car, "physics", out, quick=False)
    cfg = twin_of(cfg) if twin else cfg
    return Campaign(cfg, out / car / ("twin" if twin else "nominal"))


def mean_test_errors(campaign: Campaign, models: dict[str, object]) -> dict[str, float]:
    """Mean 30-s error of the CG's path over the test set, per model (a DynamicCar or 'kinematic')."""
    errors = test_errors(campaign.evaluation.test_set, campaign.cfg, models)
    return {name: float(error.mean()) for name, error in errors.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cars", default="f1tenth,bmw320i")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--signals", type=int, default=16)
    parser.add_argument("--out", default="runs/dynamic_identification")
    parser.add_argument("--horizon", type=float, default=None, help="restart the free runs every S s")
    parser.add_argument("--wheel-forces", action="store_true", help="the core with four wheels' forces")
    parser.add_argument("--loss", choices=("squares", "cauchy"), default="squares", help="identification's")
    args = parser.parse_args()
    out = Path(args.out).resolve()
    rows = []
    for car in [c for c in args.cars.split(",") if c]:
        for twin in (False, True):
            campaign = campaign_of(car, twin, out)
            file_car = DynamicCar.of(campaign.cfg.vehicle.spec)
            file_car = dataclasses.replace(file_car, wheel_forces=args.wheel_forces)
            candidates = campaign.oracle.candidates()
            for seed in range(args.seeds):
                rng = np.random.default_rng(seed)
                chosen = sorted(rng.choice(len(candidates), args.signals, replace=False))
                frames = campaign.oracle.answer([candidates[i] for i in chosen], seed)
                started = time.perf_counter()
                dt = 1.0 / campaign.cfg.simulation.rate_hz
                logs = control_rate_logs(frames)
                found = identify_dynamic(logs, file_car, dt, horizon=args.horizon, loss=args.loss)
                seconds = time.perf_counter() - started
                identified = scaled(file_car, found.values)
                identified = type(file_car)(**{k: (np.asarray(v).item() if np.ndim(v) == 2 else v)
                                               for k, v in vars(identified).items()})  # fmt: skip
                errors = mean_test_errors(campaign, {"kinematic file": "kinematic", "dynamic file": file_car,
                                                "dynamic identified": identified})  # fmt: skip
                row = {"car": car, "truth": "twin" if twin else "nominal", "seed": seed, **errors,
                       **{p.name: v for p, v in zip(DYNAMIC_PARAMETERS, found.values, strict=True)},
                       "identify s": round(seconds)}  # fmt: skip
                rows.append(row)
                cells = (f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items())
                print(" ".join(cells), flush=True)
    frame = pd.DataFrame(rows)
    pd.set_option("display.width", 200)
    print(f"\n## {args.signals} random signals per seed: 30-s error of the CG's path on the test set (m) and"
          " the identified scales (twin: friction 0.8, motor 0.9)")
    print(frame.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    print("\n## means over seeds")
    means = frame.drop(columns=["seed"]).groupby(["car", "truth"]).mean()
    print(means.to_string(float_format=lambda x: f"{x:.3f}"))


if __name__ == "__main__":
    main()
