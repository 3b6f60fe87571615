"""Benchmark of every car's truth simulator, side by side: nigel (MuJoCo contacts), f1tenth and bmw320i
(MuJoCo with a magic-formula tyre, `simulator.tyre_car`).

Run:  python experiments/benchmarks/bench_vehicles.py [--quick] [--threads N] [--cars nigel,f1tenth,bmw320i]

Prints per car, then one summary row per car:
1. The throttle map: steady straight speed at throttle 0.1 ... 1 (and -1) against the file's
   `steady_speed`; the top speed is throttle 1's.
2. Braking: from the speed of throttle 0.5, throttle 0; the deceleration is the slope of the speed
   between 90 % and 10 % of the speed at the brake, against min(file's brake deceleration, μ g).
3. Steady-state circular driving, ISO 4138's constant steering angle at rising speed: a constant
   bicycle angle δ = atan(L / R), R = 15.5 wheelbases (ISO 4138's 40 m at a 2.6 m wheelbase; the same
   angle for every car), throttles whose straight speeds span the linear single track's limit speed;
   steady speed v, yaw rate r, lateral acceleration a_y = v r (mean of the last 2 s). The yaw-rate gain
   r/δ against the linear single track's with the file's cornering stiffnesses (`linear_yaw_gain`):
   the largest error below 0.3 μg must be under 10 %; the largest a_y must level off within 15 % of μ g.
4. Step steer, ISO 7401: at 80 km/h Froude-scaled to the car (v0 = 22.2 m/s √(L / 2.6 m), at most 0.9
   of the top speed), throttle held, the bicycle angle steps (rate-limited by the car) to the linear
   single track's angle for 0.4 μg (and 0.8 μg); response time from 50 % steering to 90 % of the
   steady yaw rate, peak overshoot and its time.
5. The regime: the kinematic single track's (r = v tan δ / L) steady yaw-rate error at 0.3, 0.6 and
   0.8 μg (interpolated along the constant-steer sweep: r_kin / r - 1 at the truth's own speed), and its
   position error 30 s after the step steer's step: the kinematic model at the CG (sideslip
   tan β = l_r tan δ / L) driven by the truth's logged forward speed and the commanded steering, from
   the truth's pose at the step.
6. The control box: skidpads at throttle -1, -0.5, 0 (the brake), 0.25, 0.5, 1 x steering 0, ±lim/2,
   ±lim, slaloms and eights at full lock, 10 s each: runs flagged diverged (must be 0), largest roll,
   largest speed of the braked runs (stands still), simulated seconds per wall second.
7. A pool of 100 maneuvers of 20 s (every kind, throttle and steering drawn over the box, seed 0):
   its collection's wall time and simulated seconds per wall second.
8. The tyre cars' stepping (`simulator.tyre_kernel`): 16 of the pool's maneuvers (10 s each) collected
   by the compiled loop and by the NumPy reference side by side, as one batch and one maneuver at a time
   (how a campaign collects its picks): wall times, their ratio, and the largest difference of the
   logged positions between the two.
Nigel cannot reach 0.3 μg (0.01 g at most): its rows say so ("-"); its step steer is to 0.6 of its
steering limit.
"""

from __future__ import annotations

import argparse
import math
import os
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from simulator import KINDS, Maneuver, Replay, collect
from simulator.build import build_vehicle
from simulator.errors import DivergenceWarning
from simulator.vehicle import Vehicle
from simulator.vehicles.spec import GRAVITY, VehicleSpec

CARS = ("nigel", "f1tenth", "bmw320i")
RADIUS_IN_WHEELBASES = 15.5  # ISO 4138: 40 m at a 2.6 m wheelbase
ISO_SPEED, ISO_WHEELBASE = 80 / 3.6, 2.6  # ISO 7401's step steer: 80 km/h (a passenger car)
LEVELS = (0.3, 0.6, 0.8)  # lateral accelerations (share of μ g) of the regime's steady errors
# the constant-steer sweep: straight speeds as shares of the linear single track's limit speed
SWEEP = (0.2, 0.35, 0.5, 0.6, 0.7, 0.8, 0.87, 0.93, 1.0, 1.05, 1.1, 1.15, 1.2, 1.3, 1.5, 2.0, 3.0)
RATE = 30.0
DELTA_TEXT = f"{math.atan(1.0 / RADIUS_IN_WHEELBASES):.4f} rad"


