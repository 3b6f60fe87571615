"""The budget: what a campaign may still collect, in maneuvers, rounds and seconds of track time.

Seconds count the durations as driven (cut short where [safety] said so) plus a set-up time per
maneuver (`[design] setup_seconds`); a seconds budget makes candidates that no longer fit unaffordable.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from activelearn.config import CampaignConfig
from activelearn.loop.state import CampaignState


class Budget:
    """How much of a campaign's budget its collected maneuvers spent, and how many the next round may take.

    `costs`: each candidate's seconds whole (duration + set-up); `maneuvers`: the candidates, whole.
    What was driven is read off the state: its taken candidates, cut to `state.cuts` where [safety] cut.
    """

    def __init__(self, cfg: CampaignConfig, costs: np.ndarray, maneuvers: Sequence[Any]) -> None:
        self.cfg = cfg
        self.costs = costs
        self.maneuvers = maneuvers
        self.n_candidates = len(costs)

    def sim_seconds(self, state: CampaignState) -> float:
        """Seconds of driving the collected maneuvers took (durations as driven)."""
        return float(sum(state.cuts.get(str(i), self.maneuvers[i].duration) for i in state.taken))

    def track_seconds(self, state: CampaignState) -> float:
        """Seconds of track time spent: durations (as driven) plus the set-up time of every maneuver."""
        return self.sim_seconds(state) + self.cfg.design.setup_seconds * len(state.taken)

    def affordable(self, state: CampaignState) -> np.ndarray | None:
        """Candidates that still fit the seconds budget (None without one)."""
        budget = self.cfg.design.max_sim_seconds
        if budget is None:
            return None
        return self.costs <= budget - self.track_seconds(state) + 1e-9

    def next_batch_size(self, state: CampaignState) -> tuple[int, str | None]:
        """How many maneuvers the next round may collect, or 0 and the reason to stop."""
        design = self.cfg.design
        n = len(state.taken)
        k = design.per_round
        # rounds after the initial design (or after the prior alone, without one)
        if design.max_rounds is not None and len(state.batches) - (design.initial > 0) >= design.max_rounds:
            return 0, "max_rounds"
        if design.max_maneuvers is not None:
            k = min(k, design.max_maneuvers - n)
            if k <= 0:
                return 0, "max_maneuvers"
        affordable = self.affordable(state)
        open_ = np.ones(self.n_candidates, dtype=bool)
        open_[state.taken] = False
        if affordable is not None:
            k = min(k, int((affordable & open_).sum()))
            if k <= 0:
                return 0, "max_sim_seconds"
        k = min(k, int(open_.sum()))
        if k <= 0:
            return 0, "pool_exhausted"
        return k, None

    def within_budget(
        self, state: CampaignState, picks: list[int], costs: np.ndarray | None = None
    ) -> list[int]:
        """The picks, in pick order, that fit the seconds budget together (later ones wait a round).

        `costs`: this round's costs as [safety] would drive the candidates (default: whole).
        """
        budget = self.cfg.design.max_sim_seconds
        if budget is None:
            return picks
        room = budget - self.track_seconds(state) + 1e-9
        kept = []
        costs = self.costs if costs is None else costs
        for pick in picks:
            if costs[pick] <= room:
                kept.append(pick)
                room -= costs[pick]
        return kept


def total_rounds(cfg: CampaignConfig, pool_size: int) -> int:
    """Upper bound on the number of fitted rounds (for progress bars)."""
    n = min(cfg.design.max_maneuvers or pool_size, pool_size)
    if cfg.design.max_sim_seconds is not None:
        shortest = min([cfg.pool.duration, *cfg.pool.durations.values()]) + cfg.design.setup_seconds
        n = min(n, int(cfg.design.max_sim_seconds // shortest))
    rounds = math.ceil(max(0, n - cfg.design.initial) / cfg.design.per_round) + 1
    if cfg.design.max_rounds is not None:
        rounds = min(rounds, cfg.design.max_rounds + 1)
    return rounds
