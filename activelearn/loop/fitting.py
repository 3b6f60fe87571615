"""The model of each round: the data it trains on, the warm start's model, the four ways to fit it.

A round's model is, by the config:
  * fresh (the default): a new model trained on everything collected, plus a prior that is data;
  * fine-tuned (`[design.prior] use = "finetune"` or given weights): a copy of the prior's model;
  * residual (`use = "residual"`): the prior's model plus a fresh model of the difference from it;
  * warm-started (`[training] warm_start`): round r starts from round r - 1's model, kept in warm/.
Every fit is seeded by (campaign seed, round), so a resumed campaign refits the same model.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from activelearn.config import CampaignConfig, TrainingConfig
from activelearn.errors import InputError
from activelearn.loop.collection import (
    TARGETS,
    arrays,
    control_rate_logs,
    feature_columns,
    training_rows,
    training_windows,
)
from activelearn.loop.evaluation import EVAL_SAMPLES
from activelearn.loop.prior import Prior
from activelearn.loop.state import MODEL_FILE, PRIOR_MODEL_FILE
from activelearn.numerics.models import ResidualModel, build_model, load_model, model_class, save_model
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from activelearn.seeds import Stream, derived_seed

WARM_DIR = "warm"  # each round's model, kept for the next warm-started round

Rows = tuple[np.ndarray, np.ndarray, np.ndarray]


class Fitting:
    """Fits a campaign's rounds: training data (with the prior's), the prior's model, the warm store.

    `prior` is the warm start's data (None without one); the campaign sets it when it opens its
    directory, and scripts may set it to study a prior alone.
    """

    def __init__(self, cfg: CampaignConfig, directory: str | Path) -> None:
        self.cfg = cfg
        self.directory = Path(directory)
        self.prior: Prior | None = None
        self._prior_model: Any | None = None

    # ------------------------------------------------------------------ data

    def rows(self, samples: pd.DataFrame) -> Rows:
        """Inputs, targets and pool index of every training row of `samples` (no prior rows)."""
        if samples.empty:
            n_in = len(feature_columns(self.cfg.data))
            return np.zeros((0, n_in)), np.zeros((0, len(TARGETS))), np.zeros(0, dtype=int)
        rows = pd.concat(
            [training_rows(part, self.cfg.data) for _, part in samples.groupby("pool_index", sort=False)]
        )
        x, y = arrays(rows, self.cfg.data)
        return x, y, rows["pool_index"].to_numpy()

    def with_prior(self, samples: pd.DataFrame) -> pd.DataFrame:
        """The logs a round trains on: the campaign's and, where the prior is data, the prior's."""
        if self.prior is not None and self.prior.trains:
            return pd.concat([self.prior.rows, samples], ignore_index=True)
        return samples

    @property
    def prior_of_another_car(self) -> bool:
        """The prior logs are another car's (`[design.prior] same_car = false`) and the model identifies
        itself on logs (`Model.identifies_on_logs`): they then only centre that identification."""
        prior = self.cfg.design.prior
        return model_class(self.cfg.model).identifies_on_logs and prior is not None and not prior.same_car

    def training_logs(self, samples: pd.DataFrame) -> pd.DataFrame:
        """The logs a round's model trains on: `with_prior`'s, but only the car's own once it has any
        where the prior is another car's (`prior_of_another_car`).

        Another car's rows, against this car's identified core, would teach the correction the other
        car's offset: on the twin, the nominal grid's rows dragged the correction to its bound towards
        the faster car (4 % of speed where only the grid had driven) while the core alone was within 1 %.
        """
        if self.prior_of_another_car and not samples.empty:
            return samples
        return self.with_prior(samples)

    def known_logs(self, samples: pd.DataFrame | None) -> pd.DataFrame | None:
        """Every log row the campaign holds of the car: the prior's runs and the collected maneuvers."""
        prior = self.prior.rows if self.prior is not None else None
        frames = [f for f in (prior, samples) if f is not None and not f.empty]
        return pd.concat(frames, ignore_index=True) if frames else None

    def training_data(self, samples: pd.DataFrame) -> Rows:
        """Inputs, targets and maneuver ids the model of a round trains on (`training_logs`' rows)."""
        return self.rows(self.training_logs(samples))

    def training_windows(self, samples: pd.DataFrame) -> Any:
        """Free-running windows for multi-step training (`[training] rollout_horizon`), else None."""
        horizon = self.cfg.training.rollout_horizon
        if not horizon:
            return None
        samples = self.training_logs(samples)
        if samples.empty:
            return None
        frames = [part for _, part in samples.groupby("pool_index", sort=False)]
        return training_windows(frames, self.cfg.data, horizon)

    def identification_logs(
        self, samples: pd.DataFrame
    ) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[Any], list[bool] | None] | None:
        """Each training log's (controls, rates) for a model that identifies itself on logs
        (`Model.identifies_on_logs`), its maneuver id (`pool_index`, as in the training rows' groups; the
        correction gate holds maneuvers out by it) and, with `[design.prior] same_car = false`, whether it
        is the prior's (of another car). None for other kinds."""
        if not model_class(self.cfg.model).identifies_on_logs:
            return None
        parts = self.with_prior(samples).groupby("pool_index", sort=False)
        ids = list(parts.groups)
        of_another_car = [int(i) < 0 for i in ids] if self.prior_of_another_car else None
        return control_rate_logs([part for _, part in parts]), ids, of_another_car

    def data(self, samples: pd.DataFrame) -> TrainingData:
        """Everything the model of a round trains on: rows, windows and, where it uses them, the logs."""
        x, y, groups = self.training_data(samples)
        windows = self.training_windows(samples)
        logs, log_groups, of_another_car = self.identification_logs(samples) or (None, None, None)
        return TrainingData(x, y, groups, windows, logs, log_groups, of_another_car)

    # ------------------------------------------------------------------ models

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
                self._prior_model = load_prior_model(prior_cfg.model, self.cfg)
            else:
                assert self.prior is not None
                x, y, groups = self.rows(self.prior.rows)
                model = build_model(self.cfg.model)
                seed = derived_seed(self.cfg.seed, Stream.PRIOR)
                fit(model, TrainingData(x, y, groups), self.cfg.training, seed=seed)
                self._prior_model = model
        return self._prior_model

    def fit(
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
        data = self.data(samples)
        seed = derived_seed(self.cfg.seed, Stream.ROUND, round_index)
        base = self.prior_model()
        use = self.cfg.design.prior.use if self.cfg.design.prior is not None else "data"
        another_car = base is not None and self.prior_of_another_car
        if base is not None and not another_car and use == "residual":
            residual = build_model(self.cfg.model)
            difference = data.y - base.predict(data.x, n_samples=EVAL_SAMPLES, seed=0).mean
            fit(residual, TrainingData(data.x, difference, data.groups), self.cfg.training, seed=seed)
            model: Any = ResidualModel(base, residual)
        elif base is not None and not another_car:
            model = load_model_copy(base)
            if len(data.x):
                training = self.cfg.training.model_copy(update={"reinit": False})
                fit(model, data, training, seed=seed, keep_scalers=True)
        else:
            # Another car's model (`same_car = false`) centres this car's identification
            # (`start_from_another_car`); with use = "finetune" every round starts from its core and
            # correction, otherwise a round is fresh or warm-started as without a prior.
            finetune = another_car and use == "finetune"
            model, training, keep_scalers = self._fresh_or_warm(None if finetune else previous)
            if another_car:
                model.start_from_another_car(base, correction=finetune)
            if finetune:
                training = training.model_copy(update={"reinit": False})
            fit(model, data, training, seed=seed, keep_scalers=keep_scalers)
        with torch.no_grad():
            model.epistemic_scale.fill_(epistemic_scale)
        return model

    def _fresh_or_warm(self, previous: Any | None) -> tuple[Any, TrainingConfig, bool]:
        """A round's model before it trains, how it trains and whether it keeps its scalers: with
        `[training] warm_start`, a copy of `previous` (the last round's) for `warm_epochs` epochs;
        otherwise a fresh one."""
        training = self.cfg.training
        if previous is None or not training.warm_start:
            return build_model(self.cfg.model), training, False
        epochs = training.warm_epochs or max(1, training.epochs // 4)
        warm = training.model_copy(update={"reinit": False, "epochs": epochs})
        return load_model_copy(previous), warm, True

    # ------------------------------------------------------------------ the warm-model store

    def _warm_path(self, round_index: int) -> Path:
        return self.directory / WARM_DIR / f"round{round_index:03d}.pt"

    def previous_model(self, round_index: int) -> Any | None:
        """The model a warm-started round begins from: round r - 1's, as committed (None: start fresh).

        Kept per round (not model.pt, which a crash between its write and state.json's could leave one
        round ahead), so a resumed round starts from exactly the weights the uninterrupted run used.
        """
        if not self.cfg.training.warm_start or round_index == 0:
            return None
        path = self._warm_path(round_index - 1)
        return load_model(path) if path.exists() else None

    def keep_warm_model(self, model: Any, round_index: int) -> None:
        """Store round r's model for round r + 1 (before the commit point); drop older ones."""
        if not self.cfg.training.warm_start:
            return
        save_model(model, self._warm_path(round_index))
        for old in self._warm_path(0).parent.glob("round*.pt"):
            if old.name < self._warm_path(max(round_index - 1, 0)).name:
                old.unlink(missing_ok=True)


def load_prior_model(spec: str, cfg: CampaignConfig) -> Any:
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
    same_car = cfg.design.prior is None or cfg.design.prior.same_car
    if same_car and model.config.vehicle != cfg.model.vehicle:
        raise InputError("design.prior.model", spec, f"is a model of {model.config.vehicle!r}, the campaign "
                         f"drives {cfg.model.vehicle!r}: set [design.prior] same_car = false")  # fmt: skip
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
