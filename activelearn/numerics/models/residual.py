"""A known model plus a learnt residual: sim-to-real transfer with the residual's uncertainty.

The base (e.g. a model of the nominal simulator) is taken as known and fixed; the residual model
learns the new system's difference from the base's mean. Predictions add the two means; the
aleatoric and epistemic variances are the residual's, so its epistemic uncertainty (what the few
real maneuvers do not pin down yet) is what acquisition strategies see.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch
from torch import Tensor, nn

from activelearn.numerics.models.base import Model, Prediction, draw_moments

BASE_SAMPLES = 32  # posterior draws averaged for the base's mean (a fixed seed: a deterministic function)


class ResidualDraws:
    """S posterior draws of a residual model, each shifted by the base model's mean (see SampledModel)."""

    kernel = None  # rollouts take the block-by-block path: the base's mean is added per block

    def __init__(self, owner: ResidualModel, draws: Any) -> None:
        self.owner = owner
        self.draws = draws
        self.n_samples = draws.n_samples

    def block(
        self,
        x: Tensor,
        out: tuple[Tensor, Tensor] | None = None,
        moments: tuple[Tensor, Tensor, Tensor] | None = None,
        *,
        spread: float | None = None,
    ) -> tuple[Tensor, Tensor]:
        """`SampledModel.block` of base + residual: columns x (d, n) or (S, d, n), physical units."""
        means, var = self.draws.block(x, out=out, spread=spread)
        rows = x.t() if x.dim() == 2 else x.transpose(1, 2).reshape(-1, x.shape[1])
        shift = torch.as_tensor(self.owner.base_mean(rows.numpy()), dtype=means.dtype)
        if x.dim() == 2:
            means += shift.t()
        else:
            means += shift.reshape(x.shape[0], x.shape[2], -1).transpose(1, 2)
        if moments is not None:
            draw_moments(means, var, moments)
        return means, var

    @property
    def spread(self) -> float:
        """The residual's factor on each draw's deviation from the average draw (the base has none)."""
        return self.draws.spread

    def __call__(self, x: np.ndarray | Tensor) -> tuple[np.ndarray | Tensor, np.ndarray | Tensor]:
        """(means, variances), each (S, N, n_outputs), physical units; numpy in → numpy out."""
        means, var = self.draws(x)
        rows = x.reshape(-1, x.shape[-1]) if x.ndim == 3 else x
        shift = self.owner.base_mean(np.asarray(rows.detach() if isinstance(rows, Tensor) else rows))
        shift = shift.reshape(means.shape[1:]) if x.ndim == 2 else shift.reshape(means.shape)
        if isinstance(means, Tensor):
            return means + torch.as_tensor(shift, dtype=means.dtype), var
        return means + shift.astype(means.dtype), var


class ResidualModel(nn.Module):
    """base + residual: the interface of `Model` where the loop and the strategies use it."""

    kind: ClassVar[str] = "residual"
    n_members = None
    n_derived = 0  # free runs feed the two controls: the fused kernel's path where the draw has one
    rollout_block: ClassVar[int] = Model.rollout_block

    def __init__(self, base: Model, residual: Model) -> None:
        super().__init__()
        if base.n_inputs != residual.n_inputs or base.n_outputs != residual.n_outputs:
            raise ValueError("the base and the residual model need the same inputs and outputs")
        self.base = base
        self.residual = residual
        self.config = residual.config
        self.n_inputs = residual.n_inputs
        self.n_outputs = residual.n_outputs
        self.has_epistemic = residual.has_epistemic
        self.has_aleatoric = residual.has_aleatoric

    @property
    def epistemic_scale(self) -> Tensor:
        """The residual's epistemic scale (recalibration widens what the residual does not know)."""
        return self.residual.epistemic_scale

    @property
    def fan_scale(self) -> Tensor:
        """The residual's free-run fan scale (its draws make the fan)."""
        return self.residual.fan_scale

    def round_metrics(self) -> dict[str, float]:
        """What a campaign round records of the model beyond its evaluation: none of a residual model."""
        return {}

    def open_loop_free_runs(self, *args: Any, **kwargs: Any) -> None:
        """None: free runs step base and residual together (`Model.open_loop_free_runs`)."""
        return None

    def base_mean(self, x: np.ndarray) -> np.ndarray:
        """The base model's predictive mean at x (N, d), physical units."""
        return self.base.predict(np.asarray(x, dtype=np.float32), n_samples=BASE_SAMPLES, seed=0).mean

    @torch.no_grad()
    def predict(
        self, x: np.ndarray | Tensor, n_samples: int = 32, *, seed: int = 0, return_samples: bool = False,
        backend: str = "auto",
    ) -> Prediction:  # fmt: skip
        """Base mean plus the residual's predictive moments (see `Model.predict`)."""
        x = np.array(x.numpy() if isinstance(x, Tensor) else x, dtype=np.float32)  # a writable copy
        pred = self.residual.predict(x, n_samples, seed=seed, return_samples=return_samples, backend=backend)
        shift = self.base_mean(x)
        samples = None if pred.sample_means is None else pred.sample_means + shift[None]
        return Prediction(
            mean=pred.mean + shift,
            aleatoric_var=pred.aleatoric_var,
            epistemic_var=pred.epistemic_var,
            total_var=pred.total_var,
            sample_means=samples,
            has_epistemic=pred.has_epistemic,
            has_aleatoric=pred.has_aleatoric,
        )

    def draw(self, n_samples: int, *, seed: int = 0, backend: str = "auto") -> ResidualDraws:
        """S posterior functions: the base mean plus each residual draw."""
        return ResidualDraws(self, self.residual.draw(n_samples, seed=seed, backend=backend))

    def forward(self, x: Tensor) -> Tensor:
        """Deterministic export path: base mean plus the residual's posterior-mean network."""
        out, base = self.residual(x), self.base(x)
        k = self.n_outputs  # [mean, std] columns: add the base's mean, keep the residual's std
        return torch.cat([out[..., :k] + base[..., :k], out[..., k:]], dim=-1)
