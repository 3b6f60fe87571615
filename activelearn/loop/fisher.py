"""`fisher`: the maneuvers that tell the physics core's identified parameters the most (greedy D-optimal).

Space filling spreads the signals, or (`regressor_maximin`) what the model reads along them. Where a
physics core carries the model, what a maneuver is worth is what it tells the core's identification: on
the 1:10 twin (less grip, a weaker motor) the rules end far from the lookahead oracle, which gets the
motor's scale right while they under-sample what excites the drive and the yaw inertia
(docs/results/active-learning.md). This is the classic design for system identification, D-optimal
(Fisher information as the weight of a distance), sequential as the loop is:

* each candidate's information about the identified parameters is the model's
  (`Model.parameter_information`: on the dynamic core the sensitivities of its rates along the
  identification's restarted free runs of the candidate's controls, at the current scales);
* the base: the parameters' prior precision and the information of the maneuvers collected (their
  controls, as the strategy sees the pool, not the logs; a warm start's prior maneuvers are not in the
  pool and add none);
* greedily, the candidate that raises log det of the information most is picked and its information
  added, until the batch is full.

D-optimality weighs every scale alike, whether the envelope's free runs follow it or not. With
`[acquisition] fisher_criterion = "prediction"` a batch instead lowers the scales' share of the
prediction variance over the envelope (greedy I-optimal): trace(Ī Σ), Σ the scales' covariance after the
batch, Ī the pool's candidates' mean information (how much each scale moves their rates, per noise). Its
base is the identification's own covariance (`Model.identified_covariance`), every log so far in it, a
warm start's grid included; where the model keeps none, the prior's precision and the collected
candidates' information, as D-optimal's.

A model kind without such parameters (every kind but the physics kind on the dynamic core, today) is
refused with an error naming the strategy.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from activelearn.errors import InputError
from activelearn.loop.pool import maneuver_controls
from activelearn.loop.strategy import Pool, Strategy, check_k
from simulator.datasheet import LOG_RATE_HZ


class FisherStrategy(Strategy):
    """`fisher`: greedy D-optimal design in the model's identified parameters (module docstring)."""

    name = "fisher"
    uses_model = True

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        open_ = list(check_k(pool, k))
        controls = [maneuver_controls(m, LOG_RATE_HZ) for m in pool.maneuvers]
        found = model.parameter_information(controls, LOG_RATE_HZ)
        if found is None:
            raise InputError("strategy", self.name, 'needs [model] kind = "physics" with core = "dynamic"')
        info, prior_precision = found
        total = prior_precision + info[pool.taken].sum(axis=0)
        if self.acquisition.fisher_criterion == "prediction":
            known = model.identified_covariance()
            if known is not None:  # a millionth of the prior's variance: a scale the logs fixed exactly
                total = np.linalg.inv(known + 1e-6 * np.linalg.inv(prior_precision))
            return _greedy(info, total, open_, k, _prediction_variance(info.mean(axis=0)))
        return _greedy(info, total, open_, k, _minus_log_det)


def _minus_log_det(totals: np.ndarray) -> np.ndarray:
    """(m,) −log det of each information matrix (m, P, P): D-optimality's loss."""
    return -np.linalg.slogdet(totals)[1]


def _prediction_variance(weight: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The loss trace(weight · total⁻¹) of each information matrix `total` (m, P, P): the scales' share of
    the prediction variance where `weight` is the information of the points predicted (I-optimality)."""

    def loss(totals: np.ndarray) -> np.ndarray:
        return np.einsum("ij,mji->m", weight, np.linalg.inv(totals))

    return loss


def _greedy(
    info: np.ndarray, total: np.ndarray, open_: list[int], k: int, loss: Callable[[np.ndarray], np.ndarray]
) -> list[int]:
    """k candidates of `open_`, each the one whose information (`info`, (n, P, P)) added to `total` gives
    the lowest `loss`, then added to it."""
    picks: list[int] = []
    for _ in range(k):
        rows = np.asarray(open_, dtype=int)
        best = int(rows[int(np.argmin(loss(total[None] + info[rows])))])
        picks.append(best)
        open_.remove(best)
        total = total + info[best]
    return picks
