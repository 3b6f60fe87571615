"""The reference eight (closed loop: it flips on the measured heading) against its open-loop family member.

For 15 operating points (throttle -0.6..1.0, steering 0.2..0.5236, ccw, 90 s, noise-free MuJoCo), the
closed-loop eight is driven, then two figure_eight members open loop: the one `as_family` gives by
default (loop time from the nominal turn) and the one with the loop time measured from the eight's own
log (`measured_loop_time`). Prints the loop times, the number of steering flips of each, and the
distance between the closed-loop path and each open-loop path (at 30 s, 90 s, and the largest).
Results: experiments/results/figure_eight.txt.

    python experiments/investigations/figure_eight.py
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd

from simulator import FamilyManeuver, Maneuver, as_family, collect
from simulator.families import measured_loop_time

RATE = 30.0
OPERATING_POINTS = [(u, s) for u in (-0.6, -0.3, 0.3, 0.6, 1.0) for s in (0.2, 0.35, 0.5236)]


def _gap(ref: pd.DataFrame, other: pd.DataFrame, seconds: float | None = None) -> float:
    """Distance (m) between two logged paths at `seconds`, or the largest over the run."""
    d = np.hypot(ref.posX.to_numpy() - other.posX.to_numpy(), ref.posY.to_numpy() - other.posY.to_numpy())
    return float(d.max() if seconds is None else d[int(seconds * RATE)])


def _flips(log: pd.DataFrame) -> int:
    return int(np.sum(np.diff(np.sign(log.steering.to_numpy())) != 0))


def main() -> None:
    start = time.perf_counter()
    eights = [Maneuver("eight", u, s, "ccw", 90.0) for u, s in OPERATING_POINTS]
    closed = collect(eights, rate_hz=RATE, noise=None)
    nominal = [as_family(m) for m in eights]
    measured: list[FamilyManeuver] = [
        as_family(m, loop_time=measured_loop_time(closed[closed.run_id == m.name])) for m in eights
    ]
    by_nominal = collect(nominal, rate_hz=RATE, noise=None)
    by_measured = collect(measured, rate_hz=RATE, noise=None)
    print("throttle steering | loop time nominal measured (s) | flips closed nominal measured |"
          " gap nominal 30 s 90 s max | gap measured 30 s 90 s max (m) | path extent (m)")
    worst = {"nominal": 0.0, "measured": 0.0}
    for m, a, b in zip(eights, nominal, measured, strict=True):
        ref = closed[closed.run_id == m.name]
        o, q = by_nominal[by_nominal.run_id == a.name], by_measured[by_measured.run_id == b.name]
        worst["nominal"] = max(worst["nominal"], _gap(ref, o))
        worst["measured"] = max(worst["measured"], _gap(ref, q))
        extent = float(np.ptp(ref.posX.to_numpy()) + np.ptp(ref.posY.to_numpy()))
        loops = f"{a.values['loop_time']:7.2f} {b.values['loop_time']:7.2f}"
        print(f"{m.throttle:6.1f} {m.op_steering:7.4f} | {loops}"
              f" | {_flips(ref):3d} {_flips(o):3d} {_flips(q):3d}"
              f" | {_gap(ref, o, 30):.3f} {_gap(ref, o, 90):.3f} {_gap(ref, o):.3f}"
              f" | {_gap(ref, q, 30):.3f} {_gap(ref, q, 90):.3f} {_gap(ref, q):.3f} | {extent:.2f}")
    print(f"largest gap over all points: nominal loop time {worst['nominal']:.3f} m, "
          f"measured loop time {worst['measured']:.3f} m ({time.perf_counter() - start:.1f} s)")


if __name__ == "__main__":
    main()
