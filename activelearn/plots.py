"""Matplotlib figures. Functions build and return a Figure (Agg canvas); they never show or print."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FormatStrFormatter, LogLocator, MaxNLocator, NullFormatter

from activelearn.data import write_atomically
from activelearn.names import (
    N_MANEUVERS,
    POS_X,
    POS_Y,
    POSE,
    REFERENCE_STRATEGY,
    ROUND,
    SPEED,
    STEERING,
    TEST_NLL,
    THROTTLE,
    TRACK_SECONDS,
    YAW,
    YAW_RATE,
    metric_label,
)

_MAX_LEGEND = 8

# One colour per strategy, the same in every figure the project draws (a test checks that every strategy
# has one and no two share it). The reference (uniform) is black; the model-based rules warm colours.
STRATEGY_COLOURS: dict[str, str] = {
    "grid": "#8c8c8c",
    "uniform": "#000000",
    "random": "#bcbd22",
    "sobol": "#17becf",
    "lhs": "#8c564b",
    "max_epistemic": "#d62728",
    "epistemic_maximin": "#ff7f0e",
    "max_total": "#e377c2",
    "bald": "#9467bd",
    "integrated_variance": "#2ca02c",
    "safe_expander": "#98df8a",
    "igs": "#1f77b4",
    "lcmd": "#c5b0d5",
    "regressor_maximin": "#8c6d31",
    "joint_maximin": "#bd9e39",
    "fisher": "#843c39",
    "auto": "#006d77",
    "switch": "#ffbb78",
    "oracle_error": "#7b4173",
    "oracle_lookahead": "#393b79",
}


def strategy_colour(strategy: str, fallback: str = "#a0a0a0") -> str:
    """The colour `strategy` has in every figure (`fallback` for a name no strategy has, e.g. a label)."""
    return STRATEGY_COLOURS.get(strategy, fallback)


def new_figure(width: float, height: float, *, layout: str | None = "constrained") -> Figure:
    """An empty figure of `width` x `height` inches, drawn off-screen; laid out by matplotlib unless
    `layout` is None (the caller places its axes, as the round figure does: see `_InchGrid`)."""
    fig = Figure(figsize=(width, height), layout=layout)
    FigureCanvasAgg(fig)  # render off-screen whatever the global matplotlib backend is
    return fig


class _InchGrid:
    """Places axes and legends on a figure in inches from its lower left corner.

    The round figure is drawn every round of every campaign; matplotlib's constrained layout laid it
    out by drawing it once more before saving, about a third of its cost. Its panels' margins are fixed
    instead (wide enough for the labels' and ticks' text at its font sizes), and the one part whose size
    varies, a legend below a panel, is measured before the panel's axes are placed above it."""

    def __init__(self, fig: Figure) -> None:
        self.fig = fig
        self.width, self.height = fig.get_size_inches()

    def axes(self, left: float, bottom: float, width: float, height: float) -> Any:
        return self.fig.add_axes((left / self.width, bottom / self.height, width / self.width,
                                  height / self.height))  # fmt: skip

    def legend_below(self, centre: float, width: float, ncols: int, **kwargs: Any) -> float:
        """A frameless legend centred at `centre` inches along the figure's bottom edge, in at most
        `ncols` columns and fewer where they would be wider than `width` inches; its height in inches
        (0 without handles): what the panel above it must leave free."""
        if not kwargs.get("handles"):
            return 0.0
        renderer, anchor = self.fig.canvas.get_renderer(), (centre / self.width, 0.0)
        for columns in range(max(ncols, 1), 0, -1):
            legend = self.fig.legend(loc="lower center", bbox_to_anchor=anchor, frameon=False,
                                     borderaxespad=0.2, ncols=columns, **kwargs)  # fmt: skip
            box = legend.get_window_extent(renderer)
            if box.width / self.fig.dpi <= width or columns == 1:
                break
            legend.remove()
        return float(box.height) / self.fig.dpi


def save_figure(fig: Figure, path: str | Path, *, dpi: int) -> Path:
    """Write `fig` to `path` atomically: under a hidden temporary name beside it, then renamed, so a
    reader (a browser, MLflow, a second command) never finds half a figure."""
    return write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=dpi))


