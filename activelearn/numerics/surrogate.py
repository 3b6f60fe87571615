"""Forward simulation with a trained surrogate: rates with uncertainty, integrated to a pose, with fans.

Given control sequences (throttle, signed steering) at the log rate, the surrogate predicts forward
speed v and yaw rate ω at every step and integrates the planar pose of the rear axle, which does not
slip sideways (kinematic Ackermann), then places the logged point a lever arm `a` ahead of it:

    x_r' = v cos ψ,   y_r' = v sin ψ,   ψ' = ω,   (x, y) = (x_r, y_r) + a (cos ψ, sin ψ).

The logged point (Nigel's IMU, at the CG, a = l_r = 0.0793 m) has a lateral velocity a·ω in a turn;
integrating v along the heading alone leaves 0.10-0.13 m of error on skidpads, fishhooks and eights
after 30 s even with the true rates (3-9 mm with the arm): a floor under every model's free run.

Uncertainty fans come from S sampled trajectories. Each trajectory keeps ONE posterior weight draw
for its whole length (so a path is what one plausible model would do, not a zig-zag between
models), and adds aleatoric noise at every step.

Two model variants:
  * static ("controls"): rates are a function of the current controls. Nothing depends on the past,
    so maneuvers are independent and a control row repeated at consecutive steps is evaluated once
    (skidpads, straights and eights hold a handful of rows for thousands of steps). A compiled
    kernel (`activelearn.numerics.native`, its threads taking one maneuver at a time) evaluates the S
    network draws on a tile of steps' distinct rows, then noises (each step's noise a function of
    its counter) and integrates the S trajectories of that tile while it is in cache; a torch and
    NumPy reference computes the same numbers where no C compiler is.
  * dynamic (Markov "controls+rates", a "history" delay embedding, the recurrent model): rates also
    depend on past controls and rates (`activelearn.numerics.lags` says which). The rollout is
    sequential in time but batched over maneuvers and samples; each trajectory feeds its own sampled
    rates back in, so the fans propagate the uncertainty.

How far these free runs drift and how wide their fans must be: `activelearn.numerics.diagnostics`.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from activelearn.errors import InputError
from activelearn.names import POS_X, POS_Y, YAW, YAW_RATE
from activelearn.numerics import buffers, counter_noise, native
from activelearn.numerics.lags import Lags, model_lags
from activelearn.numerics.models.base import BACKENDS, CHUNK_ROWS, draw_moments
from activelearn.numerics.pose import integrate_pose
from activelearn.numerics.threads import even_blocks, intra_op_threads, parallel_map

N_CONTROLS = 2
BANDS = (0.025, 0.25, 0.5, 0.75, 0.975)  # quantiles of the 95% and 50% bands and the median
MAX_LEVER_ARM = 10.0  # m: a logged point lies within a car's length of its rear axle


@dataclass(frozen=True)
class Rollout:
    """Sampled surrogate trajectories of M maneuvers over T steps with S samples.

    Arrays are (S, M, T): `v`, `w` (sampled rates, aleatoric noise included), `x`, `y`, `yaw`
    (integrated pose). `mean_v`, `mean_w`, `epistemic_var`, `aleatoric_var` are (M, T, 2)-style
    summaries of the predictive distribution at each step (no noise sampling). `lengths` gives each
    maneuver's number of valid steps (shorter maneuvers are padded by repeating their last control).
    """

    dt: float
    v: np.ndarray
    w: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    mean_rates: np.ndarray  # (M, T, 2) predictive mean of (v, ω)
    aleatoric_var: np.ndarray  # (M, T, 2)
    epistemic_var: np.ndarray  # (M, T, 2)
    lengths: np.ndarray

    @property
    def time(self) -> np.ndarray:
        """(T,) seconds since the start."""
        return np.arange(self.v.shape[-1]) * self.dt

    def quantiles(self, name: str, index: int | None = None) -> np.ndarray:
        """Quantiles 2.5, 25, 50, 75, 97.5 % over samples of `v`, `w`, `x`, `y` or `yaw`.

        (5, M, T) for every maneuver, or (5, T) for maneuver `index` alone (much cheaper: the sort
        over samples is the cost, so per-maneuver callers should not sort all M).
        """
        values = getattr(self, name)
        return np.quantile(values if index is None else values[:, index], BANDS, axis=0)

    def mean_path(self, index: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Mean x and y over samples: (M, T) each, or (T,) for maneuver `index` alone."""
        if index is None:
            return self.x.mean(axis=0), self.y.mean(axis=0)
        return self.x[:, index].mean(axis=0), self.y[:, index].mean(axis=0)


