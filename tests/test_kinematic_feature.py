"""The kinematic feature (`[model] kinematic_feature`): a speed times tan(steering), derived inside the
model, so every path that evaluates it (training, multi-step windows, predict, the compiled kernel,
static and sequential rollouts, save/load, a campaign) sees the same network inputs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch
from pydantic import ValidationError

import simulator
from activelearn.config import DataConfig, ModelConfig, TrainingConfig
from activelearn.loop.campaign import Campaign, load_campaign_model
from activelearn.loop.collection import arrays, training_rows, training_windows
from activelearn.names import ROLLOUT_METRICS
from activelearn.numerics.lags import Lags
from activelearn.numerics.models import build_model, load_model, save_model
from activelearn.numerics.surrogate import simulate
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from simulator import Maneuver
from tests.test_dynamics import _dynamic_config

RNG = np.random.default_rng(7)


def _with_scalers(model, n_inputs: int):
    x = RNG.normal(size=(400, n_inputs)) * 0.3
    model.set_scalers(x, RNG.normal(size=(400, 2)))
    return model


@pytest.mark.parametrize(("lags", "speed_column"), [(None, "throttle"), (Lags(1, 1), "speed_lag1"),
                                                    (Lags(3, 2), "speed_lag2")])  # fmt: skip
def test_the_feature_is_the_newest_speed_times_tan_steering(lags, speed_column):
    n_inputs = 2 if lags is None else lags.n_inputs
    columns = ["throttle", "steering"] if lags is None else lags.columns()
    model = build_model(ModelConfig(n_inputs=n_inputs, history_step=1 if lags is None else lags.step,
                                    kinematic_feature=True))  # fmt: skip
    x = torch.as_tensor(RNG.uniform(-0.5, 0.5, size=(50, n_inputs)), dtype=torch.float32)
    rows = model.expand_inputs(x)
    assert rows.shape == (50, n_inputs + 1)
    torch.testing.assert_close(rows[:, :n_inputs], x)
    expected = x[:, columns.index(speed_column)] * torch.tan(x[:, columns.index("steering")])
    torch.testing.assert_close(rows[:, -1], expected)
    # the column layout (d, N) and a batch of draws (S, d, N) derive the same feature
    torch.testing.assert_close(model.expand_inputs(x.t(), dim=-2), rows.t())
    torch.testing.assert_close(model.expand_inputs(x.t()[None].repeat(3, 1, 1), dim=-2)[1], rows.t())
    # the scalers and the network's first layer span it
    assert model.x_mean.shape == (n_inputs + 1,)
    assert build_model(ModelConfig(n_inputs=n_inputs)).x_mean.shape == (n_inputs,)


@pytest.mark.parametrize("n_inputs", [2, 4])
@pytest.mark.parametrize("kind", ["hybrid", "ensemble"])
def test_compiled_and_reference_paths_agree_with_the_feature(n_inputs, kind, c_kernels):
    config = ModelConfig(n_inputs=n_inputs, kind=kind, kinematic_feature=True)
    model = _with_scalers(build_model(config), n_inputs)
    x = RNG.normal(size=(64, n_inputs)) * 0.3
    native, reference = (model.predict(x, backend=b) for b in ("native", "reference"))
    np.testing.assert_allclose(native.mean, reference.mean, atol=1e-5)
    np.testing.assert_allclose(native.epistemic_var, reference.epistemic_var, atol=1e-6)
    controls = [np.column_stack([np.full(90, 0.6), np.linspace(-0.4, 0.4, 90)])]
    start = np.array([[0.1, 0.0]])
    runs = [simulate(model, controls, rate_hz=30.0, n_samples=4, backend=b, initial_rates=start)
            for b in ("native", "reference")]  # fmt: skip
    np.testing.assert_allclose(runs[0].x, runs[1].x, atol=1e-5)
    np.testing.assert_allclose(runs[0].mean_rates, runs[1].mean_rates, atol=1e-5)


def test_save_and_load_keep_the_feature(tmp_path):
    model = _with_scalers(build_model(ModelConfig(n_inputs=4, kinematic_feature=True), seed=2), 4)
    save_model(model, tmp_path / "model.pt")
    loaded = load_model(tmp_path / "model.pt")
    assert loaded.config.kinematic_feature and loaded.n_derived == 1
    x = RNG.normal(size=(20, 4)) * 0.3
    np.testing.assert_array_equal(loaded.predict(x).mean, model.predict(x).mean)


def test_recurrent_models_refuse_the_feature():
    with pytest.raises(ValidationError, match="kinematic_feature"):
        ModelConfig(kind="recurrent", n_inputs=8, kinematic_feature=True)


def test_markov_training_with_windows_uses_the_feature():
    log = simulator.collect([Maneuver("slalom", 0.7, 0.4, "ccw", 6.0)], seed=3)
    data = DataConfig(stride=2, skip_seconds=0.0, inputs="controls+rates")
    rows = pd.concat([training_rows(part, data) for _, part in log.groupby("run_id", sort=False)])
    x, y = arrays(rows, data)
    windows = training_windows([log], data, horizon=5)
    fitted = {}
    for feature in (False, True):
        model = build_model(ModelConfig(n_inputs=4, kinematic_feature=feature), seed=0)
        fit(
            model,
            TrainingData(x, y, windows=windows),
            TrainingConfig(epochs=3, patience=None, rollout_horizon=5),
            seed=0,
        )
        fitted[feature] = model.predict(x[:100]).mean
        assert np.isfinite(fitted[feature]).all()
    assert not np.allclose(fitted[False], fitted[True])


def test_a_trained_static_map_reads_its_yaw_rate_off_the_feature():
    """Not just a wider input: trained on skidpads, the network's yaw rate hangs on the feature column.
    Held at its mean while the raw controls stay as they are, the yaw-rate error grows manifold."""
    maneuvers = [Maneuver("skidpad", throttle, steering, direction, 6.0) for throttle in (0.3, 0.6, 0.9)
                 for steering in (0.15, 0.3, 0.45) for direction in ("ccw", "cw")]  # fmt: skip
    log = simulator.collect(maneuvers, seed=3)
    data = DataConfig(stride=3, skip_seconds=2.0)
    samples = pd.concat([training_rows(part, data) for _, part in log.groupby("run_id", sort=False)])
    x, y = arrays(samples, data)
    model = build_model(ModelConfig(n_inputs=2, kinematic_feature=True), seed=0)
    fit(model, TrainingData(x, y), TrainingConfig(epochs=20, patience=None), seed=0)
    params, n = model.mean_params()

    def network(rows: torch.Tensor) -> np.ndarray:  # the forward path on expanded rows, physical units
        means, _ = model.sampled_forward((rows - model.x_mean) / model.x_std, params, n)
        return (means.mean(dim=0) * model.y_std + model.y_mean).numpy()

    with torch.no_grad():
        xt = torch.tensor(x, dtype=torch.float32)
        rows = model.expand_inputs(xt)
        intact = network(rows)
        np.testing.assert_array_equal(intact, model(xt)[:, :2].numpy())  # the path `forward` takes
        held = rows.clone()
        held[:, -1] = model.x_mean[-1]  # the feature at its mean; the throttle and steering as they are
        ablated = network(held)
    torch.testing.assert_close(held[:, :2], rows[:, :2])
    error = {name: float(np.sqrt(np.mean((out[:, 1] - y[:, 1]) ** 2))) for name, out in
             (("intact", intact), ("ablated", ablated))}  # fmt: skip
    assert error["ablated"] > 5 * error["intact"], error
    assert error["ablated"] > 0.25 * y[:, 1].std(), error  # a sizeable share of the yaw rate's spread


@pytest.mark.slow
def test_a_dynamic_campaign_trains_scores_and_rolls_out_with_the_feature(tmp_path):
    cfg = _dynamic_config(tmp_path, model={"kinematic_feature": True})
    result = Campaign(cfg, tmp_path / "c").run(figures=False)
    assert len(result.state.rounds) == 3
    for record in result.state.rounds:
        for name in (*ROLLOUT_METRICS, "test_rmse"):
            assert np.isfinite(record[name]), name
    model = load_campaign_model(tmp_path / "c")
    assert model.config.kinematic_feature and model.x_mean.shape == (cfg.model.n_inputs + 1,)
