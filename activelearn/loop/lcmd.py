"""LCMD (largest cluster maximum distance), run by bmdal-reg itself on features of the model's predictions.

Holzmüller, Zaverkin, Kästner & Steinwart, "A Framework and Benchmark for Deep Batch Active Learning
for Regression" (JMLR 24(164), 2023), whose library `bmdal_reg` this calls (`select_batch` with
`selection_method="lcmd"`, in TP-mode: `sel_with_train=True`, so the collected maneuvers count as
the training set). LCMD assigns every open candidate to its nearest centre among the collected
maneuvers and the batch's earlier picks, finds the cluster with the largest sum of squared distances
to its centre, and picks that cluster's member farthest from its centre; it repeats for the batch.

The kernel is bmdal-reg's `linear` base kernel (no transformations) on one feature vector per
candidate, so its distances are Euclidean distances between these vectors:

* the candidate's *predicted rate trajectory*: the posterior-mean v and ω at its scoring points
  (along its controls, or along its own free run with `dynamic_points = "path"`), standardised by
  `Pool.output_scale` and resampled to 32 steps of relative time (`predicted_trajectories`, as `igs`
  compares maneuvers), divided by √(steps × outputs) so that its squared distance is the mean squared
  difference between two trajectories (igs's d_y squared);
* the candidate's coordinates in the pool (`Pool.features`: operating point or family parameters in
  [0, 1]^d, maximin's d_x), and, when the pool mixes kinds, a one-hot kind scaled so two kinds lie
  `Pool.kind_distance` apart.

Why these features and not the paper's network kernels (`grad`, `ll`): those read an `nn.Sequential`
of `nn.Linear` layers, and the models here are Bayesian layer stacks, recurrent trunks, physics
models and residual corrections with no common last hidden layer. What every model has is `draw`,
its posterior functions; their mean along each maneuver is the model's view of that maneuver, and it
is path-averaged over the maneuver's scoring points as the other model-based strategies' scores are.
The coordinates keep two maneuvers the model predicts alike but that drive elsewhere apart (the
space-filling half of the comparison, as in igs), so LCMD in this space spreads over both the
operating domain and the predicted behaviour.

With nothing collected yet LCMD has no centres: greedy maximin picks (as `igs` does). A warm start's
prior maneuvers have no scoring points in the pool, so they are no centres either. Deterministic
given the round's rng (it seeds the posterior draws, and torch's generator for bmdal-reg's random
fill-up should its selection fail).

`bmdal_reg` is installed without its dependencies (`pip install --no-deps bmdal_reg==3.0.2 dill==0.4.1`,
the Makefile's set-up step): the selection code needs torch, numpy and dill only, its install_requires
add openml, seaborn, mat4py and more for its benchmark. Its 3.0.2 still reads `np.Inf`, which NumPy 2
removed: `_bmdal` gives its selection module a numpy that has it, leaving numpy itself alone.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from activelearn.errors import InputError
from activelearn.loop.greedy_sampling import TrajectoryStrategy, predicted_trajectories
from activelearn.loop.space_filling import greedy_maximin
from activelearn.loop.strategy import Pool, check_k

BMDAL_INSTALL = "pip install --no-deps bmdal_reg==3.0.2 dill==0.4.1"


class _NumpyWithInf(types.ModuleType):
    """numpy, plus the `np.Inf` alias NumPy 2 removed (given to bmdal-reg's selection module only)."""

    Inf = np.inf

    def __getattr__(self, name: str) -> Any:
        return getattr(np, name)


def _bmdal() -> tuple[Callable[..., Any], type]:
    """bmdal-reg's `select_batch` and `TensorFeatureData`, its selection module made NumPy-2-safe."""
    try:
        from bmdal_reg.bmdal import selection
        from bmdal_reg.bmdal.algorithms import select_batch
        from bmdal_reg.bmdal.feature_data import TensorFeatureData
    except ImportError as err:
        raise InputError("strategy", "lcmd", f"needs bmdal_reg ({BMDAL_INSTALL}): {err}") from err
    if not hasattr(selection.np, "Inf"):  # NumPy >= 2 removed the alias bmdal_reg 3.0.2 still uses
        selection.np = _NumpyWithInf("numpy")
    return select_batch, TensorFeatureData


def lcmd_features(model: Any, pool: Pool, n_samples: int, seed: int) -> np.ndarray:
    """(n, d) per candidate: its scaled predicted rate trajectory, its pool coordinates and kind."""
    trajectories = predicted_trajectories(model, pool, n_samples, seed)  # (n, steps, outputs)
    n, steps, outputs = trajectories.shape
    parts = [trajectories.reshape(n, steps * outputs) / np.sqrt(steps * outputs), pool.features]
    kinds = np.unique(pool.kinds)
    if len(kinds) > 1:  # one-hot rows lie √2 apart: scaled, two kinds lie kind_distance apart
        parts.append((pool.kinds[:, None] == kinds[None, :]) * (pool.kind_distance / np.sqrt(2.0)))
    return np.hstack(parts).astype(np.float64)


class LcmdStrategy(TrajectoryStrategy):
    """`lcmd`: bmdal-reg's LCMD in TP-mode, linear kernel on predicted trajectories and coordinates."""

    name = "lcmd"

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        open_ = check_k(pool, k)
        collected = np.flatnonzero(pool.taken)
        if not len(collected):  # no training set, no centres: the space-filling half alone
            return greedy_maximin(pool, k, rng)
        seed = int(rng.integers(2**31 - 1))
        features = torch.from_numpy(lcmd_features(model, pool, self.n_samples, seed))
        select_batch, tensor_data = _bmdal()
        data = {"train": tensor_data(features[collected]), "pool": tensor_data(features[open_])}
        with torch.random.fork_rng(devices=[]):  # bmdal-reg's fill-up draws from torch's generator
            torch.manual_seed(seed)
            picks, _ = select_batch(
                batch_size=k,
                models=[torch.nn.Identity()],  # the linear kernel reads no network: one kernel, one entry
                data=data,
                y_train=None,
                base_kernel="linear",
                kernel_transforms=[],
                selection_method="lcmd",
                sel_with_train=True,
                verbosity=0,
            )
        return [int(open_[i]) for i in picks.tolist()]