def plot_log(table: pd.DataFrame, title: str | None = None) -> Figure:
    """Simulation-log figure: trajectory, speed, yaw rate, heading and controls against time, per run.

    Mirrors the data figures of the reference study: the trajectory (posX, posY) on the left; on the
    right the rate variables (speed, angZ), the state (unwrapped yaw) and the controls (throttle,
    steering), each against the time since the run started.
    """
    fig = new_figure(13.0, 9.0)
    grid = fig.add_gridspec(5, 2, width_ratios=(1.0, 1.3))
    ax_xy = fig.add_subplot(grid[:, 0])
    ax_v = fig.add_subplot(grid[0, 1])
    ax_w = fig.add_subplot(grid[1, 1], sharex=ax_v)
    ax_yaw = fig.add_subplot(grid[2, 1], sharex=ax_v)
    ax_u = fig.add_subplot(grid[3, 1], sharex=ax_v)
    ax_s = fig.add_subplot(grid[4, 1], sharex=ax_v)  # a panel of its own: on one axis it hid under throttle

    run_ids = list(dict.fromkeys(table["run_id"])) if "run_id" in table else [None]
    colors = [f"C{i % 10}" for i in range(len(run_ids))]
    for run_id, color in zip(run_ids, colors, strict=True):
        run = table if run_id is None else table[table["run_id"] == run_id]
        stamps = run["timestamp"].to_numpy()
        t = run["time"].to_numpy() if "time" in run else stamps - stamps[0]
        label = None if run_id is None or len(run_ids) > _MAX_LEGEND else str(run_id)
        ax_xy.plot(run[POS_X], run[POS_Y], color=color, lw=1.0, label=label)
        ax_xy.plot(run[POS_X].iloc[:1], run[POS_Y].iloc[:1], "o", color=color, ms=4)
        ax_v.plot(t, run[SPEED], color=color, lw=0.8)
        ax_w.plot(t, run[YAW_RATE], color=color, lw=0.8)
        ax_yaw.plot(t, np.unwrap(run[YAW].to_numpy()), color=color, lw=0.8)
        ax_u.plot(t, run[THROTTLE], color=color, lw=1.0)
        ax_s.plot(t, run[STEERING], color=color, lw=1.0)

    ax_xy.set(xlabel="posX (m)", ylabel="posY (m)", title="trajectory (o = start)")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.grid(True, alpha=0.3)
    if 1 < len(run_ids) <= _MAX_LEGEND:  # one run: the title names it
        ax_xy.legend(fontsize="small", loc="best")
    ax_v.set(ylabel="speed (m/s)")
    ax_w.set(ylabel="yaw rate angZ (rad/s)")
    ax_yaw.set(ylabel="yaw, unwrapped (rad)")
    ax_u.set(ylabel="throttle")
    ax_s.set(xlabel="time (s)", ylabel="steering (rad, + left)")
    for ax in (ax_v, ax_w, ax_yaw, ax_u, ax_s):
        ax.grid(True, alpha=0.3)
    for ax in (ax_v, ax_w, ax_yaw, ax_u):
        ax.tick_params(labelbottom=False)
    if title:
        fig.suptitle(title)
    return fig


# ------------------------------------------------------------------------------------- campaign figures

# One marker shape per maneuver kind: the reference kinds (simulator.KINDS) and the families of a
# `dynamics` pool (simulator.families.FAMILIES); a test checks every kind has its own. The fill says
# which group a maneuver is in (prior, collected, chosen), so no shape doubles as a group's key.
_KIND_MARKERS = {
    "straight": "s", "skidpad": "o", "fishhook": "^", "slalom": "D", "eight": "P",
    "throttle_step": ">", "chirp": "v", "multisine": "<", "prbs": "*", "staircase": "h", "figure_eight": "X",
    # the standard tests: a thin diamond, then stars of 4, 3 and 6 points ((points, 1 = star, angle))
    "ramp_steer": "d", "step_steer": (4, 1, 0), "sine_with_dwell": (3, 1, 0), "double_lane_change": (6, 1, 0),
}  # fmt: skip
_OTHER_MARKER = "p"  # a kind no entry names


def _signed_steering(maneuver: Any) -> float:
    return 0.0 if maneuver.kind == "straight" else maneuver.sign * maneuver.steering


# The round figure's size in inches: the map panel (with its colorbar) and, right of it, the chosen
# signals' panel.
_MAP_WIDTH, _PLANS_WIDTH, _MAP_HEIGHT = 6.4, 8.6, 5.2


