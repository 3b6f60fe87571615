"""The kinematic worst case: how long a candidate may be driven, read off its control schedule alone.

It stands in for the fan before the first model, and must hold beside it where the model
extrapolates. Step by step: speed at most the car's speed_per_throttle x the largest |throttle| so far (times
the share the car kept in its own logged steady turns at the smallest |steering| so far, `turn_speed`:
speed falls as the steering grows), yaw rate at most v tan|steering| / L (no-slip kinematics; an
understeering car turns slower), any heading. The candidate may be driven up to the last whole second
before the first step whose worst case breaks a limit or whose reach meets a wall, unless a circle
holds the path: while the throttle stays constant and the steering keeps its side and never eases
(a skidpad, a fishhook's ramp, a staircase) the curvature only grows, so each osculating circle holds
the rest of the path (Tait-Kneser).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from activelearn.config import POSE_LEVER_ARM, SafetyConfig, boundary_distance, polygon_clearance
from activelearn.loop.pool import maneuver_controls
from activelearn.loop.safety.limits import smooth
from activelearn.names import SPEED, STEERING, THROTTLE
from simulator.vehicles import VehicleSpec, load_vehicle


@dataclass(frozen=True)
class Car:
    """What the kinematic worst case needs of the car: its wheelbase (m) and a speed envelope per unit
    throttle (m/s) at or above every point of its throttle -> steady speed map, rounded up to 3 digits."""

    wheelbase: float
    speed_per_throttle: float

    @classmethod
    def of(cls, vehicle: VehicleSpec | str) -> Car:
        """The envelope of a vehicle file (a spec, a shipped name or a path)."""
        spec = load_vehicle(vehicle)
        throttle, speed = spec.speed_map
        ratio = float(np.max(speed[1:] / throttle[1:]))
        digits = 2 - math.floor(math.log10(ratio))
        return cls(spec.wheelbase, math.ceil(ratio * 10**digits - 1e-9) / 10**digits)


DEFAULT_CAR = Car.of("nigel")
SPEED_PER_THROTTLE = DEFAULT_CAR.speed_per_throttle  # m/s, the default car's (Nigel: 0.287)
UNDERSTEER_MAX = 2.0  # a turn's radius at most this many times the kinematic one (docs/results/safety.md)
# The measured turn speed (`TurnSpeed`) is raised by this share of the envelope for throttles and
# directions the logs did not hold.
TURN_SPEED_MARGIN = 0.02
TURN_SPEED_MIN_SECONDS = 5.0  # s: a run shorter than this may not have settled to its turn speed


@dataclass(frozen=True)
class TurnSpeed:
    """The share of the speed envelope (speed_per_throttle x |throttle|) the car keeps in a steady turn,
    measured on its own logs (`turn_speed`).

    steerings: ascending |steering| levels of the runs held at one throttle and one steering (0 for
    straights). keep: at each level, the largest share any such run reached plus TURN_SPEED_MARGIN,
    made non-increasing with the level.
    """

    steerings: np.ndarray
    keep: np.ndarray
    runs: int

    def factor(self, steering: np.ndarray) -> np.ndarray:
        """(T,) share kept at |steering|: that of the largest level measured at or below it (1 below all).

        Assumes the speed falls as the steering grows, at any throttle and in reverse as in the logged
        runs; `[safety] measured_turn_speed = false` drops the assumption.
        """
        level = np.searchsorted(self.steerings, np.abs(steering) + 1e-9, side="right") - 1
        return np.where(level >= 0, self.keep[np.maximum(level, 0)], 1.0)


def turn_speed(
    logs: pd.DataFrame | None, rate_hz: float, window: float, car: Car = DEFAULT_CAR
) -> TurnSpeed | None:
    """The speed the car kept in its logged steady turns (None: no qualifying run).

    A run (one `pool_index`, else one `run_id`) qualifies when it holds one throttle (|throttle| >=
    0.05) and one signed steering for at least TURN_SPEED_MIN_SECONDS, so its speed has settled. Its
    share is the largest `window`-s mean |speed| over the car's speed_per_throttle x |throttle|.
    """
    if logs is None or logs.empty or not {THROTTLE, STEERING, SPEED} <= set(logs.columns):
        return None
    key = "pool_index" if "pool_index" in logs.columns else "run_id"
    steps = max(1, round(window * rate_hz))
    best: dict[float, float] = {}
    runs = 0
    for _, run in logs.groupby(key, sort=False):
        throttle, steering = run[THROTTLE].to_numpy(np.float64), run[STEERING].to_numpy(np.float64)
        if len(run) < TURN_SPEED_MIN_SECONDS * rate_hz or abs(throttle[0]) < 0.05:
            continue
        if np.ptp(throttle) > 1e-9 or np.ptp(steering) > 1e-9:
            continue
        speed = smooth(np.abs(run[SPEED].to_numpy(np.float64)), steps)
        share = float(speed.max()) / (car.speed_per_throttle * abs(throttle[0]))
        level = round(abs(float(steering[0])), 4)
        best[level] = max(best.get(level, 0.0), share)
        runs += 1
    if not best:
        return None
    levels = np.array(sorted(best))
    keep = np.minimum(np.array([best[lv] for lv in levels]) + TURN_SPEED_MARGIN, 1.0)
    return TurnSpeed(levels, np.minimum.accumulate(keep), runs)


def kinematic_bound(
    maneuver: Any, cfg: SafetyConfig, lever_arm: float = POSE_LEVER_ARM, *, rate_hz: float,
    turn: TurnSpeed | None = None, car: Car = DEFAULT_CAR,
) -> tuple[float, float, float]:  # fmt: skip
    """Risk, admissible duration and its risk by the kinematic worst case of the maneuver's schedule.

    The car may drive until the first step whose worst-case rates break a limit, and until the
    distance it may have covered reaches a wall unless the path is held in a circle (`contained`).
    """
    controls = maneuver_controls(maneuver, rate_hz)
    full = float(maneuver.duration)
    speed = car.speed_per_throttle * np.maximum.accumulate(np.abs(controls[:, 0]))
    if turn is not None:
        speed = speed * turn.factor(np.minimum.accumulate(np.abs(controls[:, 1])))
    yaw = speed * np.tan(np.abs(controls[:, 1])) / car.wheelbase
    over = (speed > cfg.max_speed) | (yaw > cfg.max_yaw_rate) | (speed * yaw > cfg.max_lateral_acceleration)
    room = max(float(boundary_distance(cfg.arena, cfg.start[0], cfg.start[1])) - cfg.margin, 0.0)
    reach = np.cumsum(speed) / rate_hz  # the most path covered by the end of each step
    if cfg.stop == "live":  # the walls are kept at run time: the limits alone bound the schedule
        room, held = math.inf, np.zeros(len(controls), dtype=bool)
    else:
        held = contained(controls, maneuver, cfg, lever_arm, reach, car.wheelbase)
    bad = over | ((reach > room) & ~held)
    first = int(np.argmax(bad)) if bad.any() else len(bad)
    if first >= len(bad):
        return 0.0, full, 0.0
    allowed = min(full, math.floor((first - 1) / rate_hz + 1e-9))  # every step up to it is within bounds
    if allowed >= cfg.min_duration:
        return 1.0, float(allowed), 0.0
    return 1.0, 0.0, float("nan")


def monotone_steps(controls: np.ndarray) -> int:
    """Leading steps of a schedule at constant throttle whose steering keeps one side and never eases:
    over them the path's curvature only grows, so each osculating circle holds the rest of it."""
    throttle, steering = controls[:, 0], controls[:, 1]
    side = np.sign(steering[np.flatnonzero(steering)[0]]) if steering.any() else 0.0
    magnitude = side * steering
    ok = (throttle == throttle[0]) & (magnitude >= 0.0)
    ok[1:] &= magnitude[1:] >= magnitude[:-1] - 1e-12
    return int(np.argmin(ok)) if not ok.all() else len(ok)


