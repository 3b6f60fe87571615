"""Nigel's datasheet, read from its vehicle file (`simulator/vehicles/nigel.toml`).

Plain numbers, no MuJoCo: module constants for the code that was written for Nigel before vehicles
became data (the physics prior, maneuver grids). New code takes a `VehicleSpec` instead.
"""

from __future__ import annotations

import numpy as np

from simulator.vehicles.spec import GRAVITY, load_vehicle  # noqa: F401 (GRAVITY re-exported)

NIGEL = load_vehicle("nigel")

THROTTLE_LIMIT = 1.0  # the normalised throttle of every car: -1 … 1, 0 brakes
STEERING_LIMIT = NIGEL.steering.limit.value  # rad
MAX_SPEED = NIGEL.max_speed  # m/s, reference linear velocity limit
MAX_YAW_RATE = NIGEL.max_yaw_rate  # rad/s, reference angular velocity limit
LF = NIGEL.geometry.lf.value  # m, CG to front axle
LR = NIGEL.geometry.lr.value  # m, CG to rear axle
WHEELBASE = NIGEL.wheelbase  # m, lf + lr
TRACK = NIGEL.geometry.track.value  # m
WHEEL_RADIUS = NIGEL.geometry.wheel_radius.value  # m
MASS = NIGEL.inertia.mass.value  # kg
YAW_INERTIA = NIGEL.inertia.yaw_inertia.value  # kg m^2
CORNERING_STIFFNESS = NIGEL.tyres.cornering_stiffness_front.value / 2.0  # N/rad per tyre
FRICTION = NIGEL.tyres.friction.value  # tyre-floor friction coefficient
LOG_RATE_HZ = NIGEL.log_rate_hz  # the AutoDRIVE logs' nominal rate

# Calibration target: steady straight-line speed for each throttle (steering 0).
REFERENCE_THROTTLE, REFERENCE_SPEED = (np.array(a) for a in NIGEL.speed_map)


def understeer_gradient() -> float:
    """The linear single track's understeer gradient K (rad per m/s²): δ = L/R + K·a_y."""
    return NIGEL.understeer_gradient()
