"""Proposal files: what a person drives next, as proposals/round-NNN.csv (and, for families, schedules).

A reference maneuver's row holds the values `activelearn simulate` takes; a family maneuver's row its
parameters, with its control schedule in proposals/round-NNN/ beside the file (written first). With
[safety], each row also holds its risk, the duration it was cut from, and (live stop) how close to a
wall the driver brakes; `proposal_figure` draws the batch in the arena.
"""

from __future__ import annotations

from collections.abc import Sequence
from math import nan
from pathlib import Path
from typing import Any

import pandas as pd

from activelearn.config import CampaignConfig, boundary_distance
from activelearn.data import atomic_write_bytes
from activelearn.loop.family_pool import proposal_table, schedule_table
from activelearn.loop.safety.live_stop import braked_paths
from activelearn.loop.safety.risk import fan
from activelearn.loop.state import PROPOSALS_DIR, CampaignState
from activelearn.names import PROPOSAL_COLUMNS
from activelearn.seeds import Stream, derived_seed
from simulator import FamilyManeuver


def proposal_path(directory: str | Path, state: CampaignState) -> Path:
    """proposals/round-NNN.csv of the pending batch (NNN = batches collected so far)."""
    return Path(directory) / PROPOSALS_DIR / f"round-{len(state.batches):03d}.csv"


def write_proposals(
    cfg: CampaignConfig, directory: str | Path, state: CampaignState, maneuvers: Sequence[Any],
    driven: Sequence[Any],
) -> Path:  # fmt: skip
    """Write the pending batch's proposal file; `driven` are its maneuvers as driven (cut where [safety]
    cut them), `maneuvers` the whole candidates."""
    assert state.pending is not None
    path = proposal_path(directory, state)
    if any(isinstance(m, FamilyManeuver) for m in driven):
        table = _family_proposals(cfg, path, list(driven))
    else:
        table = _reference_proposals(driven)
    if cfg.safety is not None:  # the risk of each proposal, and the duration it was cut from
        table["risk"] = [state.risks.get(str(i), float("nan")) for i in state.pending]
        table["cut_from"] = [maneuvers[i].duration if str(i) in state.cuts else None for i in state.pending]
        if cfg.safety.stop == "live":  # the driver brakes this close to a wall (m, the car's centre)
            table["brake_within_m"] = cfg.safety.margin + cfg.safety.stop_buffer
    atomic_write_bytes(path, table.to_csv(index=False).encode())
    return path


def _family_proposals(cfg: CampaignConfig, path: Path, driven: list[Any]) -> pd.DataFrame:
    """Family proposals: parameters per row, and beside the file each one's schedule (written first)."""
    rate = cfg.simulation.rate_hz
    folder = path.with_suffix("")  # proposals/round-NNN/
    schedules = []
    for n, m in enumerate(driven):
        name = f"{n + 1:02d}-{m.name}.csv"
        atomic_write_bytes(folder / name, schedule_table(m, rate).to_csv(index=False).encode())
        schedules.append(f"{folder.name}/{name}")
    return proposal_table(driven, schedules)


def _reference_proposals(driven: Sequence[Any]) -> pd.DataFrame:
    rows = [
        {"maneuver": m.kind, "direction": m.direction, "throttle": m.throttle, "steering": m.steering,
         "duration": m.duration}
        for m in driven
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=list(PROPOSAL_COLUMNS))


def proposal_figure(
    cfg: CampaignConfig, state: CampaignState, model: Any | None, driven: Sequence[Any], path: str | Path
) -> Path:
    """Draw the pending batch `driven` (as driven, cut where [safety] cut) in the [safety] arena; return
    the path. The fans are `model`'s, the model that judged the batch (None: the kinematic worst case's
    reach is drawn instead). Reads its arguments and changes none of them."""
    from activelearn.plots import proposals_figure, save_figure

    safety = cfg.safety
    assert safety is not None
    proposals: list[dict[str, Any]] = [
        {"label": m.name + (" (cut)" if str(i) in state.cuts else ""), "risk": state.risks.get(str(i), nan)}
        for i, m in zip(state.pending or [], driven, strict=True)
    ]
    live = safety.stop == "live" and safety.enforce
    if model is not None and driven:
        # the seed of the assessment that judged the batch: the last recorded round's (round 0's for the
        # initial design, judged by a warm start's prior model before any round was recorded)
        seed = derived_seed(cfg.seed, Stream.ROUND, max(len(state.rounds) - 1, 0))
        rollout = fan(model, driven, safety, cfg.simulation.rate_hz, seed)
        for j, proposal in enumerate(proposals):
            n = int(rollout.lengths[j])
            x, y = rollout.x[:, j, :n], rollout.y[:, j, :n]
            if live:  # each path ends where the car would brake: a fan reaching a wall is stopped there
                mean_x, mean_y, _ = braked_paths(x.mean(axis=0)[None], y.mean(axis=0)[None], safety)
                proposal.update(mean=(mean_x[0], mean_y[0]))  # the mean path, itself braked
                x, y, trigger = braked_paths(x, y, safety)
                hit = trigger >= 0
                proposal.update(brakes=(x[hit, trigger[hit]], y[hit, trigger[hit]]), n_paths=len(trigger))
            proposal.update(x=x, y=y)
    reach = None
    if model is None:
        room = float(boundary_distance(safety.arena, safety.start[0], safety.start[1])) - safety.margin
        reach = max(room, 0.0)
    fig = proposals_figure(
        safety.arena, safety.start, proposals, name=cfg.name, batch=len(state.batches), delta=safety.delta,
        margin=safety.margin, reach=reach, brake_at=safety.margin + safety.stop_buffer if live else None,
    )  # fmt: skip
    return save_figure(fig, path, dpi=110)