def epistemic_map(
    throttles: np.ndarray,
    steerings: np.ndarray,
    std: np.ndarray,
    *,
    taken: Sequence[Any],
    picks: Sequence[Any],
    prior: Sequence[Any] = (),
    title: str = "",
    plans: tuple[Sequence[str], Sequence[np.ndarray], Any] | None = None,
) -> Figure:
    """Heat map of epistemic std over throttle × signed steering, with known, collected and chosen maneuvers.

    `std` has shape (len(throttles), len(steerings)); maneuvers are marked at their operating point
    (throttle, signed steering), one marker shape per kind; `prior` (a warm start's maneuvers) in grey.
    `plans` = (names, control signals (T, 2), their predicted rollout) of the chosen maneuvers adds,
    beside the map, the throttle and steering each one applies and the path the model predicts.
    """
    fig = new_figure(_MAP_WIDTH if plans is None else _MAP_WIDTH + _PLANS_WIDTH, _MAP_HEIGHT, layout=None)
    grid = _InchGrid(fig)
    if plans is not None:
        _plans(grid, *plans)
    styles = (
        (prior, {"facecolor": "0.6", "edgecolor": "0.3", "s": 20}),
        (taken, {"facecolor": "white", "edgecolor": "black", "s": 36}),
        (picks, {"facecolor": "red", "edgecolor": "black", "s": 90}),
    )
    # Fill says what a marker is (only the groups drawn), shape which kind of maneuver it is. With one
    # kind the group's key is that kind's marker; with several, a swatch of the fill (a marker would
    # read as one of the kinds) and one outline per kind.
    kinds = sorted({m.kind for m in [*prior, *taken, *picks]})
    only = f" ({kinds[0]})" if len(kinds) == 1 else ""
    handles: list[Any] = []
    for group, (_, style), label in zip(
        (prior, taken, picks), styles, ("prior (known)", "collected", "chosen this round"), strict=True
    ):
        if not len(group):
            continue
        colours = {"facecolor": style["facecolor"], "edgecolor": style["edgecolor"]}
        if len(kinds) == 1:
            marker = _KIND_MARKERS.get(kinds[0], _OTHER_MARKER)
            handles.append(Line2D([], [], linestyle="none", marker=marker, markersize=7, label=label + only,
                                  markerfacecolor=colours["facecolor"], markeredgecolor=colours["edgecolor"]))
        else:
            handles.append(Patch(**colours, label=label))
    if len(kinds) > 1:
        handles += [
            Line2D([], [], linestyle="none", marker=_KIND_MARKERS.get(kind, _OTHER_MARKER), markersize=7,
                   markerfacecolor="none", markeredgecolor="black", label=f"shape: {kind}")
            for kind in kinds
        ]  # fmt: skip
    # no legend on an empty map (nothing collected or chosen yet): nothing to explain
    below = grid.legend_below(_MAP_WIDTH / 2, _MAP_WIDTH, 4, handles=handles, fontsize=9)
    left, right, top, bottom = 0.75, 1.35, 0.35, 0.55 + below  # the colorbar and its label on the right
    ax = grid.axes(left, bottom, _MAP_WIDTH - left - right, _MAP_HEIGHT - top - bottom)
    mesh = ax.pcolormesh(steerings, throttles, std, shading="nearest", cmap="viridis")
    fig.colorbar(mesh, cax=grid.axes(_MAP_WIDTH - right + 0.15, bottom, 0.17, _MAP_HEIGHT - top - bottom),
                 label="epistemic std (standardised, mean of v and ω)")  # fmt: skip
    for group, style in styles:
        for kind in sorted({m.kind for m in group}):
            pts = np.array([(_signed_steering(m), m.throttle) for m in group if m.kind == kind])
            ax.scatter(pts[:, 0], pts[:, 1], marker=_KIND_MARKERS.get(kind, _OTHER_MARKER), **style)
    ax.set_xlabel("signed steering (rad, + = left, ccw)")
    ax.set_ylabel("throttle")
    ax.set_title(title)
    return fig


