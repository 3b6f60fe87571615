"""The dynamic core's identified parameters (scales of its vehicle file's figures, 1 = the file): the five
of every car, and with `kinematic_core` the kinematic branch's four; their ranges and prior
(`dynamic_bounds`), what each scales on a car (`scaled_figures`), and a car under a set of them
(`scaled`, `with_scales`)."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np

from activelearn.numerics.models.dynamic_track import DynamicCar, _minimum
from activelearn.numerics.models.single_track import Identified, PhysicalParameter
from simulator.vehicles import GRAVITY

# The dynamic core's parameters identified from logs: scales of the file's figures (1 = the file).
DYNAMIC_PARAMETERS: tuple[PhysicalParameter, ...] = (
    PhysicalParameter("friction", 1.0, 0.3, 3.0, 0.3, "-", "scale of the tyres' peak friction μ"),
    PhysicalParameter("stiffness_front", 1.0, 0.3, 3.0, 0.5, "-", "scale of the front axle's stiffness"),
    PhysicalParameter("stiffness_rear", 1.0, 0.3, 3.0, 0.5, "-", "scale of the rear cornering stiffness"),
    # at most 1.25, as the kinematic core's speed gain: a free run's speed stays within 1.25x the file's
    PhysicalParameter("motor", 1.0, 0.3, 1.25, 0.3, "-", "scale of the drive (a_max, top speeds, table)"),
    PhysicalParameter("yaw_inertia", 1.0, 0.3, 3.0, 0.5, "-", "scale of the yaw inertia"),
)
# With `kinematic_core`, four more: the kinematic branch's, below the blend speed (the kinematic core's
# priors, `single_track.car_parameters`; its understeer and yaw lag as scales)
KINEMATIC_PARAMETERS: tuple[PhysicalParameter, ...] = (
    PhysicalParameter("understeer", 1.0, 0.7, 2.0, 0.5, "-", "below the blend: turn radius over L / tan δ"),
    PhysicalParameter("scrub", 0.0, 0.0, 3.0, 1.0, "-", "below the blend: speed / (1 + scrub tan² δ)"),
    PhysicalParameter("yaw_lag", 1.0, 0.1, 20.0, 4.0, "-", "below the blend: scale of the yaw rate's lag"),
    PhysicalParameter("reverse_understeer", 1.0, 0.7, 2.0, 0.5, "-", "below the blend: understeer reversing"),
)


def parameters_of(car: DynamicCar) -> tuple[PhysicalParameter, ...]:
    """The scales a car's core identifies: the five, and with `kinematic_core` its branch's four."""
    return DYNAMIC_PARAMETERS + (KINEMATIC_PARAMETERS if car.kinematic_core else ())


def scaled_figures(car: DynamicCar) -> tuple[tuple[str, float, str], ...]:
    """The file's figure each of `DYNAMIC_PARAMETERS` scales, (symbol, value, unit) in their order: what
    an identified scale means for this car."""
    if car.max_acceleration is not None:
        drive = ("a_max", car.max_acceleration, "m/s²")
    else:  # a car with a measured speed table: the scale multiplies the table
        drive = ("v_table", car.table_gain * float(car.table_speed[-1]), "m/s")
    figures = (
        ("μ", car.friction, "-"),
        ("C_f", car.stiffness_front, "N/rad"),
        ("C_r", car.stiffness_rear, "N/rad"),
        drive,
        ("I_z", car.yaw_inertia, "kg m²"),
    )
    if not car.kinematic_core:
        return figures
    # the understeers and the scrub are the figures themselves (a scale times 1), the yaw lag a scale
    branch = (("u", 1.0, "-"), ("s", 1.0, "-"), ("T_w", car.yaw_lag, "s"), ("u_rev", 1.0, "-"))
    return figures + branch


def dynamic_bounds(car: DynamicCar | None = None) -> SimpleNamespace:
    """The parameters' ranges, widths and prior in the form `single_track._map_fit` reads (`car`'s:
    `parameters_of`; None: the five)."""
    parameters = DYNAMIC_PARAMETERS if car is None else parameters_of(car)
    nominal = np.array([p.nominal for p in parameters])
    width = np.array([p.width for p in parameters])
    return SimpleNamespace(
        low=np.array([p.low for p in parameters]),
        high=np.array([p.high for p in parameters]),
        width=width, prior=Identified(nominal, np.diag(width**2)),
    )  # fmt: skip


def scaled(car: DynamicCar, theta: np.ndarray) -> DynamicCar:
    """The car with parameter sets `theta` (P, `parameters_of(car)`) applied: its scaled figures are (P, 1)
    arrays, so a step runs every set against every run at once."""
    t = np.atleast_2d(np.asarray(theta, np.float64))
    return with_scales(car, *(t[:, i : i + 1] for i in range(len(parameters_of(car)))))


def with_scales(car: DynamicCar, friction, front, rear, motor, inertia, *branch) -> DynamicCar:
    """The car with the five `DYNAMIC_PARAMETERS` scales applied, and with `kinematic_core` its branch's
    four (`KINEMATIC_PARAMETERS`, in `branch`): numbers, arrays or tensors that broadcast against the
    runs (one set, or one per parameter set / posterior draw)."""
    if len(branch) != (len(KINEMATIC_PARAMETERS) if car.kinematic_core else 0):
        raise ValueError(f"{5 + len(branch)} scales for a core of {len(parameters_of(car))}")
    mu = friction * car.friction

    def times(value: float | None):
        return None if value is None else motor * value

    extra = {}
    if branch:
        understeer, scrub, yaw_lag, reverse = branch
        extra = {"understeer": understeer, "scrub": scrub, "yaw_lag": yaw_lag * car.yaw_lag,
                 "reverse_understeer": reverse}  # fmt: skip
    return dataclasses.replace(
        car, friction=mu, brake=_minimum(mu * GRAVITY, car.brake),
        stiffness_front=front * car.stiffness_front,
        stiffness_rear=rear * car.stiffness_rear, yaw_inertia=inertia * car.yaw_inertia,
        top_speed=times(car.top_speed), reverse_top_speed=times(car.reverse_top_speed),
        max_acceleration=times(car.max_acceleration), table_gain=motor * car.table_gain, **extra,
    )  # fmt: skip
