"""Benchmark of the Nigel simulator: collection speed, throughput against raw rollout, calibration.

Run:  python experiments/benchmarks/bench_simulator.py [--threads N] [--duration SEC]

Prints
- the wall time of the reference skidpad grid (5 throttles x 5 steerings x cw/ccw, 90 s each) and the
  simulated seconds per wall second;
- the ratio of collect()'s physics-step throughput to raw mujoco.rollout steps/s for the same model,
  batch and thread count, measured in the same run (target >= 0.8);
- the straight-line throttle -> speed calibration against the reference table, with its max error;
- steady speed, yaw rate and turning radius against the kinematic radius on skidpad points
  (understeer), and the check of the kinematic eight approximation used by nominal_controls.
"""

from __future__ import annotations

import argparse
import math
import os
import time

import mujoco
import mujoco.rollout
import numpy as np

from simulator import Maneuver, Vehicle, collect, nominal_turn, reference_speed
from simulator.vehicle import MAX_YAW_RATE

THROTTLES = (0.2, 0.4, 0.6, 0.8, 1.0)
STEERINGS = (0.1047, 0.2094, 0.3142, 0.4189, 0.5236)


def skidpad_grid(duration: float) -> list[Maneuver]:
    """The reference skidpad grid."""
    return [
        Maneuver("skidpad", t, s, d, duration)
        for t in THROTTLES
        for s in STEERINGS
        for d in ("ccw", "cw")
    ]


def raw_rollout_rate(vehicle: Vehicle, maneuvers: list[Maneuver], threads: int, seconds: float) -> float:
    """Best physics steps per wall second of plain mujoco.rollout calls over the same batch.

    Same model, batch and thread count as collect; constant controls, one call per repetition,
    outputs preallocated and the thread pool reused, best of three: an upper bound for collect.
    """
    m = vehicle.model
    nstep = round(seconds / vehicle.timestep)
    nb = len(maneuvers)
    ctrl = np.stack([vehicle.controls(mv.throttle, mv.sign * mv.steering) for mv in maneuvers])
    control = np.ascontiguousarray(np.repeat(ctrl[:, None, :], nstep, axis=1))
    init = np.tile(vehicle.rest_state, (nb, 1))
    state = np.empty((nb, nstep, vehicle.nstate))
    sensordata = np.empty((nb, nstep, m.nsensordata))
    datas = [mujoco.MjData(m) for _ in range(threads)]
    best = 0.0
    with mujoco.rollout.Rollout(nthread=threads if threads > 1 else 0) as roller:
        for _ in range(3):
            start = time.perf_counter()
            roller.rollout([m] * nb, datas, init, control, state=state, sensordata=sensordata)
            best = max(best, nb * nstep / (time.perf_counter() - start))
    return best


def main() -> None:
    """Run the benchmark and print its tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--duration", type=float, default=90.0, help="seconds per maneuver")
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes: checks every part still runs (tests/test_benchmarks.py)")
    args = parser.parse_args()
    if args.quick:  # the grid's maneuvers 2 s long; the calibration tables as always (a few seconds)
        args.duration = 2.0
    threads = args.threads
    vehicle = Vehicle()
    _ = vehicle.rest_state

    grid = skidpad_grid(args.duration)
    print(f"Skidpad grid: {len(grid)} maneuvers x {args.duration:g} s, {threads} thread(s)")
    # raw rollout on a 10 s stretch of the same batch (a full 90 s would need GBs of output),
    # right before and right after the collection; the faster makes the ratio conservative
    stretch = min(10.0, args.duration)
    raw_before = raw_rollout_rate(vehicle, grid, threads, stretch)
    start = time.perf_counter()
    table = collect(grid, threads=threads, seed=0, vehicle=vehicle)
    wall = time.perf_counter() - start
    raw_after = raw_rollout_rate(vehicle, grid, threads, stretch)
    raw = max(raw_before, raw_after)
    steps = sum(math.floor(mv.duration * 30 + 1e-9) * 10 + 1 for mv in grid)
    sim_seconds = len(grid) * args.duration
    print(f"  collect wall time          {wall:8.2f} s   ({len(table)} rows)")
    print(f"  simulated s per wall s     {sim_seconds / wall:8.1f}")
    print(f"  collect throughput         {steps / wall:10.0f} steps/s")
    print(f"  raw mujoco.rollout         {raw:10.0f} steps/s"
          f"   (before {raw_before:.0f}, after {raw_after:.0f})")
    print(f"  ratio collect / raw        {steps / wall / raw:8.3f}   (target >= 0.8)")

    print("\nCalibration: straight line, steady speed (mean over the last 2 s of 8 s runs)")
    throttles = np.round(np.arange(0.1, 1.01, 0.1), 1)
    straight = collect([Maneuver("straight", float(t), duration=8.0) for t in throttles], noise=None,
                       threads=threads, vehicle=vehicle)
    steady = straight[straight.time >= 6.0].groupby("op_throttle").speed.mean()
    print(f"  {'throttle':>8} {'reference':>10} {'simulated':>10} {'error':>8}")
    errors = []
    for t in throttles:
        ref = float(reference_speed(t))
        sim = float(steady.loc[t])
        errors.append(abs(sim / ref - 1.0))
        print(f"  {t:8.1f} {ref:10.5f} {sim:10.5f} {100 * (sim / ref - 1):7.2f}%")
    print(f"  max error {100 * max(errors):.2f} %   (limit 5 %)")

    print("\nSteady turns (last 5 s of 20 s skidpads): understeer and scrub")
    points = [Maneuver("skidpad", t, s, "ccw", 20.0) for t in (0.2, 0.6, 1.0) for s in STEERINGS]
    turns = collect(points, noise=None, threads=threads, vehicle=vehicle)
    late = turns[turns.time >= 15.0].groupby("run_id", sort=False)[["speed", "angZ"]].mean()
    print(f"  {'throttle':>8} {'steer':>7} {'v m/s':>7} {'v/v0':>6} {'w rad/s':>8} {'w_kin':>7}"
          f" {'R m':>6} {'R_kin':>6} {'R/R_kin':>7} {'w_nom':>7}")
    worst_nominal = 0.0
    for mv in points:
        v, w = late.loc[mv.name]
        v0 = float(reference_speed(mv.throttle))
        r_kin = vehicle.wheelbase / math.tan(mv.steering)
        _, w_nom = nominal_turn(mv.throttle, mv.steering)
        worst_nominal = max(worst_nominal, abs(w_nom / w - 1.0))
        print(f"  {mv.throttle:8.1f} {mv.steering:7.4f} {v:7.4f} {v / v0:6.3f} {w:8.4f} {v / r_kin:7.4f}"
              f" {v / w:6.3f} {r_kin:6.3f} {v / w / r_kin:7.3f} {w_nom:7.4f}")
    print(f"  max yaw rate {late.angZ.max():.4f} rad/s (reference limit {MAX_YAW_RATE})")
    print(f"  nominal_turn yaw-rate error (eight approximation): max {100 * worst_nominal:.1f} %")


if __name__ == "__main__":
    main()
