"""A vehicle as data: the schema of a vehicle file (`simulator/vehicles/<name>.toml`) and its loader.

Every figure in a vehicle file is a small table `{ value = ..., source = "..." }`: the number in SI
units and where it comes from (a datasheet, a paper, a fit, or a derivation from other figures,
written out). `load_vehicle` validates a file against `VehicleSpec`; a bad file raises
`VehicleFileError` naming the file and the field (`geometry.lf: must be > 0`).

What reads it: the truth simulator builds the car from it (`simulator.build.build_vehicle`), the
physics prior, safety, maneuver scaling, fidelity and `identify` take their figures from it. The
derived quantities every reader needs (wheelbase, axle loads, the linear single track's understeer
gradient, the steady throttle → speed map) are methods here, so they are computed in one place.
"""

from __future__ import annotations

import math
import tomllib
from functools import cached_property
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from simulator.errors import SimulatorError

VEHICLE_DIR = Path(__file__).resolve().parent
GRAVITY = 9.81  # m/s^2, the one constant every car shares
STOPPING_MARGIN = 0.95  # share of the brake or grip limit a live stop counts on where no stop was measured


class VehicleFileError(SimulatorError, ValueError):
    """A vehicle file is missing, unreadable or invalid; `path` and `field` name the offending entry."""

    def __init__(self, path: str | Path, field: str, reason: str) -> None:
        self.path = str(path)
        self.field = field
        self.reason = reason
        super().__init__(f"{path}: {field}: {reason}" if field else f"{path}: {reason}")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


Source = Annotated[str, Field(min_length=3, description="where the number comes from")]


class Figure(_Strict):
    """One number and its source."""

    value: float = Field(allow_inf_nan=False)
    source: Source


class PositiveFigure(Figure):
    """A figure that must be > 0."""

    @field_validator("value")
    @classmethod
    def _positive(cls, value: float) -> float:
        if value <= 0:
            raise ValueError("must be > 0")
        return value


class ShareFigure(Figure):
    """A figure in [0, 1]."""

    @field_validator("value")
    @classmethod
    def _share(cls, value: float) -> float:
        if not 0.0 <= value <= 1.0:
            raise ValueError("must lie in [0, 1]")
        return value


class SpeedTable(_Strict):
    """Steady straight-line speed (m/s) at each throttle (0 … 1, increasing); reverse mirrors it."""

    throttle: list[float]
    speed: list[float]
    source: Source

    @model_validator(mode="after")
    def _check(self) -> SpeedTable:
        t, v = np.asarray(self.throttle, float), np.asarray(self.speed, float)
        if len(t) < 2 or len(t) != len(v):
            raise ValueError("throttle and speed must be lists of the same length (at least 2)")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
            raise ValueError("must be finite")
        if t[0] != 0.0 or t[-1] != 1.0 or np.any(np.diff(t) <= 0):
            raise ValueError("throttle must increase from 0 to 1")
        if v[0] != 0.0 or np.any(np.diff(v) <= 0):
            raise ValueError("speed must start at 0 and increase")
        return self


class TurnTable(_Strict):
    """Steady turn speeds (m/s) of the real car at one throttle and several steering angles (rad)."""

    throttle: float
    steering: list[float]
    speed: list[float]
    source: Source

    @model_validator(mode="after")
    def _check(self) -> TurnTable:
        if not self.steering or len(self.steering) != len(self.speed):
            raise ValueError("steering and speed must be lists of the same length")
        return self


class Geometry(_Strict):
    lf: PositiveFigure = Field(description="CG to front axle (m)")
    lr: PositiveFigure = Field(description="CG to rear axle (m)")
    track: PositiveFigure = Field(description="track width, wheel centre to wheel centre (m)")
    wheel_radius: PositiveFigure = Field(description="tyre rolling radius (m)")
    cg_height: PositiveFigure = Field(description="CG height above the ground (m)")
    length: PositiveFigure = Field(description="body length (m)")
    width: PositiveFigure = Field(description="body width (m)")


class Inertia(_Strict):
    mass: PositiveFigure = Field(description="whole car (kg)")
    yaw_inertia: PositiveFigure = Field(description="about the vertical axis through the CG (kg m^2)")


