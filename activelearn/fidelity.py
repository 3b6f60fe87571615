"""Fidelity report: replay a car's logged commands in the simulator and compare the two runs.

Whole log: the simulator replays each log's commands, held between samples, on the simulator's grid
(`activelearn.replay.on_grid`), from rest (MuJoCo starts standing; a log that does not start at rest
is replayed from rest all the same, and its `start_speed` says by how much the first seconds must
differ); the path (each run relative to its own start pose), speed and yaw rate are compared along
the whole log: the position error over time, its end, mean and largest value, and the rms speed and
yaw-rate errors. This serves any log, manual driving included.

Steady stretches: every log is cut into stretches of constant commands (throttle and steering within
a tolerance of the stretch's first command). A stretch long enough to settle is an operating point:
after `settle` seconds the mean speed and yaw rate over the rest of it are its steady response. The
same replay's windows at the same times give the simulated response (a log without such a stretch
gives none: the whole-log comparison still serves it). Speed loss in a turn is the straight-line
speed at the same throttle minus the turn's speed: simulated straights for the simulator; for the
log, its own straight stretches at that throttle when it has some, else the reference throttle map
(`straight_source` says which).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

import simulator
from activelearn.data import read_recorded_log
from activelearn.errors import DataFormatError, InputError
from activelearn.names import POSE, SPEED, STEERING, THROTTLE, YAW_RATE
from activelearn.replay import held_index, on_grid, relative_pose
from simulator.datasheet import LOG_RATE_HZ

_RESPONSES = ("v_sim", "v_log", "w_sim", "w_log")
_STRAIGHT_SECONDS = 6.0  # simulated straights: steady after 3 s, averaged over the last 3 s


@dataclass(frozen=True)
class FidelitySettings:
    """How stretches of constant commands are found and averaged."""

    settle: float = 1.0  # s dropped at the start of a stretch (the transient)
    min_window: float = 1.0  # s of steady data a stretch must still have
    throttle_tolerance: float = 0.02
    steering_tolerance: float = 0.01  # rad
    rate_hz: float = LOG_RATE_HZ  # simulator log rate of the replay

    def __post_init__(self) -> None:
        for name in ("settle", "min_window", "throttle_tolerance", "steering_tolerance", "rate_hz"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not np.isfinite(value) or value < 0:
                raise InputError(name, value, "must be a finite number >= 0")
        if self.min_window <= 0 or self.rate_hz <= 0:
            raise InputError("min_window" if self.min_window <= 0 else "rate_hz", 0, "must be > 0")


@dataclass(frozen=True)
class Stretch:
    """A stretch of constant commands in one log: its window of steady samples and its commands."""

    log: str
    start: float  # s, first sample of the steady window (log time)
    end: float  # s, last sample of the steady window
    throttle: float
    steering: float  # rad, signed


@dataclass
class FidelityReport:
    """Whole-log, per-stretch and per-operating-point comparison of simulator and logs."""

    stretches: pd.DataFrame  # one row per stretch: log, window, commands, sim and log responses
    points: pd.DataFrame  # one row per operating point (throttle, steering): means over its stretches
    vehicle: str  # "nominal" or the twin's overrides
    replays: pd.DataFrame  # one row per log: the whole-log comparison (`REPLAY_COLUMNS`)
    traces: dict[str, pd.DataFrame]  # per log, per grid step: both paths, rates and the position error


REST_SPEED = 0.02  # m/s: a log whose first |speed| is above this does not start at rest
REPLAY_COLUMNS = ("log", "seconds", "start_speed", "error_end", "error_mean", "error_max", "rms_v", "rms_w")
_STRETCH_COLUMNS = ("log", "start", "end", THROTTLE, STEERING, *_RESPONSES, "turn", "seconds")
_POINT_COLUMNS = (THROTTLE, STEERING, "stretches", "seconds", *_RESPONSES, "loss_sim", "loss_log",
                  "straight_source", "dv", "dw", "dloss")  # fmt: skip


def read_log_file(path: str | Path) -> pd.DataFrame:
    """One log (AutoDRIVE CSV, our CSV or Parquet) with finite time, commands, speed and yaw rate."""
    table = read_recorded_log(path)
    time = table["time"].to_numpy(dtype=np.float64)
    if len(table) < 2 or not (np.diff(time) > 0).all():
        raise DataFormatError(f"{path}: time must increase from row to row")
    return table.reset_index(drop=True)


def stretches(table: pd.DataFrame, log: str, settings: FidelitySettings) -> list[Stretch]:
    """The stretches of constant, non-zero throttle in a log long enough to give a steady response."""
    t = table["time"].to_numpy(dtype=np.float64)
    u = table[THROTTLE].to_numpy(dtype=np.float64)
    d = table[STEERING].to_numpy(dtype=np.float64)
    found: list[Stretch] = []
    i = 0
    while i < len(t):
        j = i + 1
        while (
            j < len(t)
            and abs(u[j] - u[i]) <= settings.throttle_tolerance
            and abs(d[j] - d[i]) <= settings.steering_tolerance
        ):
            j += 1
        start = t[i] + settings.settle
        end = t[j - 1]
        if end - start >= settings.min_window and np.median(u[i:j]) != 0.0:  # zero throttle brakes
            found.append(Stretch(log, float(start), float(end), float(np.median(u[i:j])),
                                 float(np.median(d[i:j]))))  # fmt: skip
        i = j
    return found


def _window_means(table: pd.DataFrame, start: float, end: float) -> tuple[float, float]:
    t = table["time"].to_numpy()
    rows = (t >= start - 1e-9) & (t <= end + 1e-9)
    return float(table[SPEED].to_numpy()[rows].mean()), float(table[YAW_RATE].to_numpy()[rows].mean())


def replay_of(table: pd.DataFrame, label: str, rate_hz: float) -> simulator.Replay:
    """The log's commands as a simulator Replay: each logged command held until the next one
    (`activelearn.replay.held_index`)."""
    held = held_index(table["time"].to_numpy(dtype=np.float64), rate_hz)
    throttle = table[THROTTLE].to_numpy(dtype=np.float64)[held]
    steering = table[STEERING].to_numpy(dtype=np.float64)[held]
    try:
        return simulator.Replay(label, throttle, steering, rate_hz)
    except simulator.ManeuverError as exc:
        raise InputError(f"{label}: {exc.field}", exc.value, exc.reason) from None


def compare(
    logs: Sequence[tuple[str, pd.DataFrame]],
    *,
    vehicle: simulator.Vehicle | None = None,
    vehicle_name: str = "nominal",
    settings: FidelitySettings = FidelitySettings(),  # frozen dataclass: a safe shared default
    threads: int | None = None,
) -> FidelityReport:
    """Replay every (name, table) log in the simulator and compare the whole runs, and the steady
    speed, yaw rate and speed loss of its stretches of constant commands (none where none settles)."""
    found = [s for name, table in logs for s in stretches(table, name, settings)]
    recorded = {name: on_grid(table, settings.rate_hz, name) for name, table in logs}  # gaps refused here
    replays = [replay_of(table, name, settings.rate_hz) for name, table in logs]
    turn_throttles = sorted({round(s.throttle, 4) for s in found})
    straights = [simulator.Maneuver("straight", u, duration=_STRAIGHT_SECONDS) for u in turn_throttles]
    simulated = simulator.collect(
        [*replays, *straights], rate_hz=settings.rate_hz, noise=None, threads=threads, vehicle=vehicle
    )
    by_run = {run_id: part.reset_index(drop=True) for run_id, part in simulated.groupby("run_id", sort=False)}
    traces = {name: _trace(by_run[name], recorded[name]) for name, _ in logs}
    whole = pd.DataFrame([_whole_log(name, traces[name]) for name, _ in logs], columns=list(REPLAY_COLUMNS))
    if not found:
        empty = pd.DataFrame(columns=list(_STRETCH_COLUMNS)), pd.DataFrame(columns=list(_POINT_COLUMNS))
        return FidelityReport(*empty, vehicle_name, whole, traces)
    sim_straight = {
        u: _window_means(by_run[m.name], _STRAIGHT_SECONDS / 2, _STRAIGHT_SECONDS)[0]
        for u, m in zip(turn_throttles, straights, strict=True)
    }
    tables = dict(logs)
    rows = []
    for s in found:
        v_log, w_log = _window_means(tables[s.log], s.start, s.end)
        v_sim, w_sim = _window_means(by_run[s.log], s.start, s.end)
        rows.append(dict(log=s.log, start=s.start, end=s.end, throttle=s.throttle, steering=s.steering,
                         v_sim=v_sim, v_log=v_log, w_sim=w_sim, w_log=w_log))  # fmt: skip
    frame = pd.DataFrame(rows)
    frame["turn"] = frame[STEERING].abs() > settings.steering_tolerance
    frame["seconds"] = frame["end"] - frame["start"]
    spec = vehicle.spec if vehicle is not None else simulator.load_vehicle("nigel")
    points = _points(frame, sim_straight, settings, spec)
    return FidelityReport(frame, points, vehicle_name, whole, traces)


def _trace(sim: pd.DataFrame, log: pd.DataFrame) -> pd.DataFrame:
    """The simulated and the recorded run step by step, each path relative to its own start pose."""
    n = min(len(sim), len(log))  # a diverged simulation stops early
    sim_x, sim_y, _ = relative_pose({c: sim[c].to_numpy(dtype=np.float64) for c in POSE}, n)
    log_x, log_y, _ = relative_pose({c: log[c].to_numpy(dtype=np.float64) for c in POSE}, n)
    return pd.DataFrame({
        "time": log["time"].to_numpy()[:n], "x_sim": sim_x, "y_sim": sim_y, "x_log": log_x, "y_log": log_y,
        "v_sim": sim[SPEED].to_numpy()[:n], "v_log": log[SPEED].to_numpy()[:n],
        "w_sim": sim[YAW_RATE].to_numpy()[:n], "w_log": log[YAW_RATE].to_numpy()[:n],
        "error": np.hypot(sim_x - log_x, sim_y - log_y),
    })  # fmt: skip


def _whole_log(name: str, trace: pd.DataFrame) -> dict[str, object]:
    """One log's whole-run comparison: position error (end, mean, largest), rms speed and yaw-rate error."""
    error = trace["error"].to_numpy()
    return dict(
        log=name, seconds=float(trace["time"].iloc[-1]), start_speed=float(trace["v_log"].iloc[0]),
        error_end=float(error[-1]), error_mean=float(error.mean()), error_max=float(error.max()),
        rms_v=float(np.sqrt(np.mean((trace["v_sim"] - trace["v_log"]) ** 2))),
        rms_w=float(np.sqrt(np.mean((trace["w_sim"] - trace["w_log"]) ** 2))),
    )  # fmt: skip


