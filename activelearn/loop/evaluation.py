"""How good a round's model is: the fixed test set, the uncertainty grid, free runs, prequential checks.

`evaluate` is what every round logs. The prequential checks meet the model of the last round with the
maneuvers collected after it, maneuvers it never saw: an honest calibration check, and the scales a
campaign may apply to the next round (`[design] recalibrate`, `fan_calibration`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pandas as pd
import torch

from activelearn.config import CampaignConfig
from activelearn.loop.collection import TestSet, noise_config
from activelearn.loop.oracles import Oracle
from activelearn.loop.pool import evaluation_grid
from activelearn.loop.state import CampaignState
from activelearn.loop.strategy import Pool
from activelearn.names import (
    ALEATORIC_STD_MEAN,
    CALIB_PREFIX,
    COVERAGE_95,
    EPISTEMIC_STD_MAX,
    EPISTEMIC_STD_MEAN,
    N_MANEUVERS,
    PREQUENTIAL_FAN_SCALE,
    PREQUENTIAL_POINTS,
    PREQUENTIAL_SCALE,
    PREQUENTIAL_SPEARMAN,
    ROLLOUT_SECONDS,
    TEST_CRPS,
    TEST_NLL,
    TEST_RMSE,
    TEST_RMSE_V,
    TEST_RMSE_W,
)
from activelearn.numerics import uncertainty
from activelearn.numerics.diagnostics import fan_scale_needed, free_run_metrics
from activelearn.numerics.models import Prediction
from activelearn.numerics.surrogate import model_inputs
from activelearn.numerics.uncertainty import recalibrate_epistemic

EVAL_SAMPLES = 64  # posterior draws for test metrics and uncertainty maps
FAN_SAMPLES = 32  # trajectories of a prequential fan check when the test set runs no free runs

Rows = Callable[[pd.DataFrame], tuple[np.ndarray, np.ndarray, np.ndarray]]


def standardise(pred: Prediction, scale: np.ndarray) -> Prediction:
    """A prediction in standardised units (each output divided by its scale), so v and ω weigh alike."""
    return dataclasses.replace(
        pred,
        mean=pred.mean / scale,
        aleatoric_var=pred.aleatoric_var / scale**2,
        epistemic_var=pred.epistemic_var / scale**2,
        total_var=pred.total_var / scale**2,
    )


def applied_scale(state: CampaignState, key: str = PREQUENTIAL_SCALE, recent: int | None = 2) -> float:
    """Geometric mean of the last `recent` prequential scales under `key` (None: of every one so far;
    1 before any was measured).

    The epistemic scale keeps the last two: a static model trained on few maneuvers errs far more
    between its points than one trained on many, so old scales would inflate later models' variance.
    The fan scale takes every round (`recent=None`): it is a ratio of free-run error to the
    posterior's spread, and both shrink together (the test set's own need stayed 1.8-2.4 from round 1
    to 6 on `dynamics`), while each need comes from a batch of 2-4 maneuvers and swings 1-4x; the last
    two alone left the last round's fans 0.994 wide (experiments/results/physics.txt).
    """
    scales = [r[key] for r in state.rounds if np.isfinite(r.get(key, np.nan))]
    scales = scales if recent is None else scales[-recent:]
    return float(np.exp(np.mean(np.log(scales)))) if scales else 1.0


# A fan is narrowed (a scale below 1) only once the needs come from this many maneuvers. A first need
# from 2 easy signals trimmed the full-size car's fans 2-10x (0.66 of the true positions after 6
# signals; at the model's own scale 0.86); widening is never held back (docs/results/vehicles.md,
# "The first rounds' fans").
MIN_TRIM_MANEUVERS = 6


def calibrated_maneuvers(state: CampaignState, key: str = PREQUENTIAL_FAN_SCALE) -> int:
    """How many maneuvers the needs under `key` so far were measured on: round j's need on the batch
    collected after it (the next round's maneuvers less its own; the last, those taken since)."""
    counts = [r[N_MANEUVERS] for r in state.rounds] + [len(state.taken)]
    return sum(
        counts[j + 1] - counts[j] for j, r in enumerate(state.rounds) if np.isfinite(r.get(key, np.nan))
    )


def applied_fan_scale(state: CampaignState) -> float:
    """The next model's fan scale: the geometric mean of every need so far (`applied_scale`), but not
    below 1 until `MIN_TRIM_MANEUVERS` maneuvers have been measured (the model's own fans until then)."""
    scale = applied_scale(state, PREQUENTIAL_FAN_SCALE, recent=None)
    return scale if scale >= 1.0 or calibrated_maneuvers(state) >= MIN_TRIM_MANEUVERS else 1.0


class Evaluation:
    """Scores a campaign's models on its fixed test set and on the maneuvers collected after them.

    `rows` turns collected logs into training rows (inputs, targets, pool index), as the fit does.
    """

    def __init__(self, cfg: CampaignConfig, oracle: Oracle, maneuvers: Sequence[Any], rows: Rows) -> None:
        self.cfg = cfg
        self.oracle = oracle
        self.maneuvers = maneuvers
        self.rows = rows

    @property
    def test_set(self) -> TestSet:
        """The fixed test set (simulated once per config and cached, or recorded logs)."""
        return self.oracle.test_set()

    def evaluate(self, model: Any, *, rollouts: bool = True) -> dict[str, float]:
        """Test-set accuracy and calibration, uncertainty over the evaluation grid, and (`rollouts`)
        the free runs of the test maneuvers."""
        test = self.test_set
        pred = model.predict(test.x, n_samples=EVAL_SAMPLES, seed=0)
        std_pred = standardise(pred, test.scale)
        clean, noisy = test.y_clean / test.scale, test.y_noisy / test.scale
        err = pred.mean - test.y_clean
        metrics = {
            TEST_RMSE: float(np.sqrt(np.mean((std_pred.mean - clean) ** 2))),
            TEST_RMSE_V: float(np.sqrt(np.mean(err[:, 0] ** 2))),  # m/s
            TEST_RMSE_W: float(np.sqrt(np.mean(err[:, 1] ** 2))),  # rad/s
            TEST_NLL: float(uncertainty.gaussian_nll(noisy, std_pred)),
            TEST_CRPS: float(uncertainty.crps(noisy, std_pred)),
            COVERAGE_95: float(uncertainty.coverage(noisy, std_pred, level=0.95)),
        }
        diag = uncertainty.epistemic_diagnostic(clean, std_pred)
        metrics.update({f"{CALIB_PREFIX}{k}": float(v) for k, v in diag.items() if np.isscalar(v)})
        _, _, grid = evaluation_grid(self.cfg, self.maneuvers)
        grid_pred = standardise(
            model.predict(model_inputs(model, grid), n_samples=EVAL_SAMPLES, seed=0), test.scale
        )
        epi = np.sqrt(grid_pred.epistemic_var).mean(axis=1)
        metrics[EPISTEMIC_STD_MEAN] = float(epi.mean())
        metrics[EPISTEMIC_STD_MAX] = float(epi.max())
        metrics[ALEATORIC_STD_MEAN] = float(np.sqrt(grid_pred.aleatoric_var).mean())
        if rollouts and test.logs and self.cfg.test.rollout_samples:
            # Free runs of the whole test maneuvers: what a surrogate that simulates is for. Timed,
            # so a round's log says what the rollouts cost beside the fit.
            started = time.perf_counter()
            metrics.update(
                free_run_metrics(
                    model,
                    test.logs,
                    test.truth_logs,
                    rate_hz=self.cfg.simulation.rate_hz,
                    n_samples=self.cfg.test.rollout_samples,
                    seed=0,
                )
            )
            metrics[ROLLOUT_SECONDS] = time.perf_counter() - started
        return metrics

    def pool_epistemic_max(self, model: Any, pool: Pool) -> float:
        """Largest candidate epistemic std (standardised, averaged over outputs and the maneuver)."""
        pred = standardise(model.predict(pool.points, n_samples=EVAL_SAMPLES, seed=0), pool.output_scale)
        per_point = np.sqrt(pred.epistemic_var).mean(axis=1)
        per_candidate = np.bincount(pool.owner, weights=per_point) / np.bincount(pool.owner)
        return float(per_candidate[pool.available].max()) if len(pool.available) else 0.0


    def prequential_scale(self, model: Any, new_samples: pd.DataFrame) -> float:
        """Epistemic scale that would have calibrated `model` on the maneuvers collected after it.

        Those maneuvers were not in the model's training data, so they are honest held-out operating
        points. Rows with the same controls in one maneuver are averaged (steady maneuvers become one
        nearly noise-free target); the rest keep their aleatoric variance in the likelihood.
        """
        x, y, pool_index = self.rows(new_samples)
        keys = np.column_stack([pool_index, np.round(x[:, :2], 4)])
        _, groups = np.unique(keys, axis=0, return_inverse=True)
        previous = float(model.epistemic_scale)
        scale = recalibrate_epistemic(model, x, y, groups=groups.ravel(), n_samples=EVAL_SAMPLES)
        with torch.no_grad():
            model.epistemic_scale.fill_(previous)  # the checkpointed model keeps the scale it was used with
        return scale

    def prequential_check(self, model: Any, new_samples: pd.DataFrame) -> dict[str, float]:
        """How well `model`'s epistemic std ranked its errors on the maneuvers collected after it.

        Rows of one maneuver with the same controls are averaged (a steady maneuver becomes one nearly
        noise-free point); `prequential_spearman` is the rank correlation of the epistemic std with
        |error| over those points (NaN with fewer than 3), `prequential_points` their number.
        """
        x, y, pool_index = self.rows(new_samples)
        keys = np.column_stack([pool_index, np.round(x[:, :2], 4)])
        _, groups = np.unique(keys, axis=0, return_inverse=True)
        groups = groups.ravel()
        counts = np.bincount(groups)
        x_mean = np.stack([np.bincount(groups, weights=col) / counts for col in x.T], axis=1)
        y_mean = np.stack([np.bincount(groups, weights=col) / counts for col in y.T], axis=1)
        if len(counts) < 3:
            return {PREQUENTIAL_SPEARMAN: float("nan"), PREQUENTIAL_POINTS: float(len(counts))}
        pred = standardise(model.predict(x_mean, n_samples=EVAL_SAMPLES, seed=0), self.test_set.scale)
        diag = uncertainty.epistemic_diagnostic(y_mean / self.test_set.scale, pred)
        return {PREQUENTIAL_SPEARMAN: float(diag["spearman"]), PREQUENTIAL_POINTS: float(len(counts))}

    def prequential(self, model: Any, new: pd.DataFrame) -> dict[str, float]:
        """Every check of `model` on the batch collected after it: the rank check, and the epistemic and
        fan scales that would have calibrated it where the config applies them to later rounds."""
        checks = self.prequential_check(model, new)
        if self.cfg.design.recalibrate == "prequential":
            checks[PREQUENTIAL_SCALE] = self.prequential_scale(model, new)
        if self.cfg.design.fan_calibration == "prequential":
            logs = [part.reset_index(drop=True) for _, part in new.groupby("pool_index", sort=False)]
            # The batch's logs are measurements: their pose noise is allowed for (the config's sensor
            # noise; for recorded logs, the stated one), else it reads as misses and widens every fan.
            checks[PREQUENTIAL_FAN_SCALE] = fan_scale_needed(
                model, logs, rate_hz=self.cfg.simulation.rate_hz,
                n_samples=self.cfg.test.rollout_samples or FAN_SAMPLES, seed=0,
                noise=noise_config(self.cfg.simulation.noise),
            )  # fmt: skip
        return checks
