"""The active-learning outer loop: fit, evaluate, select, collect, checkpoint, repeat.

One campaign = one config, one strategy, one seed. Every strategy shares the initial design, the
budget, the candidate pool, the test set and the training recipe; only `Strategy.select` differs.

Round r fits a fresh model on the data collected so far (seeded by (seed, r)), evaluates it on the
fixed test set and logs the metrics at step = number of training samples, then selects and collects
the next batch. After every round the directory holds a consistent checkpoint (samples.parquet,
model.pt, state.json, the latter written last as the commit point), so a campaign killed at any
moment resumes from its last round and ends with the same data and metrics as an uninterrupted run.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from activelearn.config import CampaignConfig
from activelearn.data import atomic_write_bytes, read_table, write_table
from activelearn.errors import ActiveLearnError, InputError
from activelearn.loop.acquisition import Pool, Strategy, greedy_maximin, make_strategy
from activelearn.loop.collection import (
    SimulationCache,
    TestSet,
    arrays,
    build_test_set,
    noisy_logs,
    rows_per_maneuver,
    training_rows,
)
from activelearn.loop.pool import build_pool, evaluation_grid, pool_maneuvers, test_maneuvers
from activelearn.numerics import uncertainty
from activelearn.numerics.models import Prediction, build_model, load_model, save_model
from activelearn.numerics.surrogate import model_inputs
from activelearn.numerics.training import fit
from activelearn.numerics.uncertainty import recalibrate_epistemic

STATE_FILE = "state.json"
SAMPLES_FILE = "samples.parquet"
MODEL_FILE = "model.pt"
EVAL_SAMPLES = 64  # posterior draws for test metrics and uncertainty maps

Progress = Callable[[dict[str, Any]], None]


class CampaignInterrupted(ActiveLearnError):
    """The campaign was stopped by the user; its directory can be resumed."""


def config_hash(cfg: CampaignConfig) -> str:
    """Hash of everything that determines a campaign's data except strategy and seed."""
    payload = cfg.model_dump(mode="json", exclude={"strategy", "seed", "tracking", "output_dir", "name"})
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


