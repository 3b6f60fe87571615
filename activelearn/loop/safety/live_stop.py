"""The walls kept at run time (`[safety] stop = "live"`): the car brakes near a wall.

The car brakes (throttle 0) as soon as its measured pose comes within `margin + stop_buffer` of a
wall, so the fan and the worst case judge the limits only and no candidate is cut in advance for
the walls. Simulated oracles drive the stop closed-loop in MuJoCo (`stop_rule`), their logs running
on until the car stands; a recorded pool's log, which cannot be driven again, is cut at the trigger
(`live_stop`); figures end each sampled path where it would brake (`braked_paths`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

import simulator
from activelearn.config import SafetyConfig, polygon_clearance
from activelearn.loop.safety.limits import placed_path


def stop_rule(cfg: SafetyConfig | None, settle: float = 1.0) -> simulator.StopRule | None:
    """The live stop of an enforced `[safety] stop = "live"` as the simulator drives it (None otherwise):
    brake once the pose, placed at the start pose, comes within `margin + stop_buffer` of a wall, the
    log running on at most `settle` seconds (`activelearn.config.safety.settle_seconds`)."""
    if cfg is None or cfg.stop != "live" or not cfg.enforce:
        return None
    return simulator.StopRule(
        polygon=tuple(cfg.arena), start=tuple(cfg.start), distance=cfg.margin + cfg.stop_buffer, settle=settle
    )


def live_stop(log: pd.DataFrame, cfg: SafetyConfig) -> pd.DataFrame:
    """A log that cannot be driven again cut where a live stop would have braked: up to the sample
    before the first whose pose comes within `margin + stop_buffer` of a wall (the braking is not in
    it). A log that never comes that close is returned whole."""
    x, y = placed_path(log, cfg)
    near = polygon_clearance(cfg.arena, x, y) < cfg.margin + cfg.stop_buffer
    if not near.any():
        return log
    return log.iloc[: max(int(np.argmax(near)), 1)].reset_index(drop=True)


def braked_paths(
    x: np.ndarray, y: np.ndarray, cfg: SafetyConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sampled paths (S, T) in the arena frame as a live stop leaves them: each path ends at its first
    point within `margin + stop_buffer` of a wall (the rest is NaN, which figures leave out). Returns
    the cut x, y and the (S,) index of each path's trigger point (-1: never braked)."""
    near = polygon_clearance(cfg.arena, x, y) < cfg.margin + cfg.stop_buffer
    braked = near.any(axis=-1)
    trigger = np.where(braked, np.argmax(near, axis=-1), -1)
    after = np.arange(x.shape[-1])[None, :] > np.where(braked, trigger, x.shape[-1])[:, None]
    return np.where(after, np.nan, x), np.where(after, np.nan, y), trigger
