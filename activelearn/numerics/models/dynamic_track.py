"""The dynamic single track of a car's vehicle file: a bicycle with tyre slip, saturating tyres and load
transfer, blended into the kinematic model at low speed. Issue 56's core: the physics kind's under
`core = "dynamic"` (`dynamic_physics`), and with the file's values and no data `bench_vehicle_baselines.py`'s
"dynamic file" row.

State (v_x, v_y, r, δ_w) at the CG: forward and lateral speed, yaw rate, the front wheels' bicycle angle
(it follows the commanded steering at the file's rate, within its lock). Controls: throttle τ, steering δ.

- Longitudinal, the file's drivetrain: a motor law a = a_max (τ − v_x / v_top) (reverse mirrored), within
  a_max and the power limit a_max v_switch / |v_x|; or, for a car with a measured speed table (Nigel), a
  first-order lag to the table's speed, a = (v_table(τ) − v_x) / T_v. τ = 0 brakes. |a| ≤ μ g.
- Loads with longitudinal transfer: F_zf = m (g l_r − a h) / L, F_zr = m (g l_f + a h) / L.
- Tyres per axle, the simplified magic formula F_y = μ F_z sin(C atan(Bα − E(Bα − atan Bα))) with B from
  the file's cornering stiffness per unit static load (B C μ = C_α / F_z,static: the slope at α = 0 is the
  file's), or where the file gives no shape (Nigel) the linear tyre C_α (F_z / F_z,static) α capped at
  μ F_z; the drive's longitudinal force takes its share of the driven axle's friction circle.
- Slip angles from each axle's velocity in its wheel frame, the forward speed floored at half the blend
  speed (a tyre is a lateral damper near rest, as in the truth).
- With `wheel_forces` (`[model] wheel_forces`), the forces of four wheels on these states instead: each
  wheel's load is its axle's half ± m a_y h / (2 t) (the lateral transfer of a rigid chassis on four
  equal contacts, t the track); it asks for its share of m a (the drive's, halved left and right, or the
  brake's by load) and for its axle's pure-slip F_y per newton times its load; where the two exceed μ F_z
  both are scaled back onto the circle, their direction kept (Kamm's circle). a_x, a_y are the sums of
  those forces over m, the loads taken from them in `wheel_passes` fixed-point passes; the yaw moment
  adds t/2 times the wheels' unequal forces (F_x right − left, and the front F_y's turn with δ_w). The
  blend below weighs the speed over ground √(v_x² + v_y²), so a car sliding sideways keeps spinning.
- v̇_x = a − F_yf sin δ_w / m + v_y r,  v̇_y = (F_yf cos δ_w + F_yr) / m − v_x r,
  ṙ = (l_f F_yf cos δ_w − l_r F_yr) / I_z.
- Below the blend speed v_b = ½ √(g L) (`blend_share` √(g L)) the state is pulled to the kinematic one
  (r = v_x tan δ_w / L, v_y = l_r r) with weight 1 − w, w = ½ (1 + tanh((|v_x| − v_b) / (v_b / 4))): Nigel's
  whole range sits in it (v_b 0.59 m/s, top speed 0.27), the 1:10 car's (0.90 m/s) and the full-size car's
  (2.5 m/s) do not.
  With `kinematic_core` (`[model] kinematic_blend = "core"`) the kinematic state is the kinematic core's:
  r_kin follows v_x tan δ_w / (L u) with the lag T_w (u the understeer, its own in reverse), and v_x's
  terms from the tyres and the body frame's turn (−F_yf sin δ_w / m + v_y r, which at the kinematic state
  no tyre force balances) weigh w, the scrub's drag s tan² δ_w v_x / T_v (steady: v / (1 + s tan² δ_w),
  T_v the drive's lag) 1 − w: on Nigel the identified core then follows the kinematic one
  (`experiments/investigations/nigel_blend.py`).
- Explicit substeps within each log step, as many as keep the lateral and yaw modes stable at the slip
  floor (each substep at most their time constant m v / (C_f + C_r), I_z v / (l_f² C_f + l_r² C_r)).
  The physics kind's implicit step instead damps v_y and r exponentially at the tyres' linear stiffness
  C_f, C_r, or with `tangent_damping` (`[model] tyre_damping = "tangent"`) at each axle's local slope
  ∂F_y/∂α at its slip angle, 0 past the peak: a saturated tyre damps nothing, and the step follows a spin
  at the limit (`experiments/investigations/limit_core_numerics.py`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from activelearn.numerics import native
from activelearn.numerics.models.base import kernels_for
from activelearn.numerics.models.single_track import car_parameters
from simulator.vehicles import GRAVITY, VehicleSpec

BLEND_SHARE = 0.5  # the blend speed, a share of √(g L)
# With the tyres' damping exponential, substeps of at most 25 ms (4 per 0.1-s model step, 2 per 30-Hz
# log step): identified on a campaign's 16 logs of the 1:10 car, the core's own 0.1-s free runs end the
# test set 1.53 m off at 30 s (50-ms substeps: 2.69, its yaw inertia biased to 0.93; 8-ms: 1.37).
IMPLICIT_SUBSTEP = 0.025


# `combined_slip`: the share of an axle's friction circle its lateral force keeps at a grip-limited stop
ROOM_FLOOR = 1e-3
# `wheel_forces`: fixed-point passes of the wheels' loads on the accelerations their forces give (from the
# demand and v_x r: one pass lets the full-size car's near-limit turns ring, 2-3 follow the truth's; a spin
# needs 5, `[model] wheel_passes`), each count a variant of the C kernel; and the least resultant a friction
# circle divides by
WHEEL_PASSES = 3
WHEEL_PASS_CHOICES = (3, 5)
TINY = 1e-30


@dataclass(frozen=True)
class DynamicCar:
    """The dynamic single track's figures of one car (`of(spec)` reads a vehicle file)."""

    mass: float
    yaw_inertia: float
    lf: float
    lr: float
    cg_height: float
    friction: float
    stiffness_front: float  # N/rad per axle at static load
    stiffness_rear: float
    shape: float | None  # magic formula C; None: the linear tyre capped at μ F_z
    curvature: float
    steering_limit: float
    steering_rate: float
    rear_drive_share: float
    brake: float  # m/s²
    # drivetrain: the motor law (top speeds, a_max, v_switch) or the speed table and its lag
    top_speed: float | None
    reverse_top_speed: float | None
    max_acceleration: float | None
    power_limit_speed: float | None
    table_throttle: np.ndarray
    table_speed: np.ndarray
    speed_time_constant: float
    table_gain: float = 1.0  # a scale of the speed table (identification's drive scale, table cars)
    # each axle's lateral force within what its share of the longitudinal force leaves of its friction
    # circle: the drive's shares under throttle, the brake's by load at throttle 0 (False: the rear
    # axle's drive share alone, the core before it; `[model] combined_slip`)
    combined_slip: bool = False
    # the forces of four wheels on the single track's states (`[model] wheel_forces`, `_wheel_forces`):
    # each wheel's load with longitudinal and lateral transfer, its own friction circle, the yaw moment
    # of unequal wheel forces; the kinematic blend weighed by the speed over ground
    wheel_forces: bool = False
    track: float = 0.0  # m, the wheels' lateral spacing (the file's mean track)
    # the implicit step's tyre damping at each axle's local slope ∂F_y/∂α, not its cornering stiffness
    # (`[model] tyre_damping = "tangent"`)
    tangent_damping: bool = False
    wheel_passes: int = WHEEL_PASSES  # with `wheel_forces`, the loads' passes (`[model] wheel_passes`)
    blend_share: float = BLEND_SHARE  # the kinematic blend's speed over √(g L) (`[model] blend_share`)
    # below the blend speed the kinematic core's turn and scrub (`[model] kinematic_blend = "core"`): its
    # understeer (forward, reverse), scrub and yaw lag (s); numbers, or arrays / tensors of parameter sets
    kinematic_core: bool = False
    understeer: float = 1.0
    reverse_understeer: float = 1.0
    scrub: float = 0.0
    yaw_lag: float = 0.05

    @classmethod
    def of(cls, spec: VehicleSpec, tire_friction: float = 1.0, motor_gain: float = 1.0) -> DynamicCar:
        """The file's figures (`tire_friction`, `motor_gain`: the twin's scales, for what-ifs)."""
        d, t, g = spec.drivetrain, spec.tyres, spec.geometry
        grip = t.friction.value * tire_friction * GRAVITY
        brake = grip if d.brake_deceleration is None else min(d.brake_deceleration.value, grip)
        share = 1.0 if d.driven == "rear" else 0.0 if d.driven == "front" else 0.5
        if d.front_drive_share is not None:
            share = 1.0 - d.front_drive_share.value
        grid, speed = spec.speed_map
        motor = d.top_speed is not None and d.max_acceleration is not None
        lag = d.speed_time_constant.value if d.speed_time_constant is not None else (
            d.top_speed.value / d.max_acceleration.value if motor else 0.1)  # type: ignore[union-attr]
        def value(figure, scale: float = 1.0) -> float | None:
            return None if figure is None else figure.value * scale

        return cls(
            mass=spec.inertia.mass.value, yaw_inertia=spec.inertia.yaw_inertia.value, lf=g.lf.value,
            lr=g.lr.value, cg_height=g.cg_height.value, friction=t.friction.value * tire_friction,
            stiffness_front=t.cornering_stiffness_front.value,
            stiffness_rear=t.cornering_stiffness_rear.value,
            shape=value(t.shape), curvature=value(t.curvature) or 0.0,
            steering_limit=spec.steering.limit.value, steering_rate=spec.steering.rate.value,
            rear_drive_share=share, brake=brake, top_speed=value(d.top_speed, motor_gain),
            reverse_top_speed=value(d.reverse_top_speed, motor_gain),
            max_acceleration=value(d.max_acceleration, motor_gain),
            power_limit_speed=value(d.power_limit_speed),
            table_throttle=np.asarray(grid, float), table_speed=np.asarray(speed, float) * motor_gain,
            speed_time_constant=lag, track=g.track.value, yaw_lag=_kinematic_yaw_lag(spec),
        )  # fmt: skip

    @property
    def wheelbase(self) -> float:
        return self.lf + self.lr

    @property
    def static_loads(self) -> tuple[float, float]:
        """The front and rear axles' loads at rest, N (m g l_r / L, m g l_f / L)."""
        m, L = self.mass, self.wheelbase
        return m * GRAVITY * self.lr / L, m * GRAVITY * self.lf / L

    @property
    def blend_speed(self) -> float:
        """Below it the state is pulled to the kinematic one (`blend_share` × √(g L), ½ by default)."""
        return self.blend_share * math.sqrt(GRAVITY * self.wheelbase)

    def implicit_substeps(self, dt: float) -> int:
        """Substeps per `dt` of the step with exponential tyre damping (`dynamic_step(implicit=True)`):
        stable at any length, so only accuracy binds them; `IMPLICIT_SUBSTEP` s each at most."""
        return max(1, math.ceil(dt / IMPLICIT_SUBSTEP - 1e-9))

    def substeps(self, dt: float) -> int:
        """Explicit substeps per `dt` that keep the lateral and yaw modes stable at the slip floor."""
        floor = 0.5 * self.blend_speed
        figures = (self.stiffness_front, self.stiffness_rear, self.yaw_inertia)
        c_f, c_r, inertia = (_numbers(v) for v in figures)
        lateral = np.min(self.mass * floor / (c_f + c_r))  # the stiffest of a batch of parameter sets
        yaw = np.min(inertia * floor / (self.lf**2 * c_f + self.lr**2 * c_r))
        return max(1, math.ceil(dt / min(float(lateral), float(yaw))))


