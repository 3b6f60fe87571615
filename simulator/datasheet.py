"""Nigel's datasheet (`shared/reference/nigel.md`): the one place its figures are written down.

Plain numbers, no MuJoCo: the simulator builds its model from them and the physics-structured
surrogate (`activelearn.numerics.models.physics`) takes them as its prior.
"""

from __future__ import annotations

import numpy as np

THROTTLE_LIMIT = 1.0
STEERING_LIMIT = 0.5236  # rad
MAX_SPEED = 0.2670  # m/s, reference linear velocity limit
MAX_YAW_RATE = 0.8051  # rad/s, reference angular velocity limit
LF = 0.06226  # m, CG to front axle
LR = 0.07929  # m, CG to rear axle
WHEELBASE = 0.14155  # m, lf + lr (the table rounds it to 0.1415)
TRACK = 0.153  # m
WHEEL_RADIUS = 0.0325  # m
MASS = 2.68  # kg
YAW_INERTIA = 0.01944  # kg m^2
CORNERING_STIFFNESS = 22.4768  # N/rad per tyre, identified on polished concrete
FRICTION = 0.4  # tyre-floor friction coefficient, same floor
GRAVITY = 9.81  # m/s^2
LOG_RATE_HZ = 30.0  # the AutoDRIVE logs' nominal rate

# Calibration target: steady straight-line speed for each throttle (steering 0).
REFERENCE_THROTTLE = np.round(np.arange(0.0, 1.01, 0.1), 1)
REFERENCE_SPEED = np.array(
    [0.0, 0.02867, 0.05685, 0.08457, 0.11185, 0.13871, 0.16516, 0.19122, 0.21688, 0.24215, 0.26703]
)


def understeer_gradient() -> float:
    """The linear single track's understeer gradient K (rad per m/s²) from mass, lf, lr and stiffness.

    δ = L/R + K·a_y with K = (m / L)(lr / C_f − lf / C_r), each axle two tyres of the datasheet's stiffness.
    """
    axle = 2.0 * CORNERING_STIFFNESS
    return MASS / WHEELBASE * (LR / axle - LF / axle)
