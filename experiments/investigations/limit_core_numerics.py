"""What the dynamic core misses at the limit, with the truth's own figures: its equations or its numerics?

The full-size car's campaign models end some 24 m off above 0.6 μg after 30 s (`band_errors.py`), where
the truth with its grip 1 % off ends 4 m away (`limit_sensitivity.py`). Here the core runs with the
truth's figures (the file's; on `--twin` the twin's grip and motor), so no identification is involved,
on the car's test set, by band and horizon (mean distance to the truth's path, m):

  * planar replica   the truth's tyre step (`simulator/tyre_car.py`: four wheels, each its slip angle
                     from its own velocity and its Ackermann angle, its load from the last step's
                     accelerations) on a planar rigid body, explicit, 10 substeps a log step: how far
                     the truth's MuJoCo chassis (roll, pitch, soft contacts) is from a planar model;
  * the core at the log's rate (1/30 s, explicit substeps at its slip floor), as shipped, then with the
    wheels' loads converged (`wheel_passes` 8, shipped 3: the passes start from the demand within the
    grip and v_x r, far from a spin's), with the kinematic blend at 0.1 √(g L) (shipped 0.5: 2.5 m/s on
    the full-size car, where a spinning car is pulled onto its wheels' heading), and both;
  * the core at the physics kind's step (0.1 s, the controls as it samples them): as shipped (4
    substeps of the implicit step, whose tyre damping uses the linear cornering stiffness), with both
    fixes, with 16 substeps, with the damping from the tyres' local slope (`[model] tyre_damping =
    "tangent"`: zero past the peak), and with the explicit step (converged).

Each row's passes and blend are the core's own figures (`DynamicCar.wheel_passes`, `blend_share`: the
`[model]` keys of those names); NumPy runs any number of passes, the C kernel 3 or 5.

`--sweep`: instead, at the physics kind's step, the tangent damping under each combination of the wheels'
passes (3, 5, 8), the blend (0.5, 0.25, 0.1 √(g L)) and 4 or 8 substeps (30-s error by band).
`--held-out`: the test set's kinds at other operating points (`HELD_OUT`, the full-size car's), to check
on maneuvers the sweep did not choose on.

Usage: python experiments/investigations/limit_core_numerics.py [--car bmw320i] [--twin] [--sweep]
       [--held-out]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_vehicle_baselines import BANDS, TWIN, bands_of, log_controls
from limit_sensitivity import car_test_set, truth_paths

from activelearn.numerics.models.dynamic_track import DynamicCar, dynamic_step
from simulator.tyre_car import TyreCar
from simulator.vehicles import GRAVITY

HORIZONS = (5.0, 10.0, 30.0)
MODEL_STRIDE = 3  # the physics kind's step in log steps (history_step: 0.1 s at 30 Hz)
FIXED = {"wheel_passes": 8, "blend_share": 0.1}
# `--held-out`: the full-size test set's kinds and directions at throttles and steerings between and beyond
# its own (-0.3, 0.2, 0.4, 0.6 x 0.01, 0.03, 0.08 rad)
HELD_OUT = {"bmw320i": {"throttles": [-0.2, 0.3, 0.5, 0.7], "steerings": [0.02, 0.05, 0.1]}}


def core_paths(car: DynamicCar, controls: np.ndarray, start: np.ndarray, h: float, substeps: int | None,
               implicit: bool) -> np.ndarray:  # fmt: skip
    """(M, T, 2) the CG's path of the core's free runs (steps of h s), `free_runs`' trapezoid."""
    n_runs, n_steps = controls.shape[:2]
    out = np.zeros((n_runs, n_steps, 2))
    state, x, y, heading = start.copy(), np.zeros(n_runs), np.zeros(n_runs), np.zeros(n_runs)
    for k in range(1, n_steps):
        nxt = dynamic_step(car, state, controls[:, k - 1, 0], controls[:, k - 1, 1], h, substeps, implicit)
        mid = heading + 0.25 * h * (state[:, 2] + nxt[:, 2])
        vx, vy = 0.5 * (state[:, 0] + nxt[:, 0]), 0.5 * (state[:, 1] + nxt[:, 1])
        x = x + h * (vx * np.cos(mid) - vy * np.sin(mid))
        y = y + h * (vx * np.sin(mid) + vy * np.cos(mid))
        heading, state = heading + 0.5 * h * (state[:, 2] + nxt[:, 2]), nxt
        out[:, k, 0], out[:, k, 1] = x, y
    return out