def _kinematic_yaw_lag(spec: VehicleSpec) -> float:
    """The kinematic core's prior yaw lag of a car (s, `single_track.car_parameters`): the kinematic
    branch's (`kinematic_core`) before any log."""
    return next(p.nominal for p in car_parameters(spec) if p.name == "yaw_lag")


def _numbers(value) -> np.ndarray:
    """A figure (a number, an array or a tensor of parameter sets) as a NumPy array."""
    return value.detach().numpy() if isinstance(value, Tensor) else np.asarray(value)


def _namespace(a):
    """torch for tensors, NumPy for arrays: the step runs in both (training and free runs in torch,
    identification in NumPy)."""
    return torch if isinstance(a, Tensor) else np


def _like(x, value):
    """`value` (a number, array or tensor) as x's kind: torch's binary functions take tensors only."""
    return torch.as_tensor(value, dtype=x.dtype) if isinstance(x, Tensor) else value


def _maximum(a, b):
    return torch.maximum(a, _like(a, b)) if isinstance(a, Tensor) else np.maximum(a, b)


def _minimum(a, b):
    return torch.minimum(a, _like(a, b)) if isinstance(a, Tensor) else np.minimum(a, b)


def _clip(x, low, high):
    return _minimum(_maximum(x, low), high)


def _where(condition, a, b):
    if isinstance(condition, Tensor):
        return torch.where(condition, *(v if isinstance(v, Tensor) else float(v) for v in (a, b)))
    return np.where(condition, a, b)


