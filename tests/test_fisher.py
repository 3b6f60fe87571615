"""`fisher` (greedy D-optimal design in the identified scales) on the 1:10 car's family pool."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from activelearn.config import CampaignConfig, load_config
from activelearn.loop.acquisition import make_strategy
from activelearn.loop.pool import build_pool, maneuver_controls, pool_maneuvers
from activelearn.numerics.models import build_model
from simulator.datasheet import LOG_RATE_HZ

CONFIG = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "dynamics_f1tenth.toml"


@pytest.fixture(scope="module")
def setting():
    cfg = load_config(CONFIG)
    maneuvers = pool_maneuvers(cfg.pool)[::4]  # 30 of the 120 candidates: a quick pool
    taken = np.zeros(len(maneuvers), dtype=bool)
    taken[[0, 7]] = True
    pool = build_pool(cfg, maneuvers, taken, np.ones(2), (np.zeros((1, 16)), np.ones(1)), design_seed=0)
    model = build_model(cfg.model, seed=0)
    return model, pool


def test_fisher_picks_by_greedy_d_optimality_what_the_model_says_each_candidate_tells(setting):
    model, pool = setting
    picks = make_strategy("fisher").select(model, pool, 3, np.random.default_rng(0))
    info, total = model.parameter_information([maneuver_controls(m, LOG_RATE_HZ) for m in pool.maneuvers],
                                              LOG_RATE_HZ)  # fmt: skip
    total = total + info[0] + info[7]
    expected, open_ = [], [i for i in range(len(pool.maneuvers)) if i not in (0, 7)]
    for _ in range(3):  # by hand: the largest log det of the information with the candidate added
        best = max(open_, key=lambda i: np.linalg.slogdet(total + info[i])[1])
        expected.append(best)
        open_.remove(best)
        total = total + info[best]
    assert picks == expected
    # the picks tell more than the candidates left: each raised log det by more than the median one would
    gains = [np.linalg.slogdet(total - info[p] + info[i])[1] for p in picks[-1:] for i in open_]
    assert np.linalg.slogdet(total)[1] > np.median(gains)


def test_the_information_depends_on_the_models_identified_scales(setting):
    model, pool = setting
    controls = [maneuver_controls(m, LOG_RATE_HZ) for m in pool.maneuvers[:4]]
    before, _ = model.parameter_information(controls, LOG_RATE_HZ)
    model.theta[0] = 0.5  # half the grip: the tyres saturate elsewhere, and tell other things
    after, _ = model.parameter_information(controls, LOG_RATE_HZ)
    model.theta[0] = 1.0
    assert not np.allclose(before, after, rtol=1e-2)
    with pytest.raises(ValueError, match="Hz"):
        model.parameter_information(controls, 10.0)


def test_a_config_without_the_dynamic_core_refuses_it():
    with pytest.raises(ValidationError, match="strategy: fisher needs"):
        CampaignConfig.model_validate({"name": "x", "strategy": "fisher"})
    switched = {"name": "x", "strategy": "switch", "acquisition": {"switch_to": "fisher"}}
    with pytest.raises(ValidationError, match="strategy: fisher needs"):
        CampaignConfig.model_validate(switched)
    data = load_config(CONFIG).model_dump(mode="json")
    assert CampaignConfig.model_validate({**data, "strategy": "fisher"}).strategy == "fisher"