def _plans(grid: _InchGrid, names: Sequence[str], controls: Sequence[np.ndarray], rollout: Any) -> None:
    """The chosen maneuvers' control signals (throttle, steering over time) and predicted paths with fans,
    right of the map: two stacked axes of signals, the paths beside them, the signals' names below."""
    labels = [name if len(name) <= 40 else name[:38] + "…" for name in names]
    colours = [f"C{(k + 1) % 10}" for k in range(len(names))]
    handles = [Line2D([], [], color=c, lw=1.2, label=label) for c, label in zip(colours, labels, strict=True)]
    below = grid.legend_below(_MAP_WIDTH + _PLANS_WIDTH / 2, _PLANS_WIDTH, 1 if len(handles) <= 4 else 2,
                              handles=handles, fontsize=8)
    left, gap, right, top, bottom, between = 0.75, 0.8, 0.15, 0.35, 0.5 + below, 0.5
    width = (_PLANS_WIDTH - left - gap - right) / 2
    height = _MAP_HEIGHT - top - bottom
    x0 = _MAP_WIDTH + left
    ax_s = grid.axes(x0, bottom, width, (height - between) / 2)
    ax_t = grid.axes(x0, bottom + (height + between) / 2, width, (height - between) / 2)
    ax_p = grid.axes(x0 + width + gap, bottom, width, height)
    ax_s.sharex(ax_t)
    for k, (colour, u) in enumerate(zip(colours, controls, strict=True)):
        t = np.arange(len(u)) * rollout.dt
        ax_t.plot(t, u[:, 0], color=colour, lw=1.2)
        ax_s.plot(t, u[:, 1], color=colour, lw=1.2)
        n = int(rollout.lengths[k])
        for s in range(rollout.x.shape[0]):
            ax_p.plot(rollout.x[s, k, :n], rollout.y[s, k, :n], color=colour, alpha=0.08, lw=0.6)
        mx, my = rollout.mean_path(k)
        ax_p.plot(mx[:n], my[:n], color=colour, lw=1.6)
        ax_p.plot(mx[n - 1], my[n - 1], "o", color=colour, ms=4)
    ax_t.set_ylabel("throttle")
    ax_s.set_ylabel("steering (rad)")
    ax_s.set_xlabel("time (s)")
    ax_p.plot(0.0, 0.0, "k^", ms=6)
    ax_p.set_aspect("equal", adjustable="datalim")
    ax_p.set_xlabel("x (m, start frame)")
    ax_p.set_ylabel("y (m)")
    ax_p.set_title("predicted paths (mean, fan)", fontsize=10)
    for ax in (ax_t, ax_s, ax_p):
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    ax_t.set_title("chosen control signals", fontsize=10)


def comparison_figure(
    curves: pd.DataFrame,
    metrics: Sequence[str],
    *,
    reference: str = REFERENCE_STRATEGY,
    title: str = "",
    seconds: bool = False,
) -> Figure:
    """Metric-versus-data curves, one line per strategy, mean ± 1 standard error over seeds.

    `curves` has one row per (strategy, seed, round) with `n_maneuvers` and the metric columns; the
    reference strategy is drawn dashed and thicker. With `seconds`, a second row of panels draws the
    same metrics against the track seconds spent (`track_seconds`, averaged over seeds per round).
    """
    budgets = [N_MANEUVERS, *([TRACK_SECONDS] if seconds else [])]
    fig = new_figure(3.4 * len(metrics), 3.0 * len(budgets) + 0.6)
    grid = fig.subplots(len(budgets), len(metrics), squeeze=False)
    strategies = list(dict.fromkeys(curves["strategy"]))
    n_seeds = int(curves.groupby("strategy")["seed"].nunique().max()) if "seed" in curves else 1
    for axes, budget in zip(grid, budgets, strict=True):
        for ax, metric in zip(axes, metrics, strict=True):
            for i, strategy in enumerate(strategies):
                part = curves[curves["strategy"] == strategy]
                stats = part.groupby(ROUND).agg(
                    x=(budget, "mean"), mean=(metric, "mean"), std=(metric, "std"), count=(metric, "count")
                )
                sem = (stats["std"] / np.sqrt(stats["count"])).fillna(0.0)
                color = strategy_colour(strategy, fallback=f"C{i % 10}")
                style = {"linewidth": 2.6, "linestyle": "--"} if strategy == reference else {"linewidth": 1.6}
                label = f"{strategy} (reference)" if strategy == reference else strategy
                ax.plot(stats["x"], stats["mean"], color=color, label=label, **style)
                ax.fill_between(stats["x"], stats["mean"] - sem, stats["mean"] + sem, color=color, alpha=0.2)
            ax.set_xlabel(metric_label(budget))
            if budget == N_MANEUVERS:
                ax.xaxis.set_major_locator(MaxNLocator(integer=True))
            ax.set_ylabel(metric_label(metric), fontsize=8.5)
            if metric != TEST_NLL:
                ax.set_yscale("log")
                # plain decimals at 1-2-5 steps: the default gives "1.3 x 10^-1"-style labels; minor
                # ticks are labelled only when the range spans less than a decade (else they crowd)
                low, high = ax.get_ylim()
                ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
                ax.yaxis.set_major_formatter(FormatStrFormatter("%.3g"))
                minor = FormatStrFormatter("%.3g") if high < 10 * low else NullFormatter()
                ax.yaxis.set_minor_formatter(minor)
            ax.grid(alpha=0.3)
    # One legend for every panel, below them; the title says what the lines and bands are.
    fig.legend(
        *grid[0][0].get_legend_handles_labels(),
        loc="outside lower center",
        ncols=len(strategies),
        fontsize=11,
        frameon=False,
    )
    spread = f"mean ± 1 s.e. over {n_seeds} seeds" if n_seeds > 1 else "1 seed (no band)"
    fig.suptitle(f"{title or 'strategy comparison'}: {spread}", fontsize=13)
    return fig


