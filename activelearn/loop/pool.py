"""Candidate pools, the evaluation grid, the target region and the fixed test set, from a campaign config.

Family pools (`[pool] families`) are drawn by `activelearn.loop.family_pool`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.stats import qmc

from activelearn.config import MAX_STEERING, CampaignConfig, PoolConfig, TestSetConfig
from activelearn.loop.collection import rows_per_maneuver
from activelearn.loop.family_pool import family_codes, family_features, family_maneuvers, is_family_pool
from activelearn.loop.strategy import Pool
from activelearn.numerics.paths import path_inputs
from activelearn.numerics.surrogate import model_inputs
from simulator import Maneuver, nominal_controls
from simulator.datasheet import LOG_RATE_HZ

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
    kinds: Sequence[str],
    directions: Sequence[str],
    points: Sequence[tuple[float, float]],
    duration: float | Callable[[str], float],
    full_lock: float | None = None,
) -> list[Maneuver]:
    """All maneuvers of the given kinds over the operating points, without duplicates.

    Straight maneuvers have no steering and no direction; fishhooks ramp to full lock whatever the
    grid says, so they vary in throttle and direction only. `duration` is seconds, or seconds per kind;
    `full_lock` the steering a fishhook ramps to (None: the default car's).
    """
    lock = MAX_STEERING if full_lock is None else full_lock
    seconds = duration if callable(duration) else (lambda kind: float(duration))
    seen: set[str] = set()
    maneuvers: list[Maneuver] = []
    for kind in sorted(kinds, key=KIND_ORDER.index):
        for throttle, steering in points:
            if throttle == 0.0:  # zero throttle brakes: a standing car teaches nothing
                continue
            for direction in directions:
                if kind == "straight":
                    m = Maneuver(kind, throttle, 0.0, "ccw", seconds(kind))
                elif kind == "fishhook":
                    m = Maneuver(kind, throttle, lock, direction, seconds(kind))
                else:
                    m = Maneuver(kind, throttle, steering, direction, seconds(kind))
                if m.name not in seen:
                    seen.add(m.name)
                    maneuvers.append(m)
    return maneuvers


def pool_maneuvers(cfg: PoolConfig) -> list[Any]:
    """The candidate maneuvers of a pool config, in a stable order (kind, throttle, steering, direction).

    A family pool (`families`) gives family members instead (`activelearn.loop.family_pool`).
    """
    if cfg.families:
        return list(family_maneuvers(cfg))
    return _expand(cfg.kinds, cfg.directions, _operating_points(cfg), cfg.duration_of, cfg.full_lock)


def grid_maneuvers(
    kinds: Sequence[str],
    directions: Sequence[str],
    throttles: Sequence[float],
    steerings: Sequence[float],
    duration: float,
    full_lock: float | None = None,
) -> list[Maneuver]:
    """The maneuvers of a kinds x directions x throttles x steerings grid (test sets, prior grids)."""
    points = [(float(t), float(s)) for t in throttles for s in steerings]
    return _expand(kinds, directions, points, duration, full_lock)


def test_maneuvers(cfg: TestSetConfig) -> list[Maneuver]:
    """The fixed test maneuvers: a grid independent of every campaign seed."""
    c = cfg
    return grid_maneuvers(c.kinds, c.directions, c.throttles, c.steerings, c.duration, c.full_lock)


test_maneuvers.__test__ = False  # type: ignore[attr-defined]  # not a pytest test


def maneuver_controls(maneuver: Any, rate_hz: float) -> np.ndarray:
    """(T, 2) throttle and signed steering a candidate applies: recorded if it has them, else nominal."""
    recorded = getattr(maneuver, "recorded_controls", None)
    return (
        np.asarray(recorded, dtype=np.float64)
        if recorded is not None
        else nominal_controls(maneuver, rate_hz)
    )


def evaluation_grid(
    cfg: CampaignConfig, maneuvers: Sequence[Any] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Throttle values, signed steering values and the (T*S, 2) grid of controls spanning the pool."""
    maneuvers = pool_maneuvers(cfg.pool) if maneuvers is None else maneuvers
    controls = np.concatenate([maneuver_controls(m, 1.0) for m in maneuvers])
    t_low, t_high = float(controls[:, 0].min()), float(controls[:, 0].max())
    s_max = float(np.abs(controls[:, 1]).max()) or cfg.vehicle.spec.steering.limit.value
    s_low = -s_max if (controls[:, 1] < 0).any() or "cw" in cfg.pool.directions else 0.0
    s_high = s_max if (controls[:, 1] >= 0).any() else 0.0
    throttles = np.linspace(t_low, t_high, cfg.acquisition.grid_throttles)
    steerings = np.linspace(s_low, s_high, cfg.acquisition.grid_steerings)
    tt, ss = np.meshgrid(throttles, steerings, indexing="ij")
    return throttles, steerings, np.column_stack([tt.ravel(), ss.ravel()])


def target_points(
    cfg: CampaignConfig, pool: Sequence[Any], test: Sequence[Any]
) -> tuple[np.ndarray, np.ndarray]:
    """(G, 2) controls where the model must be good (`[target]`) and the weight of each point.

    "test": the distinct controls the test maneuvers apply, weighted by how many log steps hold them
    (a skidpad is one point held for its whole duration, a slalom sweeps); "pool": the evaluation grid
    spanning the pool; "box": a grid over the configured region. At most `max_points` points are kept
    (a seeded, weight-proportional subset), so the integral's cost stays bounded.
    """
    target = cfg.target
    if target.region == "pool":
        _, _, grid = evaluation_grid(cfg, pool)
        return grid, np.ones(len(grid))
    if target.region == "box":
        assert target.throttle_range is not None and target.steering_range is not None
        throttles = np.linspace(*target.throttle_range, target.grid_size)
        magnitudes = np.linspace(*target.steering_range, target.grid_size)
        signs = [1.0 if d == "ccw" else -1.0 for d in target.directions]
        steerings = np.unique(np.concatenate([s * magnitudes for s in signs]))
        tt, ss = np.meshgrid(throttles, steerings, indexing="ij")
        grid = np.column_stack([tt.ravel(), ss.ravel()])
        return grid, np.ones(len(grid))
    controls = np.concatenate([maneuver_controls(m, cfg.simulation.rate_hz) for m in test])
    points, counts = np.unique(np.round(controls, 3), axis=0, return_counts=True)
    weights = counts / counts.sum() * len(points)
    if len(points) > target.max_points:
        keep = np.random.default_rng(0).choice(
            len(points), target.max_points, replace=False, p=counts / counts.sum()
        )
        keep.sort()
        points, weights = points[keep], np.full(target.max_points, 1.0)
    return points, weights


def operating_bounds(maneuvers: Sequence[Any]) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest (throttle, signed steering) operating point of a set of candidates."""
    raw = np.array([operating_point(m) for m in maneuvers])
    return raw.min(axis=0), raw.max(axis=0)


def operating_point(maneuver: Any) -> tuple[float, float]:
    """(throttle, signed steering amplitude) of a candidate; a straight has no steering."""
    return float(maneuver.throttle), (
        maneuver.sign * maneuver.steering if maneuver.kind != "straight" else 0.0
    )


def operating_features(
    maneuvers: Sequence[Any], bounds: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """(n, 2) operating point (throttle, signed steering) of each maneuver, scaled to [0, 1] by `bounds`.

    `bounds` default to the maneuvers' own; pass the pool's to scale other maneuvers (a prior) alike.
    """
    raw = np.array([operating_point(m) for m in maneuvers], dtype=np.float64).reshape(-1, 2)
    low, high = bounds if bounds is not None else operating_bounds(maneuvers)
    span = np.where(high > low, high - low, 1.0)
    return (raw - low) / span


def kind_codes(maneuvers: Sequence[Any]) -> tuple[list[str], np.ndarray]:
    """Contiguous integer codes of the candidates' kinds (in KIND_ORDER) and the kind names."""
    names = sorted({m.kind for m in maneuvers}, key=KIND_ORDER.index)
    return names, np.array([names.index(m.kind) for m in maneuvers])


def scoring_points(maneuver: Any, n_points: int, rows_per_maneuver: float) -> tuple[np.ndarray, np.ndarray]:
    """Distinct control points along a maneuver's schedule and how many training rows each stands for."""
    controls = maneuver_controls(maneuver, LOG_RATE_HZ)  # points along the schedule, whatever the log rate
    index = np.linspace(0, len(controls) - 1, n_points).round().astype(int)
    points, counts = np.unique(np.round(controls[index], 6), axis=0, return_counts=True)
    return points, counts * (rows_per_maneuver / n_points)


def maneuver_costs(cfg: CampaignConfig, maneuvers: Sequence[Any]) -> np.ndarray:
    """Seconds each maneuver costs on the track: its duration plus the per-maneuver set-up time."""
    return np.array([m.duration + cfg.design.setup_seconds for m in maneuvers], dtype=np.float64)


def build_pool(
    cfg: CampaignConfig,
    maneuvers: Sequence[Any],
    taken: np.ndarray,
    output_scale: np.ndarray,
    target: tuple[np.ndarray, np.ndarray],
    design_seed: int,
    *,
    affordable: np.ndarray | None = None,
    prior: Sequence[Any] = (),
) -> Pool:
    """Assemble the `Pool` strategies select from; `prior` are the maneuvers a warm start holds."""
    points, owner, weights = [], [], []
    for i, m in enumerate(maneuvers):
        rows = rows_per_maneuver(m.duration, cfg.simulation, cfg.data)
        p, w = scoring_points(m, cfg.acquisition.score_points, rows)
        points.append(p)
        weights.append(w)
        owner.append(np.full(len(p), i))
    prior_features = prior_kinds = None
    if is_family_pool(cfg.pool, maneuvers):  # distances in the normalised family-parameter space
        features, kinds = family_features(maneuvers, cfg.pool), family_codes(maneuvers, cfg.pool)
        if len(prior):
            prior_features, prior_kinds = family_features(prior, cfg.pool), family_codes(prior, cfg.pool)
    else:
        features, kinds, prior_features, prior_kinds = _operating_design(maneuvers, prior)
    target_x, target_w = target
    return Pool(
        maneuvers=tuple(maneuvers),
        features=features,
        kinds=kinds,
        points=np.concatenate(points),
        owner=np.concatenate(owner),
        weights=np.concatenate(weights),
        taken=np.asarray(taken, dtype=bool),
        target=np.asarray(target_x, dtype=np.float64),
        target_weights=np.asarray(target_w, dtype=np.float64),
        output_scale=np.asarray(output_scale, dtype=np.float64),
        design_seed=design_seed,
        kind_distance=cfg.pool.kind_distance,
        costs=maneuver_costs(cfg, maneuvers),
        affordable=affordable,
        prior_features=prior_features,
        prior_kinds=prior_kinds,
    )


def _operating_design(
    maneuvers: Sequence[Any], prior: Sequence[Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Features and kind codes of reference candidates and prior runs (operating points, kinds)."""
    bounds = operating_bounds(maneuvers)
    kind_names, kinds = kind_codes(maneuvers)
    prior_features = prior_kinds = None
    if len(prior):
        prior_features = operating_features(prior, bounds)
        # a prior kind outside the pool gets its own code (always "another kind"); unknown = -1
        prior_kinds = np.array(
            [
                -1
                if m.kind not in KIND_ORDER
                else kind_names.index(m.kind)
                if m.kind in kind_names
                else len(kind_names) + KIND_ORDER.index(m.kind)
                for m in prior
            ]
        )
    return operating_features(maneuvers, bounds), kinds, prior_features, prior_kinds


def path_points(
    cfg: CampaignConfig, model: Any, maneuvers: Sequence[Any], test: Sequence[Any], target: np.ndarray
) -> dict[str, Any]:
    """Pool points of a dynamic model along each candidate's predicted path (and the target's).

    `test`: the test maneuvers (the target follows their paths where `[target] region = "test"`);
    `target`: the target region's controls otherwise.
    """
    rate, n_points = cfg.simulation.rate_hz, cfg.acquisition.score_points
    inputs = path_inputs(model, [maneuver_controls(m, rate) for m in maneuvers], n_points, rate_hz=rate)
    rows = [rows_per_maneuver(m.duration, cfg.simulation, cfg.data) for m in maneuvers]
    fields: dict[str, Any] = {
        "points": np.concatenate(inputs),
        "owner": np.repeat(np.arange(len(inputs)), n_points),
        "weights": np.repeat(np.asarray(rows) / n_points, n_points),
    }
    if cfg.target.region == "test" and test:
        per_maneuver = max(1, cfg.target.max_points // len(test))
        paths = path_inputs(model, [maneuver_controls(m, rate) for m in test], per_maneuver, rate_hz=rate)
        fields.update(target=np.concatenate(paths), target_weights=None)
    else:
        fields["target"] = model_inputs(model, target)
    return fields
