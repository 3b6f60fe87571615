"""How far a surrogate's free runs drift from the truth, and how wide their fans must be to hold it.

Built on the rollouts of `activelearn.numerics.surrogate`: each log's recorded controls run free
through the model from its first recorded rates; the metrics compare the mean path and the 95 % fan
with the logged (or noise-free) truth. The campaign logs `free_run_metrics` every round
(`activelearn.names.ROLLOUT_METRICS`); `fan_scale_needed` / `calibrate_fan` fit a model's fan width
on held-out maneuvers (split-conformal).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from activelearn.errors import InputError
from activelearn.names import (
    CONTROLS,
    RATES,
    ROLLOUT_COVERAGE_95,
    ROLLOUT_HEADING_ERR_30S,
    ROLLOUT_METRICS,
    ROLLOUT_POS_ERR_10S,
    ROLLOUT_POS_ERR_30S,
    ROLLOUT_RMSE_V,
    ROLLOUT_RMSE_W,
    SPEED,
    TRUTH_COLUMNS,
    YAW_RATE,
)
from activelearn.numerics.surrogate import Rollout, simulate
from activelearn.replay import relative_pose
from simulator import noise_std

FAN_SCALE_RANGE = (1e-2, 1e3)  # free-run fan scales beyond these mean a broken model, not a fan

__all__ = [
    "ROLLOUT_METRICS",
    "Excursion",
    "TrackMetrics",
    "calibrate_fan",
    "fan_excursions",
    "fan_scale_needed",
    "fan_widening_needed",
    "free_run_metrics",
    "free_runs",
    "inside_fans",
    "relative_pose",
    "track_metrics",
]


@dataclass(frozen=True)
class TrackMetrics:
    """Accuracy of one surrogate rollout against ground truth."""

    rmse_v: float
    rmse_w: float
    position_error: dict[float, float]  # seconds -> metres between mean path and true path
    coverage_v: float  # fraction of true steps inside the 95% band
    coverage_w: float
    coverage_position: float  # fraction of steps whose true (x, y) lies inside both 95% bands
    mean_position_error: float  # metres between mean path and true path, averaged over the steps


@dataclass(frozen=True)
class Excursion:
    """A stretch of time where the truth stays outside a channel's 95 % fan (an anomaly to look at)."""

    channel: str  # "position", "speed" or "yaw rate"
    start: float  # s, first step outside
    end: float  # s, last step outside

    @property
    def seconds(self) -> float:
        """How long it lasts (one step counts as none)."""
        return self.end - self.start


def inside_fans(
    rollout: Rollout, index: int, truth: dict[str, np.ndarray], noise: Any | None = None
) -> dict[str, np.ndarray]:
    """Per channel ("speed", "yaw rate", "position"), per step of maneuver `index`: whether the truth
    lies inside the 95 % fan (position: inside both the x and the y band, in the start frame).

    With `noise` (a measured log's sensor noise, a `simulator.NoiseConfig`) a logged position counts
    as inside within two standard deviations of its noise beyond a band: the pose fan is the true
    path's, and a free run's first steps have a fan narrower than the noise. The sampled rates carry
    the noise the model learnt, so their bands are taken as they are.
    """
    n = int(rollout.lengths[index])
    q = {name: rollout.quantiles(name, index)[:, :n] for name in ("v", "w", "x", "y")}

    def inside(values: np.ndarray, name: str, allowed: np.ndarray | float = 0.0) -> np.ndarray:
        return (values >= q[name][0] - allowed) & (values <= q[name][-1] + allowed)

    true_x, true_y, _ = relative_pose(truth, n)
    var_x, var_y = _position_noise_variance(truth[SPEED][:n], true_x, true_y, noise)
    return {
        "speed": inside(truth[SPEED][:n], "v"),
        "yaw rate": inside(truth[YAW_RATE][:n], "w"),
        "position": inside(true_x, "x", 2.0 * np.sqrt(var_x)) & inside(true_y, "y", 2.0 * np.sqrt(var_y)),
    }


