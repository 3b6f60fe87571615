"""Predictive-uncertainty metrics, the epistemic calibration diagnostic, and its recalibration.

Metrics are plain numpy functions of (y, Prediction) in physical units, with y of shape N × n_outputs.
Variances used for NLL, CRPS, coverage, calibration and sharpness are the total predictive variance.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy import optimize, stats

if TYPE_CHECKING:
    from activelearn.numerics.models.base import Model, Prediction

_LEVELS = np.round(np.arange(0.05, 0.951, 0.05), 2)


def _mean_of(pred: Prediction | np.ndarray) -> np.ndarray:
    return np.asarray(pred if isinstance(pred, np.ndarray) else pred.mean, dtype=float)


def _check(y: np.ndarray, mean: np.ndarray) -> np.ndarray:
    y = np.asarray(y, dtype=float)
    if y.shape != mean.shape:
        raise ValueError(f"y has shape {y.shape} but the prediction has {mean.shape}")
    return y


def rmse(y: np.ndarray, pred: Prediction | np.ndarray, *, per_output: bool = False) -> float | np.ndarray:
    """Root-mean-square error of the predictive mean: overall (float) or per output (array)."""
    mean = _mean_of(pred)
    sq = (_check(y, mean) - mean) ** 2
    return np.sqrt(sq.mean(axis=0)) if per_output else float(np.sqrt(sq.mean()))


def gaussian_nll(y: np.ndarray, pred: Prediction, *, per_output: bool = False) -> float | np.ndarray:
    """Mean Gaussian negative log-likelihood of y under N(mean, total_var); inf where the var is 0."""
    y = _check(y, pred.mean)
    var = np.asarray(pred.total_var, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        nll = 0.5 * (np.log(2 * np.pi * var) + (y - pred.mean) ** 2 / var)
    nll = np.where(var > 0, nll, np.inf)
    return nll.mean(axis=0) if per_output else float(nll.mean())


def crps(y: np.ndarray, pred: Prediction, *, per_output: bool = False) -> float | np.ndarray:
    """Mean closed-form CRPS of a Gaussian predictive distribution (|error| where the std is 0)."""
    y = _check(y, pred.mean)
    sigma = np.sqrt(np.asarray(pred.total_var, dtype=float))
    err = y - pred.mean
    with np.errstate(divide="ignore", invalid="ignore"):
        z = err / sigma
        val = sigma * (z * (2 * stats.norm.cdf(z) - 1) + 2 * stats.norm.pdf(z) - 1 / np.sqrt(np.pi))
    val = np.where(sigma > 0, val, np.abs(err))
    return val.mean(axis=0) if per_output else float(val.mean())


def coverage(
    y: np.ndarray, pred: Prediction, level: float = 0.95, *, per_output: bool = False
) -> float | np.ndarray:
    """Fraction of y inside the central `level` interval of N(mean, total_var)."""
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level!r}")
    y = _check(y, pred.mean)
    half = stats.norm.ppf(0.5 + level / 2) * np.sqrt(np.asarray(pred.total_var, dtype=float))
    inside = np.abs(y - pred.mean) <= half
    return inside.mean(axis=0) if per_output else float(inside.mean())


def calibration_curve(
    y: np.ndarray, pred: Prediction, levels: np.ndarray = _LEVELS
) -> tuple[np.ndarray, np.ndarray]:
    """Expected and observed central-interval coverage at each level (default 0.05 … 0.95)."""
    levels = np.asarray(levels, dtype=float)
    observed = np.array([coverage(y, pred, float(lv)) for lv in levels])
    return levels, observed


def calibration_error(y: np.ndarray, pred: Prediction, levels: np.ndarray = _LEVELS) -> float:
    """Mean |observed − expected| central-interval coverage over levels 0.05 … 0.95."""
    expected, observed = calibration_curve(y, pred, levels)
    return float(np.mean(np.abs(observed - expected)))


def sharpness(pred: Prediction, *, per_output: bool = False) -> float | np.ndarray:
    """Mean predictive (total) std: smaller is sharper."""
    std = np.sqrt(np.asarray(pred.total_var, dtype=float))
    return std.mean(axis=0) if per_output else float(std.mean())


def epistemic_diagnostic(truth: np.ndarray, pred: Prediction) -> dict[str, float | tuple[float, ...]]:
    """How well the epistemic std explains the error of the mean against noise-free truth.

    Returns a dict with
    - z_spread: std of z = (mean − truth) / epistemic std, pooled over outputs (1 = calibrated,
      > 1 overconfident);
    - spearman: rank correlation of the epistemic std with |error| (mean over outputs);
    - std_to_rmse: mean epistemic std / RMSE (mean over outputs; < 1 overconfident);
    - rmse, mean_std: the two sides of that ratio pooled over outputs;
    - spearman_per_output, std_to_rmse_per_output: tuples, one value per output.
    """
    truth = _check(truth, pred.mean)
    err = pred.mean - truth
    std = np.sqrt(np.asarray(pred.epistemic_var, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = err / std
    z = z[np.isfinite(z)]
    rho, ratio = [], []
    for j in range(truth.shape[1]):
        r = stats.spearmanr(std[:, j], np.abs(err[:, j])).statistic if np.ptp(std[:, j]) > 0 else np.nan
        rho.append(float(r))
        out_rmse = float(np.sqrt(np.mean(err[:, j] ** 2)))
        ratio.append(float(std[:, j].mean() / out_rmse) if out_rmse > 0 else float("inf"))
    return {
        "z_spread": float(np.std(z)) if z.size else float("inf"),
        "spearman": float(np.nanmean(rho)) if not np.all(np.isnan(rho)) else float("nan"),
        "std_to_rmse": float(np.mean(ratio)),
        "rmse": float(np.sqrt(np.mean(err**2))),
        "mean_std": float(std.mean()),
        "spearman_per_output": tuple(rho),
        "std_to_rmse_per_output": tuple(ratio),
    }


def fit_variance_scale(
    err: np.ndarray, epistemic_var: np.ndarray, noise_var: np.ndarray | None = None
) -> float:
    """Maximum-likelihood c in err ~ N(0, c · epistemic_var + noise_var) (closed form when no noise)."""
    err = np.asarray(err, dtype=float).ravel()
    epi = np.maximum(np.asarray(epistemic_var, dtype=float).ravel(), 1e-30)
    if noise_var is None:
        return float(np.mean(err**2 / epi))
    noise = np.asarray(noise_var, dtype=float).ravel()

    def nll(log_c: float) -> float:
        var = np.exp(log_c) * epi + noise
        return float(np.sum(np.log(var) + err**2 / var))

    res = optimize.minimize_scalar(nll, bounds=(-20.0, 20.0), method="bounded")
    return float(np.exp(res.x))


def recalibrate_epistemic(
    model: Model,
    x: np.ndarray,
    y: np.ndarray,
    *,
    groups: np.ndarray | None = None,
    noise_free: bool = False,
    n_samples: int = 64,
    seed: int = 0,
) -> float:
    """Fit `model.epistemic_scale` on held-out operating points; store it and return it.

    The scale c multiplies the epistemic variance (predict) and widens sample deviations by √c (draw).
    y are noise-free targets (`noise_free=True`) or noisy rows; with `groups` (operating-point ids)
    rows are averaged per group first, so the noise left in each target is aleatoric var / rows.
    """
    import torch

    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    counts = np.ones(len(x))
    if groups is not None:
        groups = np.asarray(groups)
        _, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
        x = np.stack([np.bincount(inverse, weights=x[:, j]) for j in range(x.shape[1])], 1) / counts[:, None]
        y = np.stack([np.bincount(inverse, weights=y[:, j]) for j in range(y.shape[1])], 1) / counts[:, None]
    with torch.no_grad():
        model.epistemic_scale.fill_(1.0)
    pred = model.predict(x, n_samples, seed=seed)
    noise = None if noise_free else pred.aleatoric_var / counts[:, None]
    scale = fit_variance_scale(pred.mean - y, pred.epistemic_var, noise)
    if not np.isfinite(scale) or scale <= 0:
        scale = 1.0
    with torch.no_grad():
        model.epistemic_scale.fill_(scale)
    return scale


def summary(y: np.ndarray, pred: Prediction) -> dict[str, float]:
    """Every scalar metric at once, keyed by name (for logging and tables)."""
    return {
        "rmse": rmse(y, pred),  # type: ignore[dict-item]
        "nll": gaussian_nll(y, pred),  # type: ignore[dict-item]
        "crps": crps(y, pred),  # type: ignore[dict-item]
        "coverage95": coverage(y, pred, 0.95),  # type: ignore[dict-item]
        "calibration_error": calibration_error(y, pred),
        "sharpness": sharpness(pred),  # type: ignore[dict-item]
    }
