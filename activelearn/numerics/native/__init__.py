"""Compiled kernels, built on first use with the machine's C compiler and loaded through ctypes.

Four fused loops that no library provides:
  * `network.c`: S sampled weight sets of a layer stack evaluated tile by tile with the activations
    in L1, the head and the moments over draws included (`NetworkKernel`), where torch writes every
    layer's (S x width x rows) output to memory and reads it back;
  * `static_rollout.c`: the static surrogate's S trajectories, per tile of steps the network on the
    tile's distinct control rows, then each draw's noise, rates and pose while the tile is in cache
    (`static_rollout`), replacing a chain of torch passes over multi-MB arrays.
  * `physics_rollout.c`: the physics-structured surrogate's S free runs when its correction reads
    the control alone: per tile the correction on the distinct control rows, then the single
    track's recurrence, the moments and the noise per step (`physics_rollout`);
  * `dynamic_rollout.c`: the dynamic single track's rates along free runs, many parameter sets at
    once in double precision (`dynamic_rate_runs`, what an identification's search spends its time
    on), and the physics kind's S free runs on that core in float, with their poses
    (`dynamic_free_runs`); its substep is `dynamic_substep.h`, a template included once per precision.
All start their own threads (`threads` arguments), which take chunks of work from a shared counter.

They are compiled once per machine by `simulator.cbuild` (sources, flags, compiler and CPU features form
the cache key) into `CACHE_DIR` (`~/.cache/activelearn/native`; a temporary directory if that is not
writable), and written atomically. The build costs ~40 s of CPU (`dynamic_rollout.c` nearly all of
it), so one process builds while the others (a comparison's workers on a fresh machine) wait on a lock
beside it, then load its library.

Without a working C compiler `library()` returns None once with a warning, and callers take their
NumPy/torch path, which computes the same numbers (up to float rounding) but runs slower;
`simulate(..., backend="reference")` picks that path explicitly.
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

import numpy as np

from simulator import cbuild

SOURCES = tuple(
    Path(__file__).with_name(name)
    for name in ("static_rollout.c", "network.c", "physics_rollout.c", "dynamic_rollout.c")
)
# part of the cache key, not compiled on their own
HEADERS = tuple(Path(__file__).with_name(name) for name in ("network.h", "dynamic_substep.h"))
# Compile flags. -ffast-math lets GCC vectorise logf/sinf/cosf through glibc's libmvec; -march=native
# is safe because the cache key includes this machine's CPU features.
FLAGS = ("-O3", "-ffast-math", "-march=native", "-fPIC", "-pthread")
# Link flags: no -ffast-math here. Linked with it, GCC adds crtfastmath.o, whose constructor sets the
# CPU's flush-to-zero and denormals-are-zero modes for the whole process when the library loads:
# numpy's and torch's subnormal numbers would then read as 0 in every computation after it.
LINK_FLAGS = ("-shared", "-pthread")
LINK_OPTIONS = (("-lmvec", "-lm"), ("-lm",))  # libmvec is glibc's; elsewhere the scalar libm serves
COMPILERS = cbuild.COMPILERS  # the first found on PATH builds the kernels
CACHE_DIR = cbuild.CACHE_DIR

# Array arguments travel as plain addresses (c_void_p): `array.ctypes.data` costs half of
# `data_as(POINTER(c_float))`, and a predict call passes a dozen of them.
_ptr = ctypes.c_void_p
_u32 = ctypes.POINTER(ctypes.c_uint32)


class _Layer(ctypes.Structure):
    """network.c's al_layer."""

    _fields_ = [
        ("n_in", ctypes.c_int64),
        ("n_out", ctypes.c_int64),
        ("per_sample", ctypes.c_int64),
        ("activation", ctypes.c_int64),
        ("weight", _ptr),
        ("bias", _ptr),
    ]