def _points(
    frame: pd.DataFrame, sim_straight: dict[float, float], settings: FidelitySettings,
    spec: simulator.VehicleSpec,
) -> pd.DataFrame:  # fmt: skip
    """Operating points: stretches with the same commands (to 2 and 3 decimals) averaged, time-weighted."""
    frame = frame.assign(key_u=frame[THROTTLE].round(2), key_d=frame[STEERING].round(3))
    rows = []
    for (u, d), part in frame.groupby(["key_u", "key_d"], sort=True):
        weight = part["seconds"].to_numpy()
        mean = {c: float(np.average(part[c], weights=weight)) for c in (THROTTLE, *_RESPONSES)}
        row = dict(throttle=float(u), steering=float(d), stretches=len(part), seconds=float(weight.sum()), **{
            k: v for k, v in mean.items() if k != "throttle"})  # fmt: skip
        if abs(d) > settings.steering_tolerance:
            near = (frame[THROTTLE] - mean[THROTTLE]).abs() <= settings.throttle_tolerance
            straight_log = frame[~frame["turn"] & near]
            if len(straight_log):
                v0_log = float(np.average(straight_log["v_log"], weights=straight_log["seconds"]))
                source = "log"
            else:
                v0_log = float(spec.steady_speed(mean[THROTTLE]))
                source = "reference"
            v0_sim = sim_straight[min(sim_straight, key=lambda k: abs(k - mean[THROTTLE]))]
            row.update(loss_sim=v0_sim - row["v_sim"], loss_log=v0_log - row["v_log"], straight_source=source)
        else:
            row.update(loss_sim=np.nan, loss_log=np.nan, straight_source="")
        rows.append(row)
    points = pd.DataFrame(rows)
    points["dv"] = points["v_sim"] - points["v_log"]
    points["dw"] = points["w_sim"] - points["w_log"]
    points["dloss"] = points["loss_sim"] - points["loss_log"]
    return points
