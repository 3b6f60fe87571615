"""Acquisition strategies by name: the registry, `auto` and the benchmark-only oracles.

Every strategy implements one interface (`activelearn.loop.strategy.Strategy`: `select`, called
through `pick`), so the campaign loop treats them alike. Space-filling designs
(`activelearn.loop.space_filling`) ignore the model; uncertainty strategies
(`activelearn.loop.function_space`) score each candidate along the controls that maneuver would apply,
in the function space of the model's posterior draws. `auto` decides between them each round; the
oracles are yardsticks that read what no real campaign knows. `switch` spends a fixed number of
maneuvers on greedy maximin, then hands over to a model-based rule. The names are `activelearn.names`'.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from activelearn.errors import InputError
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
from activelearn.loop.greedy_sampling import GreedySamplingStrategy, TrajectoryStrategy
from activelearn.loop.lcmd import LcmdStrategy
from activelearn.loop.space_filling import (
    GridStrategy,
    LatinHypercubeStrategy,
    MaximinStrategy,
    RandomStrategy,
    SobolStrategy,
    greedy_maximin,
)
from activelearn.loop.strategy import Evidence, Pool, Strategy, check_k, per_candidate, proximity_penalty
from activelearn.names import SWITCH_RULES

__all__ = [
    "STRATEGIES",
    "AutoStrategy",
    "BaldStrategy",
    "BatchMode",
    "EpistemicMaximinStrategy",
    "Evidence",
    "FunctionSamples",
    "GreedySamplingStrategy",
    "GridStrategy",
    "IntegratedVarianceStrategy",
    "LatinHypercubeStrategy",
    "LcmdStrategy",
    "LookaheadOracleStrategy",
    "MaxEpistemicStrategy",
    "MaxTotalStrategy",
    "MaximinStrategy",
    "OracleErrorStrategy",
    "Pool",
    "RandomStrategy",
    "SafeExpanderStrategy",
    "SobolStrategy",
    "Strategy",
    "SwitchStrategy",
    "UncertaintyStrategy",
    "greedy_maximin",
    "make_strategy",
]


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

    def pick(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, evidence: Evidence | None = None
    ) -> list[int]:
        """`select` on the pool with the candidates' noise-free truth the campaign's `evidence` holds."""
        if evidence is not None and pool.truth_x is None:
            pool = dataclasses.replace(pool, **evidence.truth())
        return self.select(model, pool, k, rng)

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        available = check_k(pool, k)
        if pool.truth_x is None or pool.truth_y is None or pool.truth_owner is None:
            raise InputError(
                "strategy", self.name, "needs the pool's noise-free truth (campaigns provide it)"
            )
        mean = model.predict(pool.truth_x, n_samples=8, seed=0).mean
        err = (((mean - pool.truth_y) / pool.output_scale) ** 2).sum(axis=1)
        scores = per_candidate(err, pool.truth_owner, len(pool.maneuvers))
        open_mask = np.zeros(len(pool.maneuvers), dtype=bool)
        open_mask[available] = True
        picks: list[int] = []
        for _ in range(k):
            damped = scores * proximity_penalty(pool, picks, self.penalty_length) if picks else scores
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

    def pick(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, evidence: Evidence | None = None
    ) -> list[int]:
        """`select_with_trials`, the campaign's `evidence` retraining on each candidate batch."""
        if evidence is None:
            return self.select(model, pool, k, rng)
        return self.select_with_trials(model, pool, k, rng, evidence.trial)

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
    - Warm start (`warm_start` in the pool's context: prior data or a prior model): integrated
      variance over the target region, in the function space of the model's posterior draws; per
      second of track time when the budget is in seconds (`seconds_budget` in the pool's context)
      and candidates differ in cost. A dynamic model whose candidates are scored along their own
      free runs (`dynamic_paths` in the context) takes `max_epistemic` instead: on `dynamics_warm` it
      captured 81 % of the lookahead oracle's room where integrated variance ended level with uniform
      (docs/results/active-learning.md).
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

    def __init__(
        self,
        *,
        switch_after: int = 10,
        switch_to: str = "bald",
        switch_first: str = "uniform",
        **options: Any,
    ) -> None:
        integer = isinstance(switch_after, int | np.integer) and not isinstance(switch_after, bool)
        if not integer or switch_after < 0:
            raise InputError("acquisition.switch_after", switch_after, "must be an integer of at least 0")
        for field, rule in (("switch_first", switch_first), ("switch_to", switch_to)):
            if rule not in SWITCH_RULES:
                raise InputError(f"acquisition.{field}", rule, f"must be one of {', '.join(SWITCH_RULES)}")
        if switch_first == switch_to:
            raise InputError("acquisition.switch_to", switch_to, "must differ from switch_first")
        self.switch_after = int(switch_after)
        self.first = make_strategy(switch_first, **options)
        self.target = make_strategy(switch_to, **options)
        self.last_model_share = 0.0

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        check_k(pool, k)
        n_first = min(k, max(0, self.switch_after - int(pool.taken.sum())))
        picks = self.first.select(model, pool, n_first, rng) if n_first else []
        if n_first < k:
            later = pool.with_taken(picks) if picks else pool
            picks += self.target.select(model, later, k - n_first, rng)
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
        AutoStrategy,
        SwitchStrategy,
        OracleErrorStrategy,
        LookaheadOracleStrategy,
    )
}


_SWITCH_OPTIONS = ("switch_after", "switch_first", "switch_to")  # read by `switch` alone


def make_strategy(name: str, **options: Any) -> Strategy:
    """Build a strategy by name with the acquisition options it uses (the others are ignored).

    Uncertainty strategies take batch, n_samples, fantasy_weight, penalty_length, seed and
    cost_aware; `igs` and `lcmd` take n_samples; the oracle takes penalty_length; `switch` takes
    switch_after, switch_first and switch_to; `auto`, `switch` and the lookahead oracle pass the others
    on to the strategies they use; space-filling designs take none.
    """
    if name not in STRATEGIES:
        raise InputError("strategy", name, f"unknown strategy; choose from {', '.join(STRATEGIES)}")
    cls = STRATEGIES[name]
    switch = {key: options.pop(key) for key in _SWITCH_OPTIONS if key in options}
    if cls is SwitchStrategy:
        return cls(**switch, **options)
    if issubclass(
        cls,
        UncertaintyStrategy
        | AutoStrategy
        | LookaheadOracleStrategy
        | TrajectoryStrategy,
    ):
        return cls(**options)
    if cls is OracleErrorStrategy:
        return cls(**{k: v for k, v in options.items() if k == "penalty_length"})
    return cls()
