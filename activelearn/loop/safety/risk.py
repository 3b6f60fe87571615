"""A candidate's risk from the model's rollout fan, and the assessment that admits, cuts or refuses it.

For each candidate the round's model rolls the maneuver out from the start pose (`simulate`: S
trajectories, each one posterior draw with aleatoric noise at every step, the epistemic spread widened
by `[safety] fan_scale`). A trajectory violates at its first step that breaks a wall or a limit
(`limits.violating`, the walls `path_tolerance` wider: what a free run's path may still miss of the
car's). The candidate's risk over a duration T is the share of trajectories that violated before T:
within `delta` over the full duration it is admissible as it is; else it is cut to the longest whole
number of seconds whose risk is within `delta`, when that is at least `min_duration`; else refused.
Where the model extrapolates (its epistemic std of a rate in `trust_rates` exceeds `trust_std` of
the rate along the maneuver) the kinematic worst case must hold as well. One rollout serves
evaluation, acquisition and safety.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from activelearn.config import POSE_LEVER_ARM, SafetyConfig
from activelearn.loop.pool import maneuver_controls
from activelearn.loop.safety.kinematic_bound import DEFAULT_CAR, Car, TurnSpeed, kinematic_bound
from activelearn.loop.safety.limits import violating
from activelearn.numerics.surrogate import Rollout, simulate

CHUNK = 16  # maneuvers per rollout: S x 16 x 2 700 steps x 5 arrays of float32 stay near 60 MB
# The smallest rate a relative std is taken of (speed m/s, yaw rate rad/s), so a standing or
# straight-driving car does not divide by ~0 (docs/results/safety.md).
RATE_FLOORS = {"speed": 0.02, "yaw_rate": 0.05}


@dataclass(frozen=True)
class Assessment:
    """Admissibility of candidates: risk over the full duration, admissible duration, why not.

    risk: (n,) share of fan trajectories that violate within the full duration (NaN: not assessed).
    duration: (n,) seconds the candidate may be driven (its full duration, shorter when cut, 0 when
        not admissible). cut_risk: (n,) risk over that duration.
    """

    risk: np.ndarray
    duration: np.ndarray
    cut_risk: np.ndarray
    full: np.ndarray  # (n,) the candidates' full durations

    @property
    def admissible(self) -> np.ndarray:
        """(n,) True where the candidate may be driven (perhaps cut short)."""
        return self.duration > 0

    @property
    def cut(self) -> np.ndarray:
        """(n,) True where the candidate is admissible only when cut short."""
        return self.admissible & (self.duration < self.full - 1e-9)

    @property
    def size(self) -> int:
        """Number of admissible candidates (the safe set)."""
        return int(self.admissible.sum())

    @property
    def assessed(self) -> np.ndarray:
        """(n,) True where the candidate was assessed (an open one; the rest have risk NaN)."""
        return np.isfinite(self.risk)

    @property
    def share(self) -> float:
        """Admissible share of the assessed candidates (NaN: none assessed); unlike `size` it does not
        shrink as picks leave the pool, so it shows whether the set grows."""
        assessed = self.assessed
        return float(self.admissible[assessed].mean()) if assessed.any() else float("nan")

    @property
    def time_share(self) -> float:
        """Admissible share of the assessed candidates' driving seconds (NaN: none assessed); a cut
        candidate counts its cut seconds, so the share grows as the model trusts later seconds."""
        assessed = self.assessed
        total = float(self.full[assessed].sum())
        return float(self.duration[assessed].sum()) / total if total > 0 else float("nan")


def widened(model: Any, fan_scale: float) -> Any:
    """A copy of `model` whose epistemic std is `fan_scale` times its own; `model` is left as it is."""
    copied = copy.deepcopy(model)
    with torch.no_grad():  # the scale is a variance factor; fan_scale widens the std
        copied.epistemic_scale.fill_(float(model.epistemic_scale) * fan_scale**2)
    return copied


def fan(model: Any, maneuvers: Sequence[Any], cfg: SafetyConfig, rate_hz: float, seed: int,
        *, widen: bool = True) -> Rollout:  # fmt: skip
    """The model's rollout of `maneuvers` from the start pose, in the arena frame, its epistemic spread
    widened by [safety] `fan_scale` (`widen=False`: `model` is such a copy already, `widened`).

    The model's own pose-fan calibration (`model.fan_scale`, for predictions) is not applied:
    [safety] `fan_scale` is the margin.
    """
    x0, y0, yaw0 = cfg.start
    rollout = simulate(
        widened(model, cfg.fan_scale) if widen else model,
        [maneuver_controls(m, rate_hz) for m in maneuvers], rate_hz=rate_hz,
        n_samples=cfg.n_samples, seed=seed, initial_yaw=yaw0, fan_scale=1.0,
    )  # fmt: skip
    return dataclasses.replace(rollout, x=rollout.x + x0, y=rollout.y + y0)


def first_violations(rollout: Rollout, cfg: SafetyConfig, rate_hz: float) -> np.ndarray:
    """(S, M) seconds at which each trajectory first violates (inf: never within its maneuver)."""
    code = violating(rollout.x, rollout.y, rollout.v, rollout.w, cfg, rate_hz, cfg.path_tolerance,
                     walls=cfg.stop != "live")  # fmt: skip
    steps = np.arange(code.shape[-1])
    code[:, steps[None, :] >= rollout.lengths[:, None]] = 0  # padding past a maneuver's end
    bad = code > 0
    first = np.where(bad.any(axis=-1), bad.argmax(axis=-1), np.inf)
    return first * rollout.dt


def admissible_duration(times: np.ndarray, full: float, cfg: SafetyConfig) -> tuple[float, float, float]:
    """Full-duration risk, the duration to drive (0: none) and its risk, from (S,) first violations."""
    n = len(times)
    risk = float(np.mean(times < full))
    if risk <= cfg.delta:
        return risk, full, risk
    allowed = math.floor(cfg.delta * n + 1e-9)  # trajectories that may violate
    cut = float(np.floor(np.sort(times)[allowed]))  # before it, at most `allowed` have violated
    if cut < cfg.min_duration:
        return risk, 0.0, float("nan")
    return risk, cut, float(np.mean(times < cut))


def assess(
    model: Any | None,
    maneuvers: Sequence[Any],
    cfg: SafetyConfig,
    *,
    rate_hz: float,
    seed: int = 0,
    which: np.ndarray | None = None,
    turn: TurnSpeed | None = None,
    car: Car = DEFAULT_CAR,
) -> Assessment:
    """Admissibility of every candidate in `maneuvers` (only those in `which`; the rest are not admissible).

    With a model: from its rollout fans, in chunks of CHUNK maneuvers. Without one: the kinematic
    worst case alone, with the speed kept in turns `turn` where given.
    """
    n = len(maneuvers)
    full = np.array([float(m.duration) for m in maneuvers])
    risk, duration, cut_risk = np.full(n, np.nan), np.zeros(n), np.full(n, np.nan)
    todo = np.arange(n) if which is None else np.flatnonzero(which)
    arm = float(getattr(getattr(model, "config", None), "pose_lever_arm", POSE_LEVER_ARM))
    bounds = {"rate_hz": rate_hz, "turn": turn, "car": car}
    if model is None:
        for i in todo:
            risk[i], duration[i], cut_risk[i] = kinematic_bound(maneuvers[i], cfg, arm, **bounds)
        return Assessment(risk, duration, cut_risk, full)
    wide = widened(model, cfg.fan_scale) if len(todo) else model
    for block in range(0, len(todo), CHUNK):
        rows = todo[block : block + CHUNK]
        rollout = fan(wide, [maneuvers[i] for i in rows], cfg, rate_hz, seed + block, widen=False)
        times = first_violations(rollout, cfg, rate_hz)
        untrusted = relative_std(rollout, cfg.trust_rates) / cfg.fan_scale > cfg.trust_std
        for j, i in enumerate(rows):
            risk[i], duration[i], cut_risk[i] = admissible_duration(times[:, j], full[i], cfg)
            if untrusted[j]:  # the model extrapolates: the kinematic worst case must hold as well
                bound = kinematic_bound(maneuvers[i], cfg, arm, **bounds)
                risk[i] = max(risk[i], bound[0])
                if bound[1] < duration[i]:
                    duration[i], cut_risk[i] = bound[1], bound[2] if bound[1] > 0 else float("nan")
    return Assessment(risk, duration, cut_risk, full)


def relative_std(rollout: Rollout, rates: Sequence[str] = ("speed",)) -> np.ndarray:
    """(M,) largest epistemic std of `rates` along each maneuver, each relative to its rate (RATE_FLOORS)."""
    worst = np.zeros(len(rollout.lengths))
    past = np.arange(rollout.epistemic_var.shape[1])[None, :] >= rollout.lengths[:, None]
    for name in rates:
        column = ("speed", "yaw_rate").index(name)
        std = np.sqrt(rollout.epistemic_var[..., column])
        relative = std / np.maximum(np.abs(rollout.mean_rates[..., column]), RATE_FLOORS[name])
        relative[past] = 0.0
        worst = np.maximum(worst, relative.max(axis=1))
    return worst
