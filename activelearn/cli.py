"""Active learning of a surrogate model of Nigel's dynamics, a 1:14 car simulated in MuJoCo.

This module is the command-line interface, the only one that parses arguments or prints. Every
sub-command is a thin layer over the Python API. User mistakes (bad values, unknown names, malformed
files, output paths that cannot be written) become one red line on stderr and exit code 2; nothing
is written in that case.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from activelearn.errors import ActiveLearnError, CampaignStopped
from simulator.errors import SimulatorError

EXIT_USAGE = 2
EXIT_STOPPED = 75  # EX_TEMPFAIL: a campaign stopped for a cause outside it; --resume continues it

Handler = Callable[[argparse.Namespace], int]


def _red(text: str) -> str:
    return f"\033[31m{text}\033[0m" if sys.stderr.isatty() else text


def _one_line(text: str) -> str:
    """`text` with every non-printable character escaped (line breaks and terminal controls included)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _yellow(text: str) -> str:
    return f"\033[33m{text}\033[0m" if sys.stderr.isatty() else text


def fail(message: str) -> int:
    """Print one red error line on stderr and return the usage exit code.

    Messages can quote what the user typed (a config key, a file's bytes): escaping it keeps the
    line one line and the terminal's state untouched.
    """
    print(_red(f"error: {_one_line(message)}"), file=sys.stderr)
    return EXIT_USAGE


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one red line and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        for action in self._actions:  # a missing sub-command: name the choices
            if isinstance(action, argparse._SubParsersAction) and message.endswith(f": {action.metavar}"):
                message += f" (one of {', '.join(action.choices)})"
        fail(message)
        raise SystemExit(EXIT_USAGE)


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level parser with every sub-command registered."""
    parser = _Parser(prog="activelearn", description=__doc__.splitlines()[0],
                     epilog="`activelearn COMMAND --help` describes each command.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND",
                                title="commands")
    for register in _REGISTRARS:
        register(sub)
    return parser


def _output_path(
    option: str, value: str | Path, *, folder: bool = False, suffixes: Sequence[str] = ()
) -> Path:
    """`value` as the path of an output file (or `folder`), checked before any work is done.

    Rejects a wrong suffix, a file where a folder must be (the path itself or any folder above it), a
    folder where a file must be, and a place this process cannot write to.
    """
    import os

    from activelearn.errors import InputError

    path = Path(value)
    if suffixes and path.suffix.lower() not in suffixes:
        raise InputError(option, str(value), f"must end in {', '.join(suffixes)}")
    if path.exists() and path.is_dir() != folder:
        raise InputError(option, str(value), "is a folder" if path.is_dir() else "is a file, not a folder")
    parent = path if folder else path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(option, str(value), f"{parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(option, str(value), f"cannot write in {parent}")
    return path


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


def _add_maneuver_options(p: argparse.ArgumentParser) -> None:
    """The options that define one maneuver (simulate, predict): a reference kind, or a schedule file."""
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--maneuver", metavar="KIND", help="straight, skidpad, fishhook, slalom or eight")
    which.add_argument("--schedule", metavar="CSV",
                       help="drive this schedule open loop instead: columns time (s, from 0, one row per "
                            "log sample), throttle, steering (rad, + left), each command held until the next "
                            "row; e.g. a proposal's schedule file written by `campaign propose`")
    p.add_argument("--throttle", type=float, default=None, metavar="T",
                   help="throttle in [-1, 1] (required with --maneuver)")
    p.add_argument("--steering", type=float, default=None, metavar="S",
                   help="steering amplitude in (0, 0.5236] rad: required for skidpad, slalom and eight; "
                        "fishhook's default 0.5236; a straight takes none")
    p.add_argument("--direction", default=None, metavar="cw|ccw", help="ccw turns left first (default)")
    p.add_argument("--duration", type=float, default=None, metavar="SEC", help="seconds (default 90)")


def _maneuver_from_args(args: argparse.Namespace):
    """The validated Maneuver of --maneuver/--throttle/--steering/--direction/--duration."""
    from activelearn.errors import InputError
    from simulator import STEERING_LIMIT, Maneuver, ManeuverError

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
        steering = STEERING_LIMIT if args.maneuver == "fishhook" else 0.0
    direction = "ccw" if args.direction is None else args.direction
    duration = 90.0 if args.duration is None else args.duration
    try:
        return Maneuver(args.maneuver, args.throttle, steering, direction, duration)
    except ManeuverError as exc:
        raise InputError(_MANEUVER_OPTIONS.get(exc.field, exc.field), exc.value, exc.reason) from None


_SCHEDULE_COLUMNS = ("time", "throttle", "steering")


def _schedule_from_args(args: argparse.Namespace, rate_hz: float, fixed_rate: bool = False):
    """What --schedule FILE drives at `rate_hz`: the proposal it is (a family member) or a Replay of its rows.

    Every problem is an InputError naming the option and the file, and the column where one is at fault;
    a file at another rate names --rate, or the file itself where the rate is `fixed_rate` (predict).
    """
    import numpy as np
    import pandas as pd

    from activelearn.errors import InputError
    from simulator import ManeuverError
    from simulator.schedules import schedule_maneuver

    for option in ("throttle", "steering", "direction", "duration"):
        if getattr(args, option) is not None:
            raise InputError(f"--{option}", getattr(args, option),
                             f"the schedule sets the {option}: drop --{option} (or drop --schedule)")
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
        reason = f"is not a readable CSV table ({_one_line(str(exc))})"
        raise InputError("--schedule", str(path), reason) from None
    table.columns = [str(c).strip() for c in table.columns]
    missing = [c for c in _SCHEDULE_COLUMNS if c not in table.columns]
    if missing:
        raise InputError(f"--schedule {path}", list(table.columns),
                         f"lacks the column(s) {', '.join(missing)} (a schedule has time, throttle, "
                         "steering)")
    if table.empty:
        raise InputError(f"--schedule {path}", 0, "holds no rows below its header")
    values = {}
    for column in _SCHEDULE_COLUMNS:
        text = table[column]
        numbers = pd.to_numeric(text, errors="coerce")
        junk = numbers.isna() & text.notna() & ~text.str.strip().str.lower().isin(("nan", "inf", "-inf"))
        if junk.any():
            row = int(np.argmax(junk.to_numpy()))
            raise InputError(f"--schedule {path}: column {column}", text.iloc[row],
                             f"row {row + 1} is not a number")
        values[column] = numbers.to_numpy(dtype=np.float64)
    try:
        return schedule_maneuver(path.stem, values["time"], values["throttle"], values["steering"], rate_hz)
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


def _driven_from_args(args: argparse.Namespace, rate_hz: float, fixed_rate: bool = False):
    """The maneuver of --maneuver (and its options) or of --schedule FILE, validated."""
    if args.schedule is not None:
        return _schedule_from_args(args, rate_hz, fixed_rate)
    return _maneuver_from_args(args)


def _register_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate one maneuver of Nigel and write its log (CSV or Parquet)",
        description="Simulate one maneuver of Nigel in MuJoCo and write its log in the AutoDRIVE layout: a "
                    "reference kind (--maneuver), or a schedule file driven open loop (--schedule), such as "
                    "a proposal of `campaign propose`, to rehearse it.",
    )
    _add_maneuver_options(p)
    p.add_argument("--rate", type=float, default=30.0, metavar="HZ", help="log rate in Hz (default 30)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="noise seed (default 0)")
    p.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True,
                   help="add the default sensor noise (default: on)")
    p.add_argument("--out", required=True, metavar="PATH", help="output log, .csv or .parquet")
    p.add_argument("--autodrive", action="store_true",
                   help="write the AutoDRIVE dataset's layout (headerless 21-field CSV), not a table")
    p.add_argument("--plot", default=None, metavar="PNG", help="also draw the log figure (.png, .pdf, .svg)")
    p.set_defaults(handler=_simulate)


def _simulate(args: argparse.Namespace) -> int:
    import math
    import warnings

    from activelearn.errors import InputError
    from simulator import DivergenceWarning, NoiseConfig, collect

    # Validate everything before simulating, so a bad value never leaves a file behind.
    if not math.isfinite(args.rate) or not 0.0 < args.rate <= 300.0:
        raise InputError("--rate", args.rate, "must lie in (0, 300] Hz")
    maneuver = _driven_from_args(args, args.rate)
    if args.seed < 0:
        raise InputError("--seed", args.seed, "must be >= 0")
    out = _output_path("--out", args.out, suffixes=(".csv", ".parquet"))
    if args.autodrive and out.suffix.lower() != ".csv":
        raise InputError("--out", args.out, "an AutoDRIVE log (--autodrive) is a .csv file")
    plot = _output_path("--plot", args.plot, suffixes=_PLOT_SUFFIXES) if args.plot else None

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
    if args.autodrive:
        from activelearn.data import write_autodrive_log

        write_autodrive_log(table, out)
    else:
        write_table(table, out)
    print(f"{maneuver.name}: {len(table)} rows, mean speed {table['speed'].mean():.4f} m/s, "
          f"mean yaw rate {table['angZ'].mean():+.4f} rad/s")
    print(f"wrote {out}" + (f" and {plot}" if plot is not None else ""))
    return 0


_REGISTRARS.append(_register_simulate)


# --- campaign run / compare -----------------------------------------------------------------------

_ROUND_COLUMNS = {
    "round": "round",
    "n_maneuvers": "maneuvers",
    "n_samples": "samples",
    "test_rmse": "RMSE",
    "test_rmse_v": "RMSE v",
    "test_rmse_w": "RMSE ω",
    "test_nll": "NLL",
    "coverage_95": "cover95",
    "epistemic_std_mean": "epi std",
    "calib_std_to_rmse": "epi/err",
    "calib_z_spread": "z spread",
}
# Free-run metrics a config may rank by ([test] metric): shown after the samples when it does.
_FREE_RUN_COLUMNS = {
    "rollout_pos_err_10s": "pos 10s m",
    "rollout_pos_err_30s": "pos 30s m",
    "rollout_heading_err_30s": "yaw 30s",
    "rollout_rmse_v": "free v",
    "rollout_rmse_w": "free ω",
    "rollout_coverage_95": "fan95",
}


def _round_columns(cfg: Any, history: Any) -> dict[str, str]:
    """Columns of the per-round table that `history` has: the config's ranking metric and fan
    coverage first when it ranks by a free run, then the one-step metrics."""
    columns = dict(_ROUND_COLUMNS)
    if cfg.test.metric in _FREE_RUN_COLUMNS:
        first = {k: columns.pop(k) for k in ("round", "n_maneuvers", "n_samples")}
        ranked = {k: _FREE_RUN_COLUMNS[k] for k in (cfg.test.metric, "rollout_coverage_95")}
        columns = {**first, **ranked, **columns}
    return {k: v for k, v in columns.items() if k in history}


# Mirrors activelearn.loop.acquisition.STRATEGIES for the help texts: importing it (torch) here would
# slow down every command; tests check the copy agrees.
_STRATEGIES = ("grid", "uniform", "random", "sobol", "lhs", "max_epistemic", "epistemic_maximin", "max_total",
               "bald", "integrated_variance", "auto", "oracle_error", "oracle_lookahead")
_CACHE_NOTE = ("simulated maneuvers are cached in the config's output_dir/cache (default ./runs/cache), "
               "whatever --out says")


def _add_config_options(p: argparse.ArgumentParser, out_default: str) -> None:
    p.add_argument("config", metavar="CONFIG",
                   help="campaign config (TOML), e.g. experiments/configs/skidpad.toml")
    p.add_argument("--tracking-uri", default=None, metavar="URI",
                   help="MLflow tracking URI (default: the config's, sqlite:///mlruns/mlflow.db)")
    p.add_argument("--no-tracking", action="store_true", help="do not log to MLflow")
    p.add_argument("--params", default=None, metavar="TOML",
                   help="[model]/[training] overrides, e.g. runs/tuning/<study>/best.toml written by "
                        "`activelearn tune`")
    p.add_argument("--out", default=None, metavar="DIR",
                   help=f"output directory (default {out_default}, <output_dir> being the config's, "
                        f"default runs); {_CACHE_NOTE}")
    p.add_argument("--resume", action="store_true",
                   help="continue the stopped run in --out (an error if it holds none)")
    _add_wait(p)


def _add_wait(p: argparse.ArgumentParser) -> None:
    p.add_argument("--wait", type=float, default=120.0, metavar="S",
                   help="seconds to wait while another command writes the same campaign (default 120)")


def _notice(event: dict) -> bool:
    """Print a campaign's notices (another writer holds its lock; the tracking server went away or is
    back) as one yellow line on stderr; False for any other event."""
    if event["event"] == "lock_wait":
        text = (f"{event['directory']} is being written by {event['holder']}; "
                f"waiting up to {event['wait']:g} s")
    elif event["event"] in ("tracking_down", "tracking_back"):
        text = event["message"]
    else:
        return False
    print(_yellow(f"warning: {_one_line(text)}"), file=sys.stderr)
    return True


def _ui_hint(uri: str) -> str:
    """Where to look at the runs: a tracking server's own address, else `mlflow ui` on the store."""
    if uri.startswith(("http://", "https://")):
        return f"open {uri} in a browser"
    return f"mlflow ui --backend-store-uri {uri}"


