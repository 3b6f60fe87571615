"""Linear layers: a Bayesian layer with a Gaussian variational posterior, and a plain dense layer.

Weights use the `x @ W` layout (W has shape in × out) so that S sampled weight sets stack into an
(S, in, out) tensor and a batched matmul evaluates all of them at once. The flat parameter vector of a
Bayesian layer is `[W.flatten() (row-major), b]`, of length P = (in + 1) × out; the full-covariance
posterior is a multivariate normal over that vector with a Cholesky factor L.
"""

from __future__ import annotations

import math
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor, nn

Posterior = Literal["mean_field", "full_cov"]
KLMode = Literal["exact", "mc"]


def inverse_softplus(y: float) -> float:
    """Return x with softplus(x) = y (y > 0)."""
    return y + math.log(-math.expm1(-y))


def _uniform_(t: Tensor, bound: float, generator: torch.Generator | None) -> None:
    with torch.no_grad():
        t.uniform_(-bound, bound, generator=generator)


class BayesianLinear(nn.Module):
    """Linear layer with a Gaussian posterior over weights and biases and a Gaussian prior N(0, s²).

    Training-time `forward` samples independent weights per input row without materialising them:
    local reparameterisation for the mean-field posterior (the pre-activation is Gaussian with a
    closed-form mean and variance), and an explicit per-row draw `mu + L eps` for the full-covariance
    posterior. Both give low-variance gradients. `sample` draws S weight sets shared by every input
    row, which is what prediction and posterior covariances need.
    """

    def __init__(
        self,
        n_in: int,
        n_out: int,
        *,
        posterior: Posterior = "mean_field",
        prior_scale: float = 1.0,
        prior_trainable: bool = False,
        init_std: float = 0.01,
        kl: KLMode = "exact",
        kl_samples: int = 1,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        if posterior not in ("mean_field", "full_cov"):
            raise ValueError(f"posterior must be 'mean_field' or 'full_cov', got {posterior!r}")
        if kl not in ("exact", "mc"):
            raise ValueError(f"kl must be 'exact' or 'mc', got {kl!r}")
        self.n_in, self.n_out = n_in, n_out
        self.n_params = (n_in + 1) * n_out
        self.posterior = posterior
        self.kl_mode = kl
        self.kl_samples = kl_samples
        self.init_std = init_std
        self.weight_mu = nn.Parameter(torch.empty(n_in, n_out))
        self.bias_mu = nn.Parameter(torch.empty(n_out))
        if posterior == "mean_field":
            self.weight_rho = nn.Parameter(torch.empty(n_in, n_out))
            self.bias_rho = nn.Parameter(torch.empty(n_out))
        else:
            # Cholesky factor L = strict_lower(scale_offdiag) + diag(softplus(scale_rho)).
            self.scale_rho = nn.Parameter(torch.empty(self.n_params))
            self.scale_offdiag = nn.Parameter(torch.empty(self.n_params, self.n_params))
            self.register_buffer(
                "_tril_mask", torch.ones(self.n_params, self.n_params).tril(-1), persistent=False
            )
        log_s = torch.tensor(math.log(prior_scale))
        if prior_trainable:
            self.prior_log_scale = nn.Parameter(log_s)
        else:
            self.register_buffer("prior_log_scale", log_s)
        self.reset_parameters(generator)

    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """Initialise means like torch.nn.Linear and posterior scales to `init_std`."""
        bound = 1.0 / math.sqrt(self.n_in)
        _uniform_(self.weight_mu, bound, generator)
        _uniform_(self.bias_mu, bound, generator)
        rho = inverse_softplus(self.init_std)
        with torch.no_grad():
            if self.posterior == "mean_field":
                self.weight_rho.fill_(rho)
                self.bias_rho.fill_(rho)
            else:
                self.scale_rho.fill_(rho)
                self.scale_offdiag.zero_()

    # ----- posterior pieces -------------------------------------------------------------------
    def mean_vector(self) -> Tensor:
        """Posterior mean as the flat vector [W.flatten(), b]."""
        return torch.cat([self.weight_mu.reshape(-1), self.bias_mu])

    def std_vector(self) -> Tensor:
        """Marginal posterior std of every parameter, flat."""
        if self.posterior == "mean_field":
            return torch.cat([F.softplus(self.weight_rho).reshape(-1), F.softplus(self.bias_rho)])
        return self.scale_tril().square().sum(dim=1).sqrt()

    def scale_tril(self) -> Tensor:
        """Cholesky factor L of the posterior covariance (diagonal for mean-field)."""
        if self.posterior == "mean_field":
            return torch.diag(self.std_vector())
        return self.scale_offdiag * self._tril_mask + torch.diag(F.softplus(self.scale_rho))

    def prior_scale(self) -> Tensor:
        """Prior std s of every weight."""
        return self.prior_log_scale.exp()

    # ----- KL ---------------------------------------------------------------------------------
    def kl_divergence(self) -> Tensor:
        """KL(q || p) by the configured method (closed form or Monte Carlo)."""
        return self.kl_exact() if self.kl_mode == "exact" else self.kl_mc(self.kl_samples)

    def kl_exact(self) -> Tensor:
        """Closed-form KL between the Gaussian posterior and the N(0, s²) prior."""
        log_s = self.prior_log_scale
        inv_var = torch.exp(-2.0 * log_s)
        mu_sq = self.weight_mu.square().sum() + self.bias_mu.square().sum()
        p = self.n_params
        if self.posterior == "mean_field":
            sw, sb = F.softplus(self.weight_rho), F.softplus(self.bias_rho)
            trace = sw.square().sum() + sb.square().sum()
            log_det = 2.0 * (sw.log().sum() + sb.log().sum())
        else:
            lower = self.scale_tril()
            trace = lower.square().sum()
            log_det = 2.0 * F.softplus(self.scale_rho).log().sum()
        return 0.5 * ((trace + mu_sq) * inv_var - p + 2.0 * p * log_s - log_det)

    def kl_mc(self, n_samples: int = 1, generator: torch.Generator | None = None) -> Tensor:
        """Monte Carlo KL: mean over reparameterised draws w ~ q of log q(w) − log p(w)."""
        mu = self.mean_vector()
        eps = torch.randn(n_samples, self.n_params, generator=generator, dtype=mu.dtype)
        if self.posterior == "mean_field":
            std = self.std_vector()
            w = mu + eps * std
            log_det_half = std.log().sum()
        else:
            lower = self.scale_tril()
            w = mu + eps @ lower.T
            log_det_half = F.softplus(self.scale_rho).log().sum()
        log_s = self.prior_log_scale
        # Normalising constants (2π) cancel between q and p.
        log_q = -0.5 * eps.square().sum(dim=1) - log_det_half
        log_p = -0.5 * w.square().sum(dim=1) * torch.exp(-2.0 * log_s) - self.n_params * log_s
        return (log_q - log_p).mean()

    # ----- evaluation -------------------------------------------------------------------------
    def forward(self, x: Tensor) -> Tensor:
        """Stochastic training forward pass: independent weights per row (local reparameterisation)."""
        mean = torch.addmm(self.bias_mu, x, self.weight_mu)
        if self.posterior == "mean_field":
            var = torch.addmm(
                F.softplus(self.bias_rho).square(), x.square(), F.softplus(self.weight_rho).square()
            )
            return mean + var.sqrt() * torch.randn_like(mean)
        # Full covariance: draw this row's weight deviation L eps and apply it.
        dev = torch.randn(x.shape[0], self.n_params, dtype=x.dtype) @ self.scale_tril().T
        dev_w = dev[:, : self.n_in * self.n_out].reshape(-1, self.n_in, self.n_out)
        dev_b = dev[:, self.n_in * self.n_out :]
        return mean + torch.einsum("ni,nio->no", x, dev_w) + dev_b

    def output_moments(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Exact mean and variance of the pre-activations for rows x under the posterior."""
        mean = torch.addmm(self.bias_mu, x, self.weight_mu)
        x1 = torch.cat([x, torch.ones(x.shape[0], 1, dtype=x.dtype)], dim=1)
        # Row n, unit j: Var = || sum_i x1[n,i] L[(i,j), :] ||².
        lower = self.scale_tril().reshape(self.n_in + 1, self.n_out, self.n_params)
        proj = torch.einsum("ni,ijp->njp", x1, lower)
        return mean, proj.square().sum(dim=-1)

    def sample(
        self, n_samples: int, generator: torch.Generator | None = None, *, eps: Tensor | None = None
    ) -> tuple[Tensor, Tensor]:
        """Draw S weight sets: W of shape (S, in, out) and b of shape (S, 1, out).

        `eps`, (S, n_params) standard normals, replaces the draw from `generator` when given.
        """
        if eps is None:
            eps = torch.randn(n_samples, self.n_params, generator=generator, dtype=self.weight_mu.dtype)
        mu = self.mean_vector()
        if self.posterior == "mean_field":
            w = mu + eps * self.std_vector()
        else:
            w = mu + eps @ self.scale_tril().T
        split = self.n_in * self.n_out
        return w[:, :split].reshape(n_samples, self.n_in, self.n_out), w[:, split:].unsqueeze(1)

    def mean_params(self) -> tuple[Tensor, Tensor]:
        """Posterior-mean weights as a single 'sample': (1, in, out) and (1, 1, out)."""
        return self.weight_mu.unsqueeze(0), self.bias_mu.reshape(1, 1, -1)

    def extra_repr(self) -> str:
        return f"{self.n_in}, {self.n_out}, posterior={self.posterior}, kl={self.kl_mode}"


class DenseLinear(nn.Module):
    """Deterministic linear layer in `x @ W` layout; with `members=K` it holds K independent copies."""

    def __init__(
        self, n_in: int, n_out: int, *, members: int | None = None, generator: torch.Generator | None = None
    ) -> None:
        super().__init__()
        self.n_in, self.n_out, self.members = n_in, n_out, members
        lead = () if members is None else (members,)
        self.weight = nn.Parameter(torch.empty(*lead, n_in, n_out))
        self.bias = nn.Parameter(torch.empty(*lead, 1, n_out) if members else torch.empty(n_out))
        self.reset_parameters(generator)

    def reset_parameters(self, generator: torch.Generator | None = None) -> None:
        """Initialise like torch.nn.Linear (uniform ±1/√in)."""
        bound = 1.0 / math.sqrt(self.n_in)
        _uniform_(self.weight, bound, generator)
        _uniform_(self.bias, bound, generator)

    def forward(self, x: Tensor) -> Tensor:
        """Apply the layer; with members, x has shape (K, N, in)."""
        if self.members is None:
            return torch.addmm(self.bias, x, self.weight) if x.dim() == 2 else x @ self.weight + self.bias
        return torch.baddbmm(self.bias, x, self.weight)

    def extra_repr(self) -> str:
        return f"{self.n_in}, {self.n_out}, members={self.members}"
