"""The one interface every acquisition strategy implements, and the pool of candidates it reads.

A strategy picks k untaken candidates from a `Pool` (the candidates' geometry and costs). The campaign
calls every strategy the same way, `Strategy.pick(model, pool, k, rng, history)`, and logs what
`Strategy.round_metrics()` returns beside the round's metrics: it names none of them. Most strategies
only `select` from the pool; those that decide from what the campaign has seen read the `History`
(`activelearn.loop.history`) themselves. Every strategy builds itself from `[acquisition]`
(`AcquisitionConfig`: its defaults are the config's).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from activelearn.config import AcquisitionConfig
from activelearn.errors import InputError
from activelearn.loop.history import NO_HISTORY, History


@dataclass(frozen=True)
class Pool:
    """Candidate maneuvers: their geometry and costs, what strategies need to compare and score them.

    features: (n, d) coordinates of each candidate in [0, 1]^d (operating point: throttle, signed
        steering; for a family pool the normalised family parameters and direction,
        `activelearn.loop.family_pool`) used for distances and quasi-random designs.
    kinds: (n,) integer maneuver kind of each candidate (a different kind adds `kind_distance`).
    points / owner / weights: stacked model inputs along each candidate's control sequence, the
        candidate each point belongs to, and how many training rows each point stands for.
    taken: (n,) True where the candidate was already collected.
    target: (G, n_inputs) inputs where the model must be good (`[target]`): integrated variance and
        error-reduction scores integrate over them, weighted by `target_weights` (default equal).
    output_scale: (n_outputs,) divide outputs by this so v and omega weigh alike.
    design_seed: seeds quasi-random sequences so they continue across rounds.
    costs: (n,) seconds each candidate costs (duration + set-up); None = all alike.
    affordable: (n,) False where a candidate no longer fits the budget; None = all fit.
    prior_features / prior_kinds: operating points (scaled like `features`) and kind codes of the
        maneuvers a warm start already holds (-1 = kind unknown: no kind distance). Space-filling
        designs treat them as taken.
    """

    maneuvers: tuple[Any, ...]
    features: np.ndarray
    kinds: np.ndarray
    points: np.ndarray
    owner: np.ndarray
    weights: np.ndarray
    taken: np.ndarray
    target: np.ndarray
    output_scale: np.ndarray
    design_seed: int = 0
    kind_distance: float = 0.5
    target_weights: np.ndarray | None = None
    costs: np.ndarray | None = None
    affordable: np.ndarray | None = None
    prior_features: np.ndarray | None = None
    prior_kinds: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.maneuvers)
        for name in ("features", "kinds", "taken", "costs", "affordable"):
            value = getattr(self, name)
            if value is not None and len(value) != n:
                raise ValueError(f"Pool.{name} has {len(value)} rows for {n} maneuvers")
        if not (len(self.points) == len(self.owner) == len(self.weights)):
            raise ValueError("Pool.points, owner and weights must have the same length")
        if len(self.owner) and (self.owner.min() < 0 or self.owner.max() >= n):
            raise ValueError("Pool.owner refers to a candidate outside the pool")
        if self.target_weights is not None and len(self.target_weights) != len(self.target):
            raise ValueError("Pool.target_weights needs one weight per target point")
        if (self.prior_features is None) != (self.prior_kinds is None):
            raise ValueError("Pool.prior_features and prior_kinds go together")

    @property
    def available(self) -> np.ndarray:
        """Indices of candidates not yet collected (and within the budget)."""
        open_ = ~self.taken if self.affordable is None else ~self.taken & self.affordable
        return np.flatnonzero(open_)

    def with_taken(self, indices: Sequence[int]) -> Pool:
        """Return a copy with `indices` marked as collected."""
        taken = self.taken.copy()
        taken[list(indices)] = True
        return Pool(**{**self.__dict__, "taken": taken})

    def distances(self, rows: np.ndarray, to: np.ndarray) -> np.ndarray:
        """Pairwise distances between candidates `rows` and `to` (operating point plus kind)."""
        diff = self.features[rows][:, None, :] - self.features[to][None, :, :]
        dist = np.sqrt((diff**2).sum(-1))
        return dist + self.kind_distance * (self.kinds[rows][:, None] != self.kinds[to][None, :])

    def design_gap(self, rows: np.ndarray) -> np.ndarray:
        """Distance from candidates `rows` to the nearest collected or prior maneuver (inf: none yet)."""
        rows = np.asarray(rows, dtype=int)
        gap = np.full(len(rows), np.inf)
        taken = np.flatnonzero(self.taken)
        if len(taken):
            gap = self.distances(rows, taken).min(axis=1)
        if self.prior_features is not None and len(self.prior_features):
            diff = self.features[rows][:, None, :] - self.prior_features[None, :, :]
            dist = np.sqrt((diff**2).sum(-1))
            prior_kinds = self.prior_kinds[None, :]  # type: ignore[index]
            other_kind = (prior_kinds >= 0) & (self.kinds[rows][:, None] != prior_kinds)
            gap = np.minimum(gap, (dist + self.kind_distance * other_kind).min(axis=1))
        return gap


def check_k(pool: Pool, k: int) -> np.ndarray:
    """The pool's available candidates, once k is known to be a batch they can fill."""
    available = pool.available
    if k < 1:
        raise InputError("k", k, "must be at least 1")
    if k > len(available):
        raise InputError("k", k, f"only {len(available)} candidates are left in the pool")
    return available


def per_candidate(values: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    """Average per-point values over each candidate's points."""
    counts = np.bincount(owner, minlength=n)
    return np.bincount(owner, weights=values, minlength=n) / np.maximum(counts, 1)


def proximity_penalty(pool: Pool, picks: Sequence[int], length: float) -> np.ndarray:
    """(n,) factor in [0, 1): zero at earlier picks, one far from them (Gaussian in distance/length)."""
    dist = pool.distances(np.arange(len(pool.maneuvers)), np.array(picks)).min(axis=1)
    return 1.0 - np.exp(-0.5 * (dist / length) ** 2)


class Strategy(ABC):
    """Pick k untaken candidates from a pool.

    `acquisition`: the `[acquisition]` section it reads its options from (None: the section's
    defaults); `options` change single keys of it, validated as the config validates them.
    """

    name: ClassVar[str]
    uses_model: ClassVar[bool] = False

    def __init__(self, acquisition: AcquisitionConfig | None = None, **options: Any) -> None:
        base = AcquisitionConfig() if acquisition is None else acquisition
        self.acquisition = base.updated(**options) if options else base

    @abstractmethod
    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        """Return k distinct indices of untaken candidates in `pool`."""

    def pick(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, history: History = NO_HISTORY
    ) -> list[int]:
        """What the campaign calls every round: `select`, unless a strategy reads the `history` too."""
        return self.select(model, pool, k, rng)

    def round_metrics(self) -> dict[str, float]:
        """What the last pick logs beside the round's metrics (nothing by default)."""
        return {}
