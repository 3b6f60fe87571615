"""A dynamic model's inputs along the path a control signal would drive (trajectory-aware scoring).

A static map's inputs are the controls, so a candidate maneuver is scored at its control points. A
dynamic model reads past controls AND past rates (`activelearn.numerics.lags`): the states a maneuver
visits are reached only through the dynamics. Its candidates are therefore scored at the inputs the
model itself would see while driving the maneuver: its free run (S sampled trajectories; the mean
over them is the path) fed back into its own input layout, read at evenly spaced steps. The same
serves the target region: the inputs along the test maneuvers' predicted paths.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from activelearn.errors import InputError
from activelearn.numerics.lags import model_lags
from activelearn.numerics.surrogate import simulate


def evenly_spaced_steps(length: int, n_points: int) -> np.ndarray:
    """`n_points` step indices spread over a sequence of `length` steps, both ends included."""
    if length < 1 or n_points < 1:
        raise InputError("n_points", n_points, "need a non-empty sequence and at least one point")
    return np.linspace(0, length - 1, n_points).round().astype(int)


def path_inputs(
    model,
    controls: Sequence[np.ndarray],
    n_points: int,
    *,
    rate_hz: float,
    n_samples: int = 8,
    seed: int = 0,
) -> list[np.ndarray]:
    """Per control sequence ((T, 2) at `rate_hz`): (n_points, n_inputs) model inputs along its free run.

    Static model: the controls at those steps. Dynamic model: the lagged controls as scheduled and the
    lagged rates of its mean free run from standstill (as `simulate` starts: before the first step
    the past controls are the first control and the past rates zero).
    """
    if not len(controls):
        return []
    lags = model_lags(model)
    steps = [evenly_spaced_steps(len(c), n_points) for c in controls]
    if lags is None:
        return [np.asarray(c, dtype=np.float64)[k] for c, k in zip(controls, steps, strict=True)]
    rollout = simulate(model, controls, rate_hz=rate_hz, n_samples=n_samples, seed=seed, fan_scale=1.0)
    rates = np.stack([rollout.v.mean(axis=0), rollout.w.mean(axis=0)], axis=-1)  # (M, T, 2)
    out = []
    for i, (u, k) in enumerate(zip(controls, steps, strict=True)):
        u = np.asarray(u, dtype=np.float64)
        parts = [u[np.maximum(k - back, 0)] for back in lags.control_lags]
        for back in lags.rate_lags:
            past = rates[i, np.maximum(k - back, 0)]
            past[k < back] = 0.0  # standstill before the run
            parts.append(past)
        out.append(np.concatenate(parts, axis=1))
    return out
