"""Ask/tell with a real car: match recorded logs to the proposals they answer, then tell the campaign.

A person (or a script feeding the AutoDRIVE open-loop controller) drives the rows of
`proposals/round-NNN.csv` and hands back one log per maneuver, in any order and any number of
`ingest` calls. Each log is matched to an open proposal by the controls recorded in it: median
throttle, steering amplitude and direction, and the shape of the steering signal (none, constant,
ramp, oscillating), within the `[oracle]` tolerances; among the proposals of a family pool that
fit, the one whose schedule (proposals/round-NNN/*.csv) is closest to the log's commands. Everything
is checked before anything is written: a malformed or cut-off log, a log already ingested (same
content) or one that answers no open proposal is one error naming the file and the reason, and the
campaign directory stays as it was. `proposal_figure` draws the pending batch for the driver.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from activelearn.config import CampaignConfig, validate_config
from activelearn.data import read_recorded_log, read_table, write_table
from activelearn.errors import InputError
from activelearn.loop import lock
from activelearn.loop.campaign import Campaign
from activelearn.loop.pool import maneuver_controls
from activelearn.loop.proposals import proposal_figure as draw_proposals
from activelearn.loop.state import CONFIG_FILE, MODEL_FILE, STAGED_DIR, STATE_FILE, CampaignState
from activelearn.names import CONTROLS
from activelearn.numerics.models import load_model
from simulator import FamilyManeuver


@dataclass(frozen=True)
class Signature:
    """What a maneuver's controls look like: enough to tell which proposal a log answers."""

    throttle: float  # median
    amplitude: float  # 95th percentile of |steering|
    sign: int  # +1 if the first clear turn is left (ccw), -1 if right, 0 for none
    shape: str  # "none", "constant", "ramp" or "oscillating"
    flips_per_minute: float


def signature(controls: np.ndarray, rate_hz: float, steering_tolerance: float) -> Signature:
    """The signature of a (T, 2) throttle/steering sequence sampled at `rate_hz`."""
    throttle, steering = controls[:, 0], controls[:, 1]
    amplitude = float(np.quantile(np.abs(steering), 0.95)) if len(steering) else 0.0
    if amplitude <= steering_tolerance:
        return Signature(float(np.median(throttle)), amplitude, 0, "none", 0.0)
    clear = steering[np.abs(steering) > 0.5 * amplitude]
    signs = np.sign(clear)
    flips = int((signs[1:] != signs[:-1]).sum())
    minutes = len(steering) / rate_hz / 60.0
    if flips:
        shape = "oscillating"
    elif (
        np.ptp(np.abs(steering)) > 0.5 * amplitude
        and np.corrcoef(np.abs(steering), np.arange(len(steering)))[0, 1] > 0.9
    ):
        shape = "ramp"
    else:
        shape = "constant"
    return Signature(float(np.median(throttle)), amplitude, int(signs[0]), shape, flips / max(minutes, 1e-9))


@dataclass(frozen=True)
class LogFile:
    """A log handed to `ingest`: its path, table and content hash."""

    path: Path
    table: pd.DataFrame
    digest: str


def read_log(path: str | Path) -> LogFile:
    """Read one log (AutoDRIVE CSV, our CSV or Parquet); a malformed file is a DataFormatError naming it."""
    path = Path(path)
    table = read_recorded_log(path)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    return LogFile(path, table, digest)


def _describe(sig: Signature) -> str:
    turn = (
        ""
        if sig.shape == "none"
        else f", steering {'+' if sig.sign > 0 else '-'}{sig.amplitude:.3g} ({sig.shape})"
    )
    return f"throttle {sig.throttle:.3g}{turn}"


def match_logs(campaign: Campaign, state: CampaignState, logs: Sequence[LogFile]) -> dict[int, LogFile]:
    """Pool index of the open proposal each log answers; raise (naming the file) for any log that fails."""
    assert state.pending is not None
    cfg = campaign.cfg.oracle
    rate = campaign.cfg.simulation.rate_hz
    seen = set(state.ingested) | set(state.staged.values())
    safety = campaign.cfg.safety
    live = safety is not None and safety.stop == "live" and safety.enforce
    open_ = [i for i in state.pending if str(i) not in state.staged]
    driven = {i: campaign.driven(i, state) for i in open_}  # as the state says they are driven (cut short)
    expected = {i: signature(maneuver_controls(driven[i], rate), rate, cfg.steering_tolerance) for i in open_}
    matched: dict[int, LogFile] = {}
    for log in logs:
        if log.digest in seen:
            raise InputError(
                "LOG", str(log.path), "was ingested already (the same content as an earlier log)"
            )
        seen.add(log.digest)
        controls = log.table[list(CONTROLS)].to_numpy(dtype=np.float64)
        got = signature(controls, rate, cfg.steering_tolerance)
        if live:  # a stop at a wall ends a log early: judge it against the proposals' first seconds
            first = {i: maneuver_controls(driven[i], rate)[: len(controls)] for i in open_}
            expected = {i: signature(first[i], rate, cfg.steering_tolerance) for i in open_}
        candidates = [
            i
            for i in open_
            if i not in matched
            and abs(got.throttle - expected[i].throttle) <= cfg.throttle_tolerance
            and abs(got.amplitude - expected[i].amplitude) <= cfg.steering_tolerance
            and got.sign == expected[i].sign
            and got.shape == expected[i].shape
        ]
        if not candidates:
            still = "; ".join(
                f"{driven[i].name} ({_describe(expected[i])})" for i in open_ if i not in matched
            )
            raise InputError(
                "LOG",
                str(log.path),
                f"matches no open proposal: it drove {_describe(got)}; open: {still or 'none'}",
            )
        best = min(candidates, key=lambda i: _closeness(driven[i], controls, got, expected[i], rate))
        proposed = driven[best].duration
        span = float(log.table["time"].iloc[-1] - log.table["time"].iloc[0])
        if span < (1.0 - cfg.duration_tolerance) * proposed and not live:
            raise InputError("LOG", str(log.path), f"is cut off: {span:.1f} s of the proposed {proposed:g} s")
        matched[best] = log
    return matched