class Tyres(_Strict):
    friction: PositiveFigure = Field(description="peak tyre-road friction coefficient μ")
    cornering_stiffness_front: PositiveFigure = Field(description="front axle, static load (N/rad)")
    cornering_stiffness_rear: PositiveFigure = Field(description="rear axle, static load (N/rad)")
    shape: PositiveFigure | None = Field(None, description="magic formula shape factor C (tyre-model truth)")
    curvature: Figure | None = Field(None, description="magic formula curvature factor E (≤ 1)")

    @field_validator("curvature")
    @classmethod
    def _curvature(cls, figure: Figure | None) -> Figure | None:
        if figure is not None and figure.value > 1.0:
            raise ValueError("must be <= 1")
        return figure


class Drivetrain(_Strict):
    """Throttle in [-1, 1]: > 0 drives forward, < 0 in reverse, exactly 0 brakes all four wheels."""

    driven: Literal["rear", "front", "all"]
    speed_table: SpeedTable | None = Field(None, description="measured throttle → steady speed map")
    top_speed: PositiveFigure | None = Field(None, description="steady speed at throttle 1 (m/s)")
    reverse_top_speed: PositiveFigure | None = Field(None, description="steady speed at throttle -1 (m/s)")
    max_acceleration: PositiveFigure | None = Field(None, description="from rest at throttle 1 (m/s^2)")
    power_limit_speed: PositiveFigure | None = Field(
        None, description="above it acceleration is power-limited, a ≤ a_max · v_switch / v (m/s)")
    brake_deceleration: PositiveFigure | None = Field(None, description="at throttle 0 (m/s^2)")
    front_drive_share: ShareFigure | None = Field(None, description="share of drive force on the front axle")
    speed_time_constant: PositiveFigure | None = Field(
        None, description="speed's first-order response (s); unset: top_speed / max_acceleration")

    @model_validator(mode="after")
    def _one_map(self) -> Drivetrain:
        motor = (self.top_speed, self.reverse_top_speed, self.max_acceleration, self.power_limit_speed,
                 self.brake_deceleration)
        if self.speed_table is None and any(f is None for f in motor):
            raise ValueError("give speed_table, or the motor law: top_speed, reverse_top_speed, "
                             "max_acceleration, power_limit_speed and brake_deceleration")
        return self


class Steering(_Strict):
    limit: PositiveFigure = Field(description="largest bicycle steering angle (rad)")
    rate: PositiveFigure = Field(description="largest steering rate (rad/s)")
    yaw_time_constant: PositiveFigure | None = Field(
        None, description="yaw rate's first-order response to a steering step (s); unset: the linear "
        "single track's I_z v / (lf² C_f + lr² C_r)")


class Limits(_Strict):
    """Reference operating limits; each defaults to what the other figures imply when absent."""

    max_speed: PositiveFigure | None = Field(None, description="linear velocity limit (m/s)")
    max_yaw_rate: PositiveFigure | None = Field(None, description="angular velocity limit (rad/s)")
    stopping_deceleration: PositiveFigure | None = Field(
        None, description="mean deceleration of a stop at throttle 0, from one log sample after the "
        "command until standing, the lowest measured on the truth (m/s^2); unset: 0.95 x the smaller of "
        "brake_deceleration and friction x g")


class Sensors(_Strict):
    """The logs' rate and the sensors' noise (standard deviations; unset: the simulator's defaults)."""

    log_rate_hz: PositiveFigure = Field(description="rate of the logs (Hz)")
    encoder_cpr: PositiveFigure = Field(description="wheel encoder counts per revolution")
    speed_noise: PositiveFigure | None = Field(None, description="forward speed (m/s)")
    yaw_rate_noise: PositiveFigure | None = Field(None, description="each gyro axis (rad/s)")
    acceleration_noise: PositiveFigure | None = Field(None, description="each accelerometer axis (m/s^2)")
    position_noise: PositiveFigure | None = Field(None, description="posX, posY, posZ (m)")
    angle_noise: PositiveFigure | None = Field(None, description="roll, pitch, yaw (rad)")


