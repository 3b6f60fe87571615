"""Turning maneuvers into training and test samples: simulation cache, seeded noise, row selection.

MuJoCo is deterministic, so the noise-free log of a maneuver depends only on the maneuver, the log
rate and the vehicle model. Each one is simulated once and kept in a cache (one Parquet file per
maneuver, written atomically); sensor noise is then drawn per (campaign seed, maneuver). Strategies
that pick the same maneuver therefore see the same data (common random numbers), and a comparison
pays for each simulation once.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import simulator
from activelearn.config import CampaignConfig, DataConfig, NoiseSettings, SimulationConfig
from activelearn.config.vehicle import DEFAULT_VEHICLE
from activelearn.data import read_table, write_table
from activelearn.loop.history import CandidateTruth
from activelearn.names import CONTROLS, PREVIOUS_RATES, RATES, SPEED, YAW_RATE
from activelearn.numerics.lags import Lags
from activelearn.numerics.multistep import Windows, windows_from_logs
from activelearn.seeds import Stream, derived_seed
from simulator import Maneuver
from simulator.vehicles import VehicleSpec, load_vehicle

FEATURES: tuple[str, ...] = CONTROLS  # a static model's inputs
TARGETS: tuple[str, ...] = RATES  # every model's outputs
RATE_FEATURES: tuple[str, ...] = PREVIOUS_RATES  # a Markov model's extra inputs

Progress = Callable[[int, int], None]

CACHE_ENV = "ACTIVELEARN_CACHE_DIR"


def cache_root(cfg: CampaignConfig) -> Path:
    """Where simulated logs (and tuning's datasets) are cached: `<output_dir>/cache`, or the folder
    `$ACTIVELEARN_CACHE_DIR` names, so that many output directories share one cache (a cluster's shared
    disk, the test suite's campaigns). Entries are keyed by the simulator, so sharing is always safe."""
    shared = os.environ.get(CACHE_ENV)
    return Path(shared) if shared else Path(cfg.output_dir) / "cache"


def simulator_fingerprint(spec: VehicleSpec | str = DEFAULT_VEHICLE) -> str:
    """Short hash of the car's truth model and the simulator's version: cache entries depend on both."""
    digest = hashlib.sha256(simulator.truth_text(spec).encode())
    digest.update(getattr(simulator, "__version__", "0").encode())
    return digest.hexdigest()[:12]


class SimulationCache:
    """Noise-free maneuver logs, simulated on demand and kept as one Parquet file per maneuver.

    `vehicle` swaps in an edited model (a twin); `variant` names it in the cache path, so the logs of
    different vehicles never mix. `stop` (a `simulator.StopRule`: a live stop at the walls, driven
    closed-loop) simulates every maneuver under it, in a folder of its own named by the rule's digest,
    so a stopped and an unstopped log of one maneuver never share an entry (`stopped`).
    """

    def __init__(
        self, root: str | Path, settings: SimulationConfig, *, vehicle: Any = None, variant: str = "",
        stop: simulator.StopRule | None = None,
    ) -> None:  # fmt: skip
        self.settings = settings
        self.vehicle = vehicle
        self.variant = variant
        self.stop = stop
        self.base = Path(root)
        suffix = f"-{variant}" if variant else ""
        if stop is not None:
            suffix += f"-stop-{stop.key()}"
        spec = vehicle.spec if vehicle is not None else DEFAULT_VEHICLE
        self.root = self.base / f"sim-{simulator_fingerprint(spec)}{suffix}-{settings.rate_hz:g}hz"

    def stopped(self, stop: simulator.StopRule | None) -> SimulationCache:
        """The same simulator's cache with every maneuver driven under `stop` (None: without a stop)."""
        return SimulationCache(
            self.base, self.settings, vehicle=self.vehicle, variant=self.variant, stop=stop
        )

    def path(self, maneuver: Maneuver) -> Path:
        """Cache file of one maneuver."""
        return self.root / f"{maneuver.name}.parquet"

    def missing(self, maneuvers: Sequence[Maneuver]) -> list[Maneuver]:
        """Maneuvers not in the cache yet."""
        return [m for m in maneuvers if not self.path(m).exists()]

    def get(self, maneuvers: Sequence[Maneuver], progress: Progress | None = None) -> list[pd.DataFrame]:
        """Noise-free logs of `maneuvers`, simulating the missing ones in one parallel batch."""
        todo = self.missing(maneuvers)
        if todo:
            frame = simulator.collect(
                todo,
                rate_hz=self.settings.rate_hz,
                seed=0,
                noise=None,
                threads=self.settings.threads,
                progress=progress,
                vehicle=self.vehicle,
                stop=self.stop,
            )
            self.root.mkdir(parents=True, exist_ok=True)
            for m, (_, part) in zip(todo, frame.groupby("run_id", sort=False), strict=True):
                write_table(part.reset_index(drop=True), self.path(m))
        return [read_table(self.path(m)) for m in maneuvers]


def twin_variant(overrides: dict[str, float]) -> str:
    """Short stable name of a twin's overrides (a digest of the sorted name=value pairs)."""
    text = ";".join(f"{k}={float(v)!r}" for k, v in sorted(overrides.items()))
    return "twin-" + hashlib.sha256(text.encode()).hexdigest()[:10]


def car_cache(
    root: str | Path, cfg: CampaignConfig, overrides: dict[str, float] | None = None
) -> SimulationCache:
    """The simulation cache of the config's car ([vehicle]), a twin of it with `overrides`.

    The default car's nominal model is the simulator's own default (the cache's original folder); any
    other car, or a twin, is built from its vehicle file and named in the folder (`variant`)."""
    spec = cfg.vehicle.spec
    overrides = dict(overrides or {})
    if not overrides and spec.name == DEFAULT_VEHICLE and spec.path == load_vehicle(DEFAULT_VEHICLE).path:
        return SimulationCache(root, cfg.simulation)
    parts = [] if spec.name == DEFAULT_VEHICLE else [spec.name]
    if overrides:
        parts.append(twin_variant(overrides))
    vehicle = simulator.build_vehicle(spec, overrides)
    return SimulationCache(root, cfg.simulation, vehicle=vehicle, variant="-".join(parts))


def twin_cache(root: str | Path, cfg: CampaignConfig) -> SimulationCache:
    """The simulation cache of a config's twin oracle: its own vehicle, its own folder under `root`."""
    return car_cache(root, cfg, dict(cfg.oracle.overrides))


def noise_seed(seed: int, maneuver: Maneuver) -> int:
    """Noise seed of one maneuver in one campaign: independent of when or by whom it is collected."""
    return derived_seed(seed, Stream.NOISE, maneuver.name)


def noise_config(settings: NoiseSettings) -> simulator.NoiseConfig | None:
    """The simulator's noise model for the config's noise section (None when disabled)."""
    if not settings.enabled:
        return None
    overrides = {k: v for k, v in settings.model_dump().items() if k != "enabled" and v is not None}
    return simulator.NoiseConfig(**overrides)


def noisy_logs(
    clean: Sequence[pd.DataFrame], maneuvers: Sequence[Maneuver], settings: NoiseSettings, seed: int
) -> list[pd.DataFrame]:
    """Add seeded sensor noise to noise-free logs, one independent stream per maneuver."""
    noise = noise_config(settings)
    if noise is None:
        return [frame.copy() for frame in clean]
    return [simulator.add_noise(f, noise, noise_seed(seed, m)) for f, m in zip(clean, maneuvers, strict=True)]


def data_lags(cfg: DataConfig) -> Lags | None:
    """The input layout of a history config (`activelearn.numerics.lags`), None otherwise."""
    return Lags(cfg.history, cfg.history_step) if cfg.inputs == "history" else None


def training_windows(frames: Sequence[pd.DataFrame], cfg: DataConfig, horizon: int) -> Windows | None:
    """Free-running windows of `horizon` log steps for multi-step training, one every `stride` steps.

    None for a static map (nothing is fed back) or horizon 0. Windows start anywhere in a log,
    transients included: that is where a dynamic model's feedback matters most.
    """
    lags = data_lags(cfg) or (Lags(1, 1) if cfg.inputs == "controls+rates" else None)
    if lags is None or horizon == 0:
        return None
    return windows_from_logs(control_rate_logs(frames), lags, horizon, every=cfg.stride)


def control_rate_logs(frames: Sequence[pd.DataFrame]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each log as (controls (T, 2), rates (T, 2)): what multi-step windows and identification read."""
    return [(f[list(FEATURES)].to_numpy(np.float64), f[list(TARGETS)].to_numpy(np.float64)) for f in frames]


def training_rows(frame: pd.DataFrame, cfg: DataConfig) -> pd.DataFrame:
    """The rows of one maneuver's log that become samples: after the transient, every stride-th row.

    Adds `prev_speed` and `prev_angZ`, the rates one log step earlier, for the Markov-state model, and
    for a history config the lagged controls and rates it reads (rows without a full history dropped).
    """
    frame = frame.reset_index(drop=True).copy()
    frame[PREVIOUS_RATES[0]] = frame[SPEED].shift(1)
    frame[PREVIOUS_RATES[1]] = frame[YAW_RATE].shift(1)
    lags = data_lags(cfg)
    first = 1
    if lags is not None:
        lagged = {name: frame[source].shift(back) for name, source, back in lags.inputs() if back}
        frame = pd.concat([frame, pd.DataFrame(lagged, index=frame.index)], axis=1)
        first = lags.span
    keep = frame.iloc[first:]
    keep = keep[keep["time"] >= cfg.skip_seconds - 1e-9]
    return keep.iloc[:: cfg.stride]


def feature_columns(cfg: DataConfig) -> list[str]:
    """Model input columns for the config's input choice."""
    lags = data_lags(cfg)
    if lags is not None:
        return lags.columns()
    return list(FEATURES) + (list(RATE_FEATURES) if cfg.inputs == "controls+rates" else [])


def arrays(rows: pd.DataFrame, cfg: DataConfig) -> tuple[np.ndarray, np.ndarray]:
    """Inputs and targets of sample rows as float arrays."""
    # copy=True: a frame read from parquet can hand out read-only views, which torch warns about sharing
    x = rows[feature_columns(cfg)].to_numpy(dtype=np.float64, copy=True)
    y = rows[list(TARGETS)].to_numpy(dtype=np.float64, copy=True)
    return x, y


def truth_rows(frames: Sequence[pd.DataFrame], cfg: DataConfig) -> CandidateTruth:
    """Noise-free training rows of every candidate, stacked, and the candidate each row belongs to
    (`History.truth`: what only a simulated oracle knows)."""
    xs, ys, owner = [], [], []
    for i, frame in enumerate(frames):
        x, y = arrays(training_rows(frame, cfg), cfg)
        xs.append(x)
        ys.append(y)
        owner.append(np.full(len(x), i))
    return CandidateTruth(np.concatenate(xs), np.concatenate(ys), np.concatenate(owner))


def rows_per_maneuver(duration: float, settings: SimulationConfig, cfg: DataConfig) -> float:
    """Approximate number of training rows one maneuver of `duration` seconds contributes."""
    return max(1.0, (duration - cfg.skip_seconds) * settings.rate_hz / cfg.stride)


@dataclass(frozen=True)
class TestSet:
    """The fixed test set: inputs, noise-free and noisy targets, and the per-output scale."""

    __test__ = False  # not a pytest class

    x: np.ndarray
    y_clean: np.ndarray
    y_noisy: np.ndarray
    scale: np.ndarray
    groups: np.ndarray
    # Whole logs of the test maneuvers for free-running rollouts: as recorded (controls and the
    # initial state come from these) and the truth the paths are judged against (noise-free where
    # the oracle simulates, else the recording itself).
    logs: tuple[pd.DataFrame, ...] = ()
    truth_logs: tuple[pd.DataFrame, ...] = ()


def test_set_from_logs(tables: Sequence[pd.DataFrame], data: DataConfig) -> TestSet:
    """A test set of recorded logs: their measured rates are the only truth there is (noise included)."""
    xs, ys, groups = [], [], []
    for i, table in enumerate(tables):
        rows = training_rows(table, data)
        x, y = arrays(rows, data)
        xs.append(x)
        ys.append(y)
        groups.append(np.full(len(x), i))
    y_all = np.concatenate(ys)
    scale = y_all.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    logs = tuple(t.reset_index(drop=True) for t in tables)
    return TestSet(np.concatenate(xs), y_all, y_all, scale, np.concatenate(groups), logs, logs)


test_set_from_logs.__test__ = False  # type: ignore[attr-defined]  # not a pytest test


def build_test_set(
    maneuvers: Sequence[Maneuver],
    cache: SimulationCache,
    noise: NoiseSettings,
    data: DataConfig,
    noise_seed_base: int,
    progress: Progress | None = None,
) -> TestSet:
    """Simulate (or load) the test maneuvers and assemble the fixed, seed-independent test set."""
    clean = cache.get(maneuvers, progress=progress)
    noisy = noisy_logs(clean, maneuvers, noise, noise_seed_base)
    xs, clean_y, noisy_y, groups = [], [], [], []
    for i, (c, n) in enumerate(zip(clean, noisy, strict=True)):
        rows_c, rows_n = training_rows(c, data), training_rows(n, data)
        x, y = arrays(rows_n, data)  # controls carry no noise; previous rates are measured, so they do
        xs.append(x)
        noisy_y.append(y)
        clean_y.append(rows_c[list(TARGETS)].to_numpy(dtype=np.float64))
        groups.append(np.full(len(x), i))
    y_clean = np.concatenate(clean_y)
    scale = y_clean.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    return TestSet(
        np.concatenate(xs),
        y_clean,
        np.concatenate(noisy_y),
        scale,
        np.concatenate(groups),
        tuple(n.reset_index(drop=True) for n in noisy),
        tuple(c.reset_index(drop=True) for c in clean),
    )
