"""The dynamic single track of a car's vehicle file: a bicycle with tyre slip, saturating tyres and load
transfer, blended into the kinematic model at low speed. Issue 56's core; for now it runs with the
file's values and no data (`bench_vehicle_baselines.py`'s "dynamic file" row), not inside a model.

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
- v̇_x = a − F_yf sin δ_w / m + v_y r,  v̇_y = (F_yf cos δ_w + F_yr) / m − v_x r,
  ṙ = (l_f F_yf cos δ_w − l_r F_yr) / I_z.
- Below the blend speed v_b = ½ √(g L) the state is pulled to the kinematic one (r = v_x tan δ_w / L,
  v_y = l_r r) with weight 1 − w, w = ½ (1 + tanh((|v_x| − v_b) / (v_b / 4))): Nigel's whole range sits in
  it (v_b 0.59 m/s, top speed 0.27), the 1:10 car's (0.90 m/s) and the full-size car's (2.5 m/s) do not.
- Explicit substeps within each log step, as many as keep the lateral and yaw modes stable at the slip
  floor (each substep at most their time constant m v / (C_f + C_r), I_z v / (l_f² C_f + l_r² C_r)).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np

from activelearn.numerics.models.single_track import Identified, PhysicalParameter, _map_fit, stacked_logs
from simulator.vehicles import GRAVITY, VehicleSpec

BLEND_SHARE = 0.5  # the blend speed, a share of √(g L)


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
            speed_time_constant=lag,
        )  # fmt: skip

    @property
    def wheelbase(self) -> float:
        return self.lf + self.lr

    @property
    def blend_speed(self) -> float:
        """Below it the state is pulled to the kinematic one (½ √(g L))."""
        return BLEND_SHARE * math.sqrt(GRAVITY * self.wheelbase)

    def substeps(self, dt: float) -> int:
        """Explicit substeps per `dt` that keep the lateral and yaw modes stable at the slip floor."""
        floor = 0.5 * self.blend_speed
        c_f, c_r = self.stiffness_front, self.stiffness_rear
        lateral = np.min(self.mass * floor / (c_f + c_r))  # the stiffest of a batch of parameter sets
        yaw = np.min(self.yaw_inertia * floor / (self.lf**2 * c_f + self.lr**2 * c_r))
        return max(1, math.ceil(dt / min(float(lateral), float(yaw))))


def _acceleration(car: DynamicCar, throttle: np.ndarray, vx: np.ndarray, dt: float) -> np.ndarray:
    """Longitudinal acceleration (m/s²) from the drivetrain or the brake, within μ g."""
    grip = car.friction * GRAVITY
    if car.top_speed is not None and car.max_acceleration is not None:
        top = np.where(throttle > 0, car.top_speed, car.reverse_top_speed)
        a_max = car.max_acceleration
        limit = a_max * car.power_limit_speed / np.maximum(np.abs(vx), car.power_limit_speed)  # type: ignore[operator]
        drive = np.clip(a_max * (throttle - vx / top), -limit, limit)
    else:
        target = np.sign(throttle) * np.interp(np.abs(throttle), car.table_throttle, car.table_speed)
        drive = (target * car.table_gain - vx) / car.speed_time_constant
    stop = -np.sign(vx) * np.minimum(car.brake, np.abs(vx) / dt)  # brakes to rest, not past it
    return np.clip(np.where(throttle == 0.0, stop, drive), -grip, grip)


def _lateral_force(car: DynamicCar, alpha: np.ndarray, load: np.ndarray, static: float, stiffness: float):
    """An axle's lateral force (N) at slip angle α and load F_z."""
    cap = car.friction * load
    if car.shape is None:
        return np.clip(stiffness * load / static * alpha, -cap, cap)
    b = stiffness / static / (car.shape * car.friction)
    x = b * alpha
    if car.curvature:
        x = x - car.curvature * (x - np.arctan(x))
    return cap * np.sin(car.shape * np.arctan(x))


