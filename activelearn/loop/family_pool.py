"""Candidate pools of maneuver families: Sobol draws over family parameters and their design coordinates.

A family pool (`[pool] families`) holds, per family, `size` scrambled-Sobol points over the family's
continuous parameters (ranges from `[pool.ranges]`), each driven in every configured direction (only
once where it never steers). Seeds (prbs) are drawn from the same seeded generator.

Space-filling strategies (uniform = greedy maximin, sobol, lhs) and batch penalties measure distances
in the *normalised family-parameter space*: each continuous parameter scaled to [0, 1] by its pool
range (a fixed parameter sits at 0.5), padded with 0.5 up to the family with most parameters, plus a
direction coordinate (ccw 1, cw 0, 0.5 without steering) when the pool has both directions. Families
differ by `kind_distance` on top, as kinds do in a reference pool. Seeds are no coordinate: two PRBS
draws with different seeds and equal parameters are the same point of the design.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd
from scipy.stats import qmc

from activelearn.config import PoolConfig
from activelearn.names import STEERING, THROTTLE, TIME
from activelearn.seeds import Stream, derived_rng
from simulator import KINDS, FamilyManeuver, Maneuver, ManeuverError, as_family
from simulator.families import FAMILIES

FAMILY_ORDER: tuple[str, ...] = tuple(FAMILIES)


def pool_families(cfg: PoolConfig) -> list[str]:
    """The pool's families in registry order."""
    return sorted(cfg.families, key=FAMILY_ORDER.index)


def _draw(cfg: PoolConfig, family: str) -> list[dict[str, float]]:
    """`cfg.size` parameter vectors of one family: Sobol over its continuous parameters, seeded per family."""
    spec = FAMILIES[family]
    rng = derived_rng(cfg.seed, Stream.FAMILY, family)
    continuous = spec.continuous
    with warnings.catch_warnings():  # any number of candidates, as the operating-point pool does
        warnings.filterwarnings("ignore", message=".*balance properties.*", category=UserWarning)
        unit = qmc.Sobol(len(continuous), scramble=True, rng=rng).random(cfg.size or 0)
    draws = []
    for row in unit:
        values: dict[str, float] = {}
        for u, p in zip(row, continuous, strict=True):
            low, high = cfg.family_range(family, p.name)
            values[p.name] = float(np.clip(round(low + float(u) * (high - low), 4), low, high))
        for p in spec.parameters:
            if p.integer:
                low, high = cfg.family_range(family, p.name)
                values[p.name] = float(rng.integers(int(low), int(high) + 1))
        draws.append(values)
    return draws


def family_maneuvers(cfg: PoolConfig) -> list[FamilyManeuver]:
    """The candidates of a family pool, in a stable order (family, Sobol index, direction), no duplicates."""
    seen: set[str] = set()
    maneuvers: list[FamilyManeuver] = []
    for family in pool_families(cfg):
        for values in _draw(cfg, family):
            for direction in cfg.directions:
                m = FamilyManeuver(family, values, direction, cfg.duration_of(family))
                if m.op_steering == 0.0 and m.direction != cfg.directions[0]:
                    continue  # never steers: one direction is enough
                if m.name not in seen:
                    seen.add(m.name)
                    maneuvers.append(m)
    return maneuvers


def _as_member(maneuver: Any) -> FamilyManeuver | None:
    """A candidate or prior run as a family member (reference kinds as their special case), else None."""
    if isinstance(maneuver, FamilyManeuver):
        return maneuver
    if getattr(maneuver, "kind", None) not in KINDS:
        return None
    try:
        reference = Maneuver(maneuver.kind, maneuver.throttle, maneuver.steering, maneuver.direction, 1.0)
        return as_family(reference)
    except ManeuverError:  # an operating point out of range
        return None


def family_features(maneuvers: Sequence[Any], cfg: PoolConfig) -> np.ndarray:
    """(n, d) coordinates in the normalised family-parameter space (see the module docstring)."""
    families = pool_families(cfg)
    width = max(len(FAMILIES[f].continuous) for f in families)
    both = len(cfg.directions) > 1
    features = np.full((len(maneuvers), width + both), 0.5)
    for i, maneuver in enumerate(maneuvers):
        member = _as_member(maneuver)
        if member is None or member.family not in families:
            continue
        values = member.values
        for j, p in enumerate(FAMILIES[member.family].continuous):
            low, high = cfg.family_range(member.family, p.name)
            features[i, j] = (values[p.name] - low) / (high - low) if high > low else 0.5
        if both and member.op_steering > 0.0:
            features[i, width] = 1.0 if member.direction == "ccw" else 0.0
    return features


def family_codes(maneuvers: Sequence[Any], cfg: PoolConfig) -> np.ndarray:
    """Integer kind code of each candidate or prior run: its family's index in the pool.

    A family outside the pool gets a code of its own (always "another kind"); a run that is no family
    member (an unknown kind, an operating point out of range) gets -1 (no kind distance). A reference
    eight is the figure_eight member of its nominal loop time.
    """
    families = pool_families(cfg)
    codes = []
    for maneuver in maneuvers:
        member = _as_member(maneuver)
        if member is None:
            codes.append(-1)
        elif member.family in families:
            codes.append(families.index(member.family))
        else:
            codes.append(len(families) + FAMILY_ORDER.index(member.family))
    return np.array(codes, dtype=int)


def is_family_pool(cfg: PoolConfig, maneuvers: Sequence[Any]) -> bool:
    """Whether the candidates are the family members of a family pool."""
    return bool(cfg.families) and all(isinstance(m, FamilyManeuver) for m in maneuvers)


def proposal_table(maneuvers: Sequence[Any], schedules: Sequence[str]) -> pd.DataFrame:
    """One row per proposal: family, direction, duration, a column per family parameter, schedule file.

    Columns of parameters a row's family lacks are empty; parameter columns follow the registry order.
    """
    columns: list[str] = []
    for family in FAMILY_ORDER:
        if any(getattr(m, "kind", None) == family for m in maneuvers):
            columns += [p for p in FAMILIES[family].names if p not in columns]
    rows = [
        {"maneuver": m.kind, "direction": m.direction, "duration": m.duration, **m.values, "schedule": path}
        for m, path in zip(maneuvers, schedules, strict=True)
    ]
    table = pd.DataFrame(rows, columns=["maneuver", "direction", "duration", *columns, "schedule"])
    seeds = {p.name for f in FAMILIES.values() for p in f.parameters if p.integer}
    for column in seeds & set(columns):
        table[column] = table[column].astype("Int64")  # a seed reads as a whole number, empty elsewhere
    return table


def schedule_table(maneuver: FamilyManeuver, rate_hz: float) -> pd.DataFrame:
    """The commands to drive: time (s), throttle, steering (rad, + left), each held until the next row."""
    controls = maneuver.controls(rate_hz)
    return pd.DataFrame(
        {TIME: np.arange(len(controls)) / rate_hz, THROTTLE: controls[:, 0], STEERING: controls[:, 1]}
    )
