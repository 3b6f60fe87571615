"""`activelearn identify`: the physical parameters of a car's single track, fitted to logs."""

from __future__ import annotations

import argparse

from activelearn.cli.fidelity import log_files
from activelearn.cli.maneuver_args import add_vehicle_option


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "identify",
        help="fit the physical parameters of a car's single track to logs, beside its vehicle file's",
        description="Fit the seven physical parameters of the physics-structured model ([model] kind = "
                    "'physics') to logs (AutoDRIVE CSV, our CSV or Parquet) by free runs of their "
                    "recorded commands, and print them beside the values the car's vehicle file gives.",
    )
    p.add_argument("logs", nargs="+", metavar="LOG", help="log files, or folders searched for .csv/.parquet")
    p.add_argument("--other-car", nargs="+", default=[], metavar="LOG",
                   help="logs of another car (e.g. simulated on nominal Nigel): identified alone first, "
                        "their estimate, widened by the datasheet's widths, is the prior LOG is fitted under")
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
    from activelearn.numerics.models.single_track import (
        car_prior,
        identify_from_logs,
        identify_on_another_car,
    )

    car = car_prior(vehicle_from_args(args))
    if args.rate_hz is not None and not (math.isfinite(args.rate_hz) and args.rate_hz > 0):
        raise InputError("--rate-hz", args.rate_hz, "must be a positive number")
    tables = [read_log_file(path) for path in log_files(args.logs)]
    if args.rate_hz is None:
        args.rate_hz = log_rate_hz(tables)
    logs = control_rate_logs(tables)
    if args.other_car:
        others = control_rate_logs([read_log_file(path) for path in log_files(args.other_car)])
        found = identify_on_another_car(logs, others, dt=1.0 / args.rate_hz, car=car)
        prior = f"under the estimate from {len(others)} log(s) of another car ± the datasheet's widths"
    else:
        found = identify_from_logs(logs, dt=1.0 / args.rate_hz, car=car)
        prior = f"under {car.name}'s vehicle file (the datasheet's values) ± their widths"
    print(f"physical parameters from {len(logs)} log(s), {sum(len(u) for u, _ in logs)} steps, {prior}:")
    print(f"  {'parameter':<13}{'datasheet':>10}{'fitted':>10}{'± s.e.':>9}{'change':>9}  unit  meaning")
    for p, value, err in zip(car.parameters, found.values, found.stderr, strict=True):
        change = f"{value / p.nominal - 1:+.1%}" if p.nominal else f"{value - p.nominal:+.3f}"
        row = f"{p.name:<13}{p.nominal:>10.4f}{value:>10.4f}{err:>9.4f}{change:>9}"
        print(f"  {row}  {p.unit:<5} {p.meaning}")
    if len(logs) > 1:
        print("  s.e.: cluster-robust, each log a cluster (a log's errors are correlated along it)")
    else:  # one cluster: the sandwich is Gauss-Newton's
        print("  s.e.: Gauss-Newton from one log (its steps counted as independent: optimistic)")
    return 0

