"""The active-learning outer loop: fit, evaluate, propose, collect, checkpoint, repeat.

One campaign = one config, one strategy, one seed. Every strategy shares the initial design, the
budget, the candidate pool, the test set and the training recipe; only `Strategy.select` differs.

The loop is ask/tell. `propose()` fits the model on everything collected so far (round r, seeded by
(seed, r)), evaluates it on the fixed test set, logs the metrics at step = number of training rows and
proposes the next batch; `tell(logs)` takes the logs of that batch. `run()` is that loop with an
automatic oracle answering (the simulator, a twin of it, or a folder of recorded logs); with the
external oracle a person drives the proposals and `activelearn campaign ingest` tells.

After every step the directory holds a consistent checkpoint (samples.parquet, model.pt, state.json,
the latter written last as the commit point), so a campaign killed at any moment resumes from its
last step and ends with the same data and metrics as an uninterrupted run.

A warm start (`[design] prior`) adds rows that train every round without counting against the budget
(or, for sim-to-real, a prior model to fine-tune or to learn a residual on); learning curves then start
at the prior: round 0 is the prior alone when `design.initial` is 0.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from activelearn.config import CampaignConfig
from activelearn.data import atomic_write_bytes, read_table, write_table
from activelearn.errors import ActiveLearnError, CampaignStopped, InputError, TrackingUnavailable
from activelearn.loop import lock
from activelearn.loop.acquisition import (
    AutoStrategy,
    LookaheadOracleStrategy,
    Pool,
    Strategy,
    greedy_maximin,
    make_strategy,
)
from activelearn.loop.collection import (
    TARGETS,
    SimulationCache,
    TestSet,
    arrays,
    control_rate_logs,
    feature_columns,
    rows_per_maneuver,
    training_rows,
    training_windows,
)
from activelearn.loop.family_pool import proposal_table, schedule_table
from activelearn.loop.oracles import Oracle, make_oracle
from activelearn.loop.pool import (
    build_pool,
    evaluation_grid,
    maneuver_controls,
    maneuver_costs,
    target_points,
)
from activelearn.loop.prior import PRIOR_FILE, Prior, load_prior, prior_from_rows
from activelearn.loop.safety import Assessment, assess, live_stop, turn_speed, violations
from activelearn.loop.state import (
    CONFIG_FILE,
    MODEL_FILE,
    PRIOR_MODEL_FILE,
    PROPOSALS_DIR,
    SAMPLES_FILE,
    STAGED_DIR,
    STATE_FILE,
    CampaignState,
)
from activelearn.numerics import uncertainty
from activelearn.numerics.models import Prediction, ResidualModel, build_model, load_model, save_model
from activelearn.numerics.paths import path_inputs
from activelearn.numerics.surrogate import fan_scale_needed, free_run_metrics, model_inputs, simulate
from activelearn.numerics.training import fit
from activelearn.numerics.uncertainty import recalibrate_epistemic
from simulator import FamilyManeuver

__all__ = [
    "MODEL_FILE",
    "SAMPLES_FILE",
    "STATE_FILE",
    "Campaign",
    "CampaignInterrupted",
    "CampaignResult",
    "CampaignState",
    "config_hash",
    "default_directory",
    "load_campaign_model",
    "total_rounds",
]

EVAL_SAMPLES = 64  # posterior draws for test metrics and uncertainty maps
FAN_SAMPLES = 32  # trajectories of a prequential fan check when the test set runs no free runs
WARM_DIR = "warm"  # each round's model, kept for the next warm-started round
PROPOSAL_COLUMNS = ("maneuver", "direction", "throttle", "steering", "duration")

Progress = Callable[[dict[str, Any]], None]


class CampaignInterrupted(ActiveLearnError):
    """The campaign was stopped by the user; its directory can be resumed."""


def config_hash(cfg: CampaignConfig) -> str:
    """Hash of everything that determines a campaign's data except strategy and seed.

    [safety] is left out: at the track the arena or delta may change between rounds (`--resume`).
    """
    exclude = {"strategy", "seed", "tracking", "output_dir", "name", "safety"}
    payload = cfg.model_dump(mode="json", exclude=exclude)
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class CampaignResult:
    """Outcome of one campaign: its directory, state and the metrics of every round."""

    directory: Path
    state: CampaignState

    @property
    def history(self) -> pd.DataFrame:
        """One row per round with every logged metric."""
        return pd.DataFrame(self.state.rounds)


def _rng(seed: int, *tags: int) -> np.random.Generator:
    return np.random.default_rng([seed, *tags])


def _standardise(pred: Prediction, scale: np.ndarray) -> Prediction:
    return dataclasses.replace(
        pred,
        mean=pred.mean / scale,
        aleatoric_var=pred.aleatoric_var / scale**2,
        epistemic_var=pred.epistemic_var / scale**2,
        total_var=pred.total_var / scale**2,
    )


class Campaign:
    """One strategy, one seed, one config: the loop and its checkpoints."""

    def __init__(
        self,
        cfg: CampaignConfig,
        directory: str | Path,
        *,
        cache_dir: str | Path | None = None,
        tracker: Any | None = None,
        parent_run_id: str | None = None,
        progress: Progress | None = None,
    ) -> None:
        self.cfg = cfg
        self.directory = Path(directory)
        acq = cfg.acquisition
        self.strategy: Strategy = make_strategy(
            cfg.strategy,
            batch=acq.batch,
            n_samples=acq.n_samples,
            fantasy_weight=acq.fantasy_weight,
            penalty_length=acq.penalty_length,
            cost_aware=acq.cost_aware,
        )
        cache_root = Path(cache_dir or Path(cfg.output_dir) / "cache")
        self.nominal = SimulationCache(cache_root, cfg.simulation)  # prior grids: the nominal simulator
        self.oracle: Oracle = make_oracle(cfg, cache_root)
        self.tracker = tracker
        self.parent_run_id = parent_run_id
        self.progress = progress or (lambda event: None)
        self.lock_wait = lock.DEFAULT_WAIT  # s a second writer of the directory waits for the first
        self._tracking_down = False  # the tracking server stopped answering (warned once)
        self.maneuvers = self.oracle.candidates()
        if cfg.safety is not None and self.oracle.kind == "logs":
            raise InputError("safety", "[safety]", "judges maneuvers to drive, not oracle.kind = 'logs'")
        if len(self.maneuvers) < cfg.design.initial + 1:
            raise InputError(
                "pool", len(self.maneuvers), "the pool must hold more maneuvers than design.initial"
            )
        self.costs = maneuver_costs(cfg, self.maneuvers)
        self.prior: Prior | None = None
        self._prior_model: Any | None = None
        self._model: Any | None = None  # the model of the last fitted round, while in memory
        self._target: tuple[np.ndarray, np.ndarray] | None = None
        self._clock = (0.0, time.perf_counter())
        self._truth: dict[str, np.ndarray] | None = None
        self.cuts: dict[str, float] = {}  # the state's [safety] cuts (pool index -> seconds)
        self._pick_costs: np.ndarray | None = None  # this round's costs as [safety] would drive them

    # ------------------------------------------------------------------ data

    @property
    def test_set(self) -> TestSet:
        """The fixed test set (simulated once per config and cached, or recorded logs)."""
        return self.oracle.test_set()

    def _label(self, frames: Sequence[pd.DataFrame], indices: Sequence[int], batch: int) -> pd.DataFrame:
        """Tag logs with the pool index they answer and the batch they belong to."""
        tagged = []
        for frame, index in zip(frames, indices, strict=True):
            frame = frame.copy()
            frame["pool_index"] = index
            frame["batch"] = batch
            tagged.append(frame)
        return pd.concat(tagged, ignore_index=True)

    def _collect(self, indices: list[int], batch: int) -> pd.DataFrame:
        """Ask the oracle for the chosen maneuvers (simulated, noised with this campaign's seed)."""
        chosen = [self.driven(i) for i in indices]
        return self._label(self._stopped(self.oracle.answer(chosen, self.cfg.seed)), indices, batch)

    def _stopped(self, logs: list[pd.DataFrame]) -> list[pd.DataFrame]:
        """The oracle's logs as a live stop at the walls leaves them ([safety] stop = "live")."""
        safety = self.cfg.safety
        if safety is None or safety.stop != "live" or not safety.enforce:
            return logs
        return [live_stop(log, safety) for log in logs]

    def _answer(self, state: CampaignState) -> pd.DataFrame:
        """The pending batch's logs: those `ingest` took in already (staged), the oracle answers the rest."""
        assert state.pending is not None
        asked = [i for i in state.pending if str(i) not in state.staged]
        answered = self.oracle.answer([self.driven(i) for i in asked], self.cfg.seed) if asked else []
        answered = self._stopped(answered)
        answers = dict(zip(asked, answered, strict=True))
        frames = [
            answers[i] if i in answers else read_table(self.directory / STAGED_DIR / f"{i}.parquet")
            for i in state.pending
        ]
        return self._label(frames, state.pending, len(state.batches))

    def driven(self, index: int) -> Any:
        """Candidate `index` as it is driven: cut to a shorter duration where [safety] said so."""
        cut = self.cuts.get(str(index))
        maneuver = self.maneuvers[index]
        return maneuver if cut is None else dataclasses.replace(maneuver, duration=cut)

    def _rows(self, samples: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if samples.empty:
            n_in = len(feature_columns(self.cfg.data))
            return np.zeros((0, n_in)), np.zeros((0, len(TARGETS))), np.zeros(0, dtype=int)
        rows = pd.concat(
            [training_rows(part, self.cfg.data) for _, part in samples.groupby("pool_index", sort=False)]
        )
        x, y = arrays(rows, self.cfg.data)
        return x, y, rows["pool_index"].to_numpy()

    def _with_prior(self, samples: pd.DataFrame) -> pd.DataFrame:
        """The logs a round trains on: the campaign's and, where the prior is data, the prior's."""
        if self.prior is not None and self.prior.trains:
            return pd.concat([self.prior.rows, samples], ignore_index=True)
        return samples

    def _training_data(self, samples: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Inputs, targets and maneuver ids the model of a round trains on (prior rows included)."""
        return self._rows(self._with_prior(samples))

    def _training_windows(self, samples: pd.DataFrame) -> Any:
        """Free-running windows for multi-step training (`[training] rollout_horizon`), else None."""
        horizon = self.cfg.training.rollout_horizon
        if not horizon:
            return None
        samples = self._with_prior(samples)
        if samples.empty:
            return None
        frames = [part for _, part in samples.groupby("pool_index", sort=False)]
        return training_windows(frames, self.cfg.data, horizon)

    def _identification_logs(self, samples: pd.DataFrame) -> list[tuple[np.ndarray, np.ndarray]] | None:
        """Each training log's (controls, rates) for a physics-structured model to identify itself on."""
        if self.cfg.model.kind != "physics":
            return None
        samples = self._with_prior(samples)
        return control_rate_logs([part for _, part in samples.groupby("pool_index", sort=False)])

    def _log_groups(self, samples: pd.DataFrame) -> list[Any]:
        """The maneuver id (`pool_index`, as in the training rows' groups) of each identification log."""
        return list(self._with_prior(samples).groupby("pool_index", sort=False).groups)

    def target(self) -> tuple[np.ndarray, np.ndarray]:
        """Controls (and weights) of the target region (`[target]`, default: the test maneuvers')."""
        if self._target is None:
            self._target = target_points(self.cfg, self.maneuvers, self.oracle.test_maneuvers())
        return self._target

    def pool(
        self, taken: list[int], model: Any | None = None, affordable: np.ndarray | None = None,
        maneuvers: Sequence[Any] | None = None,
    ) -> Pool:  # fmt: skip
        """The candidate pool with `taken` marked as collected, its points as `model` inputs.

        `maneuvers`: the candidates as they would be driven (default: the pool's, whole).
        """
        maneuvers = self.maneuvers if maneuvers is None else maneuvers
        mask = np.zeros(len(maneuvers), dtype=bool)
        mask[taken] = True
        pool = build_pool(
            self.cfg,
            maneuvers,
            mask,
            self.test_set.scale,
            self.target(),
            self.cfg.seed,
            affordable=affordable,
            # what is known of this system counts as taken; a prior that only shapes a model (another
            # system's data: fine-tune, residual) does not
            prior=self.prior.runs if self.prior is not None and self.prior.trains else (),
        )
        if self.cfg.strategy == "oracle_error":
            pool = dataclasses.replace(pool, **self._pool_truth())
        if model is None or model.n_inputs == pool.points.shape[1]:
            return pool
        if self._scores_paths:
            return dataclasses.replace(pool, **self._path_points(model, maneuvers))
        return dataclasses.replace(
            pool, points=model_inputs(model, pool.points), target=model_inputs(model, pool.target)
        )

    @property
    def _scores_paths(self) -> bool:
        """Whether candidates are scored along the dynamic model's own free runs of them."""
        return self.cfg.data.inputs != "controls" and self.cfg.acquisition.dynamic_points == "path"

    def _path_points(self, model: Any, maneuvers: Sequence[Any]) -> dict[str, Any]:
        """Pool points of a dynamic model along each candidate's predicted path (and the target's)."""
        rate, n_points = self.cfg.simulation.rate_hz, self.cfg.acquisition.score_points
        inputs = path_inputs(model, [maneuver_controls(m, rate) for m in maneuvers], n_points, rate_hz=rate)
        rows = [rows_per_maneuver(m.duration, self.cfg.simulation, self.cfg.data) for m in maneuvers]
        fields: dict[str, Any] = {
            "points": np.concatenate(inputs),
            "owner": np.repeat(np.arange(len(inputs)), n_points),
            "weights": np.repeat(np.asarray(rows) / n_points, n_points),
        }
        test = self.oracle.test_maneuvers()
        if self.cfg.target.region == "test" and test:
            per_maneuver = max(1, self.cfg.target.max_points // len(test))
            target = path_inputs(
                model, [maneuver_controls(m, rate) for m in test], per_maneuver, rate_hz=rate
            )
            fields.update(target=np.concatenate(target), target_weights=None)
        else:
            fields["target"] = model_inputs(model, self.target()[0])
        return fields

    def _pool_truth(self) -> dict[str, np.ndarray]:
        """Noise-free training rows of every candidate, for the diagnostic oracle strategy only."""
        if self._truth is None:
            clean = self.oracle.truth(self.maneuvers)
            if clean is None:
                raise InputError(
                    "strategy", "oracle_error", f"needs a simulated oracle, not {self.oracle.kind!r}"
                )
            xs, ys, owner = [], [], []
            for i, frame in enumerate(clean):
                x, y = arrays(training_rows(frame, self.cfg.data), self.cfg.data)
                xs.append(x)
                ys.append(y)
                owner.append(np.full(len(x), i))
            self._truth = {
                "truth_x": np.concatenate(xs),
                "truth_y": np.concatenate(ys),
                "truth_owner": np.concatenate(owner),
            }
        return self._truth

    # ------------------------------------------------------------------ model

    def prior_model(self) -> Any | None:
        """The model a warm start begins from (fine-tune, residual base, or given weights), else None.

        Given weights (`prior.model`) are loaded and checked against [model]; otherwise the model is
        trained once on the prior rows (seeded by the campaign seed) and kept in the directory.
        """
        prior_cfg = self.cfg.design.prior
        if prior_cfg is None or (prior_cfg.use == "data" and prior_cfg.model is None):
            return None
        if self._prior_model is None:
            stored = self.directory / PRIOR_MODEL_FILE
            if stored.exists():
                self._prior_model = load_model(stored)
            elif prior_cfg.model is not None:
                self._prior_model = _load_prior_model(prior_cfg.model, self.cfg)
            else:
                assert self.prior is not None
                x, y, groups = self._rows(self.prior.rows)
                model = build_model(self.cfg.model)
                fit(model, x, y, self.cfg.training, groups=groups, seed=self.cfg.seed * 10_007 + 0x9210)
                self._prior_model = model
        return self._prior_model

    def fit_model(
        self,
        samples: pd.DataFrame,
        round_index: int,
        epistemic_scale: float = 1.0,
        previous: Any | None = None,
    ) -> Any:
        """Train the model of a round on its data, seeded by (seed, round), with a given epistemic scale.

        A fresh model by default; with a warm-start model, a copy fine-tuned from its weights (and its
        input/output scalers), or, for use = "residual", a fresh model of the difference from it.
        With `[training] warm_start`, a fresh model's round starts from `previous` (the last round's
        model) and trains `warm_epochs` epochs.
        """
        x, y, groups = self._training_data(samples)
        windows = self._training_windows(samples)
        logs = self._identification_logs(samples)
        log_groups = self._log_groups(samples) if logs is not None else None
        seed = self.cfg.seed * 10_007 + round_index
        base = self.prior_model()
        use = self.cfg.design.prior.use if self.cfg.design.prior is not None else "data"
        if base is not None and use == "residual":
            residual = build_model(self.cfg.model)
            fit(residual, x, y - base.predict(x, n_samples=EVAL_SAMPLES, seed=0).mean, self.cfg.training,
                groups=groups, seed=seed)  # fmt: skip
            model: Any = ResidualModel(base, residual)
        elif base is not None:
            model = load_model_copy(base)
            if len(x):
                training = self.cfg.training.model_copy(update={"reinit": False})
                fit(model, x, y, training, groups=groups, seed=seed, keep_scalers=True, windows=windows,
                    logs=logs, log_groups=log_groups)  # fmt: skip
        elif previous is not None and self.cfg.training.warm_start:
            model = load_model_copy(previous)
            training = self.cfg.training
            epochs = training.warm_epochs or max(1, training.epochs // 4)
            fit(model, x, y, training.model_copy(update={"reinit": False, "epochs": epochs}),
                groups=groups, seed=seed, keep_scalers=True, windows=windows, logs=logs,
                log_groups=log_groups)  # fmt: skip
        else:
            model = build_model(self.cfg.model)
            fit(model, x, y, self.cfg.training, groups=groups, seed=seed, windows=windows, logs=logs,
                log_groups=log_groups)
        with torch.no_grad():
            model.epistemic_scale.fill_(epistemic_scale)
        return model

    def _warm_path(self, round_index: int) -> Path:
        return self.directory / WARM_DIR / f"round{round_index:03d}.pt"

    def _previous_model(self, round_index: int) -> Any | None:
        """The model a warm-started round begins from: round r - 1's, as committed (None: start fresh).

        Kept per round (not model.pt, which a crash between its write and state.json's could leave one
        round ahead), so a resumed round starts from exactly the weights the uninterrupted run used.
        """
        if not self.cfg.training.warm_start or round_index == 0:
            return None
        path = self._warm_path(round_index - 1)
        return load_model(path) if path.exists() else None

    def _keep_warm_model(self, model: Any, round_index: int) -> None:
        """Store round r's model for round r + 1 (before the commit point); drop older ones."""
        if not self.cfg.training.warm_start:
            return
        save_model(model, self._warm_path(round_index))
        for old in self._warm_path(0).parent.glob("round*.pt"):
            if old.name < self._warm_path(max(round_index - 1, 0)).name:
                old.unlink(missing_ok=True)

    def prequential_scale(self, model: Any, new_samples: pd.DataFrame) -> float:
        """Epistemic scale that would have calibrated `model` on the maneuvers collected after it.

        Those maneuvers were not in the model's training data, so they are honest held-out operating
        points. Rows with the same controls in one maneuver are averaged (steady maneuvers become one
        nearly noise-free target); the rest keep their aleatoric variance in the likelihood.
        """
        x, y, pool_index = self._rows(new_samples)
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
        x, y, pool_index = self._rows(new_samples)
        keys = np.column_stack([pool_index, np.round(x[:, :2], 4)])
        _, groups = np.unique(keys, axis=0, return_inverse=True)
        groups = groups.ravel()
        counts = np.bincount(groups)
        x_mean = np.stack([np.bincount(groups, weights=col) / counts for col in x.T], axis=1)
        y_mean = np.stack([np.bincount(groups, weights=col) / counts for col in y.T], axis=1)
        if len(counts) < 3:
            return {"prequential_spearman": float("nan"), "prequential_points": float(len(counts))}
        pred = _standardise(model.predict(x_mean, n_samples=EVAL_SAMPLES, seed=0), self.test_set.scale)
        diag = uncertainty.epistemic_diagnostic(y_mean / self.test_set.scale, pred)
        return {"prequential_spearman": float(diag["spearman"]), "prequential_points": float(len(counts))}

    def _context(self, state: CampaignState) -> dict[str, float]:
        """What strategies may read: recent prequential checks (mean of 3), warm start, kind of budget,
        whether a dynamic model scores candidates along its free runs."""
        recent = [
            r["prequential_spearman"]
            for r in state.rounds
            if np.isfinite(r.get("prequential_spearman", np.nan))
        ]
        context = {"prequential_spearman": float(np.mean(recent[-3:]))} if recent else {}
        if self.cfg.design.max_sim_seconds is not None:  # the budget is track time: costs matter
            context["seconds_budget"] = 1.0
        if self.cfg.design.prior is not None:  # the model starts from what was known before
            context["warm_start"] = 1.0
        if self._scores_paths:
            context["dynamic_paths"] = 1.0
        return context

    def _trial(
        self, state: CampaignState, samples: pd.DataFrame, batch: list[int], round_index: int, model: Any
    ) -> float:
        """Test RMSE of the next round's model if `batch` were collected (the lookahead oracle only)."""
        new = self._collect(batch, len(state.batches))
        trial = self.fit_model(pd.concat([samples, new], ignore_index=True), round_index + 1, previous=model)
        return self.evaluate(trial, rollouts=False)["test_rmse"]

    def _applied_scale(self, state: CampaignState, key: str = "prequential_scale") -> float:
        """Geometric mean of the last two prequential scales under `key` (1 before any was measured).

        Only recent rounds count: a model trained on few maneuvers errs far more between its points
        than one trained on many, so old scales would inflate the variance of later models.
        """
        scales = [r[key] for r in state.rounds if np.isfinite(r.get(key, np.nan))][-2:]
        return float(np.exp(np.mean(np.log(scales)))) if scales else 1.0

    def evaluate(self, model: Any, *, rollouts: bool = True) -> dict[str, float]:
        """Test-set accuracy and calibration, uncertainty over the evaluation grid, and (`rollouts`)
        the free runs of the test maneuvers."""
        test = self.test_set
        pred = model.predict(test.x, n_samples=EVAL_SAMPLES, seed=0)
        std_pred = _standardise(pred, test.scale)
        clean, noisy = test.y_clean / test.scale, test.y_noisy / test.scale
        err = pred.mean - test.y_clean
        metrics = {
            "test_rmse": float(np.sqrt(np.mean((std_pred.mean - clean) ** 2))),
            "test_rmse_v": float(np.sqrt(np.mean(err[:, 0] ** 2))),  # m/s
            "test_rmse_w": float(np.sqrt(np.mean(err[:, 1] ** 2))),  # rad/s
            "test_nll": float(uncertainty.gaussian_nll(noisy, std_pred)),
            "test_crps": float(uncertainty.crps(noisy, std_pred)),
            "coverage_95": float(uncertainty.coverage(noisy, std_pred, level=0.95)),
        }
        diag = uncertainty.epistemic_diagnostic(clean, std_pred)
        metrics.update({f"calib_{k}": float(v) for k, v in diag.items() if np.isscalar(v)})
        _, _, grid = evaluation_grid(self.cfg, self.maneuvers)
        grid_pred = _standardise(
            model.predict(model_inputs(model, grid), n_samples=EVAL_SAMPLES, seed=0), test.scale
        )
        epi = np.sqrt(grid_pred.epistemic_var).mean(axis=1)
        metrics["epistemic_std_mean"] = float(epi.mean())
        metrics["epistemic_std_max"] = float(epi.max())
        metrics["aleatoric_std_mean"] = float(np.sqrt(grid_pred.aleatoric_var).mean())
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
            metrics["rollout_seconds"] = time.perf_counter() - started
        return metrics

    def pool_epistemic_max(self, model: Any, pool: Pool) -> float:
        """Largest candidate epistemic std (standardised, averaged over outputs and the maneuver)."""
        pred = _standardise(model.predict(pool.points, n_samples=EVAL_SAMPLES, seed=0), pool.output_scale)
        per_point = np.sqrt(pred.epistemic_var).mean(axis=1)
        per_candidate = np.bincount(pool.owner, weights=per_point) / np.bincount(pool.owner)
        return float(per_candidate[pool.available].max()) if len(pool.available) else 0.0

    # ------------------------------------------------------------------ budget

    def _sim_seconds(self, taken: list[int]) -> float:
        return float(sum(self.driven(i).duration for i in taken))

    def _track_seconds(self, taken: list[int]) -> float:
        """Seconds of track time spent: durations (as driven) plus the set-up time of every maneuver."""
        return self._sim_seconds(taken) + self.cfg.design.setup_seconds * len(taken)

    def _affordable(self, state: CampaignState) -> np.ndarray | None:
        """Candidates that still fit the seconds budget (None without one)."""
        budget = self.cfg.design.max_sim_seconds
        if budget is None:
            return None
        return self.costs <= budget - self._track_seconds(state.taken) + 1e-9

    def next_batch_size(self, state: CampaignState) -> tuple[int, str | None]:
        """How many maneuvers the next round may collect, or 0 and the reason to stop."""
        design = self.cfg.design
        n = len(state.taken)
        k = design.per_round
        # rounds after the initial design (or after the prior alone, without one)
        if design.max_rounds is not None and len(state.batches) - (design.initial > 0) >= design.max_rounds:
            return 0, "max_rounds"
        if design.max_maneuvers is not None:
            k = min(k, design.max_maneuvers - n)
            if k <= 0:
                return 0, "max_maneuvers"
        affordable = self._affordable(state)
        open_ = np.ones(len(self.maneuvers), dtype=bool)
        open_[state.taken] = False
        if affordable is not None:
            k = min(k, int((affordable & open_).sum()))
            if k <= 0:
                return 0, "max_sim_seconds"
        k = min(k, int(open_.sum()))
        if k <= 0:
            return 0, "pool_exhausted"
        return k, None

    def _within_budget(self, state: CampaignState, picks: list[int]) -> list[int]:
        """The picks, in pick order, that fit the seconds budget together (later ones wait a round)."""
        budget = self.cfg.design.max_sim_seconds
        if budget is None:
            return picks
        room = budget - self._track_seconds(state.taken) + 1e-9
        kept = []
        costs = self.costs if self._pick_costs is None else self._pick_costs
        for pick in picks:
            if costs[pick] <= room:
                kept.append(pick)
                room -= costs[pick]
        return kept

    # ------------------------------------------------------------------ checkpoints

    def _load(self, resume: bool) -> tuple[CampaignState, pd.DataFrame]:
        expected = config_hash(self.cfg)
        if (self.directory / STATE_FILE).exists():
            if not resume:
                raise InputError(
                    "--out",
                    str(self.directory),
                    "holds a campaign already; pass --resume or choose another --out",
                )
            state = CampaignState.load(self.directory)
            if (state.config_hash, state.strategy, state.seed) != (
                expected,
                self.cfg.strategy,
                self.cfg.seed,
            ):
                raise InputError(
                    "--resume",
                    str(self.directory),
                    "the checkpoint was made with another config, strategy or seed",
                )
            if state.prior_digest is not None:
                self.prior = prior_from_rows(
                    read_table(self.directory / PRIOR_FILE), self.cfg.design.prior.use
                )  # type: ignore[union-attr]
            samples = (
                read_table(self.directory / SAMPLES_FILE)
                if (self.directory / SAMPLES_FILE).exists()
                else pd.DataFrame()
            )
            if not samples.empty:
                # Rows of a batch whose state never committed are dropped; the step is redone identically.
                samples = samples[samples["batch"] < len(state.batches)].reset_index(drop=True)
            return state, samples
        # A new campaign: everything is checked before the directory is created.
        self.prior = load_prior(self.cfg, self.nominal)
        self.prior_model()
        state = CampaignState(expected, self.cfg.strategy, self.cfg.seed)
        self.directory.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(self.directory / CONFIG_FILE, self.cfg.model_dump_json(indent=1).encode())
        if self.prior is not None:
            write_table(self.prior.rows, self.directory / PRIOR_FILE)
            state.prior_digest = self.prior.digest
        if self._prior_model is not None:
            save_model(self._prior_model, self.directory / PRIOR_MODEL_FILE)
        return state, pd.DataFrame()

    def _checkpoint(self, state: CampaignState, samples: pd.DataFrame | None, model: Any | None) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        if samples is not None and not samples.empty:
            write_table(samples, self.directory / SAMPLES_FILE)
        if model is not None:
            save_model(model, self.directory / MODEL_FILE)
        state.save(self.directory)  # last: the commit point

    # ------------------------------------------------------------------ tracking

    def _track(self, call: Callable[[], Any]) -> bool:
        """Make a tracking call. A tracking server that went away is one warning and False: the campaign
        goes on, and what it missed is logged once the server is back (or at --resume)."""
        try:
            call()
        except TrackingUnavailable as exc:
            if not self._tracking_down:
                self.progress({"event": "tracking_down", "message": f"{exc}: the campaign goes on and logs "
                               "what it missed once the server is back (or at --resume)"})  # fmt: skip
            self._tracking_down = True
            return False
        self._tracking_down = False
        return True

    def _start_tracking(self, state: CampaignState) -> None:
        if self.tracker is None:
            return
        try:
            self._open_run(state)
        except TrackingUnavailable as exc:
            raise CampaignStopped(f"{exc}; nothing was trained or logged: rerun once it answers") from None

    def _open_run(self, state: CampaignState) -> None:
        assert self.tracker is not None
        name = f"{self.cfg.name}-{self.cfg.strategy}-seed{self.cfg.seed}"
        state.run_id = self.tracker.start_run(
            name,
            parent_run_id=self.parent_run_id,
            resume_run_id=state.run_id,
            tags={"strategy": self.cfg.strategy, "seed": str(self.cfg.seed), "config": self.cfg.name},
        )
        params: dict[str, Any] = self.cfg.model_dump(mode="json")
        params["oracle_info"] = self.oracle.params()
        if self.prior is not None:
            params["prior_info"] = {"maneuvers": len(self.prior.runs), "rows": len(self.prior.rows),
                                    "digest": self.prior.digest}  # fmt: skip
        self.tracker.log_params(state.run_id, params)

    def _flush_metrics(self, state: CampaignState) -> None:
        if self.tracker is None or state.run_id is None:
            return
        for index in range(state.logged, len(state.rounds)):
            if not self._track(lambda index=index: self._log_round(state, index)):
                break
            state.logged += 1
        state.save(self.directory)

    def _log_round(self, state: CampaignState, index: int) -> None:
        assert self.tracker is not None and state.run_id is not None
        record = state.rounds[index]
        stamp = state.stamps[index] if index < len(state.stamps) else None
        self.tracker.log_metrics(state.run_id, record, step=int(record["n_samples"]), timestamp=stamp)
        figure_path = self.directory / "figures" / f"epistemic_round{int(record['round']):02d}.png"
        if figure_path.exists():
            self.tracker.log_artifact(state.run_id, figure_path, "figures")

    def _plans(self, model: Any, picks: list[int]) -> tuple[list[str], list[np.ndarray], Any]:
        """Names, control signals and the model's predicted free runs of the chosen maneuvers."""
        rate = self.cfg.simulation.rate_hz
        driven = [self.driven(i) for i in picks]
        controls = [maneuver_controls(m, rate) for m in driven]
        return (
            [m.name for m in driven],
            controls,
            simulate(model, controls, rate_hz=rate, n_samples=16, seed=0),
        )

    def _figure(self, model: Any, state: CampaignState, picks: list[int], round_index: int) -> None:
        from activelearn.plots import epistemic_map  # matplotlib only when figures are drawn

        throttles, steerings, grid = evaluation_grid(self.cfg, self.maneuvers)
        pred = _standardise(
            model.predict(model_inputs(model, grid), n_samples=EVAL_SAMPLES, seed=0), self.test_set.scale
        )
        std = np.sqrt(pred.epistemic_var).mean(axis=1).reshape(len(throttles), len(steerings))
        fig = epistemic_map(
            throttles,
            steerings,
            std,
            taken=[self.maneuvers[i] for i in state.taken],
            picks=[self.maneuvers[i] for i in picks],
            prior=list(self.prior.runs) if self.prior is not None else (),
            title=f"{self.cfg.strategy}, seed {self.cfg.seed}, round {round_index}",
            plans=self._plans(model, picks) if picks else None,
        )
        path = self.directory / "figures" / f"epistemic_round{round_index:02d}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.png")
        fig.savefig(tmp, dpi=90)
        tmp.replace(path)

    # ------------------------------------------------------------------ the steps

    def _propose(self, state: CampaignState, samples: pd.DataFrame, figures: bool) -> None:
        """Fit and evaluate the round's model (or take the initial design), then propose the next batch."""
        if not state.batches and self.cfg.design.initial > 0:
            pool, safe = self._safe_pool(self.pool([]), self.prior_model(), 0, samples=samples)
            k = min(self.cfg.design.initial, len(pool.available))  # [safety] may admit fewer
            if k == 0:
                state.finished, state.stop_reason = True, "nothing_admissible"
                self._checkpoint(state, None, None)
                return
            initial = greedy_maximin(pool, k, _rng(self.cfg.seed, 0x1D))
            self._set_pending(state, initial, safe)
            self._checkpoint(state, None, None)
            return
        round_index = len(state.rounds)
        self.progress({"event": "fit", "round": round_index, "n_maneuvers": len(state.taken)})
        scale = self._applied_scale(state) if self.cfg.design.recalibrate == "prequential" else 1.0
        model = self.fit_model(samples, round_index, scale, previous=self._previous_model(round_index))
        fans: dict[str, float] = {}
        if self.cfg.design.fan_calibration == "prequential":
            fans["fan_scale"] = self._applied_scale(state, "prequential_fan_scale")
            with torch.no_grad():
                model.fan_scale.fill_(fans["fan_scale"])
        x, _, _ = self._training_data(samples)
        metrics: dict[str, Any] = {"round": round_index, "epistemic_scale": scale, **fans}
        if hasattr(model, "correction_weight"):  # the physics kind: the share of its correction kept
            metrics["correction_weight"] = float(model.correction_weight)
        metrics.update(self.evaluate(model))
        metrics.update(
            n_samples=len(x),
            n_maneuvers=len(state.taken),
            sim_seconds=self._sim_seconds(state.taken),
            track_seconds=self._track_seconds(state.taken),
        )
        metrics["wall_seconds"] = state.wall_seconds = self._wall()
        k, reason = self.next_batch_size(state)
        pool = dataclasses.replace(
            self.pool(state.taken, model, self._affordable(state)), context=self._context(state)
        )
        safe: Assessment | None = None
        if reason is None:
            started = time.perf_counter()
            pool, safe = self._safe_pool(pool, model, round_index, state.taken, samples)
            if safe is not None:
                metrics.update(self._safety_metrics(state, safe, time.perf_counter() - started))
                k = min(k, len(pool.available))
                reason = "nothing_admissible" if k <= 0 else None
        elif self.cfg.safety is not None:
            metrics.update(self._safety_metrics(state, None, 0.0))
        if reason is None and self.cfg.design.stop_epistemic_std is not None:
            metrics["pool_epistemic_std_max"] = self.pool_epistemic_max(model, pool)
            if metrics["pool_epistemic_std_max"] < self.cfg.design.stop_epistemic_std:
                reason = "stop_epistemic_std"
        picks: list[int] = []
        if reason is None:
            rng = _rng(self.cfg.seed, round_index, 0x5E1)
            if isinstance(self.strategy, LookaheadOracleStrategy):
                trial = lambda batch: self._trial(state, samples, batch, round_index, model)  # noqa: E731
                picks = self.strategy.select_with_trials(model, pool, k, rng, trial)
            else:
                picks = self.strategy.select(model, pool, k, rng)
            picks = self._within_budget(state, picks)
            if isinstance(self.strategy, AutoStrategy):
                metrics["auto_model_based"] = float(self.strategy.last_choice != "uniform")
        if figures:
            self._figure(model, state, picks, round_index)
        state.stamps.extend([int(time.time() * 1000)] * (len(state.rounds) + 1 - len(state.stamps)))
        state.rounds.append(metrics)
        if picks:
            self._set_pending(state, picks, safe)
        else:
            state.finished, state.stop_reason = True, reason or "max_sim_seconds"
        self._model = model
        self._keep_warm_model(model, round_index)
        self._checkpoint(state, None, model)
        self._flush_metrics(state)
        self.progress({"event": "round", **metrics, "picks": [self.maneuvers[i].name for i in picks]})

    def _safe_pool(
        self, pool: Pool, model: Any | None, round_index: int, taken: Sequence[int] = (),
        samples: pd.DataFrame | None = None,
    ) -> tuple[Pool, Assessment | None]:  # fmt: skip
        """The pool restricted to the candidates [safety] admits, and their assessment (None: no [safety])."""
        safety = self.cfg.safety
        if safety is None:
            return pool, None
        safe = self._assess(model, round_index, ~pool.taken, samples)
        if not safety.enforce:
            return pool, safe
        if safe.cut.any():  # score each candidate as it would be driven: a cut one by its first seconds
            driven = [
                dataclasses.replace(m, duration=float(safe.duration[i])) if safe.cut[i] else m
                for i, m in enumerate(self.maneuvers)
            ]
            rebuilt = self.pool(list(np.flatnonzero(pool.taken)), model, maneuvers=driven)
            fields = {name: getattr(rebuilt, name) for name in ("points", "owner", "weights")}
            pool = dataclasses.replace(pool, **fields)
        # what each candidate costs as it would be driven (cut short or whole), for the seconds budget
        self._pick_costs = np.where(safe.admissible, safe.duration, safe.full) + self.cfg.design.setup_seconds
        affordable = safe.admissible
        budget = self.cfg.design.max_sim_seconds
        if budget is not None:
            affordable = affordable & (self._pick_costs <= budget - self._track_seconds(taken) + 1e-9)
        return dataclasses.replace(pool, affordable=affordable, costs=self._pick_costs), safe

    def _assess(
        self, model: Any | None, round_index: int, open_: np.ndarray, samples: pd.DataFrame | None
    ) -> Assessment:
        """[safety]'s assessment of the open candidates (a benchmark's clairvoyant safe set overrides it)."""
        safety = self.cfg.safety
        assert safety is not None
        rate = self.cfg.simulation.rate_hz
        turn = None
        if safety.measured_turn_speed:
            turn = turn_speed(self._logs(samples), rate, safety.limit_window)
        return assess(model, self.maneuvers, safety, rate_hz=rate, seed=self.cfg.seed * 10_007 + round_index,
                      which=open_, turn=turn)  # fmt: skip

    def _logs(self, samples: pd.DataFrame | None) -> pd.DataFrame | None:
        """Every log row the campaign holds of the car: the prior's runs and the collected maneuvers."""
        prior = self.prior.rows if self.prior is not None else None
        frames = [f for f in (prior, samples) if f is not None and not f.empty]
        return pd.concat(frames, ignore_index=True) if frames else None

    def _safety_metrics(
        self, state: CampaignState, safe: Assessment | None, seconds: float
    ) -> dict[str, float]:
        """What a round logs of [safety]: safe-set size, risk, violations of its batch and in total."""
        total = sum(1 for reason in state.violated.values() if reason)
        before = next((r["violations_total"] for r in reversed(state.rounds) if "violations_total" in r), 0)
        metrics = {"violations": float(total - before), "violations_total": float(total)}
        if safe is not None:
            assessed = np.isfinite(safe.risk)
            metrics.update(
                safe_set_size=float(safe.size),
                safe_set_cut=float(safe.cut.sum()),
                risk_min=float(np.nanmin(safe.risk)) if assessed.any() else float("nan"),
                safety_seconds=seconds,
            )
        return metrics

    def _set_pending(self, state: CampaignState, picks: list[int], safe: Assessment | None) -> None:
        """Propose `picks`; with [safety], record their risks and the shorter durations of those cut."""
        state.pending = picks
        if safe is None:
            return
        for i in picks:
            state.risks[str(i)] = float(safe.cut_risk[i] if safe.admissible[i] else safe.risk[i])
            if safe.cut[i] and self.cfg.safety.enforce:  # type: ignore[union-attr]
                state.cuts[str(i)] = float(safe.duration[i])
        self.cuts = dict(state.cuts)

    def _receive(self, state: CampaignState, samples: pd.DataFrame, new: pd.DataFrame) -> pd.DataFrame:
        """Append the logs of the pending batch; measure the prequential scale on them if asked."""
        assert state.pending is not None
        if self.cfg.safety is not None:  # what the car did: the true path against the arena and limits
            found = violations(new, self.cfg.safety, self.cfg.simulation.rate_hz)
            state.violated.update({str(i): reason for i, reason in found.items()})
        model = (self._model or load_model(self.directory / MODEL_FILE)) if state.rounds else None
        if model is not None and model.has_epistemic:
            # The model of the last round meets maneuvers it never saw: an honest calibration check.
            checks = self.prequential_check(model, new)
            if self.cfg.design.recalibrate == "prequential":
                checks["prequential_scale"] = self.prequential_scale(model, new)
            if self.cfg.design.fan_calibration == "prequential":
                logs = [part.reset_index(drop=True) for _, part in new.groupby("pool_index", sort=False)]
                checks["prequential_fan_scale"] = fan_scale_needed(
                    model, logs, rate_hz=self.cfg.simulation.rate_hz,
                    n_samples=self.cfg.test.rollout_samples or FAN_SAMPLES, seed=0,
                )  # fmt: skip
            state.rounds[-1].update(checks)
            if self.tracker is not None and state.run_id is not None:
                tracker, run_id, step = self.tracker, state.run_id, int(state.rounds[-1]["n_samples"])
                stamp = state.stamps[-1] if len(state.stamps) == len(state.rounds) else None
                if not self._track(lambda: tracker.log_metrics(run_id, checks, step=step, timestamp=stamp)):
                    state.logged = min(state.logged, len(state.rounds) - 1)  # the round again, later
        samples = pd.concat([samples, new], ignore_index=True)
        state.batches.append(state.pending)
        state.pending = None
        state.ingested.extend(state.staged.values())  # content hashes of the logs a person handed in
        state.staged = {}
        self._checkpoint(state, samples, None)
        return samples

    def _finish(self, state: CampaignState, log_model: bool) -> None:
        if self.tracker is None or state.run_id is None:
            return
        tracker, run_id = self.tracker, state.run_id
        if state.logged < len(state.rounds):
            self._flush_metrics(state)
        if log_model and not state.model_logged and state.logged == len(state.rounds):
            model = self._model or load_model(self.directory / MODEL_FILE)
            if self._track(lambda: tracker.log_model(run_id, model)):
                state.model_logged = True
                state.save(self.directory)
        done = state.logged == len(state.rounds) and (state.model_logged or not log_model)
        if not (done and self._track(lambda: tracker.end_run(run_id, "FINISHED"))):
            unlogged = len(state.rounds) - state.logged
            missing = [f"{unlogged} round(s)"] if unlogged else []
            missing += ["the model"] if log_model and not state.model_logged else []
            raise CampaignStopped(
                f"the MLflow tracking server at {tracker.tracking_uri} does not answer: "
                f"{' and '.join(missing) or 'the end of the run'} not logged yet; the campaign's data is "
                f"complete in {self.directory}: rerun with --resume once the server answers"
            )

    def _guarded(self, state: CampaignState, step: Callable[[], Any]) -> Any:
        """Run a step; Ctrl-C marks the MLflow run KILLED, any other error FAILED."""
        tracker, run_id = self.tracker, state.run_id
        try:
            return step()
        except KeyboardInterrupt:
            if tracker is not None and run_id is not None:
                self._track(lambda: tracker.end_run(run_id, "KILLED"))
            raise CampaignInterrupted(
                f"interrupted; {self.directory} holds the last finished step: rerun with --resume"
            ) from None
        except BaseException:
            if tracker is not None and run_id is not None:
                self._track(lambda: tracker.end_run(run_id, "FAILED"))
            raise

    # ------------------------------------------------------------------ the loop

    def _open(self, resume: bool) -> tuple[CampaignState, pd.DataFrame]:
        """Load or create the directory's state, start the clock and the MLflow run."""
        state, samples = self._load(resume)
        if state.stop_reason == "nothing_admissible" and state.pending is None:
            # [safety] stopped it; [safety] may have changed since (it is not in the config hash):
            # the last round is fitted and judged again (its metrics are logged again at that step).
            state.finished, state.stop_reason = False, None
            if state.rounds and "test_rmse" in state.rounds[-1]:
                state.rounds.pop()
            state.logged = min(state.logged, len(state.rounds))
        self.cuts = dict(state.cuts)
        self._clock = (state.wall_seconds, time.perf_counter())
        self._start_tracking(state)
        if state.rounds:  # a resumed run may hold rounds that never reached MLflow
            self._flush_metrics(state)
        return state, samples

    def _wall(self) -> float:
        """Wall seconds spent on this campaign, over every command that worked on it."""
        base, started = self._clock
        return base + time.perf_counter() - started

    @lock.writer
    def run(self, *, resume: bool = False, figures: bool = True, log_model: bool = True) -> CampaignResult:
        """Run (or resume) the campaign to its budget or stop rule, the oracle answering every batch."""
        if not self.oracle.automatic:
            raise InputError(
                "oracle.kind", self.cfg.oracle.kind,
                "a person drives these maneuvers: use `activelearn campaign propose` and `campaign ingest`",
            )  # fmt: skip
        state, samples = self._open(resume)

        def loop() -> None:
            nonlocal samples
            while not state.finished:
                if state.pending is None:
                    self._propose(state, samples, figures)
                else:
                    new = self._answer(state)
                    samples = self._receive(state, samples, new)

        self._guarded(state, loop)
        self._finish(state, log_model)
        return CampaignResult(self.directory, state)

    @lock.writer
    def propose(self, *, resume: bool = False, figures: bool = True) -> list[Any]:
        """Ask: the maneuvers to drive next (written to proposals/round-NNN.csv); [] once finished."""
        state, samples = self._open(resume)
        if state.pending is None and not state.finished:
            self._guarded(state, lambda: self._propose(state, samples, figures))
        if state.finished:
            self._finish(state, log_model=True)
            return []
        assert state.pending is not None
        self._write_proposals(state)
        return [self.driven(i) for i in state.pending]

    def history(self) -> pd.DataFrame:
        """One row per fitted round with every logged metric (from the directory's state)."""
        return pd.DataFrame(CampaignState.load(self.directory).rounds)

    def proposal_path(self, state: CampaignState) -> Path:
        """proposals/round-NNN.csv of the pending batch (NNN = batches collected so far)."""
        return self.directory / PROPOSALS_DIR / f"round-{len(state.batches):03d}.csv"

    def _write_proposals(self, state: CampaignState) -> Path:
        assert state.pending is not None
        path = self.proposal_path(state)
        driven = [self.driven(i) for i in state.pending]
        if any(isinstance(m, FamilyManeuver) for m in driven):
            table = self._family_proposals(path, driven)
        else:
            table = self._reference_proposals(state)
        if self.cfg.safety is not None:  # the risk of each proposal, and the duration it was cut from
            table["risk"] = [state.risks.get(str(i), float("nan")) for i in state.pending]
            table["cut_from"] = [
                self.maneuvers[i].duration if str(i) in state.cuts else None for i in state.pending
            ]
            if self.cfg.safety.stop == "live":  # the driver brakes this close to a wall (m, the car's centre)
                table["brake_within_m"] = self.cfg.safety.margin + self.cfg.safety.stop_buffer
        atomic_write_bytes(path, table.to_csv(index=False).encode())
        return path

    def _family_proposals(self, path: Path, driven: list[Any]) -> pd.DataFrame:
        """Family proposals: parameters per row, and beside the file each one's schedule (written first)."""
        rate = self.cfg.simulation.rate_hz
        folder = path.with_suffix("")  # proposals/round-NNN/
        schedules = []
        for n, m in enumerate(driven):
            name = f"{n + 1:02d}-{m.name}.csv"
            atomic_write_bytes(folder / name, schedule_table(m, rate).to_csv(index=False).encode())
            schedules.append(f"{folder.name}/{name}")
        return proposal_table(driven, schedules)

    def _reference_proposals(self, state: CampaignState) -> pd.DataFrame:
        assert state.pending is not None
        rows = [
            {"maneuver": m.kind, "direction": m.direction, "throttle": m.throttle, "steering": m.steering,
             "duration": m.duration}
            for m in (self.driven(i) for i in state.pending)
        ]  # fmt: skip
        return pd.DataFrame(rows, columns=list(PROPOSAL_COLUMNS))

    @lock.writer
    def tell(self, logs: Sequence[pd.DataFrame], *, figures: bool = True) -> list[Any]:
        """Tell: logs of the pending batch, one per proposal, in proposal order; then propose the next.

        `activelearn campaign ingest` matches logs to proposals first (see `activelearn.loop.asktell`);
        this is the plain Python form. Returns the next proposals ([] once finished).
        """
        if not (self.directory / STATE_FILE).exists():
            raise InputError("directory", str(self.directory), "holds no campaign: call propose() first")
        state, samples = self._open(resume=True)
        if state.pending is None:
            raise InputError("logs", len(logs), "no batch is pending: call propose() first")
        if len(logs) != len(state.pending):
            raise InputError("logs", len(logs), f"the pending batch has {len(state.pending)} maneuvers")
        new = self._label(logs, state.pending, len(state.batches))
        samples = self._guarded(state, lambda: self._receive(state, samples, new))
        return self.propose(resume=True, figures=figures)


def _load_prior_model(spec: str, cfg: CampaignConfig) -> Any:
    """Weights to start from: a model.pt or a campaign directory; they must fit the config's inputs."""
    path = Path(spec)
    if path.is_dir():
        path = path / MODEL_FILE
    if not path.is_file():
        raise InputError("design.prior.model", spec, "no such model file or campaign directory")
    try:
        model = load_model(path)
    except Exception as exc:
        raise InputError("design.prior.model", spec, f"cannot read the model: {exc}") from None
    if model.n_inputs != cfg.model.n_inputs or model.config.n_outputs != cfg.model.n_outputs:
        raise InputError(
            "design.prior.model", spec,
            f"has {model.n_inputs} inputs / {model.config.n_outputs} outputs, the config "
            f"{cfg.model.n_inputs} / {cfg.model.n_outputs} (data.inputs = {cfg.data.inputs!r})",
        )  # fmt: skip
    return model


def load_model_copy(model: Any) -> Any:
    """An independent copy of a model (same class, config and weights), to fine-tune."""
    copy = build_model(model.config)
    copy.load_state_dict(model.state_dict())
    return copy


def load_campaign_model(directory: str | Path) -> Any:
    """The model of a campaign's last round."""
    return load_model(Path(directory) / MODEL_FILE)


def default_directory(cfg: CampaignConfig) -> Path:
    """runs/<config name>/<strategy>/seed<k>."""
    return Path(cfg.output_dir) / cfg.name / cfg.strategy / f"seed{cfg.seed}"


def total_rounds(cfg: CampaignConfig, pool_size: int) -> int:
    """Upper bound on the number of fitted rounds (for progress bars)."""
    n = min(cfg.design.max_maneuvers or pool_size, pool_size)
    if cfg.design.max_sim_seconds is not None:
        shortest = min([cfg.pool.duration, *cfg.pool.durations.values()]) + cfg.design.setup_seconds
        n = min(n, int(cfg.design.max_sim_seconds // shortest))
    rounds = math.ceil(max(0, n - cfg.design.initial) / cfg.design.per_round) + 1
    if cfg.design.max_rounds is not None:
        rounds = min(rounds, cfg.design.max_rounds + 1)
    return rounds
