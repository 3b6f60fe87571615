"""The compiled surrogate kernel and its counter noise: known answers, the NumPy reference, the build."""

from __future__ import annotations

import ctypes
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy import stats

from activelearn.config import ModelConfig
from activelearn.errors import InputError
from activelearn.numerics import counter_noise, native
from activelearn.numerics.models import build_model
from activelearn.numerics.surrogate import simulate

# Random123's published known-answer vectors for Philox4x32-10 (its tests/kat_vectors).
PHILOX_KAT = [
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    (
        (0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344),
        (0xA4093822, 0x299F31D0),
        (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1),
    ),
]


@pytest.fixture(scope="module")
def untrained_model():
    """An untrained default hybrid: enough to drive a rollout through either backend."""
    torch.manual_seed(0)
    return build_model(ModelConfig())


@pytest.fixture(scope="module")
def kernel(c_kernels):
    return c_kernels


def _unit_network(kernel, n_samples: int = 1) -> native.NetworkKernel:
    """A network whose every draw predicts mean 0 and variance exactly 1 (zero weights, fixed variance)."""
    zeros = np.zeros((2, 2), np.float32)
    return native.NetworkKernel(
        kernel,
        [(zeros, np.zeros(2, np.float32), False, None)],
        n_samples=n_samples,
        x_mean=np.zeros(2, np.float32),
        x_std=np.ones(2, np.float32),
        min_std=1e-3,
        head_var=np.ones(2, np.float32),
    )


