"""Warm starts: the rows and maneuvers a campaign already holds before it spends its budget.

A prior comes from a maneuver grid (simulated once by the nominal simulator and cached, with fixed
noise, so a config stays self-contained), earlier campaign directories, sample tables in the sample
schema (.parquet/.csv) or AutoDRIVE logs (.csv), in any mix. Every source is checked against the
config before anything is written: the columns the model needs, the log rate, and physical units
(throttle within [-1, 1], steering in rad within the steering limit, speeds and yaw rates a 1:14 car
can reach), so a prior in degrees or km/h is one clear error instead of a silently bad model.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from activelearn.config import CampaignConfig, PriorConfig
from activelearn.data import read_autodrive_log, read_table
from activelearn.errors import InputError
from activelearn.loop.collection import SimulationCache, noisy_logs
from activelearn.loop.pool import KIND_ORDER, grid_maneuvers
from activelearn.loop.state import SAMPLES_FILE, CampaignState
from activelearn.names import RECORDED_COLUMNS, SPEED, STEERING, THROTTLE, YAW_RATE
from simulator.vehicles import VehicleSpec

PRIOR_FILE = "prior.parquet"  # the prior rows a campaign directory keeps (resume never re-reads sources)
# Where prior runs sit in a sample table: pool_index = -1 - run number, batch = -1.
PRIOR_BATCH = -1
# Plausibility bounds in SI units: a prior beyond this many times the car's own limits is in other units
# or of another car.
_PLAUSIBLE = 10.0


@dataclass(frozen=True)
class PriorRun:
    """One maneuver of the prior: its kind ("unknown" if not recorded) and operating point."""

    kind: str
    throttle: float
    steering: float  # unsigned amplitude
    direction: str
    rows: int

    @property
    def sign(self) -> int:
        """Steering sign of the direction: +1 for ccw (left), -1 for cw."""
        return -1 if self.direction == "cw" else 1


@dataclass(frozen=True)
class Prior:
    """The prior's raw log rows (one `pool_index` < 0 per run), its runs and a content digest."""

    rows: pd.DataFrame
    runs: tuple[PriorRun, ...]
    use: str
    digest: str

    @property
    def trains(self) -> bool:
        """Whether the prior rows join the training data of every round (use = "data"; a prior of another
        car's model alone has none)."""
        return self.use == "data" and not self.rows.empty


def _sources(cfg: PriorConfig) -> list[tuple[str, Path]]:
    """(field, file or campaign directory) for every path of the prior, folders expanded."""
    found: list[tuple[str, Path]] = []
    for i, text in enumerate(cfg.paths):
        field = f"design.prior.paths[{i}]"
        path = Path(text)
        if path.is_dir() and (path / "state.json").is_file():
            found.append((field, path))
        elif path.is_dir():
            files = sorted(p for p in path.rglob("*") if p.suffix.lower() in (".csv", ".parquet"))
            if not files:
                raise InputError(field, text, "the folder holds no .csv or .parquet file")
            found.extend((field, f) for f in files)
        elif path.is_file():
            if path.suffix.lower() not in (".csv", ".parquet"):
                raise InputError(field, text, "a prior file must be .csv or .parquet")
            found.append((field, path))
        else:
            raise InputError(field, text, "no such file or directory")
    return found


def _read_source(field: str, path: Path) -> list[pd.DataFrame]:
    """The runs (one frame per run_id) of a campaign directory, a sample table or an AutoDRIVE log."""
    if path.is_dir():  # an earlier campaign: its committed batches and its own prior
        state = CampaignState.load(path)
        frames = [read_table(path / SAMPLES_FILE)] if (path / SAMPLES_FILE).exists() else []
        frames = [f[f["batch"] < len(state.batches)] for f in frames]
        if (path / PRIOR_FILE).exists():
            frames.append(read_table(path / PRIOR_FILE))
        table = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
        key = "pool_index" if "pool_index" in table else "run_id"
    elif path.suffix.lower() == ".parquet":
        table, key = read_table(path), "run_id"
    else:  # .csv: a sample table (with header) or a headerless AutoDRIVE log
        table, key = read_autodrive_log(path), "run_id"
    if table.empty:
        raise InputError(field, str(path), "holds no samples")
    missing = [c for c in RECORDED_COLUMNS if c not in table]
    if missing:
        raise InputError(field, str(path), f"lacks the column(s) {', '.join(missing)} the model needs")
    if key not in table:
        table = table.assign(run_id=path.stem)
        key = "run_id"
    return [part.reset_index(drop=True) for _, part in table.groupby(key, sort=False)]


