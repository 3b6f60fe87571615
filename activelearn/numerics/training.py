"""Training: `fit` minimises the ELBO (data term + KL/N) with minibatches and early stopping.

Speed (60,000 rows at batch 32 = 1,875 steps per epoch, so per-step overhead dominates):
- the data are standardised into contiguous float32 tensors once; each epoch gathers one permutation
  and then takes views `x[i:i+B]` (no DataLoader, no per-step copies or collation, no `.item()`);
- layers use fused `addmm` and local reparameterisation (no distribution objects), and the
  closed-form KL is a handful of tensor reductions;
- eager mode uses torch.optim's fused Adam/SGD kernels (foreach for RMSprop) and one intra-op
  thread (these matrices are too small to split across threads);
- compiled mode (`TrainingConfig.compile`, "auto" for long fits) runs gradient and optimizer update
  of a flat parameter vector as ONE torch.compile'd graph per step (`_flat_step`). It computes the
  same update as torch.optim (tested), with the training noise drawn from the same seeded RNG.
"""

from __future__ import annotations

import copy
import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor, nn
from torch.func import functional_call, grad_and_value

from activelearn.config import TrainingConfig
from activelearn.errors import InputError
from activelearn.numerics.correction_gate import choose_correction_weight
from activelearn.numerics.models.base import Model
from activelearn.numerics.multistep import Windows, window_loss
from activelearn.numerics.threads import intra_op_threads
from activelearn.numerics.training_data import TrainingData
from activelearn.numerics.uncertainty import gaussian_nll, recalibrate_epistemic, rmse

Callback = Callable[[int, dict[str, float]], "bool | None"]


