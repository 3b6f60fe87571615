"""Vehicles as data: one TOML file per car (figures with sources) and the schema that reads them."""

from simulator.vehicles.spec import (
    GRAVITY,
    VehicleFileError,
    VehicleSpec,
    load_vehicle,
    shipped_vehicles,
    vehicle_path,
)

__all__ = ["GRAVITY", "VehicleFileError", "VehicleSpec", "load_vehicle", "shipped_vehicles", "vehicle_path"]