def _check_run(field: str, path: Path, frame: pd.DataFrame, rate_hz: float, spec: VehicleSpec) -> None:
    """Reject runs that cannot be this config's data: NaNs, another log rate, other units."""
    values = frame[list(RECORDED_COLUMNS)].to_numpy(dtype=np.float64)
    if not np.isfinite(values).all():
        raise InputError(field, str(path), "has missing or non-finite values in time/controls/rates")
    if len(frame) < 3:
        raise InputError(field, str(path), f"a run of {len(frame)} rows is too short to train on")
    step = float(np.median(np.diff(frame["time"].to_numpy())))
    if not abs(step * rate_hz - 1.0) < 0.1:
        raise InputError(
            field,
            str(path),
            f"is logged at {1 / step:.3g} Hz, the config at {rate_hz:g} Hz (simulation.rate_hz)",
        )
    lock = spec.steering.limit.value
    top, turn = _PLAUSIBLE * spec.max_speed, _PLAUSIBLE * spec.max_yaw_rate
    checks = (
        (THROTTLE, 1.0 + 1e-6, "throttle must lie in [-1, 1]"),
        (STEERING, lock + 1e-3, f"steering must be in rad within ±{lock} (degrees?)"),
        (SPEED, top, f"speed beyond {top:.3g} m/s: not m/s, or not this car ([vehicle] {spec.name})"),
        (YAW_RATE, turn, f"yaw rate beyond {turn:.3g} rad/s: not rad/s (deg/s?)"),
    )
    for column, bound, reason in checks:
        worst = float(np.abs(frame[column]).max())
        if worst > bound:
            raise InputError(field, str(path), f"{reason} (largest |{column}| = {worst:.4g})")


def _run_of(frame: pd.DataFrame) -> PriorRun:
    """Kind and operating point of one prior run, from its recorded columns."""
    kind = str(frame["maneuver"].iloc[0]) if "maneuver" in frame else "unknown"
    kind = kind if kind in KIND_ORDER else "unknown"
    steering = frame[STEERING].to_numpy(dtype=np.float64)
    throttle = (
        float(frame["op_throttle"].iloc[0]) if "op_throttle" in frame else float(np.median(frame[THROTTLE]))
    )
    amplitude = (
        float(frame["op_steering"].iloc[0]) if "op_steering" in frame else float(np.max(np.abs(steering)))
    )
    direction = str(frame["direction"].iloc[0]) if "direction" in frame else "unknown"
    if direction not in ("ccw", "cw"):
        direction = "cw" if steering.mean() < 0 else "ccw"
    return PriorRun(kind, throttle, amplitude, direction, len(frame))


def load_prior(cfg: CampaignConfig, nominal: SimulationCache) -> Prior | None:
    """Read, check and label the prior of `cfg` (None without one); `nominal` simulates a prior grid."""
    prior = cfg.design.prior
    if prior is None:
        return None
    frames: list[pd.DataFrame] = []
    if prior.grid is not None:
        g = prior.grid
        lock = cfg.vehicle.spec.steering.limit.value
        maneuvers = grid_maneuvers(g.kinds, g.directions, g.throttles, g.steerings, g.duration, lock)
        if not maneuvers:
            raise InputError(
                "design.prior.grid", g.throttles, "the grid holds no maneuver (throttle 0 only?)"
            )
        frames.extend(noisy_logs(nominal.get(maneuvers), maneuvers, cfg.simulation.noise, g.noise_seed))
    for field, path in _sources(prior):
        for frame in _read_source(field, path):
            _check_run(field, path, frame, cfg.simulation.rate_hz, cfg.vehicle.spec)
            frames.append(frame)
    if prior.use == "data" and not frames and prior.paths:  # without sources: another car's model alone
        raise InputError("design.prior", prior.paths, "holds no rows")
    labelled = []
    for i, frame in enumerate(frames):
        frame = frame.drop(columns=[c for c in ("pool_index", "batch") if c in frame]).copy()
        frame["pool_index"] = -1 - i
        frame["batch"] = PRIOR_BATCH
        labelled.append(frame)
    rows = pd.concat(labelled, ignore_index=True) if labelled else pd.DataFrame()
    return prior_from_rows(rows, prior.use)


def prior_from_rows(rows: pd.DataFrame, use: str) -> Prior:
    """The prior of labelled rows (`pool_index` < 0 per run); a campaign directory stores them."""
    runs = tuple(_run_of(part) for _, part in rows.groupby("pool_index", sort=False)) if len(rows) else ()
    digest = hashlib.sha256(pd.util.hash_pandas_object(rows, index=False).to_numpy().tobytes())
    return Prior(rows, runs, use, digest.hexdigest()[:16])