# ------------------------------------------------------------------------------------ surrogate figure


def surrogate_figure(
    rollout: Any, index: int, truth: pd.DataFrame, *, title: str = "", truth_label: str = "MuJoCo",
    outside: Sequence[Any] = (),
) -> Figure:  # fmt: skip
    """Surrogate against ground truth for one maneuver: path fan, v(t) and ω(t) with 50/95% bands.

    The path panel draws every sampled trajectory faintly (one posterior draw each), the mean path
    and the true path (`truth_label`); the rate panels shade the 95% and 50% bands over samples.
    `outside` (`diagnostics.Excursion`s) marks where the truth leaves a fan: red spans on the rate
    panels (the channel's, both for position) and the true path red there.
    """
    n = int(rollout.lengths[index])
    t = rollout.time[:n]
    fig = new_figure(13.0, 6.5)
    grid = fig.add_gridspec(2, 2, width_ratios=(1.0, 1.3))
    ax_xy = fig.add_subplot(grid[:, 0])
    x0, y0, yaw0 = (truth[c].to_numpy()[0] for c in POSE)
    dx, dy = truth[POS_X].to_numpy()[:n] - x0, truth[POS_Y].to_numpy()[:n] - y0
    c, s = np.cos(-yaw0), np.sin(-yaw0)
    tx, ty = c * dx - s * dy, s * dx + c * dy
    for k in range(rollout.x.shape[0]):
        ax_xy.plot(rollout.x[k, index, :n], rollout.y[k, index, :n], color="C0", alpha=0.12, linewidth=0.8)
    mx, my = rollout.mean_path(index)
    ax_xy.plot(mx[:n], my[:n], color="C0", linewidth=2.0, label="surrogate mean")
    ax_xy.plot(tx, ty, color="black", linewidth=1.5, linestyle="--", label=truth_label)
    for i, e in enumerate(e for e in outside if e.channel == "position"):
        part = (t >= e.start - 1e-9) & (t <= e.end + 1e-9)
        ax_xy.plot(tx[part], ty[part], color="C3", linewidth=2.0, label=None if i else "outside the 95% fan")
    ax_xy.plot([], [], color="C0", alpha=0.3, label=f"{rollout.x.shape[0]} sampled paths")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.set_xlabel("x (m, start frame)")
    ax_xy.set_ylabel("y (m)")
    ax_xy.legend(fontsize=8)
    panels = (("v", SPEED, "v (m/s)", "speed"), ("w", YAW_RATE, "ω (rad/s)", "yaw rate"))
    for row, (name, column, label, channel) in enumerate(panels):
        ax = fig.add_subplot(grid[row, 1])
        q = rollout.quantiles(name, index)[:, :n]
        ax.fill_between(t, q[0], q[4], color="C0", alpha=0.18, label="95% band")
        ax.fill_between(t, q[1], q[3], color="C0", alpha=0.35, label="50% band")
        ax.plot(t, rollout.mean_rates[index, :n, row], color="C0", linewidth=1.4, label="surrogate mean")
        ax.plot(t, truth[column].to_numpy()[:n], color="black", linewidth=0.9, label=truth_label)
        for e in outside:
            if e.channel in (channel, "position"):
                ax.axvspan(e.start, e.end, color="C3", alpha=0.12 if e.channel == channel else 0.05, lw=0)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if row == 0:
            ax.legend(fontsize=8, ncols=4)
        else:
            ax.set_xlabel("time (s)")
    fig.suptitle(title)
    return fig