def fan_excursions(
    rollout: Rollout, index: int, truth: dict[str, np.ndarray], min_seconds: float = 0.5,
    noise: Any | None = None,
) -> list[Excursion]:  # fmt: skip
    """The stretches of at least `min_seconds` where the truth leaves a 95 % fan (`inside_fans`), by
    channel, in time order. A 95 % band misses one step in twenty by design: shorter stretches are
    mostly those misses."""
    found = []
    for channel, inside in inside_fans(rollout, index, truth, noise).items():
        edges = np.flatnonzero(np.diff(np.concatenate(([0], (~inside).astype(np.int8), [0]))))
        for first, stop in zip(edges[::2], edges[1::2], strict=True):
            start, end = first * rollout.dt, (stop - 1) * rollout.dt
            if end - start >= min_seconds - 1e-9:
                found.append(Excursion(channel, float(start), float(end)))
    return sorted(found, key=lambda e: (e.start, e.channel))


def track_metrics(
    rollout: Rollout, index: int, truth: dict[str, np.ndarray], times: Sequence[float] = (10.0, 30.0),
    noise: Any | None = None,
) -> TrackMetrics:  # fmt: skip
    """Compare maneuver `index` of a rollout with ground truth arrays `speed`, `angZ`, `posX`, `posY`.

    Truth positions are taken relative to the start, rotated into the start heading `yaw[0]`; the
    coverages are `inside_fans`' (`noise`: a measured log's sensor noise).
    """
    n = int(rollout.lengths[index])
    true_v, true_w = truth[SPEED][:n], truth[YAW_RATE][:n]
    true_x, true_y, _ = relative_pose(truth, n)
    mean_v, mean_w = rollout.mean_rates[index, :n, 0], rollout.mean_rates[index, :n, 1]
    mx, my = (a[:n] for a in rollout.mean_path(index))
    inside = inside_fans(rollout, index, truth, noise)
    errors = np.hypot(mx - true_x, my - true_y)
    marks = {float(t): float(errors[min(round(t / rollout.dt), n - 1)]) for t in times if t < n * rollout.dt}
    marks[float((n - 1) * rollout.dt)] = float(errors[-1])
    return TrackMetrics(
        rmse_v=float(np.sqrt(np.mean((mean_v - true_v) ** 2))),
        rmse_w=float(np.sqrt(np.mean((mean_w - true_w) ** 2))),
        position_error=marks,
        coverage_v=float(inside["speed"].mean()),
        coverage_w=float(inside["yaw rate"].mean()),
        coverage_position=float(inside["position"].mean()),
        mean_position_error=float(errors.mean()),
    )


def free_runs(
    model,
    logs: Sequence,
    *,
    rate_hz: float,
    n_samples: int = 32,
    seed: int = 0,
    fan_scale: float | None = None,
    backend: str = "auto",
) -> Rollout:
    """Each log's recorded controls run free through `model` from its first recorded rates (`backend`:
    `simulate`'s)."""
    # column by column: a frame of the two columns costs 4x (its index is built anew each time)
    controls = [np.column_stack([t[c].to_numpy(np.float64) for c in CONTROLS]) for t in logs]
    initial = np.array([[t[rate].to_numpy()[0] for rate in RATES] for t in logs])
    return simulate(
        model, controls, rate_hz=rate_hz, n_samples=n_samples, seed=seed, initial_rates=initial,
        fan_scale=fan_scale, backend=backend,
    )  # fmt: skip


def _position_noise_variance(
    speed: np.ndarray, tx: np.ndarray, ty: np.ndarray, noise: Any | None
) -> tuple[np.ndarray, np.ndarray]:
    """σ² per axis of a logged position relative to the log's start (tx, ty), from the sensor noise:
    step k's and the start's position noise, and the start heading's noise turned through the
    distance driven. Zero without noise."""
    if noise is None or not noise.enabled:
        return np.zeros_like(tx), np.zeros_like(ty)
    position, heading = (noise_std(noise, field, speed) for field in ("position", "angle"))
    both = position**2 + position[0] ** 2  # step k's and the start's
    # a start heading error ε moves (x, y) by ε (−y, x)
    return both + heading[0] ** 2 * ty**2, both + heading[0] ** 2 * tx**2