@dataclass
class CampaignState:
    """What a checkpoint records besides the samples and the model."""

    config_hash: str
    strategy: str
    seed: int
    batches: list[list[int]] = field(default_factory=list)  # pool indices collected, batch 0 = initial
    rounds: list[dict[str, Any]] = field(default_factory=list)  # metrics of each fitted round
    logged: int = 0  # rounds already written to MLflow
    model_logged: bool = False
    run_id: str | None = None
    finished: bool = False
    stop_reason: str | None = None
    wall_seconds: float = 0.0

    @property
    def taken(self) -> list[int]:
        """All collected pool indices in collection order."""
        return [i for batch in self.batches for i in batch]

    def save(self, directory: Path) -> None:
        """Write the state atomically (the checkpoint's commit point)."""
        atomic_write_bytes(directory / STATE_FILE, json.dumps(dataclasses.asdict(self), indent=1).encode())

    @classmethod
    def load(cls, directory: Path) -> CampaignState:
        """Read a saved state."""
        return cls(**json.loads((directory / STATE_FILE).read_text()))


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
        )
        self.cache = SimulationCache(cache_dir or Path(cfg.output_dir) / "cache", cfg.simulation)
        self.tracker = tracker
        self.parent_run_id = parent_run_id
        self.progress = progress or (lambda event: None)
        self.maneuvers = pool_maneuvers(cfg.pool)
        if len(self.maneuvers) < cfg.design.initial + 1:
            raise InputError(
                "pool", len(self.maneuvers), "the pool must hold more maneuvers than design.initial"
            )
        self.rows_per_maneuver = rows_per_maneuver(cfg.pool.duration, cfg.simulation, cfg.data)
        self._test: TestSet | None = None
        self._truth: dict[str, np.ndarray] | None = None

    # ------------------------------------------------------------------ data

    @property
    def test_set(self) -> TestSet:
        """The fixed test set (simulated once per config, then read from the cache)."""
        if self._test is None:
            self._test = build_test_set(
                test_maneuvers(self.cfg.test),
                self.cache,
                self.cfg.simulation.noise,
                self.cfg.data,
                self.cfg.test.noise_seed,
            )
        return self._test

    def _collect(self, indices: list[int], batch: int) -> pd.DataFrame:
        """Simulate (or read from cache) the chosen maneuvers and add this campaign's noise."""
        chosen = [self.maneuvers[i] for i in indices]
        clean = self.cache.get(chosen)
        frames = noisy_logs(clean, chosen, self.cfg.simulation.noise, self.cfg.seed)
        for frame, index in zip(frames, indices, strict=True):
            frame["pool_index"] = index
            frame["batch"] = batch
        return pd.concat(frames, ignore_index=True)

    def _training_data(self, samples: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rows = pd.concat(
            [training_rows(part, self.cfg.data) for _, part in samples.groupby("pool_index", sort=False)]
        )
        x, y = arrays(rows, self.cfg.data)
        return x, y, rows["pool_index"].to_numpy()

    def pool(self, taken: list[int], model: Any | None = None) -> Pool:
        """The candidate pool with `taken` marked as collected, its points as `model` inputs."""
        mask = np.zeros(len(self.maneuvers), dtype=bool)
        mask[taken] = True
        pool = build_pool(
            self.cfg, self.maneuvers, mask, self.test_set.scale, self.rows_per_maneuver, self.cfg.seed
        )
        if self.cfg.strategy == "oracle_error":
            pool = dataclasses.replace(pool, **self._pool_truth())
        if model is None or model.n_inputs == pool.points.shape[1]:
            return pool
        return dataclasses.replace(
            pool, points=model_inputs(model, pool.points), eval_grid=model_inputs(model, pool.eval_grid)
        )

    def _pool_truth(self) -> dict[str, np.ndarray]:
        """Noise-free training rows of every candidate, for the diagnostic oracle strategy only."""
        if self._truth is None:
            clean = self.cache.get(self.maneuvers)
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

    def fit_model(self, samples: pd.DataFrame, round_index: int, epistemic_scale: float = 1.0) -> Any:
        """Train a fresh model on all samples, seeded by (seed, round), with a given epistemic scale."""
        x, y, groups = self._training_data(samples)
        model = build_model(self.cfg.model)
        fit(model, x, y, self.cfg.training, groups=groups, seed=self.cfg.seed * 10_007 + round_index)
        with torch.no_grad():
            model.epistemic_scale.fill_(epistemic_scale)
        return model

    def prequential_scale(self, model: Any, new_samples: pd.DataFrame) -> float:
        """Epistemic scale that would have calibrated `model` on the maneuvers collected after it.

        Those maneuvers were not in the model's training data, so they are honest held-out operating
        points. Rows with the same controls in one maneuver are averaged (steady maneuvers become one
        nearly noise-free target); the rest keep their aleatoric variance in the likelihood.
        """
        x, y, pool_index = self._training_data(new_samples)
        keys = np.column_stack([pool_index, np.round(x[:, :2], 4)])
        _, groups = np.unique(keys, axis=0, return_inverse=True)
        previous = float(model.epistemic_scale)
        scale = recalibrate_epistemic(model, x, y, groups=groups.ravel(), n_samples=EVAL_SAMPLES)
        with torch.no_grad():
            model.epistemic_scale.fill_(previous)  # the checkpointed model keeps the scale it was used with
        return scale

    def _applied_scale(self, state: CampaignState) -> float:
        """Geometric mean of the last two prequential scales (1 before any was measured).

        Only recent rounds count: a model trained on few maneuvers errs far more between its points
        than one trained on many, so old scales would inflate the variance of later models.
        """
        if self.cfg.design.recalibrate == "none":
            return 1.0
        scales = [r["prequential_scale"] for r in state.rounds if "prequential_scale" in r][-2:]
        return float(np.exp(np.mean(np.log(scales)))) if scales else 1.0

    def evaluate(self, model: Any) -> dict[str, float]:
        """Test-set accuracy and calibration, and uncertainty over the evaluation grid."""
        test = self.test_set
        pred = model.predict(test.x, n_samples=EVAL_SAMPLES, seed=0)
        std_pred = _standardise(pred, test.scale)
        clean, noisy = test.y_clean / test.scale, test.y_noisy / test.scale
        err = pred.mean - test.y_clean
        metrics = {
            "test_rmse": float(np.sqrt(np.mean((std_pred.mean - clean) ** 2))),
            "test_rmse_v": float(np.sqrt(np.mean(err[:, 0] ** 2))),
            "test_rmse_w": float(np.sqrt(np.mean(err[:, 1] ** 2))),
            "test_nll": float(uncertainty.gaussian_nll(noisy, std_pred)),
            "test_crps": float(uncertainty.crps(noisy, std_pred)),
            "coverage_95": float(uncertainty.coverage(noisy, std_pred, level=0.95)),
        }
        diag = uncertainty.epistemic_diagnostic(clean, std_pred)
        metrics.update({f"calib_{k}": float(v) for k, v in diag.items() if np.isscalar(v)})
        _, _, grid = evaluation_grid(self.cfg)
        grid_pred = _standardise(
            model.predict(model_inputs(model, grid), n_samples=EVAL_SAMPLES, seed=0), test.scale
        )
        epi = np.sqrt(grid_pred.epistemic_var).mean(axis=1)
        metrics["epistemic_std_mean"] = float(epi.mean())
        metrics["epistemic_std_max"] = float(epi.max())
        metrics["aleatoric_std_mean"] = float(np.sqrt(grid_pred.aleatoric_var).mean())
        return metrics

    def pool_epistemic_max(self, model: Any, pool: Pool) -> float:
        """Largest candidate epistemic std (standardised, averaged over outputs and the maneuver)."""
        pred = _standardise(model.predict(pool.points, n_samples=EVAL_SAMPLES, seed=0), pool.output_scale)
        per_point = np.sqrt(pred.epistemic_var).mean(axis=1)
        per_candidate = np.bincount(pool.owner, weights=per_point) / np.bincount(pool.owner)
        return float(per_candidate[pool.available].max()) if len(pool.available) else 0.0

    # ------------------------------------------------------------------ budget

    def _sim_seconds(self, taken: list[int]) -> float:
        return float(sum(self.maneuvers[i].duration for i in taken))

    def next_batch_size(self, state: CampaignState) -> tuple[int, str | None]:
        """How many maneuvers the next round may collect, or 0 and the reason to stop."""
        design = self.cfg.design
        n = len(state.taken)
        k = design.per_round
        if design.max_rounds is not None and len(state.batches) - 1 >= design.max_rounds:
            return 0, "max_rounds"
        if design.max_maneuvers is not None:
            k = min(k, design.max_maneuvers - n)
            if k <= 0:
                return 0, "max_maneuvers"
        if design.max_sim_seconds is not None:
            room = int((design.max_sim_seconds - self._sim_seconds(state.taken)) // self.cfg.pool.duration)
            k = min(k, room)
            if k <= 0:
                return 0, "max_sim_seconds"
        k = min(k, len(self.maneuvers) - n)
        if k <= 0:
            return 0, "pool_exhausted"
        return k, None

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
            samples = read_table(self.directory / SAMPLES_FILE)
            # Rows of a batch whose state never committed are dropped; the round is redone identically.
            samples = samples[samples["batch"] < len(state.batches)].reset_index(drop=True)
            return state, samples
        return CampaignState(expected, self.cfg.strategy, self.cfg.seed), pd.DataFrame()

    def _checkpoint(self, state: CampaignState, samples: pd.DataFrame, model: Any | None) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        write_table(samples, self.directory / SAMPLES_FILE)
        if model is not None:
            save_model(model, self.directory / MODEL_FILE)
        state.save(self.directory)  # last: the commit point

    # ------------------------------------------------------------------ tracking

    def _start_tracking(self, state: CampaignState) -> None:
        if self.tracker is None:
            return
        name = f"{self.cfg.name}-{self.cfg.strategy}-seed{self.cfg.seed}"
        state.run_id = self.tracker.start_run(
            name,
            parent_run_id=self.parent_run_id,
            resume_run_id=state.run_id,
            tags={"strategy": self.cfg.strategy, "seed": str(self.cfg.seed), "config": self.cfg.name},
        )
        self.tracker.log_params(state.run_id, self.cfg.model_dump(mode="json"))

    def _flush_metrics(self, state: CampaignState) -> None:
        if self.tracker is None or state.run_id is None:
            return
        for record in state.rounds[state.logged :]:
            self.tracker.log_metrics(state.run_id, record, step=int(record["n_samples"]))
            figure_path = self.directory / "figures" / f"epistemic_round{int(record['round']):02d}.png"
            if figure_path.exists():
                self.tracker.log_artifact(state.run_id, figure_path, "figures")
            state.logged += 1
        state.save(self.directory)

    def _figure(self, model: Any, state: CampaignState, picks: list[int], round_index: int) -> None:
        from activelearn.plots import epistemic_map  # matplotlib only when figures are drawn

        throttles, steerings, grid = evaluation_grid(self.cfg)
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
            title=f"{self.cfg.strategy}, seed {self.cfg.seed}, round {round_index}",
        )
        path = self.directory / "figures" / f"epistemic_round{round_index:02d}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.png")
        fig.savefig(tmp, dpi=90)
        tmp.replace(path)

    # ------------------------------------------------------------------ the loop

    def run(self, *, resume: bool = False, figures: bool = True, log_model: bool = True) -> CampaignResult:
        """Run (or resume) the campaign to its budget or stop rule."""
        state, samples = self._load(resume)
        self._start_tracking(state)
        started = time.perf_counter()
        base_wall = state.wall_seconds
        model = None
        try:
            if state.rounds:  # a resumed run may hold rounds that never reached MLflow
                self._flush_metrics(state)
            if not state.batches:
                initial = greedy_maximin(self.pool([]), self.cfg.design.initial, _rng(self.cfg.seed, 0x1D))
                samples = self._collect(initial, 0)
                state.batches.append(initial)
                self._checkpoint(state, samples, None)
            while not state.finished:
                round_index = len(state.rounds)
                self.progress({"event": "fit", "round": round_index, "n_maneuvers": len(state.taken)})
                scale = self._applied_scale(state)
                model = self.fit_model(samples, round_index, scale)
                x, _, _ = self._training_data(samples)
                metrics: dict[str, Any] = {
                    "round": round_index,
                    "epistemic_scale": scale,
                    **self.evaluate(model),
                }
                metrics.update(
                    n_samples=len(x),
                    n_maneuvers=len(state.taken),
                    sim_seconds=self._sim_seconds(state.taken),
                )
                pool = self.pool(state.taken, model)
                k, reason = self.next_batch_size(state)
                if reason is None and self.cfg.design.stop_epistemic_std is not None:
                    metrics["pool_epistemic_std_max"] = self.pool_epistemic_max(model, pool)
                    if metrics["pool_epistemic_std_max"] < self.cfg.design.stop_epistemic_std:
                        reason = "stop_epistemic_std"
                picks: list[int] = []
                if reason is None:
                    picks = self.strategy.select(model, pool, k, _rng(self.cfg.seed, round_index, 0x5E1))
                if figures:
                    self._figure(model, state, picks, round_index)
                if picks:
                    new = self._collect(picks, len(state.batches))
                    if self.cfg.design.recalibrate == "prequential" and model.has_epistemic:
                        metrics["prequential_scale"] = self.prequential_scale(model, new)
                    samples = pd.concat([samples, new], ignore_index=True)
                    state.batches.append(picks)
                metrics["wall_seconds"] = base_wall + time.perf_counter() - started
                state.wall_seconds = metrics["wall_seconds"]
                state.rounds.append(metrics)
                if reason is not None:
                    state.finished, state.stop_reason = True, reason
                self._checkpoint(state, samples, model)
                self._flush_metrics(state)
                self.progress({"event": "round", **metrics, "picks": [self.maneuvers[i].name for i in picks]})
        except KeyboardInterrupt:
            if self.tracker is not None and state.run_id is not None:
                self.tracker.end_run(state.run_id, "KILLED")
            raise CampaignInterrupted(
                f"interrupted; {self.directory} holds the last finished round: rerun with --resume"
            ) from None
        except BaseException:
            if self.tracker is not None and state.run_id is not None:
                self.tracker.end_run(state.run_id, "FAILED")
            raise
        if self.tracker is not None and state.run_id is not None:
            if log_model and not state.model_logged:
                self.tracker.log_model(state.run_id, model or load_model(self.directory / MODEL_FILE))
                state.model_logged = True
                state.save(self.directory)
            self.tracker.end_run(state.run_id, "FINISHED")
        return CampaignResult(self.directory, state)


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
        n = min(n, int(cfg.design.max_sim_seconds // cfg.pool.duration))
    rounds = math.ceil(max(0, n - cfg.design.initial) / cfg.design.per_round) + 1
    if cfg.design.max_rounds is not None:
        rounds = min(rounds, cfg.design.max_rounds + 1)
    return rounds