def paths_figure(
    rollouts: dict[str, Any], cases: Sequence[tuple[str, int]], truths: Sequence[pd.DataFrame], *,
    seconds: float = 30.0, title: str = "",
) -> Figure:  # fmt: skip
    """Free-run paths of several models side by side: one row per case (a label and a maneuver index
    into every rollout and `truths`), one column per model. Each panel: the sampled paths faintly (the
    fan), their mean and the true path, over the first `seconds`."""
    fig = new_figure(3.2 * len(rollouts) + 0.6, 2.9 * len(cases) + 0.6)
    grid = fig.subplots(len(cases), len(rollouts), squeeze=False)
    for row, (label, index) in enumerate(cases):
        truth = truths[index]
        x0, y0, yaw0 = (truth[c].to_numpy()[0] for c in POSE)
        c, s = np.cos(-yaw0), np.sin(-yaw0)
        for col, (name, rollout) in enumerate(rollouts.items()):
            ax = grid[row, col]
            n = min(int(rollout.lengths[index]), round(seconds / rollout.dt) + 1)
            dx, dy = truth[POS_X].to_numpy()[:n] - x0, truth[POS_Y].to_numpy()[:n] - y0
            for k in range(rollout.x.shape[0]):
                ax.plot(rollout.x[k, index, :n], rollout.y[k, index, :n], color="C0", alpha=0.1, lw=0.7)
            mx, my = rollout.mean_path(index)
            ax.plot(mx[:n], my[:n], color="C0", lw=1.8, label="model: mean path")
            ax.plot(c * dx - s * dy, s * dx + c * dy, color="black", lw=1.3, ls="--", label="MuJoCo")
            ax.plot(mx[n - 1], my[n - 1], "o", color="C0", ms=4)
            ax.plot(c * dx[-1] - s * dy[-1], s * dx[-1] + c * dy[-1], "o", color="black", ms=4)
            ax.set_aspect("equal", adjustable="datalim")
            ax.grid(alpha=0.3)
            ax.tick_params(labelsize=8)
            if row == 0:
                ax.set_title(name, fontsize=11)
            if col == 0:
                ax.set_ylabel(f"{label}\ny (m)", fontsize=9)
            if row == len(cases) - 1:
                ax.set_xlabel("x (m, start frame)", fontsize=9)
    grid[0, 0].plot([], [], color="C0", alpha=0.4, lw=0.7, label="sampled paths (the fan)")
    handles, labels = grid[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncols=3, fontsize=9, frameon=False)
    fig.suptitle(title or f"free runs, first {seconds:g} s")
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    return fig


def fidelity_figure(points: pd.DataFrame, title: str = "") -> Figure:
    """Fidelity figure: steady speed, yaw rate and turn speed loss against steering, sim (line) vs log (dots).

    `points` is `FidelityReport.points` (empty: the panels say so); one colour per throttle.
    """
    fig = new_figure(14.5, 4.2)
    axes = fig.subplots(1, 3)
    panels = (
        ("v", "steady speed (m/s)"),
        ("w", "steady yaw rate angZ (rad/s)"),
        ("loss", "speed loss in turns (m/s)"),
    )
    for i, throttle in enumerate(sorted(points[THROTTLE].unique())):
        part = points[points[THROTTLE] == throttle].sort_values("steering")
        color = f"C{i % 10}"
        for ax, (name, _) in zip(axes, panels, strict=True):
            rows = part if name != "loss" else part[part["loss_sim"].notna()]
            if not len(rows):
                continue
            ax.plot(
                rows[STEERING],
                rows[f"{name}_sim"],
                "-x",
                color=color,
                lw=1.2,
                ms=5,
                label=f"throttle {throttle:g}" if name == "v" else None,
            )
            ax.plot(rows[STEERING], rows[f"{name}_log"], "o", color=color, ms=5, mfc="none")
    for ax, (_, label) in zip(axes, panels, strict=True):
        ax.set(xlabel="steering (rad, + left)", ylabel=label)
        ax.grid(True, alpha=0.3)
    if not len(points):
        axes[1].text(0.5, 0.5, "no stretch of constant commands\nsettles in these logs", ha="center",
                     va="center", transform=axes[1].transAxes)
    # Colour is the throttle; the marker says which side a point comes from.
    handles, labels = axes[0].get_legend_handles_labels()
    handles += [
        axes[0].plot([], [], "-x", color="black", lw=1.2, ms=5)[0],
        axes[0].plot([], [], "o", color="black", ms=5, mfc="none")[0],
    ]
    labels += ["simulator (line, ×)", "recorded log (○)"]
    fig.legend(handles, labels, loc="outside right upper", fontsize="medium", frameon=False)
    if title:
        fig.suptitle(title)
    return fig


