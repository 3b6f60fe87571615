"""The physics kind's 95 % free-run fans hold 85-99 % of the true positions (the README's claim).

A small campaign of the shipped `dynamics.toml` (the physics kind with its gated, mirror-symmetric
correction, the core's misfit carried in the fans and the prequential fan calibration), on a fixed seed:
every round, the first too (nothing to calibrate on yet: its fans are the model's own), must hold 85-99 %
of its test maneuvers' true positions in its fans. Fans too narrow (an uncalibrated or overconfident
model) or too wide (a scale run away) fail it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from activelearn.config import load_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.evaluation import MIN_TRIM_MANEUVERS, applied_fan_scale, calibrated_maneuvers
from activelearn.loop.state import CampaignState

DYNAMICS = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "dynamics.toml"

# Measured on seed 0: rounds 0-3 0.978, 0.972, 0.971, 0.961 (2026-11-30, with the discrepancy; before it
# round 0 held 0.707, rounds 1-3 0.988, 0.989, 0.989).
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
    held = [r["rollout_coverage_95"] for r in rounds]
    assert all(0.85 <= share <= 0.99 for share in held), held
    assert all(r["fan_scale"] > 1.0 for r in rounds[1:]), [r["fan_scale"] for r in rounds]  # calibrated


def _state(needs: list[float], batches: list[int]) -> CampaignState:
    """A campaign after len(needs) rounds: batch sizes `batches` (the first the initial design), round
    j's need measured on batch j + 1."""
    picks = iter(range(sum(batches)))
    state = CampaignState("hash", "uniform", 0, batches=[[next(picks) for _ in range(b)] for b in batches])
    counts = [sum(batches[: j + 1]) for j in range(len(needs))]
    pairs = zip(counts, needs, strict=True)
    state.rounds = [{"n_maneuvers": n, "prequential_fan_scale": need} for n, need in pairs]
    return state


def test_a_fan_is_narrowed_only_once_enough_maneuvers_measured_the_need_and_widened_at_once():
    """Two easy signals ask a fan 5x narrower: not yet (the model's own fans). A need to widen is applied
    from the first batch. Once MIN_TRIM_MANEUVERS maneuvers were measured, the geometric mean of every
    need is applied, narrowing too; a round whose need could not be measured counts no maneuvers."""
    assert MIN_TRIM_MANEUVERS == 6
    first = _state([0.2], [4, 2])
    assert calibrated_maneuvers(first) == 2 and applied_fan_scale(first) == 1.0
    assert applied_fan_scale(_state([3.0], [4, 2])) == pytest.approx(3.0)
    three = _state([0.2, 0.5, 0.4], [4, 2, 2, 2])
    assert calibrated_maneuvers(three) == 6
    assert applied_fan_scale(three) == pytest.approx((0.2 * 0.5 * 0.4) ** (1 / 3))
    skipped = _state([0.2, float("nan"), 0.4], [4, 2, 2, 2])
    assert calibrated_maneuvers(skipped) == 4 and applied_fan_scale(skipped) == 1.0
