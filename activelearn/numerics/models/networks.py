"""Layer-stack networks: the hybrid PBNN and its baselines behind the `Model` interface."""

from __future__ import annotations

import functools
from typing import ClassVar, Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from activelearn.config import ModelConfig
from activelearn.numerics import native
from activelearn.numerics.arch import LayerSpec, parse_arch
from activelearn.numerics.models.base import Model, derived_inputs
from activelearn.numerics.models.layers import BayesianLinear, DenseLinear


@functools.lru_cache(maxsize=4)
def standard_normals(seed: int, n_samples: int, sizes: tuple[int, ...]) -> tuple[Tensor, ...]:
    """The standard normals behind `draw(n_samples, seed=seed)`: one (S, size) block per variational layer.

    A pure function of its arguments (the generator is seeded here, the blocks drawn in layer order),
    so repeated draws with one seed reuse them: drawing 33 000 normals was 0.11 ms of a 2.6-ms
    `predict`. The weights themselves are computed afresh from the current posterior at every draw.
    Callers must not modify the returned tensors.
    """
    gen = torch.Generator().manual_seed(seed)
    return tuple(torch.randn(n_samples, size, generator=gen) for size in sizes)


_ACT = {
    "tanh": torch.tanh,
    "sigmoid": torch.sigmoid,
    "elu": F.elu,
    "relu": F.relu,
    "selu": F.selu,
    "softplus": F.softplus,
}

# In-place versions for prediction, where every intermediate is a fresh tensor: large (S, N, width)
# elementwise ops are several times faster without a new allocation.
_ACT_INPLACE = {
    "tanh": torch.tanh_,
    "sigmoid": torch.sigmoid_,
    "elu": lambda t: F.elu(t, inplace=True),
    "relu": torch.relu_,
    "selu": lambda t: F.selu(t, inplace=True),
    "softplus": F.softplus,
}

Head = Literal["gaussian", "homoscedastic", "none"]
LayerMode = Literal["as_spec", "variational", "dense"]


