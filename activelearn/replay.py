"""A recorded log on a fixed-rate grid: what replaying it (in the simulator or a surrogate) drives and meets.

The simulator and the surrogates step at a fixed rate (30 Hz); AutoDRIVE logs are nominally 30 Hz
with jitter, and their millisecond timestamps, read as seconds since 1970, carry float errors of
~1e-6 s. So a log is put on the grid k / rate from its first sample: each logged command applies
from the grid step nearest its time until the next command takes over (held between samples), and
each recorded state (speed, yaw rate, pose; heading unwrapped) is interpolated linearly at the grid
times. A log at another rate is resampled the same way. A gap longer than `MAX_GAP` seconds between
two samples is refused, naming the file: the commands the car got in it are unknown.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from activelearn.errors import DataFormatError
from activelearn.names import CONTROLS, POS_X, POS_Y, RATES, TIME, TRUTH_COLUMNS, YAW

MAX_GAP = 0.25  # s between two samples of a replayed log (7.5 steps at 30 Hz)


def grid_times(time: np.ndarray, rate_hz: float) -> np.ndarray:
    """The grid k / rate_hz from a log's first sample to the step nearest its last."""
    time = np.asarray(time, dtype=np.float64)
    steps = int(np.floor((time[-1] - time[0]) * rate_hz + 0.5)) + 1
    return np.arange(steps) / rate_hz + time[0]


def held_index(time: np.ndarray, rate_hz: float) -> np.ndarray:
    """Per grid step: the index of the logged sample whose command the car holds there.

    A sample applies from the grid step nearest its time (ties to the later step), so neither jitter
    nor the timestamps' float error shifts a command by a whole step.
    """
    time = np.asarray(time, dtype=np.float64)
    grid = grid_times(time, rate_hz)
    return np.searchsorted(time, grid + 0.5 / rate_hz - 1e-9, side="right") - 1


def on_grid(table: pd.DataFrame, rate_hz: float, name: str, max_gap: float = MAX_GAP) -> pd.DataFrame:
    """A recorded log at `rate_hz`: time from 0, the held commands, the interpolated rates and pose.

    `table` has increasing `time`, the commands and the truth columns (`read_log_file`); `name` is the
    log's file, named by the errors: a gap longer than `max_gap` s, a pose that is missing or not finite.
    """
    time = table[TIME].to_numpy(dtype=np.float64)
    steps = np.diff(time)
    if steps.size and steps.max() > max_gap:
        k = int(np.argmax(steps))
        raise DataFormatError(
            f"{name}: a gap of {steps[k]:.3f} s after {time[k] - time[0]:.3f} s (at most {max_gap:g} s "
            f"between samples): the commands in it are unknown; cut the log there"
        )
    missing = [c for c in TRUTH_COLUMNS if c not in table]
    if missing:
        raise DataFormatError(f"{name}: lacks the column(s) {', '.join(missing)}")
    if not np.isfinite(table[list(TRUTH_COLUMNS)].to_numpy(dtype=np.float64)).all():
        raise DataFormatError(f"{name}: has missing or non-finite speed, yaw rate or pose values")
    grid = grid_times(time, rate_hz)
    held = held_index(time, rate_hz)
    out = {TIME: grid - time[0]}
    out.update({c: table[c].to_numpy(dtype=np.float64)[held] for c in CONTROLS})
    for column in (*RATES, POS_X, POS_Y, YAW):
        values = table[column].to_numpy(dtype=np.float64)
        out[column] = np.interp(grid, time, np.unwrap(values) if column == YAW else values)
    return pd.DataFrame(out)


def relative_pose(truth: dict[str, np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y and unwrapped heading of the first n steps of a log, relative to its start pose."""
    dx, dy = truth[POS_X][:n] - truth[POS_X][0], truth[POS_Y][:n] - truth[POS_Y][0]
    c, s = np.cos(-truth[YAW][0]), np.sin(-truth[YAW][0])
    heading = np.unwrap(truth[YAW][:n]) - truth[YAW][0]
    return c * dx - s * dy, s * dx + c * dy, heading
