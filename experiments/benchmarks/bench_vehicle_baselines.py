"""Baselines on the cars that leave the kinematic regime: what a better physics core must beat.

For each car's cold-start dynamics config (`experiments/configs/dynamics_<car>.toml`: the shipped
`dynamics.toml` model, training and budget, the car's own operating box and test set), uniform
campaigns over `--seeds` seeds with
  * physics     the physics kind on the kinematic core: the car's kinematic single track, identified
                under its vehicle file's prior, plus the bounded Bayesian correction;
  * dynamic physics  issue 56's dynamic single track as the physics kind's core (`core = "dynamic"`,
                its identified scales' covariance in the fans: `parameter_uncertainty = "by_log"`);
  * black box   the best black box (history ensemble of 5 + kinematic feature + 30-step windows,
                `bench_physics.py`'s), the same budget;
and, with no data at all,
  * datasheet   the kinematic single track with the vehicle file's values (no identification, no
                correction) on the same test set, through the model's own free runs.
Then, with no data, by band of the test maneuvers' lateral acceleration (their truth's 90th percentile
of |v r| over μ g: below 0.3, 0.3-0.6, above 0.6), on the car's nominal truth and on a twin (less grip,
a weaker motor: `TWIN`), each file model's free runs from each test log's first recorded state (the
CG's path; lateral speed 0, the logs do not hold it):
  * kinematic file   the kinematic single track (the physics kind's core at the file's values);
  * dynamic file     the dynamic single track (`activelearn.numerics.models.dynamic_track`): tyre slip,
                     saturating tyres, load transfer, blended into the kinematic model at low speed;
  * dynamic file, wheels  the same with the forces of four wheels (`wheel_forces`: each wheel's load
                     with the lateral transfer, its own friction circle).
A model built from the same figures as the truth is flattered on the nominal truth; the twin says how
it does when the figures are off.
Prints per car and variant the 30-s position error of the free runs' mean path after the last round
and the 95 % fan's share of the true positions (`rollout_coverage_95`), mean ± s.e.m. over seeds, then
the per-seed finals. Issue 56's dynamic core is measured against these numbers.

Usage: python experiments/benchmarks/bench_vehicle_baselines.py [--cars f1tenth,bmw320i] [--seeds 10]
       [--first-seed 0] [--workers 2] [--out DIR] [--variants physics,...] [--twin] [--quick]
`--twin`: the campaigns answered by the car's twin (`TWIN`), with the identified friction and motor
scales of the kinds that identify them (`identified_*` round metrics).
`--quick` (what the test runs): one seed at quick.py's sizes, every variant, the first car of `--cars`
only (the cars share every code path; their files are checked by tests/test_vehicles.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from quick import shrink

from activelearn.config import CampaignConfig, load_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.evaluation import FAN_SAMPLES
from activelearn.names import IDENTIFIED_PREFIX, ROLLOUT_COVERAGE_95, ROLLOUT_POS_ERR_30S
from activelearn.numerics.diagnostics import free_runs as model_free_runs
from activelearn.numerics.models import build_model, load_model
from activelearn.numerics.models.dynamic_track import DynamicCar, free_runs
from activelearn.numerics.models.single_track import car_prior, run_single_track
from activelearn.replay import relative_pose
from activelearn.studies.compare import compare
from simulator.vehicles import GRAVITY

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CARS = ("f1tenth", "bmw320i")
# each variant's model knobs over the car's config (whatever core the config ships; the kinematic core
# has no discrepancy term)
KINEMATIC_CORE = {"core": "kinematic", "discrepancy": "none", "wheel_forces": False, "combined_slip": False,
                  "identification_loss": "squares"}  # fmt: skip
BLACK_BOX = {"kind": "ensemble", "ensemble_size": 5, "kinematic_feature": True, **KINEMATIC_CORE}
KINEMATIC = {**KINEMATIC_CORE, "parameter_uncertainty": "none"}
DYNAMIC = {"core": "dynamic", "parameter_uncertainty": "by_log"}  # issue 56's core under the correction
UPDATES = {"datasheet": KINEMATIC, "physics": KINEMATIC, "dynamic physics": DYNAMIC, "black box": BLACK_BOX}
VARIANTS = ("datasheet", "physics", "dynamic physics", "black box")
TWIN = {"tire_friction": 0.8, "motor_gain": 0.9}  # the fast cars' twin: less grip, a weaker motor
BANDS = (("below 0.3 μg", 0.0, 0.3), ("0.3-0.6 μg", 0.3, 0.6), ("above 0.6 μg", 0.6, np.inf))


def config_of(car: str, variant: str, out: Path, quick: bool) -> CampaignConfig:
    """The car's dynamics config for a variant, its outputs (and simulation cache) under `out`."""
    cfg = load_config(CONFIGS / f"dynamics_{car}.toml")
    model = cfg.model.model_dump(mode="json")
    cfg = cfg.model_copy(update={"model": type(cfg.model).model_validate({**model, **UPDATES[variant]})})
    if quick:
        return shrink(cfg, out)  # its training too: short windows, eager steps (a cold compile is slower)
    data = cfg.model_dump(mode="json")
    data["output_dir"] = str(out)
    return CampaignConfig.model_validate(data)