class StackModel(Model):
    """A chain of Bayesian/dense layers with activations, ending in a head.

    Heads: "gaussian" (the last layer gives mean and raw scale; std = softplus(raw) + min_std),
    "homoscedastic" (one learnt noise std per output), "none" (mean only: a point estimate).
    """

    head: ClassVar[Head] = "gaussian"
    layer_mode: ClassVar[LayerMode] = "as_spec"

    def __init__(self, config: ModelConfig, *, generator: torch.Generator | None = None) -> None:
        super().__init__(config)
        specs = [self._convert(s) for s in parse_arch(config.arch)]
        members = config.ensemble_size if self.n_members is not None else None
        out_width = 2 * config.n_outputs if self.head == "gaussian" else config.n_outputs
        layers: list[nn.Module] = []
        acts: list[str | None] = []
        width_in = self._stack_inputs(config)
        for i, spec in enumerate(specs):
            last = i == len(specs) - 1
            width = out_width if last else int(spec.width)  # type: ignore[arg-type]
            if spec.variational:
                layers.append(
                    BayesianLinear(
                        width_in,
                        width,
                        posterior=config.posterior,
                        prior_scale=config.prior_scale,
                        prior_trainable=config.prior_trainable,
                        init_std=config.posterior_init_std,
                        kl=config.kl,
                        kl_samples=config.kl_samples,
                        generator=generator,
                    )
                )
            else:
                layers.append(DenseLinear(width_in, width, members=members, generator=generator))
            acts.append(None if last else (spec.activation or config.activation))
            width_in = width
        self.layers = nn.ModuleList(layers)
        self.activations = acts
        self.variational = [isinstance(layer, BayesianLinear) for layer in layers]
        if self.head == "homoscedastic":
            self.noise_rho = nn.Parameter(torch.zeros(config.n_outputs))
        # Models without variational layers have no weight posterior to sample.
        if not any(self.variational) and self.n_members is None:
            self.has_epistemic = False  # type: ignore[misc]

    def is_variational(self) -> bool:
        """Whether any layer is variational (its KL then enters the training loss)."""
        return any(self.variational)

    def _stack_inputs(self, config: ModelConfig) -> int:
        """Width the layer stack reads: the inputs and those derived from them, or a trunk's features."""
        return config.n_inputs + derived_inputs(config)

    def _convert(self, spec: LayerSpec) -> LayerSpec:
        if self.layer_mode == "variational":
            return LayerSpec(True, spec.width, spec.activation)
        if self.layer_mode == "dense":
            return LayerSpec(False, spec.width, spec.activation)
        return spec

    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """Re-initialise every layer (and the noise std) from `generator`."""
        for layer in self.layers:
            layer.reset_parameters(generator)  # type: ignore[operator]
        if self.head == "homoscedastic":
            with torch.no_grad():
                self.noise_rho.fill_(0.0)

    # ----- heads ------------------------------------------------------------------------------
    def _head(self, h: Tensor, dim: int = -1, *, inplace: bool = False) -> tuple[Tensor, Tensor | None]:
        """(mean, variance) from the last layer's output h, its units along `dim`.

        `inplace` reuses the softplus buffer (prediction only: autograd needs the copies).
        """
        o = self.n_outputs
        if self.head == "gaussian":
            std = F.softplus(h.narrow(dim, o, o))
            var = std.add_(self.config.min_std).square_() if inplace else (std + self.config.min_std).square()
            return h.narrow(dim, 0, o), var
        if self.head == "homoscedastic":
            shape = [1] * h.dim()
            shape[dim] = -1
            return h, self._noise_var().view(shape).expand_as(h)
        return h, None

    def _noise_var(self) -> Tensor:
        """The homoscedastic head's variance per output, standardised: (softplus(rho) + min_std)²."""
        return (F.softplus(self.noise_rho) + self.config.min_std).square()

    # ----- training ---------------------------------------------------------------------------
    def train_forward(self, x: Tensor) -> tuple[Tensor, Tensor | None]:
        """Stochastic pass; x is (N, d), or (K, N, d) for an ensemble (one batch per member)."""
        h = x
        for layer, act in zip(self.layers, self.activations, strict=True):
            h = layer(h)
            if act is not None:
                h = _ACT[act](h)
        return self._head(h)

    def kl(self) -> Tensor:
        """Sum of the variational layers' KL divergences."""
        total = torch.zeros(())
        for layer, is_var in zip(self.layers, self.variational, strict=True):
            if is_var:
                total = total + layer.kl_divergence()  # type: ignore[operator]
        return total

    # ----- sampling ---------------------------------------------------------------------------
    def sample_params(self, n_samples: int, seed: int) -> list:
        """Per layer: sampled (W, b) for variational layers, member-gathered (W, b) for ensembles."""
        sizes = tuple(layer.n_params for layer, v in zip(self.layers, self.variational, strict=True) if v)
        normals = iter(standard_normals(int(seed), n_samples, sizes))
        params: list = []
        for layer, is_var in zip(self.layers, self.variational, strict=True):
            if is_var:
                w, b = layer.sample(n_samples, eps=next(normals))  # type: ignore[operator]
                params.append((w, b))
            elif self.n_members is not None:
                # Sample s is member s mod K.
                idx = torch.arange(n_samples) % self.n_members
                params.append((layer.weight[idx].clone(), layer.bias[idx].clone()))
            else:
                params.append((layer.weight.detach().clone(), layer.bias.detach().clone()))
        return params

    def mean_params(self) -> tuple[list, int]:
        """Posterior-mean weights; an ensemble contributes all K members as K 'samples'."""
        params: list = []
        for layer, is_var in zip(self.layers, self.variational, strict=True):
            if is_var:
                params.append(layer.mean_params())  # type: ignore[operator]
            else:
                params.append((layer.weight, layer.bias))
        return params, (self.n_members or 1)

    def columns_params(self, params: list) -> list:
        """`sample_params`/`mean_params` weights in column layout, one (W, b, W_aug) per layer.

        W is (out, in) or (S, out, in), b (out, 1) or (S, out, 1). W_aug is set on a sampled layer
        whose input is shared by every sample: (S·out, in + 1) with the biases as a last column, so
        one GEMM against the input with a row of ones appended adds them (a separate broadcast bias
        costs a full extra pass over the layer's largest output).
        """
        out = []
        shared_input = True
        for w, b in params:
            if w.dim() == 3:
                s, n_in, n_out = w.shape
                wc = w.transpose(1, 2).contiguous()
                bc = b.reshape(s, n_out, 1).contiguous()
                aug = torch.cat([wc, bc], dim=2).reshape(s * n_out, n_in + 1) if shared_input else None
                out.append((wc, bc, aug))
                shared_input = False
            else:
                out.append((w.t().contiguous(), b.reshape(-1, 1).contiguous(), None))
        return out

    def columns_forward(self, x: Tensor, params: list, n_samples: int) -> tuple[Tensor, Tensor]:
        """Evaluate S weight sets on standardised inputs in column layout: x is (d, N) or (S, d, N).

        Returns standardised means and variances, each (S, n_outputs, N). `params` come from
        `columns_params`. Column layout keeps the long row axis last, so every layer is a GEMM whose
        large dimension is contiguous, and each sample's block of units is contiguous for the next
        batched matmul and for the elementwise head (a row-major (S, N, out) layout makes the
        per-sample matmul and the head run on strided memory, which was ~2x slower overall).
        """
        h = x
        for (w, b, aug), act in zip(params, self.activations, strict=True):
            if w.dim() == 3 and h.dim() == 2:
                # Inputs shared by every sample: one (S·out, in + 1) @ (in + 1, N) GEMM serves all S.
                ones = torch.ones((1, h.shape[1]), dtype=h.dtype)
                h = (aug @ torch.cat([h, ones])).view(w.shape[0], w.shape[1], -1)
            elif w.dim() == 3:
                if h.shape[0] != w.shape[0]:
                    h = h.expand(w.shape[0], *h.shape[1:])
                h = torch.baddbmm(b, w, h)
            elif h.dim() == 2:
                # Shared dense weights before any sampled layer: one matmul serves every sample.
                h = torch.addmm(b, w, h)
            else:
                # Shared weights on per-sample rows: one (S·N, in) @ (in, out) GEMM, not S small ones.
                h = torch.matmul(h.transpose(1, 2), w.t()).transpose(1, 2).add_(b)
            if act is not None:
                h = _ACT_INPLACE[act](h)
        if h.dim() == 2:
            h = h.expand(n_samples, *h.shape)
        elif h.shape[0] != n_samples:
            h = h.expand(n_samples, *h.shape[1:])
        mean, var = self._head(h, dim=1, inplace=True)
        return mean, torch.zeros_like(mean) if var is None else var

    def network_kernel(self, params: list, n_samples: int) -> native.NetworkKernel | None:
        """`sample_params` weights packed for the compiled kernel; None where it is unavailable."""
        lib = native.library()
        if lib is None:
            return None
        layers = []
        for (w, b), act in zip(params, self.activations, strict=True):
            per_sample = w.dim() == 3  # (S, in, out): sampled, or one ensemble member per draw
            layers.append((w.numpy(), b.reshape(*w.shape[:-2], -1).numpy(), per_sample, act))
        head_var = None
        if self.head == "homoscedastic":
            head_var = self._noise_var().detach().numpy()
        elif self.head == "none":
            head_var = np.zeros(self.n_outputs, dtype=np.float32)
        return native.NetworkKernel(
            lib,
            layers,
            n_samples=n_samples,
            x_mean=self.x_mean.numpy(),
            x_std=self.x_std.numpy(),
            min_std=self.config.min_std,
            head_var=head_var,
        )


