"""Command-line interface: the only module that parses arguments or prints.

Every sub-command is a thin layer over the Python API. User mistakes (bad values, unknown names,
malformed files) become one red line on stderr and exit code 2; nothing is written in that case.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from activelearn.errors import ActiveLearnError
from simulator.errors import SimulatorError

EXIT_USAGE = 2

Handler = Callable[[argparse.Namespace], int]


def _red(text: str) -> str:
    return f"\033[31m{text}\033[0m" if sys.stderr.isatty() else text


def fail(message: str) -> int:
    """Print one red error line on stderr and return the usage exit code."""
    print(_red(f"error: {message}"), file=sys.stderr)
    return EXIT_USAGE


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one red line and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        fail(message)
        raise SystemExit(EXIT_USAGE)


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level parser with every sub-command registered."""
    parser = _Parser(prog="activelearn", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for register in _REGISTRARS:
        register(sub)
    return parser


# Each registrar adds one sub-command and sets `handler` on its parser.
_REGISTRARS: list[Callable[[argparse._SubParsersAction], None]] = []


# --- simulate -------------------------------------------------------------------------------------

_PLOT_SUFFIXES = (".png", ".pdf", ".svg")
# Maneuver fields -> the options that set them, so errors name what the user typed.
_MANEUVER_OPTIONS = {
    "kind": "--maneuver",
    "throttle": "--throttle",
    "steering": "--steering",
    "direction": "--direction",
    "duration": "--duration",
}


def _register_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate one maneuver of Nigel and write its log (CSV or Parquet)",
        description="Simulate one maneuver of Nigel in MuJoCo and write its log in the AutoDRIVE layout.",
    )
    p.add_argument("--maneuver", required=True, metavar="KIND",
                   help="straight, skidpad, fishhook, slalom or eight")
    p.add_argument("--throttle", required=True, type=float, metavar="T", help="throttle in [-1, 1]")
    p.add_argument("--steering", type=float, default=None, metavar="S",
                   help="steering amplitude in [0, 0.5236] rad (default: 0.5236 for fishhook, else 0)")
    p.add_argument("--direction", default="ccw", metavar="cw|ccw", help="ccw turns left first (default)")
    p.add_argument("--duration", type=float, default=90.0, metavar="SEC", help="seconds (default 90)")
    p.add_argument("--rate", type=float, default=30.0, metavar="HZ", help="log rate in Hz (default 30)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="noise seed (default 0)")
    p.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True,
                   help="add the default sensor noise (default: on)")
    p.add_argument("--out", required=True, metavar="PATH", help="output log, .csv or .parquet")
    p.add_argument("--plot", default=None, metavar="PNG", help="also draw the log figure (.png, .pdf, .svg)")
    p.set_defaults(handler=_simulate)


def _simulate(args: argparse.Namespace) -> int:
    import math
    import warnings
    from pathlib import Path

    from activelearn.errors import InputError
    from simulator import STEERING_LIMIT, DivergenceWarning, Maneuver, ManeuverError, NoiseConfig, collect

    # Validate everything before simulating, so a bad value never leaves a file behind.
    steering = args.steering
    if steering is None:
        steering = STEERING_LIMIT if args.maneuver == "fishhook" else 0.0
    try:
        maneuver = Maneuver(args.maneuver, args.throttle, steering, args.direction, args.duration)
    except ManeuverError as exc:
        raise InputError(_MANEUVER_OPTIONS.get(exc.field, exc.field), exc.value, exc.reason) from None
    if not math.isfinite(args.rate) or not 0.0 < args.rate <= 300.0:
        raise InputError("--rate", args.rate, "must lie in (0, 300] Hz")
    if args.seed < 0:
        raise InputError("--seed", args.seed, "must be >= 0")
    out = Path(args.out)
    if out.suffix.lower() not in (".csv", ".parquet"):
        raise InputError("--out", args.out, "must end in .csv or .parquet")
    if out.is_dir():
        raise InputError("--out", args.out, "is a directory")
    plot = Path(args.plot) if args.plot else None
    if plot is not None and plot.suffix.lower() not in _PLOT_SUFFIXES:
        raise InputError("--plot", args.plot, f"must end in {', '.join(_PLOT_SUFFIXES)}")

    from tqdm import tqdm

    from activelearn.data import write_table

    with tqdm(total=1, unit="sample", desc=maneuver.name, leave=False, disable=None) as bar:

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DivergenceWarning)
            table = collect([maneuver], rate_hz=args.rate, seed=args.seed,
                            noise=NoiseConfig() if args.noise else None, progress=progress)
    for warning in caught:
        print(f"warning: {warning.message}", file=sys.stderr)

    if plot is not None:
        from activelearn.plots import plot_log

        fig = plot_log(table, title=maneuver.name)
        plot.parent.mkdir(parents=True, exist_ok=True)
        tmp = plot.with_name(f".{plot.name}.tmp{plot.suffix}")
        fig.savefig(tmp, dpi=120)
        tmp.replace(plot)
    write_table(table, out)
    print(f"{maneuver.name}: {len(table)} rows, mean speed {table['speed'].mean():.4f} m/s, "
          f"mean yaw rate {table['angZ'].mean():+.4f} rad/s")
    print(f"wrote {out}" + (f" and {plot}" if plot is not None else ""))
    return 0


_REGISTRARS.append(_register_simulate)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `activelearn` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler = args.handler
    try:
        return handler(args)
    except (ActiveLearnError, SimulatorError) as exc:
        return fail(str(exc))


if __name__ == "__main__":
    raise SystemExit(main())