@dataclass
class Row:
    """One car's summary."""

    car: str
    engine: str
    grip: float  # μ g
    top_file: float = math.nan
    top_sim: float = math.nan
    map_error: float = math.nan
    brake_expected: float = math.nan
    brake_sim: float = math.nan
    gain_error: float = math.nan
    ay_max: float = math.nan
    ay_lock: float = math.nan
    response: float = math.nan
    overshoot: float = math.nan
    kinematic: dict[float, float] = field(default_factory=dict)
    position: dict[str, float] = field(default_factory=dict)
    diverged: str = ""
    box_rate: float = math.nan
    pool_wall: float = math.nan
    pool_rate: float = math.nan
    step_ratio: dict[str, float] = field(default_factory=dict)


def grip(car: Vehicle) -> float:
    """μ g of the car (m/s²)."""
    return float(getattr(car, "friction", car.spec.tyres.friction.value)) * GRAVITY


def throttle_for(spec: VehicleSpec, speed: float) -> float:
    """Throttle (0 ... 1) whose steady straight speed is `speed` (1 when it is beyond the top)."""
    throttle, speeds = spec.speed_map
    return float(np.interp(speed, speeds, throttle))


def settle_time(car: Vehicle, throttle: float, tol: float = 0.003) -> float:
    """Seconds from rest to within `tol` of the steady straight speed: the motor law integrated, traction
    capped at μ g (a car without the law, Nigel: 8 s, its motor's few time constants with margin)."""
    if not hasattr(car, "max_acceleration"):
        return 8.0
    target = throttle * (car.top_speed if throttle > 0 else car.reverse_top_speed)
    v, t, dt = 0.0, 0.0, 0.01
    while abs(v - target) > tol * abs(target) and t < 200.0:
        top = car.top_speed if throttle > 0 else car.reverse_top_speed
        a_max = min(car.max_acceleration, grip(car))
        a = float(np.clip(car.max_acceleration * (throttle - v / top), -a_max, a_max))
        power = car.max_acceleration * car.power_limit_speed / max(abs(v), car.power_limit_speed)
        v += float(np.clip(a, -power, power)) * dt
        t += dt
    return t


def run(car: Vehicle, maneuvers: list, threads: int) -> tuple[pd.DataFrame, float, int]:
    """Noise-free logs, wall seconds, number of diverged runs."""
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DivergenceWarning)
        table = collect(maneuvers, vehicle=car, noise=None, threads=threads)
    wall = time.perf_counter() - start
    return table, wall, int(table.groupby("run_id").diverged.any().sum())


def steady(table: pd.DataFrame, seconds: float = 2.0) -> pd.DataFrame:
    """Mean and spread of speed and yaw rate over each run's last `seconds`."""
    last = table[table.time >= table.groupby("run_id").time.transform("max") - seconds]
    runs = last.groupby("run_id", sort=False)
    return runs.agg(v=("speed", "mean"), r=("angZ", "mean"), r_std=("angZ", "std"), u=("throttle", "first"))


def throttle_map(car: Vehicle, row: Row, quick: bool, threads: int) -> None:
    spec = car.spec
    throttles = [0.5, 1.0] if quick else [round(0.1 * k, 1) for k in range(1, 11)]
    throttles = [*throttles, -1.0]
    maneuvers = [Maneuver("straight", u, duration=settle_time(car, u, 0.0005) + 2.0) for u in throttles]
    table, _, _ = run(car, maneuvers, threads)
    late = steady(table, 1.0)
    print("\n  throttle map (steady straight speed, mean of the last 1 s)")
    print(f"  {'throttle':>8} {'file m/s':>9} {'sim m/s':>9} {'error':>8}")
    errors = []
    for m in maneuvers:
        want = float(spec.steady_speed(m.throttle))
        got = float(late.loc[m.name, "v"])
        errors.append(abs(got / want - 1.0))
        print(f"  {m.throttle:8.1f} {want:9.4f} {got:9.4f} {100 * (got / want - 1):7.2f}%")
    row.top_file, row.top_sim = float(spec.steady_speed(1.0)), float(late.loc[maneuvers[-2].name, "v"])
    row.map_error = 100 * max(errors)
    print(f"{car.spec.name} throttle map: max error {row.map_error:.3f} % (top speed {row.top_sim:.3f} m/s,"
          f" file {row.top_file:.3f})")