def _table(car: DynamicCar, throttle):
    """The speed table at |τ| (m/s), linear between its points."""
    if not isinstance(throttle, Tensor):
        return np.interp(np.abs(throttle), car.table_throttle, car.table_speed)
    grid = torch.as_tensor(car.table_throttle, dtype=throttle.dtype)
    speed = torch.as_tensor(car.table_speed, dtype=throttle.dtype)
    x = torch.minimum(torch.maximum(throttle.abs(), grid[0]), grid[-1])  # tensors: no graph break
    i = (torch.searchsorted(grid, x.contiguous(), right=True) - 1).clamp(0, len(grid) - 2)
    share = (x - grid[i]) / (grid[i + 1] - grid[i])
    return speed[i] + share * (speed[i + 1] - speed[i])


def _acceleration(car: DynamicCar, throttle, vx, dt: float):
    """Longitudinal acceleration (m/s²) from the drivetrain or the brake, within μ g."""
    grip = car.friction * GRAVITY
    return _clip(_demand(car, throttle, vx, dt), -grip, grip)


def _demand(car: DynamicCar, throttle, vx, dt: float):
    """The longitudinal acceleration (m/s²) the drivetrain or the brake asks for."""
    xp = _namespace(vx)
    if car.top_speed is not None and car.max_acceleration is not None:
        top = _where(throttle > 0, car.top_speed, car.reverse_top_speed)
        a_max = car.max_acceleration
        limit = a_max * car.power_limit_speed / _maximum(xp.abs(vx), car.power_limit_speed)  # type: ignore[operator]
        drive = _clip(a_max * (throttle - vx / top), -limit, limit)
    else:
        target = xp.sign(throttle) * _table(car, throttle)
        drive = (target * car.table_gain - vx) / car.speed_time_constant
    stop = -xp.sign(vx) * _minimum(xp.abs(vx) / dt, car.brake)  # brakes to rest, not past it
    return _where(throttle == 0.0, stop, drive)


