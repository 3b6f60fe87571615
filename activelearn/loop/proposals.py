"""Proposal files: what a person drives next, as proposals/round-NNN.csv (and, for families, schedules).

A reference maneuver's row holds the values `activelearn simulate` takes; a family maneuver's row its
parameters, with its control schedule in proposals/round-NNN/ beside the file (written first). With
[safety], each row also holds its risk, the duration it was cut from, and (live stop) how close to a
wall the driver brakes.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from activelearn.config import CampaignConfig
from activelearn.data import atomic_write_bytes
from activelearn.loop.family_pool import proposal_table, schedule_table
from activelearn.loop.state import PROPOSALS_DIR, CampaignState
from activelearn.names import PROPOSAL_COLUMNS
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
