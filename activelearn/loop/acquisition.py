"""Acquisition strategies: score candidate maneuvers and pick a batch.

Every strategy implements `select(model, pool, k, rng) -> list[int]` (indices into `pool.maneuvers`),
so the campaign loop treats them alike. Space-filling strategies ignore the model; uncertainty
strategies score each candidate along the controls that maneuver would apply.

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

import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
from scipy.stats import qmc

from activelearn.errors import InputError

BatchMode = Literal["fantasy", "penalty", "topk"]
_VAR_FLOOR = 1e-8  # standardised variance floor: keeps 1/sigma^2 finite for near-noise-free outputs


@dataclass(frozen=True)
class Pool:
    """Candidate maneuvers and what strategies need to compare and score them.

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
    truth_x / truth_y / truth_owner: noise-free rows of every candidate, set only for the diagnostic
        `oracle_error` strategy (a real campaign cannot know them).
    context: what the campaign measured about its model so far (e.g. `prequential_spearman`, the rank
        correlation of the last models' epistemic std with their errors on the maneuvers collected
        after them), for strategies that decide from it (`auto`).
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
    truth_x: np.ndarray | None = None
    truth_y: np.ndarray | None = None
    truth_owner: np.ndarray | None = None
    context: Mapping[str, float] | None = None

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


def _check_k(pool: Pool, k: int) -> np.ndarray:
    available = pool.available
    if k < 1:
        raise InputError("k", k, "must be at least 1")
    if k > len(available):
        raise InputError("k", k, f"only {len(available)} candidates are left in the pool")
    return available


class Strategy(ABC):
    """Pick k untaken candidates from a pool."""

    name: ClassVar[str]
    uses_model: ClassVar[bool] = False

    @abstractmethod
    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        """Return k distinct indices of untaken candidates in `pool`."""


# --------------------------------------------------------------------------- space-filling designs


class GridStrategy(Strategy):
    """The reference study's sweep: untaken candidates in pool order (kind, throttle, steering)."""

    name = "grid"

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        return [int(i) for i in _check_k(pool, k)[:k]]


class RandomStrategy(Strategy):
    """Uniformly random untaken candidates."""

    name = "random"

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        return [int(i) for i in rng.choice(_check_k(pool, k), size=k, replace=False)]