class HybridPBNN(StackModel):
    """Hybrid probabilistic Bayesian NN: variational and dense layers as the spec says, Gaussian head."""

    kind = "hybrid"


class PBNN(StackModel):
    """All-variational probabilistic Bayesian NN with a Gaussian head."""

    kind = "pbnn"
    layer_mode = "variational"


class PNN(StackModel):
    """Deterministic probabilistic NN: dense layers, Gaussian head (aleatoric only, epistemic 0)."""

    kind = "pnn"
    layer_mode = "dense"
    has_epistemic = False


class BNN(StackModel):
    """All-variational Bayesian NN with one learnt homoscedastic noise std per output."""

    kind = "bnn"
    layer_mode = "variational"
    head = "homoscedastic"


class DNN(StackModel):
    """Point-estimate dense network: no uncertainty at all (reported via has_* = False, zeros)."""

    kind = "dnn"
    layer_mode = "dense"
    head = "none"
    has_epistemic = False
    has_aleatoric = False


class DeepEnsemble(StackModel):
    """K independently initialised PNNs trained side by side; epistemic = spread of member means."""

    kind = "ensemble"
    layer_mode = "dense"

    def __init__(self, config: ModelConfig, *, generator: torch.Generator | None = None) -> None:
        self.n_members = config.ensemble_size
        super().__init__(config, generator=generator)


