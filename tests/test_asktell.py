"""A real car in the loop, rehearsed: propose, drive (the `simulate` CLI), ingest, propose; logs pools.

Everything through the real CLI, MuJoCo and a real SQLite MLflow store; sizes are shrunk (short
maneuvers, few epochs), never the components.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from activelearn.cli import main
from activelearn.config import load_config
from activelearn.data import read_autodrive_log
from activelearn.loop.asktell import open_campaign, read_log
from activelearn.loop.campaign import Campaign, CampaignState
from activelearn.loop.collection import test_set_from_logs
from activelearn.loop.oracles import make_oracle
from activelearn.studies.compare import compare
from activelearn.studies.tracking import Tracker

CONFIG = """
name = "car"
strategy = "max_epistemic"
[pool]
kinds = ["straight", "skidpad", "fishhook"]
throttles = [0.3, 0.6, 0.9]
steerings = [0.15, 0.35, 0.5236]
duration = 12.0
[data]
stride = 10
[design]
initial = 2
per_round = 2
max_maneuvers = 6
[acquisition]
n_samples = 16
grid_throttles = 5
grid_steerings = 5
[training]
epochs = 20
[test]
throttles = [0.45]
steerings = [0.25]
duration = 10.0
[oracle]
kind = "external"
"""


def _snapshot(directory: Path) -> dict[str, str]:
    """Path -> content hash of every file under a directory."""
    return {
        str(p.relative_to(directory)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(directory.rglob("*"))
        if p.is_file()
    }


def _drive(row: pd.Series, out: Path) -> Path:
    """Drive one proposal with the simulate CLI (the stand-in for the car), writing an AutoDRIVE log."""
    args = ["simulate", "--maneuver", row["maneuver"], "--direction", row["direction"],
            "--throttle", str(row["throttle"]), "--steering", str(row["steering"]),
            "--duration", str(row["duration"]), "--seed", "7", "--autodrive", "--out", str(out)]  # fmt: skip
    assert main(args) == 0
    return out


@pytest.fixture
def proposed(tmp_path, capsys):
    config = tmp_path / "car.toml"
    config.write_text(CONFIG + f'[tracking]\nuri = "sqlite:///{tmp_path}/mlruns/mlflow.db"\n')
    directory = tmp_path / "campaign"
    assert main(["campaign", "propose", str(config), "--out", str(directory), "--seed", "1"]) == 0
    out = capsys.readouterr().out
    assert "drive these 2 maneuvers" in out and "round-000.csv" in out
    return tmp_path, directory


def test_the_initial_design_is_one_for_every_seed_unless_it_starts_where_the_seed_draws(tmp_path, capsys):
    """`[design] initial_start`: "centre" (the default) starts every seed's initial design at the candidate
    nearest the pool's centre (only ties after it differ: on a Sobol pool one design up to the mirror);
    "random" starts each where its seed draws."""
    designs = {}
    for start in ("centre", "random"):
        config = tmp_path / f"{start}.toml"
        config.write_text(CONFIG.replace("[design]\n", f'[design]\ninitial_start = "{start}"\n')
                          + "[tracking]\nenabled = false\n")  # fmt: skip
        for seed in range(6):
            directory = tmp_path / f"{start}{seed}"
            args = ["campaign", "propose", str(config), "--out", str(directory), "--seed", str(seed)]
            assert main(args) == 0
            rows = pd.read_csv(directory / "proposals" / "round-000.csv").drop(columns="direction")
            rows = rows.sort_values(list(rows.columns))
            designs.setdefault(start, set()).add(tuple(map(tuple, rows.values)))
    capsys.readouterr()
    assert set.intersection(*map(set, designs["centre"])) == {("straight", 0.6, 0.0, 12.0)}
    assert not set.intersection(*map(set, designs["random"])) and len(designs["random"]) >= 4


@pytest.mark.slow
def test_propose_drive_ingest_propose_round_trip(proposed, capsys):
    tmp_path, directory = proposed
    proposals = pd.read_csv(directory / "proposals" / "round-000.csv")
    assert list(proposals.columns) == ["maneuver", "direction", "throttle", "steering", "duration"]
    logs = [_drive(row, tmp_path / f"log{i}.csv") for i, row in proposals.iterrows()]
    # one log at a time, in reverse order: the first ingest says what is still missing
    assert main(["campaign", "ingest", str(directory), str(logs[1])]) == 0
    out = capsys.readouterr().out
    assert "still missing" in out
    assert CampaignState.load(directory).rounds == []
    assert main(["campaign", "ingest", str(directory), str(logs[0])]) == 0
    out = capsys.readouterr().out
    assert "round-001.csv" in out
    state = CampaignState.load(directory)
    assert len(state.rounds) == 1 and len(state.batches) == 1 and len(state.pending) == 2
    assert len(state.ingested) == 2
    # the next round, then the budget is spent: 2 + 2 + 2 maneuvers
    for round_index in (1, 2):
        proposals = pd.read_csv(directory / "proposals" / f"round-{round_index:03d}.csv")
        logs = [_drive(row, tmp_path / f"r{round_index}-{i}.csv") for i, row in proposals.iterrows()]
        assert main(["campaign", "ingest", str(directory), *map(str, logs)]) == 0
    state = CampaignState.load(directory)
    assert state.finished and state.stop_reason == "max_maneuvers" and len(state.taken) == 6
    # every round reached the same MLflow run, which is finished now
    tracker = Tracker(f"sqlite:///{tmp_path}/mlruns/mlflow.db")
    assert [n for n, _ in tracker.metric_history(state.run_id, "n_maneuvers")] == [
        int(r["n_maneuvers"]) for r in state.rounds
    ]
    assert tracker.run_status(state.run_id) == "FINISHED"


@pytest.mark.slow
def test_an_ingest_interrupted_after_taking_its_logs_is_finished_with_resume(proposed, capsys):
    tmp_path, directory = proposed
    proposals = pd.read_csv(directory / "proposals" / "round-000.csv")
    logs = [_drive(row, tmp_path / f"log{i}.csv") for i, row in proposals.iterrows()]
    reference = tmp_path / "reference"  # the same campaign, its ingest run through
    shutil.copytree(directory, reference)
    assert main(["campaign", "ingest", str(reference), *map(str, logs), "--no-tracking"]) == 0
    # The logs are taken in (the batch committed), then the ingest is killed before it proposes.
    campaign = open_campaign(directory)
    frames = [read_log(log).table for log in logs]  # proposal order, as ingest stages them
    campaign.receive(frames)
    capsys.readouterr()
    assert main(["campaign", "ingest", str(directory), "--no-tracking"]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(["campaign", "ingest", str(directory), "--resume", "--no-tracking"]) == 0
    assert "round-001.csv" in capsys.readouterr().out
    finished, expected = CampaignState.load(directory), CampaignState.load(reference)
    assert finished.batches == expected.batches and finished.pending == expected.pending
    assert [r["test_rmse"] for r in finished.rounds] == [r["test_rmse"] for r in expected.rounds]
    name = "proposals/round-001.csv"
    assert (directory / name).read_text() == (reference / name).read_text()


@pytest.mark.slow
def test_bad_logs_are_refused_and_the_directory_is_unchanged(proposed, capsys):
    tmp_path, directory = proposed
    proposals = pd.read_csv(directory / "proposals" / "round-000.csv")
    good = _drive(proposals.iloc[0], tmp_path / "good.csv")
    assert main(["campaign", "ingest", str(directory), str(good)]) == 0
    capsys.readouterr()
    before = _snapshot(directory)

    open_one = proposals.iloc[1]
    assert open_one["maneuver"] == "skidpad"  # a turn: its amplitude, direction and shape can differ
    other_steering = 0.35 if open_one["steering"] != 0.35 else 0.15
    other_direction = "ccw" if open_one["direction"] == "cw" else "cw"
    unplanned = {
        "throttle": open_one.copy(),
        "steering amplitude": open_one.copy(),
        "direction": open_one.copy(),
        "shape": open_one.copy(),
    }
    unplanned["throttle"]["throttle"] = 0.9 if open_one["throttle"] != 0.9 else 0.3
    unplanned["steering amplitude"]["steering"] = other_steering
    unplanned["direction"]["direction"] = other_direction
    unplanned["shape"]["maneuver"] = "slalom"  # the same amplitude, oscillating instead of constant
    cut = tmp_path / "cut.csv"
    whole = _drive(proposals.iloc[1], tmp_path / "whole.csv").read_text().splitlines(keepends=True)
    cut.write_text("".join(whole[: len(whole) // 2]) + whole[len(whole) // 2][:17])  # cut mid-line
    short = tmp_path / "short.csv"
    short.write_text("".join(whole[: len(whole) // 2]))  # cut at a line: half the proposed duration
    cases = {
        "repeated": (good, "ingested already"),
        **{
            f"another {what}": (_drive(row, tmp_path / f"unplanned {what}.csv"), "matches no open proposal")
            for what, row in unplanned.items()
        },
        "cut mid-line": (cut, "expected"),
        "cut short": (short, "cut off"),
    }
    for name, (log, reason) in cases.items():
        assert main(["campaign", "ingest", str(directory), str(log)]) == 2, name
        err = capsys.readouterr().err
        assert reason in err and str(log.name) in err and err.count("\n") == 1, (name, err)
        assert _snapshot(directory) == before, name


@pytest.mark.slow
def test_a_logs_pool_in_the_autodrive_layout_runs_compare(tmp_path):
    root = tmp_path / "nigel"
    n = 0
    for kind, steerings in (("skidpad", (0.15, 0.35, 0.5236)), ("straight", (0.0,))):
        for throttle in (0.3, 0.6, 0.9):
            for steering in steerings:
                for direction in ("ccw", "cw") if steering else ("ccw",):
                    n += 1
                    row = pd.Series({"maneuver": kind, "direction": direction, "throttle": throttle,
                                     "steering": steering, "duration": 12.0})  # fmt: skip
                    _drive(row, root / f"{kind}_30_hz" / f"V{n} Log.csv")
    assert len(read_autodrive_log(root / "skidpad_30_hz" / "V1 Log.csv")) > 300
    config = tmp_path / "logs.toml"
    text = CONFIG.replace('kind = "external"', f'kind = "logs"\npath = "{root}"')
    config.write_text(text)
    cfg = load_config(
        config, overrides={"output_dir": str(tmp_path / "runs"), "tracking": {"enabled": False}}
    )
    result = compare(cfg, ["uniform", "max_epistemic"], [0, 1], directory=tmp_path / "cmp", workers=1)
    curves = result.curves
    assert set(curves["strategy"]) == {"uniform", "max_epistemic"}
    assert curves.groupby(["strategy", "seed"])["n_maneuvers"].max().eq(6).all()
    # the test set is a held-out share of the recorded logs; no candidate is ever one of them
    state = CampaignState.load(tmp_path / "cmp" / "uniform" / "seed0")
    assert len(set(state.taken)) == 6
    oracle = make_oracle(cfg, tmp_path / "runs")
    files = set(root.rglob("*.csv"))
    candidates = {root / m.name for m in oracle.candidates()}
    held = sorted(files - candidates)
    assert candidates < files and len(held) == round(cfg.oracle.test_fraction * len(files))
    expected = test_set_from_logs([read_autodrive_log(f) for f in held], cfg.data)
    np.testing.assert_array_equal(oracle.test_set().x, expected.x)
    np.testing.assert_array_equal(oracle.test_set().y_noisy, expected.y_noisy)


@pytest.mark.parametrize("oracle", ["external", "logs"])
def test_test_logs_are_the_test_set_and_no_candidate_is_held_out(tmp_path, oracle):
    """`[test] logs`: the recorded logs are the test set (not the simulated grid, not a held-out share)."""
    recorded = tmp_path / "test logs"
    for i, (throttle, steering) in enumerate(((0.45, 0.25), (0.75, 0.45))):
        row = pd.Series({"maneuver": "skidpad", "direction": "ccw", "throttle": throttle,
                         "steering": steering, "duration": 10.0})  # fmt: skip
        _drive(row, recorded / f"V{i} Log.csv")
    config = tmp_path / "car.toml"
    config.write_text(CONFIG)
    if oracle == "logs":
        root = tmp_path / "nigel" / "skidpad_30_hz"
        for i, throttle in enumerate((0.3, 0.6, 0.9)):  # a small logs pool
            row = pd.Series({"maneuver": "skidpad", "direction": "cw", "throttle": throttle,
                             "steering": 0.35, "duration": 8.0})  # fmt: skip
            _drive(row, root / f"V{i} Log.csv")
        config.write_text(CONFIG.replace('kind = "external"', f'kind = "logs"\npath = "{root.parent}"'))
    cfg = load_config(config, overrides={"output_dir": str(tmp_path / "runs"), "tracking": {"enabled": False},
                                         "test": {"logs": [str(recorded)]}})  # fmt: skip
    campaign = Campaign(cfg, tmp_path / "c")
    expected = test_set_from_logs([read_autodrive_log(p) for p in sorted(recorded.glob("*.csv"))], cfg.data)
    np.testing.assert_array_equal(campaign.test_set.x, expected.x)
    np.testing.assert_array_equal(campaign.test_set.y_noisy, expected.y_noisy)
    if oracle == "logs":
        assert len(campaign.maneuvers) == 3  # every recorded log is a candidate
