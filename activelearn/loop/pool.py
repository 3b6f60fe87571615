"""Candidate pools, the evaluation grid and the fixed test set, built from a campaign config."""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
from scipy.stats import qmc

from activelearn.config import MAX_STEERING, CampaignConfig, PoolConfig, TestSetConfig
from activelearn.loop.acquisition import Pool
from simulator import Maneuver, nominal_controls

KIND_ORDER: tuple[str, ...] = ("straight", "skidpad", "fishhook", "slalom", "eight")


def _operating_points(cfg: PoolConfig) -> list[tuple[float, float]]:
    """(throttle, unsigned steering) pairs of the pool: a grid, or a seeded Sobol set."""
    if cfg.size is None:
        assert cfg.throttles is not None and cfg.steerings is not None
        return [(float(t), float(s)) for t in cfg.throttles for s in cfg.steerings]
    assert cfg.throttle_range is not None and cfg.steering_range is not None
    with warnings.catch_warnings():  # any number of candidates, as acquisition's Sobol strategy does
        warnings.filterwarnings("ignore", message=".*balance properties.*", category=UserWarning)
        unit = qmc.Sobol(2, scramble=True, rng=cfg.seed).random(cfg.size)
    low = np.array([cfg.throttle_range[0], cfg.steering_range[0]])
    high = np.array([cfg.throttle_range[1], cfg.steering_range[1]])
    points = qmc.scale(unit, low, high)
    return [(round(float(t), 4), round(float(s), 4)) for t, s in points]


def _expand(
    kinds: Sequence[str], directions: Sequence[str], points: Sequence[tuple[float, float]], duration: float
) -> list[Maneuver]:
    """All maneuvers of the given kinds over the operating points, without duplicates.

    Straight maneuvers have no steering and no direction; fishhooks ramp to full lock whatever the
    grid says, so they vary in throttle and direction only.
    """
    seen: set[str] = set()
    maneuvers: list[Maneuver] = []
    for kind in sorted(kinds, key=KIND_ORDER.index):
        for throttle, steering in points:
            if throttle == 0.0:  # zero throttle brakes: a standing car teaches nothing
                continue
            for direction in directions:
                if kind == "straight":
                    m = Maneuver(kind, throttle, 0.0, "ccw", duration)
                elif kind == "fishhook":
                    m = Maneuver(kind, throttle, MAX_STEERING, direction, duration)
                else:
                    m = Maneuver(kind, throttle, steering, direction, duration)
                if m.name not in seen:
                    seen.add(m.name)
                    maneuvers.append(m)
    return maneuvers


def pool_maneuvers(cfg: PoolConfig) -> list[Maneuver]:
    """The candidate maneuvers of a pool config, in a stable order (kind, throttle, steering, direction)."""
    return _expand(cfg.kinds, cfg.directions, _operating_points(cfg), cfg.duration)


def test_maneuvers(cfg: TestSetConfig) -> list[Maneuver]:
    """The fixed test maneuvers: a grid independent of every campaign seed."""
    points = [(float(t), float(s)) for t in cfg.throttles for s in cfg.steerings]
    return _expand(cfg.kinds, cfg.directions, points, cfg.duration)


test_maneuvers.__test__ = False  # type: ignore[attr-defined]  # not a pytest test


def evaluation_grid(cfg: CampaignConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Throttle values, signed steering values and the (T*S, 2) grid of controls spanning the pool."""
    controls = np.concatenate([nominal_controls(m, 1.0) for m in pool_maneuvers(cfg.pool)])
    t_low, t_high = float(controls[:, 0].min()), float(controls[:, 0].max())
    s_max = float(np.abs(controls[:, 1]).max()) or MAX_STEERING
    s_low = -s_max if "cw" in cfg.pool.directions else 0.0
    s_high = s_max if "ccw" in cfg.pool.directions or "straight" in cfg.pool.kinds else 0.0
    throttles = np.linspace(t_low, t_high, cfg.acquisition.grid_throttles)
    steerings = np.linspace(s_low, s_high, cfg.acquisition.grid_steerings)
    tt, ss = np.meshgrid(throttles, steerings, indexing="ij")
    return throttles, steerings, np.column_stack([tt.ravel(), ss.ravel()])


def operating_features(maneuvers: Sequence[Maneuver]) -> np.ndarray:
    """(n, 2) operating point (throttle, signed steering) of each maneuver, scaled to [0, 1]."""
    raw = np.array([[m.throttle, m.sign * m.steering if m.kind != "straight" else 0.0] for m in maneuvers])
    low, high = raw.min(axis=0), raw.max(axis=0)
    span = np.where(high > low, high - low, 1.0)
    return (raw - low) / span


def scoring_points(
    maneuver: Maneuver, n_points: int, rows_per_maneuver: float
) -> tuple[np.ndarray, np.ndarray]:
    """Distinct control points along a maneuver's schedule and how many training rows each stands for."""
    controls = nominal_controls(maneuver, 30.0)
    index = np.linspace(0, len(controls) - 1, n_points).round().astype(int)
    points, counts = np.unique(np.round(controls[index], 6), axis=0, return_counts=True)
    return points, counts * (rows_per_maneuver / n_points)


def build_pool(
    cfg: CampaignConfig,
    maneuvers: Sequence[Maneuver],
    taken: np.ndarray,
    output_scale: np.ndarray,
    rows_per_maneuver: float,
    design_seed: int,
) -> Pool:
    """Assemble the `Pool` strategies select from."""
    points, owner, weights = [], [], []
    for i, m in enumerate(maneuvers):
        p, w = scoring_points(m, cfg.acquisition.score_points, rows_per_maneuver)
        points.append(p)
        weights.append(w)
        owner.append(np.full(len(p), i))
    _, _, grid = evaluation_grid(cfg)
    kind_names = sorted({m.kind for m in maneuvers}, key=KIND_ORDER.index)  # contiguous kind codes
    return Pool(
        maneuvers=tuple(maneuvers),
        features=operating_features(maneuvers),
        kinds=np.array([kind_names.index(m.kind) for m in maneuvers]),
        points=np.concatenate(points),
        owner=np.concatenate(owner),
        weights=np.concatenate(weights),
        taken=np.asarray(taken, dtype=bool),
        eval_grid=grid,
        output_scale=np.asarray(output_scale, dtype=np.float64),
        design_seed=design_seed,
        kind_distance=cfg.pool.kind_distance,
    )
