"""Acquisition strategies by name: the registry, `auto` and the benchmark-only oracles.

Every strategy implements one interface (`activelearn.loop.strategy.Strategy`: `select`, called
through `pick`, which hands it the campaign's `History`), so the campaign loop treats them alike, and
every one builds itself from `[acquisition]` (`make_strategy`). Space-filling designs
(`activelearn.loop.space_filling`) ignore the model; uncertainty strategies
(`activelearn.loop.function_space`) score each candidate along the controls that maneuver would apply,
in the function space of the model's posterior draws. `auto` decides between them each round; the
oracles are yardsticks that read what no real campaign knows. `switch` spends a fixed number of
maneuvers on greedy maximin, then hands over to a model-based rule. The names are `activelearn.names`'.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from activelearn.config import AcquisitionConfig
from activelearn.errors import InputError
from activelearn.loop.fisher import FisherStrategy
from activelearn.loop.function_space import (
    BaldStrategy,
    BatchMode,
    EpistemicMaximinStrategy,
    FunctionSamples,
    IntegratedVarianceStrategy,
    MaxEpistemicStrategy,
    MaxTotalStrategy,
    SafeExpanderStrategy,
    UncertaintyStrategy,
)
from activelearn.loop.greedy_sampling import GreedySamplingStrategy
from activelearn.loop.history import NO_HISTORY, CandidateTruth, History, Withheld
from activelearn.loop.lcmd import LcmdStrategy
from activelearn.loop.regressor_space import JointMaximinStrategy, RegressorMaximinStrategy
from activelearn.loop.space_filling import (
    GridStrategy,
    LatinHypercubeStrategy,
    MaximinStrategy,
    RandomStrategy,
    SobolStrategy,
    greedy_maximin,
)
from activelearn.loop.strategy import Pool, Strategy, check_k, per_candidate, proximity_penalty
from activelearn.names import CORRECTION_WEIGHT, PREQUENTIAL_SPEARMAN

__all__ = [
    "STRATEGIES",
    "AutoStrategy",
    "BaldStrategy",
    "BatchMode",
    "CandidateTruth",
    "EpistemicMaximinStrategy",
    "FisherStrategy",
    "FunctionSamples",
    "GreedySamplingStrategy",
    "GridStrategy",
    "History",
    "IntegratedVarianceStrategy",
    "JointMaximinStrategy",
    "LatinHypercubeStrategy",
    "LcmdStrategy",
    "LookaheadOracleStrategy",
    "MaxEpistemicStrategy",
    "MaxTotalStrategy",
    "MaximinStrategy",
    "OracleErrorStrategy",
    "Pool",
    "RandomStrategy",
    "RegressorMaximinStrategy",
    "SafeExpanderStrategy",
    "SobolStrategy",
    "Strategy",
    "SwitchStrategy",
    "UncertaintyStrategy",
    "Withheld",
    "greedy_maximin",
    "make_strategy",
]


class OracleErrorStrategy(Strategy):
    """Diagnostic upper bound: pick the maneuvers where the current model's TRUE error is largest.

    It reads the noise-free simulation of every candidate (`History.truth`), which no real campaign
    has, to answer: could any strategy that seeks the model's errors beat space-filling here? Batches
    damp scores near earlier picks, as the `penalty` batch rule does.
    """

    name = "oracle_error"
    uses_model = True

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        return self.pick(model, pool, k, rng)

    def pick(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, history: History = NO_HISTORY
    ) -> list[int]:
        """The candidates the model errs most on, by the noise-free truth the `history` holds."""
        available = check_k(pool, k)
        if history.truth is None:
            raise InputError(
                "strategy", self.name, "needs the candidates' noise-free truth (campaigns provide it)"
            )
        truth = history.truth()
        penalty_length = self.acquisition.penalty_length
        mean = model.predict(truth.x, n_samples=8, seed=0).mean
        err = (((mean - truth.y) / pool.output_scale) ** 2).sum(axis=1)
        scores = per_candidate(err, truth.owner, len(pool.maneuvers))
        open_mask = np.zeros(len(pool.maneuvers), dtype=bool)
        open_mask[available] = True
        picks: list[int] = []
        for _ in range(k):
            damped = scores * proximity_penalty(pool, picks, penalty_length) if picks else scores
            masked = np.where(open_mask, damped, -np.inf)
            pick = int(np.argmax(masked))
            picks.append(pick)
            open_mask[pick] = False
        return picks


Trial = Callable[[list[int]], float]


class LookaheadOracleStrategy(Strategy):
    """Benchmark-only reference: the batch whose retrained model has the lowest TRUE test error (the
    config's `[test] metric`: what the comparison ranks by, the free runs' error for a dynamics config).

    Each round it proposes a handful of candidate batches (what uniform, max_epistemic and
    integrated_variance would pick, and a few random batches), has the campaign collect each, retrain
    the next round's model on it and measure the test error (`trial`), and keeps the best. No real
    campaign can do this; the gap between uniform and it is the room any acquisition rule has.
    """

    name = "oracle_lookahead"
    uses_model = True
    proposers: ClassVar[tuple[str, ...]] = ("uniform", "max_epistemic", "integrated_variance")
    n_random: ClassVar[int] = 3  # random batches tried besides the proposers'

    def candidate_batches(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[list[int]]:
        """Distinct candidate batches of k maneuvers (as sorted lists)."""
        batches: list[list[int]] = []
        for name in self.proposers:
            batch = sorted(make_strategy(name, self.acquisition).select(model, pool, k, rng))
            if batch not in batches:
                batches.append(batch)
        for _ in range(self.n_random):
            batch = sorted(int(i) for i in rng.choice(pool.available, size=k, replace=False))
            if batch not in batches:
                batches.append(batch)
        return batches

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        raise InputError("strategy", self.name, "needs a campaign to retrain on each candidate batch")

    def pick(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, history: History = NO_HISTORY
    ) -> list[int]:
        """`select_with_trials`, the campaign's `history.trial` retraining on each candidate batch."""
        if history.trial is None:
            return self.select(model, pool, k, rng)
        return self.select_with_trials(model, pool, k, rng, history.trial)

    def select_with_trials(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, trial: Trial
    ) -> list[int]:
        """The candidate batch with the lowest test error after retraining (ties: the first)."""
        check_k(pool, k)
        batches = self.candidate_batches(model, pool, k, rng)
        errors = [trial(batch) for batch in batches]
        return batches[int(np.argmin(errors))]


