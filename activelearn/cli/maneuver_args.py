"""One maneuver from the command line (simulate, predict): a reference kind and its options, or a
schedule file (a CSV of time, throttle and steering), checked cell by cell before anything runs."""

from __future__ import annotations

import argparse
from pathlib import Path

from activelearn.cli.common import one_line
from activelearn.names import SCHEDULE_COLUMNS

# Maneuver fields -> the options that set them, so errors name what the user typed.
MANEUVER_OPTIONS = {
    "kind": "--maneuver",
    "throttle": "--throttle",
    "steering": "--steering",
    "direction": "--direction",
    "duration": "--duration",
}


def add_maneuver_options(p: argparse.ArgumentParser, log: bool = False) -> None:
    """The options that define one maneuver (simulate, predict): a reference kind, or a schedule file;
    with `log`, also a recorded log whose commands are replayed (predict)."""
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--maneuver", metavar="KIND", help="straight, skidpad, fishhook, slalom or eight")
    which.add_argument("--schedule", metavar="CSV",
                       help="drive this schedule open loop instead: columns time (s, from 0, one row per "
                            "log sample), throttle, steering (rad, + left), each command held until the next "
                            "row; e.g. a proposal's schedule file written by `campaign propose`")
    if log:
        which.add_argument("--log", metavar="FILE",
                           help="replay a recorded log's commands instead (AutoDRIVE CSV, our CSV or "
                                "Parquet) and compare with what it recorded: no MuJoCo")
    add_vehicle_option(p, "nigel; predict: the model's car")
    p.add_argument("--throttle", type=float, default=None, metavar="T",
                   help="throttle in [-1, 1] (required with --maneuver)")
    p.add_argument("--steering", type=float, default=None, metavar="S",
                   help="steering amplitude in rad, up to the car's full lock: required for skidpad, slalom "
                        "and eight; fishhook's default is full lock; a straight takes none")
    p.add_argument("--direction", default=None, metavar="cw|ccw", help="ccw turns left first (default)")
    p.add_argument("--duration", type=float, default=None, metavar="SEC", help="seconds (default 90)")


def add_vehicle_option(p: argparse.ArgumentParser, default: str) -> None:
    """`--vehicle NAME|TOML`: a shipped vehicle or a vehicle file; `default` says what stands without it."""
    p.add_argument("--vehicle", default=None, metavar="NAME|TOML",
                   help="the car: a shipped vehicle (nigel, f1tenth, bmw320i) or a vehicle file "
                        f"(default: {default})")


def vehicle_from_args(args: argparse.Namespace, default: str = "nigel"):
    """The VehicleSpec of --vehicle (a shipped name or a file); a bad one is an InputError naming it."""
    from activelearn.errors import InputError
    from simulator.vehicles import VehicleFileError, load_vehicle

    name = getattr(args, "vehicle", None) or default
    try:
        return load_vehicle(name)
    except VehicleFileError as exc:
        raise InputError("--vehicle", name, str(exc)) from None


def maneuver_from_args(args: argparse.Namespace):
    """The validated Maneuver of --maneuver/--throttle/--steering/--direction/--duration, within the
    full lock of the car of --vehicle."""
    from activelearn.errors import InputError
    from simulator import Maneuver, ManeuverError

    lock = vehicle_from_args(args).steering.limit.value

    if args.throttle is None:
        raise InputError("--throttle", None,
                         f"a {args.maneuver} needs its throttle in [-1, 1], e.g. --throttle 0.6")
    steering = args.steering
    if args.maneuver == "straight" and steering:
        raise InputError("--steering", steering, "a straight does not steer; drop --steering")
    if args.maneuver in ("skidpad", "slalom", "eight") and steering is None:
        raise InputError("--steering", None,
                         f"a {args.maneuver} needs its steering amplitude in rad, e.g. --steering 0.3142")
    if steering is None:
        steering = lock if args.maneuver == "fishhook" else 0.0
    if steering > lock:
        raise InputError("--steering", steering, f"must be at most the car's full lock, {lock:g} rad")
    direction = "ccw" if args.direction is None else args.direction
    duration = 90.0 if args.duration is None else args.duration
    try:
        return Maneuver(args.maneuver, args.throttle, steering, direction, duration)
    except ManeuverError as exc:
        raise InputError(MANEUVER_OPTIONS.get(exc.field, exc.field), exc.value, exc.reason) from None


