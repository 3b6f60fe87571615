"""`activelearn fidelity`: the simulator replaying logs' commands beside them: whole runs, steady points."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from activelearn.cli.common import PLOT_SUFFIXES, output_path, print_table
from activelearn.cli.maneuver_args import add_vehicle_option


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fidelity",
        help="replay logs' commands in the simulator: the whole runs, and steady speed, yaw rate and turn "
             "speed loss",
        description="Replay the commands of each log (AutoDRIVE CSV, our CSV or Parquet) in MuJoCo and "
                    "compare the whole runs (position error over time, speed and yaw-rate errors) and, per "
                    "operating point of constant commands, the steady speed, yaw rate and speed loss in "
                    "turns of the simulator and of the log. A log at another rate than the simulator's is "
                    "resampled; one with a gap of more than 0.25 s between samples is refused.",
    )
    p.add_argument("logs", nargs="+", metavar="LOG", help="log files, or folders searched for .csv/.parquet")
    p.add_argument("--config", default=None, metavar="CONFIG",
                   help="campaign config: its car ([vehicle]), [oracle] twin (overrides) and log rate "
                        "(default: the nominal car of --vehicle)")
    add_vehicle_option(p, "nigel, or the --config's")
    p.add_argument("--plot", default=None, metavar="PNG",
                   help="also draw the steady operating points (.png, .pdf, .svg)")
    p.add_argument("--replay-plot", default=None, metavar="PNG",
                   help="also draw the whole-log replays: paths, speed, yaw rate and position error "
                        "(one row per log, the first six)")
    p.add_argument("--settle", type=float, default=1.0, metavar="SEC",
                   help="seconds dropped at the start of each stretch of constant commands (default 1)")
    p.add_argument("--min-window", type=float, default=1.0, metavar="SEC",
                   help="seconds of steady data a stretch must still have (default 1)")
    p.set_defaults(handler=_fidelity)


def log_files(specs: Sequence[str]) -> list:
    from pathlib import Path

    from activelearn.errors import InputError

    files: list[Path] = []
    for spec in specs:
        path = Path(spec)
        if path.is_dir():
            found = sorted(p for p in path.rglob("*") if p.suffix.lower() in (".csv", ".parquet"))
            if not found:
                raise InputError("LOG", spec, "the folder holds no .csv or .parquet log")
            files.extend(found)
        elif path.is_file():
            files.append(path)
        else:
            raise InputError("LOG", spec, "no such file or folder")
    if len(set(files)) != len(files):
        raise InputError("LOG", next(str(f) for f in files if files.count(f) > 1), "given twice")
    return files


def _fidelity(args: argparse.Namespace) -> int:
    import math

    from activelearn.errors import InputError
    from activelearn.fidelity import FidelitySettings, compare, read_log_file

    plot = output_path("--plot", args.plot, suffixes=PLOT_SUFFIXES) if args.plot else None
    replay_plot = (output_path("--replay-plot", args.replay_plot, suffixes=PLOT_SUFFIXES)
                   if args.replay_plot else None)  # fmt: skip
    if not math.isfinite(args.settle) or args.settle < 0:
        raise InputError("--settle", args.settle, "must be a finite number of seconds >= 0")
    if not math.isfinite(args.min_window) or args.min_window <= 0:
        raise InputError("--min-window", args.min_window, "must be a finite number of seconds > 0")
    from activelearn.cli.maneuver_args import vehicle_from_args
    from simulator import build_vehicle

    spec = vehicle_from_args(args)
    overrides: dict[str, float] = {}
    rate = spec.log_rate_hz
    if args.config is not None:
        from activelearn.config import load_config

        cfg = load_config(args.config)
        if args.vehicle is not None and vehicle_from_args(args).name != cfg.vehicle.spec.name:
            raise InputError("--vehicle", args.vehicle, f"the config drives {cfg.vehicle.name}: drop one")
        spec, rate = cfg.vehicle.spec, cfg.simulation.rate_hz
        if cfg.oracle.kind == "twin":
            overrides = dict(cfg.oracle.overrides)
    vehicle = None if spec.name == "nigel" and not overrides else build_vehicle(spec, overrides)
    name = "nominal" if spec.name == "nigel" else spec.name
    if overrides:
        name = ("" if spec.name == "nigel" else f"{spec.name} ") + "twin " + ", ".join(
            f"{k}={v:g}" for k, v in sorted(overrides.items()))
    logs = [(str(path), read_log_file(path)) for path in log_files(args.logs)]  # all read before simulating
    settings = FidelitySettings(settle=args.settle, min_window=args.min_window, rate_hz=rate)
    report = compare(logs, vehicle=vehicle, vehicle_name=name, settings=settings)

    points = report.points
    print(f"fidelity of the simulator ({name}) against {len(logs)} log(s): "
          f"{len(report.stretches)} stretch(es) of constant commands, {len(points)} operating point(s)")
    _print_replays(report.replays)
    if len(points):
        _print_points(points)
    lasting = f"{settings.settle + settings.min_window:g} s"
    for log in (n for n, _ in logs if n not in set(report.stretches["log"])):
        print(f"note: {log}: no stretch of constant non-zero throttle lasts {lasting}: no steady operating "
              "point from it")
    if not len(points):
        print("the steady table is empty: the logs have no stretch of constant commands to average "
              "(the whole-log replay above still compares them)")
    if plot is not None:
        from activelearn.plots import fidelity_figure, save_figure

        fig = fidelity_figure(points, title=f"simulator ({name}) vs {len(logs)} log(s)")
        save_figure(fig, plot, dpi=120)
        print(f"wrote {plot}")
    if replay_plot is not None:
        from activelearn.plots import replay_figure, save_figure

        fig = replay_figure(report.traces, title=f"simulator ({name}) replaying the logs' commands")
        save_figure(fig, replay_plot, dpi=100)
        print(f"wrote {replay_plot}")
    return 0


def _print_replays(replays) -> None:
    """The whole-log comparison, one row per log, and a note for each log that does not start at rest."""
    from activelearn.fidelity import REST_SPEED

    print("whole-log replay (the logged commands held between samples, MuJoCo from rest; each path in its "
          "own start frame):")
    header = ("log", "s", "v at start", "pos err end", "pos err mean", "pos err max", "rms Δv", "rms Δω")
    lines = [(row.log, f"{row.seconds:.1f}", f"{row.start_speed:.4f}", f"{row.error_end:.4f}",
              f"{row.error_mean:.4f}", f"{row.error_max:.4f}", f"{row.rms_v:.4f}", f"{row.rms_w:.4f}")
             for row in replays.itertuples()]  # fmt: skip
    print_table(header, lines, left=1)
    print("(position errors in m, v in m/s, ω in rad/s)")
    for row in replays.itertuples():
        if abs(row.start_speed) > REST_SPEED:
            print(f"note: {row.log} starts at {row.start_speed:.3f} m/s, MuJoCo at rest: its first seconds "
                  "differ by that run-up")


def _print_points(points) -> None:
    """The steady table: one row per operating point, then the RMS differences."""
    import math

    header = ("throttle", "steering", "s", "v sim", "v log", "Δv", "ω sim", "ω log", "Δω",
              "loss sim", "loss log", "Δloss", "straight")
    lines = []
    for row in points.itertuples():
        loss = ("", "", "", "")
        if row.straight_source:  # a turn
            loss = (f"{row.loss_sim:.4f}", f"{row.loss_log:.4f}", f"{row.dloss:+.4f}", row.straight_source)
        lines.append((f"{row.throttle:.2f}", f"{row.steering:+.3f}", f"{row.seconds:.0f}",
                      f"{row.v_sim:.4f}", f"{row.v_log:.4f}", f"{row.dv:+.4f}",
                      f"{row.w_sim:+.4f}", f"{row.w_log:+.4f}", f"{row.dw:+.4f}", *loss))
    print("steady operating points:")
    print_table(header, lines)
    rms_v = math.sqrt(float((points["dv"] ** 2).mean()))
    rms_w = math.sqrt(float((points["dw"] ** 2).mean()))
    print(f"RMS difference over operating points: speed {rms_v:.4f} m/s, yaw rate {rms_w:.4f} rad/s "
          "(v in m/s, ω in rad/s, loss = straight-line speed at that throttle - turn speed; "
          "straight: where the log's straight-line speed comes from)")