def campaigns(
    cfg: CampaignConfig, seeds: list[int], workers: int, directory: Path, resume: bool = False
) -> pd.DataFrame:
    """Uniform over the seeds: each seed's last round's 30-s error and fan coverage (`resume`: the
    campaigns already in `directory` are read, not run again)."""
    result = compare(cfg, ["uniform"], seeds, directory=directory, workers=workers, tracking=False,
                     resume=resume)  # fmt: skip
    last = result.curves.sort_values("round").groupby("seed").last()
    identified = [IDENTIFIED_PREFIX + name for name in ("friction", "motor")]
    identified = [c for c in identified if c in last.columns]
    return last[[ROLLOUT_POS_ERR_30S, ROLLOUT_COVERAGE_95, *identified]].reset_index()


def datasheet(cfg: CampaignConfig, directory: Path) -> pd.DataFrame:
    """The kinematic single track with the vehicle file's values, no data, on the config's test set."""
    campaign = Campaign(cfg, directory)
    test = campaign.evaluation.test_set
    model = build_model(cfg.model, seed=0)
    model.set_scalers(test.x, test.y_clean)  # the physics reads physical inputs; any scale serves
    model.corrected = False
    metrics = campaign.evaluation.evaluate(model)
    # its fans are the untrained correction's noise: no statement about the car, so not reported
    return pd.DataFrame([{"seed": 0, ROLLOUT_POS_ERR_30S: metrics[ROLLOUT_POS_ERR_30S],
                          ROLLOUT_COVERAGE_95: float("nan")}])  # fmt: skip


def twin_of(cfg: CampaignConfig) -> CampaignConfig:
    """The config answered by the car's twin (`TWIN`) instead of its nominal truth."""
    data = cfg.model_dump(mode="json")
    data["oracle"] = {**data["oracle"], "kind": "twin", "overrides": TWIN}
    return CampaignConfig.model_validate(data)


def by_band(cfg: CampaignConfig, directory: Path, twin: bool) -> pd.DataFrame:
    """The file models' 30-s errors per test maneuver, with its band, on the nominal truth or the twin."""
    cfg = twin_of(cfg) if twin else cfg
    test = Campaign(cfg, directory).evaluation.test_set
    spec = cfg.vehicle.spec
    car = DynamicCar.of(spec)
    errors = test_errors(test, cfg, {"kinematic file": "kinematic", "dynamic file": car,
                                     "dynamic file, wheels": dataclasses.replace(car, wheel_forces=True)})
    bands = bands_of(test, cfg, twin)
    return pd.DataFrame([{"variant": name, "band": band, "error": error[i]}
                         for name, error in errors.items() for i, band in enumerate(bands)])  # fmt: skip


def bands_of(test: Any, cfg: CampaignConfig, twin: bool) -> list[str]:
    """Each test maneuver's band: its truth's 90th percentile of |v r| over the car's μ g."""
    grip = cfg.vehicle.spec.tyres.friction.value * (TWIN["tire_friction"] if twin else 1.0) * GRAVITY
    out = []
    for truth in test.truth_logs:
        level = float(np.percentile(np.abs(truth["speed"].to_numpy() * truth["angZ"].to_numpy()), 90)) / grip
        out.append(next(name for name, low, high in BANDS if low <= level < high))
    return out


def trained_by_band(
    cfg: CampaignConfig,
    directory: Path,
    variant: str,
    twin: bool,
    strategy: str = "uniform",
    correction_weight: float | None = None,
) -> pd.DataFrame:
    """The last round's model of every seed of `strategy` under `directory`: its 30-s error on each test
    maneuver (the mean path of the config's `[test] rollout_samples` draws, as the campaign measures it),
    with the maneuver's band.
    `correction_weight`: the share of its correction's mean each model keeps instead of its gate's."""
    test = Campaign(cfg, directory / "probe").evaluation.test_set
    bands = bands_of(test, cfg, twin)
    rows = []
    for seed, path in sorted((int(p.parent.name.removeprefix("seed")), p)
                             for p in directory.glob(f"{strategy}/seed*/model.pt")):  # fmt: skip
        model = load_model(path)
        if correction_weight is not None:
            model.set_correction_weight(correction_weight)
        for i, error in enumerate(mean_path_errors(model, cfg, test)):
            rows.append({"variant": variant, "seed": seed, "maneuver": i, "band": bands[i], "error": error})
    return pd.DataFrame(rows)


