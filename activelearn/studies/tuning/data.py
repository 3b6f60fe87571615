"""The tuning dataset: rows from the config's pool (simulated once, cached) or from files, split by
whole operating points so validation never sees a near copy of a training row."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from activelearn.config import CampaignConfig
from activelearn.data import read_autodrive_log, read_table, write_table
from activelearn.errors import DataFormatError, InputError
from activelearn.loop.collection import (
    FEATURES,
    TARGETS,
    arrays,
    cache_root,
    car_cache,
    control_rate_logs,
    noisy_logs,
    simulator_fingerprint,
    training_rows,
)
from activelearn.loop.pool import pool_maneuvers
from activelearn.names import RECORDED_COLUMNS, STEERING, THROTTLE

_DATA_VERSION = 1  # bump when the way a dataset is assembled changes (invalidates cached tables)

Progress = Callable[[dict[str, Any]], None]


@dataclass(frozen=True)
class TuningData:
    """Samples of a study: inputs, targets and the operating point (group) of every row."""

    x: np.ndarray
    y: np.ndarray
    groups: np.ndarray  # operating-point key per row (str)
    key: str  # content hash: a study only continues on the same data
    source: str  # where the rows came from, for humans
    # Every maneuver's whole log (controls and rates at the log rate) and its operating point: what a
    # physics-structured model identifies itself on (free runs of whole logs, not the strided rows).
    logs: tuple[tuple[str, np.ndarray, np.ndarray], ...] = ()

    @property
    def n_groups(self) -> int:
        """Number of distinct operating points."""
        return len(np.unique(self.groups))


@dataclass(frozen=True)
class Split:
    """Training and validation rows; no operating point appears on both sides."""

    x_train: np.ndarray
    y_train: np.ndarray
    groups_train: np.ndarray  # integer group ids
    x_val: np.ndarray
    y_val: np.ndarray
    groups_val: np.ndarray
    val_points: tuple[str, ...]  # the held-out operating points
    # The training side's whole logs, flattened for the workers' file: (throttle, steering, v, ω)
    # steps, log i being log_steps[log_starts[i]:log_starts[i + 1]].
    log_steps: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4)))
    log_starts: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(1, dtype=np.int64))

    def training_logs(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The training side's logs as (controls (T, 2), rates (T, 2)) per maneuver."""
        bounds = zip(self.log_starts[:-1], self.log_starts[1:], strict=True)
        return [(self.log_steps[a:b, :2], self.log_steps[a:b, 2:]) for a, b in bounds]

    def describe(self) -> dict[str, int]:
        """Row and operating-point counts of both sides."""
        return {
            "train_rows": len(self.x_train),
            "val_rows": len(self.x_val),
            "train_points": len(np.unique(self.groups_train)),
            "val_points": len(self.val_points),
        }


def operating_points(rows: pd.DataFrame) -> np.ndarray:
    """Operating-point key of every row: maneuver kind, direction, throttle and steering amplitude.

    Logs without a known direction (AutoDRIVE imports) take it from the sign of their median steering,
    so cw and ccw runs at the same amplitude stay distinct points.
    """
    direction = rows["direction"].astype(str).to_numpy(copy=True)
    unknown = ~np.isin(direction, ("ccw", "cw"))
    if unknown.any():
        sign = rows.groupby("run_id")["steering"].transform("median").to_numpy()
        direction[unknown] = np.where(sign[unknown] < 0, "cw", "ccw")
    parts = [
        rows["maneuver"].astype(str).to_numpy(),
        direction,
        np.char.mod("%.4f", rows["op_throttle"].to_numpy(dtype=float)),
        np.char.mod("%.4f", rows["op_steering"].to_numpy(dtype=float)),
    ]
    return np.array(["|".join(p) for p in zip(*parts, strict=True)], dtype=object)


def group_split(groups: np.ndarray, val_fraction: float, seed: int) -> np.ndarray:
    """Boolean mask of validation rows: a seeded share of whole groups (never single rows)."""
    names = np.unique(groups)
    if len(names) < 2:
        raise InputError("data", len(names), "needs at least 2 operating points to hold one out")
    n_val = min(max(1, round(val_fraction * len(names))), len(names) - 1)
    held = np.random.default_rng(seed).permutation(len(names))[:n_val]
    return np.isin(groups, names[held])


def split_data(data: TuningData, val_fraction: float, seed: int) -> Split:
    """Hold out whole operating points for validation (seeded)."""
    is_val = group_split(data.groups, val_fraction, seed)
    _, codes = np.unique(data.groups, return_inverse=True)
    held_out = set(np.unique(data.groups[is_val]))
    kept = [np.column_stack([u, y]) for point, u, y in data.logs if point not in held_out]
    starts = np.cumsum([0] + [len(steps) for steps in kept]).astype(np.int64)
    return Split(
        log_steps=np.concatenate(kept) if kept else np.zeros((0, 4)),
        log_starts=starts,
        x_train=data.x[~is_val],
        y_train=data.y[~is_val],
        groups_train=codes[~is_val],
        x_val=data.x[is_val],
        y_val=data.y[is_val],
        groups_val=codes[is_val],
        val_points=tuple(sorted(np.unique(data.groups[is_val]))),
    )


