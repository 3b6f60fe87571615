"""`regressor_maximin`: space filled in the model's own terms, its regressor space.

Greedy maximin (`uniform`) fills the space of the candidates' parameters (operating points, family
parameters): it spreads the *signals*. What a dynamics model learns from are the inputs it reads along
them, its regressors (controls and past rates), and two signals far apart in parameters can cover the
same regressors (a slalom and a chirp at one speed) while a corner of the envelope (high speed and large
steering) is reached by few. Herkersdorf & Nelles (2025) fill the regressor space instead; this
strategy does so with the pool's scoring points (`joint_maximin` adds uniform's distance in the pool's
parameters to it, so both spaces are filled):

* a candidate's regressors are `Pool.points`, the model inputs along its controls (with
  `[acquisition] dynamic_points = "path"` along its own predicted free run, so a dynamics model's
  past-rate inputs are the rates the model expects the car to reach), standardised per input by the
  spread of all candidates' points;
* it scores the weighted mean, over its points (`Pool.weights`: the training rows each stands for),
  of each point's distance to the nearest regressor already covered: the points of the collected
  maneuvers and of the batch's earlier picks. The best score, the most new regressor space, is picked.

The collected maneuvers' regressors are the model's prediction along their controls too (the
strategy interface sees the pool, not the logs: as `igs`). A warm start's prior maneuvers have no
points in the pool and are not covered; with nothing collected yet it is greedy maximin.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from activelearn.loop.space_filling import greedy_maximin
from activelearn.loop.strategy import Pool, Strategy, check_k

CHUNK = 4096  # candidate points compared at once against the covered ones (memory: CHUNK x covered)


def standardised_points(pool: Pool) -> np.ndarray:
    """(P, d) the pool's scoring points, each input divided by its spread over all points."""
    points = np.asarray(pool.points, dtype=np.float64)
    spread = points.std(axis=0)
    return points / np.where(spread > 1e-12, spread, 1.0)


def nearest_distance(points: np.ndarray, covered: np.ndarray) -> np.ndarray:
    """(P,) distance of every point to its nearest covered point (inf where nothing is covered)."""
    if len(covered) == 0:
        return np.full(len(points), np.inf)
    out = np.empty(len(points))
    covered_sq = (covered**2).sum(axis=1)
    for start in range(0, len(points), CHUNK):
        block = points[start : start + CHUNK]
        sq = (block**2).sum(axis=1)[:, None] + covered_sq[None, :] - 2.0 * block @ covered.T
        out[start : start + CHUNK] = np.sqrt(np.maximum(sq.min(axis=1), 0.0))
    return out


def candidate_gaps(pool: Pool, gap: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(len(rows),) each candidate's weighted mean, over its points (`Pool.weights`), of `gap`."""
    weights = np.asarray(pool.weights, dtype=np.float64)
    mine = np.isin(pool.owner, rows)
    n, owners = len(pool.maneuvers), pool.owner[mine]
    score = np.bincount(owners, weights=(weights * gap)[mine], minlength=n)
    return (score / np.maximum(np.bincount(owners, weights=weights[mine], minlength=n), 1e-12))[rows]


class RegressorMaximinStrategy(Strategy):
    """`regressor_maximin`: the candidate whose regressors lie farthest from those already covered."""

    name = "regressor_maximin"
    uses_model = True  # its regressors are the model's inputs along each candidate's predicted path
    design_weight = 0.0  # the share of the score the pool's parameter space has (`joint_maximin`: 1)

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        open_ = list(check_k(pool, k))
        collected = np.flatnonzero(pool.taken)
        if len(collected) == 0 or len(pool.points) == 0:
            return greedy_maximin(pool, k, rng)
        points = standardised_points(pool)
        gap = nearest_distance(points, points[np.isin(pool.owner, collected)])  # to the covered regressors
        everyone = np.arange(len(pool.maneuvers))
        design = pool.design_gap(everyone) if self.design_weight else None
        picks: list[int] = []
        for _ in range(k):
            rows = np.asarray(open_, dtype=int)
            score = candidate_gaps(pool, gap, rows)
            if design is not None:  # each gap relative to its largest among the open candidates
                spread = design[rows] / max(design[rows].max(), 1e-12)
                score = score / max(score.max(), 1e-12) + self.design_weight * spread
            best = int(rows[int(np.argmax(score))])
            picks.append(best)
            open_.remove(best)
            gap = np.minimum(gap, nearest_distance(points, points[pool.owner == best]))  # covered now
            if design is not None:
                design = np.minimum(design, pool.distances(everyone, np.array([best]))[:, 0])
        return picks


class JointMaximinStrategy(RegressorMaximinStrategy):
    """`joint_maximin`: space filled in both spaces at once, the candidate whose regressors lie far
    from those covered and whose parameters lie far from the maneuvers taken: its regressor gap
    (`regressor_maximin`'s) and its design gap (`uniform`'s), each divided by its largest among the
    open candidates, summed. regressor_maximin alone may leave a corner of the parameters unvisited
    (on the 1:10 twin it rarely reversed); greedy maximin alone spreads the signals, not what the
    model reads."""

    name = "joint_maximin"
    design_weight = 1.0