def contained(
    controls: np.ndarray, maneuver: Any, cfg: SafetyConfig, lever_arm: float, reach: np.ndarray,
    wheelbase: float = DEFAULT_CAR.wheelbase,
) -> np.ndarray:  # fmt: skip
    """(T,) True at the steps where the worst case keeps the car `margin + path_tolerance` off the walls
    whatever its speed: the schedule's monotone part after a step whose circle holds the rest of it.

    From the start, that circle's place is known (`circles_fit`: a skidpad, or a staircase from its
    first level); from a later step t0 (a fishhook's ramp) the car is somewhere within reach(t0) of
    the start, and the circle within 2 (r + lever_arm) of it, r up to UNDERSTEER_MAX L / tan|steering(t0)|.
    """
    held = np.zeros(len(controls), dtype=bool)
    steps = monotone_steps(controls)
    if steps == 0 or not controls[:steps, 1].any():
        return held
    room = float(boundary_distance(cfg.arena, cfg.start[0], cfg.start[1])) - cfg.margin - cfg.path_tolerance
    first = float(controls[0, 1])
    if first != 0.0:
        constant = bool(np.all(controls[:steps, 1] == first))
        side = float(np.sign(first))
        fit = circles_fit(
            maneuver, cfg, lever_arm, steering=abs(first), nested=not constant, side=side, wheelbase=wheelbase
        )
        if fit:
            held[:steps] = True
            return held
    magnitude = np.abs(controls[:steps, 1])
    with np.errstate(divide="ignore"):
        radius = np.where(magnitude > 0, UNDERSTEER_MAX * wheelbase / np.tan(magnitude), np.inf)
    extent = np.minimum.accumulate(reach[:steps] + 2.0 * (radius + lever_arm))
    held[:steps] = extent <= room
    return held