@dataclass
class History:
    """Per-epoch curves of one `fit` call and the epoch whose weights were kept."""

    train_loss: list[float] = field(default_factory=list)
    train_data: list[float] = field(default_factory=list)
    kl: list[float] = field(default_factory=list)
    val_nll: list[float] = field(default_factory=list)
    val_rmse: list[float] = field(default_factory=list)
    epoch_time: list[float] = field(default_factory=list)
    best_epoch: int = -1
    stopped_early: bool = False
    kl_count: float = float("nan")
    epistemic_scale: float = 1.0
    # [model] correction_gate: the share of the correction's mean kept, and each share's held-out
    # free-run error (m); 1.0 and empty where nothing was gated
    correction_weight: float = 1.0
    gate_errors: dict[float, float] = field(default_factory=dict)
    # multi-step windows whose gradient was not finite, their steps skipped (`_Stepper._eager_step`)
    skipped_steps: int = 0

    @property
    def n_epochs(self) -> int:
        """Number of epochs run."""
        return len(self.train_loss)

    def as_dict(self) -> dict[str, object]:
        """Plain-dict form (for logging)."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def kl_count_value(kl_count: str | float, n_rows: int, groups: np.ndarray | None) -> float:
    """The N in KL/N: rows, distinct maneuvers, √(rows × maneuvers), or the given number.

    Without `groups` every row counts as its own maneuver, so all three counts equal the rows.
    """
    if not isinstance(kl_count, str):
        return float(kl_count)
    n_groups = n_rows if groups is None else len(np.unique(groups))
    if kl_count == "rows":
        return float(n_rows)
    if kl_count == "maneuvers":
        return float(n_groups)
    return math.sqrt(n_rows * n_groups)


def _check_xy(model: Model, x: np.ndarray, y: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=np.float32)
    y = np.asarray(y, dtype=np.float32)
    if x.ndim != 2 or x.shape[1] != model.n_inputs:
        raise InputError(f"x{name}", x.shape, f"expected shape (N, {model.n_inputs})")
    if y.ndim != 2 or y.shape != (len(x), model.n_outputs):
        raise InputError(f"y{name}", y.shape, f"expected shape ({len(x)}, {model.n_outputs})")
    if len(x) == 0:
        raise InputError(f"x{name}", x.shape, "no rows")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise InputError(f"x{name}/y{name}", "non-finite", "data contain NaN or inf")
    return x, y


def _optimizer(params: list[Tensor], config: TrainingConfig) -> torch.optim.Optimizer:
    # fused (Adam, SGD): one C++ kernel updates every tensor, ~2x cheaper per step than foreach;
    # RMSprop has no fused CPU kernel, foreach is the next best.
    if config.optimizer == "adam":
        return torch.optim.Adam(params, lr=config.lr, weight_decay=config.weight_decay, fused=True)
    if config.optimizer == "rmsprop":
        return torch.optim.RMSprop(params, lr=config.lr, weight_decay=config.weight_decay, foreach=True)
    return torch.optim.SGD(
        params, lr=config.lr, momentum=config.momentum, weight_decay=config.weight_decay, fused=True
    )


def _elbo(
    model: Model, xb: Tensor, yb: Tensor, loss: str, kl_weight: Tensor | float, variational: bool
) -> tuple[Tensor, Tensor]:
    """Per-row ELBO loss on standardised tensors: (data term + kl_weight · KL, data term)."""
    mean, var = model.train_forward(xb)
    err = yb - mean
    if loss == "nll" and var is not None:
        per = 0.5 * (var.log() + err.square() / var)
    elif loss == "mae":
        per = err.abs()
    elif loss == "mse":
        per = err.square()
    else:  # NLL without a variance head (DNN): unit variance, i.e. half the squared error
        per = 0.5 * err.square()
    # Sum over outputs, mean over rows; an ensemble sums its members' losses so that each member
    # receives exactly the gradient it would get if trained alone.
    data = per.sum(dim=-1).mean(dim=-1).sum()
    if variational:
        return data + kl_weight * model.kl(), data
    return data, data


class _LossModule(nn.Module):
    """Wraps a model so that `functional_call` can substitute flat-parameter views."""

    def __init__(self, model: Model, loss: str) -> None:
        super().__init__()
        self.model = model
        self.loss = loss
        self.variational = model.is_variational()

    def forward(self, xb: Tensor, yb: Tensor, kl_weight: Tensor) -> tuple[Tensor, Tensor]:
        return _elbo(self.model, xb, yb, self.loss, kl_weight, self.variational)


_ADAM_BETAS = (0.9, 0.999)
_EPS = 1e-8
_RMS_ALPHA = 0.99  # torch.optim.RMSprop's default
# Compiled steps, keyed by everything that shapes the graph; reused across fits (e.g. campaign rounds).
_STEP_CACHE: dict[str, Callable] = {}
# `compile="auto"` compiles when a fit runs at least this many steps (compiling costs ~5-20 s).
AUTO_COMPILE_STEPS = 40_000
# A step of a small network at batch 32 is mostly per-call overhead, so both options trim that:
#   cpp_wrapper: the compiled graph is entered through generated C++, not a Python wrapper that
#     allocated each intermediate buffer (reference arrangement, b32: 0.50 -> 0.41 s/epoch);
#   guard_filter_fn: no per-call guards on the template module (0.41 -> 0.35 s/epoch). Safe here:
#     the template is a private structural twin that is never modified, and each cache key (every
#     config value that shapes the graph) has its own template and compiled step.
_COMPILE_OPTIONS = {
    "cpp_wrapper": True,
    "guard_filter_fn": torch.compiler.skip_guard_on_all_nn_modules_unsafe,
}


def _flat_step(template: Model, loss: str, optimizer: str) -> Callable:
    """A pure training step on one flat parameter vector: gradient + optimizer update in one graph.

    The update rules are those of torch.optim's Adam, RMSprop (alpha 0.99, no momentum) and SGD
    (momentum, no dampening) with L2 weight decay, written out so torch.compile can fuse them with
    the forward and backward passes into a single call per step. Hyper-parameters travel in the
    tensor `hp` = [lr, kl_weight, weight_decay, momentum, step] so changing them does not recompile.
    """
    wrapper = _LossModule(template, loss)
    layout = [(f"model.{n}", p.shape, p.numel()) for n, p in template.named_parameters() if p.requires_grad]

    def loss_flat(flat: Tensor, xb: Tensor, yb: Tensor, kl_weight: Tensor) -> tuple[Tensor, Tensor]:
        params, off = {}, 0
        for name, shape, numel in layout:
            params[name] = flat[off : off + numel].view(shape)
            off += numel
        total, data = functional_call(wrapper, params, (xb, yb, kl_weight))
        return total, data.detach()

    grad_fn = grad_and_value(loss_flat, has_aux=True)

    def step(
        flat: Tensor, s1: Tensor, s2: Tensor, hp: Tensor, xb: Tensor, yb: Tensor
    ) -> tuple[Tensor, Tensor]:
        grad, (total, data) = grad_fn(flat, xb, yb, hp[1])
        grad = grad + hp[2] * flat
        lr, t = hp[0], hp[4]
        if optimizer == "adam":
            b1, b2 = _ADAM_BETAS
            s1.mul_(b1).add_(grad, alpha=1 - b1)
            s2.mul_(b2).addcmul_(grad, grad, value=1 - b2)
            denom = (s2 / (1 - b2**t)).sqrt() + _EPS
            flat.sub_(lr / (1 - b1**t) * s1 / denom)
        elif optimizer == "rmsprop":
            s2.mul_(_RMS_ALPHA).addcmul_(grad, grad, value=1 - _RMS_ALPHA)
            flat.sub_(lr * grad / (s2.sqrt() + _EPS))
        else:
            s1.mul_(hp[3]).add_(grad)
            flat.sub_(lr * s1)
        return total.detach(), data

    return step


class _FlatTrainer:
    """Holds a model's parameters as one flat vector plus optimizer state; steps via `_flat_step`."""

    def __init__(self, model: Model, config: TrainingConfig, kl_weight: float, compiled: bool) -> None:
        self.model = model
        self.params = [p for p in model.parameters() if p.requires_grad]
        self.flat = torch.cat([p.detach().reshape(-1) for p in self.params])
        self.s1 = torch.zeros_like(self.flat)
        self.s2 = torch.zeros_like(self.flat)
        self.hp = torch.tensor([config.lr, kl_weight, config.weight_decay, config.momentum, 0.0])
        self.n_steps = 0
        key = f"{model.config.model_dump_json()}|{config.loss}|{config.optimizer}|{torch.get_num_threads()}"
        if key not in _STEP_CACHE:
            # A structural twin: functional_call swaps in the flat parameters at every step.
            template = type(model)(model.config, generator=torch.Generator().manual_seed(0))
            _STEP_CACHE[key] = _flat_step(template, config.loss, config.optimizer)
        self.eager_step = _STEP_CACHE[key]
        ckey = "compiled|" + key
        if compiled and ckey not in _STEP_CACHE:
            # Every key closes over the same `step` code object: isolate its compile cache, or all
            # architectures would share dynamo's per-code-object limit of 8 recompilations.
            _STEP_CACHE[ckey] = torch.compile(
                self.eager_step,
                dynamic=False,
                isolate_recompiles=True,
                recompile_limit=32,
                options=_COMPILE_OPTIONS,
            )
        self.compiled_step = _STEP_CACHE.get(ckey) if compiled else None

    def step(self, xb: Tensor, yb: Tensor, *, eager: bool = False) -> tuple[Tensor, Tensor]:
        """One optimizer step on a batch; `eager` skips the compiled graph (odd-sized last batch)."""
        self.hp[4] += 1
        self.n_steps += 1
        fn = self.eager_step if eager or self.compiled_step is None else self.compiled_step
        return fn(self.flat, self.s1, self.s2, self.hp, xb, yb)

    @torch.no_grad()
    def write_back(self) -> None:
        """Copy the flat vector into the model's parameters."""
        off = 0
        for p in self.params:
            p.copy_(self.flat[off : off + p.numel()].view_as(p))
            off += p.numel()