def dynamic_step(
    car: DynamicCar, state: np.ndarray, throttle: np.ndarray, steering: np.ndarray, dt: float
) -> np.ndarray:
    """The state (..., 4) = (v_x, v_y, r, δ_w) after `dt` s of the controls, in `car.substeps(dt)` steps."""
    n = car.substeps(dt)
    h = dt / n
    vx, vy, r, delta = (state[..., i].astype(np.float64) for i in range(4))
    m, L, g = car.mass, car.wheelbase, GRAVITY
    static_f, static_r = m * g * car.lr / L, m * g * car.lf / L
    floor, blend = 0.5 * car.blend_speed, car.blend_speed
    target = np.clip(steering, -car.steering_limit, car.steering_limit)
    for _ in range(n):
        delta = delta + np.clip(target - delta, -car.steering_rate * h, car.steering_rate * h)
        a = _acceleration(car, throttle, vx, h)
        load_f = np.maximum(m * (g * car.lr - a * car.cg_height) / L, 0.0)
        load_r = np.maximum(m * (g * car.lf + a * car.cg_height) / L, 0.0)
        cos, sin = np.cos(delta), np.sin(delta)
        front_y = vy + car.lf * r  # the front axle's velocity, body frame, then in the wheel's
        long_f, lat_f = vx * cos + front_y * sin, front_y * cos - vx * sin
        alpha_f = np.arctan(-lat_f / np.maximum(np.abs(long_f), floor))
        alpha_r = np.arctan(-(vy - car.lr * r) / np.maximum(np.abs(vx), floor))
        f_f = _lateral_force(car, alpha_f, load_f, static_f, car.stiffness_front)
        f_r = _lateral_force(car, alpha_r, load_r, static_r, car.stiffness_rear)
        # the drive's share of the rear axle's friction circle
        drive_r = m * a * car.rear_drive_share
        room = np.sqrt(np.maximum((car.friction * load_r) ** 2 - drive_r**2, 0.0))
        f_r = np.clip(f_r, -room, room)
        dvx = a - f_f * sin / m + vy * r
        dvy = (f_f * cos + f_r) / m - vx * r
        dr = (car.lf * f_f * cos - car.lr * f_r) / car.yaw_inertia
        vx, vy, r = vx + h * dvx, vy + h * dvy, r + h * dr
        w = 0.5 * (1.0 + np.tanh((np.abs(vx) - blend) / (0.25 * blend)))  # 1: dynamic, 0: kinematic
        r_kin = vx * np.tan(delta) / L
        r = w * r + (1.0 - w) * r_kin
        vy = w * vy + (1.0 - w) * car.lr * r_kin
    return np.stack(np.broadcast_arrays(vx, vy, r, delta), axis=-1)  # δ_w has no parameter set's axis


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


# The dynamic core's parameters identified from logs: scales of the file's figures (1 = the file).
DYNAMIC_PARAMETERS: tuple[PhysicalParameter, ...] = (
    PhysicalParameter("friction", 1.0, 0.3, 3.0, 0.3, "-", "scale of the tyres' peak friction μ"),
    PhysicalParameter("stiffness_front", 1.0, 0.3, 3.0, 0.5, "-", "scale of the front axle's stiffness"),
    PhysicalParameter("stiffness_rear", 1.0, 0.3, 3.0, 0.5, "-", "scale of the rear cornering stiffness"),
    PhysicalParameter("motor", 1.0, 0.3, 3.0, 0.3, "-", "scale of the drive (a_max, top speeds, table)"),
    PhysicalParameter("yaw_inertia", 1.0, 0.3, 3.0, 0.5, "-", "scale of the yaw inertia"),
)


def _bounds() -> SimpleNamespace:
    """The parameters' ranges, widths and prior in the form `single_track._map_fit` reads."""
    nominal = np.array([p.nominal for p in DYNAMIC_PARAMETERS])
    width = np.array([p.width for p in DYNAMIC_PARAMETERS])
    return SimpleNamespace(
        low=np.array([p.low for p in DYNAMIC_PARAMETERS]),
        high=np.array([p.high for p in DYNAMIC_PARAMETERS]),
        width=width, prior=Identified(nominal, np.diag(width**2)),
    )  # fmt: skip