def circles_fit(
    maneuver: Any, cfg: SafetyConfig, lever_arm: float = POSE_LEVER_ARM, *, steering: float | None = None,
    nested: bool = False, side: float | None = None, wheelbase: float = DEFAULT_CAR.wheelbase,
) -> bool:  # fmt: skip
    """True where every possible circle of a constant steering from the start keeps `margin +
    path_tolerance` from the walls (a skidpad; `steering` a staircase's first level).

    The rear axle turns about a centre on the steering side, L / tan(steering) to UNDERSTEER_MAX
    times that away (forward or in reverse); the logged point, `lever_arm` ahead of the axle, goes
    round the same centre through the start pose (`nested`: anywhere within the circle grown by
    `lever_arm`, as for a path of growing curvature inside it). `side`: +1 left, -1 right (default:
    the maneuver's direction). Sampled every 0.5 degree and 1/64 of the radii.
    """
    if steering is None:
        if maneuver.kind != "skidpad":
            return False
        steering = maneuver.steering
    if steering <= 0:
        return False
    x0, y0, yaw0 = cfg.start
    heading, left = np.array([math.cos(yaw0), math.sin(yaw0)]), np.array([-math.sin(yaw0), math.cos(yaw0)])
    kinematic = wheelbase / math.tan(steering)
    radii = np.linspace(kinematic, UNDERSTEER_MAX * kinematic, 64)[:, None]
    sign = maneuver.sign if side is None else float(side)
    cx = x0 - lever_arm * heading[0] + sign * radii * left[0]
    cy = y0 - lever_arm * heading[1] + sign * radii * left[1]
    rho = radii + lever_arm if nested else np.hypot(radii, lever_arm)
    angle = np.linspace(0.0, 2.0 * math.pi, 720, endpoint=False)[None, :]
    clearance = polygon_clearance(cfg.arena, cx + rho * np.cos(angle), cy + rho * np.sin(angle))
    return bool(np.min(clearance) >= cfg.margin + cfg.path_tolerance)
