"""Uncertainty strategies in the function space of the model's posterior draws.

Uncertainty strategies work in *function space*: `model.draw(S)` gives S posterior function draws
f_s with weights shared across inputs, so the posterior covariance between any two inputs is the
sample covariance of f_s over s. Writing the standardised deviations as phi(x) = (f_s(x) - mean_s) /
sqrt(S) turns the posterior into a linear-Gaussian model f(x) = m(x) + phi(x)^T w, w ~ N(0, I_S).
Observing a maneuver's rows with aleatoric variance sigma^2 is then an exact rank-update of the
S x S precision of w. That gives, from one forward pass:
  * greedy batches with fantasised updates (later picks see the variance earlier picks remove),
  * integrated variance reduction over an evaluation grid (`integrated_variance`),
  * per-point epistemic variance phi^T Sigma_w phi, which reduces to the model's own at Sigma_w = I.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np

from activelearn.config import AcquisitionConfig
from activelearn.loop.history import NO_HISTORY, History
from activelearn.loop.strategy import Pool, Strategy, check_k, per_candidate, proximity_penalty

BatchMode = Literal["fantasy", "penalty", "topk"]
_VAR_FLOOR = 1e-8  # standardised variance floor: keeps 1/sigma^2 finite for near-noise-free outputs


@dataclass(frozen=True)
class FunctionSamples:
    """Posterior function draws at a set of inputs, standardised per output.

    phi: (P, O, S) deviations of the S sampled means from their average, divided by sqrt(S), so that
        the epistemic variance at point p, output o is |phi[p, o]|^2.
    aleatoric: (P, O) mean over draws of the predicted noise variance.
    """

    phi: np.ndarray
    aleatoric: np.ndarray

    @classmethod
    def from_model(
        cls, model: Any, x: np.ndarray, scale: np.ndarray, n_samples: int, seed: int
    ) -> FunctionSamples:
        """Draw `n_samples` posterior functions from `model` and evaluate them at `x`."""
        means, variances = model.draw(n_samples, seed=seed)(x)
        means = np.asarray(means, dtype=np.float64) / scale
        variances = np.asarray(variances, dtype=np.float64) / scale**2
        phi = (means - means.mean(axis=0, keepdims=True)) / np.sqrt(means.shape[0])
        return cls(phi=np.transpose(phi, (1, 2, 0)), aleatoric=variances.mean(axis=0))

    @property
    def n_samples(self) -> int:
        """Number of posterior draws S."""
        return self.phi.shape[-1]

    def epistemic(self, cov: np.ndarray | None = None) -> np.ndarray:
        """(P, O) epistemic variance under the sample-space covariance `cov` (identity by default)."""
        if cov is None:
            return (self.phi**2).sum(-1)
        return np.einsum("pos,st,pot->po", self.phi, cov, self.phi)

    def precision(self, rows: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """S x S precision added by observing points `rows`, each `weights` times, with their noise."""
        phi = self.phi[rows]  # (R, O, S)
        w = weights[rows][:, None] / np.maximum(self.aleatoric[rows], _VAR_FLOOR)  # (R, O)
        return np.einsum("ros,ro,rot->st", phi, w, phi)


class UncertaintyStrategy(Strategy):
    """Base of model-driven strategies: score candidates, pick greedily with a batch-diversity rule.

    batch: "fantasy" conditions the function-space posterior on each pick before the next (default),
        "penalty" damps scores near earlier picks, "topk" takes the k best scores (no diversity).
    n_samples: posterior draws S; fantasy_weight scales the rows each scoring point stands for.
    cost_aware: divide each candidate's score by its cost in seconds (information per second).
    """

    uses_model = True

    def __init__(self, acquisition: AcquisitionConfig | None = None, **options: Any) -> None:
        super().__init__(acquisition, **options)
        acq = self.acquisition
        self.batch: BatchMode = acq.batch
        self.n_samples = acq.n_samples
        self.fantasy_weight = acq.fantasy_weight
        self.penalty_length = acq.penalty_length
        self.cost_aware = acq.cost_aware

    def per_second(self, scores: np.ndarray, costs: np.ndarray | None) -> np.ndarray:
        """Scores per second of track time when cost-aware (scores unchanged otherwise)."""
        if not self.cost_aware or costs is None:
            return scores
        return scores / costs

    @abstractmethod
    def point_scores(self, samples: FunctionSamples, cov: np.ndarray) -> np.ndarray:
        """(P,) score of every scoring point under sample-space covariance `cov`."""

    # Scores depend on earlier picks of the batch (not only through the posterior): rescore each pick.
    rescore_after_pick: ClassVar[bool] = False

    def candidate_scores(
        self, samples: FunctionSamples, pool: Pool, cov: np.ndarray, picks: Sequence[int] = ()
    ) -> np.ndarray:
        """(n,) score of every candidate: its points' scores averaged along its control sequence."""
        return per_candidate(self.point_scores(samples, cov), pool.owner, len(pool.maneuvers))

    def samples(self, model: Any, pool: Pool, rng: np.random.Generator) -> FunctionSamples:
        """Evaluate posterior draws at the pool's scoring points."""
        seed = int(rng.integers(2**31 - 1))
        return FunctionSamples.from_model(model, pool.points, pool.output_scale, self.n_samples, seed)

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        available = check_k(pool, k)
        samples = self.samples(model, pool, rng)
        cov = np.eye(samples.n_samples)
        weights = pool.weights * self.fantasy_weight
        open_mask = np.zeros(len(pool.maneuvers), dtype=bool)
        open_mask[available] = True
        picks: list[int] = []
        scores = self.candidate_scores(samples, pool, cov)
        for _ in range(k):
            penalise = self.batch == "penalty" and picks
            damped = scores * proximity_penalty(pool, picks, self.penalty_length) if penalise else scores
            masked = np.where(open_mask, self.per_second(damped, pool.costs), -np.inf)
            pick = int(np.argmax(masked))
            picks.append(pick)
            open_mask[pick] = False
            if len(picks) < k and self.batch == "fantasy":
                rows = np.flatnonzero(pool.owner == pick)
                cov = _condition(cov, samples.precision(rows, weights))
            if len(picks) < k and (self.batch == "fantasy" or self.rescore_after_pick):
                scores = self.candidate_scores(samples, pool, cov, picks)
        return picks


