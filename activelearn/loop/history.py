"""What a campaign has seen before a round's pick, read-only, for the strategies that decide from it.

The loop builds one `History` per round, the same for every strategy; a strategy reads what it needs
(`Strategy.pick`), as an Optuna sampler reads the study's trials itself. The `Pool` holds the
candidates' geometry and costs; everything else a campaign knows is here.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np


@dataclass(frozen=True)
class Withheld:
    """Points of the open candidates [safety] does not admit whole (refused, or cut short), and the
    training rows each stands for times the share of its candidate's seconds withheld."""

    points: np.ndarray
    weights: np.ndarray

    def __post_init__(self) -> None:
        if len(self.points) != len(self.weights):
            raise ValueError("Withheld needs one weight per point")


@dataclass(frozen=True)
class CandidateTruth:
    """Noise-free training rows of every candidate, stacked, and the candidate each row belongs to:
    what only a simulated oracle knows (benchmark-only strategies read it)."""

    x: np.ndarray
    y: np.ndarray
    owner: np.ndarray


@dataclass(frozen=True)
class History:
    """The campaign so far, as a strategy may read it.

    rounds: the metrics every fitted round logged so far, oldest first, with the checks of the batch
        collected after each (e.g. `prequential_spearman`); read-only mappings.
    budget: what the budget counts, "maneuvers" or "seconds" of track time (costs then matter).
    prior: the model starts from what was known before (`[design] prior`: prior data or a prior model).
    scores_paths: a dynamic model scores candidates along its own free runs of them (`dynamic_points`).
    withheld: what [safety] withholds from the open candidates this round; None without [safety].
    truth: the candidates' noise-free rows (computed on first call); None where no campaign gives them.
    trial: the test RMSE of the next round's model had a batch been collected (retrains); None likewise.
    """

    rounds: tuple[Mapping[str, Any], ...] = ()
    budget: Literal["maneuvers", "seconds"] = "maneuvers"
    prior: bool = False
    scores_paths: bool = False
    withheld: Withheld | None = None
    truth: Callable[[], CandidateTruth] | None = None
    trial: Callable[[list[int]], float] | None = None


NO_HISTORY = History()  # what a strategy sees outside a campaign: nothing collected, nothing known
