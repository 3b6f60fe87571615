"""The arena's walls and the car's limits, and what a path or a driven log violated of them.

A step violates when its position lies closer than `margin` (plus a tolerance) to a wall or when
its rates, averaged over `limit_window` seconds (one noisy sample is no violation), exceed |v|,
|ω| or the lateral acceleration |v·ω|. The fans (`risk`) and the logs that came back
(`violations`: what the benchmark counts) are judged by the same rule.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from activelearn.config import SafetyConfig, polygon_clearance
from activelearn.names import POSE, SPEED, YAW_RATE
from simulator.stop import place

REASONS = ("arena", "speed", "yaw_rate", "lateral", "diverged")  # diverged: a fan's NaN or inf


def smooth(values: np.ndarray, steps: int) -> np.ndarray:
    """Trailing moving average over `steps` along the last axis (the first steps average fewer)."""
    if steps <= 1:
        return values
    total = np.cumsum(values, axis=-1, dtype=np.float64)
    total[..., steps:] = total[..., steps:] - total[..., :-steps]
    count = np.minimum(np.arange(1, values.shape[-1] + 1), steps)
    return total / count


def violating(x: np.ndarray, y: np.ndarray, v: np.ndarray, w: np.ndarray, cfg: SafetyConfig,
              rate_hz: float, tolerance: float = 0.0, walls: bool = True) -> np.ndarray:  # fmt: skip
    """(..., T) code of what each step violates: 0 none, else 1 + index in REASONS (first one wins).

    Positions in the arena frame (m), rates sampled at `rate_hz` (m/s, rad/s). A position closer
    than `cfg.margin + tolerance` to a wall violates unless `walls` is False (a live stop keeps them).
    """
    window = max(1, round(cfg.limit_window * rate_hz))
    with np.errstate(invalid="ignore", over="ignore"):  # a diverged trajectory is caught below
        v_avg, w_avg = smooth(v, window), smooth(w, window)
        near_wall = np.zeros(np.shape(x), dtype=bool)
        if walls:
            near_wall = polygon_clearance(cfg.arena, x, y) < cfg.margin + tolerance
        checks = (
            near_wall,
            np.abs(v_avg) > cfg.max_speed,
            np.abs(w_avg) > cfg.max_yaw_rate,
            np.abs(v_avg * w_avg) > cfg.max_lateral_acceleration,
            ~(np.isfinite(x) & np.isfinite(y) & np.isfinite(v_avg) & np.isfinite(w_avg)),
        )
    code = np.zeros(x.shape, dtype=np.int8)
    for i, bad in reversed(list(enumerate(checks))):
        code[bad] = i + 1
    return code


def placed_path(log: pd.DataFrame, cfg: SafetyConfig) -> tuple[np.ndarray, np.ndarray]:
    """The log's path relative to its first pose, placed at the arena's start pose (m).

    A simulator log (starting at the origin) and a car's log (in its own frame) are thus judged
    alike, and where the simulated live stop places them.
    """
    px, py, yaw = (log[c].to_numpy(dtype=np.float64) for c in POSE)
    return place(px, py, (px[0], py[0], yaw[0]), cfg.start)


def log_violation(log: pd.DataFrame, cfg: SafetyConfig, rate_hz: float) -> str:
    """What a driven maneuver's log violated first ("" if nothing): arena, speed, yaw_rate or lateral."""
    x, y = placed_path(log, cfg)
    code = violating(x, y, log[SPEED].to_numpy(np.float64), log[YAW_RATE].to_numpy(np.float64), cfg, rate_hz)
    bad = np.flatnonzero(code)
    return REASONS[int(code[bad[0]]) - 1] if len(bad) else ""


def violations(logs: pd.DataFrame, cfg: SafetyConfig, rate_hz: float) -> dict[int, str]:
    """Per pool index in `logs` (rows tagged with `pool_index`): what its maneuver violated ("" none)."""
    return {
        int(index): log_violation(part.reset_index(drop=True), cfg, rate_hz)
        for index, part in logs.groupby("pool_index", sort=False)
    }
