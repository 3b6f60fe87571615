"""[safety] in a round: what the assessment admits of the pool, the picks' risks and cuts, what a round logs.

The admission only returns values: the `Campaign` records them (the one writer of the state). The
assessment itself (fans against the arena and the limits) is `activelearn.loop.safety.risk.assess`;
the campaign's `assess` hook calls it (a benchmark's clairvoyant safe set replaces it).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from activelearn.config import CampaignConfig
from activelearn.loop.history import Withheld
from activelearn.loop.safety.risk import Assessment
from activelearn.loop.state import CampaignState
from activelearn.loop.strategy import Pool
from activelearn.names import VIOLATIONS


@dataclass(frozen=True)
class Admitted:
    """What [safety] admits of a round's pool.

    pool: (enforced) the pool with the affordable candidates and their costs as they would be driven.
    safe: the assessment. withheld: what it withholds of the open candidates' seconds. costs: (n,)
    seconds of each candidate as driven (None: not enforced, the whole costs count). driven: the
    candidates as they would be driven where some are cut (None: none cut); the pool's points must be
    rebuilt from them.
    """

    pool: Pool
    safe: Assessment
    withheld: Withheld
    costs: np.ndarray | None = None
    driven: list[Any] | None = None

    def verdicts(self, picks: Sequence[int], enforce: bool) -> tuple[dict[str, float], dict[str, float]]:
        """The picks' risks and, where [safety] is enforced, the shorter durations of those cut (pool
        index -> probability / seconds): what the state records of a proposed batch."""
        safe = self.safe
        risks = {str(i): float(safe.cut_risk[i] if safe.admissible[i] else safe.risk[i]) for i in picks}
        cuts = {str(i): float(safe.duration[i]) for i in picks if safe.cut[i] and enforce}
        return risks, cuts


class Admission:
    """Applies a campaign's [safety] to its pools (`admit`) and says what a round logs of it (`metrics`)."""

    def __init__(self, cfg: CampaignConfig, maneuvers: Sequence[Any]) -> None:
        self.cfg = cfg
        self.maneuvers = maneuvers

    def admit(self, pool: Pool, safe: Assessment, spent: float) -> Admitted:
        """`pool` cut down to what `safe` admits; `spent`: the track seconds the campaign spent so far."""
        safety = self.cfg.safety
        assert safety is not None
        withheld = withhold(pool, safe)
        if not safety.enforce:
            return Admitted(pool, safe, withheld)
        driven = None
        if safe.cut.any():  # score each candidate as it would be driven: a cut one by its first seconds
            driven = [
                dataclasses.replace(m, duration=float(safe.duration[i])) if safe.cut[i] else m
                for i, m in enumerate(self.maneuvers)
            ]
        # what each candidate costs as it would be driven (cut short or whole), for the seconds budget
        costs = np.where(safe.admissible, safe.duration, safe.full) + self.cfg.design.setup_seconds
        affordable = safe.admissible
        budget = self.cfg.design.max_sim_seconds
        if budget is not None:
            affordable = affordable & (costs <= budget - spent + 1e-9)
        pool = dataclasses.replace(pool, affordable=affordable, costs=costs)
        return Admitted(pool, safe, withheld, costs, driven)

    @staticmethod
    def metrics(state: CampaignState, safe: Assessment | None, seconds: float) -> dict[str, float]:
        """What a round logs of [safety]: safe-set size and shares, risk, violations (batch and total)."""
        total = sum(1 for reason in state.violated.values() if reason)
        before = next((r["violations_total"] for r in reversed(state.rounds) if "violations_total" in r), 0)
        metrics = {VIOLATIONS: float(total - before), "violations_total": float(total)}
        if safe is not None:
            metrics.update(
                safe_set_size=float(safe.size),
                safe_set_cut=float(safe.cut.sum()),
                safe_set_share=safe.share,
                safe_time_share=safe.time_share,
                risk_min=float(np.nanmin(safe.risk)) if safe.assessed.any() else float("nan"),
                safety_seconds=seconds,
            )
        return metrics


def withhold(pool: Pool, safe: Assessment) -> Withheld:
    """The points of the seconds `safe` withholds from `pool`'s open candidates (`History.withheld`).

    A refused candidate's points count whole; a cut one's weigh by the share of its seconds after the
    cut (a pool's points need not be in time order: a candidate's distinct controls are scored once).
    """
    # a refused candidate's duration is 0; the taken ones were not assessed
    share = np.where(safe.assessed, 1.0 - safe.duration / safe.full, 0.0)
    rows = np.flatnonzero(share[pool.owner] > 1e-9)
    weights = pool.weights[rows] * share[pool.owner[rows]]
    return Withheld(pool.points[rows], weights)