class MujocoContacts(_Strict):
    """The car is an MJCF model whose tyres are MuJoCo's soft contacts (Nigel: slow enough for them)."""

    engine: Literal["mujoco-contacts"]
    model: str = Field(description="MJCF file, relative to the vehicle file")
    wheel_mass: PositiveFigure = Field(description="one wheel with its tyre (kg); the chassis has the rest")
    wheel_yaw_inertia: PositiveFigure = Field(description="one wheel about its vertical axis (kg m^2)")
    reference_turns: TurnTable | None = Field(None, description="steady turn speeds the MJCF was fitted to")


class MujocoTyres(_Strict):
    """MuJoCo integrates a rigid car on frictionless wheels; a magic-formula tyre applies the forces."""

    engine: Literal["mujoco-tyres"]
    timestep: PositiveFigure = Field(description="physics step (s); the log rate must divide its rate")
    tyre_fade_speed: PositiveFigure = Field(description="below it slip angles use this speed (m/s)")


class VehicleSpec(_Strict):
    """One car: every figure with its source, and the truth model that simulates it."""

    name: str = Field(pattern=r"^[a-z0-9_]+$")
    title: str
    scale: str = Field(description="e.g. 1:14, 1:10, full size")
    geometry: Geometry
    inertia: Inertia
    tyres: Tyres
    drivetrain: Drivetrain
    steering: Steering
    limits: Limits = Limits()
    sensors: Sensors
    truth: MujocoContacts | MujocoTyres = Field(discriminator="engine")
    path: Path | None = Field(None, exclude=True, description="the file it was read from")

    @model_validator(mode="after")
    def _tyre_truth_needs_shape(self) -> VehicleSpec:
        if self.truth.engine == "mujoco-tyres":
            if self.tyres.shape is None or self.tyres.curvature is None:
                raise ValueError("truth.engine 'mujoco-tyres' needs tyres.shape and tyres.curvature")
            if self.drivetrain.top_speed is None:
                raise ValueError("drivetrain's motor law is required by truth.engine = 'mujoco-tyres'")
        return self

    # ---- derived quantities (one place) -------------------------------------------------------
    @property
    def wheelbase(self) -> float:
        """lf + lr (m)."""
        return self.geometry.lf.value + self.geometry.lr.value

    def axle_loads(self) -> tuple[float, float]:
        """Static front and rear axle loads (N)."""
        m, g, L = self.inertia.mass.value, GRAVITY, self.wheelbase
        return m * g * self.geometry.lr.value / L, m * g * self.geometry.lf.value / L

    def understeer_gradient(self) -> float:
        """The linear single track's understeer gradient K (rad per m/s²): δ = L/R + K·a_y."""
        m, L = self.inertia.mass.value, self.wheelbase
        lf, lr = self.geometry.lf.value, self.geometry.lr.value
        front, rear = self.tyres.cornering_stiffness_front.value, self.tyres.cornering_stiffness_rear.value
        return m / L * (lr / front - lf / rear)

    def linear_yaw_gain(self, speed: np.ndarray | float) -> np.ndarray:
        """Steady yaw-rate gain r/δ (1/s) of the linear single track at forward speed v: v / (L + K v²)."""
        v = np.asarray(speed, float)
        return v / (self.wheelbase + self.understeer_gradient() * v * v)

    @cached_property
    def speed_map(self) -> tuple[np.ndarray, np.ndarray]:
        """Throttle grid (0 … 1) and steady straight-line speed (m/s): the file's table or the motor law's."""
        d = self.drivetrain
        if d.speed_table is not None:
            return np.asarray(d.speed_table.throttle, float), np.asarray(d.speed_table.speed, float)
        throttle = np.round(np.linspace(0.0, 1.0, 11), 1)
        return throttle, throttle * d.top_speed.value  # the motor law's force vanishes at u · v_top

    def steady_speed(self, throttle: np.ndarray | float) -> np.ndarray:
        """Steady straight-line speed (m/s) for throttle in [-1, 1]; reverse mirrors it, scaled."""
        u = np.asarray(throttle, float)
        grid, speed = self.speed_map
        forward = np.interp(np.abs(u), grid, speed)
        d = self.drivetrain
        if d.reverse_top_speed is not None and d.top_speed is not None:
            reverse = forward * (d.reverse_top_speed.value / d.top_speed.value)
        else:
            reverse = forward
        return np.where(u < 0, -reverse, forward)

    @property
    def max_speed(self) -> float:
        """Linear velocity limit (m/s): the file's, else the top speed."""
        if self.limits.max_speed is not None:
            return self.limits.max_speed.value
        return float(self.speed_map[1][-1])

    @property
    def max_yaw_rate(self) -> float:
        """Angular velocity limit (rad/s): the file's, else the largest of min(v tan δ_max / L, μ g / v)."""
        if self.limits.max_yaw_rate is not None:
            return self.limits.max_yaw_rate.value
        kinematic = math.tan(self.steering.limit.value) / self.wheelbase
        grip = self.tyres.friction.value * GRAVITY
        crossing = math.sqrt(grip / kinematic)  # speed where the two limits meet
        return float(min(self.max_speed, crossing) * kinematic)

    @property
    def stopping_deceleration(self) -> float | None:
        """Deceleration (m/s²) a live stop may count on: the file's measured figure, else 0.95 × the
        smaller of the brake's and the grip's (the shipped tyre cars stop within 0.1 % of that
        smaller one in MuJoCo), else None (a speed-table car with no brake figure)."""
        if self.limits.stopping_deceleration is not None:
            return self.limits.stopping_deceleration.value
        brake = self.drivetrain.brake_deceleration
        if brake is None:
            return None
        return STOPPING_MARGIN * min(brake.value, self.tyres.friction.value * GRAVITY)

    @property
    def log_rate_hz(self) -> float:
        return self.sensors.log_rate_hz.value

    def figures(self) -> dict[str, tuple[float, str]]:
        """Every scalar figure as 'section.field' → (value, source), for tables and the docs."""
        out: dict[str, tuple[float, str]] = {}
        sections = ("geometry", "inertia", "tyres", "drivetrain", "steering", "limits", "sensors", "truth")
        for section in sections:
            block = getattr(self, section)
            for name in type(block).model_fields:
                item = getattr(block, name)
                if isinstance(item, Figure):
                    out[f"{section}.{name}"] = (item.value, item.source)
        return out

    def truth_file(self) -> Path:
        """The MJCF file of a 'mujoco-contacts' truth, resolved beside the vehicle file."""
        if not isinstance(self.truth, MujocoContacts):
            raise VehicleFileError(self.path or self.name, "truth.model", "only 'mujoco-contacts' has one")
        base = self.path.parent if self.path is not None else VEHICLE_DIR
        return (base / self.truth.model).resolve()