def braking(car: Vehicle, row: Row, threads: int) -> None:
    spec = car.spec
    lead = min(settle_time(car, 0.5), 15.0)
    n_drive, n_brake = round(lead * RATE), round(4.0 * RATE)
    throttle = np.r_[np.full(n_drive, 0.5), np.zeros(n_brake)]
    table, _, _ = run(car, [Replay("brake", throttle, np.zeros_like(throttle))], threads)
    t, v = table.time.to_numpy(), table.speed.to_numpy()
    v0 = v[n_drive]
    def crossing(share: float) -> float:  # time the braking speed first falls to share x v0 (interpolated)
        k = n_drive + int(np.argmax(v[n_drive:] <= share * v0))
        return float(np.interp(share * v0, v[k - 1 : k + 1][::-1], t[k - 1 : k + 1][::-1]))

    decel = 0.8 * v0 / (crossing(0.1) - crossing(0.9))
    file_brake = spec.drivetrain.brake_deceleration
    row.brake_expected = min(file_brake.value, grip(car)) if file_brake is not None else math.nan
    row.brake_sim = float(decel)
    expected = f"{row.brake_expected:.3f}" if math.isfinite(row.brake_expected) else "- (the file gives none)"
    print(f"\n  braking from {v0:.3f} m/s: {decel:.3f} m/s² (expected min(file, μ g) = {expected});"
          f" speed after 4 s {v[-1]:.4f} m/s")


def constant_steer(car: Vehicle, row: Row, quick: bool, threads: int) -> pd.DataFrame:
    """ISO 4138 constant steering angle at rising speed; returns the steady points."""
    spec = car.spec
    L = spec.wheelbase
    delta = math.atan(1.0 / RADIUS_IN_WHEELBASES)
    mug = grip(car)
    K = spec.understeer_gradient()
    limit_speed = math.sqrt(mug * L / (delta - K * mug)) if delta > K * mug else math.inf
    shares = (0.35, 0.6, 0.87, 1.0, 1.25) if quick else SWEEP
    # a car that cannot reach its limit (Nigel) sweeps its own speed range instead
    span = limit_speed if limit_speed <= spec.max_speed else spec.max_speed / max(shares)
    throttles = sorted({round(min(1.0, throttle_for(spec, s * span)), 3) for s in shares})
    throttles = [u for u in throttles if u > 0]
    maneuvers = [Maneuver("skidpad", u, delta, "ccw", settle_time(car, u) + 4.0) for u in throttles]
    table, _, _ = run(car, maneuvers, threads)
    points = steady(table)
    points["a_y"] = points.v * points.r
    points["gain"] = points.r / delta
    points["linear"] = spec.linear_yaw_gain(points.v.to_numpy())
    points["error"] = 100 * (points.gain / points.linear - 1)
    points["kinematic"] = 100 * (points.v * math.tan(delta) / L / points.r - 1)
    points["steady"] = points.r_std <= 0.02 * points.r.abs() + 1e-4
    print(f"\n  constant steer δ = {delta:.4f} rad at rising speed (ISO 4138; linear limit speed"
          f" {limit_speed:.2f} m/s)")
    print(f"  {'throttle':>8} {'v m/s':>7} {'r 1/s':>7} {'a_y/μg':>7} {'r/δ':>7} {'linear':>7} {'error':>7}"
          f" {'kin err':>8} steady")
    for _, p in points.iterrows():
        print(f"  {p.u:8.3f} {p.v:7.3f} {p.r:7.4f} {p.a_y / mug:7.3f} {p.gain:7.3f} {p.linear:7.3f}"
              f" {p.error:6.2f}% {p.kinematic:7.2f}% {'yes' if p.steady else 'no'}")
    low = points[(points.a_y < 0.3 * mug) & points.steady]
    row.gain_error = float(low.error.abs().max()) if len(low) else math.nan
    row.ay_max = float(points.a_y[points.steady].max() / mug)
    # the regime: the kinematic model's steady error along the sweep, up to the largest a_y
    rising = points[points.steady]
    rising = rising.iloc[: int(np.argmax(rising.a_y.to_numpy())) + 1]
    for level in LEVELS:
        a = level * mug
        if len(rising) >= 2 and rising.a_y.min() <= a <= rising.a_y.max():
            row.kinematic[level] = float(np.interp(a, rising.a_y, rising.kinematic))
        else:
            row.kinematic[level] = math.nan
    levels = ", ".join(f"{lv:.1f} μg {row.kinematic[lv]:.1f} %" for lv in LEVELS)
    print(f"  yaw-rate gain vs linear single track below 0.3 μg: max error {row.gain_error:.2f} %"
          f" (limit 10 %); largest steady a_y {row.ay_max:.3f} μg (within 15 % of 1 where reachable)")
    print(f"  kinematic single track's steady yaw-rate error: {levels}")
    return points


