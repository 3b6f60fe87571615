"""How predictable is a 30-s free run at the limit? The truth against itself with one figure moved a little.

Issue 57 ranks strategies by the 30-s position error of free runs, by band of lateral acceleration. Near the
grip a car's path depends steeply on its figures: a slide that starts a little earlier turns the car
elsewhere. This script asks how far two near-identical cars end apart on the same test maneuvers: each
car's test set (its cold-start config's `[test]`, `experiments/configs/dynamics_<car>.toml`) driven by its
truth, nominal or the twin (`bench_vehicle_baselines.TWIN`), and again with one figure moved by a small
step (`PERTURBATIONS`: friction and motor gain by 1 %, yaw inertia by 5 %, a twin's own values scaled
again). Per band (`bench_vehicle_baselines.BANDS`, by the unperturbed truth's 90th percentile of |v r| over
μ g) and horizon, the mean distance between the two truths' paths, each relative to its start pose, and
beside it the dynamic single track's error with the file's values (the shipped core's figures, no data).
A model that is 1 % off in its grip cannot be expected to end nearer than the first number.

With `--runs DIR` (a comparison's directory of that car and truth) the last models of each strategy
there are added (`bench_vehicle_baselines.trained_by_band`, 30 s only).

Usage: python experiments/investigations/limit_sensitivity.py [--cars bmw320i,f1tenth] [--twin]
       [--horizons 5,10,30] [--runs DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_vehicle_baselines import BANDS, TWIN, bands_of, config_of, log_controls, trained_by_band, twin_of

from activelearn.config import CampaignConfig
from activelearn.loop.campaign import Campaign
from activelearn.numerics.models.dynamic_track import DynamicCar, free_runs
from activelearn.replay import relative_pose

PERTURBATIONS = {"friction +1 %": ("tire_friction", 1.01), "friction -1 %": ("tire_friction", 0.99),
                 "motor +1 %": ("motor_gain", 1.01), "yaw inertia +5 %": ("yaw_inertia", 1.05)}  # fmt: skip
POSE = ("posX", "posY", "yaw")


def perturbed(cfg: CampaignConfig, name: str, factor: float) -> CampaignConfig:
    """The config answered by its truth (nominal or twin) with one twin figure scaled by `factor`."""
    data = cfg.model_dump(mode="json")
    overrides = dict(data["oracle"].get("overrides") or {}) if data["oracle"]["kind"] == "twin" else {}
    overrides[name] = overrides.get(name, 1.0) * factor
    data["oracle"] = {**data["oracle"], "kind": "twin", "overrides": overrides}
    return CampaignConfig.model_validate(data)


def truth_paths(test, steps: list[int]) -> np.ndarray:
    """(M, H, 2) each test maneuver's true position at each step in `steps`, relative to its start pose."""
    out = np.empty((len(test.truth_logs), len(steps), 2))
    for i, truth in enumerate(test.truth_logs):
        n = len(truth)
        x, y, _ = relative_pose({c: truth[c].to_numpy(np.float64) for c in POSE}, n)
        idx = [min(k, n - 1) for k in steps]
        out[i, :, 0], out[i, :, 1] = x[idx], y[idx]
    return out


def file_core_paths(test, cfg: CampaignConfig, steps: list[int]) -> np.ndarray:
    """(M, H, 2) the dynamic single track's free runs at the file's values (the config's slip law) from
    each test log's first recorded state, as `bench_vehicle_baselines.test_errors` runs them."""
    rate = cfg.simulation.rate_hz
    controls, start = log_controls(test)
    n = controls.shape[1]
    car = dataclasses.replace(DynamicCar.of(cfg.vehicle.spec), wheel_forces=cfg.model.wheel_forces)
    path = free_runs(car, controls, start, 1.0 / rate)[..., 4:6]
    return path[:, [min(k, n - 1) for k in steps]]


def car_test_set(
    car: str, twin: bool, work: Path, test: dict[str, Any] | None = None
) -> tuple[CampaignConfig, Any]:
    """The car's cold-start dynamics config on the dynamic core (answered by its twin with `twin`) and
    its test set, simulated under `work` (`test`: `[test]` keys changed, e.g. other operating points)."""
    cfg = config_of(car, "dynamic physics", work, quick=False)
    if test:
        data = cfg.model_dump(mode="json")
        data["test"] = {**data["test"], **test}
        cfg = CampaignConfig.model_validate(data)
    cfg = twin_of(cfg) if twin else cfg
    return cfg, Campaign(cfg, work / "truth").evaluation.test_set


def study(car: str, twin: bool, horizons: list[float], runs: Path | None, work: Path) -> pd.DataFrame:
    cfg, test = car_test_set(car, twin, work)
    steps = [round(h * cfg.simulation.rate_hz) for h in horizons]
    bands = bands_of(test, cfg, twin)
    truth = truth_paths(test, steps)
    rows = []

    def add(source: str, paths: np.ndarray) -> None:
        distance = np.nan_to_num(np.hypot(*(paths - truth).transpose(2, 0, 1)), nan=np.inf)  # (M, H)
        for i, band in enumerate(bands):
            for j, horizon in enumerate(horizons):
                rows.append({"source": source, "band": band, "horizon": horizon, "error": distance[i, j]})

    for label, (name, factor) in PERTURBATIONS.items():
        other = Campaign(perturbed(cfg, name, factor), work / label.replace(" ", "_")).evaluation.test_set
        add(f"truth, {label}", truth_paths(other, steps))
    add("dynamic core, file values", file_core_paths(test, cfg, steps))
    frame = pd.DataFrame(rows)
    if runs is not None and 30.0 in horizons:
        for strategy in sorted(p.name for p in runs.iterdir() if list(p.glob("seed*/model.pt"))):
            last = trained_by_band(cfg, runs, f"last models, {strategy}", twin, strategy=strategy)
            frame = pd.concat([frame, last.assign(horizon=30.0)[["variant", "band", "horizon", "error"]]
                               .rename(columns={"variant": "source"})], ignore_index=True)  # fmt: skip
    return frame


def table(frame: pd.DataFrame) -> pd.DataFrame:
    """Mean distance per source, horizon and band (and the band's maneuver count)."""
    order = [b for b, _, _ in BANDS if b in set(frame["band"])]
    cells = frame.groupby(["horizon", "source", "band"])["error"].mean().unstack("band")[order]
    cells["all"] = frame.groupby(["horizon", "source"])["error"].mean()
    return cells


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cars", default="bmw320i,f1tenth")
    parser.add_argument("--twin", action="store_true", help=f"the twin's truth ({TWIN})")
    parser.add_argument("--horizons", default="5,10,30", help="seconds, comma-separated")
    parser.add_argument("--runs", type=Path, default=None, help="a comparison (one car and truth)")
    args = parser.parse_args()
    horizons = [float(h) for h in args.horizons.split(",")]
    pd.set_option("display.width", 200)
    with tempfile.TemporaryDirectory() as tmp:
        for car in args.cars.split(","):
            frame = study(car, args.twin, horizons, args.runs, Path(tmp) / car)
            first = frame[frame["source"] == frame["source"].iloc[0]]
            counts = {b: int(n) // len(horizons) for b, n in first.groupby("band").size().items()}
            truth = "twin " + str(TWIN) if args.twin else "nominal"
            print(f"=== {car}, {truth} truth: distance after each horizon, m (test maneuvers per band: "
                  f"{dict(counts)}) ===")  # fmt: skip
            print(table(frame).to_string(float_format="%.2f"))
            print()


if __name__ == "__main__":
    main()