def _noise_from_kernel(kernel, key: int, n_maneuvers: int, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The rollout kernel's sampled rates under mean 0 and variance 1: its standard normal noise."""
    controls = np.zeros((n_maneuvers, n_steps, 2), np.float32)
    paths = tuple(np.empty((1, n_maneuvers, n_steps), np.float32) for _ in range(5))
    moments = tuple(np.empty((n_maneuvers, n_steps, 2), np.float32) for _ in range(3))
    native.static_rollout(
        _unit_network(kernel),
        controls,
        np.zeros(1, np.float32),
        np.array([key], np.uint64),
        0.1,
        paths,
        moments,
        out_mean=np.zeros(2),
        out_std=np.ones(2),
        spread=1.0,
    )
    return paths[0][0], paths[1][0]


@pytest.mark.parametrize(("counter", "key", "expected"), PHILOX_KAT)
def test_philox_matches_the_known_answers_in_c_and_numpy(kernel, counter, key, expected):
    words = (ctypes.c_uint32 * 4)()
    kernel.al_philox4x32_10((ctypes.c_uint32 * 4)(*counter), (ctypes.c_uint32 * 2)(*key), words)
    assert tuple(words) == expected
    assert tuple(int(w) for w in counter_noise.philox4x32_10(counter, key)) == expected


def test_kernel_draws_the_reference_noise(kernel):
    # 1 300 steps: two full tiles and a partial one; 3 maneuvers: the maneuver is part of the counter.
    assert kernel.al_tile() == counter_noise.TILE
    key = 0x0123_4567_89AB
    zv, zw = _noise_from_kernel(kernel, key, 3, 1300)
    rv, rw = counter_noise.step_noise(key, 3, 1300)
    np.testing.assert_allclose(zv, rv, atol=2e-6)
    np.testing.assert_allclose(zw, rw, atol=2e-6)
    other_v, _ = _noise_from_kernel(kernel, key + 1, 3, 1300)
    assert np.abs(other_v - zv).mean() > 0.5


def test_counter_noise_is_standard_normal_and_independent():
    zv, zw = counter_noise.step_noise(7, 16, 8000)

    def within_five_sigma(statistic: float, n: int, scale: float = 1.0) -> bool:
        return abs(statistic) < 5.0 * scale / np.sqrt(n)

    for z in (zv.ravel(), zw.ravel()):
        assert within_five_sigma(z.mean(), z.size)
        assert within_five_sigma(z.var() - 1.0, z.size, np.sqrt(2.0))
        assert within_five_sigma(np.mean(z**4) - 3.0, z.size, np.sqrt(96.0))  # Gaussian kurtosis
        assert stats.kstest(z, "norm").pvalue > 0.01
    pairs = {
        "v and ω noise of one step": (zv.ravel(), zw.ravel()),
        "consecutive steps": (zv[:, 1:].ravel(), zv[:, :-1].ravel()),
        "one counter's two steps": (zv[:, :256].ravel(), zv[:, 256:512].ravel()),
        "two maneuvers": (zv[0], zv[1]),
    }
    for name, (a, b) in pairs.items():
        assert within_five_sigma(np.corrcoef(a, b)[0, 1], a.size), name
    # A maneuver's noise depends only on its own counters, not on how many steps the batch has.
    short_v, _ = counter_noise.step_noise(7, 16, 700)
    np.testing.assert_array_equal(short_v, zv[:, :700])


@pytest.fixture
def small_build(tmp_path, monkeypatch, c_kernels) -> tuple[str, Path]:
    """The build on one small source (network.c: under a second; all four: ~40 s of CPU), its cache in
    `tmp_path`, its compiler the machine's behind a wrapper that logs each command: (compiler, log)."""
    log = tmp_path / "commands.log"
    wrapper = tmp_path / "cc-logged"
    wrapper.write_text(f'#!/bin/sh\necho "$*" >> "{log}"\nsleep 0.3\nexec {native._compiler()} "$@"\n')
    wrapper.chmod(0o755)
    sources = Path(native.__file__).parent
    monkeypatch.setattr(native, "CACHE_DIR", tmp_path / "cache")
    monkeypatch.setattr(native, "SOURCES", (sources / "network.c",))
    monkeypatch.setattr(native, "HEADERS", (sources / "network.h",))
    return str(wrapper), log


def _compiles(log: Path) -> int:
    return sum(" -c " in line for line in log.read_text().splitlines())


def test_kernel_builds_once_into_the_cache(small_build):
    compiler, log = small_build
    built = native._build(compiler)
    assert built.parent == native.CACHE_DIR and list(native.CACHE_DIR.glob("*.so")) == [built]
    stamp = built.stat().st_mtime_ns
    assert native._build(compiler) == built
    assert built.stat().st_mtime_ns == stamp and _compiles(log) == 1  # reused, not rebuilt
    assert not list(native.CACHE_DIR.glob("tmp*"))  # no temporary left behind


def test_concurrent_builders_compile_once(small_build):
    """Processes starting together on a fresh machine (a comparison's workers, a suite's) wait for one
    build instead of each compiling the kernel."""
    compiler, log = small_build
    with ThreadPoolExecutor(4) as pool:  # each takes the lock through its own open file, as a process does
        built = set(pool.map(lambda _: native._build(compiler), range(4)))
    assert len(built) == 1 and _compiles(log) == 1


def test_a_failing_compiler_warns_and_falls_back(untrained_model, c_kernels, failing_compiler):
    with failing_compiler(native, native.library):
        with pytest.warns(RuntimeWarning, match="kernel unavailable"):
            assert native.library() is None
        controls = [np.tile([0.5, 0.2], (40, 1))]
        fallback = simulate(untrained_model, controls, rate_hz=30.0, n_samples=3, seed=1)  # backend "auto"
        with pytest.raises(InputError, match="backend"):
            simulate(untrained_model, controls, rate_hz=30.0, n_samples=3, seed=1, backend="native")
    compiled = simulate(untrained_model, controls, rate_hz=30.0, n_samples=3, seed=1, backend="native")
    np.testing.assert_allclose(fallback.x, compiled.x, atol=1e-5)


def test_loading_the_kernel_leaves_the_processs_floating_point_mode_alone(c_kernels):
    """Linked with -ffast-math, the library switched the whole process to flush subnormals to zero."""
    script = (
        "import numpy as np, torch\n"
        "from activelearn.numerics import native\n"
        "assert native.library() is not None\n"
        "assert np.float32(1e-40) * np.float32(1.0) != 0.0, 'numpy flushes subnormals'\n"
        "assert np.float64(1e-310) * 1.0 != 0.0, 'numpy flushes float64 subnormals'\n"
        "assert (torch.tensor([1e-40]) * 1.0).item() != 0.0, 'torch flushes subnormals'\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
