"""The physics kind's 95 % free-run fans hold 85-99 % of the true positions (the README's claim).

A small campaign of the shipped `dynamics.toml` (the physics kind with its gated, mirror-symmetric
correction and the prequential fan calibration), on a fixed seed: every round after the first (the
first has nothing to calibrate on yet) must hold 85-99 % of its test maneuvers' true positions in its
fans. Fans too narrow (an uncalibrated or overconfident model) or too wide (a scale run away) fail it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from activelearn.config import load_config
from activelearn.loop.campaign import Campaign

DYNAMICS = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "dynamics.toml"

# Measured on seed 0 (2026-11-28): rounds 1-3 0.988, 0.989, 0.989 (round 0, uncalibrated: 0.707).
SMALL = {
    "seed": 0,
    "strategy": "uniform",
    "tracking": {"enabled": False},
    "pool": {"size": 3, "duration": 15.0},
    "design": {"initial": 2, "per_round": 2, "max_maneuvers": 8},
    "test": {"kinds": ["skidpad", "fishhook", "slalom", "eight"], "throttles": [-0.4, 0.9],
             "steerings": [0.3927], "duration": 20.0},
}  # fmt: skip


@pytest.mark.slow  # a campaign of four rounds
def test_the_physics_kinds_calibrated_fans_hold_85_to_99_percent_of_true_positions(tmp_path):
    cfg = load_config(DYNAMICS, overrides={**SMALL, "output_dir": str(tmp_path / "runs")})
    assert cfg.model.kind == "physics" and cfg.design.fan_calibration == "prequential"
    rounds = Campaign(cfg, tmp_path / "c").run(figures=False, log_model=False).state.rounds
    assert len(rounds) == 4
    held = [r["rollout_coverage_95"] for r in rounds[1:]]
    assert all(0.85 <= share <= 0.99 for share in held), held
    assert all(r["fan_scale"] > 1.0 for r in rounds[1:]), [r["fan_scale"] for r in rounds]  # calibrated