def _lateral_force(car: DynamicCar, alpha, load, static: float, stiffness):
    """An axle's lateral force (N) at slip angle α and load F_z."""
    xp = _namespace(alpha)
    cap = car.friction * load
    if car.shape is None:
        return _clip(stiffness * load / static * alpha, -cap, cap)
    return cap * xp.sin(car.shape * xp.arctan(_magic_argument(car, alpha, static, stiffness)[1]))


def _magic_argument(car: DynamicCar, alpha, static: float, stiffness) -> tuple:
    """The simplified magic formula's B α and its argument φ = B α − E (B α − atan B α) at slip angle α
    (B C μ = the cornering stiffness per unit static load)."""
    x = stiffness / static / (car.shape * car.friction) * alpha
    if not car.curvature:
        return x, x
    return x, x - car.curvature * (x - _namespace(alpha).arctan(x))


def dynamic_step(
    car: DynamicCar, state, throttle, steering, dt: float, substeps: int | None = None, implicit: bool = False
):
    """The state (..., 4) = (v_x, v_y, r, δ_w) after `dt` s of the controls, in `car.substeps(dt)` steps
    (or `substeps`). NumPy arrays (float64) or tensors (their dtype), not mixed."""
    xp = _namespace(state)
    n = car.substeps(dt) if substeps is None else substeps
    h = dt / n
    if xp is np:
        state = state.astype(np.float64)
    vx, vy, r, delta = state[..., 0], state[..., 1], state[..., 2], state[..., 3]
    m, L, g = car.mass, car.wheelbase, GRAVITY
    static_f, static_r = car.static_loads
    target = _clip(steering, -car.steering_limit, car.steering_limit)
    if car.kinematic_core and car.wheel_forces:
        raise ValueError("kinematic_core: the kinematic branch is the axles' step's, not wheel_forces'")
    for _ in range(n):
        delta = delta + _clip(target - delta, -car.steering_rate * h, car.steering_rate * h)
        if car.wheel_forces:
            vx, vy, r = _wheel_substep(car, (vx, vy, r, delta), throttle, h, implicit)
            continue
        a = _acceleration(car, throttle, vx, h)
        load_f = _maximum(m * (g * car.lr - a * car.cg_height) / L, 0.0)
        load_r = _maximum(m * (g * car.lf + a * car.cg_height) / L, 0.0)
        cos, sin = xp.cos(delta), xp.sin(delta)
        alpha_f, alpha_r = _slip_angles(car, vx, vy, r, (cos, sin))
        slopes = _damping_slopes(car, alpha_f, alpha_r) if implicit else None
        f_f = _lateral_force(car, alpha_f, load_f, static_f, car.stiffness_front)
        f_r = _lateral_force(car, alpha_r, load_r, static_r, car.stiffness_rear)
        if car.combined_slip:  # the longitudinal force's share of each axle's friction circle; at a
            # grip-limited stop a share is its axle's whole circle, where the root's slope is infinite:
            # the room keeps ROOM_FLOOR of the circle, so rounding is not magnified there
            braking, by_load = _where(throttle == 0.0, 1.0, 0.0), load_r / (load_f + load_r)  # sum >= m g
            share_r = car.rear_drive_share + braking * (by_load - car.rear_drive_share)  # as the C kernel
            drive_r, drive_f = xp.abs(m * a * share_r), xp.abs(m * a * (1.0 - share_r))
            cap_r, cap_f = car.friction * load_r, car.friction * load_f
            room = xp.sqrt(_maximum((cap_r - drive_r) * (cap_r + drive_r), (ROOM_FLOOR * cap_r) ** 2))
            room_f = xp.sqrt(_maximum((cap_f - drive_f) * (cap_f + drive_f), (ROOM_FLOOR * cap_f) ** 2))
            f_f = _clip(f_f, -room_f, room_f)
        else:  # the drive's share of the rear axle's friction circle
            drive_r = m * a * car.rear_drive_share
            room = xp.sqrt(_maximum((car.friction * load_r) ** 2 - drive_r**2, 0.0))
        f_r = _clip(f_r, -room, room)
        dvx = a - f_f * sin / m
        dvy = (f_f * cos + f_r) / m
        dr = (car.lf * f_f * cos - car.lr * f_r) / car.yaw_inertia
        rates = (dvx, dvy, dr)
        drive = (a, _inverse_lag(car, throttle)) if car.kinematic_core else None
        vx, vy, r = _advance(car, (vx, vy, r), rates, (load_f, load_r), delta, h, implicit, False, slopes,
                             drive)  # fmt: skip
    parts = xp.broadcast_arrays(vx, vy, r, delta) if xp is np else torch.broadcast_tensors(vx, vy, r, delta)
    return xp.stack(parts, axis=-1) if xp is np else torch.stack(parts, dim=-1)  # δ_w: no parameter axis