def replica_paths(truth: TyreCar, controls: np.ndarray, rate: float, substeps: int = 10) -> np.ndarray:
    """(M, T, 2) the truth's tyre step (`TyreCar.tyre_forces`' equations) on a planar rigid body."""
    n_runs, n_steps = controls.shape[:2]
    m, inertia, height, h = truth.mass, truth.yaw_inertia, truth.cg_height, 1.0 / rate / substeps
    lf, lr, half = truth.spec.geometry.lf.value, truth.spec.geometry.lr.value, 0.5 * truth.track
    length = lf + lr
    px, py = np.array([lf, lf, -lr, -lr]), np.array([half, -half, half, -half])
    vx, vy, r, delta, x, y, psi, ax, ay = (np.zeros(n_runs) for _ in range(9))
    out = np.zeros((n_runs, n_steps, 2))
    for k in range(n_steps):
        out[:, k, 0], out[:, k, 1] = x, y
        throttle, command = controls[:, k, 0], controls[:, k, 1]
        for _ in range(substeps):
            axle_f = m * (GRAVITY * lr - ax * height) / length
            axle_r = m * (GRAVITY * lf + ax * height) / length
            shift = m * ay * height / (4 * half)
            load = np.maximum(np.stack([axle_f / 2 - shift, axle_f / 2 + shift, axle_r / 2 - shift,
                                        axle_r / 2 + shift], axis=-1), 0.0)  # fmt: skip
            angle = np.zeros((n_runs, 4))
            angle[:, :2] = np.arctan(truth._ackermann_tangents(delta)[:, :2])
            ux, uy = vx[:, None] - r[:, None] * py, vy[:, None] + r[:, None] * px
            cos, sin = np.cos(angle), np.sin(angle)
            v_long, v_lat = ux * cos + uy * sin, uy * cos - ux * sin
            alpha = np.arctan(-v_lat / np.maximum(np.abs(v_long), truth.fade_speed))
            grip = truth.friction * load
            top = np.where(throttle > 0, truth.top_speed, truth.reverse_top_speed)
            a_max = truth.max_acceleration
            limit = a_max * truth.power_limit_speed / np.maximum(np.abs(vx), truth.power_limit_speed)
            accel = np.clip(a_max * (throttle - vx / top), -limit, limit)
            f_long = (truth.mass_nominal * accel)[:, None] * truth.drive_share
            b_alpha = truth.stiffness_factor * alpha
            b_alpha = b_alpha - truth.curvature * (b_alpha - np.arctan(b_alpha))
            f_lat = grip * np.sin(truth.shape * np.arctan(b_alpha))
            demand = np.hypot(f_long, f_lat)
            scale = np.where(demand > grip, grip / np.where(demand > 0, demand, 1.0), 1.0)
            fx, fy = (f_long * cos - f_lat * sin) * scale, (f_long * sin + f_lat * cos) * scale
            ax, ay = fx.sum(axis=1) / m, fy.sum(axis=1) / m
            yaw = (px * fy - py * fx).sum(axis=1) / inertia
            vx, vy, r = vx + h * (ax + vy * r), vy + h * (ay - vx * r), r + h * yaw
            step = truth.steering_rate * h
            target = np.clip(command, -truth.steering_limit, truth.steering_limit)
            delta = delta + np.clip(target - delta, -step, step)
            x = x + h * (vx * np.cos(psi) - vy * np.sin(psi))
            y = y + h * (vx * np.sin(psi) + vy * np.cos(psi))
            psi = psi + h * r
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--car", default="bmw320i")
    parser.add_argument("--twin", action="store_true", help=f"the twin's truth ({TWIN}) and its figures")
    parser.add_argument("--sweep", action="store_true", help="the tangent damping's sweep (see above)")
    parser.add_argument("--held-out", action="store_true", help="the test set at other operating points")
    args = parser.parse_args()
    if args.held_out and args.car not in HELD_OUT:
        parser.error(f"--held-out: operating points are given for {', '.join(HELD_OUT)}, not {args.car}")
    with tempfile.TemporaryDirectory() as tmp:
        points = HELD_OUT[args.car] if args.held_out else None
        cfg, test = car_test_set(args.car, args.twin, Path(tmp), points)
    rate = cfg.simulation.rate_hz
    bands = np.array(bands_of(test, cfg, args.twin))
    steps = [round(h * rate) for h in HORIZONS]
    truth = truth_paths(test, steps)
    controls, start = log_controls(test)
    figures = {"tire_friction": TWIN["tire_friction"], "motor_gain": TWIN["motor_gain"]} if args.twin else {}
    core = DynamicCar.of(cfg.vehicle.spec, **figures)
    core = dataclasses.replace(core, wheel_forces=cfg.model.wheel_forces)
    rows = []

    def add(label: str, paths: np.ndarray, stride: int = 1) -> None:
        at = paths[:, [s // stride for s in steps]]
        error = np.nan_to_num(np.hypot(*(at - truth).transpose(2, 0, 1)), nan=np.inf)
        for (band, _, _) in BANDS:
            for j, horizon in enumerate(HORIZONS):
                mean = error[bands == band, j].mean()
                rows.append({"variant": label, "horizon": horizon, "band": band, "error": mean})
        print(f"  {label}: {error[:, -1].mean():.2f} m after 30 s", flush=True)

    model_step, sampled = MODEL_STRIDE / rate, controls[:, ::MODEL_STRIDE]
    tangent = dataclasses.replace(core, tangent_damping=True)
    if args.sweep:
        for passes, share, substeps in itertools.product((3, 5, 8), (0.5, 0.25, 0.1), (4, 8)):
            varied = dataclasses.replace(tangent, wheel_passes=passes, blend_share=share)
            paths = core_paths(varied, sampled, start, model_step, substeps, True)
            add(f"tangent, passes {passes}, blend {share}, {substeps} substeps", paths, MODEL_STRIDE)
        frame = pd.DataFrame(rows)
        last = frame[frame["horizon"] == 30.0]
        table = last.pivot_table(index="variant", columns="band", values="error", sort=False)
        print(table[[b for b, _, _ in BANDS]].to_string(float_format="%.2f"))
        return
    overrides = {"mass": 1.0, **({"tire_friction": TWIN["tire_friction"], "motor_gain": TWIN["motor_gain"]}
                                  if args.twin else {})}  # fmt: skip
    replica = replica_paths(TyreCar(cfg.vehicle.spec, overrides), controls, rate)
    add("planar replica of the truth's tyre step", replica)
    log_step = 1.0 / rate
    variants = (("", {}), (", passes 8", {"wheel_passes": 8}), (", blend 0.1", {"blend_share": 0.1}),
                (", passes 8 + blend 0.1", FIXED))  # fmt: skip
    for label, values in variants:
        varied = dataclasses.replace(core, **values)
        add(f"core at 1/30 s, explicit{label}", core_paths(varied, controls, start, log_step, None, False))
    implicit = core.implicit_substeps(model_step)
    for label, values, substeps, kind in (
        (f"as shipped ({implicit} implicit substeps)", {}, implicit, "implicit"),
        ("passes 8 + blend 0.1", FIXED, implicit, "implicit"),
        ("passes 8 + blend 0.1, 16 substeps", FIXED, 16, "implicit"),
        ("passes 8 + blend 0.1, tangent damping", FIXED, implicit, "tangent"),
        ("passes 8 + blend 0.1, 16 substeps, tangent damping", FIXED, 16, "tangent"),
        ("passes 8 + blend 0.1, explicit (converged)", FIXED, None, "explicit"),
    ):
        varied = dataclasses.replace(tangent if kind == "tangent" else core, **values)
        paths = core_paths(varied, sampled, start, model_step, substeps, kind != "explicit")
        add(f"core at 0.1 s, {label}", paths, MODEL_STRIDE)
    frame = pd.DataFrame(rows)
    table = frame.pivot_table(index=["horizon", "variant"], columns="band", values="error", sort=False)
    counts = {band: int((bands == band).sum()) for band, _, _ in BANDS}
    pd.set_option("display.width", 220)
    pd.set_option("display.max_colwidth", 60)
    print(f"=== {args.car}, {'twin ' + str(TWIN) if args.twin else 'nominal'} truth, the core at the truth's "
          f"figures: distance to the truth's path, m (test maneuvers per band: {counts}) ===")  # fmt: skip
    print(table[[b for b, _, _ in BANDS]].to_string(float_format="%.2f"))


if __name__ == "__main__":
    main()