def replay_figure(traces: dict[str, pd.DataFrame], *, most: int = 6, title: str = "") -> Figure:
    """Whole-log replays, one row per log (the first `most`): both paths in the start frame, speed and
    yaw rate against time, and the distance between the paths. `traces` is `FidelityReport.traces`."""
    shown = list(traces.items())[:most]
    fig = new_figure(16.0, 3.2 * len(shown) + 0.6)
    axes = fig.subplots(len(shown), 4, squeeze=False, width_ratios=(1.0, 1.3, 1.3, 1.3))
    for row, (name, trace) in enumerate(shown):
        ax_xy, ax_v, ax_w, ax_e = axes[row]
        t = trace["time"]
        ax_xy.plot(trace["x_log"], trace["y_log"], color="black", lw=1.3, ls="--", label="recorded log")
        ax_xy.plot(trace["x_sim"], trace["y_sim"], color="C0", lw=1.5, label="simulator")
        ax_xy.set_aspect("equal", adjustable="datalim")
        ax_xy.set(xlabel="x (m, start frame)", ylabel=f"{Path(name).name}\ny (m)")
        for ax, side, label in ((ax_v, "v", "speed (m/s)"), (ax_w, "w", "yaw rate angZ (rad/s)")):
            ax.plot(t, trace[f"{side}_log"], color="black", lw=0.9)
            ax.plot(t, trace[f"{side}_sim"], color="C0", lw=1.0)
            ax.set(xlabel="time (s)", ylabel=label)
        ax_e.plot(t, trace["error"], color="C3", lw=1.2)
        ax_e.set(xlabel="time (s)", ylabel="position error (m)")
        for ax in axes[row]:
            ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize="small", loc="best")
    more = f" (the first {most} of {len(traces)} logs)" if len(traces) > most else ""
    fig.suptitle((title or "simulator replaying the logs' commands") + more)
    return fig


