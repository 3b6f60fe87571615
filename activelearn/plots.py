"""Matplotlib figures. Functions build and return a Figure (Agg canvas); they never show or print."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

_MAX_LEGEND = 8


def _new_figure(width: float, height: float) -> Figure:
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)  # render off-screen whatever the global matplotlib backend is
    return fig


def plot_log(table: pd.DataFrame, title: str | None = None) -> Figure:
    """Simulation-log figure: trajectory, speed, yaw rate, heading and controls against time, per run.

    Mirrors the data figures of the reference study: the trajectory (posX, posY) on the left; on the
    right the rate variables (speed, angZ), the state (unwrapped yaw) and the controls (throttle,
    steering), each against the time since the run started.
    """
    fig = _new_figure(13.0, 8.0)
    grid = fig.add_gridspec(4, 2, width_ratios=(1.0, 1.3))
    ax_xy = fig.add_subplot(grid[:, 0])
    ax_v = fig.add_subplot(grid[0, 1])
    ax_w = fig.add_subplot(grid[1, 1], sharex=ax_v)
    ax_yaw = fig.add_subplot(grid[2, 1], sharex=ax_v)
    ax_u = fig.add_subplot(grid[3, 1], sharex=ax_v)
    ax_s = ax_u.twinx()

    run_ids = list(dict.fromkeys(table["run_id"])) if "run_id" in table else [None]
    colors = [f"C{i % 10}" for i in range(len(run_ids))]
    for run_id, color in zip(run_ids, colors, strict=True):
        run = table if run_id is None else table[table["run_id"] == run_id]
        stamps = run["timestamp"].to_numpy()
        t = run["time"].to_numpy() if "time" in run else stamps - stamps[0]
        label = None if run_id is None or len(run_ids) > _MAX_LEGEND else str(run_id)
        ax_xy.plot(run["posX"], run["posY"], color=color, lw=1.0, label=label)
        ax_xy.plot(run["posX"].iloc[:1], run["posY"].iloc[:1], "o", color=color, ms=4)
        ax_v.plot(t, run["speed"], color=color, lw=0.8)
        ax_w.plot(t, run["angZ"], color=color, lw=0.8)
        ax_yaw.plot(t, np.unwrap(run["yaw"].to_numpy()), color=color, lw=0.8)
        ax_u.plot(t, run["throttle"], color=color, lw=1.0)
        ax_s.plot(t, run["steering"], color=color, lw=1.0, ls="--")

    ax_xy.set(xlabel="posX (m)", ylabel="posY (m)", title="trajectory (o = start)")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.grid(True, alpha=0.3)
    if len(run_ids) <= _MAX_LEGEND and run_ids[0] is not None:
        ax_xy.legend(fontsize="small", loc="best")
    ax_v.set(ylabel="speed (m/s)")
    ax_w.set(ylabel="yaw rate angZ (rad/s)")
    ax_yaw.set(ylabel="yaw, unwrapped (rad)")
    ax_u.set(xlabel="time (s)", ylabel="throttle (solid)")
    ax_s.set_ylabel("steering rad (dashed)")
    for ax in (ax_v, ax_w, ax_yaw, ax_u):
        ax.grid(True, alpha=0.3)
    for ax in (ax_v, ax_w, ax_yaw):
        ax.tick_params(labelbottom=False)
    if title:
        fig.suptitle(title)
    return fig
