"""Command schedules given as rows (time, throttle, steering), driven open loop like a proposal's schedule.

`campaign propose` writes beside each proposal of a family pool the schedule to drive: one row per
log sample, time k / rate (s), throttle and signed steering (rad, + left), each held until the next
row, in a file named `NN-<member name>.csv`. `schedule_maneuver` turns such rows back into what
`collect` runs:

- the family member its label names (`member_from_name`), when the rows are exactly that member's
  schedule at the rate: then the log is the very log `collect` gives for the member (same
  `maneuver`, `direction`, `run_id`, operating point), which a rehearsal of a proposal wants;
- otherwise a `Replay` of the rows, labelled with the label (any schedule a person wrote).

`check_schedule` is the check both go through: at least two rows, time starting at 0 and growing by
one step of 1 / rate_hz from row to row, every value finite, throttle in [-1, 1], |steering| at most
the steering limit. Each failure is a ManeuverError naming the column (or `rate_hz`), with rows
counted from 1.
"""

from __future__ import annotations

import re

import numpy as np

from simulator.errors import ManeuverError
from simulator.families import FAMILIES, FamilyManeuver
from simulator.maneuvers import DIRECTIONS, Replay, _check_real
from simulator.vehicle import STEERING_LIMIT, THROTTLE_LIMIT

STEP_TOLERANCE = 0.01  # each time step may differ from the file's mean step by this share of it
RATE_TOLERANCE = 1e-3  # relative difference allowed between the file's rate and the rate asked for
_ORDINAL = re.compile(r"^\d+-")  # the "NN-" a proposal's schedule file name starts with


def _first(mask: np.ndarray) -> int:
    return int(np.argmax(mask))


def check_schedule(
    time: np.ndarray, throttle: np.ndarray, steering: np.ndarray, rate_hz: float, lock: float = STEERING_LIMIT
) -> None:
    """Raise a ManeuverError naming the column (or rate_hz) unless the rows are a schedule at rate_hz
    within the car's full `lock` (rad; default the default car's)."""
    rate = _check_real("rate_hz", rate_hz)
    if rate <= 0.0:
        raise ManeuverError("rate_hz", rate_hz, "must be > 0")
    columns = {"time": time, "throttle": throttle, "steering": steering}
    arrays = {name: np.asarray(values, dtype=np.float64) for name, values in columns.items()}
    lengths = {len(a) for a in arrays.values()}
    if any(a.ndim != 1 for a in arrays.values()) or len(lengths) != 1:
        raise ManeuverError("time", sorted(lengths), "time, throttle and steering must be 1-D and as long")
    for name, values in arrays.items():
        bad = ~np.isfinite(values)
        if bad.any():
            raise ManeuverError(name, float(values[_first(bad)]), f"must be finite (row {_first(bad) + 1})")
    t, u, s = arrays["time"], arrays["throttle"], arrays["steering"]
    if len(t) < 2:
        raise ManeuverError("time", len(t), "needs at least 2 rows (a schedule of one command lasts no time)")
    if abs(t[0]) > 1e-6:
        raise ManeuverError("time", float(t[0]), "must start at 0 (seconds from the start of the maneuver)")
    steps = np.diff(t)
    if (steps <= 0.0).any():
        k = _first(steps <= 0.0) + 1
        reason = f"must increase from row to row (row {k + 1} after {t[k - 1]:g})"
        raise ManeuverError("time", float(t[k]), reason)
    step = float(t[-1] - t[0]) / (len(t) - 1)
    off = np.abs(steps - step) > STEP_TOLERANCE * step
    if off.any():
        k = _first(off) + 1
        raise ManeuverError("time", float(t[k]), f"must grow in equal steps: row {k + 1} comes "
                                                 f"{steps[k - 1]:.6g} s after row {k}, the file's mean step "
                                                 f"is {step:.6g} s")  # fmt: skip
    if abs(step * rate - 1.0) > RATE_TOLERANCE:
        raise ManeuverError("rate_hz", rate_hz, f"disagrees with the schedule: its rows are {step:.6g} s "
                                                f"apart ({1.0 / step:.6g} Hz), not 1/{rate:g} s")  # fmt: skip
    outside = np.abs(u) > THROTTLE_LIMIT
    if outside.any():
        k = _first(outside)
        raise ManeuverError("throttle", float(u[k]), f"must lie in [-{THROTTLE_LIMIT:g}, {THROTTLE_LIMIT:g}] "
                                                     f"(row {k + 1})")  # fmt: skip
    outside = np.abs(s) > lock
    if outside.any():
        k = _first(outside)
        raise ManeuverError("steering", float(s[k]), f"must lie in [-{lock}, {lock}] rad (row {k + 1})")


def member_from_name(name: str) -> FamilyManeuver | None:
    """The family member whose `name` this is (`FamilyManeuver.name` read back), None if it names none."""
    if not isinstance(name, str):
        return None
    for family in sorted(FAMILIES, key=len, reverse=True):  # throttle_step before any shorter prefix
        if not name.startswith(f"{family}_"):
            continue
        words = name[len(family) + 1 :].split("_")
        parameters = FAMILIES[family].parameters
        if len(words) not in (len(parameters) + 2, len(parameters) + 3) or words[0] not in DIRECTIONS:
            return None
        try:
            values = {}
            for p, word in zip(parameters, words[1:], strict=False):
                if not word.startswith(p.tag):
                    return None
                values[p.name] = float(word[len(p.tag) :])
            duration_word = words[len(parameters) + 1]
            span_words = words[len(parameters) + 2 :]
            if not duration_word.startswith("d") or any(not w.startswith("of") for w in span_words):
                return None
            duration = float(duration_word[1:])
            span = float(span_words[0][2:]) if span_words else None
            member = FamilyManeuver(family, values, words[0], duration, span)
        except (ValueError, ManeuverError):
            return None
        return member if member.name == name else None
    return None


def schedule_maneuver(
    label: str, time: np.ndarray, throttle: np.ndarray, steering: np.ndarray, rate_hz: float,
    lock: float = STEERING_LIMIT,
) -> FamilyManeuver | Replay:  # fmt: skip
    """What `collect` runs for these schedule rows: the member `label` names if the rows are its schedule.

    `label` is the schedule's name (a file's stem); a leading "NN-" (a proposal's number) is ignored
    when reading it as a member name. Anything else is a `Replay` of the rows labelled `label`.
    """
    check_schedule(time, throttle, steering, rate_hz, lock)
    commands = np.column_stack([np.asarray(throttle, np.float64), np.asarray(steering, np.float64)])
    member = member_from_name(_ORDINAL.sub("", label, count=1)) if isinstance(label, str) else None
    if member is not None:
        expected = member.controls(float(rate_hz))
        if expected.shape == commands.shape and np.array_equal(expected, commands):
            return member
    return Replay(label, commands[:, 0], commands[:, 1], float(rate_hz))
