"""`activelearn simulate`: one maneuver of a car (`--vehicle`, default Nigel) in MuJoCo, its log in the
AutoDRIVE layout."""

from __future__ import annotations

import argparse
import sys

from activelearn.cli.common import PLOT_SUFFIXES, output_path
from activelearn.cli.maneuver_args import add_maneuver_options, driven_from_args, vehicle_from_args


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate one maneuver of a car (default Nigel) and write its log (CSV or Parquet)",
        description="Simulate one maneuver of a car (--vehicle) in MuJoCo and write its log in the AutoDRIVE "
                    "layout: a reference kind (--maneuver), or a schedule file driven open loop "
                    "(--schedule), such as a proposal of `campaign propose`, to rehearse it.",
    )
    add_maneuver_options(p)
    p.add_argument("--rate", type=float, metavar="HZ", help="log rate in Hz (default: the car's, 30)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="noise seed (default 0)")
    p.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True,
                   help="add the car's sensor noise (its vehicle file's, else the default; default: on)")
    p.add_argument("--out", required=True, metavar="PATH", help="output log, .csv or .parquet")
    p.add_argument("--autodrive", action="store_true",
                   help="write the AutoDRIVE dataset's layout (headerless 21-field CSV), not a table")
    p.add_argument("--plot", default=None, metavar="PNG", help="also draw the log figure (.png, .pdf, .svg)")
    p.set_defaults(handler=_simulate)


def _simulate(args: argparse.Namespace) -> int:
    import math
    import warnings

    from activelearn.errors import InputError
    from simulator import DivergenceWarning, NoiseConfig, build_vehicle, collect

    # Validate everything before simulating, so a bad value never leaves a file behind.
    spec = vehicle_from_args(args)
    if args.rate is None:
        args.rate = spec.log_rate_hz
    if not math.isfinite(args.rate) or not 0.0 < args.rate <= 300.0:
        raise InputError("--rate", args.rate, "must lie in (0, 300] Hz")
    maneuver = driven_from_args(args, args.rate)
    if args.seed < 0:
        raise InputError("--seed", args.seed, "must be >= 0")
    out = output_path("--out", args.out, suffixes=(".csv", ".parquet"))
    if args.autodrive and out.suffix.lower() != ".csv":
        raise InputError("--out", args.out, "an AutoDRIVE log (--autodrive) is a .csv file")
    plot = output_path("--plot", args.plot, suffixes=PLOT_SUFFIXES) if args.plot else None
    vehicle = None if args.vehicle is None else build_vehicle(spec)

    from tqdm import tqdm

    from activelearn.data import write_table

    with tqdm(total=1, unit="sample", desc=maneuver.name, leave=False, disable=None) as bar:

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DivergenceWarning)
            table = collect([maneuver], rate_hz=args.rate, seed=args.seed, vehicle=vehicle,
                            noise=NoiseConfig.for_vehicle(spec) if args.noise else None, progress=progress)
    for warning in caught:
        print(f"warning: {warning.message}", file=sys.stderr)

    if plot is not None:
        from activelearn.plots import plot_log, save_figure

        save_figure(plot_log(table, title=maneuver.name), plot, dpi=120)
    if args.autodrive:
        from activelearn.data import write_autodrive_log

        write_autodrive_log(table, out)
    else:
        write_table(table, out)
    print(f"{maneuver.name}: {len(table)} rows, mean speed {table['speed'].mean():.4f} m/s, "
          f"mean yaw rate {table['angZ'].mean():+.4f} rad/s")
    print(f"wrote {out}" + (f" and {plot}" if plot is not None else ""))
    return 0

