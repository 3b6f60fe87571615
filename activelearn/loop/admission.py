"""[safety] in a round: the pool cut down to what it admits, the risks of the picks, what a round logs.

The assessment itself (fans against the arena and the limits) is `activelearn.loop.safety.assess`;
the campaign's `assess` hook calls it (a benchmark's clairvoyant safe set replaces it).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pandas as pd

from activelearn.config import CampaignConfig
from activelearn.loop.budget import Budget
from activelearn.loop.history import Withheld
from activelearn.loop.safety import Assessment
from activelearn.loop.state import CampaignState
from activelearn.loop.strategy import Pool
from activelearn.names import VIOLATIONS

Assess = Callable[[Any, int, np.ndarray, "pd.DataFrame | None"], Assessment]
Rebuild = Callable[..., Pool]


class Admission:
    """Applies a campaign's [safety] to its pools and picks (nothing without [safety]).

    `assess(model, round_index, open_, samples)`: the assessment of the open candidates; `rebuild(taken,
    model, maneuvers=...)`: the pool of the candidates as they would be driven (cut ones shorter).
    """

    def __init__(
        self, cfg: CampaignConfig, maneuvers: Sequence[Any], budget: Budget, *, assess: Assess,
        rebuild: Rebuild,
    ) -> None:  # fmt: skip
        self.cfg = cfg
        self.maneuvers = maneuvers
        self.budget = budget
        self.assess = assess
        self.rebuild = rebuild

    def safe_pool(
        self, pool: Pool, model: Any | None, round_index: int, taken: Sequence[int] = (),
        samples: pd.DataFrame | None = None,
    ) -> tuple[Pool, Assessment | None]:  # fmt: skip
        """The pool restricted to the candidates [safety] admits, and their assessment (None: no [safety])."""
        safety = self.cfg.safety
        if safety is None:
            return pool, None
        safe = self.assess(model, round_index, ~pool.taken, samples)
        if not safety.enforce:
            return pool, safe
        if safe.cut.any():  # score each candidate as it would be driven: a cut one by its first seconds
            driven = [
                dataclasses.replace(m, duration=float(safe.duration[i])) if safe.cut[i] else m
                for i, m in enumerate(self.maneuvers)
            ]
            rebuilt = self.rebuild(list(np.flatnonzero(pool.taken)), model, maneuvers=driven)
            fields = {name: getattr(rebuilt, name) for name in ("points", "owner", "weights")}
            pool = dataclasses.replace(pool, **fields)
        # what each candidate costs as it would be driven (cut short or whole), for the seconds budget
        costs = np.where(safe.admissible, safe.duration, safe.full) + self.cfg.design.setup_seconds
        self.budget.pick_costs = costs
        affordable = safe.admissible
        budget = self.cfg.design.max_sim_seconds
        if budget is not None:
            affordable = affordable & (costs <= budget - self.budget.track_seconds(taken) + 1e-9)
        return dataclasses.replace(pool, affordable=affordable, costs=costs), safe

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

    def record(self, state: CampaignState, picks: list[int], safe: Assessment) -> None:
        """Record the picks' risks and, where [safety] is enforced, the shorter durations of those cut."""
        for i in picks:
            state.risks[str(i)] = float(safe.cut_risk[i] if safe.admissible[i] else safe.risk[i])
            if safe.cut[i] and self.cfg.safety.enforce:  # type: ignore[union-attr]
                state.cuts[str(i)] = float(safe.duration[i])


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
