"""Does the single track's scrub law hold in MuJoCo's steady turns, and what would?

Drives steady turns (skidpads of 15 s, noise-free) on nominal Nigel and on `sim_to_real`'s twin over a grid
of throttle (0.2-1.0) and steering (0, 0.1-0.52 rad), takes each turn's steady speed (the last 5 s) over
the straight's at the same throttle, and fits speed laws v(δ) = v0 · f(δ, v0) by least squares on the
relative error: the single track's `1 / (1 + scrub tan² δ)` and candidates with one parameter more. Each
law is fitted on all turns, then on those with a kinematic yaw rate ω_k = v0 tan δ / L below
`--slow` rad/s only (what a campaign's first logs hold) and judged on the fastest turns.

Usage: python experiments/investigations/scrub_law.py [--slow 0.45]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np
from scipy.optimize import least_squares

import simulator
from simulator import Maneuver, datasheet

THROTTLES = np.round(np.arange(0.2, 1.01, 0.1), 2)
STEERINGS = (0.0, 0.1, 0.2, 0.3, 0.39, 0.45, 0.52)
TWIN = {"motor_gain": 0.9, "tire_friction": 0.55}  # sim_to_real.toml's twin
STEADY_ROWS = 150  # the last 5 s at 30 Hz


def steady_turns(vehicle) -> np.ndarray:
    """Rows (throttle, steering, straight speed v0, steady speed) of every turn of the grid."""
    maneuvers = [Maneuver("skidpad", float(t), d, "ccw", 15.0) for d in STEERINGS for t in THROTTLES]
    log = simulator.collect(maneuvers, seed=0, noise=None, vehicle=vehicle)
    speeds = [part["speed"].iloc[-STEADY_ROWS:].mean() for _, part in log.groupby("run_id", sort=False)]
    straight = {m.throttle: v for m, v in zip(maneuvers, speeds, strict=True) if m.steering == 0.0}
    return np.array(
        [(m.throttle, m.steering, straight[m.throttle], v) for m, v in zip(maneuvers, speeds, strict=True)
         if m.steering > 0.0]
    )  # fmt: skip


def kinematic_yaw_rate(turns: np.ndarray) -> np.ndarray:
    """ω_k = v0 tan δ / L of each turn (rad/s): the yaw rate of the straight's speed on the kinematic turn."""
    return turns[:, 2] * np.tan(turns[:, 1]) / datasheet.WHEELBASE


Law = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]  # (params, tan² δ, ω_k) -> v / v0


def laws() -> dict[str, tuple[Law, list[float]]]:
    """The speed laws compared, each with its starting parameters."""
    return {
        "1/(1 + s tan²δ)  (the single track's)": (lambda p, t2, wk: 1 / (1 + p[0] * t2), [1.2]),
        "1/(1 + s tan²δ / (1 + c ω_k²))": (
            lambda p, t2, wk: 1 / (1 + p[0] * t2 / (1 + p[1] * wk**2)), [1.2, 0.1]
        ),
        "1/(1 + (s - c ω_k²) tan²δ)": (lambda p, t2, wk: 1 / (1 + (p[0] - p[1] * wk**2) * t2), [1.2, 0.1]),
    }


def fitted(
    law: Law, start: list[float], turns: np.ndarray, rows: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The law's parameters fitted on `rows` of `turns` and its relative speed error on every turn."""
    t2 = np.tan(turns[:, 1]) ** 2
    v0, v = turns[:, 2], turns[:, 3]
    wk = kinematic_yaw_rate(turns)

    def error(p: np.ndarray) -> np.ndarray:
        return (v0 * law(p, t2, wk) - v) / v

    fit = least_squares(lambda p: error(p)[rows], start)
    return fit.x, error(fit.x)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--slow", type=float, default=0.45, help="ω_k (rad/s) below which a turn is slow")
    args = parser.parse_args()
    for name, vehicle in (("nominal", None), ("twin", simulator.twin_vehicle(TWIN))):
        turns = steady_turns(vehicle)
        wk = kinematic_yaw_rate(turns)
        slow, top = wk < args.slow, int(np.argmax(wk))
        print(f"{name}: {len(turns)} steady turns, ω_k {wk.min():.2f}-{wk.max():.2f} rad/s; "
              f"{slow.sum()} below {args.slow}")  # fmt: skip
        for label, (law, start) in laws().items():
            p_all, rel = fitted(law, start, turns, np.ones(len(turns), dtype=bool))
            p_slow, off = fitted(law, start, turns, slow)
            print(f"  {label:36s} all turns: p = {np.round(p_all, 3)}, rms {np.sqrt(np.mean(rel**2)):.2%}, "
                  f"max {np.abs(rel).max():.2%}")  # fmt: skip
            print(f"  {'':36s} fitted on the slow turns: p = {np.round(p_slow, 3)}, at the fastest turn "
                  f"{off[top]:+.2%}, the worst fast turn {np.abs(off[~slow]).max():.2%}")  # fmt: skip


if __name__ == "__main__":
    main()
