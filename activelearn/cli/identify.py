"""`activelearn identify`: the physical parameters of a car's single track, fitted to logs."""

from __future__ import annotations

import argparse
import dataclasses

from activelearn.cli.fidelity import log_files
from activelearn.cli.maneuver_args import add_vehicle_option


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "identify",
        help="fit the physical parameters of a car's single track to logs, beside its vehicle file's",
        description="Fit the physical parameters of the physics-structured model's core ([model] kind = "
                    "'physics'; the kinematic core's seven, or with --core dynamic the dynamic core's five "
                    "scales) to logs (AutoDRIVE CSV, our CSV or Parquet) by free runs of their recorded "
                    "commands, and print them beside the values the car's vehicle file gives.",
    )
    p.add_argument("logs", nargs="+", metavar="LOG", help="log files, or folders searched for .csv/.parquet")
    p.add_argument("--other-car", nargs="+", default=[], metavar="LOG",
                   help="logs of another car of the same vehicle file (e.g. simulated on the nominal car): "
                        "identified alone first, their estimate, widened by the datasheet's widths, is the "
                        "prior LOG is fitted under (either core)")
    p.add_argument("--core", choices=("kinematic", "dynamic"), default="kinematic",
                   help="the physics kind's core ([model] core): the kinematic single track's seven "
                        "parameters (default), or the dynamic single track's five scales of the file's "
                        "figures (grip, cornering stiffnesses, drive, yaw inertia), identified as its "
                        "campaigns do")
    p.add_argument("--wheel-forces", action="store_true",
                   help="--core dynamic: the forces of four wheels, each in its own friction circle "
                        "([model] wheel_forces)")
    p.add_argument("--loss", choices=("squares", "cauchy"), default="squares",
                   help="--core dynamic: the identification's loss ([model] identification_loss)")
    add_vehicle_option(p, "nigel")
    p.add_argument("--rate-hz", type=float, metavar="HZ",
                   help="the logs' rate (default: read off their time columns)")
    p.set_defaults(handler=_identify)


def _identify(args: argparse.Namespace) -> int:
    import math

    from activelearn.cli.maneuver_args import vehicle_from_args
    from activelearn.data import log_rate_hz
    from activelearn.errors import InputError
    from activelearn.fidelity import read_log_file
    from activelearn.loop.collection import control_rate_logs
    from activelearn.numerics.models.single_track import car_prior

    spec = vehicle_from_args(args)
    car = car_prior(spec)
    if args.rate_hz is not None and not (math.isfinite(args.rate_hz) and args.rate_hz > 0):
        raise InputError("--rate-hz", args.rate_hz, "must be a positive number")
    tables = [read_log_file(path) for path in log_files(args.logs)]
    if args.rate_hz is None:
        args.rate_hz = log_rate_hz(tables)
    logs = control_rate_logs(tables)
    if args.core != "dynamic" and args.wheel_forces:
        raise InputError("--wheel-forces", True, "needs --core dynamic")
    if args.core != "dynamic" and args.loss != "squares":
        raise InputError("--loss", args.loss, "needs --core dynamic")
    if args.core == "dynamic":
        _print_dynamic(logs, spec, args.other_car, 1.0 / args.rate_hz, args.wheel_forces, args.loss)
    else:
        _print_kinematic(logs, car, args.other_car, 1.0 / args.rate_hz)
    _print_stderr_note(len(logs))
    return 0


def _print_kinematic(logs, car, other_car: list[str], dt: float) -> None:
    """The kinematic core's seven parameters beside the file's (under another car's logs' estimate)."""
    from activelearn.fidelity import read_log_file
    from activelearn.loop.collection import control_rate_logs
    from activelearn.numerics.models.single_track import identify_from_logs, identify_on_another_car

    if other_car:
        others = control_rate_logs([read_log_file(path) for path in log_files(other_car)])
        found = identify_on_another_car(logs, others, dt=dt, car=car)
        prior = f"under the estimate from {len(others)} log(s) of another car ± the datasheet's widths"
    else:
        found = identify_from_logs(logs, dt=dt, car=car)
        prior = f"under {car.name}'s vehicle file (the datasheet's values) ± their widths"
    print(f"physical parameters from {len(logs)} log(s), {sum(len(u) for u, _ in logs)} steps, {prior}:")
    print(f"  {'parameter':<13}{'datasheet':>10}{'fitted':>10}{'± s.e.':>9}{'change':>9}  unit  meaning")
    for p, value, err in zip(car.parameters, found.values, found.stderr, strict=True):
        change = f"{value / p.nominal - 1:+.1%}" if p.nominal else f"{value - p.nominal:+.3f}"
        row = f"{p.name:<13}{p.nominal:>10.4f}{value:>10.4f}{err:>9.4f}{change:>9}"
        print(f"  {row}  {p.unit:<5} {p.meaning}")


def _print_dynamic(logs, spec, other_car: list[str], dt: float, wheel_forces: bool, loss: str) -> None:
    """The dynamic core's five scales, identified as its campaigns do, with the figures they scale (under
    another car's logs' scales, widened, with `other_car`)."""
    from activelearn.fidelity import read_log_file
    from activelearn.loop.collection import control_rate_logs
    from activelearn.numerics.models.dynamic_physics import (
        IDENTIFY_HORIZON,
        identify_scales,
        scales_of_another_car,
    )
    from activelearn.numerics.models.dynamic_scales import parameters_of, scaled_figures
    from activelearn.numerics.models.dynamic_track import DynamicCar

    car = dataclasses.replace(DynamicCar.of(spec), wheel_forces=wheel_forces)
    prior, under = None, f"under {spec.name}'s vehicle file (scale 1 ± its width)"
    if other_car:
        others = control_rate_logs([read_log_file(path) for path in log_files(other_car)])
        prior = scales_of_another_car(others, car, dt, loss)
        under = f"under the scales of {len(others)} log(s) of another car ± the file's widths"
    found = identify_scales(logs, car, dt, prior=prior, loss=loss)
    steps = sum(len(u) for u, _ in logs)
    print(f"the dynamic core's scales from {len(logs)} log(s), {steps} steps, {under}, free runs restarted "
          f"every {IDENTIFY_HORIZON:g} s:")
    header = f"{'parameter':<16}{'scale':>7}{'± s.e.':>8}  {'figure':<8}{'file':>10}{'fitted':>10}"
    print(f"  {header}  unit    meaning")
    rows = zip(parameters_of(car), found.values, found.stderr, scaled_figures(car), strict=True)
    for p, value, err, (symbol, figure, unit) in rows:
        row = f"{p.name:<16}{value:>7.3f}{err:>8.3f}  {symbol:<8}{figure:>10.4g}{value * figure:>10.4g}"
        print(f"  {row}  {unit:<7} {p.meaning}")


def _print_stderr_note(n_logs: int) -> None:
    if n_logs > 1:
        print("  s.e.: cluster-robust, each log a cluster (a log's errors are correlated along it)")
    else:  # one cluster: the sandwich is Gauss-Newton's
        print("  s.e.: Gauss-Newton from one log (its steps counted as independent: optimistic)")