def no_maneuver_options(args: argparse.Namespace, given: str) -> None:
    """Refuse --throttle, --steering, --direction and --duration beside `given` (a file that sets them)."""
    from activelearn.errors import InputError

    for option in ("throttle", "steering", "direction", "duration"):
        if getattr(args, option) is not None:
            raise InputError(f"--{option}", getattr(args, option),
                             f"the {given[2:]} sets the {option}: drop --{option} (or drop {given})")


def schedule_from_args(args: argparse.Namespace, rate_hz: float, fixed_rate: bool = False):
    """What --schedule FILE drives at `rate_hz`: the proposal it is (a family member) or a Replay of its rows.

    Every problem is an InputError naming the option and the file, and the column where one is at fault;
    a file at another rate names --rate, or the file itself where the rate is `fixed_rate` (predict).
    """
    import numpy as np
    import pandas as pd

    from activelearn.errors import InputError
    from simulator import ManeuverError
    from simulator.schedules import schedule_maneuver

    no_maneuver_options(args, "--schedule")
    path = Path(args.schedule)
    if not path.exists():
        raise InputError("--schedule", str(path), "no such file")
    if not path.is_file():
        raise InputError("--schedule", str(path), "is not a file")
    try:
        table = pd.read_csv(path, dtype=str, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise InputError("--schedule", str(path), "is empty: a schedule needs the header "
                                                  "time,throttle,steering and one row per command") from None
    except (pd.errors.ParserError, UnicodeDecodeError, OSError) as exc:
        reason = f"is not a readable CSV table ({one_line(str(exc))})"
        raise InputError("--schedule", str(path), reason) from None
    table.columns = [str(c).strip() for c in table.columns]
    missing = [c for c in SCHEDULE_COLUMNS if c not in table.columns]
    if missing:
        raise InputError(f"--schedule {path}", list(table.columns),
                         f"lacks the column(s) {', '.join(missing)} (a schedule has time, throttle, "
                         "steering)")
    if table.empty:
        raise InputError(f"--schedule {path}", 0, "holds no rows below its header")
    values = {}
    for column in SCHEDULE_COLUMNS:
        text = table[column]
        numbers = pd.to_numeric(text, errors="coerce")
        junk = numbers.isna() & text.notna() & ~text.str.strip().str.lower().isin(("nan", "inf", "-inf"))
        if junk.any():
            row = int(np.argmax(junk.to_numpy()))
            raise InputError(f"--schedule {path}: column {column}", text.iloc[row],
                             f"row {row + 1} is not a number")
        values[column] = numbers.to_numpy(dtype=np.float64)
    try:
        lock = vehicle_from_args(args).steering.limit.value
        return schedule_maneuver(
            path.stem, values["time"], values["throttle"], values["steering"], rate_hz, lock
        )
    except ManeuverError as exc:
        if exc.field == "rate_hz":
            step = float(values["time"][-1] - values["time"][0]) / (len(values["time"]) - 1)
            rows = f"{step:.6g} s apart ({1.0 / step:.6g} Hz)"
            if fixed_rate:
                reason = f"its rows are {rows}; predict steps at {rate_hz:g} Hz: resample it to that"
                raise InputError(f"--schedule {path}", f"{1.0 / step:.6g} Hz", reason) from None
            raise InputError("--rate", exc.value, f"the rows of {path} are {rows}, not 1/{rate_hz:g} s: "
                                                  f"pass --rate {1.0 / step:.6g}") from None
        raise InputError(f"--schedule {path}: column {exc.field}", exc.value, exc.reason) from None


def driven_from_args(args: argparse.Namespace, rate_hz: float, fixed_rate: bool = False):
    """The maneuver of --maneuver (and its options) or of --schedule FILE, validated."""
    if args.schedule is not None:
        return schedule_from_args(args, rate_hz, fixed_rate)
    return maneuver_from_args(args)

