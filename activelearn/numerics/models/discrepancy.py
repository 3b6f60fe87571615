"""The physics kind's model discrepancy: what its identified core still misses of the logs, carried in the
fans (`[model] discrepancy`).

The identification measures the core's rms misfit of its logs (v, r), in sample or cross-validated, on free
runs restarted from the logged rates every `CORRELATION_TIME` s. Each free-run draw's rates then carry an
Ornstein-Uhlenbeck error of about that size and correlation time (`discrepancy_paths`), its size drawn per
draw from the misfit's posterior (`discrepancy_sizes`), and the pose fan is widened by it about the core's
own mean path (`widened_pose`): the discrepancy widens the fan, not the path. Both cores use it.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.signal import lfilter
from torch import Tensor

from activelearn.numerics.counter_noise import step_noise
from activelearn.numerics.pose import integrate_pose

CORRELATION_TIME = 3.0  # s: the misfit's free runs restart from the logged rates this often
DISCREPANCY_KEY_BIT = 1 << 63  # the discrepancy's noise keys: the draws' (below 2^62) with it set
DISCREPANCY_SIZE_STREAM = 56  # the draws' discrepancy sizes' random stream, beside the free run's seed


def discrepancy_paths(
    size: np.ndarray, keys: list[int], n_maneuvers: int, n_steps: int, dt: float
) -> tuple[Tensor, Tensor]:
    """Each draw's model discrepancy of (v, r) along a free run, (S, M, T) each, S = len(keys): an
    Ornstein-Uhlenbeck process from zero (a run starts at the recorded rates, as the misfit's restarts
    do), its stationary size `size` ((2,), or (S, 2) a draw), its correlation time `CORRELATION_TIME`.
    Its normals are `counter_noise`'s under each draw's noise key with `DISCREPANCY_KEY_BIT` set, a stream
    of their own that dynamic_rollout.c draws alike."""
    keep = math.exp(-dt / CORRELATION_TIME)
    draws = [np.stack(step_noise(key | DISCREPANCY_KEY_BIT, n_maneuvers, n_steps)) for key in keys]
    shocks = np.stack(draws, axis=1).astype(np.float64)  # (2, S, M, T)
    shocks[..., 0] = 0.0
    paths = lfilter([math.sqrt(1.0 - keep**2)], [1.0, -keep], shocks, axis=-1)
    paths *= np.broadcast_to(np.asarray(size, np.float64), (len(keys), 2)).T[:, :, None, None]
    return torch.as_tensor(paths[0], dtype=torch.float32), torch.as_tensor(paths[1], dtype=torch.float32)


def discrepancy_sizes(misfit: np.ndarray, n_logs: float, n_samples: int, seed: int) -> np.ndarray:
    """(S, 2) each draw's discrepancy size (v, r): the measured misfit ŝ times √(n / X), X ~ χ²(n), n the
    logs it was measured on (each a cluster). That is the posterior of an rms size measured on n
    clusters under a Jeffreys prior, so the fan is the Student-t marginal over the size, not the
    Gaussian at ŝ: after 4 logs one draw in 4.5 is half again as large. n unknown (0): ŝ for every
    draw."""
    size = np.broadcast_to(np.asarray(misfit, np.float64), (n_samples, 2))
    if n_logs <= 0.0:
        return size.copy()
    chi2 = np.random.default_rng((seed, DISCREPANCY_SIZE_STREAM)).chisquare(n_logs, n_samples)
    return size * np.sqrt(n_logs / chi2)[:, None]


def widened_pose(
    pose: tuple[Tensor, ...], rates: tuple[Tensor, Tensor], frame: tuple, sizes: np.ndarray, keys: list[int]
) -> tuple[Tensor, ...]:
    """The pose fan (x, y, ψ) of draws whose rates (v, r), each (S, M, T), carry the model discrepancy
    (`discrepancy_paths` of `sizes`), moved onto the mean path of `pose`, the fan of the same rates
    without it. `frame` = (dt, headings (M, 1), lever arm, the rear axle's lateral speed or None)."""
    dt, yaw0, arm, lateral = frame
    v, w = rates
    dv, dw = discrepancy_paths(sizes, keys, *v.shape[1:], dt)
    wide = integrate_pose(v + dv, w + dw, dt, yaw0, lever_arm=arm, lateral=lateral)
    return tuple(part - part.mean(dim=0) + path.mean(dim=0) for part, path in zip(wide, pose, strict=True))