@torch.no_grad()
def _validate(
    model: Model, x_val: np.ndarray, y_val: np.ndarray, n_samples: int, seed: int
) -> tuple[float, float]:
    pred = model.predict(x_val, n_samples, seed=seed)
    val_rmse = float(rmse(y_val, pred))
    if model.has_aleatoric or model.has_epistemic:
        return float(gaussian_nll(y_val, pred)), val_rmse
    # DNN: NLL under the best constant variance per output (a monotone function of the val MSE).
    mse = np.mean((np.asarray(y_val, float) - pred.mean) ** 2, axis=0)
    return float(np.mean(0.5 * np.log(2 * np.pi * mse) + 0.5)), val_rmse


def fit(
    model: Model,
    data: TrainingData,
    config: TrainingConfig,
    *,
    validation: TrainingData | None = None,
    seed: int = 0,
    callback: Callback | None = None,
    keep_scalers: bool = False,
) -> History:
    """Train `model` on `data` (physical units); return the per-epoch History.

    The loss per row is the data term (Gaussian NLL, MSE or MAE in standardised units, summed over
    outputs) plus kl_weight · KL / N with N from `config.kl_count` (`data.groups` = per-row maneuver or
    operating-point ids for "maneuvers" and "sqrt"; without them each row is its own maneuver).
    With `validation` rows, early stopping watches the validation NLL (physical units, mean per
    output) and the best epoch's weights are restored; their `groups` let `recalibrate="validation"`
    average validation rows per operating point.
    `callback(epoch, metrics)` runs after every epoch with train_loss, train_data, kl, epoch_time,
    and val_nll / val_rmse when validation data are given; returning True stops training, and
    exceptions (e.g. optuna.TrialPruned) propagate. Same seed and inputs → identical weights; the
    global torch RNG is restored on return. `keep_scalers` keeps the model's input/output standardisation
    (fine-tuning weights learnt under it, with `config.reinit = False`) instead of refitting it to the rows.
    With `config.rollout_horizon` > 0, `data.windows` (free runs of a dynamic model,
    `activelearn.numerics.multistep`) add their loss to every `rollout_every`-th step,
    `rollout_batch` windows at a time (eager steps: the compiled path trains one-step losses only).
    The model first identifies what its kind knows of the car (`Model.identify`; a no-op for networks),
    and, where it gates a learnt correction (`Model.gates_correction`), a probe trained without a
    quarter of the maneuvers then decides the share of the correction's mean to keep
    (`activelearn.numerics.correction_gate`).
    """
    return _train(model, data, config, validation, seed, callback, keep_scalers, gate=True)


