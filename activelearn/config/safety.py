"""The [safety] section (issue 23): the arena a track day happens in, the car's limits and the risk.

The admissibility of candidates is computed in `activelearn.loop.safety`; the arena's geometry is
`activelearn.config.geometry`.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from activelearn.config.base import NonNegative, Positive, _Section
from activelearn.config.geometry import boundary_distance, polygon_area, polygon_self_crossing
from activelearn.errors import ConfigError


class SafetyConfig(_Section):
    """A bounded arena, the car's limits and the risk a proposal may carry (`activelearn.loop.safety`).

    arena: the polygon the car must stay in, vertices [x, y] in metres (closed implicitly; repeating
        the first vertex at the end is allowed). start: the pose [x, y, yaw] every maneuver starts
        from. A candidate is admissible when the model's rollout fan gives it a probability of at
        most `delta` of leaving the arena (its centre closer than `margin` to a wall) or exceeding a
        limit; one whose risk reaches delta later than `min_duration` is cut short there.
    """

    arena: list[tuple[float, float]]
    start: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Defaults a little above what Nigel can do (0.267 m/s, 0.805 rad/s, about 0.17 m/s² at full
    # throttle and full lock), so the arena binds and the limits only where set lower.
    max_speed: Positive = 0.3  # |v|, m/s
    max_yaw_rate: Positive = 0.9  # |ω|, rad/s
    max_lateral_acceleration: Positive = 0.2  # |v·ω|, m/s²
    delta: float = 0.05
    margin: NonNegative = 0.16  # m: half the car's length, so its body stays inside too
    # m, fans only: what a free run's path may still miss of the car's. Free runs integrate the rear axle and
    # place the logged point `pose_lever_arm` ahead of it, so the CG's side slip is in the fan (true rates
    # retrace the logged path to ~1 cm). Measured on safe_track.toml
    # (experiments/investigations/safety_guards.py, results/safety_guards.txt): beside the kinematic guard no
    # admitted true path hit a wall at 0 either, but the nearest came within 8 mm (fan_scale 1) and 28 mm (3)
    # of the margin in the first round; at 0.04, within 43 mm there and 10 mm after 8 maneuvers (a trusted fan
    # 1-2 % off a 2.9-m circle), for 0.4 % fewer admitted seconds (0.16: 1.5 %).
    path_tolerance: NonNegative = 0.04
    min_duration: Positive = 5.0  # s: a candidate cut shorter than this is not admissible
    n_samples: Annotated[int, Field(ge=8)] = 64  # trajectories of the fan
    # Widens the fan's epistemic spread (a std factor) over the model's own: its epistemic std ranks
    # errors but is 2-4x too small on campaign designs (docs/results/calibration.md; z spread 2.9-5.6 on
    # safe_track.toml), and a fan too narrow drives the car into the wall.
    fan_scale: Annotated[float, Field(ge=1)] = 3.0
    # The fan is trusted alone where the model's own epistemic std of the speed stays within this
    # share of the speed along the maneuver; beyond, the kinematic worst case must hold as well
    # (activelearn/loop/safety.py). Measured on safe_track.toml's prior model: 0.001-0.013 on the
    # prior's forward operating points, 0.03-0.08 in reverse, where the fan missed the true speed.
    trust_std: Positive = 0.02
    limit_window: NonNegative = 0.5  # s: rates are averaged over this window before the limits apply
    # The kinematic worst case takes the speed the car kept in its own logged steady turns (the
    # prior's and the campaign's skidpads and straights, `activelearn.loop.safety.turn_speed`) instead
    # of assuming none is lost in turns; false: none is.
    measured_turn_speed: bool = True
    # How the walls are kept: "planned" (each proposal is admitted, or cut short in advance, by its fan's
    # risk of meeting a wall or breaking a limit) or "live" (the car brakes as soon as its measured pose
    # comes within `margin + stop_buffer` of a wall, so only the limits are judged by the fan; the log
    # ends there). Nigel stops within 1.7 cm and 0.17 s from any speed in MuJoCo (results/bench_safety.txt).
    stop: Literal["planned", "live"] = "planned"
    # m, live stop only: what the car travels between the pose that triggers the stop and standing still
    # (braking plus the pose's latency: ~0.27 m/s x latency); 0.05 m is an automatic stop on a 30-Hz pose.
    stop_buffer: NonNegative = 0.05
    enforce: bool = True  # false: measure risk and violations only, pick from every candidate

    @field_validator("arena", mode="after")
    @classmethod
    def _check_arena(cls, value: list[tuple[float, float]]) -> list[tuple[float, float]]:
        if len(value) > 1 and value[0] == value[-1]:
            value = value[:-1]
        if any(not math.isfinite(c) for vertex in value for c in vertex):
            raise ValueError("vertices must be finite")
        if len(value) < 3 or len(set(value)) < 3:
            raise ValueError("the polygon is open: it needs 3 or more distinct vertices")
        crossing = polygon_self_crossing(value)
        if crossing is not None:
            i, j = crossing
            raise ValueError(f"the polygon crosses itself (edge {i} and edge {j})")
        if abs(polygon_area(value)) < 1e-9:
            raise ValueError("the polygon is open: its vertices enclose no area")
        return value

    @field_validator("delta")
    @classmethod
    def _check_delta(cls, value: float) -> float:
        if not 0.0 < value < 1.0:
            raise ValueError("delta must lie in (0, 1)")
        return value

    @model_validator(mode="after")
    def _start_inside(self) -> SafetyConfig:
        if not all(math.isfinite(c) for c in self.start):
            raise ConfigError("start", list(self.start), "must be finite")
        room = float(boundary_distance(self.arena, self.start[0], self.start[1]))
        if room <= self.margin:
            where = "outside the arena" if room <= 0 else f"within margin = {self.margin} m of a wall"
            raise ConfigError("start", list(self.start), f"the start lies {where}")
        return self
