"""Metrics against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from activelearn.numerics.models import Prediction
from activelearn.numerics.uncertainty import (
    calibration_curve,
    calibration_error,
    coverage,
    crps,
    epistemic_diagnostic,
    fit_variance_scale,
    gaussian_nll,
    rmse,
    sharpness,
    summary,
)


def _pred(mean, alea, epi=None) -> Prediction:
    mean = np.asarray(mean, float)
    alea = np.asarray(alea, float)
    epi = np.zeros_like(mean) if epi is None else np.asarray(epi, float)
    return Prediction(mean=mean, aleatoric_var=alea, epistemic_var=epi, total_var=alea + epi)


def test_rmse_per_output_and_overall():
    y = np.array([[0.0, 0.0], [1.0, 2.0]])
    p = _pred([[1.0, 0.0], [1.0, 0.0]], np.ones((2, 2)))
    np.testing.assert_allclose(rmse(y, p, per_output=True), [math.sqrt(0.5), math.sqrt(2.0)])
    assert rmse(y, p) == pytest.approx(math.sqrt(5 / 4))
    assert rmse(y, p.mean) == pytest.approx(math.sqrt(5 / 4))  # a plain mean array works too


def test_gaussian_nll_hand_values():
    y = np.array([[0.0, 1.0]])
    p = _pred([[0.0, 0.0]], [[1.0, 4.0]])
    first = 0.5 * math.log(2 * math.pi)
    second = 0.5 * (math.log(2 * math.pi * 4) + 1 / 4)
    np.testing.assert_allclose(gaussian_nll(y, p, per_output=True), [first, second])
    assert gaussian_nll(y, p) == pytest.approx((first + second) / 2)
    assert gaussian_nll(y, _pred([[0.0, 0.0]], [[0.0, 1.0]])) == math.inf  # zero variance


def test_crps_hand_values():
    # Standard normal at y = 0: 2φ(0) − 1/√π.
    expected = 2 / math.sqrt(2 * math.pi) - 1 / math.sqrt(math.pi)
    assert crps(np.zeros((1, 1)), _pred([[0.0]], [[1.0]])) == pytest.approx(expected)
    # CRPS scales with σ and reduces to |error| for a point forecast.
    assert crps(np.zeros((1, 1)), _pred([[0.0]], [[4.0]])) == pytest.approx(2 * expected)
    assert crps(np.array([[3.0]]), _pred([[1.0]], [[0.0]])) == pytest.approx(2.0)
    # y one σ away: σ (z (2Φ(z) − 1) + 2φ(z) − 1/√π) with z = 1.
    z = 1.0
    phi, cdf = math.exp(-0.5) / math.sqrt(2 * math.pi), 0.5 * (1 + math.erf(z / math.sqrt(2)))
    assert crps(np.array([[1.0]]), _pred([[0.0]], [[1.0]])) == pytest.approx(
        z * (2 * cdf - 1) + 2 * phi - 1 / math.sqrt(math.pi)
    )


def test_coverage_hand_values():
    y = np.array([[0.5], [1.5], [2.5], [-1.0]])
    p = _pred(np.zeros((4, 1)), np.ones((4, 1)))
    assert coverage(y, p, 0.95) == pytest.approx(0.75)  # |z| ≤ 1.96 for 3 of 4
    assert coverage(y, p, 0.5) == pytest.approx(0.25)  # |z| ≤ 0.674 only for 0.5
    with pytest.raises(ValueError):
        coverage(y, p, 1.5)


def test_calibration_error_hand_values():
    p = _pred(np.zeros((4, 1)), np.ones((4, 1)))
    # Every error is 0: every central interval covers everything, observed = 1 at each level.
    levels, observed = calibration_curve(np.zeros((4, 1)), p)
    np.testing.assert_allclose(observed, 1.0)
    assert calibration_error(np.zeros((4, 1)), p) == pytest.approx(np.mean(1 - levels))
    # Large calibrated sample: close to 0.
    rng = np.random.default_rng(0)
    n = 20000
    big = _pred(np.zeros((n, 1)), np.ones((n, 1)))
    assert calibration_error(rng.standard_normal((n, 1)), big) < 0.01
    # Overconfident by 2x: well above 0.
    assert calibration_error(2 * rng.standard_normal((n, 1)), big) > 0.15


def test_sharpness_is_mean_total_std():
    p = _pred(np.zeros((2, 2)), [[1.0, 4.0], [9.0, 16.0]])
    assert sharpness(p) == pytest.approx(2.5)
    np.testing.assert_allclose(sharpness(p, per_output=True), [2.0, 3.0])


def test_epistemic_diagnostic_hand_values():
    truth = np.zeros((4, 1))
    err = np.array([[1.0], [-1.0], [2.0], [-2.0]])
    std = np.array([[1.0], [1.0], [2.0], [2.0]])
    d = epistemic_diagnostic(truth, _pred(err, np.zeros((4, 1)), std**2))
    assert d["z_spread"] == pytest.approx(1.0)  # z = ±1
    assert d["spearman"] == pytest.approx(1.0)  # larger std ↔ larger |error|
    assert d["std_to_rmse"] == pytest.approx(1.5 / math.sqrt(10 / 4))
    # Overconfident by 5x: z spread 5, ratio 1/5 of the above.
    d5 = epistemic_diagnostic(truth, _pred(err, np.zeros((4, 1)), (std / 5) ** 2))
    assert d5["z_spread"] == pytest.approx(5.0)
    assert d5["std_to_rmse"] == pytest.approx(d["std_to_rmse"] / 5)


def test_fit_variance_scale():
    err = np.array([2.0, -2.0, 4.0])
    epi = np.array([1.0, 1.0, 4.0])
    assert fit_variance_scale(err, epi) == pytest.approx(4.0)  # mean(err²/epi)
    # With noise: the MLE solves the likelihood; check it against a brute-force grid.
    rng = np.random.default_rng(0)
    epi = rng.uniform(0.5, 2.0, 500)
    noise = np.full(500, 0.5)
    err = rng.standard_normal(500) * np.sqrt(3.0 * epi + noise)
    c = fit_variance_scale(err, epi, noise)
    grid = np.linspace(0.5, 8, 2000)
    ll = [-np.sum(np.log(g * epi + noise) + err**2 / (g * epi + noise)) for g in grid]
    assert c == pytest.approx(grid[int(np.argmax(ll))], rel=0.01)
    assert 2.0 < c < 4.5


def test_summary_has_every_metric():
    p = _pred(np.zeros((3, 2)), np.ones((3, 2)))
    s = summary(np.zeros((3, 2)), p)
    assert set(s) == {"rmse", "nll", "crps", "coverage95", "calibration_error", "sharpness"}
    assert s["rmse"] == 0.0 and s["coverage95"] == 1.0
