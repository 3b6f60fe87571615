"""Compiled kernels, built on first use with the machine's C compiler and loaded through ctypes.

One fused loop that no library provides: noise, rates and pose of one sampled trajectory of the
static surrogate (`static_rollout.c`), replacing a chain of torch passes over multi-MB arrays. It is
compiled once per machine (sources, flags, compiler and CPU features form the cache key) into
`CACHE_DIR` (`~/.cache/activelearn/native`; a temporary directory if that is not writable), and
written atomically so concurrent processes can race to build it safely.

Without a working C compiler `library()` returns None once with a warning, and callers take their
NumPy/torch path, which computes the same numbers (up to float rounding) but runs slower;
`simulate(..., backend="reference")` picks that path explicitly.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import numpy as np

SOURCES = (Path(__file__).with_name("static_rollout.c"),)
# -ffast-math lets GCC vectorise logf/sinf/cosf through glibc's libmvec; -march=native is safe
# because the cache key includes this machine's CPU features.
FLAGS = ("-O3", "-ffast-math", "-march=native", "-fPIC", "-shared")
LINK_OPTIONS = (("-lmvec", "-lm"), ("-lm",))  # libmvec is glibc's; elsewhere the scalar libm serves
COMPILE_TIMEOUT_S = 120
COMPILERS = ("cc", "gcc", "clang")  # the first found on PATH builds the kernels
CACHE_DIR = Path.home() / ".cache" / "activelearn" / "native"

_f32 = ctypes.POINTER(ctypes.c_float)
_i64 = ctypes.POINTER(ctypes.c_int64)
_u32 = ctypes.POINTER(ctypes.c_uint32)
SIGNATURES = {
    "al_tile": ([], ctypes.c_int),
    "al_philox4x32_10": ([_u32, _u32, _u32], None),
    "al_static_trajectory": (
        [ctypes.c_int64, ctypes.c_int64, ctypes.c_float, _f32, _f32, _f32, _f32, _i64, _f32, ctypes.c_int64]
        + [ctypes.c_uint32, ctypes.c_uint32]
        + [_f32] * 5,
        None,
    ),
}


def _compiler() -> str:
    for name in COMPILERS:
        if shutil.which(name):
            return name
    raise OSError(f"no C compiler found (looked for {', '.join(COMPILERS)})")


def _cpu_features() -> str:
    try:
        with open("/proc/cpuinfo") as info:
            return next((line for line in info if line.startswith(("flags", "Features"))), "")
    except OSError:
        return platform.processor()


def _build(compiler: str) -> Path:
    """Compile the kernel into the cache (or find it there) and return the library's path."""
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True, check=False).stdout
    sources = [path.read_text() for path in SOURCES]
    identity = [*sources, " ".join(FLAGS), version, platform.machine(), _cpu_features()]
    key = hashlib.sha256("\0".join(identity).encode()).hexdigest()[:16]
    name = f"kernels-{key}.so"
    if (CACHE_DIR / name).exists():
        return CACHE_DIR / name
    try:
        CACHE_DIR.mkdir(parents=True, exist_ok=True)
        target = CACHE_DIR / name
    except OSError:  # a read-only home: build for this process only
        target = Path(tempfile.mkdtemp(prefix="activelearn-native-")) / name
    errors = []
    for link in LINK_OPTIONS:
        fd, tmp = tempfile.mkstemp(suffix=".so", dir=target.parent)
        os.close(fd)
        done = subprocess.run(
            [compiler, *FLAGS, "-o", tmp, *map(str, SOURCES), *link],
            capture_output=True,
            text=True,
            timeout=COMPILE_TIMEOUT_S,
            check=False,
        )
        if done.returncode == 0:
            os.replace(tmp, target)  # atomic: a concurrent builder's identical file may win, harmlessly
            return target
        os.unlink(tmp)
        message = done.stderr.strip()
        errors.append(message.splitlines()[-1] if message else f"exit status {done.returncode}")
    raise OSError(f"{compiler} failed: {' | '.join(errors)}")


@functools.cache
def library() -> ctypes.CDLL | None:
    """The compiled kernels, or None (warned once) where they cannot be built."""
    try:
        lib = ctypes.CDLL(str(_build(_compiler())))
    except (OSError, subprocess.SubprocessError) as error:
        warnings.warn(
            f"activelearn: compiled kernel unavailable ({error}); using the slower NumPy/torch path",
            RuntimeWarning,
            stacklevel=2,
        )
        return None
    for name, (argtypes, restype) in SIGNATURES.items():
        function = getattr(lib, name)
        function.argtypes, function.restype = argtypes, restype
    return lib


def _pointer(array: np.ndarray, kind: type = ctypes.c_float):
    return array.ctypes.data_as(ctypes.POINTER(kind))


def static_trajectory(
    lib: ctypes.CDLL,
    rates: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    index: np.ndarray,
    yaw0: np.ndarray,
    key: int,
    dt: float,
    out: tuple[np.ndarray, ...],
) -> None:
    """Fill one sampled trajectory with `al_static_trajectory` (see static_rollout.c).

    `rates` = (mean_v, var_v, mean_w, var_w) of one draw per distinct control row (float32, unit
    stride); `index` (M·T,) int64 gives each step's row; `yaw0` holds one heading per maneuver, or
    one for all; `out` = (v, w, x, y, yaw), each a contiguous float32 (M, T) array, is written.
    """
    n_maneuvers, n_steps = out[0].shape
    lib.al_static_trajectory(
        n_maneuvers,
        n_steps,
        dt,
        *(_pointer(a) for a in rates),
        _pointer(index, ctypes.c_int64),
        _pointer(yaw0),
        0 if yaw0.size == 1 else 1,
        key & 0xFFFFFFFF,
        key >> 32,
        *(_pointer(a) for a in out),
    )
