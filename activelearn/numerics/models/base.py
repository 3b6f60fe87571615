"""The interface every model kind implements: `Model`, its `Prediction`, and `SampledModel` draws."""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from activelearn.config import ModelConfig
from activelearn.errors import InputError
from activelearn.numerics import native
from activelearn.numerics.lags import N_CONTROLS, Lags, model_lags
from activelearn.numerics.native import NetworkKernel
from activelearn.numerics.threads import even_blocks, intra_op_threads
from activelearn.numerics.training_data import TrainingData

# Rows per block on the torch path of `SampledModel` and `predict`. Blocks bound the S × rows × width
# activations; the per-sample GEMMs of big blocks split well over torch's intra-op threads, while
# running small blocks on a pool of Python threads was slower (GEMMs in concurrent threads contend).
CHUNK_ROWS = 4096
# How sampled networks are evaluated: "native" (the compiled tile kernel,
# activelearn/numerics/native/network.c), "reference" (torch) or "auto" (native where a C compiler
# built it). Both compute the same numbers up to float rounding.
BACKENDS = ("auto", "native", "reference")


def kernels_for(backend: str):
    """The compiled C kernels (activelearn/numerics/native) a `backend` runs on: None for `"reference"`, or
    for `"auto"` where they do not build; `"native"` where they do not build, and an unknown name, are
    errors naming the field."""
    if backend not in BACKENDS:
        raise InputError("backend", backend, f"must be one of {', '.join(BACKENDS)}")
    lib = None if backend == "reference" else native.library()
    if backend == "native" and lib is None:
        raise InputError("backend", backend, "the compiled kernel could not be built on this machine")
    return lib


@dataclass(frozen=True)
class Prediction:
    """Predictive moments in physical units; every array is N × n_outputs.

    `aleatoric_var` is the mean over posterior samples of the predicted variances, `epistemic_var` the
    variance over samples of the predicted means (times the model's `epistemic_scale`), `total_var`
    their sum (the variance of the predictive mixture). `sample_means` (S × N × n_outputs) is set
    when `predict(..., return_samples=True)`. `has_epistemic` / `has_aleatoric` are False when the
    model cannot represent that kind of uncertainty (the zeros are then "not modelled", not "certain").
    """

    mean: np.ndarray
    aleatoric_var: np.ndarray
    epistemic_var: np.ndarray
    total_var: np.ndarray
    sample_means: np.ndarray | None = None
    has_epistemic: bool = True
    has_aleatoric: bool = True

    @property
    def epistemic_std(self) -> np.ndarray:
        """Square root of `epistemic_var`."""
        return np.sqrt(self.epistemic_var)

    @property
    def aleatoric_std(self) -> np.ndarray:
        """Square root of `aleatoric_var`."""
        return np.sqrt(self.aleatoric_var)

    @property
    def total_std(self) -> np.ndarray:
        """Square root of `total_var`."""
        return np.sqrt(self.total_var)


def _kernel_input(x: Tensor) -> Tensor:
    """x (d, N) or (S, d, N) as the kernel reads it: float32, unit stride along N, whole sets per draw."""
    x = x.to(torch.float32)
    if (x.shape[-1] > 1 and x.stride(-1) != 1) or (x.dim() == 3 and x.stride(0) != x.shape[1] * x.stride(1)):
        x = x.contiguous()
    return x


def _as_tensor(x: np.ndarray | Tensor, n_inputs: int) -> Tensor:
    if isinstance(x, np.ndarray) and not x.flags.writeable:
        x = x.copy()  # torch would share a read-only buffer (pandas' copy-on-write views are read-only)
    t = torch.as_tensor(x, dtype=torch.float32)
    if t.dim() not in (2, 3) or t.shape[-1] != n_inputs:
        raise InputError("x", tuple(t.shape), f"expected shape (N, {n_inputs}) or (S, N, {n_inputs})")
    return t


def derived_inputs(config: ModelConfig) -> int:
    """Inputs a model derives from its own (`ModelConfig.kinematic_feature`): its network reads these too."""
    return 1 if config.kinematic_feature else 0