def scaled(car: DynamicCar, theta: np.ndarray) -> DynamicCar:
    """The car with parameter sets `theta` (P, 5) applied: its scaled figures are (P, 1) arrays, so a
    step runs every set against every run at once."""
    t = np.atleast_2d(np.asarray(theta, np.float64))
    friction, front, rear, motor, inertia = (t[:, i : i + 1] for i in range(len(DYNAMIC_PARAMETERS)))
    mu = car.friction * friction

    def times(value: float | None) -> np.ndarray | None:
        return None if value is None else value * motor

    return dataclasses.replace(
        car, friction=mu, brake=np.minimum(car.brake, mu * GRAVITY),
        stiffness_front=car.stiffness_front * front,
        stiffness_rear=car.stiffness_rear * rear, yaw_inertia=car.yaw_inertia * inertia,
        top_speed=times(car.top_speed), reverse_top_speed=times(car.reverse_top_speed),
        max_acceleration=times(car.max_acceleration), table_gain=car.table_gain * motor,
    )  # fmt: skip


def rate_runs(car: DynamicCar, controls: np.ndarray, start: np.ndarray, dt: float) -> np.ndarray:
    """Free runs' rates (..., M, T, 2) = (v_x, r) of controls (M, T, 2) from start states (M, 4); `...`
    is a `scaled` car's batch of parameter sets."""
    state = np.asarray(start, np.float64)
    rates = []
    for k in range(1, controls.shape[1]):
        state = dynamic_step(car, state, controls[:, k - 1, 0], controls[:, k - 1, 1], dt)
        rates.append(state[..., [0, 2]])
    first = np.asarray(start, np.float64)[..., [0, 2]]
    return np.stack([np.broadcast_to(first, rates[0].shape if rates else first.shape), *rates], axis=-2)


def identify_dynamic(
    logs: list[tuple[np.ndarray, np.ndarray]], car: DynamicCar, dt: float, every: int = 3,
    horizon: float | None = None,
) -> Identified:
    """Output-error MAP of the five `DYNAMIC_PARAMETERS` (scales of the file's figures, the file as the
    prior) from logs, (controls (T, 2), rates (T, 2) = speed, yaw rate), as the kinematic core's
    `identify_from_logs` does: free runs from each log's first recorded rates (lateral speed 0), every
    `every`-th step compared, each log a cluster of the covariance. `horizon` (s): free runs restart
    from the recorded rates every `horizon` s instead (a spinning car's 30 s are chaotic in the
    parameters; a few seconds are not)."""
    logs = [(np.asarray(u, np.float64), np.asarray(y, np.float64)) for u, y in logs if len(u) > 1]
    bounds = _bounds()
    if not logs:
        return Identified(bounds.prior.values.copy(), bounds.prior.covariance.copy())
    owners = list(range(len(logs)))
    if horizon is not None:
        steps = max(2, round(horizon / dt))
        cut = [(i, u[k : k + steps + 1], y[k : k + steps + 1]) for i, (u, y) in enumerate(logs)
               for k in range(0, len(u) - 1, steps)]  # fmt: skip
        owners = [i for i, u, _ in cut if len(u) > 1]
        logs = [(u, y) for _, u, y in cut if len(u) > 1]
    controls, rates, valid, keep = stacked_logs(logs, every)
    start = np.column_stack([rates[:, 0, 0], np.zeros(len(logs)), rates[:, 0, 1], controls[:, 0, 1]])

    def errors_of(sets: np.ndarray) -> np.ndarray:  # (P, n, 2)
        predicted = rate_runs(scaled(car, sets), controls, start, dt)
        return np.nan_to_num(predicted - rates, nan=1e3, posinf=1e3, neginf=-1e3)[:, keep]

    clusters = np.asarray(owners)[np.nonzero(keep)[0]]  # a log's windows share its cluster
    return _map_fit(errors_of, rates[valid].std(axis=0), clusters, bounds.prior, None, bounds)
