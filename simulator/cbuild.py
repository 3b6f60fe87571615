"""Compile C sources into a shared library once per machine, cached under a key of what decides its code.

Used by the truth simulator's tyre step (`simulator.tyre_kernel`) and by the surrogate's kernels
(`activelearn.numerics.native`). The key covers the sources and headers, the flags, the compiler's
version, the machine and its CPU features, and what the caller adds (a library's version). One process
builds while the others wait on a lock beside the cached file (a comparison's workers, a test suite's,
starting together on a fresh machine), then load its library; the library is written atomically.
"""

from __future__ import annotations

import ctypes
import fcntl
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

COMPILERS = ("cc", "gcc", "clang")  # the first found on PATH builds
COMPILE_TIMEOUT_S = 120
CACHE_DIR = Path.home() / ".cache" / "activelearn" / "native"


@dataclass(frozen=True)
class Recipe:
    """What to build: sources compiled with `flags` each, linked with `link_flags` and the first of
    `link_options` that links; `headers` and `identity` only enter the cache key."""

    prefix: str
    sources: Sequence[Path]
    headers: Sequence[Path] = ()
    flags: Sequence[str] = ()
    link_flags: Sequence[str] = ("-shared",)
    link_options: Sequence[Sequence[str]] = ((),)
    identity: Sequence[str] = ()


def find_compiler(candidates: Sequence[str] | None = None) -> str:
    """The first C compiler of `candidates` (default `COMPILERS`) on PATH (OSError when none is)."""
    candidates = COMPILERS if candidates is None else candidates
    for name in candidates:
        if shutil.which(name):
            return name
    raise OSError(f"no C compiler found (looked for {', '.join(candidates)})")


def cpu_features() -> str:
    """The CPU's feature flags (part of the key: a library built with -march=native runs only here)."""
    try:
        with open("/proc/cpuinfo") as info:
            return next((line for line in info if line.startswith(("flags", "Features"))), "")
    except OSError:
        return platform.processor()


def run_compiler(command: list[str]) -> str | None:
    """Run one compiler command: None on success, else the last line of its complaint."""
    done = subprocess.run(command, capture_output=True, text=True, timeout=COMPILE_TIMEOUT_S, check=False)
    if done.returncode == 0:
        return None
    message = done.stderr.strip()
    return message.splitlines()[-1] if message else f"exit status {done.returncode}"


def build(recipe: Recipe, compiler: str, cache_dir: Path | None = None) -> Path:
    """Compile `recipe` into `cache_dir` (default `CACHE_DIR`; or find it there) and return its path."""
    cache_dir = CACHE_DIR if cache_dir is None else cache_dir
    version = subprocess.run([compiler, "--version"], capture_output=True, text=True, check=False).stdout
    texts = [path.read_text() for path in (*recipe.sources, *recipe.headers)]
    link = [" ".join(option) for option in recipe.link_options]
    identity = [*texts, " ".join(recipe.flags), " ".join(recipe.link_flags), *link, *recipe.identity]
    identity += [version, platform.machine(), cpu_features()]
    key = hashlib.sha256("\0".join(identity).encode()).hexdigest()[:16]
    name = f"{recipe.prefix}-{key}.so"
    if (cache_dir / name).exists():
        return cache_dir / name
    try:
        cache_dir.mkdir(parents=True, exist_ok=True)
        target = cache_dir / name
    except OSError:  # a read-only home: build for this process only
        target = Path(tempfile.mkdtemp(prefix="activelearn-native-")) / name
    with open(target.with_suffix(".lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one builder; released when the file closes or the process dies
        if target.exists():  # another process built it while this one waited
            return target
        return _compile_into(recipe, compiler, target)


def _compile_into(recipe: Recipe, compiler: str, target: Path) -> Path:
    """Compile the recipe's sources and link them into `target`, written atomically."""
    errors = []
    with tempfile.TemporaryDirectory(prefix="activelearn-native-build-") as workdir:
        objects = [str(Path(workdir) / f"{source.stem}.o") for source in recipe.sources]
        for source, obj in zip(recipe.sources, objects, strict=True):
            error = run_compiler([compiler, *recipe.flags, "-c", str(source), "-o", obj])
            if error is not None:
                raise OSError(f"{compiler} failed: {error}")
        for option in recipe.link_options:
            fd, tmp = tempfile.mkstemp(suffix=".so", dir=target.parent)
            os.close(fd)
            error = run_compiler([compiler, *recipe.link_flags, "-o", tmp, *objects, *option])
            if error is None:
                os.replace(tmp, target)  # atomic: a reader never finds half a library
                return target
            os.unlink(tmp)
            errors.append(error)
    raise OSError(f"{compiler} failed: {' | '.join(errors)}")


def load(build_library: Callable[[], Path], unavailable: str) -> ctypes.CDLL | None:
    """The library `build_library()` returns, loaded; None with one RuntimeWarning, `unavailable` and
    the error, where it cannot be built or loaded (the caller then takes its slower path)."""
    try:
        return ctypes.CDLL(str(build_library()))
    except (OSError, subprocess.SubprocessError) as error:
        warnings.warn(f"{unavailable} ({error})", RuntimeWarning, stacklevel=3)
        return None


__all__ = [
    "CACHE_DIR", "COMPILERS", "Recipe", "build", "cpu_features", "find_compiler", "load", "run_compiler",
]  # fmt: skip