def shipped_vehicles() -> tuple[str, ...]:
    """Names of the vehicle files that ship with the simulator."""
    return tuple(sorted(p.stem for p in VEHICLE_DIR.glob("*.toml")))


def vehicle_path(name_or_path: str | Path) -> Path:
    """The file of a shipped name (`nigel`) or a path to a vehicle file."""
    text = str(name_or_path)
    if text in shipped_vehicles():
        return VEHICLE_DIR / f"{text}.toml"
    path = Path(text)
    if path.suffix != ".toml" and not path.exists():
        shipped = ", ".join(shipped_vehicles())
        raise VehicleFileError(text, "", f"no such vehicle; shipped: {shipped}, or a path to a .toml file")
    return path


_CACHE: dict[tuple[str, int, int], VehicleSpec] = {}


def load_vehicle(name_or_path: str | Path = "nigel") -> VehicleSpec:
    """Read and validate a vehicle file (a shipped name or a path); cached by path, size and mtime."""
    if isinstance(name_or_path, VehicleSpec):
        return name_or_path
    path = vehicle_path(name_or_path)
    try:
        stat = path.stat()
    except OSError as exc:
        raise VehicleFileError(path, "", f"cannot read: {exc.strerror or exc}") from None
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key in _CACHE:
        return _CACHE[key]
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise VehicleFileError(path, "", f"cannot read: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise VehicleFileError(path, "", f"not valid TOML: {exc}") from None
    try:
        spec = VehicleSpec.model_validate({**raw, "path": path})
    except ValidationError as exc:
        error = exc.errors()[0]
        loc = [str(part) for part in error["loc"] if not str(part).startswith(("mujoco-", "function-"))]
        field = ".".join(loc)
        raise VehicleFileError(path, field, error["msg"].removeprefix("Value error, ")) from None
    _CACHE[key] = spec
    return spec