def lock_turns(car: Vehicle, row: Row, quick: bool, threads: int) -> None:
    """Steady turns at half and full lock past the limit: where the lateral acceleration levels off."""
    spec = car.spec
    mug = grip(car)
    maneuvers = []
    for lock in (0.5, 1.0):
        steering = lock * car.steering_limit
        kinematic = math.sqrt(mug * spec.wheelbase / math.tan(steering))  # the kinematic turn's speed at μ g
        for multiple in (2.0,) if quick else (1.5, 2.0, 3.0):
            u = round(min(1.0, throttle_for(spec, multiple * kinematic)), 3)
            m = Maneuver("skidpad", u, steering, "ccw", settle_time(car, u) + 4.0)
            if m not in maneuvers:
                maneuvers.append(m)
    table, _, _ = run(car, maneuvers, threads)
    points = steady(table)
    print("\n  turns past the limit (straight speed 1.5, 2, 3 x the kinematic turn's at μ g), last 2 s")
    print(f"  {'steering':>8} {'throttle':>8} {'v m/s':>7} {'r 1/s':>7} {'a_y/μg':>7} steady")
    best = 0.0
    for m in maneuvers:
        p = points.loc[m.name]
        ok = p.r_std <= 0.02 * abs(p.r) + 1e-4
        a_y = p.v * p.r / mug
        best = max(best, a_y) if ok else best
        flag = "yes" if ok else "no"
        print(f"  {m.steering:8.4f} {m.throttle:8.3f} {p.v:7.3f} {p.r:7.4f} {a_y:7.3f} {flag}")
    row.ay_lock = best
    print(f"  largest steady a_y at half or full lock: {best:.3f} μg")


def kinematic_path(
    spec: VehicleSpec, speed: np.ndarray, steering: np.ndarray, pose: tuple[float, float, float],
    substeps: int = 20,
) -> tuple[np.ndarray, np.ndarray]:
    """CG path of the kinematic single track under logged speed and steering (held over each 1/30 s)."""
    L, lr = spec.wheelbase, spec.geometry.lr.value
    x, y, psi = pose
    xs, ys = [x], [y]
    h = 1.0 / RATE / substeps
    for v, d in zip(speed[:-1], steering[:-1], strict=True):
        tan_beta = lr * math.tan(d) / L
        r = v * math.tan(d) / L
        for _ in range(substeps):
            mid = psi + 0.5 * r * h
            x += h * v * (math.cos(mid) - tan_beta * math.sin(mid))
            y += h * v * (math.sin(mid) + tan_beta * math.cos(mid))
            psi += r * h
        xs.append(x)
        ys.append(y)
    return np.array(xs), np.array(ys)