class _Network(ctypes.Structure):
    """network.c's al_network."""

    _fields_ = [
        ("n_layers", ctypes.c_int64),
        ("n_samples", ctypes.c_int64),
        ("n_inputs", ctypes.c_int64),
        ("n_outputs", ctypes.c_int64),
        ("layers", ctypes.POINTER(_Layer)),
        ("x_mean", _ptr),
        ("x_std", _ptr),
        ("gaussian_head", ctypes.c_int64),
        ("min_std", ctypes.c_float),
        ("head_var", _ptr),
    ]


class _Outputs(ctypes.Structure):
    """network.c's al_outputs."""

    _fields_ = [
        ("means", _ptr),
        ("variances", _ptr),
        ("ld_draws", ctypes.c_int64),
        ("centre", _ptr),
        ("aleatoric", _ptr),
        ("epistemic", _ptr),
        ("ld_moments", ctypes.c_int64),
        ("out_mean", _ptr),
        ("out_std", _ptr),
        ("spread", ctypes.c_float),
    ]


SIGNATURES = {
    "al_tile": ([], ctypes.c_int),
    "al_philox4x32_10": ([_u32, _u32, _u32], None),
    "al_static_rollout": (
        [ctypes.POINTER(_Network), ctypes.POINTER(_Outputs), ctypes.c_int64, ctypes.c_int64]
        + [ctypes.c_float, ctypes.c_float, _ptr, _ptr, ctypes.c_int64, _ptr, ctypes.c_int64]
        + [_ptr] * 8
        + [ctypes.c_int64],
        ctypes.c_int,
    ),
    "al_physics_parameter_count": ([], ctypes.c_int),
    "al_physics_rollout": (
        [ctypes.POINTER(_Network), _ptr, ctypes.c_int64, ctypes.c_int64, ctypes.c_int64]
        + [_ptr] * 7
        + [ctypes.c_float, ctypes.c_float]
        + [_ptr] * 4
        + [ctypes.c_int64],
        ctypes.c_int,
    ),
    "al_kinematic_car_count": ([], ctypes.c_int),
    "al_kinematic_rate_runs": ([_ptr, _ptr, *[ctypes.c_int64] * 3, _ptr, _ptr, ctypes.c_double, _ptr], None),
    "al_dynamic_car_count": ([], ctypes.c_int),
    "al_dynamic_set_count": ([], ctypes.c_int),
    "al_dynamic_wheel_pass_choice": ([ctypes.c_int], ctypes.c_int),
    "al_dynamic_rate_runs": (
        [_ptr] * 4 + [ctypes.c_int64] * 4 + [_ptr] * 2 + [ctypes.c_double] + [ctypes.c_int64] * 2
        + [_ptr, ctypes.c_int64],
        ctypes.c_int,
    ),
    "al_dynamic_limit_count": ([], ctypes.c_int),
    "al_dynamic_free_runs": (
        [_ptr] * 4 + [ctypes.c_int64, _ptr] + [ctypes.c_int64] * 4 + [ctypes.c_double]
        + [ctypes.c_int64] * 3 + [ctypes.c_double] + [_ptr] * 11
        + [ctypes.c_float] * 2 + [ctypes.c_double] + [_ptr] * 5 + [ctypes.c_int64],
        ctypes.c_int,
    ),
    "al_network_forward": (
        [
            ctypes.POINTER(_Network),
            ctypes.c_int64,  # rows
            _ptr,  # x
            ctypes.c_int64,  # ld_x
            ctypes.c_int64,  # x_per_sample
            ctypes.POINTER(_Outputs),
            ctypes.c_int64,  # threads
        ],
        ctypes.c_int,
    ),
}
ACTIVATION_CODES = {None: 0, "relu": 1, "tanh": 2, "sigmoid": 3, "elu": 4, "selu": 5, "softplus": 6}


def _compiler() -> str:
    return cbuild.find_compiler(COMPILERS)


def _build(compiler: str) -> Path:
    """Compile the kernel into the cache (or find it there) and return the library's path.

    Sources are compiled to objects with `FLAGS`, then linked with `LINK_FLAGS` (see there why apart).
    """
    recipe = cbuild.Recipe("kernels", SOURCES, HEADERS, FLAGS, LINK_FLAGS, LINK_OPTIONS)
    return cbuild.build(recipe, compiler, CACHE_DIR)


