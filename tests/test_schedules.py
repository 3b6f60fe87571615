"""Rehearsing a proposal (issue 22): `simulate --schedule` and `predict --schedule` drive a schedule file.

Real MuJoCo, real files, the real CLI: a schedule `campaign propose` wrote is simulated through the
CLI, must give the very log `simulator.collect` gives for the proposed family member, and `ingest`
must match it to that proposal. Schedules are a few seconds long.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import simulator
from activelearn.cli import main
from activelearn.data import write_autodrive_log, write_table
from activelearn.loop.campaign import CampaignState
from activelearn.loop.family_pool import schedule_table
from simulator import (
    FAMILIES,
    STEERING_LIMIT,
    FamilyManeuver,
    ManeuverError,
    Replay,
    check_schedule,
    member_from_name,
    schedule_maneuver,
)

RATE = 30.0


def run(argv: list[str]) -> int:
    """Exit code of the CLI, whether it returns or exits."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


MEMBERS = [
    FamilyManeuver("slalom", {"throttle": 0.6, "amplitude": 0.3, "frequency": 0.2, "delay": 1e-5}, "cw", 20),
    FamilyManeuver("fishhook", {"throttle": -0.4, "rate": 0.1, "amplitude": STEERING_LIMIT}, "ccw", 12.5),
    FamilyManeuver("throttle_step", {"throttle_start": 0.6, "throttle_end": -0.3, "switch_time": 2,
                                     "ramp_time": 0.5, "steering": 0.1}, "cw", 9),
    FamilyManeuver("chirp", {"throttle": 1 / 3, "amplitude": 0.3, "f0": 0.05, "f1": 0.5}, "ccw", 30),
    FamilyManeuver("multisine", {"throttle": 0.7, "amplitude": 0.31, "f_low": 0.05, "f_high": 0.5}, "cw", 6),
    FamilyManeuver("prbs", {"throttle": 0.6, "amplitude": 0.3, "switch_time": 0.7, "seed": 12}, "ccw", 8),
    FamilyManeuver("staircase", {"throttle": -0.7, "start": 0.15, "amplitude": 0.45, "hold": 2.5}, "cw", 10),
    FamilyManeuver("figure_eight", {"throttle": 0.6, "amplitude": 0.35, "loop_time": 2.5}, "cw", 6),
    FamilyManeuver("ramp_steer", {"throttle": 0.5, "amplitude": 0.3, "rate": 0.05, "settle": 1.5}, "ccw", 8),
    FamilyManeuver("step_steer", {"throttle": 0.8, "amplitude": 0.2, "step_time": 1.2, "rise_time": 0.0234},
                   "cw", 5),
    FamilyManeuver("sine_with_dwell", {"throttle": 0.6, "amplitude": 0.25, "frequency": 2.9, "dwell": 0.117,
                                       "delay": 1.4}, "ccw", 4),
    FamilyManeuver("double_lane_change", {"throttle": 0.7, "amplitude": 0.3, "period": 0.35, "gap": 0.2,
                                          "delay": 1.0}, "cw", 4),
]


# ----------------------------------------------------------------------------------- simulator.schedules


@pytest.mark.parametrize("member", [*MEMBERS, dataclasses.replace(MEMBERS[3], duration=5.0)], ids=str)
def test_a_member_name_reads_back_as_the_member(member: FamilyManeuver) -> None:
    assert member_from_name(member.name) == member


def test_every_family_is_read_back() -> None:
    assert {m.family for m in MEMBERS} == set(FAMILIES)


@pytest.mark.parametrize(
    "name",
    ["prbs", "mine", "chirp_up_t1_a0.1_fa0.1_fb0.2_d3", "chirp_ccw_t1_a0.1_fa0.1_fb0.2",
     "chirp_ccw_t1_a0.1_fa0.1_fb0.2_d3_x", "chirp_ccw_t2_a0.1_fa0.1_fb0.2_d3",  # throttle 2: no member
     "chirp_ccw_t1_a0.1_fb0.1_fa0.2_d3", "slalom_ccw_t0.5_a0.1_f0.1_w0_d0"],
)  # fmt: skip
def test_other_names_name_no_member(name: str) -> None:
    assert member_from_name(name) is None


