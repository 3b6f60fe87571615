"""A closed-loop stop at the walls of an arena: `collect(..., stop=StopRule(...))`.

The rule is judged by `collect` itself at every log sample, on the car's true (noise-free) pose:
the pose is taken relative to the run's first pose and placed at `start` in the arena's frame. At
the first sample j whose placed pose lies closer than `distance` to the polygon's boundary (or
outside it) the throttle becomes 0 (the brake) from sample j + 1 on, one log sample of latency (plus
the vehicle's own actuation `latency`); the steering is held at sample j's. The run then goes on,
past the maneuver's own end if need be, until the car stands (|speed| below `still_speed`) or
`settle` seconds after the trigger, and its log ends there. The braking rows are logged like any
other (throttle 0).

Sensor noise never feeds the stop, as it never feeds the physics: noise-free and noisy logs of a
maneuver share one trajectory (the pose noise, ~2 mm, is small beside any useful buffer).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from simulator.errors import ManeuverError


@dataclass(frozen=True)
class StopRule:
    """Brake near the walls of a polygon arena (see the module docstring).

    polygon: the arena's vertices (x, y) in metres, closed implicitly; start: the pose (x, y, yaw)
    the run's first pose is placed at; distance: the clearance (m) below which the car brakes;
    still_speed: |forward speed| (m/s) at which the braked car counts as standing; settle: the
    longest the log runs on after the trigger (s).
    """

    polygon: tuple[tuple[float, float], ...]
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    distance: float = 0.0
    still_speed: float = 0.002
    settle: float = 1.0

    def __post_init__(self) -> None:
        try:
            polygon = tuple((float(x), float(y)) for x, y in self.polygon)
            start = tuple(float(v) for v in self.start)
        except (TypeError, ValueError):
            raise ManeuverError("stop.polygon", self.polygon, "must be vertices (x, y)") from None
        if len(polygon) < 3 or not all(math.isfinite(c) for v in polygon for c in v):
            raise ManeuverError("stop.polygon", self.polygon, "must be 3 or more finite vertices (x, y)")
        if len(start) != 3 or not all(math.isfinite(c) for c in start):
            raise ManeuverError("stop.start", self.start, "must be a finite pose (x, y, yaw)")
        object.__setattr__(self, "polygon", polygon)
        object.__setattr__(self, "start", start)
        for name in ("distance", "still_speed", "settle"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ManeuverError(f"stop.{name}", value, "must be a finite number")
            if name == "settle" and value <= 0:
                raise ManeuverError(f"stop.{name}", value, "must be > 0")
            if value < 0:
                raise ManeuverError(f"stop.{name}", value, "must be >= 0")
            object.__setattr__(self, name, float(value))

    def key(self) -> str:
        """A short stable digest of the rule: caches of stopped logs are keyed by it."""
        text = repr((self.polygon, self.start, self.distance, self.still_speed, self.settle))
        return hashlib.sha256(text.encode()).hexdigest()[:10]

    def placed(
        self, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, origin: tuple[float, float, float]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Positions relative to `origin` (the run's first pose), placed at `start` (m)."""
        return place(x, y, origin, self.start)

    def clearance(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Signed distance (m) of points to the polygon's boundary: > 0 inside, < 0 outside."""
        px = np.atleast_1d(np.asarray(x, dtype=float))[:, None]
        py = np.atleast_1d(np.asarray(y, dtype=float))[:, None]
        v = np.asarray(self.polygon)
        ax, ay = v[:, 0][None, :], v[:, 1][None, :]
        bx, by = np.roll(v[:, 0], -1)[None, :], np.roll(v[:, 1], -1)[None, :]
        ex, ey = bx - ax, by - ay
        t = np.clip(((px - ax) * ex + (py - ay) * ey) / (ex * ex + ey * ey), 0.0, 1.0)
        dist = np.min(np.hypot(px - ax - t * ex, py - ay - t * ey), axis=1)
        crosses = ((ay > py) != (by > py)) & (px < ax + (py - ay) * ex / np.where(ey == 0, 1.0, ey))
        inside = np.sum(crosses, axis=1) % 2 == 1
        return np.where(inside, dist, -dist)


def place(
    x: np.ndarray, y: np.ndarray, origin: tuple[float, float, float], start: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Positions (m) taken relative to the pose `origin` (x, y, yaw) and placed at the pose `start`:
    how a run's path lies in an arena whatever frame its log was recorded in."""
    x0, y0, yaw0 = start
    turn = yaw0 - origin[2]
    c, s = math.cos(turn), math.sin(turn)
    dx, dy = np.asarray(x) - origin[0], np.asarray(y) - origin[1]
    return x0 + c * dx - s * dy, y0 + s * dx + c * dy


# Called by `collect` on its per-run book-keeping (`simulator.collect._Run`) after every chunk.


def brake_on_trigger(stop: StopRule, run: Any, k: int, kk: int, settle: int, vehicle: Any) -> int | None:
    """Judge the run's samples k..kk-1 (true poses); at the first that triggers, brake from the next
    sample on (throttle 0, steering held), make room for `settle` samples after it and return it."""
    ch = vehicle.decode(run.sens[k:kk])
    if run.origin is None:
        run.origin = (float(ch["posX"][0]), float(ch["posY"][0]), float(ch["yaw"][0]))
    with np.errstate(invalid="ignore"):
        x, y = stop.placed(ch["posX"], ch["posY"], ch["yaw"], run.origin)
        near = stop.clearance(x, y) < stop.distance
    if not near.any():
        return None
    j = k + int(np.argmax(near))
    run.stopped_at = j
    run.extend(j + 1 + settle, vehicle)
    hold = run.steering[j]
    run.throttle[j + 1 :] = 0.0
    run.steering[j + 1 :] = hold
    run.ctrl[j + 1 :] = vehicle.controls(0.0, hold)
    return j


def end_when_standing(stop: StopRule, run: Any, k: int, kk: int, vehicle: Any) -> None:
    """End a braking run's log at its first sample after the trigger (among k..kk-1) that stands."""
    if run.stopped_at is None:
        return
    first = max(k, run.stopped_at + 1)
    if first < kk:
        still = np.flatnonzero(np.abs(vehicle.decode(run.sens[first:kk])["speed"]) < stop.still_speed)
        if len(still):
            run.n = first + int(still[0]) + 1
