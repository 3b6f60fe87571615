"""What a comparison leaves in MLflow: its parent run's series, note and params, its children's steps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from activelearn.config import load_config
from activelearn.studies.compare import band_series, compare, comparison_note, comparison_params, config_hash
from activelearn.studies.tracking import NOTE_TAG, Tracker

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"


def _curves() -> pd.DataFrame:
    return pd.DataFrame([
        {"strategy": s, "seed": seed, "round": r, "n_maneuvers": 3 + 2 * r, "n_samples": 100 * (r + 1) + seed,
         "test_rmse": 0.5 / (r + 1) + 0.01 * seed + (0.1 if s == "auto" else 0.0)}
        for s in ("uniform", "auto") for seed in range(3) for r in range(3)
    ])  # fmt: skip


def test_band_series_is_each_strategys_mean_and_standard_error_at_each_maneuver_count() -> None:
    rows = band_series(_curves(), ["test_rmse"])
    assert [step for step, _ in rows] == [3, 5, 7]  # maneuvers collected, not training rows
    _, values = rows[1]
    seeds = np.array([0.25, 0.26, 0.27])
    sem = seeds.std(ddof=1) / np.sqrt(3)
    assert values["uniform/test_rmse_mean"] == pytest.approx(seeds.mean())
    assert values["uniform/test_rmse_lo"] == pytest.approx(seeds.mean() - sem)
    assert values["uniform/test_rmse_hi"] == pytest.approx(seeds.mean() + sem)
    assert values["auto/test_rmse_mean"] == pytest.approx(seeds.mean() + 0.1)
    assert set(values) == {f"{s}/test_rmse_{k}" for s in ("uniform", "auto") for k in ("mean", "lo", "hi")}


def test_the_parent_run_says_what_was_compared_and_holds_no_single_campaign_params() -> None:
    cfg = load_config(SMOKE)
    params = comparison_params(cfg, ["uniform", "max_epistemic"], [0, 1, 2], "test_rmse", "uniform")
    assert "strategy" not in params and "seed" not in params
    assert params["strategies"] == ["uniform", "max_epistemic"] and params["seeds"] == [0, 1, 2]
    assert params["config"] == "smoke" and params["config_hash"] == config_hash(cfg)
    # the hash is what the campaigns share: a campaign's own strategy and seed leave it alone
    assert config_hash(cfg.model_copy(update={"strategy": "uniform", "seed": 7})) == config_hash(cfg)
    other = cfg.model_copy(update={"training": cfg.training.model_copy(update={"epochs": 3})})
    assert config_hash(other) != config_hash(cfg)
    note = comparison_note(cfg, ["uniform", "max_epistemic"], [0, 1, 2], "test_rmse", "uniform")
    for text in ("`uniform`", "`max_epistemic`", "seeds 0, 1, 2", "`smoke`", config_hash(cfg),
                 "comparison.png", "up to 7 maneuvers", "Group by"):  # fmt: skip
        assert text in note, text


@pytest.mark.slow
def test_a_comparison_shows_its_curves_on_the_parent_run_of_a_sqlite_store(tmp_path: Path) -> None:
    uri = f"sqlite:///{tmp_path}/mlruns/mlflow.db"
    cfg = load_config(SMOKE, overrides={
        "output_dir": str(tmp_path / "runs"), "tracking": {"uri": uri}, "training": {"epochs": 25},
        "design": {"initial": 3, "per_round": 2, "max_maneuvers": 5},
    })  # fmt: skip
    strategies, seeds = ["uniform", "max_epistemic"], [0, 1]
    result = compare(cfg, strategies, seeds, directory=tmp_path / "cmp", workers=1)
    tracker = Tracker(uri, cfg.tracking.experiment)
    parent = tracker.client.get_run(result.parent_run_id)

    # params: the comparison's, none of one campaign's
    params = parent.data.params
    assert "strategy" not in params and "seed" not in params
    assert params["strategies"] == "uniform,max_epistemic" and params["seeds"] == "0,1"
    assert params["config"] == "smoke" and params["config_hash"] == config_hash(cfg)
    # the note: what was compared and where the figure is
    note = parent.data.tags[NOTE_TAG]
    assert tracker.note(result.parent_run_id) == note
    for text in ("`uniform`", "`max_epistemic`", "seeds 0, 1", "comparison.png"):
        assert text in note, text
    assert "| uniform |" in note  # the final values, once finished
    # and the figure itself, drawn by MLflow's page from the run's own artifact
    assert f"(get-artifact?path=comparison.png&run_uuid={result.parent_run_id})" in note
    assert "comparison.png" in {a.path for a in tracker.client.list_artifacts(result.parent_run_id)}

    # every child: named strategy/seed, tagged with its strategy, stepped by maneuvers collected
    children = [tracker.client.get_run(r) for r in tracker.child_runs(result.parent_run_id)]
    names = sorted(c.info.run_name for c in children)
    assert names == sorted(f"{s}/seed{k}" for s in strategies for k in seeds)
    child_steps = set()
    for child in children:
        strategy = child.data.tags["strategy"]
        assert child.info.run_name.startswith(f"{strategy}/") and child.data.params["strategy"] == strategy
        rmse = tracker.metric_history(child.info.run_id, "test_rmse")
        maneuvers = tracker.metric_history(child.info.run_id, "n_maneuvers")
        assert [s for s, _ in rmse] == [s for s, _ in maneuvers] == [int(v) for _, v in maneuvers] == [3, 5]
        rows = tracker.metric_history(child.info.run_id, "n_samples")
        assert [s for s, _ in rows] == [3, 5] and rows[0][1] < rows[1][1]  # the training rows: a metric
        child_steps.update(s for s, _ in rmse)

    # the parent: each strategy's mean and ± 1 s.e. band over seeds, at the children's steps
    curves = result.curves
    for strategy in strategies:
        series = {k: tracker.metric_history(result.parent_run_id, f"{strategy}/test_rmse_{k}")
                  for k in ("mean", "lo", "hi")}  # fmt: skip
        assert [s for s, _ in series["mean"]] == sorted(child_steps) == [3, 5]
        for (step, mean), (_, lo), (_, hi) in zip(series["mean"], series["lo"], series["hi"], strict=True):
            values = curves[(curves["strategy"] == strategy) & (curves["n_maneuvers"] == step)]["test_rmse"]
            assert mean == pytest.approx(values.mean()) and len(values) == 2
            assert lo <= mean <= hi and hi - mean == pytest.approx(values.std(ddof=1) / np.sqrt(2))
        assert tracker.metric_history(result.parent_run_id, f"summary/{strategy}_final_rmse")