def fan_widening_needed(
    rollout: Rollout, truth_logs: Sequence, noise: Any | None = None
) -> np.ndarray:
    """Per step of every run: the factor by which the 95 % position fan must widen about the mean
    path to hold the true position (x and y band both; <= 1 where it already does; inf where the
    fan has no width yet).

    With `noise` (the logs' sensor noise, a `simulator.NoiseConfig`), the logged positions are
    measurements, not the truth: the relative position of step k carries the position noise of step
    k and of the start, and the start heading's noise turned through the distance driven (variance
    σ²). The fan is for the true position, so the squared error is taken less that variance, its
    unbiased estimate of the true squared error (errors in variables): the need is
    sqrt(max(e² − σ², 0)) / gap. Without it a noisy log's first steps (no fan yet, 2-6 mm of noise)
    and every step's noise read as misses. Measured (the truth's need, noise allowed for, naive): a
    physics model on dynamics.toml's test set 1.85, 2.15, 2.55; on 12 held-out pool signals 2.27,
    2.56, 2.90; a static skidpad model on 12-s maneuvers 12.3, 12.9, 16.5. The rest of the overshoot
    comes from the first steps, where fan and error are both smaller than the noise. Subtracting the
    95 % band's z² σ² instead came closer on the first two (1.84, 2.20) but fell 40 % short on the
    third (7.5): fans too narrow.
    """
    band_x, band_y = (np.quantile(getattr(rollout, a), (0.025, 0.975), axis=0) for a in ("x", "y"))
    mean_x, mean_y = rollout.mean_path()
    needs = []
    for i, table in enumerate(truth_logs):
        n = int(rollout.lengths[i])
        tx, ty, _ = relative_pose({c: table[c].to_numpy(dtype=np.float64) for c in TRUTH_COLUMNS}, n)
        speed = table[SPEED].to_numpy(dtype=np.float64)[:n]
        noise_x, noise_y = _position_noise_variance(speed, tx, ty, noise)
        per_axis = []
        for truth, centre, band, allowed in (
            (tx, mean_x[i, :n], band_x[:, i, :n], noise_x),
            (ty, mean_y[i, :n], band_y[:, i, :n], noise_y),
        ):
            error = truth - centre
            gap = np.where(error >= 0, band[1] - centre, centre - band[0])
            beyond = np.sqrt(np.maximum(error**2 - allowed, 0.0))
            with np.errstate(divide="ignore", invalid="ignore"):
                need = beyond / np.maximum(gap, 0.0)
            per_axis.append(np.where(beyond < 1e-9, 0.0, need))  # the start, or within the noise
        needs.append(np.maximum(*per_axis))
    return np.concatenate(needs)


def fan_scale_needed(
    model,
    logs: Sequence,
    *,
    level: float = 0.95,
    rate_hz: float,
    n_samples: int = 32,
    seed: int = 0,
    noise: Any | None = None,
) -> float:
    """The free-run fan scale under which `level` of the true positions of `logs` lie inside the
    95 % fan (split-conformal on held-out maneuvers). Leaves the model as it was. `noise` is the
    logs' sensor noise, allowed for when they are measurements (`fan_widening_needed`).

    The scale widens the pose fan about the mean path (`simulate`), so a band's quantiles move
    exactly by it and one rollout tells the scale. A run that blows up gives scale 1e3.
    """
    if not 0.0 < level < 1.0:
        raise InputError("level", level, "must lie in (0, 1)")
    if not logs:
        raise InputError("logs", 0, "need at least one log to calibrate the fan on")
    rollout = free_runs(model, logs, rate_hz=rate_hz, n_samples=n_samples, seed=seed, fan_scale=1.0)
    needs = np.nan_to_num(fan_widening_needed(rollout, logs, noise), nan=np.inf)
    # "higher": an order statistic, no interpolation between a finite need and an infinite one
    need = float(np.quantile(needs, level, method="higher"))
    return float(np.clip(need, *FAN_SCALE_RANGE))