def _closeness(
    maneuver: Any, controls: np.ndarray, got: Signature, expected: Signature, rate: float
) -> float:
    """How far a log's controls are from a proposal's: the RMS difference of the whole schedules for a
    family member (many look alike by signature), the difference in steering flips per minute otherwise."""
    if isinstance(maneuver, FamilyManeuver):
        schedule = maneuver_controls(maneuver, rate)
        n = min(len(schedule), len(controls))
        return float(np.sqrt(np.mean((schedule[:n] - controls[:n]) ** 2)))
    return abs(got.flips_per_minute - expected.flips_per_minute)


def open_campaign(directory: str | Path, *, tracker: Any | None = None) -> Campaign:
    """The campaign of a directory made by `propose` (its config and strategy, seed from its state)."""
    directory = Path(directory)
    if not (directory / STATE_FILE).is_file() or not (directory / CONFIG_FILE).is_file():
        raise InputError(
            "DIR", str(directory), "holds no campaign (run `activelearn campaign propose` first)"
        )
    cfg: CampaignConfig = validate_config(json.loads((directory / CONFIG_FILE).read_text()))
    return Campaign(cfg, directory, tracker=tracker)


@dataclass(frozen=True)
class IngestReport:
    """What an ingest did: logs matched to proposals, proposals still missing, the next proposals."""

    matched: dict[str, str]  # log path -> maneuver name
    missing: list[Any]
    proposals: list[Any]
    proposals_path: Path | None
    finished: bool


@lock.writer
def ingest(campaign: Campaign, paths: Sequence[str | Path], *, resume: bool = False) -> IngestReport:
    """Take logs of the pending batch; once it is complete, retrain and propose the next batch.

    Without --resume, a directory whose last ingest was interrupted after its logs were appended is
    refused (its step must be finished first); `resume=True` finishes it, with or without new logs.
    """
    directory = campaign.directory
    state = CampaignState.load(directory)  # [safety]: proposals cut short are driven (and matched) short
    if state.finished:
        raise InputError("DIR", str(directory), f"the campaign has finished ({state.stop_reason})")
    if state.pending is None:
        if not resume:
            raise InputError(
                "DIR", str(directory), "an earlier ingest stopped before proposing: rerun with --resume"
            )
        if paths:
            raise InputError(
                "LOG", str(paths[0]), "no batch is pending yet: run with --resume and no logs first"
            )
        proposals = campaign.propose(resume=True)
        return _report(campaign, {}, proposals)
    if not paths and not resume:
        raise InputError("LOG", "", "give at least one log of the pending proposals")
    logs = [read_log(p) for p in paths]  # every check before any write
    matched = match_logs(campaign, state, logs) if logs else {}
    for index, log in matched.items():
        write_table(log.table, directory / STAGED_DIR / f"{index}.parquet")
        state.staged[str(index)] = log.digest
    names = {str(log.path): campaign.driven(i, state).name for i, log in matched.items()}
    missing = [campaign.driven(i, state) for i in state.pending if str(i) not in state.staged]
    state.save(directory)  # staged logs are kept: a later ingest (or --resume) completes the batch
    if missing:
        return IngestReport(names, missing, [], None, False)
    frames = [read_table(directory / STAGED_DIR / f"{i}.parquet") for i in state.pending]
    proposals = campaign.tell(frames)
    for i in list(CampaignState.load(directory).batches[-1]):
        (directory / STAGED_DIR / f"{i}.parquet").unlink(missing_ok=True)
    return _report(campaign, names, proposals)


def _report(campaign: Campaign, names: dict[str, str], proposals: list[Any]) -> IngestReport:
    state = CampaignState.load(campaign.directory)
    path = campaign.proposal_path(state) if proposals else None
    return IngestReport(names, [], proposals, path, state.finished)


def proposal_figure(campaign: Campaign, path: str | Path) -> Path:
    """Draw the pending proposals of a campaign's directory in its arena (`campaign propose --plot`).

    The fans come from the model that judged them: the round's, or a warm start's prior model for the
    initial design (without either, the kinematic worst case's reach is drawn instead).
    """
    state = CampaignState.load(campaign.directory)
    model_file = campaign.directory / MODEL_FILE
    model = load_model(model_file) if state.rounds and model_file.exists() else campaign.fitting.prior_model()
    driven = [campaign.driven(i, state) for i in state.pending or []]
    return draw_proposals(campaign.cfg, state, model, driven, path)