def _train(
    model: Model,
    data: TrainingData,
    config: TrainingConfig,
    validation: TrainingData | None,
    seed: int,
    callback: Callback | None,
    keep_scalers: bool,
    *,
    gate: bool,
) -> History:
    """`fit`, with the correction gate where `gate` (its probe trains without one)."""
    x, y = _check_xy(model, data.x, data.y, "")
    windows = data.windows
    if config.rollout_horizon and windows is not None:
        if windows.lags.n_inputs != model.n_inputs:
            raise InputError("windows", windows.lags.n_inputs, f"the model reads {model.n_inputs} inputs")
    else:
        windows = None
    data = replace(data, x=x, y=y, windows=windows)
    if validation is not None:
        x_val, y_val = _check_xy(model, validation.x, validation.y, "_val")
        validation = replace(validation, x=x_val, y=y_val)
    groups = data.groups
    if groups is not None and len(groups) != len(x):
        raise InputError("groups", len(groups), f"needs one id per row ({len(x)})")
    n = len(x)
    history = History(kl_count=kl_count_value(config.kl_count, n, groups))
    kl_weight = config.kl_weight / history.kl_count
    batch = min(config.batch_size, n)
    if config.recalibrate == "validation" and validation is None:
        raise InputError("recalibrate", config.recalibrate, "needs x_val and y_val")

    steps_per_epoch = math.ceil(n / batch)
    use_compile = (
        windows is None
        and model.compilable
        and (
            config.compile is True
            or (config.compile == "auto" and steps_per_epoch * config.epochs >= AUTO_COMPILE_STEPS)
        )
    )
    if config.compile is True or (config.compile == "auto" and windows is not None):
        model.compile_steps()  # a window is tens of core steps, each hundreds of small ops eagerly
    model.set_correction_weight(1.0)  # trained with its whole correction (where the kind has one)
    gated = gate and model.gates_correction(data)
    probe = copy.deepcopy(model) if gated else None  # as it starts training: the probe starts there too

    def train_probe(held_in: TrainingData) -> Model:
        _train(probe, held_in, config, validation, seed, None, keep_scalers, gate=False)  # type: ignore[arg-type]
        return probe  # type: ignore[return-value]

    with intra_op_threads(config.num_threads), torch.random.fork_rng(devices=[]):
        _fit(model, data, config, validation, seed, callback, history, kl_weight, batch, use_compile,
             keep_scalers)  # fmt: skip
        if gated:
            chosen = choose_correction_weight(
                train_probe, data, seed=seed, min_held_out=model.config.correction_gate_min_held_out
            )
            if chosen is not None:
                history.correction_weight, history.gate_errors = chosen
                model.set_correction_weight(history.correction_weight)
    return history


