"""How far each car travels from a live stop's trigger until it stands, in MuJoCo, against the braking
distance a `[safety] stop = "live"` config is checked with (`activelearn.config.safety.braking_distance`).

Each car drives straight at a throttle for 20 s; a stop rule's wall is placed at 0.6 of the free run's
travel, so the stop triggers at the steady speed. Printed per run: the speed at the triggering pose, the
travel from it until the car stands, the mean deceleration after one log sample of latency, and the
braking distance the config check assumes (one log sample at the trigger speed, then the car's
`stopping_deceleration`) over the travel (at least 1: the check never promises less room than the car
needs). Tyre cars are also run on their twin's grip (`tire_friction` 0.8), where grip limits the brake.

Usage: python experiments/investigations/braking.py [--cars nigel,f1tenth,bmw320i]
"""

from __future__ import annotations

import argparse

import numpy as np

from activelearn.config.safety import braking_distance
from simulator import Maneuver, StopRule, build_vehicle, collect, load_vehicle

THROTTLES = (0.1, 0.2, 0.3, 0.5, 0.8, 1.0, -0.3, -1.0)


def stop_from_steady(vehicle, throttle: float) -> tuple[float, float, float]:
    """(speed at the triggering pose, travel until standing, seconds until standing) of one straight."""
    maneuver = Maneuver("straight", throttle, 0.0, "ccw", 20.0)
    free = collect(maneuver, noise=None, vehicle=vehicle)
    wall = 0.6 * float(free["posX"].iloc[-1])
    far = 1e4
    polygon = ((-far, -far), (wall, -far), (wall, far), (-far, far)) if throttle > 0 else (
        (wall, -far), (far, -far), (far, far), (wall, far))
    log = collect(maneuver, noise=None, vehicle=vehicle, stop=StopRule(polygon, settle=10.0))
    trigger = int(np.flatnonzero(log["throttle"].to_numpy() == 0.0)[0]) - 1
    speed = abs(float(log["speed"].iloc[trigger]))
    travel = abs(float(log["posX"].iloc[-1] - log["posX"].iloc[trigger]))
    return speed, travel, (len(log) - 1 - trigger) / vehicle.spec.log_rate_hz


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cars", default="nigel,f1tenth,bmw320i")
    args = parser.parse_args()
    for car in args.cars.split(","):
        spec = load_vehicle(car)
        grips = [1.0] if spec.truth.engine == "mujoco-contacts" else [1.0, 0.8]
        for grip in grips:
            vehicle = build_vehicle(spec, {"tire_friction": grip} if grip != 1.0 else None)
            deceleration = spec.stopping_deceleration * grip
            latency = 1.0 / spec.log_rate_hz
            print(f"== {car}, tyre friction x{grip:g}: stopping_deceleration {deceleration:.3f} m/s² "
                  f"(file {spec.stopping_deceleration:g} x {grip:g}), latency {latency:.4f} s")
            print(f"{'throttle':>8} {'speed m/s':>10} {'travel m':>10} {'time s':>7} {'decel m/s²':>11} "
                  f"{'check m':>10} {'check/travel':>12}")
            for throttle in THROTTLES:
                speed, travel, seconds = stop_from_steady(vehicle, throttle)
                braking = travel - speed * latency
                measured = speed**2 / (2.0 * braking) if braking > 0 else float("inf")
                check = braking_distance(speed, deceleration, latency)
                print(f"{throttle:>+8.1f} {speed:>10.3f} {travel:>10.4f} {seconds:>7.2f} {measured:>11.2f} "
                      f"{check:>10.4f} {check / travel:>12.3f}")


if __name__ == "__main__":
    main()
