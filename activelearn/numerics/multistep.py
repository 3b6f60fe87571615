"""Multi-step training of dynamic models: the loss of free-running windows.

A model trained on one-step targets only sees recorded past rates at its inputs; running free it
sees its own predictions, and small one-step errors compound (exposure bias). The window loss runs
the model `H` log steps from a recorded history, each step reading the controls as recorded and
the rates it predicted itself (its mean, so the loss is differentiable end to end), and scores every
step's Gaussian prediction against the recorded rates. Back-propagation runs through the whole
window (truncated BPTT: windows start anew from recorded histories).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from activelearn.errors import InputError
from activelearn.numerics.lags import Lags


@dataclass(frozen=True)
class Windows:
    """Free-running training windows in physical units.

    `controls` (W, (k-1)s + H, 2): the controls from the oldest one a window's first step reads to
    its last step; `past` (W, ks, 2): the recorded rates before the window; `target` (W, H, 2): the
    rates to predict. `lags` is the model's input layout; `source` (W,) the index of the log each
    window comes from (to train on a subset of the logs).
    """

    controls: np.ndarray
    past: np.ndarray
    target: np.ndarray
    lags: Lags
    source: np.ndarray | None = None

    def of_logs(self, keep: np.ndarray) -> Windows | None:
        """The windows of the logs whose indices are in `keep` (None if none)."""
        if self.source is None:
            raise InputError("windows", "source", "windows without their logs' indices cannot be split")
        rows = np.isin(self.source, keep)
        if not rows.any():
            return None
        return Windows(self.controls[rows], self.past[rows], self.target[rows], self.lags, self.source[rows])

    @property
    def horizon(self) -> int:
        """Steps per window."""
        return int(self.target.shape[1])

    def __len__(self) -> int:
        return int(self.target.shape[0])


def windows_from_logs(
    logs: Sequence[tuple[np.ndarray, np.ndarray]], lags: Lags, horizon: int, every: int
) -> Windows | None:
    """Windows of `horizon` steps from logs given as (controls (T, 2), rates (T, 2)), one every
    `every` steps of each log; None when no log is long enough."""
    if horizon < 1 or every < 1:
        raise InputError("rollout_horizon", horizon, "windows need horizon >= 1 and a step >= 1")
    back_u, back_y = (lags.history - 1) * lags.step, lags.span
    controls, past, target, source = [], [], [], []
    for i, (u, y) in enumerate(logs):
        for t0 in range(back_y, len(u) - horizon + 1, every):
            source.append(i)
            controls.append(u[t0 - back_u : t0 + horizon])
            past.append(y[t0 - back_y : t0])
            target.append(y[t0 : t0 + horizon])
    if not target:
        return None
    as_array = lambda parts: np.asarray(np.stack(parts), dtype=np.float32)  # noqa: E731
    return Windows(as_array(controls), as_array(past), as_array(target), lags, np.array(source))


def window_loss(model, windows: Windows, rows: Tensor) -> Tensor:
    """Mean per-step Gaussian NLL (standardised units, summed over outputs) of free runs of `rows`.

    An ensemble runs every window once per member, each member fed its own predictions, and sums
    the members' losses as its one-step loss does (each member gets the gradient it would alone).
    """
    lags = windows.lags
    controls = torch.from_numpy(windows.controls)[rows]
    past = torch.from_numpy(windows.past)[rows]
    target = (torch.from_numpy(windows.target)[rows] - model.y_mean) / model.y_std
    members = model.n_members
    if members is not None:  # (K, W, ...): one batch of windows per member
        controls, past, target = (t.expand(members, *t.shape) for t in (controls, past, target))
    rates: list[Tensor] = list(past.unbind(-2))  # grows by predictions
    back_u = (lags.history - 1) * lags.step
    total = torch.zeros(())
    for h in range(windows.horizon):
        now = len(rates)  # index of step h in the rates list
        inputs = [controls[..., back_u + h - d, :] for d in lags.control_lags]
        inputs += [rates[now - d] for d in lags.rate_lags]
        x = model.standardise_inputs(torch.cat(inputs, dim=-1))
        mean, var = model.train_forward(x)
        err = target[..., h, :] - mean
        per = err.square() if var is None else 0.5 * (var.log() + err.square() / var)
        total = total + per.sum(dim=-1).mean(dim=-1).sum()
        rates.append(mean * model.y_std + model.y_mean)
    return total / windows.horizon
