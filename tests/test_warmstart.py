"""Warm starts, target regions and costs: real MuJoCo, real models, shrunk sizes."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from activelearn.cli import main
from activelearn.config import ModelConfig, TrainingConfig, load_config
from activelearn.data import read_table, write_table
from activelearn.errors import ConfigError, InputError
from activelearn.loop.acquisition import (
    IntegratedVarianceStrategy,
    MaxEpistemicStrategy,
    greedy_maximin,
    make_strategy,
)
from activelearn.loop.campaign import Campaign, CampaignState
from activelearn.loop.collection import control_rate_logs
from activelearn.loop.history import History
from activelearn.loop.pool import (
    build_pool,
    operating_features,
    pool_maneuvers,
    target_points,
    test_maneuvers,
)
from activelearn.loop.prior import PRIOR_FILE
from activelearn.loop.state import MODEL_FILE, PRIOR_MODEL_FILE
from activelearn.numerics import synthetic
from activelearn.numerics.models import ResidualModel, build_model, load_model, save_model
from activelearn.numerics.models import single_track as st
from activelearn.numerics.models.residual import BASE_SAMPLES
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from activelearn.numerics.uncertainty import rmse
from tests.conftest import flat_weights

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"
PRIOR_GRID = {"kinds": ["skidpad"], "throttles": [0.3, 0.6], "steerings": [0.15], "duration": 10.0}


def warm_config(tmp_path: Path, **overrides):
    """The smoke config with a small prior grid; the initial design is the prior alone."""
    data = {
        "output_dir": str(tmp_path / "runs"),
        "tracking": {"enabled": False},
        "training": {"epochs": 20},
        "design": {"initial": 0, "per_round": 2, "max_maneuvers": 4, "prior": {"grid": PRIOR_GRID}},
        **overrides,
    }
    return load_config(SMOKE, overrides=data)


def test_prior_rows_train_every_round_but_count_against_no_budget(tmp_path):
    cfg = warm_config(tmp_path)
    result = Campaign(cfg, tmp_path / "c").run(figures=False, log_model=False)
    prior = read_table(tmp_path / "c" / PRIOR_FILE)
    assert set(prior["pool_index"]) == {-1, -2, -3, -4}  # 2 throttles x 1 steering x 2 directions
    assert (prior["batch"] == -1).all()
    history = result.history
    # round 0 is the prior alone: the curve starts there, with no budget spent
    assert history["n_maneuvers"].tolist() == [0, 2, 4]
    assert history["track_seconds"].iloc[0] == 0.0
    prior_rows = history["n_samples"].iloc[0]
    assert prior_rows > 0
    # every later round trains on the prior rows plus the new ones
    samples = read_table(tmp_path / "c" / "samples.parquet")
    x, _, _ = Campaign(cfg, tmp_path / "other").fitting.rows(samples)
    assert history["n_samples"].iloc[-1] == prior_rows + len(x)
    assert len(result.state.taken) == cfg.design.max_maneuvers
    assert result.state.stop_reason == "max_maneuvers"


@pytest.mark.slow
def test_a_prior_of_another_car_only_centres_the_identification(tmp_path):
    """`same_car = false` on the twin: round 0's model is identified on the (nominal) prior grid, the
    next on the twin's own logs under the grid's estimate (`identify_on_another_car`); true pools them.
    The correction trains on the grid's rows in round 0 and, with false, on the twin's alone after."""
    def logs(frame):
        return control_rate_logs([part for _, part in frame.groupby("pool_index", sort=False)])

    found, grid = {}, {**PRIOR_GRID, "kinds": ["straight", "skidpad"]}
    for same_car in (True, False):
        cfg = warm_config(
            tmp_path, oracle={"kind": "twin", "overrides": {"motor_gain": 0.8}},
            data={"stride": 5, "skip_seconds": 0.0, "inputs": "history", "history": 3, "history_step": 2},
            model={"kind": "physics", "arch": "D16-V8-V"}, training={"epochs": 2},
            pool={"kinds": ["straight"], "duration": 8.0},
            design={"initial": 0, "per_round": 2, "max_maneuvers": 2,
                    "prior": {"grid": grid, "same_car": same_car}},
        )  # fmt: skip
        directory = tmp_path / f"same_car_{same_car}"
        campaign = Campaign(cfg, directory)
        result = campaign.run(figures=False)
        prior_rows, samples = read_table(directory / PRIOR_FILE), read_table(directory / "samples.parquet")
        prior, own = logs(prior_rows), logs(samples)
        n_prior, n_own = len(campaign.fitting.rows(prior_rows)[0]), len(campaign.fitting.rows(samples)[0])
        trained = result.history["n_samples"].tolist()
        assert trained == [n_prior, n_prior + n_own if same_car else n_own]
        found[same_car] = load_model(directory / "model.pt").theta.numpy()
        expected = st.identify_from_logs(prior + own) if same_car else st.identify_on_another_car(own, prior)
        np.testing.assert_allclose(found[same_car], expected.values, rtol=1e-5)
    assert found[False][0] == pytest.approx(0.8, abs=0.03)  # the twin's motor, from its two straights
    assert found[True][0] > found[False][0] + 0.03  # pooled, the grid's nominal motor pulls it up


@pytest.mark.slow
def test_a_killed_warm_campaign_resumes_with_its_prior(tmp_path):
    cfg = warm_config(tmp_path)
    reference = Campaign(cfg, tmp_path / "ref").run(figures=False, log_model=False)
    victim = Campaign(cfg, tmp_path / "kill")
    victim.propose(figures=False)  # round 0 fitted, first batch proposed: then "killed"
    resumed = Campaign(cfg, tmp_path / "kill").run(resume=True, figures=False, log_model=False)
    assert resumed.state.prior_digest == reference.state.prior_digest is not None
    assert resumed.state.batches == reference.state.batches
    assert [r["test_rmse"] for r in resumed.state.rounds] == [r["test_rmse"] for r in reference.state.rounds]
    pd.testing.assert_frame_equal(
        read_table(tmp_path / "ref" / PRIOR_FILE), read_table(tmp_path / "kill" / PRIOR_FILE)
    )


@pytest.mark.slow
def test_a_prior_campaign_directory_and_table_feed_a_new_campaign(tmp_path):
    earlier = Campaign(warm_config(tmp_path), tmp_path / "earlier").run(figures=False, log_model=False)
    table = tmp_path / "known.parquet"
    write_table(read_table(tmp_path / "earlier" / "samples.parquet"), table)
    cfg = warm_config(
        tmp_path, design={"initial": 0, "max_maneuvers": 2, "prior": [str(tmp_path / "earlier"), str(table)]}
    )
    campaign = Campaign(cfg, tmp_path / "c")
    result = campaign.run(figures=False, log_model=False)
    runs = campaign.prior.runs
    # the earlier campaign's own prior (4) and its 4 maneuvers, then the table's 4 maneuvers again
    assert len(runs) == 4 + len(earlier.state.taken) * 2
    assert result.history["n_maneuvers"].tolist() == [0, 2]


@pytest.mark.parametrize(
    ("column", "value", "reason"),
    [("steering", 20.0, "degrees"), ("speed", 25.0, "m/s"), ("time", None, "Hz")],
)
def test_a_prior_in_other_units_is_one_clear_error_and_writes_nothing(
    tmp_path, capsys, column, value, reason
):
    source = read_table(_simulated_log(tmp_path))
    if value is None:
        source["time"] = source["time"] * 3.0  # logged at 10 Hz
    else:
        source.loc[5, column] = value
    bad = tmp_path / "bad.parquet"
    write_table(source, bad)
    config = tmp_path / "warm.toml"
    config.write_text(SMOKE.read_text().replace("[design]", f'[design]\nprior = ["{bad}"]'))
    out = tmp_path / "out"
    code = main(["campaign", "run", str(config), "--out", str(out), "--no-tracking"])
    err = capsys.readouterr().err
    assert code == 2
    assert "design.prior.paths[0]" in err and reason in err and err.count("\n") == 1
    assert not out.exists()


def _simulated_log(tmp_path: Path) -> Path:
    path = tmp_path / "log.parquet"
    assert main(["simulate", "--maneuver", "skidpad", "--throttle", "0.5", "--steering", "0.2",
                 "--duration", "6", "--out", str(path)]) == 0  # fmt: skip
    return path


def test_a_prior_model_with_other_inputs_is_rejected(tmp_path):
    model = build_model(ModelConfig(n_inputs=4))
    save_model(model, tmp_path / "markov.pt")
    cfg = warm_config(
        tmp_path, design={"initial": 1, "prior": {"model": str(tmp_path / "markov.pt"), "use": "finetune"}}
    )
    with pytest.raises(InputError, match=r"design\.prior\.model.*4 inputs"):
        Campaign(cfg, tmp_path / "c").run(figures=False, log_model=False)
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("use", ["finetune", "residual"])
def test_finetune_and_residual_warm_starts_run_and_keep_their_prior_model(tmp_path, use):
    initial = 1 if use == "residual" else 0
    cfg = warm_config(tmp_path, design={"initial": initial, "max_maneuvers": 3,
                                        "prior": {"grid": PRIOR_GRID, "use": use}})  # fmt: skip
    result = Campaign(cfg, tmp_path / "c").run(figures=False, log_model=False)
    assert (tmp_path / "c" / "prior_model.pt").exists()
    assert np.isfinite(result.history["test_rmse"]).all()
    # the prior rows do not train the rounds: only the new maneuvers' rows count
    samples = read_table(tmp_path / "c" / "samples.parquet")
    x, y, _ = Campaign(cfg, tmp_path / "other").fitting.rows(samples)
    assert result.history["n_samples"].iloc[-1] == len(x)
    prior = load_model(tmp_path / "c" / PRIOR_MODEL_FILE)
    if use == "residual":
        # The last round's model is the stored prior plus a residual learnt on the difference from it.
        model = load_model(tmp_path / "c" / MODEL_FILE)
        assert isinstance(model, ResidualModel)
        assert torch.equal(flat_weights(model.base), flat_weights(prior))
        mean = model.predict(x, n_samples=8, seed=0).mean
        base = prior.predict(x, n_samples=BASE_SAMPLES, seed=0).mean
        residual = model.residual.predict(x, n_samples=8, seed=0).mean
        np.testing.assert_allclose(mean, base + residual, rtol=1e-5, atol=1e-6)
        assert rmse(y, mean) < rmse(y, residual)  # the residual alone misses what the prior knows
    else:
        # A round fine-tunes a copy of the prior: with a vanishing learning rate it stays the prior.
        still = warm_config(tmp_path, training={"epochs": 1, "lr": 1e-9}, design=cfg.design.model_dump())
        tuned = Campaign(still, tmp_path / "c").fitting.fit(samples, 1)
        torch.testing.assert_close(flat_weights(tuned), flat_weights(prior), rtol=0, atol=1e-6)
        assert torch.equal(tuned.x_mean, prior.x_mean) and torch.equal(tuned.y_std, prior.y_std)


# --------------------------------------------------------------------------------------- strategies


@pytest.fixture(scope="module")
def pool_cfg(tmp_path_factory):
    return load_config(
        SMOKE,
        overrides={
            "output_dir": str(tmp_path_factory.mktemp("runs")),
            "pool": {
                "throttles": [-0.8, -0.4, 0.2, 0.6, 1.0],
                "steerings": [0.1, 0.3, 0.5],
                "duration": 10.0,
            },
            "test": {"throttles": [0.5], "steerings": [0.2], "duration": 10.0},
        },
    )


@pytest.fixture(scope="module")
def forward_model():
    """A hybrid trained on forward throttle only: unsure in reverse."""
    x = synthetic.random_points(500, throttle=(0.2, 1.0), steering=(-0.5, 0.5), seed=3)
    y = synthetic.observe(x, np.random.default_rng(0))
    model = build_model(ModelConfig())
    fit(model, TrainingData(x, y), TrainingConfig(epochs=40, patience=None), seed=0)
    return model


def _pool(cfg, **kwargs):
    maneuvers = pool_maneuvers(cfg.pool)
    target = kwargs.pop("target", None) or target_points(cfg, maneuvers, test_maneuvers(cfg.test))
    taken = np.zeros(len(maneuvers), dtype=bool)
    return build_pool(cfg, maneuvers, taken, np.array([0.1, 0.3]), target, 0, **kwargs)


def test_uniform_treats_the_prior_as_taken(pool_cfg):
    maneuvers = pool_maneuvers(pool_cfg.pool)
    forward = [m for m in maneuvers if m.throttle > 0]
    pool = _pool(pool_cfg, prior=forward)
    picks = greedy_maximin(pool, 4, np.random.default_rng(0))
    assert all(maneuvers[i].throttle < 0 for i in picks)  # the unknown part first
    cold = greedy_maximin(_pool(pool_cfg), 4, np.random.default_rng(0))
    assert any(maneuvers[i].throttle > 0 for i in cold)


def test_the_target_region_decides_what_integrated_variance_integrates(pool_cfg, forward_model):
    strategy = IntegratedVarianceStrategy(n_samples=32)
    picks = {}
    for name, box in {"reverse": (-0.8, -0.4), "forward": (0.6, 1.0)}.items():
        cfg = pool_cfg.model_copy(
            update={"target": pool_cfg.target.model_copy(update={"region": "box", "throttle_range": box,
                                                                   "steering_range": (0.1, 0.5)})}
        )  # fmt: skip
        maneuvers = pool_maneuvers(cfg.pool)
        pool = _pool(cfg, target=target_points(cfg, maneuvers, []))
        chosen = strategy.select(forward_model, pool, 2, np.random.default_rng(0))
        picks[name] = [maneuvers[i].throttle for i in chosen]
    assert all(t < 0 for t in picks["reverse"])
    assert all(t > 0 for t in picks["forward"])


def test_cost_aware_picks_prefer_the_cheaper_of_two_equally_informative_candidates(pool_cfg, forward_model):
    maneuvers = pool_maneuvers(pool_cfg.pool)
    pool = _pool(pool_cfg)
    plain = MaxEpistemicStrategy(n_samples=32, batch="topk")
    best = plain.select(forward_model, pool, 1, np.random.default_rng(0))[0]
    # a copy of the best candidate that costs three times as much, placed first in the pool
    twin = dataclasses.replace(maneuvers[best], duration=maneuvers[best].duration * 3)
    both = [twin, *maneuvers]
    features = operating_features(both)
    points = np.concatenate([pool.points[pool.owner == best], pool.points])
    owner = np.concatenate([np.zeros((pool.owner == best).sum(), dtype=int), pool.owner + 1])
    weights = np.concatenate([pool.weights[pool.owner == best], pool.weights])
    priced = dataclasses.replace(
        pool, maneuvers=tuple(both), features=features,
        kinds=np.concatenate([[pool.kinds[best]], pool.kinds]), points=points, owner=owner,
        weights=weights, taken=np.zeros(len(both), dtype=bool),
        costs=np.array([m.duration for m in both]), affordable=None,
    )  # fmt: skip
    assert plain.select(forward_model, priced, 1, np.random.default_rng(0)) == [0]  # a tie: the first
    aware = MaxEpistemicStrategy(n_samples=32, batch="topk", cost_aware=True)
    assert aware.select(forward_model, priced, 1, np.random.default_rng(0)) == [best + 1]


def test_a_seconds_budget_with_kind_durations_stops_before_it_is_exceeded(tmp_path):
    cfg = load_config(
        SMOKE,
        overrides={
            "output_dir": str(tmp_path / "runs"),
            "tracking": {"enabled": False},
            "training": {"epochs": 15},
            "pool": {"kinds": ["straight", "skidpad"], "durations": {"straight": 6.0, "skidpad": 12.0}},
            "design": {"initial": 2, "per_round": 2, "max_maneuvers": None, "max_sim_seconds": 70.0,
                       "setup_seconds": 5.0},
        },
    )  # fmt: skip
    result = Campaign(cfg, tmp_path / "c").run(figures=False, log_model=False)
    spent = result.history["track_seconds"].iloc[-1]
    assert spent <= 70.0
    costs = {m.name: m.duration + 5.0 for m in pool_maneuvers(cfg.pool)}
    cheapest = min(costs.values())
    assert spent > 70.0 - 2 * cheapest  # it did not stop early with room for more
    state = CampaignState.load(tmp_path / "c")
    assert state.stop_reason == "max_sim_seconds"


def test_auto_decides_from_the_warm_start_and_is_deterministic(pool_cfg, forward_model):
    maneuvers = pool_maneuvers(pool_cfg.pool)
    auto = make_strategy("auto", n_samples=32)
    cold = _pool(pool_cfg)
    assert auto.decide(History()) == "uniform"
    assert auto.select(forward_model, cold, 3, np.random.default_rng(5)) == greedy_maximin(
        cold, 3, np.random.default_rng(5)
    )
    warm = _pool(pool_cfg, prior=[m for m in maneuvers if m.throttle > 0])
    known = History(prior=True)
    assert auto.decide(known) == "integrated_variance"
    first = auto.pick(forward_model, warm, 3, np.random.default_rng(5), known)
    assert first == auto.pick(forward_model, warm, 3, np.random.default_rng(5), known)
    assert first == make_strategy("integrated_variance", n_samples=32).select(
        forward_model, warm, 3, np.random.default_rng(5)
    )
    # the guard: a model whose std ranked its recent errors the wrong way round (the mean of the last
    # three rounds that checked it) is not asked
    checks = [{"prequential_spearman": s} for s in (0.9, -0.5, float("nan"), -0.4, 0.2)]
    distrusted = History(rounds=tuple(checks), prior=True)
    assert auto.decide(distrusted) == "uniform"
    assert auto.decide(History(rounds=tuple(checks[:1] + checks[2:]), prior=True)) == "integrated_variance"
    # a dynamic model scoring candidates along its free runs seeks its largest uncertainty, guard kept
    paths = History(prior=True, scores_paths=True)
    assert auto.decide(paths) == "max_epistemic"
    assert auto.pick(forward_model, warm, 3, np.random.default_rng(5), paths) == make_strategy(
        "max_epistemic", n_samples=32
    ).select(forward_model, warm, 3, np.random.default_rng(5))
    assert auto.decide(dataclasses.replace(paths, rounds=distrusted.rounds)) == "uniform"
    assert auto.decide(History(scores_paths=True)) == "uniform"
    # the gate guard: a model that keeps none of its correction's mean is not asked; a share kept is
    assert auto.decide(paths, kept_correction=0.0) == "uniform"
    assert auto.decide(paths, kept_correction=0.5) == "max_epistemic"
    assert auto.decide(known, kept_correction=1.0) == "integrated_variance"
    gated = build_model(ModelConfig(kind="physics", n_inputs=16, history_step=3), seed=0)  # a kept share
    gated.set_correction_weight(0.0)
    assert auto.pick(gated, warm, 3, np.random.default_rng(5), paths) == make_strategy("uniform").pick(
        gated, warm, 3, np.random.default_rng(5), paths
    )
    assert auto.last_choice == "uniform"


@pytest.mark.slow
def test_auto_campaigns_are_deterministic_for_a_seed(tmp_path):
    cfg = warm_config(tmp_path, strategy="auto")
    a = Campaign(cfg, tmp_path / "a").run(figures=False, log_model=False)
    b = Campaign(cfg, tmp_path / "b").run(figures=False, log_model=False)
    assert a.state.batches == b.state.batches
    assert a.history["test_rmse"].tolist() == b.history["test_rmse"].tolist()
    # a warm start: integrated variance in every round that picked (the last round only stops)
    assert a.history["auto_model_based"].dropna().tolist() == [1.0, 1.0]


F1TENTH = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "dynamics_f1tenth.toml"


def _small_f1tenth(tmp_path: Path, name: str, **overrides):
    """dynamics_f1tenth.toml shrunk: a pool of 8-s maneuvers, two taken, one test maneuver, a short fit."""
    small = {
        "name": name, "output_dir": str(tmp_path / "runs"), "tracking": {"enabled": False},
        "pool": {"size": 2, "duration": 8.0},
        "design": {"initial": 2, "per_round": 2, "max_maneuvers": 2},
        "model": {"discrepancy": "none", "correction_gate": False},
        "training": {"epochs": 2, "rollout_horizon": 0, "warm_start": False},
        "test": {"kinds": ["skidpad"], "throttles": [0.3], "steerings": [0.08], "duration": 8.0},
    }  # fmt: skip
    for section, values in overrides.items():
        small[section] = {**small.get(section, {}), **values} if isinstance(values, dict) else values
    return load_config(F1TENTH, overrides=small)


@pytest.mark.slow
def test_a_campaign_starts_from_another_cars_model(tmp_path):
    """`[design.prior] model` of another car (`same_car = false`): the nominal car's campaign model, its
    identified scales widened by the file's widths, is the prior the twin's own logs are identified
    under; `use = "finetune"` starts the round from its correction as well. The same model as this
    car's (`same_car = true`) would be fine-tuned as is, and another vehicle's is refused there."""
    from activelearn.numerics.models.dynamic_physics import identify_scales
    from activelearn.numerics.models.dynamic_scales import dynamic_bounds

    donor_dir = tmp_path / "donor"
    Campaign(_small_f1tenth(tmp_path, "donor"), donor_dir).run(figures=False)
    donor = load_model(donor_dir / MODEL_FILE)
    scale = donor.theta_scale.double()
    prior = st.widened(st.Identified(donor.theta.double().numpy(), (scale @ scale.T).numpy()),
                       dynamic_bounds().width)  # fmt: skip
    twin = {"kind": "twin", "overrides": {"tire_friction": 0.8, "motor_gain": 0.9}}
    found = {}
    for use in ("data", "finetune"):
        section = {"model": str(donor_dir), "same_car": False, "use": use}
        cfg = _small_f1tenth(tmp_path, f"twin_{use}", oracle=twin, design={"prior": section})
        directory = tmp_path / f"twin_{use}"
        Campaign(cfg, directory).run(figures=False)
        model = load_model(directory / MODEL_FILE)
        samples = read_table(directory / "samples.parquet")
        logs = control_rate_logs([part for _, part in samples.groupby("pool_index", sort=False)])
        expected = identify_scales(logs, model.dynamic_car, 1.0 / 30.0, prior=prior)
        np.testing.assert_allclose(model.theta.numpy(), expected.values, rtol=1e-5)
        found[use] = model
    # fine-tuned from the donor's correction, the twin's ends elsewhere than the one trained from scratch
    weights = {use: torch.cat([p.flatten() for p in m.correction.parameters()]) for use, m in found.items()}
    assert not torch.allclose(weights["data"], weights["finetune"])

    nigel = load_config(SMOKE, overrides={
        "output_dir": str(tmp_path / "runs"), "tracking": {"enabled": False},
        "design": {"prior": {"model": str(donor_dir), "use": "finetune"}},
    })  # fmt: skip
    with pytest.raises(InputError, match=r"design\.prior\.model.*same_car = false"):
        Campaign(nigel, tmp_path / "nigel").run(figures=False)


def test_another_cars_model_is_checked_at_the_edge(tmp_path):
    """`same_car = false` with a model: a physics model's core is what crosses, so rows beside it, a
    residual on it or a network kind are refused, naming the field; its core alone (`use = "data"`)
    needs no rows."""
    model = str(tmp_path / "donor")

    def config(prior: dict):
        return _small_f1tenth(tmp_path, "x", design={"prior": {"model": model, "same_car": False, **prior}})

    assert config({"use": "data"}).design.prior.model == model
    with pytest.raises(ConfigError, match="not both"):
        config({"grid": PRIOR_GRID})
    with pytest.raises(ConfigError, match="not 'residual'"):
        config({"use": "residual"})
    network = {"design": {"prior": {"model": model, "same_car": False, "use": "finetune"}}}
    with pytest.raises(ConfigError, match=r"design\.prior\.model.*kind = \"physics\""):
        load_config(SMOKE, overrides=network)