def mean_path_errors(model: Any, cfg: CampaignConfig, test: Any) -> np.ndarray:
    """A trained model's 30-s error on each test maneuver (inf where a run blows up): the mean path of the
    config's `[test] rollout_samples` draws against the truth's, as the campaign measures it."""
    rollout = model_free_runs(model, list(test.logs), rate_hz=cfg.simulation.rate_hz,
                              n_samples=cfg.test.rollout_samples or FAN_SAMPLES)  # fmt: skip
    mean_x, mean_y = rollout.mean_path()
    errors = []
    for i, truth in enumerate(test.truth_logs):
        n = int(rollout.lengths[i])
        k = min(round(30.0 / rollout.dt), n - 1)
        tx, ty, _ = relative_pose({c: truth[c].to_numpy(np.float64) for c in ("posX", "posY", "yaw")}, n)
        errors.append(float(np.hypot(mean_x[i, k] - tx[k], mean_y[i, k] - ty[k])))
    return np.nan_to_num(np.array(errors), nan=np.inf)


def test_errors(test: Any, cfg: CampaignConfig, models: dict[str, Any]) -> dict[str, np.ndarray]:
    """Per model (a `DynamicCar`, or "kinematic": the file's kinematic single track), the 30-s error of
    the CG's path on every test maneuver (inf where a run blows up): free runs of each log's commands
    (held past its end) from its first recorded state (lateral speed 0: the logs do not hold it),
    against the truth's path relative to its start pose."""
    spec, rate = cfg.vehicle.spec, cfg.simulation.rate_hz
    controls, start = log_controls(test)
    dt, n = 1.0 / rate, controls.shape[1]
    k = min(round(30.0 * rate), n - 1)
    columns = ("posX", "posY", "yaw")
    truth = np.array([relative_pose({c: t[c].to_numpy(np.float64) for c in columns}, k + 1)[:2]
                      for t in test.truth_logs])[:, :, k]  # fmt: skip
    out = {}
    for name, model in models.items():
        if model == "kinematic":
            prior = car_prior(spec)
            rates = run_single_track(controls, start[:, [0, 2]], prior.nominal, dt, prior)[0]  # (M, T, 2)
            path = _kinematic_paths(rates, spec.geometry.lr.value, dt)[:, k]
        else:
            path = free_runs(model, controls, start, dt)[:, k, 4:6]
        error = np.hypot(path[:, 0] - truth[:, 0], path[:, 1] - truth[:, 1])
        out[name] = np.nan_to_num(error, nan=np.inf)
    return out


def log_controls(test: Any) -> tuple[np.ndarray, np.ndarray]:
    """The test logs' commands (M, T, 2), each held past its end to the longest, and the free runs' start
    states (M, 4) = (v_x, v_y, r, δ_w) from each log's first recorded row (v_y 0: the logs do not hold it)."""
    n = max(len(log) for log in test.logs)
    controls, start = np.zeros((len(test.logs), n, 2)), np.zeros((len(test.logs), 4))
    for i, log in enumerate(test.logs):
        u = log[["throttle", "steering"]].to_numpy(np.float64)
        controls[i, : len(u)], controls[i, len(u) :] = u, u[-1]
        start[i] = [log["speed"].iloc[0], 0.0, log["angZ"].iloc[0], log["steering"].iloc[0]]
    return controls, start


test_errors.__test__ = False  # type: ignore[attr-defined]  # not a pytest test


def _kinematic_paths(rates: np.ndarray, lr: float, dt: float) -> np.ndarray:
    """(M, T, 2) the CG's path of kinematic free runs (M, T, 2 rates v, r): lateral speed l_r r."""
    yaw_rate = np.concatenate([np.zeros_like(rates[:, :1, 1]), rates[:, :-1, 1]], axis=1)
    heading = np.cumsum(yaw_rate, axis=1) * dt
    vx, vy = rates[..., 0], lr * rates[..., 1]
    cos, sin = np.cos(heading), np.sin(heading)
    step = np.stack([vx * cos - vy * sin, vx * sin + vy * cos], axis=-1)
    path = np.cumsum(dt * step[:, :-1], axis=1)  # the position at step k: the velocities before it
    return np.concatenate([np.zeros_like(path[:, :1]), path], axis=1)


