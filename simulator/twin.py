"""Twins: a car's model with parameter overrides, a stand-in for a real car that differs from nominal.

Every parameter is a scale of a nominal model quantity (1 = nominal) or an additive offset (0 =
nominal); `TWIN_PARAMETERS` documents its meaning, unit and allowed range. `twin_vehicle` applies
overrides to a Vehicle's private MjModel copy (and to its control path for steering and latency);
with no overrides it is the nominal Vehicle, bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from numbers import Real
from pathlib import Path

import mujoco

from simulator.errors import OverrideError
from simulator.vehicle import Vehicle
from simulator.vehicles.spec import VehicleSpec


@dataclass(frozen=True)
class TwinParameter:
    """One overridable parameter: what it changes, its unit, its nominal value and allowed range."""

    name: str
    meaning: str
    unit: str
    nominal: float
    low: float
    high: float


TWIN_PARAMETERS: dict[str, TwinParameter] = {
    p.name: p
    for p in (
        TwinParameter(
            "tire_friction",
            "scale of the tyre-road friction coefficient (the vehicle file's tyres.friction)",
            "scale",
            1.0,
            0.25,
            2.0,
        ),
        TwinParameter(
            "mass",
            "scale of the chassis mass (the car less its wheels), a payload at the CG: "
            "the inertia is unchanged (see yaw_inertia)",
            "scale",
            1.0,
            0.5,
            2.0,
        ),
        TwinParameter(
            "yaw_inertia",
            "scale of the whole car's yaw inertia about its CG (the vehicle file's inertia.yaw_inertia); "
            "the chassis takes the change",
            "scale",
            1.0,
            0.5,
            2.0,
        ),
        TwinParameter(
            "motor_gain",
            "scale of the drive actuator gain (stall torque and back-EMF drag together; the drivetrain "
            "loss stays): below 1 a weaker motor, slower at every throttle",
            "scale",
            1.0,
            0.25,
            2.0,
        ),
        TwinParameter(
            "steering_offset",
            "added to the commanded bicycle steering angle before the Ackermann split (misaligned servo)",
            "rad",
            0.0,
            -0.1,
            0.1,
        ),
        TwinParameter(
            "steering_gain",
            "scale of the commanded bicycle steering angle (servo travel; wheel angles are still "
            "limited to the steering joints' range)",
            "scale",
            1.0,
            0.5,
            1.5,
        ),
        TwinParameter(
            "latency",
            "actuation delay of throttle and steering (the control applied at time t is the command of "
            "t - latency), rounded to the car's physics step",
            "s",
            0.0,
            0.0,
            0.2,
        ),
    )
}


def check_overrides(overrides: Mapping[str, float]) -> dict[str, float]:
    """Validated overrides as floats; an unknown name or a bad value raises OverrideError naming it."""
    if not isinstance(overrides, Mapping):
        raise OverrideError("overrides", overrides, "must be a mapping of parameter name to number")
    known = ", ".join(TWIN_PARAMETERS)
    checked: dict[str, float] = {}
    for name, value in overrides.items():
        spec = TWIN_PARAMETERS.get(name)
        if spec is None:
            raise OverrideError(name, value, f"unknown twin parameter; known: {known}")
        if not isinstance(value, Real) or isinstance(value, bool) or not math.isfinite(value):
            raise OverrideError(name, value, "must be a finite number")
        if not spec.low <= value <= spec.high:
            raise OverrideError(name, value, f"must lie in [{spec.low:g}, {spec.high:g}] ({spec.unit})")
        checked[name] = float(value)
    return checked


def twin_vehicle(
    overrides: Mapping[str, float] | None = None, spec: VehicleSpec | str | Path = "nigel"
) -> Vehicle:
    """A Vehicle with the overrides applied to its private model copy (nominal when none are given)."""
    values = check_overrides(overrides or {})
    vehicle = Vehicle(spec=spec)
    m = vehicle.model
    scale = {name: values.get(name, spec.nominal) for name, spec in TWIN_PARAMETERS.items()}
    if scale["tire_friction"] != 1.0:
        # default contacts take the larger of the two geoms' coefficients: scale floor and tyres alike
        tyres = [m.geom(f"tyre_{w}").id for w in ("fl", "fr", "rl", "rr")]
        for g in (*tyres, m.geom("floor").id):
            m.geom_friction[g, 0] *= scale["tire_friction"]
        m.pair_friction[:, :2] *= scale["tire_friction"]  # explicit front pairs: both tangential axes
    chassis = m.body("chassis").id
    if scale["mass"] != 1.0:
        m.body_mass[chassis] *= scale["mass"]
    if scale["yaw_inertia"] != 1.0:
        total = _yaw_inertia(m)
        m.body_inertia[chassis, 2] += (scale["yaw_inertia"] - 1.0) * total
    if scale["motor_gain"] != 1.0:
        for name in ("drive_fwd", "drive_rev"):
            m.actuator(name).gainprm[:3] *= scale["motor_gain"]
    if scale["mass"] != 1.0 or scale["yaw_inertia"] != 1.0:
        mujoco.mj_setConst(m, mujoco.MjData(m))  # constraint weights depend on mass and inertia
    vehicle.steering_gain = scale["steering_gain"]
    vehicle.steering_offset = scale["steering_offset"]
    vehicle.latency = scale["latency"]
    return vehicle


def _yaw_inertia(m: mujoco.MjModel) -> float:
    """Yaw inertia (kg m^2) of the whole car about its CG at the model's reference pose."""
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    chassis = m.body("chassis").id
    cg = d.subtree_com[chassis]
    total = 0.0
    for b in range(1, m.nbody):
        # body_inertia is about the body's principal axes; every body here has its yaw axis vertical
        offset = d.xipos[b] - cg
        total += m.body_inertia[b, 2] + m.body_mass[b] * float(offset[0] ** 2 + offset[1] ** 2)
    return float(total)


__all__ = ["TWIN_PARAMETERS", "TwinParameter", "check_overrides", "twin_vehicle"]