class AutoStrategy(Strategy):
    """`auto`, the recommended strategy: decides each round from what the campaign knows.

    - Cold start (no prior): greedy maximin (`uniform`). Measured on every cold-start pool, no
      model-based rule beat it (docs/results/active-learning.md).
    - Warm start (`History.prior`: prior data or a prior model): integrated variance over the target
      region, in the function space of the model's posterior draws; per second of track time when the
      budget is in seconds (`History.budget`) and candidates differ in cost. A dynamic model whose
      candidates are scored along their own free runs (`History.scores_paths`) takes `max_epistemic`
      instead: on `dynamics_warm` it captured 81 % of the lookahead oracle's room where integrated
      variance ended level with uniform (docs/results/active-learning.md).
    - Guard: when the last models' epistemic std ranked their errors on the maneuvers collected after
      them the wrong way round (`prequential_spearman` < 0, the mean of the last `guard_rounds` rounds
      that measured it), the uncertainty is not to be trusted this round and maximin picks instead.
    - Gate guard: when this round's model keeps none of its correction's mean (its `correction_weight`
      round metric is 0: the correction gate found the correction did not help on held-out maneuvers),
      its epistemic spread is the correction's, which its mean does not use, so maximin picks. On the
      1:10 warm start the gate keeps none in most rounds, and max_epistemic there ended at twice
      uniform's error (docs/results/active-learning.md).
    `last_choice` records what it did (for the round's metrics).
    """

    name = "auto"
    uses_model = True
    guard_rounds: ClassVar[int] = 3

    def __init__(self, acquisition: AcquisitionConfig | None = None, **options: Any) -> None:
        super().__init__(acquisition, **options)
        self.last_choice = ""

    def prequential_spearman(self, history: History) -> float | None:
        """Mean rank check of the last rounds that measured one (None: none did)."""
        recent = [
            r[PREQUENTIAL_SPEARMAN]
            for r in history.rounds
            if np.isfinite(r.get(PREQUENTIAL_SPEARMAN, np.nan))
        ]
        return float(np.mean(recent[-self.guard_rounds :])) if recent else None

    def decide(self, history: History, kept_correction: float | None = None) -> str:
        """The strategy this round uses: "uniform", "integrated_variance" or "max_epistemic".
        `kept_correction`: the share of its correction's mean this round's model keeps (None: a model
        without a gated correction)."""
        if not history.prior or kept_correction == 0.0:
            return "uniform"
        spearman = self.prequential_spearman(history)
        if spearman is not None and np.isfinite(spearman) and spearman < 0:
            return "uniform"
        return "max_epistemic" if history.scores_paths else "integrated_variance"

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        return self.pick(model, pool, k, rng)

    def pick(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, history: History = NO_HISTORY
    ) -> list[int]:
        self.last_choice = self.decide(history, model.round_metrics().get(CORRECTION_WEIGHT))
        options: dict[str, Any] = {}
        seconds = history.budget == "seconds"
        if seconds and pool.costs is not None and pool.costs.max() > 1.2 * pool.costs.min():
            options["cost_aware"] = True
        return make_strategy(self.last_choice, self.acquisition, **options).pick(model, pool, k, rng, history)

    def round_metrics(self) -> dict[str, float]:
        """`auto_model_based`: 1 when this round's pick used the model, 0 when maximin picked."""
        return {"auto_model_based": float(self.last_choice != "uniform")}


