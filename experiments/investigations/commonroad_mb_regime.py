"""Does the published full-size car leave the kinematic regime by 0.8 μg? CommonRoad's own multi-body
model of its vehicle 2 (BMW 320i: suspension, roll, roll steer, Pacejka tyres) against our truth.

bench_vehicles.py measures our truth (a rigid car, magic-formula tyres of the file's figures): the
kinematic single track's steady yaw-rate error at 0.8 μg is 7.2 % (issue 55 expected > 10 %). This
script drives CommonRoad's multi-body model the same way (ISO 4138 constant steer, δ = atan(1/15.5),
speed rising slowly under a constant acceleration command) and prints the same error at 0.3, 0.6,
0.8 μg and where the car stops gaining lateral acceleration. Needs `pip install
commonroad-vehicle-models` (not a dependency of the project: an outside check of our truth).

Usage: python experiments/investigations/commonroad_mb_regime.py [--acceleration 0.5]
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
from scipy.integrate import solve_ivp

STEER = math.atan(1.0 / 15.5)  # rad, bench_vehicles.py's constant steer
LEVELS = (0.3, 0.6, 0.8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--acceleration", type=float, default=0.5, help="command after 3 s (m/s²)")
    parser.add_argument("--seconds", type=float, default=150.0)
    args = parser.parse_args()
    try:
        from vehiclemodels.init_mb import init_mb
        from vehiclemodels.parameters_vehicle2 import parameters_vehicle2
        from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb
    except ImportError:
        sys.exit("needs CommonRoad's vehicle models: pip install commonroad-vehicle-models")
    p = parameters_vehicle2()
    wheelbase, grip = p.a + p.b, p.tire.p_dy1 * 9.81

    def rhs(t: float, x: np.ndarray) -> list[float]:
        steer_rate = float(np.clip((STEER - x[2]) * 20.0, -p.steering.v_max, p.steering.v_max))
        return vehicle_dynamics_mb(x, [steer_rate, 0.0 if t < 3.0 else args.acceleration], p)

    x0 = init_mb([0.0, 0.0, 0.0, 8.0, 0.0, 0.0, 0.0], p)
    sol = solve_ivp(rhs, (0.0, args.seconds), x0, method="LSODA", max_step=0.01, rtol=1e-6, atol=1e-8)
    t, vx, vy, r = sol.t, sol.y[3], sol.y[10], sol.y[5]
    a_y = np.hypot(vx, vy) * r
    with np.errstate(divide="ignore", invalid="ignore"):
        kinematic = 100.0 * (vx * math.tan(STEER) / wheelbase / r - 1.0)
    late = t > 3.0
    print(f"CommonRoad multi-body, vehicle 2 (BMW 320i): constant steer {STEER:.4f} rad, "
          f"acceleration command {args.acceleration} m/s² after 3 s ({sol.message})")
    for level in LEVELS:
        reached = np.flatnonzero(late & (a_y >= level * grip))
        if len(reached):
            i = reached[0]
            print(f"  {level:.1f} μg at {vx[i]:.2f} m/s: kinematic yaw-rate error {kinematic[i]:.1f} %")
        else:
            print(f"  {level:.1f} μg: not reached")
    top = int(np.argmax(np.where(late, a_y, -np.inf)))
    largest = a_y[top] / grip
    print(f"  largest a_y {largest:.3f} μg at {vx[top]:.2f} m/s: kinematic error {kinematic[top]:.1f} %")


if __name__ == "__main__":
    main()