def arena_figure(
    arena: Sequence[tuple[float, float]],
    start: tuple[float, float, float],
    proposals: Sequence[dict[str, Any]],
    *,
    margin: float = 0.0,
    reach: float | None = None,
    title: str = "",
    brake_line: tuple[np.ndarray, np.ndarray, np.ndarray, float] | None = None,
) -> Figure:
    """The arena, the start pose and each proposal's predicted path with its 95 % fan and risk.

    Each proposal is a dict with `label`, `risk` and, when a model predicted it, `x`, `y` (S, T)
    sampled paths in the arena frame (NaN after a path ends; then `mean` gives the mean path); the 5 %
    of paths farthest from the mean path are left out, so the band drawn holds 95 % of the fan.
    `reach` (m) draws the circle the kinematic worst case keeps the car in (before any model). Under
    a live stop, `brake_line` = (grid x, grid y, clearance, level) draws where the car brakes, and a
    proposal's `brakes` (x, y) marks the points where its paths would be braked (`n_paths`: how many
    paths it has).
    """
    fig = new_figure(9.5, 6.0)
    ax = fig.add_subplot()
    ring = np.vstack([np.asarray(arena, dtype=float), np.asarray(arena[:1], dtype=float)])
    ax.fill(ring[:, 0], ring[:, 1], color="0.95", zorder=0)
    ax.plot(ring[:, 0], ring[:, 1], color="k", lw=2.0, label="arena")
    x0, y0, yaw0 = start
    arrow = 0.25
    ax.annotate("", xy=(x0 + arrow * np.cos(yaw0), y0 + arrow * np.sin(yaw0)), xytext=(x0, y0),
                arrowprops={"arrowstyle": "-|>", "color": "k", "lw": 1.5})  # fmt: skip
    ax.plot([x0], [y0], "ko", ms=6, label=f"start (yaw {yaw0:.2f} rad)")
    if reach is not None and reach > 0:
        circle = np.linspace(0, 2 * np.pi, 200)
        ax.plot(x0 + reach * np.cos(circle), y0 + reach * np.sin(circle), "k:", lw=1.0,
                label="worst-case reach (no model yet)")  # fmt: skip
    if brake_line is not None:
        gx, gy, clearance, level = brake_line
        ax.contour(gx, gy, clearance, levels=[level], colors="r", linestyles="--", linewidths=1.0)
        ax.plot([], [], "r--", lw=1.0, label=f"live stop: brakes within {level:g} m of a wall")
    colors = [f"C{i % 10}" for i in range(len(proposals))]
    for proposal, color in zip(proposals, colors, strict=True):
        label = f"{proposal['label']}: risk {proposal['risk']:.3f}"
        if "brakes" in proposal:
            label += f", braked {len(proposal['brakes'][0])}/{proposal['n_paths']}"
        if "x" not in proposal:
            ax.plot([], [], color=color, label=label)
            continue
        x, y = np.asarray(proposal["x"]), np.asarray(proposal["y"])
        if "mean" in proposal:  # given (under a live stop: the mean of the whole paths, itself braked)
            mx, my = (np.asarray(a) for a in proposal["mean"])
        else:
            mx, my = x.mean(axis=0), y.mean(axis=0)
        deviation = np.nanmax(np.hypot(x - mx, y - my), axis=1)
        keep = deviation <= np.quantile(deviation, 0.95)
        for xs, ys in zip(x[keep], y[keep], strict=True):
            ax.plot(xs, ys, color=color, lw=0.5, alpha=0.15)
        ax.plot(mx, my, color=color, lw=2.0, label=label)
        last = np.flatnonzero(np.isfinite(mx))[-1:]
        ax.plot(mx[last], my[last], "s", color=color, ms=5)
        if "brakes" in proposal:
            ax.plot(*proposal["brakes"], "x", color=color, ms=4, mew=1.0)
    ax.set_aspect("equal")
    span = ring.max(axis=0) - ring.min(axis=0)
    pad = 0.05 * float(span.max())
    ax.set_xlim(ring[:, 0].min() - pad, ring[:, 0].max() + pad)
    ax.set_ylim(ring[:, 1].min() - pad, ring[:, 1].max() + pad)
    ax.set(xlabel="x (m)", ylabel="y (m)", title=(title + "\n" if title else "")
           + f"mean path and 95 % of the fan (margin {margin:g} m; square = end)")  # fmt: skip
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7, framealpha=0.8)
    return fig


def proposals_figure(
    arena: Sequence[tuple[float, float]],
    start: tuple[float, float, float],
    proposals: Sequence[dict[str, Any]],
    *,
    name: str,
    batch: int,
    delta: float,
    margin: float,
    reach: float | None = None,
    brake_at: float | None = None,
) -> Figure:
    """A campaign's pending proposals in its [safety] arena (`campaign propose --plot`): `arena_figure`
    titled with the campaign's `name`, the `batch` and `delta`. `brake_at` (m from a wall, under a
    live stop) draws the line where the car brakes, where each proposal's paths end."""
    from activelearn.config.geometry import polygon_clearance

    title = f"{name}: proposals of batch {batch}, delta {delta:g}"
    brake_line = None
    if brake_at is not None:
        title += (f"\nlive stop: the car brakes within margin + stop_buffer = {brake_at:g} m of a wall"
                  "\n(dashed), so a path ends there (x); the risk counts the limits only")  # fmt: skip
        lo, hi = np.min(arena, axis=0), np.max(arena, axis=0)
        gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], 240), np.linspace(lo[1], hi[1], 240))
        brake_line = (gx, gy, polygon_clearance(arena, gx, gy), brake_at)
    return arena_figure(arena, start, proposals, margin=margin, reach=reach, title=title,
                        brake_line=brake_line)  # fmt: skip
