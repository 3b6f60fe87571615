"""The [tuning] section: what `activelearn tune` searches (its space) and the study's settings.

Read by `activelearn tune` only; `CampaignConfig` excludes it from dumps, so campaign hashes, logged
params and the configs sent to workers do not depend on it.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, ValidationError, ValidationInfo, field_validator, model_validator

from activelearn.config.base import Count, _Section
from activelearn.numerics.arch import ACTIVATIONS

SpaceKind = Literal["float", "int", "bool", "choice"]
# Every tunable parameter: its kind and, for choices, the allowed values. Widths apply per hidden
# layer: dense layers draw from `width`, variational ones from `variational_width` (a full-covariance
# posterior costs O(p²) in a layer's parameter count p, so variational layers stay narrow by default).
SPACE_PARAMS: dict[str, tuple[SpaceKind, tuple[Any, ...] | None]] = {
    "lr": ("float", None),
    "epochs": ("int", None),
    "batch_size": ("int", None),
    "activation": ("choice", ACTIVATIONS),
    "optimizer": ("choice", ("sgd", "rmsprop", "adam")),
    "loss": ("choice", ("nll", "mse", "mae")),
    "posterior": ("choice", ("mean_field", "full_cov")),
    "kl": ("choice", ("exact", "mc")),
    "prior_scale": ("float", None),
    "n_layers": ("int", None),
    "width": ("int", None),
    "variational_width": ("int", None),
    "variational": ("bool", None),
    "variational_head": ("bool", None),
    "hidden_size": ("int", None),
    # the physics kind's correction (read by kind = "physics" only)
    "correction": ("choice", ("ensemble", "hybrid")),
    "correction_inputs": ("choice", ("control", "history")),
    "correction_symmetry": ("choice", ("none", "mirror")),
    "residual_bound": ("float", None),
}
# Search-space parameters that may be left unset: trials then keep the config's [model] value.
OPTIONAL_SPACE_PARAMS = ("correction", "correction_inputs", "correction_symmetry", "residual_bound")
# Upper bounds that keep a sampled network buildable and trainable in reasonable time (and the
# physics correction's bound within ModelConfig's range).
_SPACE_MAX = {"n_layers": 8, "width": 1024, "variational_width": 1024, "hidden_size": 512}
_SPACE_MAX["residual_bound"] = 0.5


class Range(_Section):
    """A numeric interval of the search space: [low, high], optionally log-uniform or stepped."""

    low: int | float = Field(description="Lower end of the interval (inclusive)")
    high: int | float = Field(description="Upper end of the interval (inclusive)")
    log: bool = Field(False, description="Sample log-uniformly instead of uniformly")
    step: float | None = Field(
        None, description="Spacing of the values sampled from `low` on (not with `log`); unset: continuous"
    )


def _check_space_value(name: str, kind: SpaceKind, allowed: tuple[Any, ...] | None, value: Any) -> Any:
    """Validate one fixed value or choice of parameter `name`; return it in its canonical type."""
    if kind == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"takes true/false, got {value!r}")
        return value
    if kind == "choice":
        if value not in allowed:  # type: ignore[operator]
            raise ValueError(f"unknown value {value!r}; choose from {', '.join(allowed)}")  # type: ignore[arg-type]
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"takes a number, got {value!r}")
    if not math.isfinite(value):  # int(inf) would overflow; an infinite range cannot be sampled
        raise ValueError(f"must be finite, got {value!r}")
    if kind == "int":
        if value != int(value):
            raise ValueError(f"takes whole numbers, got {value!r}")
        value = int(value)
        if value < 1:
            raise ValueError(f"must be >= 1, got {value!r}")
        if name in _SPACE_MAX and value > _SPACE_MAX[name]:
            raise ValueError(f"must be <= {_SPACE_MAX[name]}, got {value!r}")
        return value
    if not value > 0:
        raise ValueError(f"must be > 0, got {value!r}")
    if name in _SPACE_MAX and value > _SPACE_MAX[name]:
        raise ValueError(f"must be <= {_SPACE_MAX[name]}, got {value!r}")
    return float(value)


def check_space_param(name: str, value: Any) -> Range | list[Any] | Any:
    """Validate one search-space entry: a fixed value, a list of choices or a {low, high} range."""
    kind, allowed = SPACE_PARAMS[name]
    if isinstance(value, list | tuple):
        if not value:
            raise ValueError("empty list of choices")
        choices = [_check_space_value(name, kind, allowed, v) for v in value]
        if len(set(choices)) != len(choices):
            raise ValueError(f"duplicate choices {choices}")
        return choices
    if isinstance(value, dict | Range):
        if kind not in ("float", "int"):
            raise ValueError("takes a value or a list of choices, not a range")
        try:
            rng = Range.model_validate(value if isinstance(value, dict) else value.model_dump())
        except ValidationError as exc:
            error = exc.errors()[0]
            where = ".".join(str(p) for p in error["loc"])
            raise ValueError(f"range {where}: {error['msg']}") from None
        low = _check_space_value(name, kind, allowed, rng.low)
        high = _check_space_value(name, kind, allowed, rng.high)
        if low > high:
            raise ValueError(f"empty range: low ({low!r}) > high ({high!r})")
        if rng.step is not None:
            if not rng.step > 0:
                raise ValueError(f"step must be > 0, got {rng.step!r}")
            if rng.log:
                raise ValueError("a range is either log or stepped, not both")
            if kind == "int" and rng.step != int(rng.step):
                raise ValueError(f"step must be a whole number, got {rng.step!r}")
        return Range(low=low, high=high, log=rng.log, step=rng.step)
    return _check_space_value(name, kind, allowed, value)


class SearchSpace(_Section):
    """What `activelearn tune` samples: per parameter a fixed value, a list of choices or a range.

    TOML forms: `optimizer = "adam"` (fixed), `activation = ["relu", "elu"]` (choices),
    `lr = { low = 1e-4, high = 1e-1, log = true }` or `epochs = { low = 20, high = 200, step = 10 }`.
    The network has `n_layers` hidden layers; each is variational or dense (`variational`), with a
    width from `variational_width` or `width`; `variational_head` makes the output layer variational.
    """

    model_config = ConfigDict(extra="forbid", validate_assignment=True, validate_default=True)

    lr: Any = Field(Range(low=1e-4, high=1e-1, log=True), description="Learning rate ([training] lr)")
    epochs: Any = Field(
        Range(low=20, high=200, step=10),
        description="Training epochs ([training] epochs; the largest is Hyperband's budget)",
    )
    batch_size: Any = Field([16, 32, 64, 128, 256], description="Rows per minibatch ([training] batch_size)")
    activation: Any = Field(
        list(ACTIVATIONS), description="Activation of every hidden layer ([model] activation)"
    )
    optimizer: Any = Field(["sgd", "rmsprop", "adam"], description="Optimiser ([training] optimizer)")
    loss: Any = Field(["nll", "mse", "mae"], description="Data term of the ELBO ([training] loss)")
    posterior: Any = Field(
        ["mean_field", "full_cov"], description="Posterior of the variational layers ([model] posterior)"
    )
    kl: Any = Field(["exact", "mc"], description="KL term, closed form or Monte Carlo ([model] kl)")
    prior_scale: Any = Field(
        Range(low=0.1, high=10.0, log=True), description="Std of the weight prior ([model] prior_scale)"
    )
    n_layers: Any = Field(Range(low=1, high=4), description="Hidden layers of the sampled `arch` (at most 8)")
    width: Any = Field([8, 16, 32, 64], description="Width of each dense hidden layer (drawn per layer)")
    variational_width: Any = Field(
        [4, 8, 16], description="Width of each variational hidden layer (drawn per layer)"
    )
    variational: Any = Field(
        [False, True], description="Whether each hidden layer is variational or dense (drawn per layer)"
    )
    # The read-out is variational by default: the model then always has epistemic uncertainty.
    variational_head: Any = Field(True, description="Whether the output layer is variational")
    # A history model's layout ([data] history, history_step) shapes the study's data: one study per layout.
    hidden_size: Any = Field(
        32, description="Width of the recurrent model's GRU trunk ([model] hidden_size; kind = 'recurrent')"
    )
    # The physics kind's correction (read by kind = "physics" only). Unset (None): the config's [model]
    # value, not searched.
    correction: Any = Field(
        None, description="kind = 'physics': the correction's kind ([model] correction); unset: not searched"
    )
    correction_inputs: Any = Field(
        None,
        description="kind = 'physics': what the correction reads ([model] correction_inputs); unset: not "
        "searched",
    )
    correction_symmetry: Any = Field(
        None,
        description="kind = 'physics': whether the correction is mirror-symmetric ([model] "
        "correction_symmetry); unset: not searched",
    )
    residual_bound: Any = Field(
        None,
        description="kind = 'physics': bound on the steady-state residuals ([model] residual_bound, at most "
        "0.5); unset: not searched",
    )

    @field_validator("*")
    @classmethod
    def _check_param(cls, value: Any, info: ValidationInfo) -> Any:
        if value is None and info.field_name in OPTIONAL_SPACE_PARAMS:
            return None
        return check_space_param(info.field_name, value)  # type: ignore[arg-type]


class TuningConfig(_Section):
    """`activelearn tune`: the search space, the validation split and the pruner/sampler settings."""

    space: SearchSpace = Field(SearchSpace(), description="What the trials sample")
    val_fraction: Annotated[float, Field(gt=0, lt=1)] = Field(
        0.2, description="Share of operating points (whole maneuvers) held out for validation"
    )
    sampler_startup_trials: Annotated[int, Field(ge=0)] = Field(
        10,
        description="TPE samples at random for this many first trials of each run, then models the good "
        "region",
    )
    pruner_startup_trials: Annotated[int, Field(ge=0)] = Field(
        5, description="MedianPruner: prune only once this many trials have completed"
    )
    pruner_warmup_epochs: Annotated[int, Field(ge=0)] = Field(
        10, description="MedianPruner: never prune a trial before this epoch"
    )
    hyperband_min_epochs: Count = Field(
        5, description="HyperbandPruner: the fewest epochs a trial runs before it can be stopped"
    )
    # Every trial is a new architecture: compiling would cost more than it saves (see training.py).
    compile: bool = Field(False, description="Compile the trials' training steps with torch.compile")
    # Every machine joining a study should use the same values (same config).
    heartbeat_interval: Annotated[int, Field(ge=1)] = Field(
        10, description="Seconds between the heartbeats a running trial records (Optuna)"
    )
    grace_period: Annotated[int, Field(ge=2)] = Field(
        60,
        description="Seconds without a heartbeat after which a trial (its worker or machine gone) is marked "
        "FAIL and queued again",
    )
    retry_lost: Annotated[int, Field(ge=0)] = Field(
        2, description="How many times a lost trial is queued again"
    )

    @model_validator(mode="after")
    def _grace_exceeds_heartbeat(self) -> TuningConfig:
        if self.grace_period <= self.heartbeat_interval:
            raise ValueError("grace_period must exceed heartbeat_interval")
        return self