def _condition(cov: np.ndarray, precision: np.ndarray) -> np.ndarray:
    """Sample-space covariance after adding `precision`: (cov^-1 + precision)^-1, computed stably."""
    # cov - cov P (I + cov P)^-1 cov avoids inverting a near-singular cov after many updates.
    eye = np.eye(len(cov))
    return cov - cov @ precision @ np.linalg.solve(eye + cov @ precision, cov)


class MaxEpistemicStrategy(UncertaintyStrategy):
    """Pick maneuvers whose controls the model knows least about (epistemic variance)."""

    name = "max_epistemic"

    def point_scores(self, samples: FunctionSamples, cov: np.ndarray) -> np.ndarray:
        return samples.epistemic(cov).sum(axis=1)


class MaxTotalStrategy(UncertaintyStrategy):
    """Pick by total predictive variance (aleatoric + epistemic): chases noise, on purpose."""

    name = "max_total"

    def point_scores(self, samples: FunctionSamples, cov: np.ndarray) -> np.ndarray:
        return (samples.epistemic(cov) + samples.aleatoric).sum(axis=1)


class BaldStrategy(UncertaintyStrategy):
    """BALD: mutual information between a new observation and the weights.

    For a Gaussian head whose predictive is approximated as Gaussian, I(y; w) = 0.5 log(1 + epi/ale)
    per output (the entropy of N(m, epi + ale) minus the expected entropy N(., ale)); outputs are
    treated as independent given the weights, so their informations add.
    """

    name = "bald"

    def point_scores(self, samples: FunctionSamples, cov: np.ndarray) -> np.ndarray:
        ratio = samples.epistemic(cov) / np.maximum(samples.aleatoric, _VAR_FLOOR)
        return 0.5 * np.log1p(ratio).sum(axis=1)


class EpistemicMaximinStrategy(MaxEpistemicStrategy):
    """Space-filling weighted by uncertainty: maximise epistemic variance × squared gap to the design.

    Greedy maximin alone ignores the model; max_epistemic alone piles up at the pool's edges, where a
    network's variance grows whatever the data say. Their product keeps maximin's coverage and lets
    the model break its near-ties. Batches also use the fantasised variance (`batch` applies).
    """

    name = "epistemic_maximin"

    rescore_after_pick = True

    def candidate_scores(
        self, samples: FunctionSamples, pool: Pool, cov: np.ndarray, picks: Sequence[int] = ()
    ) -> np.ndarray:
        scores = super().candidate_scores(samples, pool, cov, picks)
        everyone = np.arange(len(pool.maneuvers))
        gap = pool.design_gap(everyone)
        if len(picks):
            gap = np.minimum(gap, pool.distances(everyone, np.asarray(picks, dtype=int)).min(axis=1))
        if not np.isfinite(gap).any():
            return scores
        return scores * gap**2