class RecurrentPBNN(StackModel):
    """A GRU trunk over the history window with the hybrid PBNN's layers as its head.

    The inputs are a dynamic model's history (`activelearn.numerics.lags`: k lagged controls, then k
    lagged rates); the trunk reads them as k tokens (u_{t-is}, y_{t-(i+1)s}), oldest first, and its
    last hidden state, beside the newest token itself, feeds the layers of `arch`, variational where
    the spec says: the reference study's "Bayesian LSTM" with the uncertainty in the head, as the
    hybrid PBNN places it in an MLP. The newest token skips the trunk because a GRU's gates saturate:
    far from the data its state stays bounded, and a head that saw only the state would not know it
    was extrapolating (measured: epistemic std 1.0x on inputs scaled 20x without it).
    The trunk is deterministic, so the S posterior draws share it and differ in the head only; the
    aleatoric/epistemic split and the fans work as for every other kind. No compiled kernel: torch.
    """

    kind = "recurrent"

    def __init__(self, config: ModelConfig, *, generator: torch.Generator | None = None) -> None:
        if config.n_inputs < 4 or config.n_inputs % 4:
            raise ValueError(f"kind = 'recurrent' reads 4k history inputs, got n_inputs = {config.n_inputs}")
        super().__init__(config, generator=generator)
        self.history = config.n_inputs // 4
        self.trunk = nn.GRU(4, config.hidden_size, batch_first=True)
        self._reset_trunk(generator)

    def _stack_inputs(self, config: ModelConfig) -> int:
        return config.hidden_size + 4  # the trunk's state and the newest (controls, rates) token

    def _reset_trunk(self, generator: torch.Generator | None) -> None:
        bound = 1.0 / float(np.sqrt(self.config.hidden_size))  # torch's own GRU initialisation, seeded
        with torch.no_grad():
            for weight in self.trunk.parameters():
                weight.uniform_(-bound, bound, generator=generator)

    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """Re-initialise the trunk and the head from `generator`."""
        super().reset_parameters(generator)
        self._reset_trunk(generator)

    def features(self, x: Tensor) -> Tensor:
        """The trunk's last hidden state and the newest token (..., hidden + 4) for standardised
        history rows x (..., 4k)."""
        k = self.history
        lead = x.shape[:-1]
        rows = x.reshape(-1, 2 * k, 2)  # k control pairs then k rate pairs, newest first
        tokens = torch.cat([rows[:, :k], rows[:, k:]], dim=-1).flip(1)  # (n, k, 4), oldest first
        _, last = self.trunk(tokens)
        return torch.cat([last[0], tokens[:, -1]], dim=-1).reshape(*lead, -1)

    def train_forward(self, x: Tensor) -> tuple[Tensor, Tensor | None]:
        """Stochastic pass on standardised x (N, 4k): the trunk, then the head's layers."""
        return super().train_forward(self.features(x))

    def columns_forward(self, x: Tensor, params: list, n_samples: int) -> tuple[Tensor, Tensor]:
        """`StackModel.columns_forward`, the head reading the trunk's features of x: (4k, N) or (S, 4k, N)."""
        features = self.features(x.transpose(-1, -2)).transpose(-1, -2)
        return super().columns_forward(features, params, n_samples)

    def network_kernel(self, params: list, n_samples: int) -> native.NetworkKernel | None:
        """The compiled kernel evaluates layer stacks only: the recurrent model runs on torch."""
        return None


# The network kinds; `activelearn.numerics.models.registry` adds the physics-structured one.
NETWORK_CLASSES: dict[str, type[StackModel]] = {
    cls.kind: cls for cls in (HybridPBNN, PBNN, PNN, BNN, DNN, DeepEnsemble, RecurrentPBNN)
}
