"""The [model] and [training] sections: what a surrogate is and how `numerics.training.fit` trains it."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator

from activelearn.config.base import POSE_LEVER_ARM, _Section
from activelearn.numerics.arch import ACTIVATIONS, parse_arch

ModelKind = Literal["hybrid", "pbnn", "pnn", "bnn", "dnn", "ensemble", "recurrent", "physics"]
Activation = Literal[ACTIVATIONS]  # type: ignore[valid-type]


class ModelConfig(_Section):
    """Which network to build and how its Bayesian layers are parameterised."""

    kind: ModelKind = "hybrid"
    # Spec string (e.g. "V8-D32-D32-D8-V") or a preset name from ARCH_PRESETS. Baselines reuse the
    # widths: pbnn/bnn turn every layer variational, pnn/dnn/ensemble turn every layer dense.
    arch: str = "default"
    # Activation of tokens that do not name their own.
    activation: Activation = "relu"
    posterior: Literal["mean_field", "full_cov"] = "mean_field"
    kl: Literal["exact", "mc"] = "exact"
    kl_samples: int = Field(1, description="weight draws per step for the Monte Carlo KL")
    prior_scale: float = 1.0
    prior_trainable: bool = False
    # Initial posterior std of every variational weight (weight units, inputs are standardised).
    posterior_init_std: float = 0.01
    ensemble_size: int = 5
    # Floor of the Gaussian head's std, in standardised output units.
    min_std: float = 1e-3
    n_inputs: int = 2
    n_outputs: int = 2
    # Log steps between the lagged inputs of a dynamic model (`activelearn.numerics.lags`); a campaign
    # sets it from [data] history_step. The forward simulation reads it from the saved model.
    history_step: int = 1
    # Metres the logged position lies ahead of the rear axle; free runs place their paths there
    # (`activelearn.numerics.surrogate`). A campaign sets it from [data] pose_lever_arm.
    pose_lever_arm: Annotated[float, Field(ge=-1.0, le=1.0)] = POSE_LEVER_ARM
    # Width of the recurrent model's GRU trunk (kind = "recurrent"): it reads the history window as a
    # sequence of (controls, rates) tokens, oldest first; the layers of `arch` form its head.
    hidden_size: int = 32
    # Also feed the network the kinematic yaw-rate proxy, a speed times tan(steering): throttle ×
    # tan(steering) for a static map, the newest past speed × tan(current steering) for a dynamic one.
    # A steady turn's ω is about v·tan(δ)/L: with the product as an input the net need not build it
    # from few operating points (measured: half the static map's free-run error on eights, see the
    # docs/results/models.md). Derived inside the model, so data, rollouts and kernels are unchanged.
    kinematic_feature: bool = False
    # kind = "physics" (`activelearn.numerics.models.physics`): Nigel's single track from its datasheet,
    # its physical parameters identified from the training logs, plus a Bayesian correction of this kind
    # (same arch, activation and ensemble_size) that learns only what the physics misses.
    # The correction's defaults (hybrid, bound 0.05) beat the ensemble with bound 0.2 and the bare identified
    # single track on 4 of 4 fresh seeds after 4 cold-start signals (experiments/results/physics.txt).
    correction: Literal["ensemble", "hybrid"] = Field(
        "hybrid", description="kind = 'physics': the Bayesian correction's kind"
    )
    identify: bool = Field(
        True, description="kind = 'physics': fit the physical parameters to the training logs before training"
    )
    residual_bound: Annotated[float, Field(ge=0.0, le=0.5)] = Field(
        0.05,
        description="kind = 'physics': largest learnt change of a steady rate, times its limit",
    )
    correction_inputs: Literal["control", "history"] = Field(
        "history",
        description="kind = 'physics': what the correction reads: the newest control (the operating "
        "point; free runs then evaluate it once per distinct control) or the whole input window",
    )
    # Where the logs allow, a probe trained without a quarter of the training maneuvers decides how
    # much of the correction's mean to keep (0, 1/2 or all) by free runs of the held-out ones; its
    # posterior spread (the epistemic band) is kept whatever the choice. The correction fits one-step
    # targets and, with little data, drags free runs away from the identified core
    # (experiments/results/physics.txt).
    correction_gate: bool = Field(
        False,
        description="kind = 'physics': keep the correction's mean only as far as it beats the identified "
        "core on held-out maneuvers (a probe fit without a quarter of them)",
    )

    @model_validator(mode="after")
    def _check_kinematic_feature(self) -> ModelConfig:
        if self.kinematic_feature and self.kind in ("recurrent", "physics"):
            why = "its trunk reads tokens" if self.kind == "recurrent" else "its physics knows the kinematics"
            raise ValueError(f"kinematic_feature: not for kind = {self.kind!r} ({why})")
        return self

    @field_validator("arch")
    @classmethod
    def _check_arch(cls, value: str) -> str:
        try:
            parse_arch(value)
        except ValueError as exc:
            raise ValueError(f"arch: {exc}") from None
        return value

    @field_validator("prior_scale", "posterior_init_std", "min_std")
    @classmethod
    def _check_positive(cls, value: float, info) -> float:
        if not value > 0:
            raise ValueError(f"{info.field_name} must be > 0, got {value!r}")
        return value

    @field_validator("kl_samples", "n_inputs", "n_outputs", "history_step", "hidden_size")
    @classmethod
    def _check_count(cls, value: int, info) -> int:
        if value < 1:
            raise ValueError(f"{info.field_name} must be >= 1, got {value!r}")
        return value

    @field_validator("ensemble_size")
    @classmethod
    def _check_ensemble(cls, value: int) -> int:
        if value < 2:
            raise ValueError(f"ensemble_size must be >= 2, got {value!r}")
        return value


KLCount = Literal["rows", "maneuvers", "sqrt"]


class TrainingConfig(_Section):
    """How `activelearn.numerics.training.fit` trains a model."""

    # Data term of the ELBO. "nll" = Gaussian NLL (the head's variance is learnt); "mse"/"mae" fit the
    # mean only, as the reference study did (the head's scale then receives no gradient).
    loss: Literal["nll", "mse", "mae"] = "nll"
    optimizer: Literal["adam", "rmsprop", "sgd"] = "adam"
    lr: float = 1e-3
    # "cosine" anneals the learning rate to 1% of `lr` over `epochs`: the final weights then stop
    # wandering with the minibatch noise, which makes fits on a fixed budget far less seed-dependent.
    lr_schedule: Literal["constant", "cosine"] = "constant"
    momentum: float = 0.9
    weight_decay: float = 0.0
    epochs: int = 400
    batch_size: int = 64
    # Epochs without a better validation NLL before stopping; None trains all epochs.
    patience: int | None = 60
    # N in KL/N: "rows" = training rows, "maneuvers" = distinct `groups`, "sqrt" = √(rows × maneuvers), or a
    # positive number used as is (without groups every row is its own maneuver). Default "sqrt", measured
    # (experiments/investigations/model_selection.py klsize): held-out z spread before recalibration stays in
    # 0.8-1.6 from 8 to 40 operating points and 60 to 600 rows per point, where "rows" drifts from 1.4 to 5.1
    # (overconfident as rows per maneuver grow) and "maneuvers" to 0.7 (underconfident).
    kl_count: KLCount | float = "sqrt"
    # Extra multiplier on KL/N (cold/warm posterior tempering); 1 is the plain ELBO.
    kl_weight: float = 1.0
    # Posterior samples used for the per-epoch validation metrics.
    n_eval_samples: int = 16
    # Fit `epistemic_scale` on the validation set after training ("validation"), or leave it at 1.
    recalibrate: Literal["none", "validation"] = "none"
    # Re-initialise the weights from `seed` before training (reproducible); False continues training.
    reinit: bool = True
    # Compile the whole training step (forward, backward, update) with torch.compile: ~5x faster per
    # step, after a one-off compile of ~5-20 s. "auto" compiles fits of >= 40,000 steps.
    compile: bool | Literal["auto"] = "auto"
    # torch intra-op threads during fit (restored afterwards); these layers are too small to gain
    # from more threads, and one thread avoids contention. None leaves torch's setting alone.
    num_threads: int | None = 1
    # Campaigns: start each round from the previous round's weights (and scalers) and train
    # `warm_epochs` epochs (default a quarter of `epochs`) instead of a fresh model for `epochs`.
    warm_start: bool = False
    warm_epochs: int | None = None
    # Multi-step training of dynamic models: beside the one-step loss, the Gaussian NLL of free runs
    # of `rollout_horizon` log steps (the model fed its own mean predictions, back-propagated through
    # the whole window), `rollout_batch` windows on every `rollout_every`-th step, weighted by
    # `rollout_weight` (times `rollout_every`, so the weight per epoch does not depend on it). 0: off.
    rollout_horizon: Annotated[int, Field(ge=0, le=900)] = 0
    rollout_weight: Annotated[float, Field(gt=0)] = 1.0
    rollout_batch: Annotated[int, Field(ge=1)] = 32
    # The window loss joins every n-th optimiser step: a window of H steps costs H small forward and
    # backward passes (measured ~0.2 s per step on a busy 2-core machine at H = 30, batch 32).
    rollout_every: Annotated[int, Field(ge=1)] = 8
    # Largest global gradient norm of a step while windows train (0: no clipping). Back-propagation
    # through a free run can explode: unclipped, the Markov model trained on 30-step windows ran free
    # to infinity on every kind; clipped at 1 its free runs stayed within 0.12-0.16 m at 30 s.
    rollout_clip: Annotated[float, Field(ge=0)] = 1.0

    @field_validator("lr")
    @classmethod
    def _check_lr(cls, value: float) -> float:
        if not value > 0:
            raise ValueError(f"lr must be > 0, got {value!r}")
        return value

    @field_validator("momentum", "weight_decay", "kl_weight")
    @classmethod
    def _check_non_negative(cls, value: float, info) -> float:
        if not value >= 0:
            raise ValueError(f"{info.field_name} must be >= 0, got {value!r}")
        return value

    @field_validator("epochs", "batch_size", "n_eval_samples")
    @classmethod
    def _check_count(cls, value: int, info) -> int:
        if value < 1:
            raise ValueError(f"{info.field_name} must be >= 1, got {value!r}")
        return value

    @field_validator("warm_epochs")
    @classmethod
    def _check_warm_epochs(cls, value: int | None) -> int | None:
        if value is not None and value < 1:
            raise ValueError(f"warm_epochs must be >= 1 or None, got {value!r}")
        return value

    @field_validator("num_threads")
    @classmethod
    def _check_threads(cls, value: int | None) -> int | None:
        if value is not None and value < 1:
            raise ValueError(f"num_threads must be >= 1 or None, got {value!r}")
        return value

    @field_validator("patience")
    @classmethod
    def _check_patience(cls, value: int | None) -> int | None:
        if value is not None and value < 1:
            raise ValueError(f"patience must be >= 1 or None, got {value!r}")
        return value

    @field_validator("kl_count")
    @classmethod
    def _check_kl_count(cls, value: str | float) -> str | float:
        if isinstance(value, str):
            return value
        if not value > 0:
            raise ValueError(f"kl_count must be 'rows', 'maneuvers', 'sqrt' or a number > 0, got {value!r}")
        return float(value)

