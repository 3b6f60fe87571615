"""How much of a physics-structured model's learnt correction to keep: decided on held-out maneuvers.

The correction of `[model] kind = "physics"` is trained on one-step (and short multi-step) targets.
With few maneuvers its mean can drag whole free runs away from the identified single track
(experiments/results/physics.txt: 0.056 m against the bare core's 0.039 after 4 cold-start signals),
and the training loss cannot tell: it sees the same maneuvers. So, with `[model] correction_gate`, a
probe copy of the model is trained as the model is but without a quarter of the training maneuvers,
and the held-out maneuvers' free runs (their recorded controls, from their first recorded rates)
pick the share of the correction's posterior mean a prediction keeps: 0, 1/2 or all of it
(`GATE_WEIGHTS`, ties to the smaller). With fewer held-out maneuvers than `[model]
correction_gate_min_held_out` the gate stays closed (share 0) without a probe. Each posterior draw's
deviation from that mean, the epistemic band, is kept whatever the choice, so a gated model still knows
where its data end.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch

from activelearn.errors import InputError
from activelearn.numerics.surrogate import path_from_rates, simulate
from activelearn.numerics.training_data import Log, TrainingData
from simulator.datasheet import LOG_RATE_HZ

GATE_WEIGHTS = (0.0, 0.5, 1.0)
HELD_OUT_SHARE = 0.25  # of the training maneuvers, at least one
GATE_SAMPLES = 32  # posterior draws of the held-out free runs

# Trains the probe on the held-in data (rows, logs and windows) and returns it. Called once.
ProbeTrainer = Callable[[TrainingData], torch.nn.Module]


def held_out_count(n_maneuvers: int) -> int:
    """How many of `n_maneuvers` the probe leaves out: a quarter, rounded, at least one."""
    return max(1, round(HELD_OUT_SHARE * n_maneuvers))


def held_out_groups(log_groups: Sequence, seed: int) -> np.ndarray:
    """The maneuver ids held out from the probe: a seeded quarter (at least one) of the distinct ids."""
    distinct = np.unique(np.asarray(log_groups))
    return np.random.default_rng(seed).choice(distinct, size=held_out_count(len(distinct)), replace=False)


def free_run_error(model, logs: Sequence[Log], *, seed: int = 0) -> float:
    """RMS position error (m) of the mean free path along each log, averaged over the logs.

    Positions integrate the rates (the rear axle's, no lever arm) for the truth and the model alike.
    """
    controls = [np.asarray(u, dtype=np.float64) for u, _ in logs]
    initial = np.array([y[0] for _, y in logs], dtype=np.float64)
    rollout = simulate(
        model, controls, rate_hz=LOG_RATE_HZ, n_samples=GATE_SAMPLES, seed=seed, initial_rates=initial,
        lever_arm=0.0,
    )  # fmt: skip
    mean_x, mean_y = rollout.mean_path()
    errors = []
    for i, (u, y) in enumerate(logs):
        n = len(u)
        tx, ty, _ = path_from_rates(y[:, 0], y[:, 1], dt=rollout.dt)
        errors.append(np.sqrt(np.mean((mean_x[i, :n] - tx) ** 2 + (mean_y[i, :n] - ty) ** 2)))
    return float(np.mean(errors))


def choose_correction_weight(
    train_probe: ProbeTrainer, data: TrainingData, *, seed: int, min_held_out: int = 1
) -> tuple[float, dict[float, float]] | None:
    """The share of the correction's mean to keep and each share's held-out error (m).

    `data` needs `groups` (the rows' maneuver ids), `logs` and `log_groups` (each log's id among them).
    None when there are fewer than two maneuvers or no row is left for the probe; (0, {}) without a
    probe when fewer than `min_held_out` maneuvers would be held out.
    """
    logs, log_groups = data.logs or [], data.log_groups
    if log_groups is None or len(log_groups) != len(logs):
        raise InputError("log_groups", None if log_groups is None else len(log_groups),
                         f"needs one id per log ({len(logs)})")  # fmt: skip
    n_maneuvers = len(np.unique(np.asarray(log_groups)))
    if n_maneuvers < 2:
        return None
    if held_out_count(n_maneuvers) < min_held_out:
        return 0.0, {}
    held = held_out_groups(log_groups, seed)
    rows = ~np.isin(data.groups, held)
    in_probe = ~np.isin(np.asarray(log_groups), held)
    if not rows.any():
        return None
    probe = train_probe(data.without(held))
    held_logs = [log for log, keep in zip(logs, in_probe, strict=True) if not keep and len(log[0]) > 1]
    if not held_logs:
        return None
    errors = {}
    with torch.no_grad():
        for weight in GATE_WEIGHTS:
            probe.set_correction_weight(weight)
            errors[weight] = free_run_error(probe, held_logs, seed=seed)
    best = min(GATE_WEIGHTS, key=lambda w: (errors[w], w))
    return best, errors
