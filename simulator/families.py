"""Parametrised maneuver families: open-loop control signals u(t) = (throttle, steering), named parameters.

A family maps named parameters to a command schedule, drivable open loop by a script or a person
(hold each command until the next sample). Steering is given towards the maneuver's `direction`
(ccw = left, +); `FamilyManeuver` applies the sign. Times t are seconds since the start.

  slalom         throttle, amplitude A, frequency f (Hz), delay (s):  A cos(2 pi f (t - delay)) after
                 driving `delay` s straight. f = 0 is a skidpad, A = 0 a straight.
  fishhook       throttle, rate (rad/s), amplitude A:  min(rate t, A).
  throttle_step  throttle_start, throttle_end, switch_time (s), ramp_time (s), steering: the throttle
                 goes from start to end at switch_time, linearly over ramp_time (0 = a step); end 0
                 brakes, a negative end reverses. Steering is held constant.
  chirp          throttle, amplitude A, f0, f1 (Hz):  A sin(2 pi (f0 t + (f1 - f0) t^2 / (2 T))), T the
                 span (the duration), so the frequency moves linearly from f0 to f1.
  multisine      throttle, amplitude A, f_low, f_high (Hz): MULTISINE_TONES tones evenly spread over
                 [f_low, f_high] with Schroeder phases, scaled so the peak over the span is A.
  prbs           throttle, amplitude A, switch_time h (s), seed: +A or -A held for h s, the level of
                 every interval after the first (+A) drawn by numpy's Generator(seed); reproducible.
  staircase      throttle, start A0, amplitude A, hold h (s): a skidpad whose steering steps from A0 to A
                 in STAIRCASE_LEVELS equal levels, each held h s, the last (A) to the end. A0 < A: the
                 car goes round ever smaller circles, each inside the last (several operating points
                 of high steering in the room of one skidpad); A0 = A is a skidpad.
  figure_eight   throttle, amplitude A, loop_time T (s): steering +A for T s, then -A for T s, and so on:
                 an eight driven on a stopwatch. T = the time of one full turn is the reference eight.

The standard vehicle-dynamics tests, open loop (`froude` families: their default pool ranges are the
standards' full-size figures Froude-scaled to the default car, and a config for another car scales them
to it; see FROUDE_REFERENCE):
  ramp_steer          throttle, amplitude A, rate (rad/s), settle (s): ISO 4138's steady-state circular
                      test, ramp-steer variant: straight for `settle` s, then the steering rises linearly
                      at `rate` to A and is held: min(rate (t - settle), A) after the settle. A fishhook
                      with a straight start and a quasi-static rate (a slowly increasing steer).
  step_steer          throttle, amplitude A, step_time (s), rise_time (s): ISO 7401's step steer: straight
                      until step_time, then a linear ramp to A over rise_time (the standard's fast ramp,
                      >= 200 deg/s at the steering wheel), held. rise_time 0 is an ideal step.
  sine_with_dwell     throttle, amplitude A, frequency f (Hz), dwell (s), delay (s): NHTSA FMVSS 126's
                      sine with dwell: after `delay` s straight, one cycle A sin(2 pi f tau) whose second
                      peak (-A, at tau = 3 / 4f) is held for `dwell` s before the last quarter back to 0.
  double_lane_change  throttle, amplitude A, period P (s), gap G (s), delay (s): ISO 3888's double lane
                      change, open loop (no path follower, so the car need not stay in the lanes): after
                      `delay` s straight, A sin(2 pi tau / P) for one period (the lane change out), G s
                      straight, then -A sin(2 pi tau' / P) for one period (the change back), then 0.

All five reference kinds are special cases (`as_family`). The reference eight flips its steering when
the measured heading has turned a full circle (closed loop); its family member flips every
`loop_time` s, taken from the nominal turn (`simulator.maneuvers.eight_loop_time`, the schedule
campaigns already plan eights with) or measured on the car (`measured_loop_time` of a logged eight).
The two drive apart where the car's turn takes longer or shorter than T (measured in MuJoCo:
`tests/test_families.py`, `experiments/results/figure_eight.txt`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import pandas as pd

from simulator.errors import ManeuverError
from simulator.maneuvers import (
    DIRECTIONS,
    FISHHOOK_RATE,
    LOOP_TIME_LIMIT,
    SLALOM_DELAY,
    SLALOM_FREQUENCY,
    Maneuver,
    _check_real,
    alternating,
    eight_loop_time,
    sample_times,
)
from simulator.vehicle import STEERING_LIMIT, THROTTLE_LIMIT
from simulator.vehicles import load_vehicle

MULTISINE_TONES = 5
STAIRCASE_LEVELS = 4  # steering levels of a staircase, A0 first and A last
REFERENCE_RATE = 30.0  # Hz: the rate at which op_throttle / op_steering are read off the schedule
_FINE_RATE = 100.0  # Hz: grid on which the multisine's peak is normalised (independent of the log rate)

Signal = Callable[[Mapping[str, float], np.ndarray, float], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Parameter:
    """A family parameter: name, allowed [low, high], unit, the short tag in names, default pool range."""

    name: str
    low: float
    high: float
    unit: str
    tag: str
    pool: tuple[float, float]
    integer: bool = False  # a seed: drawn as an integer, not a coordinate of the design space


@dataclass(frozen=True)
class Family:
    """A family of open-loop maneuvers: its parameters and the signal they define."""

    name: str
    parameters: tuple[Parameter, ...]
    signal: Signal
    doc: str
    # A standard test whose default pool ranges are a full-size car's Froude-scaled to the default car:
    # a config for another car scales its time and frequency parameters by that car's time scale too.
    froude: bool = False

    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names in order."""
        return tuple(p.name for p in self.parameters)

    @property
    def continuous(self) -> tuple[Parameter, ...]:
        """The parameters that span the design space (seeds excluded)."""
        return tuple(p for p in self.parameters if not p.integer)

    def parameter(self, name: str) -> Parameter:
        """The parameter called `name` (ManeuverError naming it if the family has none)."""
        for p in self.parameters:
            if p.name == name:
                return p
        choices = ", ".join(self.names)
        raise ManeuverError(name, name, f"is not a parameter of {self.name}; choose from {choices}")