def _fit(
    model: Model,
    data: TrainingData,
    config: TrainingConfig,
    validation: TrainingData | None,
    seed: int,
    callback: Callback | None,
    history: History,
    kl_weight: float,
    batch: int,
    use_compile: bool,
    keep_scalers: bool,
) -> History:
    """The training loop of `fit` (arguments validated, RNG forked, threads set)."""
    x, y = data.x, data.y
    has_val = validation is not None
    early_stopping = has_val and config.patience is not None
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    if config.reinit:
        model.reset_parameters(gen)
        with torch.no_grad():
            model.epistemic_scale.fill_(1.0)
    if not keep_scalers:
        model.set_scalers(x, y)
    # what the kind knows of the car, before its weights train (from its last solution when warm)
    model.identify(data, warm=not config.reinit)
    xs = model.standardise_inputs(torch.from_numpy(x)).contiguous()
    ys = ((torch.from_numpy(y) - model.y_mean) / model.y_std).contiguous()
    stepper = _Stepper(model, config, kl_weight, batch, use_compile, data.windows, gen)
    best_score, best_state, bad_epochs = math.inf, None, 0

    for epoch in range(config.epochs):
        t0 = time.perf_counter()
        if config.lr_schedule == "cosine":
            decay = 0.5 * (1.0 + math.cos(math.pi * epoch / config.epochs))
            stepper.set_lr(config.lr * (0.01 + 0.99 * decay))
        train_loss, train_data = stepper.epoch(xs, ys, gen)
        history.skipped_steps = stepper.skipped
        metrics: dict[str, float] = {"train_loss": train_loss, "train_data": train_data}
        with torch.no_grad():
            metrics["kl"] = float(model.kl())
        history.train_loss.append(train_loss)
        history.train_data.append(train_data)
        history.kl.append(metrics["kl"])
        score = train_loss
        if has_val:
            val_nll, val_rmse = _validate(model, validation.x, validation.y, config.n_eval_samples, seed)  # type: ignore[union-attr]
            metrics["val_nll"], metrics["val_rmse"] = val_nll, val_rmse
            history.val_nll.append(val_nll)
            history.val_rmse.append(val_rmse)
            score = val_nll
        metrics["epoch_time"] = time.perf_counter() - t0
        history.epoch_time.append(metrics["epoch_time"])

        if score < best_score:
            best_score, bad_epochs, history.best_epoch = score, 0, epoch
            if early_stopping:
                best_state = copy.deepcopy(model.state_dict())
        else:
            bad_epochs += 1
        if callback is not None and callback(epoch, dict(metrics)):
            break
        if early_stopping and bad_epochs >= config.patience:  # type: ignore[operator]
            history.stopped_early = True
            break
        if not math.isfinite(train_loss):
            break

    if best_state is not None and history.best_epoch != history.n_epochs - 1:
        model.load_state_dict(best_state)
    if not early_stopping:
        history.best_epoch = history.n_epochs - 1
    model.eval()
    if config.recalibrate == "validation":
        assert validation is not None
        history.epistemic_scale = recalibrate_epistemic(
            model, validation.x, validation.y, groups=validation.groups, seed=seed
        )
    return history


