"""Layer-stack networks: the hybrid PBNN and its baselines behind the `Model` interface."""

from __future__ import annotations

from typing import ClassVar, Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from activelearn.config import ModelConfig
from activelearn.models.base import Model
from activelearn.models.layers import BayesianLinear, DenseLinear
from activelearn.models.spec import LayerSpec, parse_arch

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
        width_in = config.n_inputs
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
    def _head(self, h: Tensor, *, contiguous: bool = False) -> tuple[Tensor, Tensor | None]:
        o = self.n_outputs
        if self.head == "gaussian":
            raw = h[..., o:]
            # Elementwise ops on a strided slice of a large (S, N, 2·O) tensor are ~10x slower.
            std = F.softplus(raw.contiguous() if contiguous else raw) + self.config.min_std
            return h[..., :o], std.square()
        if self.head == "homoscedastic":
            std = F.softplus(self.noise_rho) + self.config.min_std
            return h, std.square().expand_as(h)
        return h, None

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
    def sample_params(self, n_samples: int, generator: torch.Generator) -> list:
        """Per layer: sampled (W, b) for variational layers, member-gathered (W, b) for ensembles."""
        params: list = []
        for layer, is_var in zip(self.layers, self.variational, strict=True):
            if is_var:
                w, b = layer.sample(n_samples, generator)  # type: ignore[operator]
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

    def sampled_forward(self, x: Tensor, params: list, n_samples: int) -> tuple[Tensor, Tensor]:
        """Evaluate S weight sets with batched matmuls; x is (N, d) or (S, N, d), standardised."""
        h = x
        for (w, b), act in zip(params, self.activations, strict=True):
            if w.dim() == 3 and h.dim() == 2:
                # Rows shared by every sample: one (N, in) @ (in, S·out) GEMM instead of a batched
                # matmul over an expanded (S, N, in) copy of the input. The bias is added in the
                # GEMM's contiguous (N, S, out) layout, then viewed as (S, N, out).
                s, n_in, n_out = w.shape
                h = (h @ w.permute(1, 0, 2).reshape(n_in, s * n_out)).reshape(-1, s, n_out)
                h = h.add_(b.transpose(0, 1)).transpose(0, 1)
            elif w.dim() == 3:
                if h.shape[0] != w.shape[0]:
                    h = h.expand(w.shape[0], *h.shape[1:])
                h = torch.baddbmm(b, h, w)
            else:
                # Shared dense weights: one matmul serves every sample (no expansion needed yet).
                h = (h @ w).add_(b)
            if act is not None:
                h = _ACT_INPLACE[act](h)
        if h.dim() == 2:
            h = h.expand(n_samples, *h.shape)
        elif h.shape[0] != n_samples:
            h = h.expand(n_samples, *h.shape[1:])
        mean, var = self._head(h, contiguous=True)
        if var is None:
            var = torch.zeros_like(mean)
        return mean, var


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


MODEL_CLASSES: dict[str, type[StackModel]] = {
    cls.kind: cls for cls in (HybridPBNN, PBNN, PNN, BNN, DNN, DeepEnsemble)
}


def build_model(cfg: ModelConfig, *, seed: int | None = 0) -> Model:
    """Build the model `cfg.kind` describes, its weights initialised from `seed` (None: global RNG)."""
    gen = torch.Generator().manual_seed(seed) if seed is not None else None
    return MODEL_CLASSES[cfg.kind](cfg, generator=gen)