class IntegratedVarianceStrategy(UncertaintyStrategy):
    """Integrated variance reduction: pick the maneuver that most lowers epistemic variance on the target.

    The reduction is exact for the linear-Gaussian sample-space posterior: observing candidate c
    with precision P_c changes the target variance from tr(C M) to tr((C^-1 + P_c)^-1 M), where
    M = sum over target points (weighted) and outputs of phi phi^T. The target is `pool.target`
    (`[target]`: by default the controls of the test maneuvers). Batches always use fantasised updates.
    """

    name = "integrated_variance"

    def point_scores(self, samples: FunctionSamples, cov: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError("integrated_variance scores whole candidates")

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        return self.reduce_variance(model, pool, k, rng, pool.target, pool.target_weights)

    def reduce_variance(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, target: np.ndarray,
        target_weights: np.ndarray | None,
    ) -> list[int]:  # fmt: skip
        """The k candidates that most lower the epistemic variance at `target` (weights None: equal)."""
        available = list(check_k(pool, k))
        seed = int(rng.integers(2**31 - 1))
        stacked = np.concatenate([pool.points, target])
        samples = FunctionSamples.from_model(model, stacked, pool.output_scale, self.n_samples, seed)
        cand = FunctionSamples(samples.phi[: len(pool.points)], samples.aleatoric[: len(pool.points)])
        m = _target_moment(samples.phi[len(pool.points) :], target_weights)
        weights = pool.weights * self.fantasy_weight
        precisions = {c: cand.precision(np.flatnonzero(pool.owner == c), weights) for c in available}
        cov = np.eye(cand.n_samples)
        picks: list[int] = []
        for _ in range(k):
            before = np.trace(cov @ m)
            gains = np.array([before - np.trace(_condition(cov, precisions[c]) @ m) for c in available])
            costs = None if pool.costs is None else pool.costs[available]
            pick = available.pop(int(np.argmax(self.per_second(gains, costs))))
            picks.append(int(pick))
            cov = _condition(cov, precisions[pick])
        return picks

    def target_variance(self, model: Any, pool: Pool, seed: int = 0) -> float:
        """Integrated epistemic variance over the target (standardised units, weighted)."""
        samples = FunctionSamples.from_model(model, pool.target, pool.output_scale, self.n_samples, seed)
        return float(np.trace(_target_moment(samples.phi, pool.target_weights)))


class SafeExpanderStrategy(IntegratedVarianceStrategy):
    """Grow the safe set: among the admitted candidates, drive those whose data most lower the epistemic
    variance where [safety] withholds seconds (`History.withheld`: refused candidates, cut ones' rest).

    SafeOpt's expanders (Sui et al., ICML 2015) are the safe points whose data could make unsafe ones
    safe; this aims at the withheld points directly, as transductive active learning does (Hübotter et
    al., NeurIPS 2024: variance reduction on a target set outside the sampling set). Under a physics
    model a candidate is withheld for its limits by the fan, or because the model extrapolates there
    (`trust_std`) and the kinematic worst case does not hold: lowering the variance there is what lets
    the fan judge it. The reduction is integrated_variance's, exact in the sample-space posterior.
    Without [safety], or when nothing open is withheld, the target is `[target]`'s (integrated_variance).
    """

    name = "safe_expander"

    def pick(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, history: History = NO_HISTORY
    ) -> list[int]:
        """Aim at what the `history` says [safety] withholds this round (`[target]`'s points if nothing)."""
        withheld = history.withheld
        if withheld is None or not len(withheld.points):
            return self.select(model, pool, k, rng)
        return self.reduce_variance(model, pool, k, rng, withheld.points, withheld.weights)


def _target_moment(phi: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """M = sum over target points g (weight w_g) and outputs of phi phi^T, an S x S matrix."""
    if weights is None:
        return np.einsum("gos,got->st", phi, phi)
    return np.einsum("gos,g,got->st", phi, weights, phi)