def linear_step(spec: VehicleSpec, speed: float, delta: float, rate: float, seconds: float = 3.0,
                dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """Yaw rate of the linear single track (the file's cornering stiffnesses) at constant speed after a
    steering ramp to `delta` at `rate` from t = 0: times, yaw rates and the steady yaw rate."""
    from scipy.linalg import expm

    m, inertia = spec.inertia.mass.value, spec.inertia.yaw_inertia.value
    lf, lr = spec.geometry.lf.value, spec.geometry.lr.value
    cf, cr = spec.tyres.cornering_stiffness_front.value, spec.tyres.cornering_stiffness_rear.value
    a = np.array([[-(cf + cr) / (m * speed), -speed - (cf * lf - cr * lr) / (m * speed)],
                  [-(cf * lf - cr * lr) / (inertia * speed), -(cf * lf**2 + cr * lr**2) / (inertia * speed)]])
    b = np.array([cf / m, cf * lf / inertia])
    big = np.zeros((3, 3))
    big[:2, :2], big[:2, 2] = a, b
    step = expm(big * dt)
    ad, bd = step[:2, :2], step[:2, 2]
    t = np.arange(0.0, seconds, dt)
    x = np.zeros(2)
    r = np.empty_like(t)
    for k, tk in enumerate(t):
        r[k] = x[1]
        x = ad @ x + bd * min(delta, rate * tk)  # steering held over each step
    return t, r, float(spec.linear_yaw_gain(speed) * delta)


def response(
    t: np.ndarray, r: np.ndarray, t_step: float, t50: float, r_ss: float
) -> tuple[float, float, float]:
    """ISO 7401 response time (50 % steering to 90 % of the steady yaw rate), peak overshoot (%) and the
    peak's time, from a yaw-rate record whose steering starts at t_step."""
    after = t >= t_step
    k90 = int(np.argmax(after & (r >= 0.9 * r_ss)))
    t90 = float(np.interp(0.9 * r_ss, r[k90 - 1 : k90 + 1], t[k90 - 1 : k90 + 1]))
    early = after & (t <= t_step + 3.0)
    k_peak = int(np.argmax(np.where(early, r, -np.inf)))
    return t90 - t50, 100 * (r[k_peak] / r_ss - 1), float(t[k_peak] - t50)


def step_steer(car: Vehicle, row: Row, quick: bool, threads: int) -> None:
    spec = car.spec
    L = spec.wheelbase
    mug = grip(car)
    v0 = min(ISO_SPEED * math.sqrt(L / ISO_WHEELBASE), 0.9 * spec.max_speed)
    u0 = throttle_for(spec, v0)
    v0 = float(spec.steady_speed(u0))
    K = spec.understeer_gradient()
    reachable = v0 * v0 * car.steering_limit / (L + K * v0 * v0) > 0.4 * mug
    targets = {"0.4 μg": 0.4, "0.8 μg": 0.8} if reachable else {"0.6 lock": None}
    lead = settle_time(car, u0)
    after = 10.0 if quick else 30.0
    maneuvers, deltas = [], {}
    n_lead, n_after = round(lead * RATE), round(after * RATE) + 1
    for name, level in targets.items():
        if level is None:
            delta = 0.6 * car.steering_limit
        else:
            delta = level * mug * (L + K * v0 * v0) / (v0 * v0)
        deltas[name] = delta
        steering = np.r_[np.zeros(n_lead), np.full(n_after, delta)]
        maneuvers.append(Replay(f"step {name}", np.full_like(steering, u0), steering))
    table, _, _ = run(car, maneuvers, threads)
    rate = getattr(car, "steering_rate", spec.steering.rate.value)
    print(f"\n  step steer (ISO 7401) at {v0:.3f} m/s (throttle {u0:.3f}), steering held {after:g} s")
    print(f"  {'target':>8} {'δ rad':>7} {'r_ss':>7} {'a_y/μg':>7} {'t90 s':>7} {'peak s':>7}"
          f" {'overshoot':>9} {'linear ST: t90':>14} {'overshoot':>9} {'kin pos err 30 s':>17}")
    for name, delta in deltas.items():
        g = table[table.run_id == f"step {name}"]
        t, r = g.time.to_numpy(), g.angZ.to_numpy()
        t_step = t[n_lead]
        t50 = t_step + 0.5 * delta / rate
        window = (t >= t_step + 3.0) & (t <= t_step + 5.0)
        r_ss = float(r[window].mean())
        t90, overshoot, t_peak = response(t, r, t_step, t50, r_ss)
        lt, lr_, l_ss = linear_step(spec, float(g.speed.iloc[n_lead]), delta, rate)
        l90, l_over, _ = response(lt, lr_, 0.0, 0.5 * delta / rate, l_ss)
        # the kinematic single track from the truth's pose at the step, the truth's logged speed
        pose = (float(g.posX.iloc[n_lead]), float(g.posY.iloc[n_lead]), float(g.yaw.iloc[n_lead]))
        xs, ys = kinematic_path(spec, g.speed.to_numpy()[n_lead:], g.steering.to_numpy()[n_lead:], pose)
        error = float(np.hypot(xs[-1] - g.posX.iloc[-1], ys[-1] - g.posY.iloc[-1]))
        ay = float(g.speed.to_numpy()[window].mean()) * r_ss / mug
        print(f"  {name:>8} {delta:7.4f} {r_ss:7.4f} {ay:7.3f} {t90:7.3f} {t_peak:7.3f} {overshoot:8.2f}%"
              f" {l90:14.3f} {l_over:8.2f}% {error:15.3f} m")
        row.position[name] = error
        if name in ("0.4 μg", "0.6 lock"):
            row.response, row.overshoot = t90, overshoot


def control_box(car: Vehicle, row: Row, quick: bool, threads: int) -> None:
    lim = car.steering_limit
    duration = 3.0 if quick else 10.0
    maneuvers = []
    for u in (-1.0, -0.5, 0.0, 0.25, 0.5, 1.0):
        maneuvers.append(Maneuver("straight", u, duration=duration))
        for s in (lim / 2, lim):
            maneuvers += [Maneuver("skidpad", u, s, d, duration) for d in ("ccw", "cw")]
    for u in (-1.0, 0.5, 1.0):
        maneuvers += [Maneuver("slalom", u, lim, "ccw", duration), Maneuver("eight", u, lim, "cw", duration)]
    table, wall, diverged = run(car, maneuvers, threads)
    braked = table[table.throttle == 0.0]
    row.diverged = f"{diverged}/{len(maneuvers)}"
    row.box_rate = len(maneuvers) * duration / wall
    roll, pitch = np.degrees(table.roll.abs().max()), np.degrees(table.pitch.abs().max())
    print(f"\n  control box: {len(maneuvers)} maneuvers x {duration:g} s: diverged {row.diverged},"
          f" largest |roll| {roll:.2f} deg, |pitch| {pitch:.2f} deg,"
          f" |speed| {table.speed.abs().max():.2f} m/s, |yaw rate| {table.angZ.abs().max():.2f} rad/s;"
          f" braked runs' largest |speed| {braked.speed.abs().max():.2e} m/s;"
          f" {row.box_rate:.1f} simulated s per wall s")


def pool_maneuvers(car: Vehicle, n: int, duration: float) -> list[Maneuver]:
    """n maneuvers of every kind, throttle and steering drawn over the control box (seed 0)."""
    rng = np.random.default_rng(0)
    maneuvers = []
    for _ in range(n):
        kind = str(rng.choice(KINDS))
        throttle = float(np.round(rng.uniform(-1.0, 1.0), 3)) or 0.5
        steering = float(np.round(rng.uniform(0.0, car.steering_limit), 4))
        maneuvers.append(Maneuver(kind, throttle, steering, str(rng.choice(["ccw", "cw"])), duration))
    return maneuvers


def pool(car: Vehicle, row: Row, quick: bool, threads: int) -> None:
    n, duration = (10, 5.0) if quick else (100, 20.0)
    maneuvers = pool_maneuvers(car, n, duration)
    _, wall, diverged = run(car, maneuvers, threads)
    row.pool_wall, row.pool_rate = wall, n * duration / wall
    print(f"\n  pool: {n} maneuvers x {duration:g} s collected in {wall:.2f} s: {row.pool_rate:.1f}"
          f" simulated s per wall s ({diverged} diverged)")


def stepping(car: Vehicle, row: Row, quick: bool, threads: int) -> None:
    """A tyre car's compiled stepping loop against its NumPy reference, side by side (section 8)."""
    if not hasattr(car, "backend"):
        return
    n, duration = (4, 2.0) if quick else (16, 10.0)
    maneuvers = pool_maneuvers(car, n, duration)
    print(f"\n  stepping, {n} pool maneuvers x {duration:g} s, {threads} threads (compiled against NumPy):")
    chosen = car.backend
    try:
        for label, batches in (("one batch", [maneuvers]), ("one at a time", [[m] for m in maneuvers])):
            walls, logs = {}, {}
            for backend in ("reference", "compiled"):
                car.backend = backend
                start = time.perf_counter()
                tables = [run(car, batch, threads)[0] for batch in batches]
                walls[backend] = time.perf_counter() - start
                logs[backend] = pd.concat(tables)
            a, b = logs["reference"], logs["compiled"]
            gap = float(np.hypot(*(a[c].to_numpy() - b[c].to_numpy() for c in ("posX", "posY"))).max())
            row.step_ratio[label] = ratio = walls["reference"] / walls["compiled"]
            rate = n * duration / walls["compiled"]
            print(f"    {label:>13}: NumPy {walls['reference']:.2f} s, compiled {walls['compiled']:.2f} s"
                  f" (x{ratio:.1f}; {rate:.0f} simulated s per wall s); largest position gap {gap:.1e} m")
    finally:
        car.backend = chosen


def summary(rows: list[Row]) -> None:
    print("\n## Summary, one row per car (μ g: the car's friction x g; '-': not reachable)")
    head = (f"{'car':>8} {'truth':>16} {'top file':>8} {'top sim':>8} {'map err':>7} {'brake exp':>9}"
            f" {'brake sim':>9} {'gain err':>8} {'ay max':>6} {'ay lock':>7} {'t90':>6} {'oversh':>6}"
            f" {'kin 0.3':>7} {'kin 0.6':>7} {'kin 0.8':>7} {'pos 30 s (m)':>22} {'box div':>7}"
            f" {'box s/s':>7} {'pool s':>7} {'pool s/s':>8} {'C x batch/one':>13}")  # fmt: skip
    print(head)

    def pct(x: float) -> str:
        return "-" if not math.isfinite(x) else f"{x:.1f}%"

    for r in rows:
        pos = " / ".join(f"{k} {v:.2f}" for k, v in r.position.items())
        brake = f"{r.brake_expected:.3f}" if math.isfinite(r.brake_expected) else "-"
        print(f"{r.car:>8} {r.engine:>16} {r.top_file:8.3f} {r.top_sim:8.3f} {pct(r.map_error):>7}"
              f" {brake:>9} {r.brake_sim:9.3f} {pct(r.gain_error):>8} {r.ay_max:6.3f} {r.ay_lock:7.3f}"
              f" {r.response:6.3f} {pct(r.overshoot):>6} {pct(r.kinematic.get(0.3, math.nan)):>7}"
              f" {pct(r.kinematic.get(0.6, math.nan)):>7} {pct(r.kinematic.get(0.8, math.nan)):>7} {pos:>22}"
              f" {r.diverged:>7} {r.box_rate:7.1f} {r.pool_wall:7.2f} {r.pool_rate:8.1f}"
              f" {' / '.join(f'{v:.1f}' for v in r.step_ratio.values()) or '-':>13}")
    print("\nchecks:")
    for r in rows:
        verdict = []
        if math.isfinite(r.gain_error):
            verdict.append(f"yaw gain below 0.3 μg within 10 %: {'pass' if r.gain_error < 10 else 'FAIL'}")
        if max(r.ay_max, r.ay_lock) > 0.5:
            sweep = "pass" if abs(r.ay_max - 1) <= 0.15 else "FAIL"
            lock = "pass" if abs(r.ay_lock - 1) <= 0.15 else "FAIL"
            verdict.append(f"a_y levels off within 15 % of μ g at δ {DELTA_TEXT}: {sweep} ({r.ay_max:.3f});"
                           f" at half or full lock: {lock} ({r.ay_lock:.3f})")
        verdict.append(f"no divergence in the box: {'pass' if r.diverged.startswith('0/') else 'FAIL'}")
        need = {"f1tenth": 0.6, "bmw320i": 0.8}.get(r.car)
        if need is not None:
            err = r.kinematic.get(need, math.nan)
            ok = math.isfinite(err) and abs(err) > 10
            verdict.append(f"kinematic off by > 10 % at {need} μg: {'pass' if ok else 'FAIL'} ({pct(err)})")
        print(f"  {r.car}: " + "; ".join(verdict))


def main() -> None:
    """Run the benchmark and print its tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--cars", default=",".join(CARS))
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes: checks every part still runs (tests/test_benchmarks.py)")
    args = parser.parse_args()
    rows = []
    for name in args.cars.split(","):
        car = build_vehicle(name)
        _ = car.rest_state
        row = Row(name, car.spec.truth.engine, grip(car))
        print(f"\n## {name}: {car.spec.title} ({car.spec.truth.engine}, physics step"
              f" {car.timestep * 1e3:.3f} ms, μ g = {row.grip:.3f} m/s²)")
        throttle_map(car, row, args.quick, args.threads)
        braking(car, row, args.threads)
        constant_steer(car, row, args.quick, args.threads)
        lock_turns(car, row, args.quick, args.threads)
        step_steer(car, row, args.quick, args.threads)
        control_box(car, row, args.quick, args.threads)
        pool(car, row, args.quick, args.threads)
        stepping(car, row, args.quick, args.threads)
        rows.append(row)
    summary(rows)


if __name__ == "__main__":
    main()