def _stack(controls: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Pad control sequences to one (M, T, 2) array by repeating each last row; return it and lengths."""
    if not controls:
        raise InputError("controls", 0, "give at least one control sequence")
    lengths = np.array([len(c) for c in controls])
    if lengths.min() < 1:
        raise InputError("controls", int(lengths.min()), "every control sequence needs at least one step")
    out = np.empty((len(controls), int(lengths.max()), N_CONTROLS))
    for i, c in enumerate(controls):
        c = np.asarray(c, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != N_CONTROLS:
            raise InputError("controls", c.shape, "each control sequence must have shape (T, 2)")
        if not np.isfinite(c).all():
            raise InputError("controls", i, "control sequences must be finite")
        out[i, : len(c)] = c
        out[i, len(c) :] = c[-1]
    return out, lengths


def path_from_rates(
    v: np.ndarray, w: np.ndarray, *, dt: float, lever_arm: float = 0.0, yaw0: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pose (x, y, ψ) a sequence of rates (T,) drives, relative to its start, as free runs place it.

    The same integration as `simulate`'s (the logged point `lever_arm` metres ahead of the rear axle):
    for paths from any rates, e.g. MuJoCo's true v with a model's ω, to see which rate an error is in.
    """
    v_, w_ = (torch.from_numpy(np.array(a, dtype=np.float64))[None] for a in (v, w))
    start = torch.full((1, 1), float(yaw0), dtype=torch.float64)
    x, y, yaw = integrate_pose(v_, w_, dt, start, lever_arm=lever_arm)
    return x[0].numpy(), y[0].numpy(), yaw[0].numpy()


def _distinct_rows(controls: np.ndarray) -> tuple[np.ndarray, torch.Tensor]:
    """Rows of (M, T, 2) controls where the control changed from the step before, and each step's index.

    Skidpads, straights and eights hold a handful of rows for thousands of steps; consecutive
    repeats are evaluated once. The index never decreases, so spreading results back to the steps
    reads memory in order.
    """
    flat = np.ascontiguousarray(controls.reshape(-1, N_CONTROLS), dtype=np.float64)
    as_one = flat.view(np.complex128).ravel()  # a (throttle, steering) row as one comparable number
    changed = np.empty(len(as_one), dtype=bool)
    changed[0] = True
    np.not_equal(as_one[1:], as_one[:-1], out=changed[1:])
    return flat[changed], torch.as_tensor(np.cumsum(changed) - 1)


def _static_rollout(
    model,
    controls: np.ndarray,
    n_samples: int,
    gen: torch.Generator,
    dt: float,
    yaw0,
    backend: str,
    lever_arm: float,
):
    """Sampled trajectories of a static model: rates and pose, each (S, M, T), and per-step moments.

    One posterior draw per trajectory; each trajectory's aleatoric noise comes from counters under
    its own key (`activelearn.numerics.counter_noise`), so the result depends neither on the thread count
    nor on the backend. Native: the compiled kernel evaluates the network on each tile's distinct
    control rows and noises and integrates that tile at once, its threads taking one maneuver at a
    time. Reference: torch evaluates every distinct control row, NumPy/torch the rest.
    """
    seed = int(torch.randint(2**31 - 1, (1,), generator=gen))
    keys = torch.randint(2**62, (n_samples,), generator=gen).tolist()
    sampled = model.draw(n_samples, seed=seed, backend=backend)
    # The fused kernel reads the two controls; a model that derives inputs from them (the kinematic
    # feature) takes the block path, whose network evaluation is still the compiled one.
    if sampled.kernel is None or model.n_derived:
        return _reference_rollout(sampled, controls, keys, dt, yaw0, lever_arm)
    n_maneuvers, n_steps, _ = controls.shape
    # Reused memory where an earlier rollout's arrays have been dropped: first-touch page faults
    # of 440 MB of fans cost a third of a 256-maneuver rollout (`activelearn.numerics.buffers`).
    paths = tuple(buffers.empty((n_samples, n_maneuvers, n_steps)) for _ in range(5))
    moments = tuple(buffers.empty((n_maneuvers, n_steps, 2)) for _ in range(3))
    native.static_rollout(
        sampled.kernel,
        np.ascontiguousarray(controls, dtype=np.float32),
        yaw0,
        np.array(keys, dtype=np.uint64),
        dt,
        paths,
        moments,
        out_mean=model.y_mean.numpy(),
        out_std=model.y_std.numpy(),
        spread=sampled.spread,
        lever_arm=lever_arm,
        threads=torch.get_num_threads(),
    )
    return paths, tuple(torch.from_numpy(m) for m in moments)


def _reference_rollout(
    sampled, controls: np.ndarray, keys: list[int], dt: float, yaw0: np.ndarray, lever_arm: float
):
    """`_static_rollout` in torch and NumPy: each distinct control row through the network, then the paths."""
    n_maneuvers, n_steps, _ = controls.shape
    unique, index = _distinct_rows(controls)
    inputs = torch.as_tensor(unique.T, dtype=torch.float32)
    n_unique = inputs.shape[1]
    means, variances = (torch.empty((sampled.n_samples, 2, n_unique)) for _ in range(2))
    centre, aleatoric, epistemic = (torch.empty((2, n_unique)) for _ in range(3))
    for rows in even_blocks(n_unique, CHUNK_ROWS):
        sampled.block(
            inputs[:, rows],
            out=(means[..., rows], variances[..., rows]),
            moments=(centre[:, rows], aleatoric[:, rows], epistemic[:, rows]),
        )
    shape = (n_maneuvers, n_steps)
    paths = _reference_trajectories(
        means.numpy(), variances.numpy(), index.numpy(), keys, shape, dt, yaw0, lever_arm
    )

    def per_step(moment: torch.Tensor) -> torch.Tensor:  # (2, U) → (M, T, 2)
        return moment.index_select(1, index).t().reshape(n_maneuvers, n_steps, 2)

    return paths, (per_step(centre), per_step(aleatoric), per_step(epistemic))


def _reference_trajectories(
    means, variances, index, keys, shape, dt, yaw0, lever_arm
) -> tuple[np.ndarray, ...]:
    """What the compiled kernel computes, in NumPy and torch: the fallback without a C compiler."""
    n_maneuvers, n_steps = shape
    means, std, index = torch.from_numpy(means), torch.from_numpy(variances).sqrt(), torch.from_numpy(index)
    start = torch.from_numpy(yaw0)[:, None]
    paths = tuple(torch.empty((len(keys), n_maneuvers, n_steps)) for _ in range(5))

    def trajectory(s: int) -> None:
        v, w, x, y, yaw = (p[s] for p in paths)
        noise = counter_noise.step_noise(keys[s], n_maneuvers, n_steps)
        for j, (rate, z) in enumerate(zip((v, w), noise, strict=True)):
            rate.copy_(torch.from_numpy(z))
            mean_at, std_at = (m[s, j].index_select(0, index).view_as(rate) for m in (means, std))
            torch.addcmul(mean_at, std_at, rate, out=rate)
        integrate_pose(v, w, dt, start, out=(x, y, yaw), lever_arm=lever_arm)

    parallel_map(trajectory, range(len(keys)))
    return tuple(p.numpy() for p in paths)


def simulate(
    model,
    controls: Sequence[np.ndarray],
    *,
    rate_hz: float,
    n_samples: int = 32,
    seed: int = 0,
    initial_rates: np.ndarray | None = None,
    initial_yaw: np.ndarray | float = 0.0,
    backend: str = "auto",
    lever_arm: float | None = None,
    fan_scale: float | None = None,
) -> Rollout:
    """Forward-simulate `model` along control sequences (each (T, 2) at `rate_hz`) with S samples.

    `initial_rates` (M, 2) seeds a dynamic model's past rates (default: standing still; its past
    controls are the first control);
    `initial_yaw` is one heading or one per maneuver. Positions are those of the logged point,
    `lever_arm` metres ahead of the rear axle (default: the model's `[model] pose_lever_arm`).
    `fan_scale` scales each sampled pose's (x, y, ψ)
    deviation from the mean over samples, so the pose fan widens about an unchanged mean path
    (default: the model's `fan_scale`, fitted by `calibrate_fan`; 1 leaves the fan as the posterior
    and the noise make it; rates are never scaled). Deterministic for a given seed.

    `backend` picks the compiled kernels ("native": network, noise and pose fused per tile for a
    static model; the network kernel for a Markov one), torch and NumPy ("reference", 3-4x slower)
    or "auto" (native where a C compiler built it). Both draw the same numbers, so they agree up
    to float rounding.
    """
    if n_samples < 2:
        raise InputError("n_samples", n_samples, "must be at least 2 to form bands")
    if not rate_hz > 0:
        raise InputError("rate_hz", rate_hz, "must be positive")
    if backend not in BACKENDS:
        raise InputError("backend", backend, f"must be one of {', '.join(BACKENDS)}")
    stacked, lengths = _stack(controls)
    try:
        start_yaw = np.broadcast_to(np.asarray(initial_yaw, dtype=np.float32), (len(stacked),)).copy()
    except ValueError:
        raise InputError(
            "initial_yaw", np.shape(initial_yaw), f"give one heading or one per maneuver ({len(stacked)})"
        ) from None
    if lever_arm is None:
        lever_arm = float(model.config.pose_lever_arm)
    if not (np.isfinite(lever_arm) and abs(lever_arm) <= MAX_LEVER_ARM):
        raise InputError("lever_arm", lever_arm, f"must be finite and at most {MAX_LEVER_ARM} m in size")
    fan_scale = float(model.fan_scale) if fan_scale is None else float(fan_scale)
    if not (np.isfinite(fan_scale) and fan_scale > 0):
        raise InputError("fan_scale", fan_scale, "must be a positive number")
    dt = 1.0 / rate_hz
    gen = torch.Generator().manual_seed(int(seed))
    try:
        lags = model_lags(model)
    except ValueError as exc:
        raise InputError("model.n_inputs", int(model.n_inputs), str(exc)) from None
    with torch.no_grad():
        if lags is None:
            (v, w, x, y, yaw), (mean_rates, aleatoric, epistemic) = _static_rollout(
                model, stacked, n_samples, gen, dt, start_yaw, backend, lever_arm
            )
        else:
            (v, w), (mean_rates, aleatoric, epistemic), pose = _sequential_rollout(
                model, stacked, n_samples, gen, initial_rates, lags, backend, pose=(dt, start_yaw, lever_arm)
            )
            if pose is None:
                pose = integrate_pose(v, w, dt, torch.from_numpy(start_yaw)[:, None], lever_arm=lever_arm)
            v, w, x, y, yaw = (np.asarray(p) for p in (v, w, *pose))
    if fan_scale != 1.0:
        _widen_about_the_mean((x, y, yaw), fan_scale)
    return Rollout(
        dt=dt,
        v=v,
        w=w,
        x=x,
        y=y,
        yaw=yaw,
        mean_rates=mean_rates.numpy(),
        aleatoric_var=aleatoric.numpy(),
        epistemic_var=epistemic.numpy(),
        lengths=lengths,
    )


def _widen_about_the_mean(paths: Sequence[np.ndarray], fan_scale: float) -> None:
    """Scale each sampled pose's deviation from the mean over samples by `fan_scale`, in place."""
    for path in paths:
        mean = path.mean(axis=0)
        path -= mean
        path *= fan_scale
        path += mean


def _sequential_rollout(
    model,
    controls: np.ndarray,
    n_samples: int,
    gen: torch.Generator,
    initial_rates,
    lags: Lags,
    backend: str = "auto",
    pose: tuple[float, np.ndarray, float] | None = None,
):
    """Sequential rollout of a dynamic model: inputs are the lagged controls and rates of `lags`.

    Each trajectory feeds its own sampled rates (aleatoric noise included) back in, so the spread of
    the fan grows with the uncertainty it propagates. Before the first step the past rates are
    `initial_rates` and the past controls the first control. Moments are over the S trajectories per
    step. Maneuvers are independent, so each thread-pool task runs every step of its own block of
    maneuvers (no per-step synchronisation: 2 700 steps of hand-offs cost more than the kernel).
    Returns the rates (v, w), the moments, and the pose (x, y, yaw) where a kind's whole-run kernel
    integrated it for `pose` = (dt, headings, lever arm), else None.
    """
    n_maneuvers, n_steps, _ = controls.shape
    seed = int(torch.randint(2**31 - 1, (1,), generator=gen))
    # Column layout throughout: inputs (S, 4k, M), rates (S, 2, M) per step.
    start = torch.zeros((n_samples, 2, n_maneuvers))
    if initial_rates is not None:
        start[:] = torch.as_tensor(np.asarray(initial_rates, dtype=np.float32)).t()
    # A kind whose learnt part reads the controls alone computes its free runs whole (its noise from
    # the draws' seed, so `gen` is left as the step loop below finds it).
    whole = model.open_loop_free_runs(n_samples, seed, controls, start, lags, backend, pose)
    if whole is not None:
        rates, moments, paths = whole
        return (rates[:, 0], rates[:, 1]), moments, paths
    sampled_model = model.draw(n_samples, seed=seed, backend=backend)
    step_controls = torch.as_tensor(controls, dtype=torch.float32).permute(1, 2, 0).contiguous()  # (T, 2, M)
    noise = torch.randn((n_steps, n_samples, n_maneuvers, 2), generator=gen).transpose(2, 3)
    # Sampled rates are written straight into their (S, 2, M, T) home and the moments per step into
    # (T, 2, M): no (T, S, 2, M) arrays of every draw's mean and variance, and no transposes of them.
    rates = torch.empty((n_samples, 2, n_maneuvers, n_steps))
    moments = tuple(torch.empty((n_steps, 2, n_maneuvers)) for _ in range(3))
    n_ctrl = N_CONTROLS * lags.history  # rate inputs start here
    spread = sampled_model.spread

    @torch.no_grad()  # grad mode is per thread: the pool's threads do not inherit the caller's
    def run(block: slice) -> None:
        width = block.stop - block.start
        inputs = torch.empty((n_samples, lags.n_inputs, width))
        means, variances = (torch.empty((n_samples, 2, width)) for _ in range(2))
        for k in range(n_steps):
            for j, back in enumerate(lags.control_lags):
                inputs[:, 2 * j : 2 * j + 2] = step_controls[max(k - back, 0), :, block]
            for j, back in enumerate(lags.rate_lags):
                past = rates[:, :, block, k - back] if k >= back else start[..., block]
                inputs[:, n_ctrl + 2 * j : n_ctrl + 2 * j + 2] = past
            step_moments = tuple(m[k, :, block] for m in moments)
            if spread == 1.0:
                sampled_model.block(inputs, out=(means, variances), moments=step_moments)
            else:
                widened_step(sampled_model, inputs, (means, variances), step_moments, spread)
            torch.addcmul(means, noise[k, ..., block], variances.sqrt_(), out=rates[:, :, block, k])

    if sampled_model.kernel is None:
        # Torch: blocks of a fixed size (so the numbers do not depend on the thread count) on the
        # thread pool, one intra-op thread each. Torch's own intra-op threads sync at every one of
        # the thousands of small ops: 13x slower on a busy 2-core machine (recurrent model, measured).
        # A model whose step is many small ops (the physics kind) amortises them over wider blocks.
        # A lone block (at most `rollout_block` maneuvers: a quick run's fans, a round's new maneuvers)
        # runs on the calling thread, also on one intra-op thread: with two, its small ops spun and
        # stalled (physics model, 18 maneuvers x 10 s, S = 8, busy 2-core machine: 0.2-8 s against
        # 0.08-0.15 s; the same numbers bit for bit).
        workers = torch.get_num_threads()  # read before the block sets it to 1
        with intra_op_threads(1):
            parallel_map(run, even_blocks(n_maneuvers, model.rollout_block), workers)
    else:
        parallel_map(run, even_blocks(n_maneuvers, -(-n_maneuvers // torch.get_num_threads())))
    # (T, 2, M) → (M, T, 2); v and ω are (S, M, T) views of the rates.
    return (rates[:, 0], rates[:, 1]), tuple(m.permute(2, 0, 1).contiguous() for m in moments), None


def widened_step(
    sampled_model, inputs: torch.Tensor, out: tuple[torch.Tensor, torch.Tensor],
    moments: tuple[torch.Tensor, torch.Tensor, torch.Tensor], spread: float,
) -> None:  # fmt: skip
    """One free-run step with each draw's epistemic deviation widened by `spread`, into `out`.

    Each draw steps from its own past, and only the deviation of its *function* from the average
    draw's is widened: that deviation is read at the draws' common input (their inputs' average), so
    the draws' differing pasts are carried forward as they are, not widened again at every step.
    Widening every draw's whole deviation instead compounds: a draw ahead of the others by d one step
    is ahead by spread · a · d the next (a: how much of its past a step keeps), which diverges once
    spread · a > 1 (the [safety] fan's spread of 3 drove a physics model's yaw rate to 10^8-10^31
    rad/s over 30-90 s of reverse driving, where its draws unwidened stayed within 0.6 rad/s).
    """
    means, variances = out
    sampled_model.block(inputs, out=out, spread=1.0)
    common = inputs.mean(dim=0, keepdim=True).expand_as(inputs).contiguous()
    at_common, _ = sampled_model.block(common, spread=1.0)
    means.add_(at_common - at_common.mean(dim=0, keepdim=True), alpha=spread - 1.0)
    draw_moments(means, variances, moments)


def estimate_lever_arm(logs: Sequence, *, rate_hz: float, min_yaw_rate: float = 0.2) -> float:
    """Where the logged pose lies ahead of the rear axle (m), from logs' positions, heading and ω.

    A kinematic car's rear axle does not slip sideways, so the logged point's sideways velocity in
    the body frame is a·ω: a least-squares fit over the turning steps (|ω| >= `min_yaw_rate`, rad/s).
    Tells `[model] pose_lever_arm` for a car whose pose reference is not documented.
    """
    lateral, rates = [], []
    for table in logs:
        x, y = (table[c].to_numpy(dtype=np.float64) for c in (POS_X, POS_Y))
        yaw, w = np.unwrap(table[YAW].to_numpy(dtype=np.float64)), table[YAW_RATE].to_numpy(dtype=np.float64)
        if len(x) < 3:
            continue
        vx, vy = np.gradient(x) * rate_hz, np.gradient(y) * rate_hz
        sideways = -np.sin(yaw) * vx + np.cos(yaw) * vy
        turning = np.abs(w) >= min_yaw_rate
        lateral.append(sideways[turning])
        rates.append(w[turning])
    w_all = np.concatenate(rates) if rates else np.empty(0)
    if len(w_all) < 10:
        raise InputError("logs", len(w_all), f"need at least 10 steps turning at |ω| >= {min_yaw_rate} rad/s")
    return float(np.dot(w_all, np.concatenate(lateral)) / np.dot(w_all, w_all))


class SteadyStates:
    """The last few `steady_state_inputs` results, by model state, controls and settings.

    A round asks for the same steady states more than once: the evaluation grid for the round's
    metrics and again for its figure, the target region for the pool and again for the pool [safety]
    rebuilds with cut candidates. The key is the model's content (its state dict, its configuration
    and the plain attributes of each of its modules, such as the physics kind's `corrected`), not the
    object, so a model changed in place is computed anew. A hit returns a copy of the very array the
    miss computed: the same numbers, bit for bit. `misses` counts the computations (tests read it).
    """

    def __init__(self, size: int = 16) -> None:
        self.size = size
        self.misses = 0
        self._entries: OrderedDict[bytes, np.ndarray] = OrderedDict()

    @staticmethod
    def key(model, controls: np.ndarray, steps: int, n_samples: int) -> bytes:
        """A digest of everything the steady state depends on."""
        digest = hashlib.blake2b(digest_size=20)
        for module in model.modules():
            plain = sorted((k, v) for k, v in vars(module).items() if isinstance(v, bool | int | float | str))
            digest.update(f"{type(module).__qualname__}{getattr(module, 'config', None)!r}{plain!r}".encode())
        for name, tensor in model.state_dict().items():
            digest.update(name.encode())
            digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
        digest.update(f"{controls.shape}{steps},{n_samples}".encode())
        digest.update(controls.tobytes())
        return digest.digest()

    def get(self, key: bytes) -> np.ndarray | None:
        """A copy of the stored result, or None."""
        found = self._entries.get(key)
        if found is None:
            return None
        self._entries.move_to_end(key)
        return found.copy()

    def put(self, key: bytes, value: np.ndarray) -> None:
        """Store a result (the oldest is dropped beyond `size`)."""
        self.misses += 1
        self._entries[key] = value.copy()
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)


STEADY_STATES = SteadyStates()


def steady_state_inputs(model, controls: np.ndarray, *, steps: int = 60, n_samples: int = 8) -> np.ndarray:
    """Inputs of a dynamic model at the rates it settles to under constant `controls`.

    Acquisition and uncertainty maps score controls; a dynamic model also needs the rates it would be
    in. Holding each control for `steps` iterations from standstill and feeding back the
    posterior-mean rates (every lag of the history holds the same control and rates once settled)
    gives the quasi-steady state, a fair stand-in for slowly varying maneuvers (fishhook, skidpad,
    straight) and an approximation for slalom and eight. Results are kept (`STEADY_STATES`): the same
    model state and controls are computed once.
    """
    controls = np.asarray(controls, dtype=np.float32)
    key = STEADY_STATES.key(model, controls, steps, n_samples)
    found = STEADY_STATES.get(key)
    if found is not None:
        return found
    lags = model_lags(model)
    history = 1 if lags is None else lags.history
    # One intra-op thread: the steps are small ops (S x rows elements, below torch's grain size), and
    # on a busy 2-core machine torch's second OpenMP thread only spins and stalls them. Measured with
    # safe_track.toml's physics model, 225 rows, 15 calls each: 2 threads median 0.09 s, worst 7.4 s
    # (spikes of 2-10 s in every round of a campaign); 1 thread median 0.025 s, worst 0.06 s; the same
    # numbers bit for bit (element-wise ops, and GEMMs of the same shapes).
    with torch.no_grad(), intra_op_threads(1):
        sampled = model.draw(n_samples, seed=0)
        ctrl = torch.as_tensor(controls).repeat(1, history)
        rates = torch.zeros((len(controls), 2))

        def window() -> torch.Tensor:
            return torch.cat([ctrl, rates.repeat(1, history)], dim=-1)

        for _ in range(steps):
            means, _ = sampled(window())
            rates = means.mean(dim=0)
        out = window().numpy().astype(np.float64)
    STEADY_STATES.put(key, out)
    return out


def model_inputs(model, controls: np.ndarray) -> np.ndarray:
    """Controls as model inputs: unchanged for a static model, with quasi-steady rates for a dynamic one."""
    return (
        np.asarray(controls, dtype=np.float64)
        if model.n_inputs == N_CONTROLS
        else steady_state_inputs(model, controls)
    )