def _wheel_substep(car: DynamicCar, state: tuple, throttle, h: float, implicit: bool) -> tuple:
    """(v_x, v_y, r) after a substep of `h` s under the forces of four wheels (`_wheel_forces`), δ_w
    already moved; the kinematic blend weighed by the speed over ground, so that a car sliding sideways
    at a low forward speed keeps spinning."""
    vx, vy, r, delta = state
    xp = _namespace(vx)
    static_f, static_r = car.static_loads
    cos, sin = xp.cos(delta), xp.sin(delta)
    alpha_f, alpha_r = _slip_angles(car, vx, vy, r, (cos, sin))
    unit = (_lateral_force(car, alpha_f, static_f, static_f, car.stiffness_front) / static_f,
            _lateral_force(car, alpha_r, static_r, static_r, car.stiffness_rear) / static_r)  # fmt: skip
    ax, ay, (x_f, y_f, y_r), moment, (load_f, load_r) = _wheel_forces(
        car, _demand(car, throttle, vx, h), throttle == 0.0, unit, vx * r, (cos, sin)
    )
    dr = (car.lf * (y_f * cos + x_f * sin) - car.lr * y_r + moment) / car.yaw_inertia
    slopes = _damping_slopes(car, alpha_f, alpha_r) if implicit else None
    return _advance(car, (vx, vy, r), (ax, ay, dr), (load_f, load_r), delta, h, implicit, True, slopes)


def _slip_angles(car: DynamicCar, vx, vy, r, turn: tuple) -> tuple:
    """Each axle's slip angle from its velocity in its wheel frame (`turn` = (cos δ_w, sin δ_w)), the
    forward speed floored at half the blend speed (a tyre is a lateral damper near rest)."""
    xp = _namespace(vx)
    cos, sin = turn
    floor = 0.5 * car.blend_speed
    front_y = vy + car.lf * r  # the front axle's velocity, body frame, then in the wheel's
    long_f, lat_f = vx * cos + front_y * sin, front_y * cos - vx * sin
    alpha_f = xp.arctan(-lat_f / _maximum(xp.abs(long_f), floor))
    return alpha_f, xp.arctan(-(vy - car.lr * r) / _maximum(xp.abs(vx), floor))


def _damping_slopes(car: DynamicCar, alpha_f, alpha_r) -> tuple | None:
    """Each axle's ∂(F_y / F_z)/∂α at its slip angle for the implicit step's damping (N/rad per newton
    of load, at least 0): the linear tyre's stiffness within its cap, the magic formula's
    k cos(C atan φ) φ' / (1 + φ²) (k = B C μ, the slope at α = 0); None without `tangent_damping`."""
    if not car.tangent_damping:
        return None
    xp = _namespace(alpha_f)
    out = []
    for alpha, static, stiffness in zip((alpha_f, alpha_r), car.static_loads,
                                        (car.stiffness_front, car.stiffness_rear), strict=True):
        k = stiffness / static
        if car.shape is None:
            out.append(_where(xp.abs(k * alpha) < car.friction, k * xp.ones_like(alpha), 0.0))
            continue
        x, phi = _magic_argument(car, alpha, static, stiffness)
        dphi = 1.0 - car.curvature + car.curvature / (1.0 + x * x) if car.curvature else 1.0
        out.append(_maximum(k * xp.cos(car.shape * xp.arctan(phi)) / (1.0 + phi * phi) * dphi, 0.0))
    return tuple(out)