def greedy_maximin(pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
    """Greedy maximin: repeatedly add the candidate farthest from everything taken, known or chosen.

    Prior maneuvers (a warm start) count as taken, so the design fills the unknown part first.
    """
    available = list(_check_k(pool, k))
    everyone = np.arange(len(pool.maneuvers))
    design_gap = pool.design_gap(everyone)
    picks: list[int] = []
    for _ in range(k):
        if np.isfinite(design_gap).any():
            gaps = design_gap[available]
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
        available = list(_check_k(pool, k))
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


# --------------------------------------------------------------------------- uncertainty strategies


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


def _per_candidate(values: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    """Average per-point values over each candidate's points."""
    counts = np.bincount(owner, minlength=n)
    return np.bincount(owner, weights=values, minlength=n) / np.maximum(counts, 1)


class UncertaintyStrategy(Strategy):
    """Base of model-driven strategies: score candidates, pick greedily with a batch-diversity rule.

    batch: "fantasy" conditions the function-space posterior on each pick before the next (default),
        "penalty" damps scores near earlier picks, "topk" takes the k best scores (no diversity).
    n_samples: posterior draws S; fantasy_weight scales the rows each scoring point stands for.
    cost_aware: divide each candidate's score by its cost in seconds (information per second).
    """

    uses_model = True

    def __init__(
        self,
        *,
        batch: BatchMode = "fantasy",
        n_samples: int = 64,
        fantasy_weight: float = 1.0,
        penalty_length: float = 0.15,
        seed: int = 0,
        cost_aware: bool = False,
    ) -> None:
        if batch not in ("fantasy", "penalty", "topk"):
            raise InputError("acquisition.batch", batch, "must be one of fantasy, penalty, topk")
        if n_samples < 2:
            raise InputError("acquisition.n_samples", n_samples, "must be at least 2")
        if fantasy_weight <= 0:
            raise InputError("acquisition.fantasy_weight", fantasy_weight, "must be positive")
        if penalty_length <= 0:
            raise InputError("acquisition.penalty_length", penalty_length, "must be positive")
        self.batch = batch
        self.n_samples = n_samples
        self.fantasy_weight = fantasy_weight
        self.penalty_length = penalty_length
        self.seed = seed
        self.cost_aware = cost_aware

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
        return _per_candidate(self.point_scores(samples, cov), pool.owner, len(pool.maneuvers))

    def samples(self, model: Any, pool: Pool, rng: np.random.Generator) -> FunctionSamples:
        """Evaluate posterior draws at the pool's scoring points."""
        seed = int(rng.integers(2**31 - 1))
        return FunctionSamples.from_model(model, pool.points, pool.output_scale, self.n_samples, seed)

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        available = _check_k(pool, k)
        samples = self.samples(model, pool, rng)
        cov = np.eye(samples.n_samples)
        weights = pool.weights * self.fantasy_weight
        open_mask = np.zeros(len(pool.maneuvers), dtype=bool)
        open_mask[available] = True
        picks: list[int] = []
        scores = self.candidate_scores(samples, pool, cov)
        for _ in range(k):
            penalise = self.batch == "penalty" and picks
            damped = scores * _proximity_penalty(pool, picks, self.penalty_length) if penalise else scores
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


def _proximity_penalty(pool: Pool, picks: Sequence[int], length: float) -> np.ndarray:
    """(n,) factor in [0, 1): zero at earlier picks, one far from them (Gaussian in distance/length)."""
    dist = pool.distances(np.arange(len(pool.maneuvers)), np.array(picks)).min(axis=1)
    return 1.0 - np.exp(-0.5 * (dist / length) ** 2)


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

    def __init__(self, **options: Any) -> None:
        options.setdefault("batch", "fantasy")
        super().__init__(**options)

    def point_scores(self, samples: FunctionSamples, cov: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError("integrated_variance scores whole candidates")

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        available = list(_check_k(pool, k))
        seed = int(rng.integers(2**31 - 1))
        stacked = np.concatenate([pool.points, pool.target])
        samples = FunctionSamples.from_model(model, stacked, pool.output_scale, self.n_samples, seed)
        cand = FunctionSamples(samples.phi[: len(pool.points)], samples.aleatoric[: len(pool.points)])
        m = _target_moment(samples.phi[len(pool.points) :], pool.target_weights)
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


def _target_moment(phi: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """M = sum over target points g (weight w_g) and outputs of phi phi^T, an S x S matrix."""
    if weights is None:
        return np.einsum("gos,got->st", phi, phi)
    return np.einsum("gos,g,got->st", phi, weights, phi)



class OracleErrorStrategy(Strategy):
    """Diagnostic upper bound: pick the maneuvers where the current model's TRUE error is largest.

    It reads the noise-free simulation of every candidate (`Pool.truth_*`), which no real campaign
    has, to answer: could any strategy that seeks the model's errors beat space-filling here? Batches
    damp scores near earlier picks, as the `penalty` batch rule does.
    """

    name = "oracle_error"
    uses_model = True

    def __init__(self, penalty_length: float = 0.15) -> None:
        self.penalty_length = penalty_length

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        available = _check_k(pool, k)
        if pool.truth_x is None or pool.truth_y is None or pool.truth_owner is None:
            raise InputError(
                "strategy", self.name, "needs the pool's noise-free truth (campaigns provide it)"
            )
        mean = model.predict(pool.truth_x, n_samples=8, seed=0).mean
        err = (((mean - pool.truth_y) / pool.output_scale) ** 2).sum(axis=1)
        scores = _per_candidate(err, pool.truth_owner, len(pool.maneuvers))
        open_mask = np.zeros(len(pool.maneuvers), dtype=bool)
        open_mask[available] = True
        picks: list[int] = []
        for _ in range(k):
            damped = scores * _proximity_penalty(pool, picks, self.penalty_length) if picks else scores
            masked = np.where(open_mask, damped, -np.inf)
            pick = int(np.argmax(masked))
            picks.append(pick)
            open_mask[pick] = False
        return picks


Trial = Callable[[list[int]], float]


class LookaheadOracleStrategy(Strategy):
    """Benchmark-only reference: the batch whose retrained model has the lowest TRUE test error.

    Each round it proposes a handful of candidate batches (what uniform, max_epistemic and
    integrated_variance would pick, and a few random batches), has the campaign collect each, retrain
    the next round's model on it and measure the test error (`trial`), and keeps the best. No real
    campaign can do this; the gap between uniform and it is the room any acquisition rule has.
    """

    name = "oracle_lookahead"
    uses_model = True
    needs_trial: ClassVar[bool] = True
    proposers: ClassVar[tuple[str, ...]] = ("uniform", "max_epistemic", "integrated_variance")

    def __init__(self, n_random: int = 3, **options: Any) -> None:
        self.n_random = n_random
        self.options = options

    def candidate_batches(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[list[int]]:
        """Distinct candidate batches of k maneuvers (as sorted lists)."""
        batches: list[list[int]] = []
        for name in self.proposers:
            batch = sorted(make_strategy(name, **self.options).select(model, pool, k, rng))
            if batch not in batches:
                batches.append(batch)
        for _ in range(self.n_random):
            batch = sorted(int(i) for i in rng.choice(pool.available, size=k, replace=False))
            if batch not in batches:
                batches.append(batch)
        return batches

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        raise InputError("strategy", self.name, "needs a campaign to retrain on each candidate batch")

    def select_with_trials(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, trial: Trial
    ) -> list[int]:
        """The candidate batch with the lowest test error after retraining (ties: the first)."""
        _check_k(pool, k)
        batches = self.candidate_batches(model, pool, k, rng)
        errors = [trial(batch) for batch in batches]
        return batches[int(np.argmin(errors))]


class AutoStrategy(Strategy):
    """`auto`, the recommended strategy: decides each round from what the campaign knows.

    - Cold start (no prior): greedy maximin (`uniform`). Measured on every cold-start pool, no
      model-based rule beat it (README, "When does active learning pay?").
    - Warm start (`warm_start` in the pool's context: prior data or a prior model): integrated
      variance over the target region, in the function space of the model's posterior draws; per
      second of track time when the budget is in seconds (`seconds_budget` in the pool's context)
      and candidates differ in cost. A dynamic model whose candidates are scored along their own
      free runs (`dynamic_paths` in the context) takes `max_epistemic` instead: on `dynamics_warm` it
      captured 81 % of the lookahead oracle's room where integrated variance ended level with uniform
      (README, "When does active learning pay?").
    - Guard: when the last models' epistemic std ranked their errors on the maneuvers collected after
      them the wrong way round (`prequential_spearman` < 0 over the recent rounds), the uncertainty is
      not to be trusted this round and maximin picks instead.
    `last_choice` records what it did (for the round's metrics).
    """

    name = "auto"
    uses_model = True

    def __init__(self, **options: Any) -> None:
        self.options = options
        self.last_choice = ""

    def decide(self, pool: Pool) -> str:
        """The strategy this round uses: "uniform", "integrated_variance" or "max_epistemic"."""
        context = pool.context or {}
        if not context.get("warm_start"):
            return "uniform"
        spearman = context.get("prequential_spearman")
        if spearman is not None and np.isfinite(spearman) and spearman < 0:
            return "uniform"
        return "max_epistemic" if context.get("dynamic_paths") else "integrated_variance"

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        self.last_choice = self.decide(pool)
        options = dict(self.options)
        seconds = bool((pool.context or {}).get("seconds_budget"))
        if seconds and pool.costs is not None and pool.costs.max() > 1.2 * pool.costs.min():
            options["cost_aware"] = True
        return make_strategy(self.last_choice, **options).select(model, pool, k, rng)


STRATEGIES: dict[str, type[Strategy]] = {
    cls.name: cls
    for cls in (
        GridStrategy,
        MaximinStrategy,
        RandomStrategy,
        SobolStrategy,
        LatinHypercubeStrategy,
        MaxEpistemicStrategy,
        EpistemicMaximinStrategy,
        MaxTotalStrategy,
        BaldStrategy,
        IntegratedVarianceStrategy,
        AutoStrategy,
        OracleErrorStrategy,
        LookaheadOracleStrategy,
    )
}


def make_strategy(name: str, **options: Any) -> Strategy:
    """Build a strategy by name with the acquisition options it uses (the others are ignored).

    Uncertainty strategies take batch, n_samples, fantasy_weight, penalty_length, seed and
    cost_aware; the oracle takes penalty_length; `auto` and the lookahead oracle pass them on to the
    strategies they use; space-filling designs take none.
    """
    if name not in STRATEGIES:
        raise InputError("strategy", name, f"unknown strategy; choose from {', '.join(STRATEGIES)}")
    cls = STRATEGIES[name]
    if issubclass(cls, UncertaintyStrategy | AutoStrategy | LookaheadOracleStrategy):
        return cls(**options)
    if cls is OracleErrorStrategy:
        return cls(**{k: v for k, v in options.items() if k == "penalty_length"})
    return cls()
