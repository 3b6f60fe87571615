"""Build the truth simulator of any car from its vehicle file, with twin overrides.

A 'mujoco-contacts' car (Nigel) is its MJCF model (`simulator.vehicle.Vehicle`); a 'mujoco-tyres'
car is a rigid MuJoCo car on frictionless wheels with a magic-formula tyre (`simulator.tyre_car`).
Both answer `collect` the same way.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from simulator.twin import check_overrides, twin_vehicle
from simulator.vehicle import Vehicle, model_xml
from simulator.vehicles.spec import VehicleSpec, load_vehicle


def build_vehicle(
    vehicle: VehicleSpec | str | Path = "nigel", overrides: Mapping[str, float] | None = None
) -> Vehicle:
    """The car of a vehicle file (a shipped name or a path), twin overrides applied (nominal when none)."""
    spec = load_vehicle(vehicle)
    if spec.truth.engine == "mujoco-contacts":
        return twin_vehicle(overrides, spec)
    from simulator.tyre_car import TyreCar

    return TyreCar(spec, check_overrides(overrides or {}))


def truth_text(vehicle: VehicleSpec | str | Path = "nigel") -> str:
    """Everything that decides what the car's simulator computes, as text (the cache's key).

    A 'mujoco-contacts' car: its filled MJCF. A 'mujoco-tyres' car: its figures, the tyre model's code and
    which path steps it (the compiled step and the NumPy one differ in the last bits).
    """
    spec = load_vehicle(vehicle)
    if spec.truth.engine == "mujoco-contacts":
        return model_xml(spec)
    from simulator import tyre_car, tyre_kernel

    # the stopping deceleration is a safety check's figure, not the simulator's: left out of the key
    figures = spec.model_dump_json(exclude={"limits": {"stopping_deceleration"}})
    code = Path(tyre_car.__file__).read_text()
    if tyre_kernel.library() is not None:
        code += tyre_kernel.SOURCE.read_text() + " ".join(tyre_kernel.NUMERIC_FLAGS)
    return figures + code