def _inverse_lag(car: DynamicCar, throttle):
    """1 / the drive's time constant (1/s): the speed table's lag, or the motor law's a_max / v_top (in
    reverse its reverse top speed)."""
    if car.top_speed is not None and car.max_acceleration is not None:
        return car.max_acceleration / _where(throttle > 0, car.top_speed, car.reverse_top_speed)
    return 1.0 / car.speed_time_constant


def _blend_weight(car: DynamicCar, speed):
    """w = ½ (1 + tanh((speed − v_b) / (v_b / 4))): 1 dynamic, 0 kinematic."""
    blend = car.blend_speed
    return 0.5 * (1.0 + _namespace(speed).tanh((speed - blend) / (0.25 * blend)))


def _advance(car: DynamicCar, state: tuple, rates: tuple, loads: tuple, delta, h: float, implicit: bool,
             ground: bool, slopes: tuple | None = None, drive: tuple | None = None) -> tuple:  # fmt: skip
    """(v_x, v_y, r) after `h` s of their rates of change (the forces over m and I_z, without the body
    frame's turn) at the axles' `loads`, then blended into the kinematic state below the blend speed,
    weighed by |v_x| or, with `ground`, by the speed over ground. `slopes`: the axles' damping slopes
    per newton of load (`_damping_slopes`), else their cornering stiffness. `drive`: with
    `kinematic_core`, the drive's acceleration in `dvx` and 1 / its time constant (`_inverse_lag`)."""
    (vx, vy, r), (dvx, dvy, dr), (load_f, load_r) = state, rates, loads
    xp = _namespace(vx)
    m, L, blend = car.mass, car.wheelbase, car.blend_speed
    static_f, static_r = car.static_loads
    vx0, vy0, r0 = vx, vy, r

    def speed_of(vx, vy):  # what the blend weighs
        return xp.sqrt(vx * vx + vy * vy) if ground else xp.abs(vx)

    def forward(turn):  # v_x's rate with the body frame's `turn` (v_y r)
        if drive is None:
            return dvx + turn
        a, inverse_lag = drive  # the tyres' and turn's terms weigh w at the substep's start, the scrub 1 − w
        w0 = _blend_weight(car, speed_of(vx0, vy0))
        scrub = car.scrub * xp.tan(delta) ** 2 * vx0 * inverse_lag
        return a + w0 * ((dvx - a) + turn) - (1.0 - w0) * scrub

    if implicit:
        # The tyres' damping of v_y and r exponential (stable at any substep), and the body
        # frame's turn of the velocity semi-implicit, v_x from the new v_y (an explicit turn adds
        # speed in a spin, √(1 + (r h)²) a substep). The steady states are the explicit step's.
        speed = _maximum(xp.abs(vx), 0.5 * blend)
        if slopes is None:
            c_f, c_r = car.stiffness_front * load_f / static_f, car.stiffness_rear * load_r / static_r
            x_lat = h * (c_f + c_r) / (m * speed)
            x_yaw = h * (car.lf**2 * c_f + car.lr**2 * c_r) / (car.yaw_inertia * speed)
        else:  # a saturated tyre damps nothing: the share floored where (1 − e^−x) / x is 0 / 0
            c_f, c_r = slopes[0] * load_f, slopes[1] * load_r
            x_lat = _maximum(h * (c_f + c_r) / (m * speed), TINY)
            x_yaw = _maximum(h * (car.lf**2 * c_f + car.lr**2 * c_r) / (car.yaw_inertia * speed), TINY)
        vy = vy + h * (dvy - vx * r) * _relaxed(x_lat)
        vx = vx + h * forward(vy * r)
        r = r + h * dr * _relaxed(x_yaw)
    else:
        vx, vy, r = vx + h * forward(vy * r), vy + h * (dvy - vx * r), r + h * dr
    w = _blend_weight(car, speed_of(vx, vy))  # 1: dynamic, 0: kinematic
    if car.kinematic_core:  # the kinematic core's turn, reached with its yaw lag from the substep's start
        understeer = _where(vx >= 0.0, car.understeer, car.reverse_understeer)
        follow = -xp.expm1(_like(vx, -h / car.yaw_lag))
        r_kin = r0 + follow * (vx * xp.tan(delta) / (L * understeer) - r0)
    else:
        r_kin = vx * xp.tan(delta) / L
    return vx, w * vy + (1.0 - w) * car.lr * r_kin, w * r + (1.0 - w) * r_kin


