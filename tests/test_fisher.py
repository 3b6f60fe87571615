"""`fisher` (greedy D-optimal design in the identified scales, or I-optimal: `fisher_criterion`) on the 1:10
car's family pool."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from activelearn.config import CampaignConfig, load_config
from activelearn.loop.acquisition import make_strategy
from activelearn.loop.pool import build_pool, maneuver_controls, pool_maneuvers
from activelearn.numerics.models import build_model
from activelearn.numerics.models.single_track import Identified
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


def _by_hand(info, total, open_, k, loss):
    """k greedy picks of `open_`, each the lowest `loss` of `total` plus its information, written out."""
    picks = []
    for _ in range(k):
        best = min(open_, key=lambda i: loss(total + info[i]))
        picks.append(best)
        open_ = [i for i in open_ if i != best]
        total = total + info[best]
    return picks


def test_fisher_picks_by_greedy_d_optimality_what_the_model_says_each_candidate_tells(setting):
    model, pool = setting
    picks = make_strategy("fisher").select(model, pool, 3, np.random.default_rng(0))
    info, total = model.parameter_information([maneuver_controls(m, LOG_RATE_HZ) for m in pool.maneuvers],
                                              LOG_RATE_HZ)  # fmt: skip
    total = total + info[0] + info[7]
    open_ = [i for i in range(len(pool.maneuvers)) if i not in (0, 7)]
    # by hand: the largest log det of the information with the candidate added
    expected = _by_hand(info, total, open_, 3, lambda m: -np.linalg.slogdet(m)[1])
    total = total + sum(info[i] for i in expected)
    open_ = [i for i in open_ if i not in expected]
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


def test_the_prediction_criterion_starts_from_the_identifications_own_covariance(setting):
    model, pool = setting
    controls = [maneuver_controls(m, LOG_RATE_HZ) for m in pool.maneuvers]
    info, prior_precision = model.parameter_information(controls, LOG_RATE_HZ)
    weight = info.mean(axis=0)
    open_ = [i for i in range(len(pool.maneuvers)) if i not in (0, 7)]

    def variance(total):
        return np.trace(weight @ np.linalg.inv(total))

    strategy = make_strategy("fisher", fisher_criterion="prediction")
    assert model.identified_covariance() is None  # no identification yet: the prior and the collected
    expected = _by_hand(info, prior_precision + info[0] + info[7], open_, 3, variance)
    assert strategy.select(model, pool, 3, np.random.default_rng(0)) == expected
    # an identification that pinned every scale but the first (a warm start's grid, say): the picks follow
    # what is left unknown, not what the collected candidates told
    covariance = np.diag([0.04, 1e-4, 1e-4, 1e-4, 1e-4])
    model.set_identified(Identified(model.theta.double().numpy(), covariance))
    try:
        assert np.allclose(model.identified_covariance(), covariance, rtol=1e-5, atol=1e-9)
        known = np.linalg.inv(covariance + 1e-6 * np.linalg.inv(prior_precision))
        picks = strategy.select(model, pool, 3, np.random.default_rng(0))
        assert picks == _by_hand(info, known, open_, 3, variance)
        first = [info[i][0, 0] for i in open_]  # what each candidate tells of the first scale
        assert info[picks[0]][0, 0] > np.median(first)
        assert picks != _by_hand(info, prior_precision + info[0] + info[7], open_, 3, variance)
    finally:
        model.theta_scale.zero_()  # the module's model as it was: no identification
    assert model.identified_covariance() is None
