"""Improved greedy sampling (iGS): diversity in the candidates' parameters *and* their predicted behaviour.

Wu, Lin & Huang, "Active learning for regression using greedy sampling" (Information Sciences, 2019):
a candidate c scores min over the collected maneuvers j of d_x(c, j) · d_y(c, j), the product of
its distance to j in the input space and in the output space, and the best score is picked. Greedy
maximin (`uniform`) is the d_x half alone. Here

* d_x is the pool's distance between operating points or family parameters (`Pool.distances`, the
  one maximin uses), and
* d_y the RMS distance between two maneuvers' *predicted rate trajectories* (v and ω, standardised by
  `Pool.output_scale`): the model's mean at each candidate's scoring points (along its controls, or
  along its own free run with `dynamic_points = "path"`), resampled to `TRAJECTORY_POINTS` steps of
  its relative time so maneuvers of different lengths compare.

The collected maneuvers' trajectories are the model's predictions too (iGS uses their measured
outputs; a model trained on them predicts them closely, and the strategy interface sees the pool,
not the logs). A batch treats its earlier picks as collected. A warm start's prior maneuvers have no
scoring points in the pool: they are not compared, so on a warm start iGS diversifies against the
campaign's own maneuvers only. With nothing collected yet it is greedy maximin.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from activelearn.config import AcquisitionConfig
from activelearn.errors import InputError
from activelearn.loop.space_filling import greedy_maximin
from activelearn.loop.strategy import Pool, Strategy, check_k

TRAJECTORY_POINTS = 32  # steps each predicted trajectory is resampled to


def predicted_trajectories(
    model: Any, pool: Pool, n_samples: int, seed: int, n_points: int = TRAJECTORY_POINTS
) -> np.ndarray:
    """(n, n_points, n_outputs) the model's mean rates along every candidate, standardised per output."""
    means, _ = model.draw(n_samples, seed=seed)(pool.points)
    mean = np.asarray(means, dtype=np.float64).mean(axis=0) / pool.output_scale  # (P, O)
    out = np.empty((len(pool.maneuvers), n_points, mean.shape[1]))
    grid = np.linspace(0.0, 1.0, n_points)
    for c in range(len(pool.maneuvers)):
        rows = mean[pool.owner == c]
        if len(rows) == 0:
            raise InputError("pool", c, "a candidate without scoring points has no predicted trajectory")
        where = np.linspace(0.0, 1.0, len(rows)) if len(rows) > 1 else np.zeros(1)
        out[c] = np.column_stack([np.interp(grid, where, rows[:, o]) for o in range(rows.shape[1])])
    return out


def trajectory_distances(trajectories: np.ndarray, rows: np.ndarray, to: np.ndarray) -> np.ndarray:
    """(len(rows), len(to)) RMS distance between the predicted trajectories of `rows` and `to`."""
    diff = trajectories[rows][:, None] - trajectories[to][None, :]
    return np.sqrt((diff**2).mean(axis=(2, 3)))


class TrajectoryStrategy(Strategy):
    """A strategy that compares candidates by their predicted rate trajectories (`predicted_trajectories`,
    the mean of `[acquisition] n_samples` posterior draws): `igs` and `lcmd`."""

    uses_model = True

    def __init__(self, acquisition: AcquisitionConfig | None = None, **options: Any) -> None:
        # The draws' seed comes from the round's rng (`select`), as the uncertainty strategies' does.
        super().__init__(acquisition, **options)
        self.n_samples = self.acquisition.n_samples


class GreedySamplingStrategy(TrajectoryStrategy):
    """`igs`: maximise min over collected maneuvers of (parameter distance × predicted-behaviour distance)."""

    name = "igs"

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        open_ = list(check_k(pool, k))
        collected = list(np.flatnonzero(pool.taken))
        if not collected:  # nothing to be diverse from: the d_x half alone
            return greedy_maximin(pool, k, rng)
        trajectories = predicted_trajectories(model, pool, self.n_samples, int(rng.integers(2**31 - 1)))
        picks: list[int] = []
        for _ in range(k):
            refs = np.asarray(collected + picks, dtype=int)
            rows = np.asarray(open_, dtype=int)
            score = (pool.distances(rows, refs) * trajectory_distances(trajectories, rows, refs)).min(axis=1)
            picks.append(int(open_.pop(int(np.argmax(score)))))
        return picks
