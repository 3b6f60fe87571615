"""Issue tests 1-3, 6 and 7: the default model's uncertainty is informative and calibrated.

All on synthetic Ackermann data (activelearn.numerics.synthetic), with the default ModelConfig and the default
KL counting. Tests 1-3 and 6 use a shorter schedule (150 epochs at lr 3e-3 instead of up to 400 at
1e-3) to keep the suite fast; test 7 uses the default TrainingConfig as is. Epistemic novelty only
appears once the posterior has contracted on the data: at lr 1e-3 it takes ~400 epochs
(experiments/investigations/model_selection.py gap: ratio ~1.8 after 150 epochs, ~3.2 after 400).
"""

from __future__ import annotations

import numpy as np
import pytest

from activelearn.config import ModelConfig, TrainingConfig
from activelearn.numerics import synthetic as syn
from activelearn.numerics.models import build_model
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from activelearn.numerics.uncertainty import coverage, epistemic_diagnostic, recalibrate_epistemic, rmse

pytestmark = pytest.mark.slow  # models trained to convergence on the calibration tasks

STEER = syn.STEER_MAX
TRAIN = TrainingConfig(epochs=150, batch_size=64, lr=3e-3, patience=None)


def _novelty_ratio(arch: str, seed: int = 0) -> np.ndarray:
    """Per-output epistemic std on reverse-throttle/right-steering inputs over the std on the data."""
    x = syn.random_points(2000, throttle=(0.2, 1.0), steering=(0.0, STEER), seed=seed)
    y = syn.observe(x, np.random.default_rng(seed + 1))  # noise grows with throttle
    model = build_model(ModelConfig(arch=arch))
    fit(model, TrainingData(x, y), TRAIN, seed=seed)
    on = syn.grid(np.linspace(0.2, 1.0, 9), np.linspace(0.0, STEER, 9))
    off = syn.grid(np.linspace(-1.0, -0.2, 9), np.linspace(-STEER, 0.0, 9))
    s_on = model.predict(on, 64).epistemic_std.mean(axis=0)
    s_off = model.predict(off, 64).epistemic_std.mean(axis=0)
    return s_off / s_on


def test_1_novelty_2d_default():
    """Test 1 (2-D): epistemic std on unseen inputs is ≥ 3x the std on the data, for each output."""
    ratio = _novelty_ratio(ModelConfig().arch)
    assert ratio.min() >= 3.0, ratio


def test_1_novelty_discriminates_the_reference_arrangement():
    """The same measurement fails for the reference hybrid (saturating first layer hides novelty)."""
    ratio = _novelty_ratio("reference")
    assert ratio.mean() < 2.0, ratio


def test_1_novelty_1d_gap_and_beyond():
    """Test 1 (1-D): std in the gap and beyond the data range is ≥ 2x the std inside the data."""
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(-1, -0.3, 500), rng.uniform(0.3, 1, 500)])[:, None]
    y = np.sin(2.5 * x) + 0.05 * rng.standard_normal(x.shape)
    model = build_model(ModelConfig(n_inputs=1, n_outputs=1))
    fit(model, TrainingData(x, y), TRAIN)
    inside = np.concatenate([np.linspace(-0.95, -0.35, 20), np.linspace(0.35, 0.95, 20)])[:, None]
    gap = np.linspace(-0.15, 0.15, 20)[:, None]
    beyond = np.concatenate([np.linspace(-1.8, -1.3, 10), np.linspace(1.3, 1.8, 10)])[:, None]
    s_in, s_gap, s_beyond = (float(model.predict(z, 64).epistemic_std.mean()) for z in (inside, gap, beyond))
    assert s_gap >= 2 * s_in, (s_gap, s_in)
    assert s_beyond >= 2 * s_in, (s_beyond, s_in)


@pytest.fixture(scope="module")
def heteroscedastic():
    """Default model trained on noisy rows spread over the whole operating box."""
    x, y = syn.uniform_rows(3000, steering=(-STEER, STEER), seed=0)
    model = build_model(ModelConfig())
    fit(model, TrainingData(x, y), TRAIN)
    return model


def test_2_aleatoric_std_tracks_true_noise(heteroscedastic):
    """Test 2: predicted aleatoric std correlates ≥ 0.9 with the true noise std (each output)."""
    pts = syn.random_points(300, steering=(-STEER, STEER), seed=10)
    pred = heteroscedastic.predict(pts, 32)
    true = syn.noise_std(pts)
    corr = [np.corrcoef(pred.aleatoric_std[:, j], true[:, j])[0, 1] for j in range(2)]
    assert min(corr) >= 0.9, corr


def test_3_coverage_on_held_out_in_distribution_data(heteroscedastic):
    """Test 3: 95% interval coverage of held-out noisy rows lies in [0.90, 0.99]."""
    x, y = syn.uniform_rows(3000, steering=(-STEER, STEER), seed=20)
    cov = coverage(y, heteroscedastic.predict(x, 32), 0.95)
    assert 0.90 <= cov <= 0.99, cov


def test_6_hybrid_accuracy_close_to_dnn_on_skidpad_data():
    """Test 6: on skidpad-like steady states the hybrid's RMSE is within 1.5x the DNN's."""
    x, y, _ = syn.repeated_rows(syn.skidpad_points(), 60, seed=0)
    test = syn.random_points(300, steering=(-STEER, STEER), seed=1)
    truth = syn.steady_state(test)
    errors = {}
    for kind in ("hybrid", "dnn"):
        model = build_model(ModelConfig(kind=kind))
        fit(model, TrainingData(x, y), TRAIN)
        errors[kind] = rmse(truth, model.predict(test, 32))
    assert errors["hybrid"] <= 1.5 * errors["dnn"], errors
    assert np.isfinite(errors["dnn"]) and errors["dnn"] > 0


def test_7_epistemic_calibration_after_recalibration():
    """Test 7: repeated noisy rows at 40 points; on held-out points z spread is in [0.5, 2]."""
    d = syn.calibration_task(0)
    model = build_model(ModelConfig())
    cfg = TrainingConfig()  # default KL counting, optimizer and early stopping
    fit(
        model,
        TrainingData(d["x"], d["y"], groups=d["groups"]),
        cfg,
        validation=TrainingData(d["val_x"], d["val_y"]),
    )
    before = epistemic_diagnostic(d["test_truth"], model.predict(d["test_points"], 64))
    scale = recalibrate_epistemic(model, d["cal_points"], d["cal_truth"], noise_free=True)
    after = epistemic_diagnostic(d["test_truth"], model.predict(d["test_points"], 64))
    assert scale > 0
    assert 0.5 <= after["z_spread"] <= 2.0, (before, scale, after)
    # the recalibration moved the spread towards 1 (by a ratio: 2 is as far off as 0.5)
    assert abs(np.log(after["z_spread"])) < abs(np.log(before["z_spread"])), (before, scale, after)
