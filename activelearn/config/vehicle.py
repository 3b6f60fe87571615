"""[vehicle]: which car a campaign drives, and the figures of it the other sections default to.

A shipped vehicle's name (`nigel`, `f1tenth`, `bmw320i`) or the path of a vehicle file
(`simulator/vehicles/*.toml` shows the layout; a relative path is read from the working directory).
The file is read and checked when the config is: a bad one is a ConfigError naming the file and the
field. The steering grids the pool and the test set default to are the car's reference grids: its
full lock × (0.2, 0.4, 0.6, 0.8, 1) for the pool (Nigel's 6°…30°, to 4 decimals) and × (≈0.1, 0.3,
0.5, 0.7, 0.9) for the test set. A family pool's default steering ranges scale by the car's full
lock over Nigel's, and the standard tests' (ramp_steer, step_steer, sine_with_dwell,
double_lane_change) times and frequencies by its Froude time scale sqrt(wheelbase / Nigel's) as well.
"""

from __future__ import annotations

import math
from typing import Any

from pydantic import Field, field_validator

from activelearn.config.base import _Section
from simulator.vehicles import VehicleFileError, VehicleSpec, load_vehicle

DEFAULT_VEHICLE = "nigel"
DEFAULT_CAR = load_vehicle(DEFAULT_VEHICLE)  # the figures the sections' defaults show


class VehicleConfig(_Section):
    """The car: a shipped vehicle's name or a vehicle file's path."""

    name: str = Field(
        DEFAULT_VEHICLE,
        min_length=1,
        description="A shipped vehicle (`nigel`, `f1tenth`, `bmw320i`) or the path of a vehicle file "
        "(TOML: geometry, mass, tyres, drivetrain, steering, sensors, each figure with its source)",
    )

    @field_validator("name")
    @classmethod
    def _readable(cls, value: str) -> str:
        try:
            load_vehicle(value)
        except VehicleFileError as exc:
            raise ValueError(str(exc)) from None
        return value

    @property
    def spec(self) -> VehicleSpec:
        """The vehicle file's figures."""
        return load_vehicle(self.name)


def pool_steerings(spec: VehicleSpec) -> list[float]:
    """The pool's default steering grid: full lock × (0.2, 0.4, 0.6, 0.8, 1), to 4 decimals (rad)."""
    lock = spec.steering.limit.value
    return [round(lock * k / 5.0, 4) for k in range(1, 6)]


def test_steerings(spec: VehicleSpec) -> list[float]:
    """The test set's default steering grid: full lock × (0.1 to 2 decimals, 0.3, 0.5, 0.7, 0.9) (rad)."""
    lock = spec.steering.limit.value
    return [round(lock * 0.1, 2), *(round(lock * k / 10.0, 4) for k in (3, 5, 7, 9))]


test_steerings.__test__ = False  # type: ignore[attr-defined]  # not a pytest test


def time_scale(spec: VehicleSpec) -> float:
    """The car's Froude time scale over the default car's: sqrt(its wheelbase / the default car's)."""
    return math.sqrt(spec.wheelbase / DEFAULT_CAR.wheelbase)


def _scaled_family_ranges(families: list[Any], given: Any, ratio: float, time: float = 1.0) -> Any:
    """A family pool's ranges with every steering parameter (rad, rad/s) the config leaves unset at its
    family's default pool range scaled by the car's full lock over the default car's (`ratio`).

    The standard tests' families (`Family.froude`) are Froude-scaled as well, by the car's time scale
    `time`: their unset time parameters (s) × time, frequencies (Hz) ÷ time and rates (rad/s) ÷ time
    besides the lock. The other families' times and frequencies stay as they are."""
    from simulator.families import FAMILIES

    if not isinstance(given, dict):
        return given
    out = {family: dict(values) if isinstance(values, dict) else values for family, values in given.items()}
    for family in families:  # a family that is not a known name is [pool] validation's to report
        if not isinstance(family, str) or family not in FAMILIES or not isinstance(out.get(family, {}), dict):
            continue
        spec = FAMILIES[family]
        for p in spec.continuous:
            factor = {"rad": ratio, "rad/s": ratio}.get(p.unit, 1.0)
            if spec.froude:
                factor *= {"s": time, "Hz": 1.0 / time, "rad/s": 1.0 / time}.get(p.unit, 1.0)
            if factor != 1.0 and p.name not in out.get(family, {}):
                out.setdefault(family, {})[p.name] = [p.pool[0] * factor, p.pool[1] * factor]
    return out


def car_defaults(data: dict[str, Any]) -> dict[str, Any]:
    """A raw config with the defaults that depend on the car filled in from [vehicle] (given keys stay).

    Only values that differ from the default car's are written, so a Nigel config reads (and dumps) as
    it always has."""
    vehicle = data.get("vehicle")
    name = vehicle.get("name", DEFAULT_VEHICLE) if isinstance(vehicle, dict) else DEFAULT_VEHICLE
    if not isinstance(name, str):
        return data
    try:
        spec = load_vehicle(name)
    except VehicleFileError:
        return data  # [vehicle] reports it
    fills = {
        "pool": {"steerings": (pool_steerings(spec), pool_steerings(DEFAULT_CAR)),
                 "full_lock": (spec.steering.limit.value, DEFAULT_CAR.steering.limit.value)},
        "test": {"steerings": (test_steerings(spec), test_steerings(DEFAULT_CAR)),
                 "full_lock": (spec.steering.limit.value, DEFAULT_CAR.steering.limit.value)},
        "model": {"vehicle": (name, DEFAULT_VEHICLE),
                  "pose_lever_arm": (spec.geometry.lr.value, DEFAULT_CAR.geometry.lr.value)},
    }
    noise = {
        name: (figure.value, None)
        for name in ("speed", "yaw_rate", "acceleration", "position", "angle")
        if (figure := getattr(spec.sensors, f"{name}_noise")) is not None
    }
    noise["reference_speed"] = (spec.max_speed, DEFAULT_CAR.max_speed)
    out = dict(data)
    pool = out.get("pool")
    ratio = spec.steering.limit.value / DEFAULT_CAR.steering.limit.value
    time = time_scale(spec)
    if isinstance(pool, dict) and isinstance(pool.get("families"), list) and (ratio != 1.0 or time != 1.0):
        ranges = _scaled_family_ranges(pool["families"], pool.get("ranges", {}), ratio, time)
        if ranges != pool.get("ranges", {}):
            out["pool"] = {**pool, "ranges": ranges}
    simulation = out.get("simulation", {})
    if isinstance(simulation, dict):
        given = simulation.get("noise", {})
        if isinstance(given, dict):
            added = {k: car for k, (car, default) in noise.items() if k not in given and car != default}
            if added:
                out["simulation"] = {**simulation, "noise": {**given, **added}}
    for section, keys in fills.items():
        given = out.get(section, {})
        if not isinstance(given, dict):
            continue
        added = {k: car for k, (car, default) in keys.items() if k not in given and car != default}
        if section == "pool" and {"steering_range", "families"} & set(given):
            added.pop("steerings", None)
        if added:
            out[section] = {**given, **added}
    return out
