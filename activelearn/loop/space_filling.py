"""Space-filling designs: strategies that ignore the model and spread the batch over the pool.

`uniform` (greedy maximin) is the strong baseline every comparison measures against; it also draws
every campaign's initial design (`greedy_maximin`).
"""

from __future__ import annotations

import warnings
from typing import Any, Literal

import numpy as np
from scipy.stats import qmc

from activelearn.loop.strategy import Pool, Strategy, check_k


class GridStrategy(Strategy):
    """The reference study's sweep: untaken candidates in pool order (kind, throttle, steering)."""

    name = "grid"

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        return [int(i) for i in check_k(pool, k)[:k]]


class RandomStrategy(Strategy):
    """Uniformly random untaken candidates."""

    name = "random"

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        return [int(i) for i in rng.choice(check_k(pool, k), size=k, replace=False)]


def greedy_maximin(
    pool: Pool, k: int, rng: np.random.Generator, start: Literal["centre", "random"] = "centre"
) -> list[int]:
    """Greedy maximin: repeatedly add the candidate farthest from everything taken, known or chosen.

    Prior maneuvers (a warm start) count as taken, so the design fills the unknown part first. An empty
    design starts at the candidate nearest the pool's centre (`start` "centre") or at one drawn by `rng`
    ("random": each seed its own design).
    """
    available = list(check_k(pool, k))
    everyone = np.arange(len(pool.maneuvers))
    design_gap = pool.design_gap(everyone)
    picks: list[int] = []
    for _ in range(k):
        if np.isfinite(design_gap).any():
            gaps = design_gap[available]
        elif start == "random":  # empty design: every candidate ties, the draw below picks
            gaps = np.zeros(len(available))
        else:  # empty design: start from the candidate nearest the centre of the pool
            centre = pool.features.mean(axis=0)
            gaps = -np.linalg.norm(pool.features[available] - centre, axis=1)
        best = np.flatnonzero(gaps >= gaps.max() - 1e-9)
        pick = available[int(rng.choice(best))]  # ties broken at random, so seeds differ
        picks.append(int(pick))
        design_gap = np.minimum(design_gap, pool.distances(everyone, np.array([pick]))[:, 0])
        available.remove(pick)
    return picks


class MaximinStrategy(Strategy):
    """`uniform`: greedy maximin over the pool, a strong space-filling baseline."""

    name = "uniform"

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        return greedy_maximin(pool, k, rng)


class _QuasiRandomStrategy(Strategy):
    """Quasi-random points in the feature cube (+ a kind coordinate), snapped to nearest candidates."""

    def _engine(self, d: int, seed: int) -> qmc.QMCEngine:
        raise NotImplementedError

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        available = list(check_k(pool, k))
        n_kinds = int(pool.kinds.max()) + 1
        d = pool.features.shape[1] + (1 if n_kinds > 1 else 0)
        # The sequence is seeded by the campaign, not the round, so rounds continue one design.
        n_taken = int(pool.taken.sum())
        with warnings.catch_warnings():  # a prefix of any length is what a continued design needs
            warnings.filterwarnings("ignore", message=".*balance properties.*", category=UserWarning)
            targets = self._engine(d, pool.design_seed).random(n_taken + k)[n_taken:]
        picks: list[int] = []
        for target in targets:
            cont = target[: pool.features.shape[1]]
            dist = np.linalg.norm(pool.features[available] - cont, axis=1)
            if n_kinds > 1:
                kind = min(int(target[-1] * n_kinds), n_kinds - 1)
                dist = dist + pool.kind_distance * (pool.kinds[available] != kind)
            pick = available.pop(int(np.argmin(dist)))
            picks.append(int(pick))
        return picks


class SobolStrategy(_QuasiRandomStrategy):
    """Scrambled Sobol sequence (scipy.stats.qmc) snapped to the nearest untaken candidates."""

    name = "sobol"

    def _engine(self, d: int, seed: int) -> qmc.QMCEngine:
        return qmc.Sobol(d, scramble=True, rng=seed)


class LatinHypercubeStrategy(_QuasiRandomStrategy):
    """Latin hypercube (scipy.stats.qmc) snapped to the nearest untaken candidates."""

    name = "lhs"

    def _engine(self, d: int, seed: int) -> qmc.QMCEngine:
        return qmc.LatinHypercube(d, rng=seed)
