"""`activelearn campaign run | propose | ingest`: one campaign, the simulator or a person answering."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from activelearn.cli import common
from activelearn.cli.common import (
    EXIT_INTERRUPTED,
    PLOT_SUFFIXES,
    Parser,
    add_config_options,
    add_wait,
    load_campaign_config,
    output_path,
    red,
    ui_hint,
)
from activelearn.names import (
    METRICS,
    N_MANEUVERS,
    N_SAMPLES,
    ROLLOUT_COVERAGE_95,
    ROLLOUT_METRICS,
    ROUND,
    ROUND_TABLE,
    STRATEGY_NAMES,
    TEST_RMSE,
)


def round_columns(cfg: Any, history: Any) -> dict[str, str]:
    """Columns of the per-round table that `history` has: the config's ranking metric and fan
    coverage first when it ranks by a free run, then the one-step metrics."""
    columns = {k: METRICS[k].column for k in ROUND_TABLE}
    if cfg.test.metric in ROLLOUT_METRICS:
        first = {k: columns.pop(k) for k in (ROUND, N_MANEUVERS, N_SAMPLES)}
        ranked = {k: METRICS[k].column for k in (cfg.test.metric, ROLLOUT_COVERAGE_95)}
        columns = {**first, **ranked, **columns}
    return {k: v for k, v in columns.items() if k in history}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("campaign", help="run, propose or ingest one active-learning campaign",
                       description="Active-learning campaigns: one config, one strategy, one seed. `run` "
                                   "lets the simulator answer every batch; `propose` and `ingest` let a "
                                   "person drive the car.")
    campaign_sub = p.add_subparsers(dest="campaign_command", required=True, parser_class=Parser,
                                    metavar="COMMAND", title="commands")
    run = campaign_sub.add_parser("run", help="run (or resume) a campaign, the simulator answering",
                                  description="Run (or resume) a campaign to its budget; the config's oracle "
                                              "(the simulator, a twin or recorded logs) answers every batch.")
    add_config_options(run, "<output_dir>/<name>/<strategy>/seed<N>")
    _add_strategy_seed(run)
    run.set_defaults(handler=_campaign_run)

    propose = campaign_sub.add_parser(
        "propose", help="start a campaign a person drives: write the first maneuvers to drive",
        description="Ask: run the initial design (or the prior's model) and write "
                    "DIR/proposals/round-NNN.csv with the maneuvers to drive (the values `activelearn "
                    "simulate` takes).",
    )  # fmt: skip
    add_config_options(propose, "<output_dir>/<name>/<strategy>/seed<N>")
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
    add_wait(ingest)
    ingest.set_defaults(handler=_campaign_ingest)


def _add_strategy_seed(p: argparse.ArgumentParser) -> None:
    p.add_argument("--strategy", default=None, metavar="S",
                   help=f"strategy (default: the config's): {', '.join(STRATEGY_NAMES)}")
    p.add_argument("--seed", type=int, default=None, metavar="N", help="seed (default: the config's)")


def _strategy_seed(args: argparse.Namespace) -> dict[str, object]:
    """Config overrides of --strategy and --seed."""
    return {k: v for k, v in (("strategy", args.strategy), ("seed", args.seed)) if v is not None}


def _print_proposals(maneuvers: list, path, vehicle: str = "nigel") -> None:
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
    car = "" if vehicle == "nigel" else f" --vehicle {vehicle}"  # to rehearse on the config's car
    print("e.g. activelearn simulate{car} --maneuver {maneuver} --direction {direction} "
          "--throttle {throttle} --steering {steering} --duration {duration} --out LOG.csv"
          .format(car=car, **rows[0]))  # fmt: skip


def _campaign_directory(args: argparse.Namespace, cfg) -> Path:
    """The campaign directory of --out (or the config's default), checked before any work is done."""
    from activelearn.errors import InputError
    from activelearn.loop.campaign import default_directory
    from activelearn.loop.state import STATE_FILE

    directory = output_path("--out", args.out or default_directory(cfg), folder=True)
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

    cfg = load_campaign_config(args, **_strategy_seed(args))
    plot = Path(args.plot) if args.plot else None
    if plot is not None and plot.suffix.lower() not in PLOT_SUFFIXES:
        raise InputError("--plot", args.plot, f"must end in {', '.join(PLOT_SUFFIXES)}")
    if plot is not None and cfg.safety is None:
        raise InputError("--plot", args.plot, "draws the [safety] arena: the config has no [safety] section")
    from activelearn.loop.campaign import Campaign, CampaignInterrupted  # torch: after the input is checked

    directory = _campaign_directory(args, cfg)
    campaign = Campaign(cfg, directory, tracker=_campaign_tracker(cfg, args), progress=common.notice)
    campaign.lock_wait = args.wait
    try:
        proposals = campaign.propose(resume=args.resume)
    except CampaignInterrupted as exc:
        print(red(f"interrupted: {exc}"), file=sys.stderr)
        return EXIT_INTERRUPTED
    from activelearn.loop.state import CampaignState

    if not proposals:
        print(_finished_message(CampaignState.load(directory), cfg, directory)
              or f"the campaign has finished; directory: {directory}")  # fmt: skip
        return 0

    state = CampaignState.load(directory)
    _print_proposals(proposals, campaign.proposal_path(state), cfg.vehicle.name)
    if cfg.safety is not None:
        _print_safety(campaign, state)
    if plot is not None:
        from activelearn.loop.asktell import proposal_figure

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
    campaign.progress, campaign.lock_wait = common.notice, args.wait
    try:
        report = ingest(campaign, args.logs, resume=args.resume)
    except CampaignInterrupted as exc:
        print(red(f"interrupted: {exc}"), file=sys.stderr)
        return EXIT_INTERRUPTED
    for log, name in report.matched.items():
        print(f"{log} -> {name}")
    if report.missing:
        print("still missing: " + ", ".join(m.name for m in report.missing))
        return 0
    history = campaign.history()
    if not history.empty:
        columns = round_columns(campaign.cfg, history)
        last = history[list(columns)].tail(1).rename(columns=columns)
        print(last.to_string(index=False, float_format="%.4g"))
    if report.finished:
        from activelearn.loop.state import CampaignState

        state = CampaignState.load(campaign.directory)
        print(_finished_message(state, campaign.cfg, campaign.directory)
              or f"the campaign has finished; directory: {campaign.directory}")  # fmt: skip
    else:
        _print_proposals(report.proposals, report.proposals_path, campaign.cfg.vehicle.name)
        if campaign.cfg.safety is not None:
            from activelearn.loop.state import CampaignState

            _print_safety(campaign, CampaignState.load(campaign.directory))
    return 0


def _campaign_run(args: argparse.Namespace) -> int:

    from tqdm import tqdm

    cfg = load_campaign_config(args, **_strategy_seed(args))
    from activelearn.loop.campaign import Campaign, CampaignInterrupted, total_rounds  # after the config

    directory = _campaign_directory(args, cfg)
    tracker = _campaign_tracker(cfg, args)
    campaign = Campaign(cfg, directory, tracker=tracker)
    bar = tqdm(total=total_rounds(cfg, len(campaign.maneuvers)), unit="round",
               desc=f"{cfg.name} {cfg.strategy} seed {cfg.seed}", disable=None)

    def progress(event: dict) -> None:
        if common.notice(event):
            bar.refresh()
        elif event["event"] == "round":
            bar.update(1)
            bar.set_postfix(maneuvers=event[N_MANEUVERS], samples=event[N_SAMPLES],
                            rmse=f"{event[TEST_RMSE]:.4f}")

    campaign.progress, campaign.lock_wait = progress, args.wait
    try:
        result = campaign.run(resume=args.resume)
    except CampaignInterrupted as exc:
        bar.close()
        print(red(f"interrupted: {exc}"), file=sys.stderr)
        return EXIT_INTERRUPTED
    bar.close()
    history = result.history
    columns = round_columns(cfg, history)
    print(history[list(columns)].rename(columns=columns).to_string(index=False, float_format="%.4g"))
    print(_finished_message(result.state, cfg, directory)
          or f"stopped by {result.state.stop_reason}; campaign directory: {directory}")  # fmt: skip
    if tracker is not None:
        print(f"MLflow run {result.state.run_id} in {cfg.tracking.uri} "
              f"({ui_hint(cfg.tracking.uri)})")
    return 0

