"""What a campaign directory holds besides its samples and models, and the names of its files.

The state is written last in every checkpoint (atomically): it is the commit point. A directory whose
state says a batch is pending is waiting for that batch's logs, from the simulator (which answers at
once) or from a person driving the car (`activelearn campaign ingest`).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from activelearn.data import atomic_write_bytes
from activelearn.errors import DataFormatError
from activelearn.loop import lock

STATE_FILE = lock.COMMIT_FILE
SAMPLES_FILE = "samples.parquet"
MODEL_FILE = "model.pt"
PRIOR_MODEL_FILE = "prior_model.pt"
CONFIG_FILE = "config.json"
PROPOSALS_DIR = "proposals"
STAGED_DIR = "staged"


@dataclass
class CampaignState:
    """What a checkpoint records besides the samples and the model."""

    config_hash: str
    strategy: str
    seed: int
    batches: list[list[int]] = field(default_factory=list)  # pool indices collected, batch 0 = initial
    rounds: list[dict[str, Any]] = field(default_factory=list)  # metrics of each fitted round
    logged: int = 0  # rounds already written to MLflow
    # ms timestamp of each round's metrics in MLflow: logging a round again (a retry) adds nothing
    stamps: list[int] = field(default_factory=list)
    model_logged: bool = False
    run_id: str | None = None
    finished: bool = False
    stop_reason: str | None = None
    wall_seconds: float = 0.0
    # Ask/tell: the batch proposed and not collected yet, and what arrived of it so far
    # (pool index -> content hash of its log, the rows wait in staged/<pool index>.parquet).
    pending: list[int] | None = None
    staged: dict[str, str] = field(default_factory=dict)
    ingested: list[str] = field(default_factory=list)  # content hashes of every log taken in
    prior_digest: str | None = None
    # [safety] (issue 23): driven duration of candidates cut short and the risk of each pick (pool
    # index -> seconds / probability), and what each collected maneuver violated (pool index -> reason).
    cuts: dict[str, float] = field(default_factory=dict)
    risks: dict[str, float] = field(default_factory=dict)
    violated: dict[str, str] = field(default_factory=dict)

    @property
    def taken(self) -> list[int]:
        """All collected pool indices in collection order."""
        return [i for batch in self.batches for i in batch]

    def save(self, directory: Path) -> None:
        """Write the state atomically (the checkpoint's commit point)."""
        lock.check(directory)  # never commit after another command took the directory over
        atomic_write_bytes(directory / STATE_FILE, json.dumps(dataclasses.asdict(self), indent=1).encode())

    @classmethod
    def load(cls, directory: Path) -> CampaignState:
        """Read a saved state."""
        path = Path(directory) / STATE_FILE
        try:
            return cls(**json.loads(path.read_text()))
        except (json.JSONDecodeError, TypeError) as exc:
            raise DataFormatError(f"{path}: not a campaign state ({exc})") from None
