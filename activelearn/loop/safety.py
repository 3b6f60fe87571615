"""Safe exploration in a bounded arena: which candidates the car may drive, and what it did.

A track day happens in an arena (`[safety] arena`, a polygon in metres, every maneuver starting
from `start`) with limits the car must not exceed (|v|, |ω|, the lateral acceleration |v·ω|). For
each candidate the round's model rolls the maneuver out (`activelearn.numerics.surrogate.simulate`:
S trajectories, each one posterior draw with aleatoric noise at every step) from the start pose.
A trajectory *violates* at its first step whose position lies closer than `margin` (the car's
body) plus `path_tolerance` (what a free run's path may still miss of the car's: a few cm, now that
the rollout integrates the non-slipping rear axle and places the logged CG ahead of it) to a
wall or whose rates, averaged over `limit_window` seconds, exceed a limit. The candidate's
risk over a duration T is the share of trajectories that violated before T:

  * risk(full duration) <= delta: admissible as it is;
  * else, cut short: the longest whole number of seconds T with risk(T) <= delta, when
    T >= `min_duration` (the proposal carries T and says it was cut);
  * else not admissible.

Before the first model (a cold start's initial design without a prior model), and wherever the
model extrapolates (its epistemic std of the speed, and of the yaw rate where `trust_rates` says so,
along the maneuver exceeds `trust_std` of the rate: there its fan missed the true speed, measured in
reverse after a forward-only prior, and the true yaw rate of a staircase on the twin), a
kinematic worst case stands in for the fan, or must hold beside it. It reads the candidate's control
schedule step by step (a reference kind or any family member): speed at most SPEED_PER_THROTTLE x
the largest |throttle| so far (the reference throttle table lies below that line) x the share of it
the car kept in its own logged steady turns at the smallest |steering| so far (`turn_speed`: the
prior's and the campaign's skidpads and straights; speed falls as the steering grows), yaw rate at most
v tan|steering| / L (no-slip kinematics; Nigel understeers, so its true yaw rate is lower), any
heading. The candidate may be driven up to the last whole second before the first step whose worst
case breaks a limit or whose reach (the path it may have covered) meets a wall, unless a circle
holds the path. While the throttle stays constant and the steering keeps its side and never eases
(a skidpad, a fishhook's ramp, a staircase), the path's curvature only grows, so each osculating
circle holds the rest of it (Tait-Kneser); the rear axle's radius at steering s lies between
L / tan(s) and UNDERSTEER_MAX times that, the logged point `pose_lever_arm` ahead of it. From the
start the first circle's place is known (centre on the steering side of the start pose, forward or
in reverse): where every such circle keeps `margin + path_tolerance` from the walls, the schedule's
monotone part may be driven whole. From a later step t0 the car is somewhere within reach(t0) of the
start and the rest of its path within 2 (r + lever arm) of it: held where that stays off the walls
(a fishhook whose ramp is quick).

With `stop = "live"` the walls are kept at run time instead: the car brakes (throttle 0) as soon as
its measured pose comes within `margin + stop_buffer` of a wall, so the fan and the worst case judge
the limits only and a candidate is no longer cut in advance for the walls. Simulated oracles drive
the stop closed-loop in MuJoCo (`stop_rule` -> `simulator.StopRule`): from the log sample after the
trigger the throttle is 0 and the log runs on until the car stands, so `violations` count the
braking too (Nigel travels 2.4 cm from the triggering pose at top speed, 0.4 cm at 0.085 m/s; a
`stop_buffer` below the braking distance from `max_speed` is refused by the config, one it cannot
stop in shows as arena violations). A person's log ends where the car's own log ends; a recorded
pool's log, which cannot be driven again, is cut at the trigger (`live_stop`).

`violations` checks the logs that came back (simulated or driven) against the same arena and limits:
what the benchmark counts. The fan is the rollout of the lead's dynamics issue too: one rollout
serves evaluation, acquisition and safety.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

import simulator
from activelearn.config import POSE_LEVER_ARM, SafetyConfig, boundary_distance, polygon_clearance
from activelearn.loop.pool import maneuver_controls
from activelearn.numerics.surrogate import Rollout, simulate
from activelearn.seeds import Stream, derived_seed
from simulator.stop import place

SPEED_PER_THROTTLE = 0.287  # m/s: above every point of the reference throttle -> speed table
WHEELBASE = 0.1415  # m, Nigel (reference/nigel.md)
# A skidpad's radius at most this many times the kinematic one: MuJoCo's steady skidpads lie at
# 1.02-1.07 (safe_track.toml's pool, forward and reverse), the twin of the fidelity table
# (docs/how-to/fidelity.md) at 1.01-1.03; within the lateral-acceleration limit (0.12 m/s², far
# below grip) the car does not slide. Twice is the margin for a car that is not the model.
UNDERSTEER_MAX = 2.0
# The measured turn speed (`TurnSpeed`) is raised by this share of the envelope for throttles and
# directions the logs did not hold (the envelope lies 0-7 % above the reference speed table).
TURN_SPEED_MARGIN = 0.02
TURN_SPEED_MIN_SECONDS = 5.0  # s: a run shorter than this may not have settled to its turn speed
CHUNK = 16  # maneuvers per rollout: S x 16 x 2 700 steps x 5 arrays of float32 stay near 60 MB
REASONS = ("arena", "speed", "yaw_rate", "lateral", "diverged")  # diverged: a fan's NaN or inf


@dataclass(frozen=True)
class Assessment:
    """Admissibility of candidates: risk over the full duration, admissible duration, why not.

    risk: (n,) share of fan trajectories that violate within the full duration (NaN: not assessed).
    duration: (n,) seconds the candidate may be driven (its full duration, shorter when cut, 0 when
        not admissible). cut_risk: (n,) risk over that duration.
    """

    risk: np.ndarray
    duration: np.ndarray
    cut_risk: np.ndarray
    full: np.ndarray  # (n,) the candidates' full durations

    @property
    def admissible(self) -> np.ndarray:
        """(n,) True where the candidate may be driven (perhaps cut short)."""
        return self.duration > 0

    @property
    def cut(self) -> np.ndarray:
        """(n,) True where the candidate is admissible only when cut short."""
        return self.admissible & (self.duration < self.full - 1e-9)

    @property
    def size(self) -> int:
        """Number of admissible candidates (the safe set)."""
        return int(self.admissible.sum())

    @property
    def assessed(self) -> np.ndarray:
        """(n,) True where the candidate was assessed (an open one; the rest have risk NaN)."""
        return np.isfinite(self.risk)

    @property
    def share(self) -> float:
        """Admissible share of the assessed candidates (NaN: none assessed).

        Unlike `size` it does not shrink as picks leave the pool, so it shows whether the set grows.
        """
        assessed = self.assessed
        return float(self.admissible[assessed].mean()) if assessed.any() else float("nan")

    @property
    def time_share(self) -> float:
        """Admissible share of the assessed candidates' driving seconds (NaN: none assessed).

        A candidate admissible only when cut counts its cut seconds: the share grows when the model
        comes to trust a candidate's later seconds, which the count of candidates does not show.
        """
        assessed = self.assessed
        total = float(self.full[assessed].sum())
        return float(self.duration[assessed].sum()) / total if total > 0 else float("nan")


def _smooth(values: np.ndarray, steps: int) -> np.ndarray:
    """Trailing moving average over `steps` along the last axis (the first steps average fewer)."""
    if steps <= 1:
        return values
    total = np.cumsum(values, axis=-1, dtype=np.float64)
    total[..., steps:] = total[..., steps:] - total[..., :-steps]
    count = np.minimum(np.arange(1, values.shape[-1] + 1), steps)
    return total / count


def violating(x: np.ndarray, y: np.ndarray, v: np.ndarray, w: np.ndarray, cfg: SafetyConfig,
              rate_hz: float, tolerance: float = 0.0, walls: bool = True) -> np.ndarray:  # fmt: skip
    """(..., T) code of what each step violates: 0 none, else 1 + index in REASONS (first one wins).

    Positions in the arena frame (m), rates sampled at `rate_hz` (m/s, rad/s); the rates are
    averaged over `cfg.limit_window` seconds first, so one noisy sample is not a limit violation.
    A position closer than `cfg.margin + tolerance` to a wall violates (unless `walls` is False: a
    live stop keeps them).
    """
    window = max(1, round(cfg.limit_window * rate_hz))
    with np.errstate(invalid="ignore", over="ignore"):  # a diverged trajectory is caught below
        v_avg, w_avg = _smooth(v, window), _smooth(w, window)
        near_wall = np.zeros(np.shape(x), dtype=bool)
        if walls:
            near_wall = polygon_clearance(cfg.arena, x, y) < cfg.margin + tolerance
        checks = (
            near_wall,
            np.abs(v_avg) > cfg.max_speed,
            np.abs(w_avg) > cfg.max_yaw_rate,
            np.abs(v_avg * w_avg) > cfg.max_lateral_acceleration,
            ~(np.isfinite(x) & np.isfinite(y) & np.isfinite(v_avg) & np.isfinite(w_avg)),
        )
    code = np.zeros(x.shape, dtype=np.int8)
    for i, bad in reversed(list(enumerate(checks))):
        code[bad] = i + 1
    return code


def fan(model: Any, maneuvers: Sequence[Any], cfg: SafetyConfig, rate_hz: float, seed: int) -> Rollout:
    """The model's rollout of `maneuvers` from the start pose (epistemic spread widened by `fan_scale`).

    Positions are in the arena frame. The model's own pose-fan calibration (`model.fan_scale`, which
    `[design] fan_calibration` fits for predictions) is not applied: [safety] `fan_scale` is the margin.
    """
    x0, y0, yaw0 = cfg.start
    previous = float(model.epistemic_scale)
    try:
        with torch.no_grad():  # the scale is a variance factor; fan_scale widens the std
            model.epistemic_scale.fill_(previous * cfg.fan_scale**2)
        rollout = simulate(
            model, [maneuver_controls(m, rate_hz) for m in maneuvers], rate_hz=rate_hz,
            n_samples=cfg.n_samples, seed=seed, initial_yaw=yaw0, fan_scale=1.0,
        )  # fmt: skip
    finally:
        with torch.no_grad():
            model.epistemic_scale.fill_(previous)
    return dataclasses.replace(rollout, x=rollout.x + x0, y=rollout.y + y0)


def first_violations(rollout: Rollout, cfg: SafetyConfig, rate_hz: float) -> np.ndarray:
    """(S, M) seconds at which each trajectory first violates (inf: never within its maneuver)."""
    code = violating(rollout.x, rollout.y, rollout.v, rollout.w, cfg, rate_hz, cfg.path_tolerance,
                     walls=cfg.stop != "live")  # fmt: skip
    steps = np.arange(code.shape[-1])
    code[:, steps[None, :] >= rollout.lengths[:, None]] = 0  # padding past a maneuver's end
    bad = code > 0
    first = np.where(bad.any(axis=-1), bad.argmax(axis=-1), np.inf)
    return first * rollout.dt


def admissible_duration(times: np.ndarray, full: float, cfg: SafetyConfig) -> tuple[float, float, float]:
    """Full-duration risk, the duration to drive (0: none) and its risk, from (S,) first violations."""
    n = len(times)
    risk = float(np.mean(times < full))
    if risk <= cfg.delta:
        return risk, full, risk
    allowed = math.floor(cfg.delta * n + 1e-9)  # trajectories that may violate
    cut = float(np.floor(np.sort(times)[allowed]))  # before it, at most `allowed` have violated
    if cut < cfg.min_duration:
        return risk, 0.0, float("nan")
    return risk, cut, float(np.mean(times < cut))


def assess(
    model: Any | None,
    maneuvers: Sequence[Any],
    cfg: SafetyConfig,
    *,
    rate_hz: float,
    seed: int = 0,
    which: np.ndarray | None = None,
    turn: TurnSpeed | None = None,
) -> Assessment:
    """Admissibility of every candidate in `maneuvers` (only those in `which`; the rest are not admissible).

    With a model: from its rollout fans, in chunks of CHUNK maneuvers. Without one: the kinematic
    worst case alone (see the module docstring), with the speed kept in turns `turn` where given.
    """
    n = len(maneuvers)
    full = np.array([float(m.duration) for m in maneuvers])
    risk, duration, cut_risk = np.full(n, np.nan), np.zeros(n), np.full(n, np.nan)
    todo = np.arange(n) if which is None else np.flatnonzero(which)
    arm = float(getattr(getattr(model, "config", None), "pose_lever_arm", POSE_LEVER_ARM))
    if model is None:
        for i in todo:
            risk[i], duration[i], cut_risk[i] = kinematic_bound(maneuvers[i], cfg, arm, rate_hz, turn)
        return Assessment(risk, duration, cut_risk, full)
    for block in range(0, len(todo), CHUNK):
        rows = todo[block : block + CHUNK]
        rollout = fan(model, [maneuvers[i] for i in rows], cfg, rate_hz, seed + block)
        times = first_violations(rollout, cfg, rate_hz)
        untrusted = relative_std(rollout, cfg.trust_rates) / cfg.fan_scale > cfg.trust_std
        for j, i in enumerate(rows):
            risk[i], duration[i], cut_risk[i] = admissible_duration(times[:, j], full[i], cfg)
            if untrusted[j]:  # the model extrapolates: the kinematic worst case must hold as well
                bound = kinematic_bound(maneuvers[i], cfg, arm, rate_hz, turn)
                risk[i] = max(risk[i], bound[0])
                if bound[1] < duration[i]:
                    duration[i], cut_risk[i] = bound[1], bound[2] if bound[1] > 0 else float("nan")
    return Assessment(risk, duration, cut_risk, full)


# The smallest rate a relative std is taken of (speed m/s, yaw rate rad/s): ~7 % of Nigel's top speed and
# of its largest yaw rate, so a standing or straight-driving car does not divide by ~0.
RATE_FLOORS = {"speed": 0.02, "yaw_rate": 0.05}


def relative_std(rollout: Rollout, rates: Sequence[str] = ("speed",)) -> np.ndarray:
    """(M,) largest epistemic std of `rates` along each maneuver, each relative to its rate (RATE_FLOORS)."""
    worst = np.zeros(len(rollout.lengths))
    past = np.arange(rollout.epistemic_var.shape[1])[None, :] >= rollout.lengths[:, None]
    for name in rates:
        column = ("speed", "yaw_rate").index(name)
        std = np.sqrt(rollout.epistemic_var[..., column])
        relative = std / np.maximum(np.abs(rollout.mean_rates[..., column]), RATE_FLOORS[name])
        relative[past] = 0.0
        worst = np.maximum(worst, relative.max(axis=1))
    return worst


@dataclass(frozen=True)
class TurnSpeed:
    """The share of the speed envelope (SPEED_PER_THROTTLE x |throttle|) the car keeps in a steady turn,
    measured on its own logs (`turn_speed`).

    steerings: ascending |steering| levels of the runs held at one throttle and one steering (0 for
    straights). keep: at each level, the largest share any such run reached (its 0.5-s mean |speed|
    over the envelope of its throttle) plus TURN_SPEED_MARGIN, made non-increasing with the level.
    """

    steerings: np.ndarray
    keep: np.ndarray
    runs: int

    def factor(self, steering: np.ndarray) -> np.ndarray:
        """(T,) share kept at |steering|: that of the largest level measured at or below it (1 below all).

        Valid where the speed falls as the steering grows (the reference car's tyre scrub,
        shared/reference/nigel.md), at any throttle and in reverse as in the logged runs: both are
        assumptions, which TURN_SPEED_MARGIN softens and `[safety] measured_turn_speed = false` drops.
        """
        level = np.searchsorted(self.steerings, np.abs(steering) + 1e-9, side="right") - 1
        return np.where(level >= 0, self.keep[np.maximum(level, 0)], 1.0)


def turn_speed(logs: pd.DataFrame | None, rate_hz: float, window: float) -> TurnSpeed | None:
    """The speed the car kept in its logged steady turns (None: no qualifying run).

    A run (one `pool_index`, else one `run_id`) qualifies when it holds one throttle (|throttle| >=
    0.05) and one signed steering for at least TURN_SPEED_MIN_SECONDS, so its speed has settled: the
    reference car settles within a few steps of a throttle change. Its share is the largest
    `window`-s mean |speed| over SPEED_PER_THROTTLE x |throttle| (sensor noise only raises it).
    """
    if logs is None or logs.empty or not {"throttle", "steering", "speed"} <= set(logs.columns):
        return None
    key = "pool_index" if "pool_index" in logs.columns else "run_id"
    steps = max(1, round(window * rate_hz))
    best: dict[float, float] = {}
    runs = 0
    for _, run in logs.groupby(key, sort=False):
        throttle, steering = run["throttle"].to_numpy(np.float64), run["steering"].to_numpy(np.float64)
        if len(run) < TURN_SPEED_MIN_SECONDS * rate_hz or abs(throttle[0]) < 0.05:
            continue
        if np.ptp(throttle) > 1e-9 or np.ptp(steering) > 1e-9:
            continue
        speed = _smooth(np.abs(run["speed"].to_numpy(np.float64)), steps)
        share = float(speed.max()) / (SPEED_PER_THROTTLE * abs(throttle[0]))
        level = round(abs(float(steering[0])), 4)
        best[level] = max(best.get(level, 0.0), share)
        runs += 1
    if not best:
        return None
    levels = np.array(sorted(best))
    keep = np.minimum(np.array([best[lv] for lv in levels]) + TURN_SPEED_MARGIN, 1.0)
    return TurnSpeed(levels, np.minimum.accumulate(keep), runs)


def kinematic_bound(
    maneuver: Any, cfg: SafetyConfig, lever_arm: float = POSE_LEVER_ARM, rate_hz: float = 30.0,
    turn: TurnSpeed | None = None,
) -> tuple[float, float, float]:  # fmt: skip
    """Risk, admissible duration and its risk by the kinematic worst case of the maneuver's schedule.

    Read off the control schedule (any family or reference kind), step by step: speed at most
    SPEED_PER_THROTTLE x the largest |throttle| so far (times, with `turn`, the share the car keeps at
    the smallest |steering| so far: speed only falls as the steering grows), yaw rate at most
    v tan|steering| / L, heading anything. The car may drive until the first step whose worst-case
    rates break a limit, and until the distance it may have covered reaches a wall, unless the path is
    held in a circle (`contained`): then the whole schedule, or its part that is held.
    """
    controls = maneuver_controls(maneuver, rate_hz)
    full = float(maneuver.duration)
    speed = SPEED_PER_THROTTLE * np.maximum.accumulate(np.abs(controls[:, 0]))
    if turn is not None:
        speed = speed * turn.factor(np.minimum.accumulate(np.abs(controls[:, 1])))
    yaw = speed * np.tan(np.abs(controls[:, 1])) / WHEELBASE
    over = (speed > cfg.max_speed) | (yaw > cfg.max_yaw_rate) | (speed * yaw > cfg.max_lateral_acceleration)
    room = max(float(boundary_distance(cfg.arena, cfg.start[0], cfg.start[1])) - cfg.margin, 0.0)
    reach = np.cumsum(speed) / rate_hz  # the most path covered by the end of each step
    if cfg.stop == "live":  # the walls are kept at run time: the limits alone bound the schedule
        room, held = math.inf, np.zeros(len(controls), dtype=bool)
    else:
        held = contained(controls, maneuver, cfg, lever_arm, reach)
    bad = over | ((reach > room) & ~held)
    first = int(np.argmax(bad)) if bad.any() else len(bad)
    if first >= len(bad):
        return 0.0, full, 0.0
    allowed = min(full, math.floor((first - 1) / rate_hz + 1e-9))  # every step up to it is within bounds
    if allowed >= cfg.min_duration:
        return 1.0, float(allowed), 0.0
    return 1.0, 0.0, float("nan")


def monotone_steps(controls: np.ndarray) -> int:
    """Leading steps of a schedule at constant throttle whose steering keeps one side and never eases.

    Over them the kinematic path's curvature only grows: each osculating circle holds the rest of the
    path (Tait-Kneser), as a skidpad's circle or a fishhook's spiral does.
    """
    throttle, steering = controls[:, 0], controls[:, 1]
    side = np.sign(steering[np.flatnonzero(steering)[0]]) if steering.any() else 0.0
    magnitude = side * steering
    ok = (throttle == throttle[0]) & (magnitude >= 0.0)
    ok[1:] &= magnitude[1:] >= magnitude[:-1] - 1e-12
    return int(np.argmin(ok)) if not ok.all() else len(ok)


def contained(
    controls: np.ndarray, maneuver: Any, cfg: SafetyConfig, lever_arm: float, reach: np.ndarray
) -> np.ndarray:
    """(T,) True at the steps where the kinematic worst case keeps the car `margin + path_tolerance` off
    the walls whatever its speed: the schedule's monotone part (`monotone_steps`) after a step whose
    circle holds the rest of it. From the start, that circle's place is known (`circles_fit`: a
    skidpad, or a staircase from its first level); from a later step t0 (a fishhook's ramp) the car is
    somewhere within reach(t0) of the start, and the circle within 2 (r + lever_arm) of it, r up to
    UNDERSTEER_MAX L / tan|steering(t0)|.
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
        if circles_fit(maneuver, cfg, lever_arm, steering=abs(first), nested=not constant, side=side):
            held[:steps] = True
            return held
    magnitude = np.abs(controls[:steps, 1])
    with np.errstate(divide="ignore"):
        radius = np.where(magnitude > 0, UNDERSTEER_MAX * WHEELBASE / np.tan(magnitude), np.inf)
    extent = np.minimum.accumulate(reach[:steps] + 2.0 * (radius + lever_arm))
    held[:steps] = extent <= room
    return held


def circles_fit(
    maneuver: Any, cfg: SafetyConfig, lever_arm: float = POSE_LEVER_ARM, *, steering: float | None = None,
    nested: bool = False, side: float | None = None,
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
    kinematic = WHEELBASE / math.tan(steering)
    radii = np.linspace(kinematic, UNDERSTEER_MAX * kinematic, 64)[:, None]
    sign = maneuver.sign if side is None else float(side)
    cx = x0 - lever_arm * heading[0] + sign * radii * left[0]
    cy = y0 - lever_arm * heading[1] + sign * radii * left[1]
    rho = radii + lever_arm if nested else np.hypot(radii, lever_arm)
    angle = np.linspace(0.0, 2.0 * math.pi, 720, endpoint=False)[None, :]
    clearance = polygon_clearance(cfg.arena, cx + rho * np.cos(angle), cy + rho * np.sin(angle))
    return bool(np.min(clearance) >= cfg.margin + cfg.path_tolerance)


def placed_path(log: pd.DataFrame, cfg: SafetyConfig) -> tuple[np.ndarray, np.ndarray]:
    """The log's path relative to its first pose, placed at the arena's start pose (m)."""
    px, py, yaw = (log[c].to_numpy(dtype=np.float64) for c in ("posX", "posY", "yaw"))
    return place(px, py, (px[0], py[0], yaw[0]), cfg.start)  # as the simulated live stop places it


def stop_rule(cfg: SafetyConfig | None) -> simulator.StopRule | None:
    """The live stop of an enforced `[safety] stop = "live"` as the simulator drives it (None otherwise):
    brake once the pose, placed at the start pose, comes within `margin + stop_buffer` of a wall."""
    if cfg is None or cfg.stop != "live" or not cfg.enforce:
        return None
    return simulator.StopRule(
        polygon=tuple(cfg.arena), start=tuple(cfg.start), distance=cfg.margin + cfg.stop_buffer
    )


def live_stop(log: pd.DataFrame, cfg: SafetyConfig) -> pd.DataFrame:
    """A log that cannot be driven again (a recorded pool's) cut where a live stop would have braked: up
    to the sample before the first whose measured pose comes within `margin + stop_buffer` of a wall
    (the braking is not in it: simulated oracles drive it, `stop_rule`). A log that never comes that
    close is returned whole."""
    x, y = placed_path(log, cfg)
    near = polygon_clearance(cfg.arena, x, y) < cfg.margin + cfg.stop_buffer
    if not near.any():
        return log
    return log.iloc[: max(int(np.argmax(near)), 1)].reset_index(drop=True)


def log_violation(log: pd.DataFrame, cfg: SafetyConfig, rate_hz: float) -> str:
    """What a driven maneuver's log violated first ("" if nothing): arena, speed, yaw_rate or lateral.

    The log's path is taken relative to its first pose and placed at the arena's start pose, so a
    simulator log (starting at the origin) and a car's log (in its own frame) are judged alike.
    """
    x, y = placed_path(log, cfg)
    code = violating(x, y, log["speed"].to_numpy(np.float64), log["angZ"].to_numpy(np.float64), cfg, rate_hz)
    bad = np.flatnonzero(code)
    return REASONS[int(code[bad[0]]) - 1] if len(bad) else ""


def violations(logs: pd.DataFrame, cfg: SafetyConfig, rate_hz: float) -> dict[int, str]:
    """Per pool index in `logs` (rows tagged with `pool_index`): what its maneuver violated ("" none)."""
    return {
        int(index): log_violation(part.reset_index(drop=True), cfg, rate_hz)
        for index, part in logs.groupby("pool_index", sort=False)
    }


def braked_paths(
    x: np.ndarray, y: np.ndarray, cfg: SafetyConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sampled paths (S, T) in the arena frame as a live stop leaves them: each path ends at its first
    point within `margin + stop_buffer` of a wall (the car brakes there and stands within the buffer;
    the rest is NaN, which figures leave out). Returns the cut x, y and the (S,) index of each path's
    trigger point (-1: never braked)."""
    near = polygon_clearance(cfg.arena, x, y) < cfg.margin + cfg.stop_buffer
    braked = near.any(axis=-1)
    trigger = np.where(braked, np.argmax(near, axis=-1), -1)
    after = np.arange(x.shape[-1])[None, :] > np.where(braked, trigger, x.shape[-1])[:, None]
    return np.where(after, np.nan, x), np.where(after, np.nan, y), trigger


def proposal_figure(campaign: Any, path: str | Path) -> Path:
    """Draw the pending proposals of a campaign in its arena (`campaign propose --plot`); return the path.

    The fans come from the model that judged them (the round's, or a warm start's prior model for
    the initial design; without either, the kinematic worst case's reach is drawn instead).
    """
    from activelearn.loop.state import MODEL_FILE, CampaignState
    from activelearn.numerics.models import load_model
    from activelearn.plots import arena_figure, save_figure

    cfg, safety = campaign.cfg, campaign.cfg.safety
    state = CampaignState.load(campaign.directory)
    campaign.cuts = dict(state.cuts)
    pending = state.pending or []
    model_file = campaign.directory / MODEL_FILE
    model = load_model(model_file) if state.rounds and model_file.exists() else campaign.fitting.prior_model()
    maneuvers = [campaign.driven(i) for i in pending]
    proposals = []
    for i, m in zip(pending, maneuvers, strict=True):
        cut = " (cut)" if str(i) in state.cuts else ""
        proposals.append({"label": f"{m.name}{cut}", "risk": state.risks.get(str(i), float("nan"))})
    live = safety.stop == "live" and safety.enforce
    if model is not None and maneuvers:
        seed = derived_seed(cfg.seed, Stream.ROUND, len(state.rounds))  # the campaign's fan of this model
        rollout = fan(model, maneuvers, safety, cfg.simulation.rate_hz, seed)
        for j, proposal in enumerate(proposals):
            n = int(rollout.lengths[j])
            x, y = rollout.x[:, j, :n], rollout.y[:, j, :n]
            if live:  # each path ends where the car would brake: a fan reaching a wall is stopped there
                mean_x, mean_y, _ = braked_paths(x.mean(axis=0)[None], y.mean(axis=0)[None], safety)
                proposal.update(mean=(mean_x[0], mean_y[0]))  # the mean path, itself braked
                x, y, trigger = braked_paths(x, y, safety)
                hit = trigger >= 0
                proposal.update(brakes=(x[hit, trigger[hit]], y[hit, trigger[hit]]), n_paths=len(trigger))
            proposal.update(x=x, y=y)
    reach = None
    if model is None:
        room = float(boundary_distance(safety.arena, safety.start[0], safety.start[1])) - safety.margin
        reach = max(room, 0.0)
    title = f"{cfg.name}: proposals of batch {len(state.batches)}, delta {safety.delta:g}"
    brake_line = None
    if live:
        brake_at = safety.margin + safety.stop_buffer
        title += (f"\nlive stop: the car brakes within margin + stop_buffer = {brake_at:g} m of a wall"
                  "\n(dashed), so a path ends there (x); the risk counts the limits only")  # fmt: skip
        lo, hi = np.min(safety.arena, axis=0), np.max(safety.arena, axis=0)
        gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], 240), np.linspace(lo[1], hi[1], 240))
        brake_line = (gx, gy, polygon_clearance(safety.arena, gx, gy), brake_at)
    fig = arena_figure(safety.arena, safety.start, proposals, margin=safety.margin, reach=reach, title=title,
                       brake_line=brake_line)  # fmt: skip
    return save_figure(fig, path, dpi=110)