@functools.cache
def library() -> ctypes.CDLL | None:
    """The compiled kernels, or None (warned once) where they cannot be built."""
    unavailable = "activelearn: compiled kernel unavailable; using the slower NumPy/torch path"
    lib = cbuild.load(lambda: _build(_compiler()), unavailable)
    if lib is None:
        return None
    for name, (argtypes, restype) in SIGNATURES.items():
        function = getattr(lib, name)
        function.argtypes, function.restype = argtypes, restype
    return lib


def _address(array: np.ndarray | None) -> int | None:
    """Where an array's data starts (None for no array: a NULL pointer)."""
    return None if array is None else array.ctypes.data


def _unit_stride(array: np.ndarray) -> bool:
    """Consecutive along the last axis (a length-1 axis has any stride)."""
    return array.shape[-1] == 1 or array.strides[-1] == array.itemsize


class NetworkKernel:
    """S sampled weight sets of a layer stack packed for `al_network_forward` (network.c).

    `layers` lists (weight, bias, per_sample, activation) per layer: weight (in, out) and bias (out,)
    shared by every draw, or (S, in, out) and (S, out) per draw (torch's layouts); activation is a
    name or None (the last layer gets none). The head is Gaussian (the last layer gives mean and
    raw scale, variance (softplus(raw) + min_std)²) when `head_var` is None, else a fixed
    standardised variance per output. The kernel standardises inputs with `x_mean`, `x_std`.
    Arrays are copied to contiguous float32 and kept alive with the instance.
    """

    def __init__(
        self,
        lib: ctypes.CDLL,
        layers: list[tuple[np.ndarray, np.ndarray, bool, str | None]],
        *,
        n_samples: int,
        x_mean: np.ndarray,
        x_std: np.ndarray,
        min_std: float,
        head_var: np.ndarray | None,
    ) -> None:
        self.lib = lib
        self._keep: list[np.ndarray] = []
        packed = (_Layer * len(layers))()
        for slot, (weight, bias, per_sample, activation) in zip(packed, layers, strict=True):
            w, b = self._own(weight), self._own(bias)
            slot.n_in, slot.n_out = w.shape[-2], w.shape[-1]
            slot.per_sample, slot.activation = int(per_sample), ACTIVATION_CODES[activation]
            slot.weight, slot.bias = _address(w), _address(b)
        self._layers = packed  # self.net points into it
        self.net = _Network(
            n_layers=len(layers),
            n_samples=n_samples,
            n_inputs=packed[0].n_in,
            n_outputs=packed[len(layers) - 1].n_out // (2 if head_var is None else 1),
            layers=packed,
            x_mean=_address(self._own(x_mean)),
            x_std=_address(self._own(x_std)),
            gaussian_head=int(head_var is None),
            min_std=min_std,
            head_var=None if head_var is None else _address(self._own(head_var)),
        )

    def _own(self, array: np.ndarray) -> np.ndarray:
        kept = np.ascontiguousarray(array, dtype=np.float32)
        self._keep.append(kept)
        return kept

    def forward(
        self,
        x: np.ndarray,
        *,
        draws: tuple[np.ndarray, np.ndarray] | None = None,
        moments: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        out_mean: np.ndarray | None = None,
        out_std: np.ndarray | None = None,
        spread: float = 1.0,
        threads: int = 1,
    ) -> None:
        """Evaluate every draw on the N columns of x on up to `threads` threads; write the results.

        x is (d, N), shared by every draw, or (S, d, N), one input set per draw; float32 with unit
        stride along N (row strides are passed on). `draws` = (means, variances), each (S, o, N),
        and `moments` = (centre, aleatoric, epistemic), each (o, N), are float32 arrays (or views
        with unit stride along N) to fill. Draws are mapped to out_mean + out_std · (c + spread ·
        (m − c)) with c their average (identity when the scalers are None), variances scaled by
        out_std²; moments are of the mapped draws.
        """
        per_sample = x.ndim == 3
        if (
            x.dtype != np.float32
            or not _unit_stride(x)
            or (per_sample and x.strides[0] != x.shape[1] * x.strides[1])
        ):
            raise ValueError("x must be float32 with unit stride along N (and whole input sets per draw)")
        out, scalers = _output_map(out_mean, out_std, spread)
        if draws is not None:
            means, variances = draws
            whole = means.strides[0] == means.shape[1] * means.strides[1]
            if means.strides != variances.strides or not _unit_stride(means) or not whole:
                raise ValueError("draws must share one layout with unit stride along N")
            out.means, out.variances, out.ld_draws = (
                _address(means),
                _address(variances),
                means.strides[1] // 4,
            )
        if moments is not None:
            if len({m.strides for m in moments}) != 1 or not _unit_stride(moments[0]):
                raise ValueError("moments must share one layout with unit stride along N")
            out.centre, out.aleatoric, out.epistemic = (_address(m) for m in moments)
            out.ld_moments = moments[0].strides[0] // 4
        status = self.lib.al_network_forward(
            ctypes.byref(self.net),
            x.shape[-1],
            _address(x),
            x.strides[-2] // 4,
            int(per_sample),
            ctypes.byref(out),
            threads,
        )
        del scalers  # kept alive through the call above (locals, so concurrent calls are safe)
        if status != 0:
            raise MemoryError("al_network_forward could not allocate its scratch memory")


