"""MuJoCo simulator of cars described by vehicle files (Nigel, a 1:10 racing car, a full-size car):
benchmark maneuvers logged in the AutoDRIVE layout.

Knows nothing about learning; `activelearn` reaches MuJoCo only through this package.
"""

from simulator.build import build_vehicle, truth_text
from simulator.collect import AUTODRIVE_COLUMNS, COLUMNS, EXTRA_COLUMNS, collect
from simulator.errors import DivergenceError, DivergenceWarning, ManeuverError, OverrideError, SimulatorError
from simulator.families import FAMILIES, Family, FamilyManeuver, as_family, family
from simulator.maneuvers import (
    DIRECTIONS,
    KINDS,
    Maneuver,
    Replay,
    nominal_controls,
    nominal_turn,
    sample_times,
)
from simulator.noise import NoiseConfig, add_noise, noise_std
from simulator.schedules import check_schedule, member_from_name, schedule_maneuver
from simulator.stop import StopRule
from simulator.twin import TWIN_PARAMETERS, TwinParameter, check_overrides, twin_vehicle
from simulator.vehicle import (
    ENCODER_CPR,
    MAX_SPEED,
    MAX_YAW_RATE,
    STEERING_LIMIT,
    THROTTLE_LIMIT,
    Vehicle,
    ackermann_angles,
    model_xml,
    reference_speed,
)
from simulator.vehicles import VehicleFileError, VehicleSpec, load_vehicle, shipped_vehicles

__version__ = "0.1.0"

__all__ = [
    "AUTODRIVE_COLUMNS",
    "COLUMNS",
    "DIRECTIONS",
    "ENCODER_CPR",
    "EXTRA_COLUMNS",
    "FAMILIES",
    "KINDS",
    "MAX_SPEED",
    "MAX_YAW_RATE",
    "STEERING_LIMIT",
    "THROTTLE_LIMIT",
    "TWIN_PARAMETERS",
    "DivergenceError",
    "DivergenceWarning",
    "Family",
    "FamilyManeuver",
    "Maneuver",
    "ManeuverError",
    "NoiseConfig",
    "OverrideError",
    "Replay",
    "SimulatorError",
    "StopRule",
    "TwinParameter",
    "Vehicle",
    "VehicleFileError",
    "VehicleSpec",
    "__version__",
    "ackermann_angles",
    "add_noise",
    "as_family",
    "build_vehicle",
    "check_overrides",
    "check_schedule",
    "collect",
    "family",
    "load_vehicle",
    "member_from_name",
    "model_xml",
    "noise_std",
    "nominal_controls",
    "nominal_turn",
    "reference_speed",
    "sample_times",
    "schedule_maneuver",
    "shipped_vehicles",
    "truth_text",
    "twin_vehicle",
]
