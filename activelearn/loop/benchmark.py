"""The surrogate beside MuJoCo: the same maneuvers simulated by both, on the controls MuJoCo applied.

A floor above the numerics because it runs the simulator (`activelearn predict` and the benchmarks
use it); the numerics themselves never run MuJoCo.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

import simulator
from activelearn.names import CONTROLS, RATES, TRUTH_COLUMNS
from activelearn.numerics.diagnostics import TrackMetrics, track_metrics
from activelearn.numerics.surrogate import Rollout, simulate
from simulator import Maneuver


@dataclass(frozen=True)
class Benchmark:
    """A surrogate rollout beside the MuJoCo log of the same maneuvers, with per-maneuver metrics."""

    rollout: Rollout
    truth: list  # one pandas DataFrame per maneuver (MuJoCo log, AutoDRIVE layout)
    metrics: list[TrackMetrics]


def against_simulator(
    model,
    maneuvers: Sequence[Maneuver],
    *,
    rate_hz: float,
    n_samples: int = 32,
    seed: int = 0,
    noise: object | None = "default",
) -> Benchmark:
    """Simulate maneuvers in MuJoCo and with the surrogate on the same applied controls; compare them.

    The surrogate is driven by the controls MuJoCo actually applied (for the eight these come from
    heading feedback), and a Markov model starts from the rates logged at the first step.
    """
    noise_cfg = simulator.NoiseConfig() if noise == "default" else noise
    log = simulator.collect(list(maneuvers), rate_hz=rate_hz, seed=seed, noise=noise_cfg)
    truth = [part.reset_index(drop=True) for _, part in log.groupby("run_id", sort=False)]
    controls = [t[list(CONTROLS)].to_numpy() for t in truth]
    initial = np.array([[t[rate].iloc[0] for rate in RATES] for t in truth])
    rollout = simulate(
        model, controls, rate_hz=rate_hz, n_samples=n_samples, seed=seed, initial_rates=initial
    )
    metrics = [
        track_metrics(rollout, i, {c: t[c].to_numpy() for c in TRUTH_COLUMNS})
        for i, t in enumerate(truth)
    ]
    return Benchmark(rollout, truth, metrics)