def _load_campaign_config(args: argparse.Namespace, **overrides: object):
    from activelearn.config import load_config

    if args.tracking_uri is not None:
        overrides["tracking"] = {"uri": args.tracking_uri}
    return load_config(args.config, params=args.params, overrides=overrides)


def _register_campaign(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("campaign", help="run, propose or ingest one active-learning campaign",
                       description="Active-learning campaigns: one config, one strategy, one seed. `run` "
                                   "lets the simulator answer every batch; `propose` and `ingest` let a "
                                   "person drive the car.")
    campaign_sub = p.add_subparsers(dest="campaign_command", required=True, parser_class=_Parser,
                                    metavar="COMMAND", title="commands")
    run = campaign_sub.add_parser("run", help="run (or resume) a campaign, the simulator answering",
                                  description="Run (or resume) a campaign to its budget; the config's oracle "
                                              "(the simulator, a twin or recorded logs) answers every batch.")
    _add_config_options(run, "<output_dir>/<name>/<strategy>/seed<N>")
    _add_strategy_seed(run)
    run.set_defaults(handler=_campaign_run)

    propose = campaign_sub.add_parser(
        "propose", help="start a campaign a person drives: write the first maneuvers to drive",
        description="Ask: run the initial design (or the prior's model) and write "
                    "DIR/proposals/round-NNN.csv with the maneuvers to drive (the values `activelearn "
                    "simulate` takes).",
    )  # fmt: skip
    _add_config_options(propose, "<output_dir>/<name>/<strategy>/seed<N>")
    _add_strategy_seed(propose)
    propose.add_argument("--plot", default=None, metavar="PNG",
                         help="also draw the proposals' predicted paths, fans and risks in the arena")
    propose.set_defaults(handler=_campaign_propose)

    ingest = campaign_sub.add_parser(
        "ingest", help="tell a campaign the logs of its proposals; retrain and propose the next batch",
        description="Tell: match each log to the proposal it answers (by its recorded controls), append the "
                    "samples, retrain, log the round to MLflow and write the next proposals.",
    )  # fmt: skip
    ingest.add_argument("directory", metavar="DIR", help="the campaign directory `campaign propose` made")
    ingest.add_argument("logs", nargs="*", metavar="LOG", help="logs (AutoDRIVE layout, .csv or .parquet)")
    ingest.add_argument("--resume", action="store_true",
                        help="finish a step an interrupted ingest left (no logs needed)")
    ingest.add_argument("--tracking-uri", default=None, metavar="URI",
                        help="MLflow tracking URI (default: the campaign config's)")
    ingest.add_argument("--no-tracking", action="store_true", help="do not log to MLflow")
    _add_wait(ingest)
    ingest.set_defaults(handler=_campaign_ingest)


def _add_strategy_seed(p: argparse.ArgumentParser) -> None:
    p.add_argument("--strategy", default=None, metavar="S",
                   help=f"strategy (default: the config's): {', '.join(_STRATEGIES)}")
    p.add_argument("--seed", type=int, default=None, metavar="N", help="seed (default: the config's)")


def _strategy_seed(args: argparse.Namespace) -> dict[str, object]:
    """Config overrides of --strategy and --seed."""
    return {k: v for k, v in (("strategy", args.strategy), ("seed", args.seed)) if v is not None}


def _print_proposals(maneuvers: list, path) -> None:
    import pandas as pd

    from simulator import FamilyManeuver

    if any(isinstance(m, FamilyManeuver) for m in maneuvers):
        rows = [{"#": i + 1, "maneuver": m.kind, "direction": m.direction, "duration": m.duration,
                 "parameters": ", ".join(f"{k}={v:g}" for k, v in m.params)}
                for i, m in enumerate(maneuvers)]  # fmt: skip
        print(f"drive these {len(rows)} maneuvers ({path}):")
        print(pd.DataFrame(rows).to_string(index=False))
        print(f"each row's schedule file (in {Path(path).with_suffix('')}) lists time (s), throttle and "
              "steering (rad, + left): hold each command until the next row")  # fmt: skip
        return
    rows = [{"#": i + 1, "maneuver": m.kind, "direction": m.direction, "throttle": m.throttle,
             "steering": m.steering, "duration": m.duration} for i, m in enumerate(maneuvers)]  # fmt: skip
    print(f"drive these {len(rows)} maneuvers ({path}):")
    print(pd.DataFrame(rows).to_string(index=False))
    print("e.g. activelearn simulate --maneuver {maneuver} --direction {direction} --throttle {throttle} "
          "--steering {steering} --duration {duration} --out LOG.csv".format(**rows[0]))  # fmt: skip


def _campaign_directory(args: argparse.Namespace, cfg) -> Path:
    """The campaign directory of --out (or the config's default), checked before any work is done."""
    from activelearn.errors import InputError
    from activelearn.loop.campaign import default_directory
    from activelearn.loop.state import STATE_FILE

    directory = _output_path("--out", args.out or default_directory(cfg), folder=True)
    if args.resume and not (directory / STATE_FILE).is_file():
        raise InputError("--resume", str(directory),
                         f"holds no campaign to resume (no {STATE_FILE}): check --out, or drop --resume")
    return directory


def _campaign_tracker(cfg, args):
    if not cfg.tracking.enabled or args.no_tracking:
        return None
    from activelearn.studies.tracking import Tracker

    return Tracker(args.tracking_uri or cfg.tracking.uri, cfg.tracking.experiment)


def _campaign_propose(args: argparse.Namespace) -> int:

    from activelearn.errors import InputError
    from activelearn.loop.campaign import Campaign, CampaignInterrupted

    cfg = _load_campaign_config(args, **_strategy_seed(args))
    plot = Path(args.plot) if args.plot else None
    if plot is not None and plot.suffix.lower() not in _PLOT_SUFFIXES:
        raise InputError("--plot", args.plot, f"must end in {', '.join(_PLOT_SUFFIXES)}")
    if plot is not None and cfg.safety is None:
        raise InputError("--plot", args.plot, "draws the [safety] arena: the config has no [safety] section")
    directory = _campaign_directory(args, cfg)
    campaign = Campaign(cfg, directory, tracker=_campaign_tracker(cfg, args), progress=_notice)
    campaign.lock_wait = args.wait
    try:
        proposals = campaign.propose(resume=args.resume)
    except CampaignInterrupted as exc:
        print(_red(f"interrupted: {exc}"), file=sys.stderr)
        return 130
    from activelearn.loop.state import CampaignState

    if not proposals:
        print(_finished_message(CampaignState.load(directory), cfg, directory)
              or f"the campaign has finished; directory: {directory}")  # fmt: skip
        return 0

    state = CampaignState.load(directory)
    _print_proposals(proposals, campaign.proposal_path(state))
    if cfg.safety is not None:
        _print_safety(campaign, state)
    if plot is not None:
        from activelearn.loop.safety import proposal_figure

        print(f"wrote {proposal_figure(campaign, plot)}")
    print(f"then: activelearn campaign ingest {directory} LOG...")
    return 0


def _finished_message(state, cfg, directory) -> str:
    """What to change before `--resume` when [safety] stopped a campaign ("" for any other stop)."""
    if state.stop_reason != "nothing_admissible":
        return ""
    last = state.rounds[-1] if state.rounds else {}
    risk = f" (the safest candidate's risk: {last['risk_min']:.3f})" if "risk_min" in last else ""
    return (f"stopped: no candidate is admissible at safety.delta = {cfg.safety.delta:g}{risk}. The "
            f"directory {directory} is kept: widen safety.arena, move safety.start, raise safety.delta or "
            "lower safety.min_duration in the config, then rerun with --resume")  # fmt: skip


def _print_safety(campaign, state) -> None:
    """Risk of each proposal and the durations [safety] cut, under the proposals' table."""
    safety = campaign.cfg.safety
    last = state.rounds[-1] if state.rounds else {}
    size = f"{int(last['safe_set_size'])} admissible candidates, " if "safe_set_size" in last else ""
    print(f"[safety] {size}delta {safety.delta:g}: " + "; ".join(
        f"#{n + 1} risk {state.risks.get(str(i), float('nan')):.3f}"
        + (f", cut from {campaign.maneuvers[i].duration:g} s" if str(i) in state.cuts else "")
        for n, i in enumerate(state.pending or [])
    ))  # fmt: skip


def _campaign_ingest(args: argparse.Namespace) -> int:
    from activelearn.loop.asktell import ingest, open_campaign
    from activelearn.loop.campaign import CampaignInterrupted

    campaign = open_campaign(args.directory)
    campaign.tracker = _campaign_tracker(campaign.cfg, args)
    campaign.progress, campaign.lock_wait = _notice, args.wait
    try:
        report = ingest(campaign, args.logs, resume=args.resume)
    except CampaignInterrupted as exc:
        print(_red(f"interrupted: {exc}"), file=sys.stderr)
        return 130
    for log, name in report.matched.items():
        print(f"{log} -> {name}")
    if report.missing:
        print("still missing: " + ", ".join(m.name for m in report.missing))
        return 0
    history = campaign.history()
    if not history.empty:
        columns = _round_columns(campaign.cfg, history)
        last = history[list(columns)].tail(1).rename(columns=columns)
        print(last.to_string(index=False, float_format="%.4g"))
    if report.finished:
        from activelearn.loop.state import CampaignState

        state = CampaignState.load(campaign.directory)
        print(_finished_message(state, campaign.cfg, campaign.directory)
              or f"the campaign has finished; directory: {campaign.directory}")  # fmt: skip
    else:
        _print_proposals(report.proposals, report.proposals_path)
        if campaign.cfg.safety is not None:
            from activelearn.loop.state import CampaignState

            _print_safety(campaign, CampaignState.load(campaign.directory))
    return 0


def _campaign_run(args: argparse.Namespace) -> int:

    from tqdm import tqdm

    from activelearn.loop.campaign import Campaign, CampaignInterrupted, total_rounds

    cfg = _load_campaign_config(args, **_strategy_seed(args))
    directory = _campaign_directory(args, cfg)
    tracker = _campaign_tracker(cfg, args)
    campaign = Campaign(cfg, directory, tracker=tracker)
    bar = tqdm(total=total_rounds(cfg, len(campaign.maneuvers)), unit="round",
               desc=f"{cfg.name} {cfg.strategy} seed {cfg.seed}", disable=None)

    def progress(event: dict) -> None:
        if _notice(event):
            bar.refresh()
        elif event["event"] == "round":
            bar.update(1)
            bar.set_postfix(maneuvers=event["n_maneuvers"], samples=event["n_samples"],
                            rmse=f"{event['test_rmse']:.4f}")

    campaign.progress, campaign.lock_wait = progress, args.wait
    try:
        result = campaign.run(resume=args.resume)
    except CampaignInterrupted as exc:
        bar.close()
        print(_red(f"interrupted: {exc}"), file=sys.stderr)
        return 130
    bar.close()
    history = result.history
    columns = _round_columns(cfg, history)
    print(history[list(columns)].rename(columns=columns).to_string(index=False, float_format="%.4g"))
    print(_finished_message(result.state, cfg, directory)
          or f"stopped by {result.state.stop_reason}; campaign directory: {directory}")  # fmt: skip
    if tracker is not None:
        print(f"MLflow run {result.state.run_id} in {cfg.tracking.uri} "
              f"({_ui_hint(cfg.tracking.uri)})")
    return 0


_REGISTRARS.append(_register_campaign)

_SUMMARY_COLUMNS = {
    "strategy": "strategy",
    "seeds": "seeds",
    "final_rmse": "final RMSE",
    "final_rmse_sem": "± s.e.",
    "final_rmse_v": "v (m/s)",
    "final_rmse_w": "ω (rad/s)",
    "final_nll": "final NLL",
    "rmse_auc": "RMSE AUC",
    "final_metric": "final metric",
    "final_metric_sem": "± s.e. ",
    "metric_auc": "metric AUC",
    "reached": "reached",
    "maneuvers_to_target": "maneuvers to target",
    "ratio_to_reference": "ratio",
    "seconds_to_target": "seconds to target",
    "seconds_ratio": "s ratio",
}


def _register_compare(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compare", help="compare strategies over seeds under one MLflow parent run",
                       description="Run strategies x seeds on one config and compare them with uniform.")
    _add_config_options(p, "<output_dir>/<name>/compare")
    p.add_argument("--strategies", default="uniform,max_epistemic", metavar="A,B,...",
                   help="comma-separated strategies (default: uniform,max_epistemic), from "
                        f"{', '.join(_STRATEGIES)}")
    p.add_argument("--seeds", type=int, default=3, metavar="N", help="seeds 0..N-1 (default 3)")
    p.add_argument("--workers", type=int, default=None, metavar="K",
                   help="parallel processes, or CPUs of a local Ray cluster (default: number of cores)")
    p.add_argument("--executor", default="process", metavar="NAME",
                   help="process (default: local processes) or ray (one task per campaign on a Ray cluster)")
    p.add_argument("--ray-address", default=None, metavar="ADDR",
                   help="with --executor ray: auto (the cluster this machine belongs to), HOST:PORT, "
                        "or local (an in-process cluster; the default)")
    p.add_argument("--metric", default=None, metavar="NAME",
                   help="what the table, the 'to reach uniform' columns and the figure rank by: test_rmse, "
                        "rollout_pos_err_30s, ... (default: the config's [test] metric)")
    p.set_defaults(handler=_compare)


def _compare(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from activelearn.errors import InputError
    from activelearn.studies.compare import compare

    strategies = [s.strip() for s in args.strategies.split(",") if s.strip()]
    if args.seeds < 1:
        raise InputError("--seeds", args.seeds, "must be at least 1")
    if args.workers is not None and args.workers < 1:
        raise InputError("--workers", args.workers, "must be at least 1")
    cfg = _load_campaign_config(args)
    directory = _output_path("--out", args.out or Path(cfg.output_dir) / cfg.name / "compare", folder=True)
    if args.resume and not (directory / "compare.json").is_file():
        raise InputError("--resume", str(directory),
                         "holds no comparison to resume (no compare.json): check --out, or drop --resume")
    n_jobs = len(strategies) * args.seeds
    bars: dict[str, tqdm] = {}

    def progress(event: dict) -> None:
        if event["event"] == "sim_progress":
            bar = bars.setdefault("sim", tqdm(total=event["total"], unit="sample", desc="simulating pool",
                                              leave=False, disable=None))
            bar.update(event["done"] - bar.n)
        elif event["event"] == "dashboard":
            tqdm.write(f"Ray dashboard: {event['url']}", file=sys.stderr)
        elif event["event"] == "job":
            bar = bars.setdefault("jobs", tqdm(total=n_jobs, unit="campaign", desc="campaigns", disable=None))
            bar.update(1)
            bar.set_postfix(last=f"{event['strategy']}/seed{event['seed']}", rmse=f"{event['test_rmse']:.4f}")

    try:
        result = compare(cfg, strategies, list(range(args.seeds)), directory=directory, workers=args.workers,
                         tracking=cfg.tracking.enabled and not args.no_tracking, resume=args.resume,
                         progress=progress, executor=args.executor, ray_address=args.ray_address,
                         metric=args.metric, lock_wait=args.wait)
    except KeyboardInterrupt:
        print(_red("interrupted: finished rounds are checkpointed; rerun the same command with --resume"),
              file=sys.stderr)
        return 130
    finally:
        for bar in bars.values():
            bar.close()
    table = result.table
    metric = table.attrs["metric"]
    if metric == "test_rmse":
        print(f"target: {table.attrs['reference']}'s final RMSE {table.attrs['target_rmse']:.4g} "
              "(standardised; RMSE of v in m/s and ω in rad/s beside it)")
    else:
        print(f"target: {table.attrs['reference']}'s final {metric} {table.attrs['target_rmse']:.4g} "
              "(final metric; one-step RMSE beside it)")
    summary = table[[c for c in _SUMMARY_COLUMNS if c in table]].rename(columns=_SUMMARY_COLUMNS)
    print(summary.to_string(index=False, float_format="%.4g"))
    print(f"figure: {result.figure_path}")
    print(f"curves and table: {result.directory}")
    if result.parent_run_id is not None:
        print(f"MLflow parent run {result.parent_run_id} ({_ui_hint(cfg.tracking.uri)})")
    return 0


_REGISTRARS.append(_register_compare)


# --- tune -----------------------------------------------------------------------------------------

_BEST_COLUMNS = {
    "trial": "trial",
    "val_nll": "val NLL",
    "val_rmse": "val RMSE",
    "arch": "arch",
    "activation": "act",
    "posterior": "posterior",
    "kl": "kl",
    "prior_scale": "prior",
    "lr": "lr",
    "optimizer": "opt",
    "loss": "loss",
    "batch_size": "batch",
    "epochs": "epochs",
    "best_epoch": "best ep",
}


# Mirrors activelearn.studies.tuning.DEFAULT_STORAGE / PRUNERS: importing that module (Optuna, torch) here
# would slow down every command; tests check the copies agree.
_TUNE_STORAGE = "sqlite:///mlruns/optuna.db"
_TUNE_PRUNERS = ("median", "hyperband", "none")


def _register_tune(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "tune", help="tune the model's hyperparameters with Optuna (tracked in MLflow)",
        description="Optuna study over the config's [tuning.space]: minimise the validation NLL (and "
                    "optionally RMSE) on operating points held out whole. Same --study-name continues.",
    )  # fmt: skip
    p.add_argument("config", metavar="CONFIG",
                   help="campaign config (TOML) with an optional [tuning] section")
    p.add_argument("--n-trials", type=int, required=True, metavar="N",
                   help="trials this command adds to the study (shared by its workers)")
    p.add_argument("--storage", default=_TUNE_STORAGE, metavar="URL",
                   help=f"Optuna storage (default {_TUNE_STORAGE}); postgresql://user:pass@host/db "
                        "lets workers on many machines join one study")
    p.add_argument("--study-name", default=None, metavar="NAME",
                   help="study name (default: the config's name)")
    p.add_argument("--workers", type=int, default=1, metavar="K", help="worker processes (default 1)")
    p.add_argument("--timeout", type=float, default=None, metavar="SEC",
                   help="start no new trial after SEC seconds")
    p.add_argument("--tracking-uri", default=None, metavar="URI",
                   help="MLflow tracking URI (default: the config's, sqlite:///mlruns/mlflow.db)")
    p.add_argument("--no-tracking", action="store_true", help="do not log to MLflow")
    p.add_argument("--data", nargs="+", default=None, metavar="PATH",
                   help="train on these tables (.parquet) or AutoDRIVE logs (.csv) instead of simulating "
                        "the config's pool")
    p.add_argument("--objectives", default="nll", metavar="nll|nll,rmse",
                   help="validation NLL, or NLL and RMSE (multi-objective: no pruning)")
    p.add_argument("--pruner", default="median", choices=_TUNE_PRUNERS, help="trial pruner (default median)")
    p.add_argument("--seed", type=int, default=None, metavar="N", help="sampler seed (default: the config's)")
    p.add_argument("--out", default=None, metavar="TOML",
                   help="best params file (default runs/tuning/<study>/best.toml); figures go beside it")
    p.set_defaults(handler=_tune)


def _tune(args: argparse.Namespace) -> int:
    import math

    from tqdm import tqdm

    from activelearn.config import load_config
    from activelearn.errors import InputError
    from activelearn.studies.tuning import TuningInterrupted, parse_objectives, tune

    # Argument checks first: a mistake never creates a study, a run or a file.
    if args.n_trials < 1:
        raise InputError("--n-trials", args.n_trials, "must be at least 1")
    if args.workers < 1:
        raise InputError("--workers", args.workers, "must be at least 1")
    if args.timeout is not None and not args.timeout > 0:
        raise InputError("--timeout", args.timeout, "must be > 0 seconds")
    if args.out is not None:
        _output_path("--out", args.out)
    objectives = parse_objectives(args.objectives)
    overrides: dict[str, object] = {}
    if args.tracking_uri is not None:
        overrides["tracking"] = {"uri": args.tracking_uri}
    cfg = load_config(args.config, overrides=overrides)
    study_name = args.study_name or cfg.name
    bars: dict[str, tqdm] = {}
    counts = {"COMPLETE": 0, "PRUNED": 0, "FAIL": 0}
    best = [math.inf]

    def progress(event: dict) -> None:
        kind = event["event"]
        if kind == "note":
            tqdm.write(f"note: {event['message']}", file=sys.stderr)
        elif kind == "warning":  # a worker was lost; the study goes on without losing a trial
            tqdm.write(_yellow(f"warning: {event['message']}"), file=sys.stderr)
        elif kind == "sim_progress":
            bar = bars.setdefault("sim", tqdm(total=event["total"], unit="sample", desc="simulating pool",
                                              leave=False, disable=None))
            bar.update(event["done"] - bar.n)
        elif kind == "start":
            if "sim" in bars:
                bars.pop("sim").close()
            if event["existing_trials"]:
                tqdm.write(f"continuing study {event['study']!r} ({event['existing_trials']} trials so far)",
                           file=sys.stderr)
            tqdm.write(f"data: {event['train_rows']} training rows at {event['train_points']} operating "
                       f"points, {event['val_rows']} validation rows at {event['val_points']} held-out "
                       "points", file=sys.stderr)
            bars["trials"] = tqdm(total=args.n_trials, unit="trial", desc=f"tune {study_name}", disable=None)
        elif kind == "trial":
            counts[event["state"]] = counts.get(event["state"], 0) + 1
            if event["state"] == "COMPLETE" and event["values"]:
                best[0] = min(best[0], event["values"][0])
            if event["state"] == "FAIL" and event.get("fail_reason"):
                tqdm.write(f"trial {event['number']} failed: {event['fail_reason']}", file=sys.stderr)
            bar = bars.get("trials")
            if bar is not None:
                bar.update(1)
                bar.set_postfix(best_nll=f"{best[0]:.4g}", pruned=counts["PRUNED"], failed=counts["FAIL"])

    try:
        result = tune(cfg, n_trials=args.n_trials, storage=args.storage, study_name=args.study_name,
                      workers=args.workers, timeout=args.timeout, data=args.data, objectives=objectives,
                      pruner=args.pruner, seed=args.seed, out=args.out, tracking=not args.no_tracking,
                      progress=progress)  # fmt: skip
    except TuningInterrupted as exc:
        print(_red(f"interrupted: {exc}"), file=sys.stderr)
        return 130
    finally:
        for bar in bars.values():
            bar.close()
    states = ", ".join(f"{n.lower()} {c}" for n, c in result.states.items() if c)
    print(f"study {result.study_name!r}: {result.n_trials} trials this run ({states}), "
          f"{result.study_trials} finished in all; {result.trials_per_minute:.2f} trials/min")
    for note in result.notes:
        print(f"note: {note}")
    if result.best.empty:
        print("no completed trial yet")
        return 1
    title = "Pareto front (val NLL, val RMSE)" if len(result.objectives) > 1 else "best trials"
    table = result.best[[c for c in _BEST_COLUMNS if c in result.best]].rename(columns=_BEST_COLUMNS)
    print(f"{title}:")
    print(table.to_string(index=False, float_format="%.4g"))
    print(f"best params: {result.best_path}  "
          f"(activelearn campaign run {args.config} --params {result.best_path})")
    if result.figures:
        print("figures: " + ", ".join(str(f) for f in result.figures))
    print(f"storage: {result.storage}  (optuna-dashboard {result.storage})")
    if result.parent_run_id is not None:
        print(f"MLflow parent run {result.parent_run_id} ({_ui_hint(cfg.tracking.uri)})")
    return 0


_REGISTRARS.append(_register_tune)

# --- predict --------------------------------------------------------------------------------------


_PREDICT_RATE = 30.0  # Hz: the rate predict simulates at (MuJoCo's log and the surrogate's steps)


def _register_predict(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="forward-simulate a trained surrogate against MuJoCo on one maneuver",
                       description="Run the surrogate (with uncertainty fans) and MuJoCo on one maneuver: a "
                                   "reference kind (--maneuver) or a schedule file at 30 Hz (--schedule).")
    p.add_argument("--model", required=True, metavar="URI|PATH",
                   help="model file (model.pt), campaign directory, or MLflow model URI (runs:/<id>/model)")
    _add_maneuver_options(p)
    p.add_argument("--samples", type=int, default=32, metavar="S", help="sampled trajectories (default 32)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="noise and sampling seed (default 0)")
    p.add_argument("--out", default=None, metavar="PNG", help="write the figure here (.png, .pdf, .svg)")
    p.add_argument("--run-id", default=None, metavar="RUN",
                   help="also log metrics and figure to this MLflow run")
    p.add_argument("--tracking-uri", default="sqlite:///mlruns/mlflow.db", metavar="URI",
                   help="MLflow store for runs:/ URIs and --run-id (default sqlite:///mlruns/mlflow.db)")
    p.set_defaults(handler=_predict)


def _load_any_model(spec: str, tracking_uri: str):
    from pathlib import Path

    from activelearn.errors import InputError
    from activelearn.numerics.models import load_model

    path = Path(spec)
    if path.is_dir():
        if not (path / "model.pt").is_file():
            raise InputError("--model", spec, "the folder holds no model.pt (a campaign directory has one "
                                              "once a round is fitted: after `campaign run` or an ingest)")
        path = path / "model.pt"
    if path.is_file():
        try:
            return load_model(path)
        except Exception as exc:  # a foreign or truncated file: say which
            raise InputError("--model", spec, f"cannot read the model file: {exc}") from None
    if "://" not in spec and not spec.startswith(("runs:/", "models:/")):
        raise InputError("--model", spec, "no such file, directory or MLflow model URI")
    _existing_store(tracking_uri)
    from activelearn.studies.tracking import load_model as load_mlflow_model

    return load_mlflow_model(spec, tracking_uri)


def _existing_store(tracking_uri: str) -> None:
    """Refuse a local SQLite MLflow store that does not exist (MLflow would create it, empty)."""
    from activelearn.errors import InputError

    if tracking_uri.startswith("sqlite:///") and not Path(tracking_uri.removeprefix("sqlite:///")).is_file():
        raise InputError("--tracking-uri", tracking_uri,
                         "no MLflow store there; give the store that holds the run (the command that "
                         "logged it printed it)")


def _predict(args: argparse.Namespace) -> int:

    from activelearn.errors import InputError

    maneuver = _driven_from_args(args, _PREDICT_RATE, fixed_rate=True)
    if args.samples < 2:
        raise InputError("--samples", args.samples, "must be at least 2")
    if not 0 <= args.seed < 2**32:  # torch's manual_seed overflows past 2**64
        raise InputError("--seed", args.seed, "must lie in [0, 2**32)")
    out = _output_path("--out", args.out, suffixes=_PLOT_SUFFIXES) if args.out else None
    if args.run_id is not None:
        _existing_store(args.tracking_uri)
    model = _load_any_model(args.model, args.tracking_uri)
    tracker = None
    if args.run_id is not None:
        from activelearn.studies.tracking import Tracker

        tracker = Tracker(args.tracking_uri)
        tracker.run_status(args.run_id)  # fails early, naming the run, before simulating

    from activelearn.numerics.surrogate import against_simulator

    result = against_simulator(model, [maneuver], rate_hz=_PREDICT_RATE, n_samples=args.samples,
                               seed=args.seed)
    m = result.metrics[0]
    rows = [("RMSE v (m/s)", m.rmse_v), ("RMSE ω (rad/s)", m.rmse_w)]
    rows += [(f"position error at {t:g} s (m)", e) for t, e in m.position_error.items()]
    rows += [("steps inside 95% band: v", m.coverage_v), ("steps inside 95% band: ω", m.coverage_w),
             ("steps inside 95% band: position", m.coverage_position)]
    width = max(len(name) for name, _ in rows)
    print(f"{maneuver.name}: surrogate ({args.samples} samples) against MuJoCo")
    for name, value in rows:
        print(f"  {name:<{width}}  {value:.4f}")
    fig = None
    if out is not None or tracker is not None:
        from activelearn.plots import surrogate_figure

        title = f"{maneuver.name}: surrogate vs MuJoCo"
        fig = surrogate_figure(result.rollout, 0, result.truth[0], title=title)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.name}.tmp{out.suffix}")
        fig.savefig(tmp, dpi=120)
        tmp.replace(out)
        print(f"wrote {out}")
    if tracker is not None:
        metrics = {"predict_rmse_v": m.rmse_v, "predict_rmse_w": m.rmse_w, "predict_coverage_v": m.coverage_v,
                   "predict_coverage_w": m.coverage_w, "predict_coverage_position": m.coverage_position}
        metrics.update({f"predict_position_error_{t:g}s": e for t, e in m.position_error.items()})
        tracker.log_metrics(args.run_id, metrics, step=0)
        tracker.log_figure(args.run_id, fig, f"predict/{maneuver.name}.png")
        print(f"logged to MLflow run {args.run_id}")
    return 0


_REGISTRARS.append(_register_predict)


# --- fidelity -------------------------------------------------------------------------------------


def _register_fidelity(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fidelity",
        help="replay logs' commands in the simulator and compare steady speed, yaw rate and turn speed loss",
        description="Replay the commands of each log (AutoDRIVE CSV, our CSV or Parquet) in MuJoCo and "
                    "compare, per operating point of constant commands, the steady speed, yaw rate and "
                    "speed loss in turns of the simulator and of the log.",
    )
    p.add_argument("logs", nargs="+", metavar="LOG", help="log files, or folders searched for .csv/.parquet")
    p.add_argument("--config", default=None, metavar="CONFIG",
                   help="campaign config: its [oracle] twin (overrides) and log rate (default: nominal car)")
    p.add_argument("--plot", default=None, metavar="PNG", help="also draw the figure (.png, .pdf, .svg)")
    p.add_argument("--settle", type=float, default=1.0, metavar="SEC",
                   help="seconds dropped at the start of each stretch of constant commands (default 1)")
    p.add_argument("--min-window", type=float, default=1.0, metavar="SEC",
                   help="seconds of steady data a stretch must still have (default 1)")
    p.set_defaults(handler=_fidelity)


def _log_files(specs: Sequence[str]) -> list:
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

    plot = _output_path("--plot", args.plot, suffixes=_PLOT_SUFFIXES) if args.plot else None
    if not math.isfinite(args.settle) or args.settle < 0:
        raise InputError("--settle", args.settle, "must be a finite number of seconds >= 0")
    if not math.isfinite(args.min_window) or args.min_window <= 0:
        raise InputError("--min-window", args.min_window, "must be a finite number of seconds > 0")
    vehicle, name, rate = None, "nominal", 30.0
    if args.config is not None:
        from activelearn.config import load_config

        cfg = load_config(args.config)
        rate = cfg.simulation.rate_hz
        if cfg.oracle.kind == "twin":
            from simulator import twin_vehicle

            vehicle = twin_vehicle(cfg.oracle.overrides)
            name = "twin " + ", ".join(f"{k}={v:g}" for k, v in sorted(cfg.oracle.overrides.items()))
    logs = [(str(path), read_log_file(path)) for path in _log_files(args.logs)]  # all read before simulating
    settings = FidelitySettings(settle=args.settle, min_window=args.min_window, rate_hz=rate)
    report = compare(logs, vehicle=vehicle, vehicle_name=name, settings=settings)

    points = report.points
    print(f"fidelity of the simulator ({name}) against {len(logs)} log(s): "
          f"{len(report.stretches)} stretch(es) of constant commands, {len(points)} operating point(s)")
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
    widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(header)]
    print("  ".join(h.rjust(w) for h, w in zip(header, widths, strict=True)))
    for line in lines:
        print("  ".join(c.rjust(w) for c, w in zip(line, widths, strict=True)))
    rms_v = math.sqrt(float((points["dv"] ** 2).mean()))
    rms_w = math.sqrt(float((points["dw"] ** 2).mean()))
    print(f"RMS difference over operating points: speed {rms_v:.4f} m/s, yaw rate {rms_w:.4f} rad/s "
          "(v in m/s, ω in rad/s, loss = straight-line speed at that throttle - turn speed; "
          "straight: where the log's straight-line speed comes from)")
    if plot is not None:
        from activelearn.plots import fidelity_figure

        fig = fidelity_figure(points, title=f"simulator ({name}) vs {len(logs)} log(s)")
        plot.parent.mkdir(parents=True, exist_ok=True)
        tmp = plot.with_name(f".{plot.name}.tmp{plot.suffix}")
        fig.savefig(tmp, dpi=120)
        tmp.replace(plot)
        print(f"wrote {plot}")
    return 0


_REGISTRARS.append(_register_fidelity)


# --- identify -------------------------------------------------------------------------------------


def _register_identify(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "identify",
        help="fit the physical parameters of Nigel's single track to logs, beside the datasheet's",
        description="Fit the seven physical parameters of the physics-structured model ([model] kind = "
                    "'physics') to logs (AutoDRIVE CSV, our CSV or Parquet) by free runs of their "
                    "recorded commands, and print them beside the datasheet's values.",
    )
    p.add_argument("logs", nargs="+", metavar="LOG", help="log files, or folders searched for .csv/.parquet")
    p.add_argument("--rate-hz", type=float, default=30.0, metavar="HZ", help="the logs' rate (default 30)")
    p.set_defaults(handler=_identify)


def _identify(args: argparse.Namespace) -> int:
    import math

    from activelearn.errors import InputError
    from activelearn.fidelity import read_log_file
    from activelearn.loop.collection import control_rate_logs
    from activelearn.numerics.models.physics import PARAMETERS, identify_from_logs

    if not (math.isfinite(args.rate_hz) and args.rate_hz > 0):
        raise InputError("--rate-hz", args.rate_hz, "must be a positive number")
    logs = control_rate_logs([read_log_file(path) for path in _log_files(args.logs)])
    values, stderr = identify_from_logs(logs, dt=1.0 / args.rate_hz)
    print(f"physical parameters from {len(logs)} log(s), {sum(len(u) for u, _ in logs)} steps:")
    print(f"  {'parameter':<13}{'datasheet':>10}{'fitted':>10}{'± s.e.':>9}{'change':>9}  unit  meaning")
    for p, value, err in zip(PARAMETERS, values, stderr, strict=True):
        change = f"{value / p.nominal - 1:+.1%}" if p.nominal else f"{value - p.nominal:+.3f}"
        row = f"{p.name:<13}{p.nominal:>10.4f}{value:>10.4f}{err:>9.4f}{change:>9}"
        print(f"  {row}  {p.unit:<5} {p.meaning}")
    return 0


_REGISTRARS.append(_register_identify)


def _nearest_key(exc: Exception) -> str:
    """'; did you mean KEY?' for a config key that does not exist but is close to one that does."""
    import difflib
    import typing

    from activelearn.errors import ConfigError

    if not isinstance(exc, ConfigError) or not exc.reason.startswith("Extra inputs"):
        return ""
    from pydantic import BaseModel

    from activelearn.config import CampaignConfig

    *sections, key = exc.field.split(".")
    schema: type[BaseModel] = CampaignConfig
    for section in sections:
        field = schema.model_fields.get(section)
        # a section's type, or the model of an optional one (`PriorConfig | None`)
        kinds = [field.annotation, *typing.get_args(field.annotation)] if field is not None else []
        models = [k for k in kinds if isinstance(k, type) and issubclass(k, BaseModel)]
        if not models:
            return ""
        schema = models[0]
    found = difflib.get_close_matches(key, list(schema.model_fields), n=1)
    return f"; did you mean {'.'.join([*sections, found[0]])}?" if found else ""


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `activelearn` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler = args.handler
    try:
        return handler(args)
    except CampaignStopped as exc:
        fail(str(exc))
        return EXIT_STOPPED
    except (ActiveLearnError, SimulatorError) as exc:
        return fail(str(exc) + _nearest_key(exc))


if __name__ == "__main__":
    raise SystemExit(main())
