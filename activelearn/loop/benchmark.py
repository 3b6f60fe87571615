"""The surrogate beside MuJoCo: the same maneuvers simulated by both, on the controls MuJoCo applied;
and the surrogate beside a recorded log: the log's commands replayed free through it (`against_log`).

A floor above the numerics because it runs the simulator (`activelearn predict` and the benchmarks
use it); the numerics themselves never run MuJoCo.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

import simulator
from activelearn.names import CONTROLS, RATES, TRUTH_COLUMNS
from activelearn.numerics.diagnostics import Excursion, TrackMetrics, fan_excursions, free_runs, track_metrics
from activelearn.numerics.surrogate import Rollout, simulate
from activelearn.replay import on_grid
from simulator import Maneuver

MIN_EXCURSION = 0.5  # s: shorter stretches outside a 95 % fan are mostly the misses it has by design


@dataclass(frozen=True)
class Benchmark:
    """A surrogate rollout beside the MuJoCo log of the same maneuvers, with per-maneuver metrics."""

    rollout: Rollout
    truth: list  # one pandas DataFrame per maneuver (MuJoCo log, AutoDRIVE layout; or a log on the grid)
    metrics: list[TrackMetrics]
    excursions: tuple[Excursion, ...] = ()  # against_log: where the log leaves the 95 % fans


def against_simulator(
    model,
    maneuvers: Sequence[Maneuver],
    *,
    rate_hz: float,
    n_samples: int = 32,
    seed: int = 0,
    noise: object | None = "default",
    vehicle: object | None = None,
) -> Benchmark:
    """Simulate maneuvers in MuJoCo and with the surrogate on the same applied controls; compare them.

    The surrogate is driven by the controls MuJoCo actually applied (for the eight these come from
    heading feedback), and a Markov model starts from the rates logged at the first step. `vehicle`: a
    built car (`simulator.build_vehicle`; None: the default car).
    """
    noise_cfg = simulator.NoiseConfig() if noise == "default" else noise
    log = simulator.collect(list(maneuvers), rate_hz=rate_hz, seed=seed, noise=noise_cfg, vehicle=vehicle)
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


def against_log(
    model,
    table: pd.DataFrame,
    name: str,
    *,
    rate_hz: float,
    n_samples: int = 32,
    seed: int = 0,
    min_seconds: float = MIN_EXCURSION,
    noise: object | None = "default",
) -> Benchmark:
    """Replay a recorded log's commands free through the surrogate and compare it with the log.

    The log goes on the model's grid (`activelearn.replay.on_grid`: commands held between samples,
    states interpolated; a gap refused, naming `name`); the free run starts from its first recorded
    rates, and its pose in the log's start frame (`free_runs`). Besides the metrics, the stretches of
    at least `min_seconds` where the log leaves a 95 % fan (position, speed, yaw rate). `noise` is the
    log's sensor noise (default: the simulator's, modelled on AutoDRIVE's), allowed for in the
    position fan (`inside_fans`); None takes the log as the truth.
    """
    noise_cfg = simulator.NoiseConfig() if noise == "default" else noise
    truth = on_grid(table, rate_hz, name)
    rollout = free_runs(model, [truth], rate_hz=rate_hz, n_samples=n_samples, seed=seed)
    columns = {c: truth[c].to_numpy() for c in TRUTH_COLUMNS}
    metrics = track_metrics(rollout, 0, columns, noise=noise_cfg)
    outside = fan_excursions(rollout, 0, columns, min_seconds, noise=noise_cfg)
    return Benchmark(rollout, [truth], [metrics], tuple(outside))