class _Stepper:
    """Runs epochs of minibatch steps, eagerly (module + torch.optim) or compiled (`_FlatTrainer`)."""

    def __init__(
        self,
        model: Model,
        config: TrainingConfig,
        kl_weight: float,
        batch: int,
        use_compile: bool,
        windows: Windows | None = None,
        gen: torch.Generator | None = None,
    ) -> None:
        self.model, self.config, self.kl_weight, self.batch = model, config, kl_weight, batch
        self.windows, self.gen = windows, gen
        self.n_steps = 0
        self.skipped = 0  # window steps skipped for a non-finite gradient
        self.variational = kl_weight > 0 and model.is_variational()
        self.flat = _FlatTrainer(model, config, kl_weight, compiled=True) if use_compile else None
        self.opt = _optimizer([p for p in model.parameters() if p.requires_grad], config)

    def set_lr(self, lr: float) -> None:
        """Change the learning rate of the next steps (both step paths)."""
        for group in self.opt.param_groups:
            group["lr"] = lr
        if self.flat is not None:
            self.flat.hp[0] = lr

    def _eager_step(self, xb: Tensor, yb: Tensor) -> tuple[Tensor, Tensor]:
        loss, data = _elbo(self.model, xb, yb, self.config.loss, self.kl_weight, self.variational)
        self.n_steps += 1
        windows = self.windows if self.n_steps % self.config.rollout_every == 0 else None  # this step's
        total = loss
        if windows is not None:
            rows = torch.randint(len(windows), (self.config.rollout_batch,), generator=self.gen)
            weight = self.config.rollout_weight * self.config.rollout_every
            total = loss + weight * window_loss(self.model, windows, rows)
        self.opt.zero_grad(set_to_none=True)
        total.backward()
        norm = None
        if self.windows is not None and self.config.rollout_clip > 0:
            norm = torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.config.rollout_clip)
        if windows is not None:
            # A window whose free run left every bound (a spinning car at a core's extreme scales) gives
            # a non-finite gradient: the step is skipped, or it would turn every weight into NaN (seen on
            # the full-size car). Its one-step loss is what the epoch reports.
            if norm is None:  # the norm alone: an infinite bound scales every gradient by exactly 1
                norm = torch.nn.utils.clip_grad_norm_(self.model.parameters(), math.inf)
            if not bool(torch.isfinite(norm)):
                self.skipped += 1
                self.opt.zero_grad(set_to_none=True)
                return loss.detach(), data.detach()
        self.opt.step()
        return total.detach(), data.detach()

    def _flat_step(self, xb: Tensor, yb: Tensor) -> tuple[Tensor, Tensor]:
        assert self.flat is not None
        # The compiled graph has a static batch size; an odd last batch runs the same step eagerly.
        eager = xb.shape[-2] != self.batch
        try:
            return self.flat.step(xb, yb, eager=eager)
        except Exception as exc:  # compilation needs a C++ toolchain; fall back to eager mode
            if self.flat.n_steps > 1 or eager:
                raise
            warnings.warn(f"torch.compile failed ({exc}); training eagerly", RuntimeWarning, stacklevel=2)
            self.flat = None
            return self._eager_step(xb, yb)

    def epoch(self, xs: Tensor, ys: Tensor, gen: torch.Generator) -> tuple[float, float]:
        """One pass over shuffled data; returns the mean loss and data term per row (and member)."""
        n, batch, members = len(xs), self.batch, self.model.n_members
        self.model.train()
        if members is None:
            perm = torch.randperm(n, generator=gen)
        else:  # each ensemble member sees its own shuffle: (K, n, d)
            perm = torch.stack([torch.randperm(n, generator=gen) for _ in range(members)])
        # One gather per epoch, then every batch is a view: no per-step copies or collation.
        xe, ye = xs[perm], ys[perm]
        tot_loss, tot_data, n_steps = torch.zeros(()), torch.zeros(()), 0
        for i in range(0, n, batch):
            xb, yb = xe[..., i : i + batch, :], ye[..., i : i + batch, :]
            loss, data = self._flat_step(xb, yb) if self.flat is not None else self._eager_step(xb, yb)
            # Accumulate as tensors: a float() per step would add a conversion to every step.
            tot_loss += loss
            tot_data += data
            n_steps += 1
        if self.flat is not None:
            self.flat.write_back()
        self.model.eval()
        scale = 1.0 / (n_steps * (members or 1))
        return float(tot_loss) * scale, float(tot_data) * scale