class SwitchStrategy(Strategy):
    """`switch`: `switch_first` (greedy maximin by default) for the first `switch_after` maneuvers,
    then `switch_to` (a model-based rule by default).

    A budget switch. Maximin first, then a rule: the first maneuvers cover the domain while the model
    knows too little for its uncertainty to rank candidates. A rule first, then maximin: the rule's
    early picks pay (on the twin `bald` reached uniform's final error after half the signals) but
    its later ones pile up where the model's uncertainty stays large, so maximin spreads the rest.
    From the `switch_after`-th collected maneuver on (the initial design counts) `switch_to` picks; a
    round whose batch straddles the switch has `switch_first` fill the maneuvers left before it, then
    `switch_to` the rest (it sees the first picks as taken). `switch_model_based` logs the share of
    the round's picks a model-based rule made.
    """

    name = "switch"
    uses_model = True

    def __init__(self, acquisition: AcquisitionConfig | None = None, **options: Any) -> None:
        super().__init__(acquisition, **options)
        acq = self.acquisition
        self.switch_after = acq.switch_after
        self.first = make_strategy(acq.switch_first, acq)
        self.target = make_strategy(acq.switch_to, acq)
        self.last_model_share = 0.0

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        return self.pick(model, pool, k, rng)

    def pick(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, history: History = NO_HISTORY
    ) -> list[int]:
        check_k(pool, k)
        n_first = min(k, max(0, self.switch_after - int(pool.taken.sum())))
        picks = self.first.pick(model, pool, n_first, rng, history) if n_first else []
        if n_first < k:
            later = pool.with_taken(picks) if picks else pool
            picks += self.target.pick(model, later, k - n_first, rng, history)
        by_model = n_first * self.first.uses_model + (k - n_first) * self.target.uses_model
        self.last_model_share = by_model / k
        return picks

    def round_metrics(self) -> dict[str, float]:
        """`switch_model_based`: the share of this round's picks a model-based rule made (0 to 1)."""
        return {"switch_model_based": self.last_model_share}


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
        SafeExpanderStrategy,
        GreedySamplingStrategy,
        LcmdStrategy,
        RegressorMaximinStrategy,
        JointMaximinStrategy,
        FisherStrategy,
        AutoStrategy,
        SwitchStrategy,
        OracleErrorStrategy,
        LookaheadOracleStrategy,
    )
}


def make_strategy(name: str, acquisition: AcquisitionConfig | None = None, **options: Any) -> Strategy:
    """Build a strategy by name from `[acquisition]` (None: its defaults), `options` changing single keys.

    Each strategy reads the options it uses: uncertainty strategies batch, n_samples, fantasy_weight,
    penalty_length and cost_aware; `igs` and `lcmd` n_samples; the error oracle penalty_length;
    `switch` switch_after, switch_first and switch_to; `auto`, `switch` and the lookahead oracle hand
    the section on to the strategies they use; space-filling designs read none.
    """
    if name not in STRATEGIES:
        raise InputError("strategy", name, f"unknown strategy; choose from {', '.join(STRATEGIES)}")
    return STRATEGIES[name](acquisition, **options)