def calibrate_fan(model, logs: Sequence, **kwargs) -> float:
    """Fit the model's `fan_scale` on held-out logs (`fan_scale_needed`); store it and return it."""
    scale = fan_scale_needed(model, logs, **kwargs)
    with torch.no_grad():
        model.fan_scale.fill_(scale)
    return scale


def free_run_metrics(
    model,
    logs: Sequence,
    truth_logs: Sequence | None = None,
    *,
    rate_hz: float,
    n_samples: int = 32,
    seed: int = 0,
) -> dict[str, float]:
    """Run each logged maneuver free through `model` and measure how far it drifts (`ROLLOUT_METRICS`).

    Each rollout starts from its log's first recorded rates and is given only the recorded controls
    (the eight's too, which MuJoCo chose by heading feedback); nothing after the start is fed back
    from the log. Against `truth_logs` (noise-free where known; default the logs themselves):
    position error of the mean path at 10 s and 30 s (a maneuver shorter than that at its end) and
    heading error at 30 s, averaged over maneuvers; RMSE of the mean v and ω along the run; the share
    of true positions inside the 95 % fan (both the x and the y band), over every step of every run.
    """
    truth_logs = logs if truth_logs is None else truth_logs
    rollout = free_runs(model, logs, rate_hz=rate_hz, n_samples=n_samples, seed=seed)
    band_x, band_y = (np.quantile(getattr(rollout, a), (0.025, 0.975), axis=0) for a in ("x", "y"))
    mean_x, mean_y = rollout.mean_path()
    mean_yaw = rollout.yaw.mean(axis=0)
    at = {10.0: [], 30.0: []}
    heading, sq_v, sq_w, inside, steps = [], 0.0, 0.0, 0, 0
    for i, table in enumerate(truth_logs):
        n = int(rollout.lengths[i])
        truth = {c: table[c].to_numpy(dtype=np.float64) for c in TRUTH_COLUMNS}
        tx, ty, tyaw = relative_pose(truth, n)
        # a run that blew up (inf, then nan) is as far off as can be: inf, so rankings put it last
        errors = np.nan_to_num(np.hypot(mean_x[i, :n] - tx, mean_y[i, :n] - ty), nan=np.inf)
        for t in at:
            at[t].append(errors[min(round(t / rollout.dt), n - 1)])
        k30 = min(round(30.0 / rollout.dt), n - 1)
        gap = mean_yaw[i, k30] - tyaw[k30]
        heading.append(abs(np.angle(np.exp(1j * gap))) if np.isfinite(gap) else np.inf)  # wrapped to [0, π]
        sq_v += float(np.sum((rollout.mean_rates[i, :n, 0] - truth[SPEED][:n]) ** 2))
        sq_w += float(np.sum((rollout.mean_rates[i, :n, 1] - truth[YAW_RATE][:n]) ** 2))
        within = (band_x[0, i, :n] <= tx) & (tx <= band_x[1, i, :n])
        within &= (band_y[0, i, :n] <= ty) & (ty <= band_y[1, i, :n])
        inside += int(within.sum())
        steps += n
    return {
        ROLLOUT_POS_ERR_10S: float(np.mean(at[10.0])),
        ROLLOUT_POS_ERR_30S: float(np.mean(at[30.0])),
        ROLLOUT_HEADING_ERR_30S: float(np.mean(heading)),
        ROLLOUT_RMSE_V: float(np.nan_to_num(np.sqrt(sq_v / steps), nan=np.inf)),
        ROLLOUT_RMSE_W: float(np.nan_to_num(np.sqrt(sq_w / steps), nan=np.inf)),
        ROLLOUT_COVERAGE_95: float(inside / steps),
    }