def _rows(member: FamilyManeuver, rate: float = RATE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    table = schedule_table(member, rate)
    return table["time"].to_numpy(), table["throttle"].to_numpy(), table["steering"].to_numpy()


def test_a_proposals_schedule_is_its_member_and_anything_else_a_replay() -> None:
    member = MEMBERS[5]
    t, u, s = _rows(member)
    assert schedule_maneuver(f"03-{member.name}", t, u, s, RATE) == member
    assert schedule_maneuver(member.name, t, u, s, RATE) == member
    renamed = schedule_maneuver("mine", t, u, s, RATE)
    assert isinstance(renamed, Replay) and renamed.name == "mine" and renamed.rate_hz == RATE
    assert np.array_equal(renamed.throttles, u) and np.array_equal(renamed.steerings, s)
    edited = s.copy()
    edited[40] = 0.0  # the name promises the member, the rows are not its schedule: the rows win
    assert isinstance(schedule_maneuver(f"01-{member.name}", t, u, edited, RATE), Replay)
    assert isinstance(schedule_maneuver(f"01-{member.name}", t[:-1], u[:-1], s[:-1], RATE), Replay)


@pytest.mark.parametrize(
    ("change", "field", "words"),
    [
        (lambda t, u, s: (t[:1], u[:1], s[:1]), "time", "at least 2 rows"),
        (lambda t, u, s: (t + 1.0, u, s), "time", "start at 0"),
        (lambda t, u, s: (np.r_[t[:5], t[4], t[6:]], u, s), "time", "increase"),
        (lambda t, u, s: (np.r_[t[:5], t[5] + 0.01, t[6:]], u, s), "time", "equal steps"),
        (lambda t, u, s: (t * 1.5, u, s), "rate_hz", "(20 Hz)"),
        (lambda t, u, s: (t, np.r_[u[:3], np.nan, u[4:]], s), "throttle", "finite (row 4)"),
        (lambda t, u, s: (t, u, np.r_[s[:3], np.inf, s[4:]]), "steering", "finite (row 4)"),
        (lambda t, u, s: (t, np.r_[u[:7], -1.2, u[8:]], s), "throttle", "row 8"),
        (lambda t, u, s: (t, u, np.r_[s[:7], 0.53, s[8:]]), "steering", "row 8"),
    ],
)
def test_check_schedule_names_the_column(change, field: str, words: str) -> None:
    t, u, s = change(*_rows(MEMBERS[5]))
    with pytest.raises(ManeuverError) as info:
        check_schedule(t, u, s, RATE)
    assert info.value.field == field and words in info.value.reason


def test_check_schedule_takes_rounded_times_and_the_limits_themselves() -> None:
    t, u, s = _rows(MEMBERS[1])  # fishhook: holds the steering limit, throttle -0.4
    assert np.abs(s).max() == STEERING_LIMIT
    check_schedule(np.round(t, 4), u, s, RATE)  # times written with 4 decimals are still 30 Hz
    check_schedule(t, np.clip(u * 10, -1, 1), s, RATE)


# ------------------------------------------------------------------------------- propose, drive, ingest

PROPOSE = """
name = "rehearse"
strategy = "uniform"
[pool]
families = ["prbs"]
directions = ["ccw"]
size = 4
duration = 3.0
[pool.ranges.prbs]
throttle = [0.6, 0.6]
amplitude = [0.3, 0.3]
switch_time = [0.5, 0.5]
[design]
initial = 3
per_round = 1
max_maneuvers = 4
[training]
epochs = 5
[test]
throttles = [0.6]
steerings = [0.3]
duration = 3.0
[oracle]
kind = "external"
"""


def test_a_proposals_schedule_simulated_through_the_cli_is_its_log_and_ingest_matches_it(tmp_path, capsys):
    config = tmp_path / "rehearse.toml"
    config.write_text(f'output_dir = "{tmp_path / "runs"}"\n' + PROPOSE)
    directory = tmp_path / "campaign"
    assert run(["campaign", "propose", str(config), "--out", str(directory), "--no-tracking"]) == 0
    capsys.readouterr()
    proposals = pd.read_csv(directory / "proposals" / "round-000.csv")
    # three PRBS proposals alike in everything but their seed: only the schedule tells their logs apart
    assert len(proposals) == 3 and (proposals["maneuver"] == "prbs").all()
    assert proposals["seed"].nunique() == 3
    logs = {}
    for i in (0, 1):
        row = proposals.iloc[i]
        member = FamilyManeuver("prbs", {k: row[k] for k in FAMILIES["prbs"].names}, row["direction"], 3.0)
        schedule = directory / "proposals" / row["schedule"]
        expected = simulator.collect([member], rate_hz=RATE, seed=11 + i)
        if i == 0:  # our table: every column, the maneuver's own name and operating point included
            logs[i] = tmp_path / "drive0.csv"
            assert run(["simulate", "--schedule", str(schedule), "--seed", "11", "--out", str(logs[i])]) == 0
            same = write_table(expected, tmp_path / "expected0.csv")
            assert pd.read_csv(logs[i])["run_id"].iloc[0] == member.name
        else:  # the car's own layout
            logs[i] = tmp_path / "drive1.csv"
            argv = ["simulate", "--schedule", str(schedule), "--seed", "12", "--autodrive"]
            assert run([*argv, "--out", str(logs[i])]) == 0
            same = write_autodrive_log(expected, tmp_path / "expected1.csv")
        assert logs[i].read_bytes() == same.read_bytes()
    # the logs in reverse order: each goes to its own proposal (the batch stays open: no retraining)
    assert run(["campaign", "ingest", str(directory), str(logs[1]), str(logs[0]), "--no-tracking"]) == 0
    out = capsys.readouterr().out
    for i in (0, 1):
        name = Path(proposals.iloc[i]["schedule"]).stem.split("-", 1)[1]
        assert f"{logs[i]} -> {name}" in out
    state = CampaignState.load(directory)  # proposal i (pool index pending[i]) holds log i
    digests = {str(state.pending[i]): hashlib.sha256(logs[i].read_bytes()).hexdigest() for i in (0, 1)}
    assert state.staged == digests
    assert "still missing" in out and state.rounds == []


def test_a_schedule_of_ones_own_is_a_replay_with_the_members_physics(tmp_path):
    member = dataclasses.replace(MEMBERS[0], duration=2.0)
    mine = tmp_path / "mine.csv"
    schedule_table(member, 15.0).to_csv(mine, index=False)
    out = tmp_path / "mine.parquet"
    argv = ["simulate", "--schedule", str(mine), "--rate", "15", "--no-noise", "--out", str(out)]
    assert run([*argv, "--plot", str(tmp_path / "mine.png")]) == 0
    assert (tmp_path / "mine.png").stat().st_size > 10_000
    log = pd.read_parquet(out)
    expected = simulator.collect([member], rate_hz=15.0, seed=0, noise=None)
    assert set(log["maneuver"]) == {"replay"} and set(log["run_id"]) == {"mine"}
    assert set(log["direction"]) == {"cw"} and (log["op_steering"] == log["steering"].abs().max()).all()
    # a member reads its operating point off its 30 Hz schedule, a replay off its own rows: all else equal
    same = [c for c in log.columns if c not in ("maneuver", "run_id", "op_steering")]
    pd.testing.assert_frame_equal(log[same], expected[same])


# ---------------------------------------------------------------------------------------------- predict


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    """A small hybrid trained briefly on two short skidpads (enough to draw fans, not to be good)."""
    from activelearn.config import DataConfig, ModelConfig, TrainingConfig
    from activelearn.loop.collection import arrays, training_rows
    from activelearn.numerics.models import build_model, save_model
    from activelearn.numerics.training import fit
    from activelearn.numerics.training_data import TrainingData

    data = DataConfig(stride=3, skip_seconds=0.5)
    log = simulator.collect([simulator.Maneuver("skidpad", 0.6, 0.3, d, 4.0) for d in ("ccw", "cw")], seed=1)
    x, y = arrays(pd.concat([training_rows(p, data) for _, p in log.groupby("run_id")]), data)
    model = build_model(ModelConfig(n_inputs=2))
    fit(model, TrainingData(x, y), TrainingConfig(epochs=5, patience=None), seed=0)
    path = tmp_path_factory.mktemp("model") / "model.pt"
    save_model(model, path)
    return path


def test_predict_drives_the_schedule_and_writes_the_figure(tmp_path, capsys, model_file):
    member = dataclasses.replace(MEMBERS[5], duration=3.0)
    schedule = tmp_path / f"01-{member.name}.csv"
    schedule_table(member, RATE).to_csv(schedule, index=False)
    out = tmp_path / "fan.png"
    argv = ["predict", "--model", str(model_file), "--samples", "4", "--out", str(out)]
    assert run([*argv, "--schedule", str(schedule)]) == 0
    stdout = capsys.readouterr().out
    assert f"{member.name}: surrogate (4 samples) against MuJoCo" in stdout
    assert "RMSE v" in stdout and "inside 95% band" in stdout
    assert out.stat().st_size > 10_000
    slow = tmp_path / "slow.csv"
    schedule_table(member, 20.0).to_csv(slow, index=False)
    argv = ["predict", "--model", str(model_file), "--out", str(tmp_path / "x.png")]
    assert run([*argv, "--schedule", str(slow)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "30 Hz" in err[0] and "(20 Hz)" in err[0] and not (tmp_path / "x.png").exists()


# ------------------------------------------------------------------------------------------- bad input

GOOD = "time,throttle,steering\n0,0.5,0.1\n0.1,0.5,0.2\n0.2,0.5,0.3\n0.3,0.5,0.2\n"


@pytest.mark.parametrize(
    ("text", "extra", "words"),
    [
        (None, [], ["--schedule", "no such file"]),
        ("", [], ["--schedule", "is empty"]),
        ("time,throttle,steering\n", [], ["--schedule", "no rows"]),
        ("time,throttle\n0,0.5\n0.1,0.5\n", [], ["--schedule", "lacks the column(s) steering"]),
        ("t,u,s\n0,0.5,0.1\n", [], ["--schedule", "time, throttle, steering"]),
        (GOOD.replace("0.2,0.5,0.3", "0.1,0.5,0.3"), [], ["column time", "increase", "row 3"]),
        (GOOD.replace("0.2,0.5,0.3", "0.25,0.5,0.3"), [], ["column time", "equal steps", "row 3"]),
        (GOOD.replace("\n0,", "\n1,", 1), [], ["column time", "start at 0"]),
        (GOOD, [], ["--rate", "(10 Hz)", "not 1/30 s"]),
        (GOOD.replace("0.5,0.3", "nan,0.3"), ["--rate", "10"], ["column throttle", "finite", "row 3"]),
        (GOOD.replace("0.5,0.3", "0.5,inf"), ["--rate", "10"], ["column steering", "finite", "row 3"]),
        (GOOD.replace("0.5,0.3", ",0.3"), ["--rate", "10"], ["column throttle", "finite", "row 3"]),
        (GOOD.replace("0.5,0.3", "fast,0.3"), ["--rate", "10"], ["column throttle", "not a number", "row 3"]),
        (GOOD.replace("0.5,0.3", "1.01,0.3"), ["--rate", "10"], ["column throttle", "[-1, 1]", "row 3"]),
        (GOOD.replace("0.5,0.3", "0.5,-0.5237"), ["--rate", "10"], ["column steering", "0.5236", "row 3"]),
        (GOOD, ["--rate", "10", "--throttle", "0.5"], ["--throttle", "drop --throttle"]),
        (GOOD, ["--rate", "10", "--direction", "cw"], ["--direction", "drop --direction"]),
        (GOOD, ["--rate", "10", "--maneuver", "skidpad"], ["--maneuver", "not allowed"]),
    ],
)
def test_a_bad_schedule_is_one_line_exit_2_and_no_file(tmp_path, capsys, text, extra, words) -> None:
    schedule = tmp_path / "plan.csv"
    if text is not None:
        schedule.write_text(text)
    out = tmp_path / "out" / "log.csv"
    argv = ["simulate", "--schedule", str(schedule), "--out", str(out), "--plot", str(out.parent / "f.png")]
    assert run([*argv, *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), err
    assert all(w in err[0] for w in words), err[0]
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == (["plan.csv"] if text is not None else [])


def test_the_good_schedule_of_the_bad_input_cases_drives(tmp_path) -> None:
    schedule = tmp_path / "plan.csv"
    schedule.write_text(GOOD)
    out = tmp_path / "log.csv"
    assert run(["simulate", "--schedule", str(schedule), "--rate", "10", "--out", str(out)]) == 0
    log = pd.read_csv(out)
    assert log["steering"].tolist() == [0.1, 0.2, 0.3, 0.2] and (log["throttle"] == 0.5).all()


def test_neither_maneuver_nor_schedule_is_a_usage_error(tmp_path, capsys) -> None:
    assert run(["simulate", "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--maneuver" in err[0] and "--schedule" in err[0]
    assert list(tmp_path.iterdir()) == []
