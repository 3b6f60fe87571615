"""Run many maneuvers in parallel through mujoco.rollout and log them in the AutoDRIVE column layout.

How a collection runs:
- every maneuver is one rollout of the batch; `threads` MjData instances step the batch in parallel;
- time advances in chunks of at most 2 s of log samples (fewer if the batch is large, to bound
  memory: a chunk holds the full state and sensors of every physics step). Between chunks the
  state is carried over exactly and the solver warm start is recomputed from it, and the eight
  maneuver decides its next steering flips from the heading measured so far;
- only the log samples are kept: a sample is taken every 1 / rate_hz s at the nearest physics step
  (exact for rates dividing the 300 Hz physics rate, such as 30 Hz); commands are held between
  samples, so the logged throttle/steering is what the car received until the next row (with a
  vehicle `latency`, what was sent: the car applies it `latency` seconds later);
- with a `stop` rule (simulator.stop) every run is braked closed-loop near an arena's walls: a run
  whose true pose triggers it is simulated again from the next sample with throttle 0, and its log
  runs on (past the maneuver's end if need be) until the car stands;
- sensor noise is drawn per maneuver from `SeedSequence(seed).spawn(len(maneuvers))[i]`, keyed by
  the maneuver's position in the list, so results never depend on the thread count. The physics,
  including the eight's heading feedback, never sees the noise: noise-free and noisy logs of a
  maneuver share one trajectory.

Columns (COLUMNS): the AutoDRIVE layout first -- timestamp (s on a virtual clock, runs laid end to
end), throttle and steering (the command held from this row to the next; steering signed, + left),
leftTicks/rightTicks (rear encoders, 1920 counts/rev, int), posX/posY/posZ (CG, m), roll/pitch/yaw
(rad, ROS ZYX angles; yaw wrapped to (-pi, pi]), speed (body-frame forward velocity, m/s),
angX/angY/angZ (gyro, rad/s; angZ is the yaw rate), accX/accY/accZ (accelerometer specific force,
m/s^2, +9.81 on z at rest) -- then time (s since the run started), maneuver (kind), direction,
op_throttle, op_steering (unsigned amplitude applied; 0 for straight), run_id (the maneuver's
name, "#2", "#3"... appended for repeats in one call) and diverged.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable, Sequence

import mujoco
import mujoco.rollout
import numpy as np
import pandas as pd

from simulator.datasheet import LOG_RATE_HZ
from simulator.errors import DivergenceError, DivergenceWarning, ManeuverError
from simulator.families import FamilyManeuver
from simulator.maneuvers import Maneuver, Replay, open_loop_steering
from simulator.noise import NoiseConfig, is_int, is_real, noisy_columns
from simulator.stop import StopRule, brake_on_trigger, end_when_standing
from simulator.vehicle import Vehicle

AUTODRIVE_COLUMNS = (
    "timestamp",
    "throttle",
    "steering",
    "leftTicks",
    "rightTicks",
    "posX",
    "posY",
    "posZ",
    "roll",
    "pitch",
    "yaw",
    "speed",
    "angX",
    "angY",
    "angZ",
    "accX",
    "accY",
    "accZ",
)
EXTRA_COLUMNS = ("time", "maneuver", "direction", "op_throttle", "op_steering", "run_id", "diverged")
COLUMNS = AUTODRIVE_COLUMNS + EXTRA_COLUMNS

MAX_TILT = math.radians(60.0)  # roll or pitch beyond this is a rollover
AIRBORNE_SAMPLES = 2  # consecutive log samples with no tyre on the floor count as airborne
_CHUNK_SECONDS = 2.0  # < one full turn of the eight at any reachable yaw rate: at most one flip a chunk
_CHUNK_BYTES = 64 * 2**20  # memory bound of one chunk's rollout outputs

ProgressCallback = Callable[[int, int], None]


class _Run:
    """Book-keeping of one maneuver during a collection."""

    def __init__(self, index: int, maneuver: Maneuver, run_id: str, n: int, vehicle: Vehicle) -> None:
        self.index = index
        self.maneuver = maneuver
        self.run_id = run_id
        self.n = n  # number of log samples
        self.throttle = np.full(n, maneuver.throttle)
        self.steering = np.zeros(n)
        self.ctrl = np.zeros((n, vehicle.model.nu))
        self.sens = np.full((n, vehicle.model.nsensordata), np.nan)
        self.state = vehicle.rest_state.copy()
        self.warmstart = np.zeros(vehicle.model.nv)
        self.diverged_at: int | None = None
        self.reason = ""
        self.airborne = 0  # consecutive airborne samples so far
        # closed-loop eight: current steering sign, unwrapped heading, heading at the start of the turn
        self.sign = maneuver.sign
        self.yaw = 0.0
        self.turn_start = 0.0
        self.flip_sample: int | None = None
        # closed-loop stop (StopRule): the run's first true pose, the sample whose pose triggered it
        self.origin: tuple[float, float, float] | None = None
        self.stopped_at: int | None = None

    def extend(self, n: int, vehicle: Vehicle) -> None:
        """Make room for n log samples (a stop runs on past the maneuver's end)."""
        extra = n - len(self.throttle)
        if extra > 0:
            self.throttle = np.concatenate([self.throttle, np.zeros(extra)])
            self.steering = np.concatenate([self.steering, np.zeros(extra)])
            self.ctrl = np.concatenate([self.ctrl, np.zeros((extra, self.ctrl.shape[1]))])
            self.sens = np.concatenate([self.sens, np.full((extra, self.sens.shape[1]), np.nan)])
        self.n = n

    @property
    def kept(self) -> int:
        """Rows to keep: all, or up to and including the first diverged sample."""
        return self.n if self.diverged_at is None else self.diverged_at + 1

    def diverge(self, sample: int, reason: str) -> None:
        if self.diverged_at is None or sample < self.diverged_at:
            self.diverged_at = sample
            self.reason = reason


class _Buffers:
    """Reusable contiguous arrays for the rollout inputs and outputs of every chunk.

    Reusing memory that is already mapped keeps page faults out of the timed rollout; a view of
    the first elements of a flat buffer is C-contiguous, as mujoco.rollout requires.
    """

    def __init__(self) -> None:
        self._flat: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        size = math.prod(shape)
        flat = self._flat.get(name)
        if flat is None or flat.size < size:
            flat = self._flat[name] = np.empty(size)
        return flat[:size].reshape(shape)


def _check_args(
    maneuvers: Sequence[Maneuver | Replay | FamilyManeuver] | Maneuver | Replay | FamilyManeuver,
    rate_hz: float,
    seed: int,
    noise: NoiseConfig | None,
    threads: int | None,
    on_divergence: str,
    physics_rate: float,
    stop: StopRule | None = None,
) -> list[Maneuver]:
    if isinstance(maneuvers, Maneuver | Replay | FamilyManeuver):
        maneuvers = [maneuvers]
    if isinstance(maneuvers, str | bytes) or not isinstance(maneuvers, Sequence):
        raise ManeuverError("maneuvers", maneuvers, "must be a sequence of Maneuver")
    for m in maneuvers:
        if not isinstance(m, Maneuver | Replay | FamilyManeuver):
            raise ManeuverError("maneuvers", m, "every item must be a Maneuver (a Replay, a FamilyManeuver)")
    if not is_real(rate_hz) or not math.isfinite(rate_hz):
        raise ManeuverError("rate_hz", rate_hz, "must be a finite number")
    if not 0.0 < rate_hz <= physics_rate + 1e-9:
        raise ManeuverError("rate_hz", rate_hz, f"must lie in (0, {physics_rate:g}] Hz (the physics rate)")
    for m in maneuvers:
        if isinstance(m, Replay) and m.rate_hz != rate_hz:
            raise ManeuverError("rate_hz", rate_hz, f"must equal replay {m.label!r}'s rate_hz {m.rate_hz:g}")
    if not is_int(seed) or seed < 0:
        raise ManeuverError("seed", seed, "must be an integer >= 0")
    if noise is not None and not isinstance(noise, NoiseConfig):
        raise ManeuverError("noise", noise, "must be a NoiseConfig or None")
    if threads is not None and (not is_int(threads) or threads < 1):
        raise ManeuverError("threads", threads, "must be an integer >= 1")
    if on_divergence not in ("warn", "raise"):
        raise ManeuverError("on_divergence", on_divergence, "must be 'warn' or 'raise'")
    if stop is not None and not isinstance(stop, StopRule):
        raise ManeuverError("stop", stop, "must be a StopRule or None")
    return list(maneuvers)


def _check_steering(
    maneuvers: list[Maneuver | Replay | FamilyManeuver], limit: float, rate_hz: float
) -> None:
    """Every maneuver's steering within the car's limit (maneuvers are built before the car is known)."""
    for m in maneuvers:
        if isinstance(m, Replay):
            largest = float(np.abs(m.steerings).max())
        elif isinstance(m, Maneuver):
            largest = m.op_steering
        else:
            largest = float(np.abs(m.controls(rate_hz)[:, 1]).max())
        if largest > limit + 1e-12:
            name = m.label if isinstance(m, Replay) else m.name
            raise ManeuverError("steering", largest, f"must be <= the car's limit {limit:g} rad ({name})")


_DEFAULT_VEHICLE: Vehicle | None = None


def _default_vehicle() -> Vehicle:
    global _DEFAULT_VEHICLE
    if _DEFAULT_VEHICLE is None:
        _DEFAULT_VEHICLE = Vehicle()
    return _DEFAULT_VEHICLE


def collect(
    maneuvers: Sequence[Maneuver | Replay | FamilyManeuver] | Maneuver | Replay | FamilyManeuver,
    *,
    rate_hz: float = LOG_RATE_HZ,
    seed: int = 0,
    noise: NoiseConfig | None = NoiseConfig(),  # noqa: B008 (a frozen dataclass: a safe shared default)
    threads: int | None = None,
    progress: ProgressCallback | None = None,
    on_divergence: str = "warn",
    vehicle: Vehicle | None = None,
    stop: StopRule | None = None,
) -> pd.DataFrame:
    """Simulate maneuvers in parallel and return their logs, one row per log sample, in COLUMNS order.

    `noise=None` (or `NoiseConfig(enabled=False)`) logs the true signals. `threads` defaults to all
    cores; the data do not depend on it. `progress(done, total)` is called after every chunk with
    counts of log samples. `vehicle` swaps in an edited model (studies, tests).

    Divergence (NaN/inf or a MuJoCo instability reset, roll or pitch beyond 60 deg, or no tyre on
    the floor for two samples) does not stop the other maneuvers: a diverged run keeps its rows up
    to the first bad sample, all flagged `diverged = True`, and is simulated no further. With
    `on_divergence="warn"` (default) a DivergenceWarning names the runs, so a long campaign keeps
    the healthy runs and decides itself what to drop; with "raise" a DivergenceError names them and
    carries the table in `.data`.

    A `Replay` (recorded commands, at `rate_hz`) runs like a maneuver of kind "replay"; a
    `FamilyManeuver` (simulator.families) runs its open-loop schedule, logged with `maneuver` = its
    family, `run_id` = its name (the parameters), `op_throttle` its median throttle and `op_steering`
    its largest |steering|.

    `stop` (a `simulator.stop.StopRule`) closes a stop at the walls of an arena around every run: once
    the run's true pose comes within `stop.distance` of the arena's boundary, the throttle is 0 (the
    brake) from the next sample on and the log runs on, past the maneuver's end if need be, until
    the car stands; a run that never comes that close is simulated as without it.
    """
    vehicle = vehicle if vehicle is not None else _default_vehicle()
    dt = vehicle.timestep
    physics_rate = 1.0 / dt
    maneuvers = _check_args(maneuvers, rate_hz, seed, noise, threads, on_divergence, physics_rate, stop)
    _check_steering(maneuvers, vehicle.steering_limit, float(rate_hz))
    rate_hz = float(rate_hz)
    if not maneuvers:
        return _empty_table()

    runs = _make_runs(maneuvers, rate_hz, vehicle)
    n_max = max(run.n for run in runs)
    settle = 0 if stop is None else max(1, math.ceil(stop.settle * rate_hz - 1e-9))
    if stop is not None:
        n_max += settle + 1  # a stopped run may log `settle` samples past its maneuver's end
    # physics step at which each log sample is taken (nearest step to k / rate_hz)
    sample_step = np.rint(np.arange(n_max + 1) * (physics_rate / rate_hz)).astype(np.int64)
    total = sum(run.n for run in runs)
    done = 0

    nthread = min(threads if threads is not None else (os.cpu_count() or 1), len(runs))
    datas = [mujoco.MjData(vehicle.model) for _ in range(nthread)]
    scratch = mujoco.MjData(vehicle.model)
    nu, nstate = vehicle.model.nu, vehicle.nstate
    nsens = vehicle.model.nsensordata
    steps_per_sample = physics_rate / rate_hz
    chunk_cap = max(1, round(_CHUNK_SECONDS * rate_hz))
    buffers = _Buffers()
    delay = vehicle.latency_steps  # 0 for the nominal car: the original code path, bit for bit
    idle = vehicle.controls(0.0, 0.0)  # the command before a run starts: the brake it settled with

    with mujoco.rollout.Rollout(nthread=nthread if nthread > 1 else 0) as roller:
        k = 0
        while True:
            active = [run for run in runs if run.diverged_at is None and run.n > k]
            if not active:
                break
            nb = len(active)
            bytes_per_sample = nb * steps_per_sample * (nstate + nsens + nu) * 8
            chunk = int(min(chunk_cap, max(1, _CHUNK_BYTES // bytes_per_sample)))
            k1 = min(k + chunk, max(run.n for run in active))
            start = int(sample_step[k])
            # the last sample of a run needs its own step; otherwise stop where sample k1 begins (always
            # there under a stop rule: a run stopped in this chunk may go on past its last sample)
            more = stop is not None or any(run.n > k1 for run in active)
            end = int(sample_step[k1]) if more else int(sample_step[k1 - 1]) + 1
            nstep = end - start
            # log sample that owns each physics step of the chunk (commands held between samples)
            owner = np.searchsorted(sample_step, np.arange(start, end), side="right") - 1

            for run in active:
                if run.maneuver.kind == "eight" and run.stopped_at is None:
                    _plan_eight(run, k, min(k1, run.n), sample_step, dt, vehicle)
            control = buffers.get("control", (nb, nstep, nu))
            init = np.empty((nb, nstate))
            warm = np.empty((nb, vehicle.model.nv))
            if delay:
                # actuation latency: step s applies the command owning step s - delay (brake before t=0)
                lagged = np.searchsorted(sample_step, np.arange(start, end) - delay, side="right") - 1
            for b, run in enumerate(active):
                control[b] = _run_controls(run, owner, lagged if delay else None, idle)
                init[b] = run.state
                warm[b] = _warmstart(vehicle, scratch, run, control[b, 0])
            state_out = buffers.get("state", (nb, nstep, nstate))
            sens_out = buffers.get("sensordata", (nb, nstep, nsens))
            _rollout(vehicle, roller, datas, init, control, nstep, warm, state_out, sens_out)

            local = sample_step[k:k1] - start
            for b, run in enumerate(active):
                kk = min(k1, run.n)
                rows = local[: kk - k]
                run.sens[k:kk] = sens_out[b, rows]
                run.state = state_out[b, -1].copy()
                times = state_out[b, rows, vehicle.state_time]
                if stop is not None:
                    n_before = run.n
                    times = _apply_stop(
                        stop, run, k, k1, times, state_out[b], start, end, sample_step, settle, vehicle,
                        roller, datas, scratch, lagged if delay else None, idle,
                    )
                    total += run.n - n_before
                    kk = min(k1, run.n)
                # a MuJoCo instability (bad qacc) resets or freezes the state: time stops matching
                expected = (sample_step[k:kk] + 1) * dt
                _check_divergence(run, k, vehicle, times[: kk - k], expected, dt)
                if run.maneuver.kind == "eight" and run.diverged_at is None and run.stopped_at is None:
                    _track_heading(run, k, kk, vehicle)
                done += (kk - k) + (run.n - kk if run.diverged_at is not None else 0)
            if progress is not None:
                progress(done, total)
            k = k1

    table = _assemble(runs, vehicle, sample_step, dt, rate_hz, seed, noise)
    diverged = [run for run in runs if run.diverged_at is not None]
    if diverged:
        names = [run.run_id for run in diverged]
        detail = "; ".join(
            f"{run.run_id} at t={sample_step[run.diverged_at] * dt:.2f} s ({run.reason})" for run in diverged
        )
        if on_divergence == "raise":
            raise DivergenceError(names, detail, data=table)
        warnings.warn(f"{len(diverged)} maneuver(s) diverged: {detail}", DivergenceWarning, stacklevel=2)
    return table


def _run_controls(run: _Run, owner: np.ndarray, lagged: np.ndarray | None, idle: np.ndarray) -> np.ndarray:
    """The run's actuator controls at the physics steps whose log samples are `owner` (commands held
    between samples, the last one after the run's end); with a latency, `lagged` are the samples whose
    commands the steps apply (< 0: before the run started, the brake `idle`)."""
    if lagged is None:
        return run.ctrl[np.minimum(owner, run.n - 1)]
    control = run.ctrl[np.clip(lagged, 0, run.n - 1)]
    control[lagged < 0] = idle
    return control


def _apply_stop(
    stop: StopRule, run: _Run, k: int, k1: int, times: np.ndarray, states: np.ndarray, start: int, end: int,
    sample_step: np.ndarray, settle: int, vehicle: Vehicle, roller: mujoco.rollout.Rollout,
    datas: list[mujoco.MjData], scratch: mujoco.MjData, lagged: np.ndarray | None, idle: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """Judge the stop rule on the run's samples k..k1-1 just simulated (states: the chunk's states,
    steps start..end-1), brake and re-simulate from the sample after a trigger, end the log where
    the braked car stands. Returns the physics times of the run's samples from k on."""
    times = times.copy()
    j = brake_on_trigger(stop, run, k, min(k1, run.n), settle, vehicle) if run.stopped_at is None else None
    if j is not None and j + 1 < k1:  # the chunk drove on after the trigger: drive its rest again, braking
        s0 = int(sample_step[j + 1])
        steps = np.arange(s0, end)
        owner = np.searchsorted(sample_step, steps, side="right") - 1
        lag = None if lagged is None else lagged[s0 - start :]
        control = _run_controls(run, owner, lag, idle)[None]
        run.state = states[s0 - start - 1].copy()
        warm = _warmstart(vehicle, scratch, run, control[0, 0])[None]
        state_out = np.empty((1, len(steps), vehicle.nstate))
        sens_out = np.empty((1, len(steps), vehicle.model.nsensordata))
        init, control = run.state[None].copy(), np.ascontiguousarray(control)
        _rollout(vehicle, roller, datas, init, control, len(steps), warm, state_out, sens_out)
        kk = min(k1, run.n)
        rows = sample_step[j + 1 : kk] - s0
        run.sens[j + 1 : kk] = sens_out[0, rows]
        run.state = state_out[0, -1].copy()
        times = np.concatenate([times[: j + 1 - k], state_out[0, rows, vehicle.state_time]])
    end_when_standing(stop, run, k, min(k1, run.n), vehicle)
    return times


def _make_runs(maneuvers: list[Maneuver], rate_hz: float, vehicle: Vehicle) -> list[_Run]:
    """One _Run per maneuver, with unique run ids and the open-loop command schedules filled in."""
    seen: dict[str, int] = {}
    runs = []
    for i, maneuver in enumerate(maneuvers):
        name = maneuver.name
        seen[name] = seen.get(name, 0) + 1
        run_id = name if seen[name] == 1 else f"{name}#{seen[name]}"
        n = maneuver.n if isinstance(maneuver, Replay) else math.floor(maneuver.duration * rate_hz + 1e-9) + 1
        run = _Run(i, maneuver, run_id, n, vehicle)
        if isinstance(maneuver, Replay):
            run.throttle = maneuver.throttles.copy()
            run.steering = maneuver.steerings.copy()
            run.ctrl = vehicle.controls(run.throttle, run.steering)
        elif isinstance(maneuver, FamilyManeuver):
            schedule = maneuver.controls(rate_hz)
            run.throttle, run.steering = schedule[:, 0].copy(), schedule[:, 1].copy()
            run.ctrl = vehicle.controls(run.throttle, run.steering)
        elif maneuver.kind != "eight":
            run.steering = open_loop_steering(maneuver, np.arange(n) / rate_hz)
            run.ctrl = vehicle.controls(run.throttle, run.steering)
        runs.append(run)
    return runs


def _steps_itself(vehicle: Vehicle) -> bool:
    """Whether the car steps its own batches (a tyre model: `simulator.tyre_car.TyreCar.rollout`)."""
    return callable(getattr(vehicle, "rollout", None))


def _rollout(
    vehicle: Vehicle, roller: mujoco.rollout.Rollout, datas: list[mujoco.MjData], init: np.ndarray,
    control: np.ndarray, nstep: int, warm: np.ndarray, state_out: np.ndarray, sens_out: np.ndarray,
) -> None:  # fmt: skip
    """Step a batch of runs `nstep` physics steps from FULLPHYSICS states under per-step controls,
    writing every step's state and sensor data: mujoco.rollout, or the car's own stepper."""
    if _steps_itself(vehicle):
        vehicle.rollout(roller, datas, init, control, nstep, state_out, sens_out)
        return
    roller.rollout(
        [vehicle.model] * len(init),
        datas,
        init,
        control,
        control_spec=mujoco.mjtState.mjSTATE_CTRL.value,
        skip_checks=True,
        nstep=nstep,
        initial_warmstart=warm,
        state=state_out,
        sensordata=sens_out,
    )


def _warmstart(vehicle: Vehicle, scratch: mujoco.MjData, run: _Run, ctrl: np.ndarray) -> np.ndarray:
    """Constraint-solver warm start for the run's next step: the accelerations at its current state
    (none for a car that steps itself: it starts every step's solver cold, so any state resumes exactly)."""
    m = vehicle.model
    if _steps_itself(vehicle):
        return run.warmstart
    mujoco.mj_setState(m, scratch, run.state, mujoco.mjtState.mjSTATE_FULLPHYSICS.value)
    scratch.ctrl[:] = ctrl
    scratch.qacc_warmstart[:] = run.warmstart
    mujoco.mj_forward(m, scratch)
    if np.all(np.isfinite(scratch.qacc)):
        run.warmstart = scratch.qacc.copy()
    else:
        run.warmstart = np.zeros(m.nv)
    return run.warmstart


def _plan_eight(run: _Run, k: int, kk: int, sample_step: np.ndarray, dt: float, vehicle: Vehicle) -> None:
    """Steering for samples k..kk-1 of an eight: flip the sign when the current turn completes 2 pi.

    The heading is extrapolated from the measured heading and yaw rate at the chunk start, so the
    flip lands on the sample where the turn completes; _track_heading then re-anchors the next turn
    on the heading actually measured at that sample.
    """
    amp = run.maneuver.op_steering
    _, yaw_rate = vehicle.yaw_and_rate(run.state)
    t0 = sample_step[k] * dt
    run.flip_sample = None
    for j in range(k, kk):
        if run.flip_sample is None:
            predicted = run.yaw + float(yaw_rate) * (sample_step[j] * dt - t0)
            if abs(predicted - run.turn_start) >= 2.0 * math.pi:
                run.sign = -run.sign
                run.flip_sample = j
        run.steering[j] = run.sign * amp
    run.ctrl[k:kk] = vehicle.controls(run.throttle[k:kk], run.steering[k:kk])


def _track_heading(run: _Run, k: int, kk: int, vehicle: Vehicle) -> None:
    """Unwrap the eight's measured heading over the chunk and re-anchor the turn at a flip."""
    yaw = vehicle.decode(run.sens[k:kk])["yaw"]
    end_yaw, _ = vehicle.yaw_and_rate(run.state)
    wrapped = np.concatenate([[run.yaw], yaw, [end_yaw]])
    unwrapped = np.unwrap(wrapped)
    # np.unwrap keeps the first value, which is the (already unwrapped) heading at the chunk start
    if run.flip_sample is not None:
        run.turn_start = float(unwrapped[1 + run.flip_sample - k])
    run.yaw = float(unwrapped[-1])


def _check_divergence(
    run: _Run, k: int, vehicle: Vehicle, times: np.ndarray, expected: np.ndarray, dt: float
) -> None:
    """Flag the first sample of this chunk that is non-finite, unstable, rolled over or airborne."""
    sens = run.sens[k : k + len(times)]
    bad = ~np.all(np.isfinite(sens), axis=1)
    if np.any(bad):
        run.diverge(k + int(np.argmax(bad)), "NaN or inf in the state")
    unstable = ~np.isfinite(times) | (np.abs(times - expected) > 0.5 * dt)
    if np.any(unstable):
        run.diverge(k + int(np.argmax(unstable)), "simulation unstable (MuJoCo reset the state)")
    if not np.all(np.isfinite(run.state)):
        run.diverge(k + len(times) - 1, "NaN or inf in the state")
    channels = vehicle.decode(np.nan_to_num(sens))
    tilted = (np.abs(channels["roll"]) > MAX_TILT) | (np.abs(channels["pitch"]) > MAX_TILT)
    if np.any(tilted):
        run.diverge(k + int(np.argmax(tilted)), "rolled over (roll or pitch beyond 60 deg)")
    for j, airborne in enumerate(np.sum(channels["contacts"], axis=1) == 0):
        run.airborne = run.airborne + 1 if airborne else 0
        if run.airborne >= AIRBORNE_SAMPLES:
            run.diverge(k + j, "all four wheels off the ground")
            break


def _assemble(
    runs: list[_Run],
    vehicle: Vehicle,
    sample_step: np.ndarray,
    dt: float,
    rate_hz: float,
    seed: int,
    noise: NoiseConfig | None,
) -> pd.DataFrame:
    """Build the sample table in COLUMNS order: true channels per run, then that run's seeded noise."""
    children = np.random.SeedSequence(seed).spawn(len(runs))
    parts: dict[str, list[np.ndarray]] = {c: [] for c in COLUMNS}
    offset = 0.0
    for run in runs:
        n = run.kept
        ch = vehicle.decode(run.sens[:n])
        time = sample_step[:n] * dt
        cols = {c: ch[c] for c in AUTODRIVE_COLUMNS if c in ch}
        with np.errstate(invalid="ignore"):
            for column, wheel in (("leftTicks", "wheel_left"), ("rightTicks", "wheel_right")):
                ticks = np.nan_to_num(ch[wheel] * (vehicle.encoder_cpr / (2.0 * np.pi)))
                cols[column] = np.rint(ticks).astype(np.int64)
        if noise is not None and noise.enabled:
            noisy_columns(cols, noise, np.random.default_rng(children[run.index]))
        m = run.maneuver
        cols.update(
            timestamp=offset + time,
            throttle=run.throttle[:n],
            steering=run.steering[:n],
            time=time,
            maneuver=np.full(n, m.kind, dtype=object),
            direction=np.full(n, m.direction, dtype=object),
            op_throttle=np.full(n, m.throttle),
            op_steering=np.full(n, m.op_steering),
            run_id=np.full(n, run.run_id, dtype=object),
            diverged=np.full(n, run.diverged_at is not None),
        )
        for c in COLUMNS:
            parts[c].append(cols[c])
        offset += run.n / rate_hz  # runs laid end to end on one virtual recording clock
    table = pd.DataFrame({c: np.concatenate(parts[c]) for c in COLUMNS})
    for c in ("maneuver", "direction", "run_id"):
        table[c] = table[c].astype("str")
    return table


def _empty_table() -> pd.DataFrame:
    """A table with no rows and the usual columns and dtypes."""
    dtypes = {c: "float64" for c in COLUMNS}
    dtypes.update(leftTicks="int64", rightTicks="int64", diverged="bool")
    dtypes.update(maneuver="str", direction="str", run_id="str")
    return pd.DataFrame({c: pd.Series(dtype=t) for c, t in dtypes.items()})[list(COLUMNS)]
