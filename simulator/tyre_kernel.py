"""The tyre cars' compiled stepping loop (`tyre_step.c`): built on first use, loaded through ctypes.

`TyreCar.rollout` steps its batches here, ~10x faster than its NumPy path (a Python call of ~90 NumPy
operations and one `mujoco.rollout` call per physics step). The C file compiles against the MuJoCo
headers shipped in the `mujoco` wheel and links the wheel's own libmujoco, so it steps the very
mjModel and mjData the Python objects hold. Without a working C compiler `library()` returns None once
with a warning and the cars take the NumPy path, which computes the same equations (its numbers differ
in the last bits: the simulation cache's key says which path simulated).
"""

from __future__ import annotations

import ctypes
import functools
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from simulator import cbuild

SOURCE = Path(__file__).with_name("tyre_step.c")
_MUJOCO_DIR = Path(mujoco.__file__).parent
# Portable and reproducible: no -march=native, no -ffast-math, no fused multiply-adds (what decides the
# numbers, in the simulation cache's key); then where the MuJoCo headers are on this machine.
NUMERIC_FLAGS = ("-O2", "-fPIC", "-pthread", "-ffp-contract=off")
FLAGS = (*NUMERIC_FLAGS, f"-I{_MUJOCO_DIR / 'include'}")

_i64, _f64, _ptr = ctypes.c_int64, ctypes.c_double, ctypes.c_void_p


class _Car(ctypes.Structure):
    """tyre_step.c's al_tyre_car."""

    _fields_ = [
        *[(name, _i64) for name in ("nstate", "nsens", "nu", "nv", "xfrc", "quat", "vel", "omega", "delta")],
        ("loads", _i64 * 4), ("touch", _i64 * 4), ("steer", _i64 * 2), ("spin", _i64 * 2), ("kin", _i64 * 4),
        ("centres", _f64 * 3 * 4), ("ipos", _f64 * 3),
        *[(name, _f64) for name in ("wheelbase", "half_track", "wheel_radius", "fade_speed", "friction",
                                    "shape", "curvature")],
        ("stiffness", _f64 * 4),
        *[(name, _f64) for name in ("max_acceleration", "top_speed", "reverse_top_speed", "power_limit_speed",
                                    "mass_nominal", "brake_deceleration")],
        ("drive_share", _f64 * 4),
        *[(name, _f64) for name in ("steering_limit", "steering_step", "spin_factor")],
    ]  # fmt: skip


def _mujoco_library() -> Path:
    """The wheel's libmujoco (the one its Python modules load)."""
    found = sorted(_MUJOCO_DIR.glob("libmujoco.so*"))
    if not found:
        raise OSError(f"no libmujoco.so* in {_MUJOCO_DIR}")
    return found[0]


@functools.cache
def library() -> ctypes.CDLL | None:
    """The compiled tyre step, or None (warned once) where it cannot be built."""
    def build() -> Path:
        lib_mujoco = _mujoco_library()
        option = (str(lib_mujoco), f"-Wl,-rpath,{lib_mujoco.parent}", "-lm")
        link = ("-shared", "-pthread")
        recipe = cbuild.Recipe("tyre-step", (SOURCE,), (), FLAGS, link, (option,), (mujoco.__version__,))
        return cbuild.build(recipe, cbuild.find_compiler())

    lib = cbuild.load(build, "simulator: compiled tyre step unavailable; the tyre cars take the NumPy path")
    if lib is None:
        return None
    lib.al_tyre_car_size.restype = _i64
    if lib.al_tyre_car_size() != ctypes.sizeof(_Car):
        raise RuntimeError("simulator.tyre_kernel._Car does not match tyre_step.c's al_tyre_car")
    lib.al_tyre_rollout.argtypes = [_ptr, _ptr, _i64, ctypes.POINTER(_Car), _i64, _i64, *[_ptr] * 4]
    lib.al_tyre_rollout.restype = ctypes.c_int
    return lib


def car_figures(car: Any) -> _Car:
    """The figures and state offsets the C step reads, from a built `TyreCar` (which imports this module)."""
    m = car.model
    step = car.steering_rate * m.opt.timestep
    return _Car(
        nstate=car.nstate, nsens=m.nsensordata, nu=m.nu, nv=m.nv, xfrc=6 * m.body("chassis").id,
        quat=int(car._quat[0]), vel=int(car._vel[0]), omega=int(car._omega[0]), delta=int(car._delta),
        loads=(_i64 * 4)(*map(int, car._loads)), touch=(_i64 * 4)(*map(int, car._touch)),
        steer=(_i64 * 2)(*map(int, car._steer_qpos)), spin=(_i64 * 2)(*map(int, car._spin_qpos)),
        kin=(_i64 * 4)(*map(int, car._kin_qvel)),
        centres=(_f64 * 3 * 4)(*[(_f64 * 3)(*row) for row in car._centres]), ipos=(_f64 * 3)(*car._ipos),
        wheelbase=car.wheelbase, half_track=car._half_track, wheel_radius=car.wheel_radius,
        fade_speed=car.fade_speed, friction=car.friction, shape=car.shape, curvature=car.curvature,
        stiffness=(_f64 * 4)(*car.stiffness_factor), max_acceleration=car.max_acceleration,
        top_speed=car.top_speed, reverse_top_speed=car.reverse_top_speed,
        power_limit_speed=car.power_limit_speed, mass_nominal=car.mass_nominal,
        brake_deceleration=car.brake_deceleration, drive_share=(_f64 * 4)(*car.drive_share),
        steering_limit=car.steering_limit, steering_step=step, spin_factor=m.opt.timestep / car.wheel_radius,
    )  # fmt: skip


def rollout(
    lib: ctypes.CDLL, car: Any, datas: Sequence[mujoco.MjData], initial_state: np.ndarray,
    control: np.ndarray, nstep: int, state: np.ndarray, sensordata: np.ndarray,
) -> None:  # fmt: skip
    """Step runs in C as `TyreCar.rollout` describes, a thread per MjData of `datas` (whole runs each)."""
    m = car.model
    nb = len(initial_state)
    init = np.ascontiguousarray(initial_state, dtype=np.float64)
    ctrl = np.ascontiguousarray(control[:, :nstep], dtype=np.float64)
    for name, array, shape in (("state", state, (nb, nstep, car.nstate)),
                               ("sensordata", sensordata, (nb, nstep, m.nsensordata))):  # fmt: skip
        if array.shape != shape or array.dtype != np.float64 or not array.flags.c_contiguous:
            raise ValueError(f"{name} must be C-contiguous float64 of shape {shape}, not {array.shape}")
    if ctrl.shape != (nb, nstep, m.nu):
        raise ValueError(f"control must have shape {(nb, nstep, m.nu)}, not {ctrl.shape}")
    threads = max(1, min(len(datas), nb))
    addresses = (ctypes.c_void_p * threads)(*[d._address for d in datas[:threads]])
    status = lib.al_tyre_rollout(
        m._address, addresses, threads, ctypes.byref(car.kernel_figures), nb, nstep,
        init.ctypes.data, ctrl.ctypes.data, state.ctypes.data, sensordata.ctypes.data,
    )  # fmt: skip
    if status != 0:
        warnings.warn("simulator: a tyre-step thread could not start; the others stepped its runs",
                      RuntimeWarning, stacklevel=2)  # fmt: skip


__all__ = ["FLAGS", "NUMERIC_FLAGS", "SOURCE", "car_figures", "library", "rollout"]