def band_table(frame: pd.DataFrame) -> pd.DataFrame:
    """Mean 30-s error (and test maneuvers) per variant and band, and over all."""
    cells = frame.groupby(["variant", "band"])["error"].agg(lambda e: f"{e.mean():.2f} ({len(e)})").unstack()
    cells["all"] = frame.groupby("variant")["error"].agg(lambda e: f"{e.mean():.2f} ({len(e)})")
    return cells[[b for b, _, _ in BANDS if b in cells.columns] + ["all"]]


def _sem(values: np.ndarray) -> float:
    return float(values.std(ddof=1) / np.sqrt(len(values))) if len(values) > 1 else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cars", default=",".join(CARS))
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="runs/vehicle_baselines", help="campaigns and the simulation cache")
    parser.add_argument("--resume", action="store_true", help="read the campaigns already under --out")
    parser.add_argument("--variants", default=",".join(VARIANTS), help="a subset of " + ", ".join(VARIANTS))
    parser.add_argument("--no-data-only", action="store_true", help="only the file models' rows by band")
    parser.add_argument("--twin", action="store_true", help=f"campaigns answered by the car's twin {TWIN}")
    parser.add_argument("--quick", action="store_true", help="one seed, the first car, quick sizes")
    args = parser.parse_args()
    cars = [c for c in args.cars.split(",") if c]
    if not cars or set(cars) - set(CARS):
        parser.error(f"--cars: a subset of {', '.join(CARS)}")
    variants = [v for v in args.variants.split(",") if v]
    if not variants or set(variants) - set(VARIANTS):
        parser.error(f"--variants: a subset of {', '.join(VARIANTS)}")
    if args.quick:
        args.seeds, cars = 1, cars[:1]
    if args.seeds < 1 or args.workers < 1:
        parser.error("--seeds and --workers: at least 1")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    out = Path(args.out).resolve()
    rows, finals, trained = [], [], []
    for car in cars if not args.no_data_only else ():
        for variant in variants:
            start = time.perf_counter()
            cfg = config_of(car, "physics" if variant == "datasheet" else variant, out, args.quick)
            cfg = twin_of(cfg) if args.twin else cfg
            where = out / car / ("twin" if args.twin else "") / variant.replace(" ", "_")
            if variant == "datasheet":
                frame = datasheet(cfg, where)
            else:
                frame = campaigns(cfg, seeds, args.workers, where, args.resume)
            errors, cover = frame[ROLLOUT_POS_ERR_30S].to_numpy(), frame[ROLLOUT_COVERAGE_95].to_numpy()
            fan = "–" if np.isnan(cover).all() else f"{cover.mean():.3f} ± {_sem(cover):.3f}"
            rows.append({"car": car, "variant": variant, "seeds": len(frame),
                         "30-s error m": f"{errors.mean():.3f} ± {_sem(errors):.3f}",
                         "median m": f"{np.median(errors):.3f}", "fan 95 %": fan,
                         "wall s": round(time.perf_counter() - start)})  # fmt: skip
            finals += [{"car": car, "variant": variant, **row} for row in frame.to_dict("records")]
            if variant != "datasheet":
                trained.append(trained_by_band(cfg, where, f"{car} {variant}", args.twin))
            for name in ("friction", "motor"):
                if IDENTIFIED_PREFIX + name in frame:
                    found = frame[IDENTIFIED_PREFIX + name].to_numpy()
                    spread = f"{found.min():.3f}-{found.max():.3f}"
                    rows[-1][f"identified {name}"] = f"{found.mean():.3f} ({spread})"
            print(f"{car} {variant}: {rows[-1]['30-s error m']} m, fan {rows[-1]['fan 95 %']}", flush=True)
    pd.set_option("display.width", 160)
    for car in cars if args.no_data_only or not args.twin else ():  # the twin's campaigns: theirs alone
        for twin in (False, True):
            cfg = config_of(car, "physics", out, args.quick)
            frame = by_band(cfg, out / car / ("twin" if twin else "nominal"), twin)
            oracle = f"twin {TWIN}" if twin else "nominal truth"
            print(f"\n## {car}, {oracle}: no data, 30-s error of the CG's path (m) by band (test maneuvers)")
            print(band_table(frame).to_string())
    if not rows:
        return
    print("\n## Baselines: uniform, the last round's free runs of the test set (mean ± s.e.m. over seeds;"
          " a free run that blows up counts with its error)")
    print(pd.DataFrame(rows).fillna("–").to_string(index=False))
    print("\n## After the last round, by band: mean 30-s error over seeds and test maneuvers"
          " (m; maneuvers x seeds)")
    print(band_table(pd.concat(trained)).to_string())
    print("\n## Finals by seed")
    print(pd.DataFrame(finals).to_string(index=False, float_format=lambda x: f"{x:.4f}"))


if __name__ == "__main__":
    main()
