"""Benchmark maneuvers of the reference dataset and their control schedules u(t) = (throttle, steering).

Schedules follow shared/reference/nigel.md (and the reference open-loop controller script):
  straight  constant throttle, steering 0
  skidpad   constant throttle, constant steering sign * delta
  fishhook  constant throttle, steering ramp sign * min(0.006 t, delta); the reference grid uses
            delta = 0.5236 (the ramp reaches the steering limit at 87.3 s)
  slalom    constant throttle, 3 s straight, then sign * delta * cos(0.9 (t - 3))
  eight     constant throttle, steering sign * delta, the sign flipping after each full turn judged
            from the heading (closed loop, run by simulator.collect in chunks)
`direction` mirrors the steering sign: ccw (+1) turns left first and gives a positive yaw rate.
Commands are held constant between log samples (a controller running at the log rate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real
from typing import Any

import numpy as np

from simulator.datasheet import LOG_RATE_HZ
from simulator.errors import ManeuverError
from simulator.vehicle import MAX_SPEED, STEERING_LIMIT, THROTTLE_LIMIT, WHEELBASE, reference_speed

KINDS = ("straight", "skidpad", "fishhook", "slalom", "eight")
DIRECTIONS = ("ccw", "cw")
FISHHOOK_RATE = 0.006  # rad/s, steering ramp rate of the reference fishhook
SLALOM_DELAY = 3.0  # s driven straight before the slalom starts
SLALOM_FREQUENCY = 0.9  # rad/s, angular frequency of the slalom steering

# Kinematic approximation of the simulator's steady turn, used only where the closed-loop eight must
# be predicted without simulating (nominal_controls). Fitted to the skidpad grid of the MuJoCo model
# (experiments/benchmarks/bench_simulator.py prints the check):
#   speed   v = v_ref(throttle) * (1 - SCRUB_SPEED_LOSS * (delta / 0.5236)^2)
#   radius  R = L / tan(delta) * (UNDERSTEER_BASE + UNDERSTEER_SPEED * v / 0.267)
# Refitted after the turn-speed calibration of issue 15 (max yaw-rate error 4.7 % over the grid; the
# understeer of the calibrated model hardly changes with speed, hence the small negative slope).
LOOP_TIME_LIMIT = 3600.0  # s: the longest loop of an eight; one that never turns never flips
SCRUB_SPEED_LOSS = 0.293
UNDERSTEER_BASE = 1.036
UNDERSTEER_SPEED = -0.015


def _check_real(field: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ManeuverError(field, value, "must be a number")
    number = float(value)
    if not math.isfinite(number):
        raise ManeuverError(field, value, "must be finite")
    return number


def _fmt(value: float, decimals: int) -> str:
    """Fixed decimals when exact at that precision, else the shortest exact repr (keeps names unique)."""
    text = f"{value:.{decimals}f}"
    return text if float(text) == value else repr(value)


@dataclass(frozen=True)
class Maneuver:
    """One scripted maneuver: kind, operating throttle and steering amplitude, direction, duration (s)."""

    kind: str
    throttle: float
    steering: float = 0.0
    direction: str = "ccw"
    duration: float = 90.0

    def __post_init__(self) -> None:
        if not isinstance(self.kind, str) or self.kind not in KINDS:
            raise ManeuverError("kind", self.kind, f"must be one of {', '.join(KINDS)}")
        throttle = _check_real("throttle", self.throttle)
        if not -THROTTLE_LIMIT <= throttle <= THROTTLE_LIMIT:
            raise ManeuverError("throttle", self.throttle, "must lie in [-1, 1]")
        steering = _check_real("steering", self.steering)
        if steering < 0.0:
            raise ManeuverError("steering", self.steering, "must be >= 0 (direction carries the sign)")
        if steering >= 0.5 * math.pi:
            raise ManeuverError("steering", self.steering, "must be < pi/2 rad (collect checks the car's)")
        if not isinstance(self.direction, str) or self.direction not in DIRECTIONS:
            raise ManeuverError("direction", self.direction, "must be 'cw' or 'ccw'")
        duration = _check_real("duration", self.duration)
        if duration <= 0.0:
            raise ManeuverError("duration", self.duration, "must be > 0")
        # normalise ints to floats so equal maneuvers compare and hash equal
        object.__setattr__(self, "throttle", throttle)
        object.__setattr__(self, "steering", steering)
        object.__setattr__(self, "duration", duration)

    @property
    def sign(self) -> int:
        """Steering sign of the direction: +1 for ccw (left), -1 for cw."""
        return 1 if self.direction == "ccw" else -1

    @property
    def name(self) -> str:
        """Stable readable identifier, e.g. skidpad_ccw_t0.60_s0.3142_d90."""
        return (
            f"{self.kind}_{self.direction}_t{_fmt(self.throttle, 2)}"
            f"_s{_fmt(self.steering, 4)}_d{self.duration:g}"
        )

    @property
    def op_steering(self) -> float:
        """Unsigned steering amplitude actually applied (0 for straight, which ignores steering)."""
        return 0.0 if self.kind == "straight" else self.steering


@dataclass(frozen=True, eq=False)
class Replay:
    """Recorded commands replayed open loop: sample k holds (throttles[k], steerings[k]) for 1 / rate_hz s.

    `collect` runs it like a maneuver (kind "replay", logged at the same rate), e.g. to simulate the
    controls of a real car's log. Steering is signed (+ left); `direction` is that of the first clear
    turn. The arrays are copied and made read-only.
    """

    label: str
    throttles: np.ndarray
    steerings: np.ndarray
    rate_hz: float = LOG_RATE_HZ

    kind = "replay"

    def __post_init__(self) -> None:
        if not isinstance(self.label, str) or not self.label:
            raise ManeuverError("label", self.label, "must be a non-empty string")
        rate = _check_real("rate_hz", self.rate_hz)
        if rate <= 0.0:
            raise ManeuverError("rate_hz", self.rate_hz, "must be > 0")
        arrays = {}
        for field in ("throttles", "steerings"):
            try:
                values = np.array(getattr(self, field), dtype=float)
            except (TypeError, ValueError):
                raise ManeuverError(field, getattr(self, field), "must be a 1-D array of numbers") from None
            if values.ndim != 1 or len(values) == 0:
                raise ManeuverError(field, values.shape, "must be a non-empty 1-D array")
            if not np.isfinite(values).all():
                bad = int(np.argmin(np.isfinite(values)))
                raise ManeuverError(field, bad, "holds a non-finite value at this index")
            values.flags.writeable = False
            arrays[field] = values
        if len(arrays["throttles"]) != len(arrays["steerings"]):
            raise ManeuverError("steerings", len(arrays["steerings"]), "must be as long as throttles")
        for field, limit in (("throttles", THROTTLE_LIMIT), ("steerings", 0.5 * math.pi)):
            largest = float(np.abs(arrays[field]).max())
            if largest > limit:
                raise ManeuverError(field, largest, f"must lie in [-{limit}, {limit}]")
        object.__setattr__(self, "rate_hz", rate)
        object.__setattr__(self, "throttles", arrays["throttles"])
        object.__setattr__(self, "steerings", arrays["steerings"])

    @property
    def name(self) -> str:
        """The label: the run id of the replay in a collected table."""
        return self.label

    @property
    def n(self) -> int:
        """Number of command samples."""
        return len(self.throttles)

    @property
    def duration(self) -> float:
        """Time (s) from the first to the last command sample."""
        return (self.n - 1) / self.rate_hz

    @property
    def throttle(self) -> float:
        """Median throttle (the operating throttle logged in `op_throttle`)."""
        return float(np.median(self.throttles))

    @property
    def op_steering(self) -> float:
        """Largest |steering| applied."""
        return float(np.abs(self.steerings).max())

    @property
    def steering(self) -> float:
        """Same as op_steering (Maneuver's field name)."""
        return self.op_steering

    @property
    def sign(self) -> int:
        """Sign of the first clear turn: +1 left (ccw), -1 right (cw); +1 if it never turns."""
        clear = self.steerings[np.abs(self.steerings) > 0.5 * self.op_steering] if self.op_steering else []
        return -1 if len(clear) and clear[0] < 0 else 1

    @property
    def direction(self) -> str:
        """ccw or cw, from `sign`."""
        return "ccw" if self.sign > 0 else "cw"


def sample_times(duration: float, rate_hz: float) -> np.ndarray:
    """Nominal log times k / rate for k = 0 .. floor(duration * rate), both ends included."""
    n = math.floor(duration * rate_hz + 1e-9) + 1
    return np.arange(n) / rate_hz


def open_loop_steering(maneuver: Maneuver, t: np.ndarray) -> np.ndarray:
    """Signed steering (rad) at times t for the open-loop kinds; the eight's first loop for eight."""
    t = np.asarray(t, dtype=float)
    amp = maneuver.op_steering
    sign = maneuver.sign
    if maneuver.kind == "straight":
        return np.zeros_like(t)
    if maneuver.kind in ("skidpad", "eight"):
        return np.full_like(t, sign * amp)
    if maneuver.kind == "fishhook":
        return sign * np.minimum(FISHHOOK_RATE * t, amp)
    # slalom
    wave = amp * np.cos(SLALOM_FREQUENCY * (t - SLALOM_DELAY))
    return sign * np.where(t < SLALOM_DELAY, 0.0, wave)


def nominal_turn(throttle: float, steering: float) -> tuple[float, float]:
    """Approximate steady (speed m/s, |yaw rate| rad/s) of a constant (throttle, steering) turn."""
    speed = float(reference_speed(throttle)) * (1.0 - SCRUB_SPEED_LOSS * (steering / STEERING_LIMIT) ** 2)
    if steering == 0.0:
        return speed, 0.0
    understeer = UNDERSTEER_BASE + UNDERSTEER_SPEED * abs(speed) / MAX_SPEED
    radius = WHEELBASE / math.tan(steering) * understeer
    return speed, abs(speed) / radius


def eight_loop_time(throttle: float, steering: float) -> float:
    """Nominal time (s) of one full turn of a constant (throttle, steering) turn: the eight's flip period.

    2 pi / w with w the yaw rate of `nominal_turn`; LOOP_TIME_LIMIT where the car does not turn (no
    flip in any maneuver of sensible length).
    """
    _, yaw_rate = nominal_turn(throttle, steering)
    if yaw_rate <= 0.0:
        return LOOP_TIME_LIMIT
    return float(min(max(2.0 * math.pi / yaw_rate, 0.5), LOOP_TIME_LIMIT))


def alternating(t: np.ndarray, loop_time: float) -> np.ndarray:
    """+1 during the first `loop_time` s, -1 during the next, and so on: an eight's steering sign."""
    loop = np.floor(np.asarray(t, dtype=float) / loop_time + 1e-9)
    return np.where(loop % 2 == 0, 1.0, -1.0)


def nominal_controls(maneuver: Maneuver, rate_hz: float = LOG_RATE_HZ) -> np.ndarray:
    """(T, 2) array of (throttle, signed steering) the maneuver applies at each log step, without simulating.

    Rows match the rows `collect` logs for the same maneuver and rate. A family member
    (`simulator.families.FamilyManeuver`) returns its own schedule. For the eight, whose real
    schedule flips on measured heading, the flips are placed every 2 pi / w, with w the yaw rate
    of `nominal_turn` (kinematic turn corrected for the simulator's scrub and understeer): the
    schedule of its figure_eight member (`simulator.families.as_family`).
    """
    rate = _check_real("rate_hz", rate_hz)
    if rate <= 0.0:
        raise ManeuverError("rate_hz", rate_hz, "must be > 0")
    if not isinstance(maneuver, Maneuver) and callable(getattr(maneuver, "controls", None)):
        return maneuver.controls(rate)  # an open-loop family member (simulator.families)
    t = sample_times(maneuver.duration, rate)
    steering = open_loop_steering(maneuver, t)
    if maneuver.kind == "eight":
        steering = steering * alternating(t, eight_loop_time(maneuver.throttle, maneuver.op_steering))
    throttle = np.full_like(t, maneuver.throttle)
    return np.column_stack([throttle, steering])