# Steering parameters may take any angle below pi/2 (collect checks the car's own lock); their default pool
# ranges are the default car's (a config for another car scales them: activelearn.config.vehicle).
ANGLE_MAX = 1.5708  # rad
_T = Parameter("throttle", -THROTTLE_LIMIT, THROTTLE_LIMIT, "", "t", (0.2, 1.0))
_A = Parameter("amplitude", 0.0, ANGLE_MAX, "rad", "a", (0.1, STEERING_LIMIT))


def _const(value: float, t: np.ndarray) -> np.ndarray:
    return np.full_like(t, value)


def _slalom(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    wave = p["amplitude"] * np.cos(2.0 * math.pi * p["frequency"] * (t - p["delay"]))
    return _const(p["throttle"], t), np.where(t < p["delay"], 0.0, wave)


def _fishhook(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    return _const(p["throttle"], t), np.minimum(p["rate"] * t, p["amplitude"])


def _step_share(t: np.ndarray, start: float, ramp: float) -> np.ndarray:
    """0 before `start`, 1 from `ramp` s after it, linear between (a jump at `start` when `ramp` is 0)."""
    if ramp > 0.0:
        return np.clip((t - start) / ramp, 0.0, 1.0)
    return (t >= start).astype(float)


def _throttle_step(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    share = _step_share(t, p["switch_time"], p["ramp_time"])
    throttle = p["throttle_start"] + share * (p["throttle_end"] - p["throttle_start"])
    return throttle, _const(p["steering"], t)


def _chirp(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    f0, f1 = p["f0"], p["f1"]
    phase = 2.0 * math.pi * (f0 * t + (f1 - f0) * t**2 / (2.0 * span))
    return _const(p["throttle"], t), p["amplitude"] * np.sin(phase)


def _multisine_wave(p: Mapping[str, float], t: np.ndarray) -> np.ndarray:
    k = np.arange(1, MULTISINE_TONES + 1)
    freqs = np.linspace(p["f_low"], p["f_high"], MULTISINE_TONES)
    phases = -math.pi * k * (k - 1) / MULTISINE_TONES  # Schroeder: a low crest factor
    return np.sin(2.0 * math.pi * freqs[:, None] * t[None, :] + phases[:, None]).sum(axis=0)


def _multisine(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    fine = np.arange(math.floor(span * _FINE_RATE) + 1) / _FINE_RATE
    peak = float(np.abs(_multisine_wave(p, fine)).max()) or 1.0
    steering = np.clip(p["amplitude"] * _multisine_wave(p, t) / peak, -p["amplitude"], p["amplitude"])
    return _const(p["throttle"], t), steering


def _prbs(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    hold = p["switch_time"]
    n = math.floor(span / hold + 1e-9) + 1
    levels = np.where(np.random.default_rng(int(p["seed"])).integers(0, 2, n) == 1, 1.0, -1.0)
    levels[0] = 1.0  # the first turn goes towards the direction
    index = np.minimum(np.floor(t / hold + 1e-9).astype(int), n - 1)
    return _const(p["throttle"], t), p["amplitude"] * levels[index]


def _staircase(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    level = np.minimum(np.floor(t / p["hold"] + 1e-9), STAIRCASE_LEVELS - 1)
    steering = p["start"] + (p["amplitude"] - p["start"]) * level / (STAIRCASE_LEVELS - 1)
    return _const(p["throttle"], t), steering


def _figure_eight(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    return _const(p["throttle"], t), p["amplitude"] * alternating(t, p["loop_time"])


def _ramp_steer(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    return _const(p["throttle"], t), np.clip(p["rate"] * (t - p["settle"]), 0.0, p["amplitude"])


def _step_steer(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    return _const(p["throttle"], t), p["amplitude"] * _step_share(t, p["step_time"], p["rise_time"])


def _sine_with_dwell(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    f, dwell = p["frequency"], p["dwell"]
    tau = t - p["delay"]
    second_peak = 0.75 / f
    # the phase stops at the second peak for `dwell` s, then runs on to the end of the cycle
    phase = np.where(tau < second_peak, tau, np.maximum(tau - dwell, second_peak))
    wave = p["amplitude"] * np.sin(2.0 * math.pi * f * phase)
    return _const(p["throttle"], t), np.where((tau >= 0.0) & (tau < 1.0 / f + dwell), wave, 0.0)


def _double_lane_change(p: Mapping[str, float], t: np.ndarray, span: float) -> tuple[np.ndarray, np.ndarray]:
    period, amplitude = p["period"], p["amplitude"]
    out = t - p["delay"]
    back = out - period - p["gap"]

    def cycle(tau: np.ndarray) -> np.ndarray:
        return np.where((tau >= 0.0) & (tau < period), amplitude * np.sin(2.0 * math.pi * tau / period), 0.0)

    return _const(p["throttle"], t), cycle(out) - cycle(back)


def _hz(name: str, tag: str, pool: tuple[float, float]) -> Parameter:
    return Parameter(name, 0.0, 2.0, "Hz", tag, pool)


def _seconds(name: str, tag: str, pool: tuple[float, float], low: float = 0.0) -> Parameter:
    return Parameter(name, low, 600.0, "s", tag, pool)


def _throttle(name: str, tag: str, pool: tuple[float, float]) -> Parameter:
    return Parameter(name, -THROTTLE_LIMIT, THROTTLE_LIMIT, "", tag, pool)


_STEP = (
    _throttle("throttle_start", "t", (0.2, 1.0)),
    _throttle("throttle_end", "e", (-0.5, 1.0)),
    _seconds("switch_time", "at", (2.0, 10.0)),
    _seconds("ramp_time", "r", (0.0, 5.0)),
    Parameter("steering", 0.0, ANGLE_MAX, "rad", "s", (0.0, STEERING_LIMIT)),
)
_SEED = Parameter("seed", 0, 2**31 - 1, "", "seed", (0, 9999), integer=True)

# The standard tests are written for a full-size car: their default pool ranges are its figures at equal
# Froude number v^2 / (g L), scaled to the default car by the wheelbase L (times x sqrt(L / L_ref),
# frequencies / it) and by full lock (road-wheel angles and rates x lock / lock_ref). A config for another
# car scales them back to that car (activelearn.config.vehicle): a full-size car's config gets the
# standards' own figures.
FROUDE_REFERENCE = "bmw320i"  # the full-size car whose figures the standards' values are
_DEFAULT_CAR, _REFERENCE_CAR = load_vehicle("nigel"), load_vehicle(FROUDE_REFERENCE)
FROUDE_TIME = math.sqrt(_DEFAULT_CAR.wheelbase / _REFERENCE_CAR.wheelbase)  # the default car's time scale
_LOCK = _DEFAULT_CAR.steering.limit.value / _REFERENCE_CAR.steering.limit.value


def _full_size(name: str, unit: str, tag: str, full: tuple[float, float], low: float = 0.0,
               high: float = 600.0) -> Parameter:
    """A standard's parameter whose default pool range `full` is given for the full-size car."""
    scale = {"s": FROUDE_TIME, "Hz": 1.0 / FROUDE_TIME, "rad/s": _LOCK / FROUDE_TIME}[unit]
    return Parameter(name, low, high, unit, tag, (full[0] * scale, full[1] * scale))


_SETTLE = (3.0, 10.0)  # s, full size: straight at speed before the steering input
_STANDARDS = (
    Family("ramp_steer", (_T, _A, _full_size("rate", "rad/s", "r", (0.005, 0.03), low=1e-4, high=2.0),
                          _full_size("settle", "s", "w", _SETTLE)),
           _ramp_steer, "ISO 4138 ramp steer: straight, then a slow steering ramp to a hold", froude=True),
    Family("step_steer", (_T, _A, _full_size("step_time", "s", "at", _SETTLE),
                          _full_size("rise_time", "s", "r", (0.05, 0.2))),
           _step_steer, "ISO 7401 step steer: straight, then a fast ramp to a hold", froude=True),
    Family("sine_with_dwell", (_T, _A, _full_size("frequency", "Hz", "f", (0.5, 0.9), low=0.01, high=10.0),
                               _full_size("dwell", "s", "h", (0.25, 0.75)),
                               _full_size("delay", "s", "w", _SETTLE)),
           _sine_with_dwell, "FMVSS 126 sine with dwell: one cycle, its second peak held", froude=True),
    Family("double_lane_change", (_T, _A, _full_size("period", "s", "p", (1.0, 2.5), low=0.01),
                                  _full_size("gap", "s", "g", (0.5, 1.5)),
                                  _full_size("delay", "s", "w", _SETTLE)),
           _double_lane_change, "ISO 3888 double lane change, open loop: two opposite sine periods",
           froude=True),
)  # fmt: skip
FAMILIES: dict[str, Family] = {
    f.name: f
    for f in (
        Family("slalom", (_T, _A, _hz("frequency", "f", (0.02, 0.5)), _seconds("delay", "w", (0.0, 5.0))),
               _slalom, "cosine steering after a straight start (skidpad at f = 0)"),
        Family("fishhook", (_T, Parameter("rate", 1e-4, 2.0, "rad/s", "r", (0.006, 0.3)), _A),
               _fishhook, "steering ramp to a hold"),
        Family("throttle_step", _STEP,
               _throttle_step, "throttle step or ramp (accelerate, brake, reverse) at constant steering"),
        Family("chirp", (_T, _A, _hz("f0", "fa", (0.02, 0.3)), _hz("f1", "fb", (0.02, 0.6))),
               _chirp, "steering sine sweeping linearly from f0 to f1"),
        Family("multisine", (_T, _A, _hz("f_low", "fl", (0.02, 0.2)), _hz("f_high", "fh", (0.2, 0.8))),
               _multisine, "sum of tones with Schroeder phases"),
        Family("prbs", (_T, _A, _seconds("switch_time", "h", (0.5, 5.0), low=0.05), _SEED),
               _prbs, "pseudo-random binary steering sequence"),
        Family("staircase", (_T, Parameter("start", 0.0, ANGLE_MAX, "rad", "s", (0.1, 0.3)), _A,
                             _seconds("hold", "h", (3.0, 10.0), low=0.05)),
               _staircase, "skidpad whose steering steps from start to amplitude"),
        Family("figure_eight", (_T, _A, Parameter("loop_time", 0.5, LOOP_TIME_LIMIT, "s", "T", (4.0, 20.0))),
               _figure_eight, "steering +A and -A alternating every loop_time s (open-loop eight)"),
        *_STANDARDS,
    )
}  # fmt: skip


def family(name: str) -> Family:
    """The registered family `name` (ManeuverError naming `family` otherwise)."""
    if not isinstance(name, str) or name not in FAMILIES:
        raise ManeuverError("family", name, f"must be one of {', '.join(FAMILIES)}")
    return FAMILIES[name]


def _short(value: float, integer: bool) -> str:
    """Shortest readable text that reads back as exactly `value` (keeps names unique)."""
    if integer:
        return str(int(value))
    text = f"{value:.6g}"
    return text if float(text) == value else repr(value)


@dataclass(frozen=True)
class FamilyManeuver:
    """One member of a family: its parameter values, direction and duration (s). Quacks like `Maneuver`.

    `params` may be given as a mapping; it is stored as (name, value) pairs in the family's order.
    `controls(rate_hz)` is the schedule `simulator.collect` applies and logs. `span` (default: the
    duration) is the time over which the signal is laid out (a chirp's sweep, a multisine's peak), so
    `dataclasses.replace(m, duration=shorter)` drives the first seconds of the same signal.
    """

    family: str
    params: Any
    direction: str = "ccw"
    duration: float = 30.0
    span: float | None = None

    def __post_init__(self) -> None:
        fam = family(self.family)
        given = dict(self.params) if not isinstance(self.params, Mapping) else dict(self.params.items())
        for name in given:
            fam.parameter(name)
        values = []
        for p in fam.parameters:
            if p.name not in given:
                raise ManeuverError(p.name, None, f"is missing ({self.family} needs {', '.join(fam.names)})")
            value = _check_real(p.name, given[p.name])
            if not p.low <= value <= p.high:
                unit = f" {p.unit}" if p.unit else ""
                raise ManeuverError(p.name, given[p.name], f"must lie in [{p.low:g}, {p.high:g}]{unit}")
            if p.integer and value != int(value):
                raise ManeuverError(p.name, given[p.name], "must be a whole number")
            values.append((p.name, float(int(value)) if p.integer else value))
        if not isinstance(self.direction, str) or self.direction not in DIRECTIONS:
            raise ManeuverError("direction", self.direction, "must be 'cw' or 'ccw'")
        duration = _check_real("duration", self.duration)
        if duration <= 0.0:
            raise ManeuverError("duration", self.duration, "must be > 0")
        span = duration if self.span is None else _check_real("span", self.span)
        if span <= 0.0:
            raise ManeuverError("span", self.span, "must be > 0")
        object.__setattr__(self, "params", tuple(values))
        object.__setattr__(self, "duration", duration)
        object.__setattr__(self, "span", span)

    @property
    def kind(self) -> str:
        """The family name (logged in the `maneuver` column)."""
        return self.family

    @property
    def values(self) -> dict[str, float]:
        """Parameter values by name."""
        return dict(self.params)

    @property
    def sign(self) -> int:
        """Steering sign of the direction: +1 for ccw (left), -1 for cw."""
        return 1 if self.direction == "ccw" else -1

    @property
    def name(self) -> str:
        """Stable readable identifier, e.g. slalom_ccw_t0.6_a0.3_f0.2_w0_d20."""
        fam = FAMILIES[self.family]
        pairs = zip(fam.parameters, self.params, strict=True)
        tags = "_".join(f"{p.tag}{_short(v, p.integer)}" for p, (_, v) in pairs)
        cut = f"_of{self.span:g}" if self.span != self.duration else ""
        return f"{self.family}_{self.direction}_{tags}_d{self.duration:g}{cut}"

    def controls(self, rate_hz: float = REFERENCE_RATE) -> np.ndarray:
        """(T, 2) throttle and signed steering at the log times k / rate_hz, as `collect` applies them."""
        rate = _check_real("rate_hz", rate_hz)
        if rate <= 0.0:
            raise ManeuverError("rate_hz", rate_hz, "must be > 0")
        t = sample_times(self.duration, rate)
        throttle, steering = FAMILIES[self.family].signal(self.values, t, float(self.span or self.duration))
        throttle = np.clip(throttle, -THROTTLE_LIMIT, THROTTLE_LIMIT)
        steering = self.sign * np.clip(steering, -ANGLE_MAX, ANGLE_MAX) + 0.0  # no -0.0
        return np.column_stack([throttle, steering]).astype(np.float64)

    @cached_property
    def _operating(self) -> tuple[float, float]:
        # Only the two numbers are kept: a pool holds thousands of members, and a schedule of 600 s
        # at 30 Hz is 290 kB (a fuzzed pool of 60 000 members once held 17 GB of them).
        u = self.controls(REFERENCE_RATE)
        return float(np.median(u[:, 0])), float(np.abs(u[:, 1]).max())

    @property
    def throttle(self) -> float:
        """Median throttle of the schedule (logged as `op_throttle`)."""
        return self._operating[0]

    @property
    def op_steering(self) -> float:
        """Largest |steering| of the schedule (logged as `op_steering`)."""
        return self._operating[1]

    @property
    def steering(self) -> float:
        """Same as op_steering (Maneuver's field name)."""
        return self.op_steering


def measured_loop_time(log: pd.DataFrame) -> float:
    """Flip period (s) of a logged eight: the median time between its steering sign flips after the first.

    The first loop starts from rest, so its flip may come late: it is left out where later flips
    exist; with one flip only, its time is returned. ManeuverError naming `log` if the steering never
    flips. `as_family(eight, loop_time=measured_loop_time(log))` is the open-loop eight of that car.
    """
    steering = np.sign(log["steering"].to_numpy(dtype=float))
    times = log["time"].to_numpy(dtype=float) if "time" in log else log["timestamp"].to_numpy(dtype=float)
    turning = steering != 0.0
    steering, times = steering[turning], times[turning]
    flips = np.flatnonzero(steering[1:] != steering[:-1]) + 1
    if len(flips) == 0:
        raise ManeuverError("log", "eight", "has no steering flip: no loop time to measure")
    flip_times = times[flips] - times[0]
    gaps = np.diff(flip_times)
    return float(np.median(gaps)) if len(gaps) else float(flip_times[0])


def as_family(maneuver: Maneuver, loop_time: float | None = None) -> FamilyManeuver:
    """The family member that drives a reference maneuver's schedule.

    Straight, skidpad and slalom are slalom members, the fishhook a fishhook member, all with the same
    schedule. The eight is the figure_eight member that flips every `loop_time` s: by default
    `eight_loop_time` (the schedule `nominal_controls` plans eights with), or a time measured on the
    car (`measured_loop_time`). The reference eight flips on the measured heading instead, so the two
    agree only as far as the turn's time does. `loop_time` is refused for the other kinds.
    """
    u, s, kind = maneuver.throttle, maneuver.op_steering, maneuver.kind
    if loop_time is not None and kind != "eight":
        raise ManeuverError("loop_time", loop_time, f"is only for the eight, not the {kind}")
    if kind in ("straight", "skidpad"):
        params = {"throttle": u, "amplitude": s, "frequency": 0.0, "delay": 0.0}
        name = "slalom"
    elif kind == "slalom":
        params = {"throttle": u, "amplitude": s, "frequency": SLALOM_FREQUENCY / (2.0 * math.pi),
                  "delay": SLALOM_DELAY}  # fmt: skip
        name = "slalom"
    elif kind == "fishhook":
        params, name = {"throttle": u, "rate": FISHHOOK_RATE, "amplitude": s}, "fishhook"
    elif kind == "eight":
        period = eight_loop_time(u, s) if loop_time is None else loop_time
        params, name = {"throttle": u, "amplitude": s, "loop_time": period}, "figure_eight"
    else:
        raise ManeuverError("kind", kind, "is no reference kind")
    return FamilyManeuver(name, params, maneuver.direction, maneuver.duration)