def draw_moments(means: Tensor, var: Tensor, moments: tuple[Tensor, Tensor, Tensor]) -> None:
    """Write the mean, aleatoric and epistemic variance over S draws (S, n_outputs, n) into `moments`."""
    centre, aleatoric, epistemic = moments
    torch.mean(means, dim=0, out=centre)
    torch.mean(var, dim=0, out=aleatoric)
    # Population variance (ddof 0): the mixture's variance.
    torch.mean((means - centre).square_(), dim=0, out=epistemic)


def column_scalers(t: Tensor) -> tuple[Tensor, Tensor]:
    """Mean and standard deviation of each column of rows t (N, d); a constant column gets std 1."""
    std = t.std(dim=0, unbiased=False)
    return t.mean(dim=0), torch.where(std > 1e-8, std, torch.ones_like(std))


def draw_spread(epistemic_scale: float, n_samples: int) -> float:
    """Factor on each of `n_samples` draws' deviation from their average: √(epistemic scale)."""
    return float(epistemic_scale) ** 0.5 if n_samples > 1 else 1.0


class SampledModel:
    """S posterior weight draws, fixed at creation; call it on inputs to get per-draw moments.

    `sampled(x)` takes x of shape (N, d) or (S, N, d), numpy or torch, and returns `(means, variances)`
    each (S, N, n_outputs) in physical units (numpy in → numpy out, torch in → torch out). Sample s
    uses the same weights for every row and every call, so covariances over samples between inputs
    are meaningful and a forward simulation can keep one draw per trajectory. The model's
    `epistemic_scale` c (read at draw time) widens each sample mean's deviation from the average of
    the S means by √c. Variances are the aleatoric part (zeros for a DNN).

    `sampled.columns(x)` is the fast path for large inputs: torch x in column layout, (d, N) or
    (S, d, N), and torch (S, n_outputs, N) results.

    `backend` (see `BACKENDS`) picks the compiled tile kernel or torch; `kernel` is None on torch.
    """

    def __init__(self, model: Model, params: list, n_samples: int, seed: int, backend: str = "auto") -> None:
        if backend not in BACKENDS:
            raise InputError("backend", backend, f"must be one of {', '.join(BACKENDS)}")
        self.model = model
        self.n_samples = n_samples
        self.seed = seed
        self.epistemic_scale = float(model.epistemic_scale)
        self._params = params
        self.kernel = None if backend == "reference" else model.network_kernel(params, n_samples)
        if backend == "native" and self.kernel is None:
            raise InputError("backend", backend, "the compiled kernel could not be built on this machine")

    def standardised(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Standardised (S, n_outputs, n) means and variances for one block of physical column inputs.

        The epistemic scale is not applied. Always torch (the reference the kernel is tested against).
        """
        m = self.model
        return m.columns_forward(m.standardise_inputs(x, dim=-2), self._column_params, self.n_samples)

    @functools.cached_property
    def _column_params(self) -> list:
        """The draws rearranged for torch's column-layout pass (built on first use: the kernel reads
        `sample_params`' layout as it is)."""
        return self.model.columns_params(self._params)

    def block(
        self,
        x: Tensor,
        out: tuple[Tensor, Tensor] | None = None,
        moments: tuple[Tensor, Tensor, Tensor] | None = None,
        *,
        spread: float | None = None,
    ) -> tuple[Tensor, Tensor]:
        """Physical (S, n_outputs, n) means and variances for one block of inputs (d, n) or (S, d, n).

        `out`, when given, receives the means and the variances (slices of larger tensors, say, with
        unit stride along n). `moments`, when given, receives the (n_outputs, n) mean, aleatoric and
        epistemic variance over these draws. `spread` overrides the factor on each draw's deviation
        from the average draw (default: `self.spread`). Runs on the calling thread.
        """
        m = self.model
        spread = self.spread if spread is None else float(spread)
        if self.kernel is not None:
            if out is None:
                out = tuple(torch.empty((self.n_samples, m.n_outputs, x.shape[-1])) for _ in range(2))
            self._kernel_forward(x, 1, draws=out, moments=moments, spread=spread)
            return out
        means, var = self.standardised(x)
        if spread != 1.0:
            centre = means.mean(dim=0, keepdim=True)
            means = (means - centre).mul_(spread).add_(centre)
        out_means, out_var = (None, None) if out is None else out
        means = torch.addcmul(m.y_mean[:, None], means, m.y_std[:, None], out=out_means)
        var = torch.mul(var, m.y_std.square()[:, None], out=out_var)
        if moments is not None:
            draw_moments(means, var, moments)
        return means, var

    def _kernel_input(self, x: Tensor) -> Tensor:
        """Physical column inputs as the kernel reads them: with the derived inputs, in its layout."""
        return _kernel_input(self.model.expand_inputs(x, dim=-2))

    def _kernel_forward(
        self,
        x: Tensor,
        threads: int,
        draws: tuple[Tensor, Tensor],
        moments: tuple[Tensor, Tensor, Tensor] | None = None,
        spread: float | None = None,
    ) -> None:
        """Physical draws (and their moments) from the compiled kernel, written into the given tensors."""
        m = self.model
        self.kernel.forward(
            self._kernel_input(x).numpy(),
            draws=(draws[0].numpy(), draws[1].numpy()),
            moments=None if moments is None else tuple(t.numpy() for t in moments),
            out_mean=m.y_mean.numpy(),
            out_std=m.y_std.numpy(),
            spread=self.spread if spread is None else spread,
            threads=threads,
        )

    @property
    def spread(self) -> float:
        """Factor on each draw's deviation from the average draw: √(epistemic scale)."""
        return draw_spread(self.epistemic_scale, self.n_samples)

    @torch.no_grad()
    def columns(self, x: Tensor, out: tuple[Tensor, Tensor] | None = None) -> tuple[Tensor, Tensor]:
        """Physical means and variances (S, n_outputs, N) for physical inputs x of shape (d, N) or (S, d, N).

        The compiled kernel splits the rows over its own threads (torch's thread count); torch runs
        blocks of `CHUNK_ROWS` rows (which bounds the (S, width, rows) activations). `out` as in `block`.
        """
        if out is None:
            out = tuple(torch.empty((self.n_samples, self.model.n_outputs, x.shape[-1])) for _ in range(2))
        means, var = out
        if self.kernel is not None:
            self._kernel_forward(x, torch.get_num_threads(), draws=(means, var))
            return means, var
        for rows in even_blocks(x.shape[-1], CHUNK_ROWS):
            self.block(x[..., rows], out=(means[..., rows], var[..., rows]))
        return means, var

    @torch.no_grad()
    def moments(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Standardised (n_outputs, N) mean, aleatoric and epistemic variance over the draws at x (d, N).

        The population moments of the S draws (the epistemic scale is not applied); the per-draw
        values are never stored.
        """
        n_rows = x.shape[-1]
        centre, aleatoric, epistemic = (torch.empty((self.model.n_outputs, n_rows)) for _ in range(3))
        if self.kernel is not None:
            self.kernel.forward(
                self._kernel_input(x).numpy(),
                moments=tuple(t.numpy() for t in (centre, aleatoric, epistemic)),
                threads=torch.get_num_threads(),
            )
            return centre, aleatoric, epistemic
        for rows in even_blocks(n_rows, CHUNK_ROWS):
            means, var = self.standardised(x[..., rows])
            mean = means.mean(dim=0)
            # Population variance (ddof 0): the mixture's variance.
            centre[:, rows], aleatoric[:, rows] = mean, var.mean(dim=0)
            epistemic[:, rows] = (means - mean).square_().mean(dim=0)
        return centre, aleatoric, epistemic

    def __call__(self, x: np.ndarray | Tensor) -> tuple[np.ndarray | Tensor, np.ndarray | Tensor]:
        """Evaluate every draw on x; see the class docstring for shapes and units."""
        numpy_in = not isinstance(x, Tensor)
        xt = _as_tensor(x, self.model.n_inputs)
        if xt.dim() == 3 and xt.shape[0] != self.n_samples:
            raise InputError("x", tuple(xt.shape), f"leading dimension must equal n_samples={self.n_samples}")
        means, var = self.columns(xt.transpose(-1, -2).contiguous())
        means, var = means.transpose(1, 2).contiguous(), var.transpose(1, 2).contiguous()
        if numpy_in:
            return means.numpy(), var.numpy()
        return means, var


class Model(nn.Module, ABC):
    """Common interface of every model kind (hybrid PBNN, PBNN, PNN, BNN, DNN, deep ensemble).

    Inputs and outputs are standardised internally; the scalers (`x_mean`, `x_std`, `y_mean`,
    `y_std`) are buffers fitted by `activelearn.numerics.training.fit` and saved with the state dict, as are
    `epistemic_scale` (fitted by `activelearn.numerics.uncertainty.recalibrate_epistemic`) and
    `fan_scale`, the widening of a free run's pose fan about its mean path (`diagnostics.calibrate_fan`).
    """

    kind: ClassVar[str] = ""
    has_epistemic: ClassVar[bool] = True
    has_aleatoric: ClassVar[bool] = True
    # Number of independently trained members (deep ensemble), None for a single network.
    n_members: int | None = None
    # Whether `training.fit` may compile its step: a compiled step runs a structural twin of the model
    # with only the parameters swapped in, so a kind whose forward pass reads fitted buffers cannot.
    compilable: ClassVar[bool] = True
    # Maneuvers per task of a free run on torch (no compiled kernel): fixed, so that the numbers do not
    # depend on the thread count; a kind whose step is many small ops amortises them over wider blocks.
    rollout_block: ClassVar[int] = 16

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.n_inputs = config.n_inputs
        self.n_outputs = config.n_outputs
        # The scalers (and the network) span the derived inputs too: `expand_inputs` appends them.
        self.n_derived = derived_inputs(config)
        # the kinematic feature's speed input: the throttle, or the newest past speed (read per step)
        lags = model_lags(self) if self.n_derived else None
        self._speed_input = 0 if lags is None else N_CONTROLS * lags.history
        self.register_buffer("x_mean", torch.zeros(config.n_inputs + self.n_derived))
        self.register_buffer("x_std", torch.ones(config.n_inputs + self.n_derived))
        self.register_buffer("y_mean", torch.zeros(config.n_outputs))
        self.register_buffer("y_std", torch.ones(config.n_outputs))
        self.register_buffer("epistemic_scale", torch.tensor(1.0))
        self.register_buffer("fan_scale", torch.tensor(1.0))

    # ----- what each kind implements ----------------------------------------------------------
    @abstractmethod
    def train_forward(self, x: Tensor) -> tuple[Tensor, Tensor | None]:
        """Stochastic training pass on standardised x: (mean, variance) or (mean, None) without a head."""

    @abstractmethod
    def kl(self) -> Tensor:
        """Sum of KL(q || p) over the variational layers (0 for deterministic models)."""

    @abstractmethod
    def sample_params(self, n_samples: int, seed: int) -> list:
        """Draw n_samples weight sets (seeded) to pass to `sampled_forward`."""

    @abstractmethod
    def mean_params(self) -> tuple[list, int]:
        """Posterior-mean weights (every ensemble member) and the number of 'samples' they form."""

    @abstractmethod
    def columns_params(self, params: list) -> list:
        """`sample_params` / `mean_params` weights rearranged for `columns_forward`."""

    @abstractmethod
    def columns_forward(self, x: Tensor, params: list, n_samples: int) -> tuple[Tensor, Tensor]:
        """Standardised (S, n_outputs, N) means and variances for standardised x (d, N) or (S, d, N)."""

    def sampled_forward(self, x: Tensor, params: list, n_samples: int) -> tuple[Tensor, Tensor]:
        """Row layout: standardised (S, N, n_outputs) means and variances for x (N, d) or (S, N, d)."""
        means, var = self.columns_forward(x.transpose(-1, -2), self.columns_params(params), n_samples)
        return means.transpose(1, 2), var.transpose(1, 2)

    @abstractmethod
    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """Re-initialise every learnable parameter from `generator`."""

    # ----- hooks for what only some kinds do (neutral here; `training.fit` and the loop call them) ---
    # Whether the kind identifies itself on whole logs (`TrainingData.logs`) before its weights train:
    # the loop then hands it the logs, and a prior of another car only centres that identification.
    identifies_on_logs: ClassVar[bool] = False

    def identify(self, data: TrainingData, *, warm: bool = False) -> None:
        """Fit what the kind knows of the car to the training data before its weights train (rows in
        physical units, `data.logs` per maneuver, some flagged as another car's); `warm`: start the
        search from what this model identified before (a warm-started round). Networks know nothing
        beforehand: a no-op."""

    def start_from_another_car(self, other: Model, *, correction: bool) -> None:
        """Take what another car's trained model (`[design.prior] model` with `same_car = false`) knows that
        carries over: for a kind that identifies itself on logs, the other's identified core as the prior
        of this car's identification and, with `correction`, its correction's weights to train from."""
        raise NotImplementedError(f"a {self.kind} model does not start from another car's model")

    def gates_correction(self, data: TrainingData) -> bool:
        """Whether `training.fit` chooses, on maneuvers held out of `data`, the share of this model's
        learnt correction to keep (`activelearn.numerics.correction_gate`). A kind without one: False."""
        return False

    def set_correction_weight(self, weight: float) -> None:
        """Keep this share of the learnt correction's mean (a kind without a correction: a no-op)."""

    def compile_steps(self) -> None:
        """Compile what the kind's window losses and free runs step through (torch.compile), for the rest
        of this model's life; `training.fit` asks it (`[training] compile`). A kind whose step is its
        network (run by the compiled kernels already): a no-op."""

    def round_metrics(self) -> dict[str, float]:
        """What a campaign round records of the fitted model beyond its evaluation (none here)."""
        return {}

    def physical_parameters(self) -> dict[str, float]:
        """The identified physical parameters by name (physical units); none for a network."""
        return {}

    def parameter_information(
        self, controls: list[np.ndarray], rate_hz: float
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """What each control sequence (T, 2) at `rate_hz`, driven, would tell the identification of this
        model's physical parameters: their Fisher information, (n, P, P), and the prior's precision (P, P).
        None for a kind that identifies none this way (the `fisher` strategy then refuses it)."""
        return None

    def identified_covariance(self) -> np.ndarray | None:
        """(P, P) the identified physical parameters' covariance as the identification left it, every log
        so far included; None where the model keeps none (a network, or no `parameter_uncertainty`)."""
        return None

    def is_variational(self) -> bool:
        """Whether the training loss adds the KL divergence (`kl`) of variational layers."""
        return False

    def open_loop_free_runs(
        self,
        n_samples: int,
        seed: int,
        controls: np.ndarray,
        start: Tensor,
        lags: Lags,
        backend: str,
        pose: tuple[float, np.ndarray, float] | None = None,
    ) -> tuple[Tensor, tuple[Tensor, Tensor, Tensor], tuple[np.ndarray, ...] | None] | None:
        """Sampled free runs computed whole, for a kind whose learnt part reads the controls alone (its
        past rates enter through fixed physics only), or None: a network reads its own past rates, so
        free runs step it (`surrogate._sequential_rollout`). Arguments and results as the physics
        kind's (`PhysicsModel.open_loop_free_runs`)."""
        return None

    # ----- shared behaviour -------------------------------------------------------------------
    def expand_inputs(self, x: Tensor, dim: int = -1) -> Tensor:
        """Physical inputs with the derived ones appended along `dim` (-1: rows (N, d); -2: columns).

        The kinematic feature is a speed times tan(steering): the throttle for a static map, the newest
        past speed for a dynamic one (`activelearn.numerics.lags`). Without derived inputs, x itself.
        """
        if not self.n_derived:
            return x
        speed = x.select(dim, self._speed_input)
        feature = speed * torch.tan(x.select(dim, 1))
        return torch.cat([x, feature.unsqueeze(dim)], dim=dim)

    def standardise_inputs(self, x: Tensor, dim: int = -1) -> Tensor:
        """Physical inputs (rows or columns, see `expand_inputs`) as the network reads them."""
        x = self.expand_inputs(x, dim)
        if dim == -1:
            return (x - self.x_mean) / self.x_std
        return (x - self.x_mean[:, None]) / self.x_std[:, None]

    @torch.no_grad()
    def set_scalers(self, x: np.ndarray | Tensor, y: np.ndarray | Tensor) -> None:
        """Fit the input and output standardisation to data (constant columns get std 1)."""
        xt = self.expand_inputs(torch.as_tensor(x, dtype=torch.float32))
        yt = torch.as_tensor(y, dtype=torch.float32)
        for mean_buf, std_buf, t in ((self.x_mean, self.x_std, xt), (self.y_mean, self.y_std, yt)):
            mean, std = column_scalers(t)
            mean_buf.copy_(mean)
            std_buf.copy_(std)

    def draw(self, n_samples: int, *, seed: int = 0, backend: str = "auto") -> SampledModel:
        """Draw `n_samples` posterior weight sets, fixed across calls (same seed → same draws).

        Deep ensemble: sample s is member s mod K. DNN and PNN: every sample is the same network.
        `backend` picks how the draws are evaluated (see `BACKENDS`). The weights are computed from
        the current posterior at every call; only the seeded standard normals behind them are reused.
        """
        if n_samples < 1:
            raise InputError("n_samples", n_samples, "must be >= 1")
        # One intra-op thread: these ops are small, and a multi-threaded one leaves torch's OpenMP
        # workers spin-waiting afterwards on the cores the kernel's threads are about to use
        # (2 700-row predict on 2 threads: 2.7 ms against 1.9 ms).
        with torch.no_grad(), intra_op_threads(1):
            params = self.sample_params(n_samples, int(seed))
        return SampledModel(self, params, n_samples, seed, backend)

    def network_kernel(self, params: list, n_samples: int) -> NetworkKernel | None:
        """`sample_params` weights packed for the compiled kernel; None where it is unavailable."""
        return None

    @torch.no_grad()
    def predict(
        self,
        x: np.ndarray | Tensor,
        n_samples: int = 32,
        *,
        seed: int = 0,
        return_samples: bool = False,
        backend: str = "auto",
    ) -> Prediction:
        """Predictive mean and aleatoric/epistemic/total variance at x (N × d), physical units.

        Deterministic for a given seed. For a deep ensemble the moments are over its K members
        (S = K whatever `n_samples` says), so they are the ensemble's exact mixture moments.
        `backend` is "auto", "native" (compiled kernel) or "reference" (torch); see `BACKENDS`.
        """
        xt = _as_tensor(x, self.n_inputs)
        if xt.dim() != 2:
            raise InputError("x", tuple(xt.shape), f"predict expects shape (N, {self.n_inputs})")
        s = self.n_members if self.n_members is not None else n_samples
        sampled = self.draw(s, seed=seed, backend=backend)
        # Moments in standardised units, then scaled: the (S, n_outputs, N) samples are never
        # stored, rescaled or copied unless asked for.
        columns = xt.t().contiguous()
        # Scaled in float64 by NumPy: a dozen small torch ops cost more than the arithmetic here.
        mean, alea, epi = (t.numpy().T.astype(np.float64) for t in sampled.moments(columns))
        y_std, y_mean = self.y_std.numpy().astype(np.float64), self.y_mean.numpy().astype(np.float64)
        mean = mean * y_std + y_mean
        alea = alea * y_std**2 if self.has_aleatoric else np.zeros_like(mean)
        epi = epi * (y_std**2 * sampled.epistemic_scale) if self.has_epistemic else np.zeros_like(mean)
        sample_means = None
        if return_samples:  # a second pass, in physical units (a rarely used diagnostic)
            sample_means = sampled.columns(columns)[0].transpose(1, 2).contiguous().numpy()
        return Prediction(
            mean=mean,
            aleatoric_var=alea,
            epistemic_var=epi,
            total_var=alea + epi,
            sample_means=sample_means,
            has_epistemic=self.has_epistemic,
            has_aleatoric=self.has_aleatoric,
        )

    def forward(self, x: Tensor) -> Tensor:
        """Deterministic export path: posterior-mean network on physical x → [mean, aleatoric std]."""
        params, s = self.mean_params()
        means, var = self.sampled_forward(self.standardise_inputs(x), params, s)
        mean = means.mean(dim=0) * self.y_std + self.y_mean
        std = var.mean(dim=0).sqrt() * self.y_std
        return torch.cat([mean, std], dim=-1)