def _output_map(
    out_mean: np.ndarray | None, out_std: np.ndarray | None, spread: float
) -> tuple[_Outputs, list]:
    """An al_outputs holding only the map of draws to outputs, and the arrays its pointers refer to."""
    scalers = [None if a is None else np.ascontiguousarray(a, dtype=np.float32) for a in (out_mean, out_std)]
    return _Outputs(
        out_mean=_address(scalers[0]), out_std=_address(scalers[1]), spread=spread
    ), scalers


def static_rollout(
    kernel: NetworkKernel,
    controls: np.ndarray,
    yaw0: np.ndarray,
    keys: np.ndarray,
    dt: float,
    paths: tuple[np.ndarray, ...],
    moments: tuple[np.ndarray, np.ndarray, np.ndarray],
    *,
    out_mean: np.ndarray,
    out_std: np.ndarray,
    spread: float,
    lever_arm: float = 0.0,
    threads: int = 1,
) -> None:
    """Fill S sampled trajectories of M maneuvers with `al_static_rollout` on up to `threads` threads.

    `kernel` holds the S network draws; `controls` (M, T, 2) float32 are the control rows (see
    static_rollout.c). `yaw0` holds one heading per maneuver, or one for all; `keys` (S,) uint64
    are the draws' noise keys. `paths` = (v, w, x, y, yaw), each an (S, M, T) float32 array with
    unit stride along T and whole maneuvers per draw, and `moments` = (centre, aleatoric,
    epistemic), each (M, T, 2) contiguous, are written. Draws are mapped as in `NetworkKernel.forward`.
    x, y are the path of the point `lever_arm` metres ahead of the rear axle (`pose.integrate_pose`).
    """
    n_maneuvers, n_steps, _ = controls.shape
    if controls.dtype != np.float32 or not controls.flags.c_contiguous:
        raise ValueError("controls must be contiguous float32 (M, T, 2)")
    ld_sample = paths[0].strides[0] // 4
    if any(p.strides != paths[0].strides or p.strides[1:] != (n_steps * 4, 4) for p in paths):
        raise ValueError("paths must share one (S, M, T) layout with whole maneuvers per draw")
    if any(not m.flags.c_contiguous or m.shape != (n_maneuvers, n_steps, 2) for m in moments):
        raise ValueError("moments must be contiguous (M, T, 2) arrays")
    mapping, scalers = _output_map(out_mean, out_std, spread)
    keys = np.ascontiguousarray(keys, dtype=np.uint64)
    status = kernel.lib.al_static_rollout(
        ctypes.byref(kernel.net),
        ctypes.byref(mapping),
        n_maneuvers,
        n_steps,
        dt,
        lever_arm,
        _address(controls),
        _address(yaw0),
        0 if yaw0.size == 1 else 1,
        _address(keys),
        ld_sample,
        *(_address(a) for a in (*paths, *moments)),
        threads,
    )
    del scalers  # kept alive through the call above
    if status != 0:
        raise MemoryError("al_static_rollout could not allocate its scratch memory")


