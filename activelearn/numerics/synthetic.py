"""Synthetic steady-state data for Nigel: an Ackermann map with heteroscedastic noise.

Stands in for simulator data in tests and benchmarks. Inputs are (throttle τ, steering δ), outputs
(forward speed v [m/s], yaw rate ω [rad/s]):

    v = V_MAX · τ · (1 − SCRUB · (δ / δ_max)²)                 speed drops with steering (tire scrub)
    ω_kin = v · tan δ / (L · (1 + K · v²))                       understeer gradient K
    ω = Ω_MAX · tanh(ω_kin / Ω_MAX)                               yaw rate saturates below Ω_MAX

Noise is Gaussian with a std that grows with |τ| (slower settling at high throttle).
"""

from __future__ import annotations

import numpy as np

from simulator.vehicles import load_vehicle

_NIGEL = load_vehicle("nigel")  # a toy of the default car: its figures, not its physics
WHEELBASE = _NIGEL.wheelbase  # m
V_MAX = _NIGEL.max_speed  # m/s at full throttle, straight
STEER_MAX = _NIGEL.steering.limit.value  # rad
OMEGA_MAX = _NIGEL.max_yaw_rate  # rad/s
SCRUB = 0.25  # fractional speed loss at full lock
UNDERSTEER = 5.0  # s²/m², K in 1 + K v²
# Noise std = base + slope · |τ|, per output (v, ω).
NOISE_BASE = np.array([0.002, 0.006])
NOISE_SLOPE = np.array([0.008, 0.03])

SKIDPAD_THROTTLES = (0.2, 0.4, 0.6, 0.8, 1.0)
SKIDPAD_STEERINGS = tuple(round(STEER_MAX * k / 5.0, 4) for k in range(1, 6))  # 6° … 30°


def _controls(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape[1] < 2:
        raise ValueError(f"controls must have shape (N, 2), got {x.shape}")
    return x[:, 0], x[:, 1]


def steady_state(x: np.ndarray) -> np.ndarray:
    """Noise-free steady-state (v, ω) for controls x of shape (N, 2) = (throttle, steering)."""
    tau, delta = _controls(x)
    v = V_MAX * tau * (1.0 - SCRUB * (delta / STEER_MAX) ** 2)
    omega_kin = v * np.tan(delta) / (WHEELBASE * (1.0 + UNDERSTEER * v**2))
    omega = OMEGA_MAX * np.tanh(omega_kin / OMEGA_MAX)
    return np.stack([v, omega], axis=1)


def noise_std(x: np.ndarray) -> np.ndarray:
    """True noise std of (v, ω) at controls x (N, 2); grows linearly with |throttle|."""
    tau, _ = _controls(x)
    return NOISE_BASE[None, :] + NOISE_SLOPE[None, :] * np.abs(tau)[:, None]


def observe(x: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Noisy observations of the steady state at controls x (N, 2)."""
    return steady_state(x) + rng.standard_normal((len(x), 2)) * noise_std(x)


def grid(throttles: np.ndarray | tuple, steerings: np.ndarray | tuple) -> np.ndarray:
    """All (throttle, steering) pairs of two value lists, shape (len(t) · len(s), 2)."""
    tt, ss = np.meshgrid(np.asarray(throttles, float), np.asarray(steerings, float), indexing="ij")
    return np.stack([tt.ravel(), ss.ravel()], axis=1)


def skidpad_points(both_directions: bool = True) -> np.ndarray:
    """The reference skidpad operating grid: τ ∈ {0.2…1.0} × δ ∈ {0.1047…0.5236}, cw and ccw."""
    steer = np.asarray(SKIDPAD_STEERINGS)
    if both_directions:
        steer = np.concatenate([-steer[::-1], steer])
    return grid(SKIDPAD_THROTTLES, steer)


def random_points(
    n: int,
    *,
    throttle: tuple[float, float] = (0.2, 1.0),
    steering: tuple[float, float] = (-STEER_MAX, STEER_MAX),
    seed: int = 0,
) -> np.ndarray:
    """n operating points drawn uniformly from a throttle × steering box."""
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(*throttle, n), rng.uniform(*steering, n)], axis=1)


def repeated_rows(
    points: np.ndarray, rows_per_point: int, *, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Log `rows_per_point` noisy rows at each operating point, as a steady maneuver would.

    Returns (x, y, groups): x (M·R, 2) controls, y (M·R, 2) noisy (v, ω), groups (M·R,) the index of
    each row's operating point (one maneuver per point).
    """
    rng = np.random.default_rng(seed)
    points = np.asarray(points, dtype=float)
    x = np.repeat(points, rows_per_point, axis=0)
    groups = np.repeat(np.arange(len(points)), rows_per_point)
    return x, observe(x, rng), groups


def uniform_rows(
    n: int,
    *,
    throttle: tuple[float, float] = (0.2, 1.0),
    steering: tuple[float, float] = (-STEER_MAX, STEER_MAX),
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """n rows at independent uniform controls in a box, with noisy targets: (x, y)."""
    x = random_points(n, throttle=throttle, steering=steering, seed=seed)
    return x, observe(x, np.random.default_rng(seed + 1))


def calibration_task(
    seed: int = 0,
    *,
    n_points: int = 40,
    rows_per_point: int = 60,
    n_calibration: int = 30,
    n_test: int = 200,
    val_rows: int = 10,
) -> dict[str, np.ndarray]:
    """The epistemic-calibration setting: repeated noisy rows at a few operating points.

    Keys: x, y, groups (training rows: `rows_per_point` noisy rows at each of `n_points` random points
    in the full box); cal_points / cal_truth (held-out points with noise-free targets, for fitting the
    recalibration); val_x, val_y (`val_rows` noisy rows at each calibration point, for early
    stopping); test_points / test_truth (other held-out points with noise-free targets).
    """
    box = {"throttle": (0.2, 1.0), "steering": (-STEER_MAX, STEER_MAX)}
    x, y, groups = repeated_rows(random_points(n_points, **box, seed=seed), rows_per_point, seed=seed + 1)
    cal = random_points(n_calibration, **box, seed=seed + 100)
    test = random_points(n_test, **box, seed=seed + 200)
    val_x, val_y, _ = repeated_rows(cal, val_rows, seed=seed + 2)
    return {
        "x": x,
        "y": y,
        "groups": groups,
        "cal_points": cal,
        "cal_truth": steady_state(cal),
        "val_x": val_x,
        "val_y": val_y,
        "test_points": test,
        "test_truth": steady_state(test),
    }