def _wheel_forces(car: DynamicCar, demand, braking, unit: tuple, lateral, turn: tuple) -> tuple:
    """The forces of four wheels on the single track: (a_x, a_y) in the body frame, the front axle's
    longitudinal and lateral force and the rear's lateral one (wheel frames), the yaw moment of the
    wheels' unequal forces, and the axles' loads.

    Each wheel's load: its axle's (longitudinal transfer) shared left and right with the lateral
    transfer of a rigid body on four equal contacts, m a_y h / (2 t) a wheel on either axle (what the
    truth's MuJoCo chassis gives). Each wheel asks for its share of m `demand` (the drive's shares
    under throttle, the brake's by load at throttle 0) and for its axle's lateral force per newton of
    load (`unit`, pure slip) times its load; where the two exceed μ F_z both are scaled back onto the
    circle, their direction kept (Kamm's circle, as the truth's tyres). The loads follow the
    accelerations those forces give: `car.wheel_passes` fixed-point passes from the demand within μ g and
    the state's v_x r (`lateral`). `turn` = (cos δ_w, sin δ_w)."""
    xp = _namespace(demand)
    m, L, g, height, half = car.mass, car.wheelbase, GRAVITY, car.cg_height, 0.5 * car.track
    cos, sin = turn
    grip = car.friction * g
    ax, ay = _clip(demand, -grip, grip), lateral
    drive = (m * demand * 0.5 * (1.0 - car.rear_drive_share), m * demand * 0.5 * car.rear_drive_share)
    for _ in range(car.wheel_passes):
        load_f = _maximum(m * (g * car.lr - ax * height) / L, 0.0)
        load_r = _maximum(m * (g * car.lf + ax * height) / L, 0.0)
        shift = m * ay * height / (4.0 * half)  # to the wheels on the outside of the turn
        loads = (_maximum(0.5 * load_f - shift, 0.0), _maximum(0.5 * load_f + shift, 0.0),
                 _maximum(0.5 * load_r - shift, 0.0), _maximum(0.5 * load_r + shift, 0.0))  # fmt: skip
        total = loads[0] + loads[1] + loads[2] + loads[3]  # at least m g
        forces = []
        for i, load in enumerate(loads):  # front left, front right, rear left, rear right
            f_long = _where(braking, m * demand * load / total, drive[i // 2])
            f_lat = unit[i // 2] * load
            resultant = _maximum(xp.sqrt(f_long * f_long + f_lat * f_lat), TINY)
            scale = _minimum(car.friction * load / resultant, 1.0)
            forces.append((f_long * scale, f_lat * scale))
        (x_fl, y_fl), (x_fr, y_fr), (x_rl, y_rl), (x_rr, y_rr) = forces
        x_f, y_f, x_r, y_r = x_fl + x_fr, y_fl + y_fr, x_rl + x_rr, y_rl + y_rr
        ax, ay = (x_f * cos - y_f * sin + x_r) / m, (x_f * sin + y_f * cos + y_r) / m
    moment = half * ((x_fr - x_fl) * cos + (x_rr - x_rl) + (y_fl - y_fr) * sin)
    return ax, ay, (x_f, y_f, y_r), moment, (load_f, load_r)


def _relaxed(x):
    """(1 − e^(−x)) / x: the share of an explicit step that a linear decay at rate x / h makes in h
    (exponential Euler: exact for the tyres' linear damping, stable at any h)."""
    xp = _namespace(x)
    return -xp.expm1(-x) / x


def quasi_static_lateral(car: DynamicCar, vx, r):
    """The CG's lateral speed of a steady turn at (v_x, r), for a state the logs do not hold: the rear
    axle carries m a_y l_f / L (a_y = v_x r), at its linear slip α_r = F_yr / C_r, kept within its
    grip's linear reach μ F_zr / C_r; v_y = l_r r − |v_x| tan α_r (blended to the kinematic l_r r at
    low speed, as the step is)."""
    xp = _namespace(vx)
    load_r = car.static_loads[1]
    reach = car.friction * load_r / car.stiffness_rear
    alpha = _clip(car.mass * vx * r * car.lf / car.wheelbase / car.stiffness_rear, -reach, reach)
    speed = _maximum(xp.abs(vx), 0.5 * car.blend_speed)
    w = _blend_weight(car, xp.abs(vx))
    return car.lr * r - w * speed * xp.tan(alpha)


def free_runs(car: DynamicCar, controls: np.ndarray, start: np.ndarray, dt: float) -> np.ndarray:
    """Free runs of controls (M, T, 2) from start (M, 4) states: (M, T, 6) = (v_x, v_y, r, δ_w, x, y) of
    the CG relative to its start pose (heading 0), one row per control step, the first being `start`."""
    n_runs, n_steps = controls.shape[:2]
    out = np.empty((n_runs, n_steps, 6))
    state = np.asarray(start, np.float64).copy()
    x, y, heading = np.zeros(n_runs), np.zeros(n_runs), np.zeros(n_runs)
    out[:, 0, :4], out[:, 0, 4], out[:, 0, 5] = state, x, y
    for k in range(1, n_steps):
        nxt = dynamic_step(car, state, controls[:, k - 1, 0], controls[:, k - 1, 1], dt)
        # the path by the trapezoid of the two states' velocities in the world frame
        mid_heading = heading + 0.5 * dt * (state[:, 2] + nxt[:, 2]) * 0.5
        vx, vy = 0.5 * (state[:, 0] + nxt[:, 0]), 0.5 * (state[:, 1] + nxt[:, 1])
        x = x + dt * (vx * np.cos(mid_heading) - vy * np.sin(mid_heading))
        y = y + dt * (vx * np.sin(mid_heading) + vy * np.cos(mid_heading))
        heading = heading + 0.5 * dt * (state[:, 2] + nxt[:, 2])
        state = nxt
        out[:, k, :4], out[:, k, 4], out[:, k, 5] = state, x, y
    return out


# What dynamic_rollout.c reads: the car's shared figures (its C_ enum's order) and each lane's (S_).
NATIVE_SET = ("friction", "brake", "stiffness_front", "stiffness_rear", "yaw_inertia", "top_speed",
              "reverse_top_speed", "max_acceleration", "table_gain", "understeer", "scrub", "yaw_lag",
              "reverse_understeer")  # fmt: skip


def native_car(car: DynamicCar) -> np.ndarray:
    """The car's shared figures as dynamic_rollout.c reads them (its C_ enum)."""
    motor = car.top_speed is not None and car.max_acceleration is not None
    return np.array([
        GRAVITY, car.mass, car.lf, car.lr, car.cg_height, car.shape or 0.0, car.curvature,
        car.steering_limit, car.steering_rate, car.rear_drive_share, float(motor),
        car.power_limit_speed or 0.0, car.speed_time_constant, car.blend_speed, float(car.combined_slip),
        ROOM_FLOOR, float(car.wheel_passes if car.wheel_forces else 0), car.track, float(car.tangent_damping),
        float(car.kinematic_core),
    ])  # fmt: skip


def _set_figures(car: DynamicCar) -> list[np.ndarray]:
    return [_numbers(1.0 if (v := getattr(car, name)) is None else v) for name in NATIVE_SET]


def native_sets(car: DynamicCar, batch: tuple[int, ...]) -> np.ndarray:
    """A `scaled` car's per-set figures (prod(batch), its S_ enum) for dynamic_rollout.c, broadcast to
    the lanes' `batch`."""
    figures = [np.broadcast_to(f, batch) for f in _set_figures(car)]
    return np.stack(figures, axis=-1).reshape(-1, len(NATIVE_SET))


def _native_rate_runs(
    lib, car: DynamicCar, controls: np.ndarray, start: np.ndarray, dt: float, substeps: int, implicit: bool
) -> np.ndarray:
    """`rate_runs` by the compiled kernel: one lane per (parameter set, run), the batch flattened."""
    batch = np.broadcast_shapes(*(f.shape for f in _set_figures(car)), start.shape[:-1])
    if batch[-1:] != controls.shape[:1]:
        raise ValueError(f"the runs' batch {batch} does not end in the controls' {controls.shape[0]} runs")
    starts = np.broadcast_to(start, (*batch, 4)).reshape(-1, 4)
    rates = native.dynamic_rate_runs(
        lib, native_car(car), native_sets(car, batch), (car.table_throttle, car.table_speed), controls,
        starts, dt, substeps, implicit, threads=torch.get_num_threads(),
    )  # fmt: skip
    return rates.reshape(*batch, controls.shape[1], 2)


def rate_runs(
    car: DynamicCar, controls: np.ndarray, start: np.ndarray, dt: float, implicit: bool = False,
    backend: str = "auto",
) -> np.ndarray:  # fmt: skip
    """Free runs' rates (..., M, T, 2) = (v_x, r) of controls (M, T, 2) from start states (M, 4); `...`
    is a `scaled` car's batch of parameter sets. `implicit`: the step with implicit tyre damping.
    `backend`: the compiled kernel (`"native"`, dynamic_rollout.c; some 10x NumPy's), this NumPy loop
    (`"reference"`), or the kernel where it builds (`"auto"`)."""
    lib = kernels_for(backend)
    state = np.asarray(start, np.float64)
    substeps = car.implicit_substeps(dt) if implicit else car.substeps(dt)
    if lib is not None:
        return _native_rate_runs(lib, car, np.asarray(controls, np.float64), state, dt, substeps, implicit)
    rates = []
    for k in range(1, controls.shape[1]):
        u = controls[:, k - 1]
        state = dynamic_step(car, state, u[:, 0], u[:, 1], dt, substeps, implicit)
        rates.append(state[..., [0, 2]])
    first = np.asarray(start, np.float64)[..., [0, 2]]
    return np.stack([np.broadcast_to(first, rates[0].shape if rates else first.shape), *rates], axis=-2)