def physics_rollout(
    kernel: NetworkKernel,
    parameters: np.ndarray,
    controls: np.ndarray,
    start: np.ndarray,
    keys: np.ndarray,
    rate_lag: int,
    rates: np.ndarray,
    moments: tuple[np.ndarray, np.ndarray, np.ndarray],
    *,
    pose: tuple[float, float, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    threads: int = 1,
) -> None:
    """Fill S sampled free runs of M maneuvers with `al_physics_rollout` on up to `threads` threads.

    `kernel` holds the correction's S draws; `parameters` the physics in physics_rollout.c's order
    (`activelearn.numerics.models.physics.native_parameters`); `controls` (M, T, 2) the control each
    step reads; `start` (S, 2, M) the rates before the first step; `keys` (S,) uint64 the noise
    keys. `rates` (S, 2, M, T) and `moments` (centre, aleatoric, epistemic), each (M, T, 2), are
    written; all float32 and contiguous. `pose` = (dt, lever arm, headings (M,), (x, y, yaw) each
    (S, M, T)) also integrates each draw's pose (`pose.integrate_pose`'s) into x, y, yaw.
    """
    n_maneuvers, n_steps, _ = controls.shape
    dt, arm, yaw0, paths = pose if pose is not None else (0.0, 0.0, None, (None, None, None))
    arrays = (controls, start, rates, *moments) + ((yaw0, *paths) if pose is not None else ())
    if any(a.dtype != np.float32 or not a.flags.c_contiguous for a in arrays):
        raise ValueError("controls, start, rates, moments and the pose must be contiguous float32")
    if rates.shape != (len(keys), 2, n_maneuvers, n_steps) or start.shape != (len(keys), 2, n_maneuvers):
        raise ValueError("rates must be (S, 2, M, T) and start (S, 2, M)")
    if any(m.shape != (n_maneuvers, n_steps, 2) for m in moments):
        raise ValueError("moments must be (M, T, 2)")
    if pose is not None and (
        yaw0.shape != (n_maneuvers,) or any(p.shape != (len(keys), n_maneuvers, n_steps) for p in paths)
    ):
        raise ValueError("the pose's headings must be (M,) and its paths (S, M, T)")
    if rate_lag < 1:
        raise ValueError("rate_lag must be at least 1")
    parameters = np.ascontiguousarray(parameters, dtype=np.float32)
    if len(parameters) != kernel.lib.al_physics_parameter_count():
        raise ValueError("parameters do not match physics_rollout.c's layout")
    keys = np.ascontiguousarray(keys, dtype=np.uint64)
    status = kernel.lib.al_physics_rollout(
        ctypes.byref(kernel.net),
        _address(parameters),
        n_maneuvers,
        n_steps,
        int(rate_lag),
        *(_address(a) for a in (controls, start, keys, rates, *moments)),
        float(dt),
        float(arm),
        *(_address(a) for a in (yaw0, *paths)),
        threads,
    )
    if status != 0:
        raise MemoryError("al_physics_rollout could not allocate its scratch memory")


def kinematic_rate_runs(
    lib: ctypes.CDLL, car: np.ndarray, sets: np.ndarray, controls: np.ndarray, start: np.ndarray, dt: float
) -> np.ndarray:
    """Rates (P, M, T, 2) of the kinematic single track's bare free runs (`al_kinematic_rate_runs`): each
    parameter set of `sets` (P, 7) on each run of `controls` (M, T, 2) from `start` (M, 2); `car` holds
    physics_rollout.c's K_COUNT figures. All float64 (copied where they are not)."""
    car, sets, controls, start = (np.ascontiguousarray(a, np.float64) for a in (car, sets, controls, start))
    (n_sets, width), (n_runs, n_steps, _) = sets.shape, controls.shape
    if len(car) != lib.al_kinematic_car_count() or width != 7 or start.shape != (n_runs, 2):
        raise ValueError("car, sets (P, 7) and start (M, 2) do not match physics_rollout.c's layout")
    rates = np.empty((n_sets, n_runs, n_steps, 2))
    if n_sets and n_runs and n_steps:
        lib.al_kinematic_rate_runs(_address(car), _address(sets), n_sets, n_runs, n_steps, _address(controls),
                                   _address(start), float(dt), _address(rates))  # fmt: skip
    return rates


def dynamic_rate_runs(
    lib: ctypes.CDLL,
    car: np.ndarray,
    sets: np.ndarray,
    table: tuple[np.ndarray, np.ndarray],
    controls: np.ndarray,
    start: np.ndarray,
    dt: float,
    substeps: int,
    implicit: bool,
    *,
    threads: int = 1,
) -> np.ndarray:
    """Rates (B, T, 2) = (v_x, r) of B free runs with `al_dynamic_rate_runs` on up to `threads` threads.

    Lane b steps the figures `sets[b]` (B, dynamic_rollout.c's S_COUNT) through run b % M of `controls`
    (M, T, 2) from `start[b]` (B, 4) = (v_x, v_y, r, δ_w), `substeps` substeps a step of `dt` s; `car`
    holds the shared figures (its C_COUNT) and `table` the speed table's (throttle, speed) points. All
    float64 (copied where they are not).
    """
    car, sets, grid, speed, controls, start = (
        np.ascontiguousarray(a, dtype=np.float64) for a in (car, sets, *table, controls, start)
    )
    n_lanes, (n_runs, n_steps, _) = len(sets), controls.shape
    if len(car) != lib.al_dynamic_car_count() or sets.shape[1:] != (lib.al_dynamic_set_count(),):
        raise ValueError("car and sets do not match dynamic_rollout.c's layout")
    if start.shape != (n_lanes, 4) or n_lanes % max(n_runs, 1) or len(grid) != len(speed) or len(grid) < 2:
        raise ValueError("start must be (B, 4) with B a multiple of the runs, and the table >= 2 points")
    rates = np.empty((n_lanes, n_steps, 2))
    status = lib.al_dynamic_rate_runs(
        *(_address(a) for a in (car, sets, grid, speed)),
        len(grid), n_lanes, n_runs, n_steps,
        _address(controls), _address(start), float(dt), int(substeps), int(implicit), _address(rates),
        int(threads),
    )  # fmt: skip
    _check_dynamic_status("al_dynamic_rate_runs", status, "could not start its work")
    return rates


def dynamic_free_runs(
    lib: ctypes.CDLL,
    car: np.ndarray,
    sets: np.ndarray,
    table: tuple[np.ndarray, np.ndarray],
    limits: np.ndarray,
    dt: float,
    substeps: int,
    draws: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    controls: np.ndarray,
    start: tuple[np.ndarray, np.ndarray],
    rate_lag: int,
    spread: float,
    *,
    pose: tuple[float, float, np.ndarray, tuple[np.ndarray, float] | None] | None = None,
    threads: int = 1,
) -> tuple[np.ndarray, ...]:
    """S free runs of the physics kind on the dynamic core with `al_dynamic_free_runs` (see there).

    `car`, `sets` (S, S_COUNT) and `table` as `dynamic_rate_runs`'; `limits` the correction's bounds
    (L_COUNT); `draws` = (z (S, 4, U), noise std (S, 2, U), each draw's noise key (S,) uint64: the
    kernel draws its normals, `counter_noise`'s stream, each step's row (M, T));
    `controls` (M, T, 2) the control each step reads; `start` = ((v_x, r), (v_y, δ_w)), each (S, 2, M).
    `pose` = (dt, lever arm, headings (M,), the model discrepancy's (each draw's sizes of v and r (S, 2),
    correlation time) or None) asks for each draw's pose as well: the kernel draws the discrepancy's
    normals from each draw's key with its top bit set (`discrepancy.discrepancy_paths`' stream).
    Returns the rates with the sensors' noise (S, 2, M, T), the moments (centre, aleatoric, epistemic),
    each (M, T, 2), and with `pose` (x, y, yaw), each (S, M, T); float32.
    """
    car, sets, grid, speed, limits = (
        np.ascontiguousarray(a, dtype=np.float64) for a in (car, sets, *table, limits)
    )
    z, noise_std, controls, *starts = (
        np.ascontiguousarray(a, dtype=np.float32) for a in (*draws[:2], controls, *start)
    )
    keys = np.ascontiguousarray(draws[2], dtype=np.uint64)
    index = np.ascontiguousarray(draws[3], dtype=np.int64)
    n_samples, (n_maneuvers, n_steps, _), n_rows = len(sets), controls.shape, z.shape[-1]
    if len(car) != lib.al_dynamic_car_count() or sets.shape[1:] != (lib.al_dynamic_set_count(),):
        raise ValueError("car and sets do not match dynamic_rollout.c's layout")
    if len(limits) != lib.al_dynamic_limit_count():
        raise ValueError("limits do not match dynamic_rollout.c's layout")
    pose_dt, arm, yaw0, discrepancy = pose if pose is not None else (0.0, 0.0, None, None)
    paths = (n_samples, n_maneuvers, n_steps)
    shapes = {
        "z": (z.shape, (n_samples, 4, n_rows)),
        "noise_std": (noise_std.shape, (n_samples, 2, n_rows)),
        "keys": (keys.shape, (n_samples,)),
        "index": (index.shape, (n_maneuvers, n_steps)),
        "start": (starts[0].shape, (n_samples, 2, n_maneuvers)),
        "start_hidden": (starts[1].shape, (n_samples, 2, n_maneuvers)),
    }
    if pose is not None:
        yaw0 = np.ascontiguousarray(yaw0, dtype=np.float32)
        shapes["headings"] = (yaw0.shape, (n_maneuvers,))
    correlation_time = 1.0
    if discrepancy is not None:
        discrepancy, correlation_time = np.ascontiguousarray(discrepancy[0], dtype=np.float64), discrepancy[1]
        shapes["discrepancy"] = (discrepancy.shape, (n_samples, 2))
    for name, (shape, expected) in shapes.items():
        if shape != expected:
            raise ValueError(f"{name} must be {expected}, not {shape}")
    if rate_lag < 1:
        raise ValueError("rate_lag must be at least 1")
    if index.size and (index.min() < 0 or index.max() >= n_rows):
        raise ValueError("index must name rows of z")
    rates = np.empty((n_samples, 2, n_maneuvers, n_steps), np.float32)
    moments = tuple(np.empty((n_maneuvers, n_steps, 2), np.float32) for _ in range(3))
    poses = tuple(np.empty(paths, np.float32) for _ in range(3)) if pose is not None else ()
    pose_arrays = (yaw0, discrepancy, *(poses or (None,) * 3))
    status = lib.al_dynamic_free_runs(
        *(_address(a) for a in (car, sets, grid, speed)), len(grid), _address(limits),
        n_samples, n_maneuvers, n_steps, n_rows, float(dt), int(substeps), int(rate_lag),
        int(spread != 1.0), float(spread),
        *(_address(a) for a in (controls, index, z, noise_std, keys, *starts, rates, *moments)),
        float(pose_dt), float(arm), float(correlation_time), *(_address(a) for a in pose_arrays),
        int(threads),
    )  # fmt: skip
    _check_dynamic_status("al_dynamic_free_runs", status, "could not allocate its scratch memory")
    return (rates, *moments, *poses)


def _check_dynamic_status(name: str, status: int, failure: str) -> None:
    """A dynamic kernel's status: -2, the car's wheel passes (its C_WHEEL_FORCES) have no variant in
    the kernel (dynamic_track.WHEEL_PASS_CHOICES), or the wheels' forces come with the kinematic core;
    another non-zero, `failure` (memory or threads)."""
    if status == -2:
        raise ValueError(f"{name}: the car's wheel passes have no kernel variant (C_WHEEL_FORCES), or the "
                         "wheels' forces come with the kinematic core (C_KINEMATIC_CORE)")
    if status != 0:
        raise MemoryError(f"{name} {failure}")
