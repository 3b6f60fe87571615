"""experiments/investigations/oracle_luck.py: a finished campaign's design driven again under its own seed and
another (real MuJoCo, real models, the smoke config shrunk)."""

from __future__ import annotations

import sys
from pathlib import Path

from activelearn.config import load_config
from activelearn.loop.campaign import Campaign

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments" / "investigations"))

from oracle_luck import ReplayCampaign  # noqa: E402


def test_a_replayed_design_is_its_campaign_under_its_own_seed_and_keeps_its_picks_under_another(tmp_path):
    """Under the campaign's own seed the replay is the campaign, to the bit; under another seed it drives
    the same batches (the initial design's too, which that seed would draw otherwise): only luck differs."""
    overrides = {
        "training": {"epochs": 10},
        "design": {"initial": 3, "per_round": 2, "max_maneuvers": 5, "initial_start": "random"},
    }
    cfg = load_config(ROOT / "experiments" / "configs" / "smoke.toml", overrides={"seed": 3, **overrides})
    other_seed = cfg.model_copy(update={"seed": 4})
    run = {"figures": False, "log_model": False}
    original = Campaign(cfg, tmp_path / "original").run(**run).state
    own = Campaign(other_seed, tmp_path / "own").run(**run).state
    assert own.batches[0] != original.batches[0], "seed 4's own initial design must differ to test anything"

    same = ReplayCampaign(cfg, tmp_path / "same", original.batches).run(**run).state
    assert same.batches == original.batches
    assert [r["test_rmse"] for r in same.rounds] == [r["test_rmse"] for r in original.rounds]

    replayed = ReplayCampaign(other_seed, tmp_path / "replayed", original.batches).run(**run).state
    assert replayed.batches == original.batches
    assert replayed.rounds[-1]["test_rmse"] != original.rounds[-1]["test_rmse"]