def content_hash(payload: Any) -> str:
    """Short, stable hash of a JSON-able payload (dataset and study signatures)."""
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _assemble(
    rows: pd.DataFrame, cfg: CampaignConfig, key: str, source: str, logs: pd.DataFrame
) -> TuningData:
    x, y = arrays(rows, cfg.data)
    runs = [run for _, run in logs.groupby("run_id", sort=False)]
    whole = tuple(
        (str(run["point"].iloc[0]), u, y_)
        for run, (u, y_) in zip(runs, control_rate_logs(runs), strict=True)
    )
    return TuningData(
        x=x, y=y, groups=rows["point"].to_numpy(dtype=object), key=key, source=source, logs=whole
    )


def _log_table(frames: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """The maneuvers' whole logs, (controls, rates) at the log rate with their run and operating point."""
    table = pd.concat([frame.assign(point=operating_points(frame)) for frame in frames], ignore_index=True)
    return table[["run_id", "point", *FEATURES, *TARGETS]]


def dataset_key(cfg: CampaignConfig) -> str:
    """Hash of everything that determines the data collected from a config's pool."""
    return content_hash(
        {
            "version": _DATA_VERSION,
            "simulator": simulator_fingerprint(cfg.vehicle.spec),
            "seed": cfg.seed,
            "pool": cfg.pool.model_dump(mode="json"),
            "simulation": cfg.simulation.model_dump(mode="json"),
            "data": cfg.data.model_dump(mode="json"),
        }
    )


def collect_dataset(
    cfg: CampaignConfig, cache_dir: str | Path | None = None, progress: Progress | None = None
) -> TuningData:
    """All of the config's pool maneuvers, simulated with its noise and seed, as training rows.

    Cached as Parquet under `cache_root(cfg)` (`<output_dir>/cache`) keyed by `dataset_key`; the
    noise-free logs go through the same `SimulationCache` as campaigns, so tuning and campaigns simulate
    each maneuver once.
    """
    root = Path(cache_dir) if cache_dir is not None else cache_root(cfg)
    key = dataset_key(cfg)
    path, log_path = root / f"tuning-data-{key}.parquet", root / f"tuning-logs-{key}.parquet"
    if path.exists() and log_path.exists():
        return _assemble(read_table(path), cfg, key, str(path), read_table(log_path))
    maneuvers = pool_maneuvers(cfg.pool)

    def sim_progress(done: int, total: int) -> None:
        if progress is not None:
            progress({"event": "sim_progress", "done": done, "total": total})

    clean = car_cache(root, cfg).get(maneuvers, progress=sim_progress)
    frames = noisy_logs(clean, maneuvers, cfg.simulation.noise, cfg.seed)
    rows = pd.concat([training_rows(f, cfg.data) for f in frames], ignore_index=True)
    rows["point"] = operating_points(rows)
    logs = _log_table(frames)
    write_table(logs, log_path)  # the rows' table last: where it exists, so do the logs
    write_table(rows, path)
    return _assemble(rows, cfg, key, str(path), logs)




def load_dataset(paths: Sequence[str | Path], cfg: CampaignConfig) -> TuningData:
    """Rows from sample tables (.parquet, or .csv as written by `simulate`) or AutoDRIVE CSV logs."""
    if not paths:
        raise InputError("--data", [], "give at least one file")
    parts, runs, digest = [], [], hashlib.sha256()
    for index, raw in enumerate(paths):
        path = Path(raw)
        if not path.is_file():
            raise InputError("--data", str(path), "no such file")
        suffix = path.suffix.lower()
        if suffix == ".parquet":
            table = read_table(path)
        elif suffix == ".csv":
            table = read_autodrive_log(path)
        else:
            raise InputError("--data", str(path), "must be a .parquet table or a .csv log")
        missing = [c for c in RECORDED_COLUMNS if c not in table.columns]
        if missing:
            raise DataFormatError(f"{path}: lacks column(s) {', '.join(missing)}")
        table = table.copy()
        for column, default in (("maneuver", "unknown"), ("direction", "unknown"), ("run_id", path.stem)):
            if column not in table.columns:
                table[column] = default
        for column, values in (("op_throttle", table[THROTTLE]), ("op_steering", table[STEERING].abs())):
            if column not in table.columns:
                table[column] = table.groupby("run_id")[values.name].transform("median")
        table["run_id"] = f"{index}:" + table["run_id"].astype(str)
        for _, run in table.groupby("run_id", sort=False):
            parts.append(training_rows(run, cfg.data))
            runs.append(run)
        digest.update(path.read_bytes())
    rows = pd.concat(parts, ignore_index=True)
    if rows.empty:
        raise InputError("--data", [str(p) for p in paths], "no rows left after data.skip_seconds/stride")
    rows["point"] = operating_points(rows)
    key = content_hash(
        {"version": _DATA_VERSION, "files": digest.hexdigest(), "data": cfg.data.model_dump(mode="json")}
    )
    return _assemble(rows, cfg, key, ", ".join(str(p) for p in paths), _log_table(runs))
