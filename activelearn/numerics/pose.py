"""The planar pose a free run's rates drive: one integrator for every kind and core.

ψ_{k+1} = ψ_k + ω_k dt and the position by the heading at the step's start (the rates are each step's
mean over it); a dynamic core adds the rear axle's lateral speed (its sideslip), a kinematic one has
none. The sums move the rear axle; the pose reported is that of a point `lever_arm` metres ahead of it.
"""

from __future__ import annotations

import torch
from torch import Tensor


def integrate_pose(
    v: Tensor,
    w: Tensor,
    dt: float,
    yaw0: Tensor,
    out: tuple[Tensor, Tensor, Tensor] | None = None,
    lever_arm: float = 0.0,
    lateral: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """(x, y, ψ), each like v (..., T), relative to the start, from speed `v`, yaw rate `w` and where given
    the rear axle's `lateral` speed (m/s, to the left). `yaw0` broadcasts against (..., 1). Writes into
    `out` = (x, y, yaw) when given."""
    x, y, yaw = out if out is not None else (torch.empty_like(v) for _ in range(3))
    scratch = torch.empty_like(v)

    def shifted_cumsum(rate: Tensor, into: Tensor) -> Tensor:
        """into[..., k] = sum of rate[..., :k] (the value before step k)."""
        into[..., 0] = 0.0
        torch.cumsum(rate[..., :-1], dim=-1, out=into[..., 1:])
        return into

    shifted_cumsum(w, yaw)
    torch.add(yaw0, yaw, alpha=dt, out=yaw)
    # One scratch buffer serves v cos ψ, then v sin ψ.
    torch.cos(yaw, out=scratch).mul_(v)
    if lateral is not None:
        scratch.sub_(torch.sin(yaw) * lateral)
    shifted_cumsum(scratch, x).mul_(dt)
    torch.sin(yaw, out=scratch).mul_(v)
    if lateral is not None:
        scratch.add_(torch.cos(yaw) * lateral)
    shifted_cumsum(scratch, y).mul_(dt)
    if lever_arm:  # cos ψ and sin ψ again: keeping them costs a buffer and measured no faster
        start = torch.as_tensor(yaw0, dtype=v.dtype)
        x.add_(torch.cos(yaw, out=scratch).sub_(torch.cos(start)), alpha=lever_arm)
        y.add_(torch.sin(yaw, out=scratch).sub_(torch.sin(start)), alpha=lever_arm)
    return x, y, yaw
