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

A model kind without such parameters (every kind but the physics kind on the dynamic core, today) is
refused with an error naming the strategy.
"""

from __future__ import annotations

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
        info, total = found
        total = total + info[pool.taken].sum(axis=0)
        picks: list[int] = []
        for _ in range(k):
            rows = np.asarray(open_, dtype=int)
            gain = np.linalg.slogdet(total[None] + info[rows])[1]
            best = int(rows[int(np.argmax(gain))])
            picks.append(best)
            open_.remove(best)
            total = total + info[best]
        return picks
