"""`activelearn fidelity`: replaying logs' commands in MuJoCo tells the same car from a different one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from activelearn import cli
from activelearn.data import write_autodrive_log
from activelearn.fidelity import FidelitySettings, compare, read_log_file, stretches
from simulator import Maneuver, NoiseConfig, collect, twin_vehicle

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"
TWIN = {"motor_gain": 0.8, "tire_friction": 0.6}


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    """A nominal skidpad log written by `activelearn simulate --autodrive`, and the same drive by a twin."""
    root = tmp_path_factory.mktemp("logs")
    nominal = root / "nominal.csv"
    argv = ["simulate", "--maneuver", "skidpad", "--throttle", "0.9", "--steering", "0.36",
            "--direction", "cw", "--duration", "5", "--autodrive", "--out", str(nominal)]  # fmt: skip
    assert cli.main(argv) == 0
    twin = root / "twin.csv"
    drive = Maneuver("skidpad", 0.9, 0.36, "cw", 5.0)
    write_autodrive_log(collect([drive], noise=NoiseConfig(), seed=3, vehicle=twin_vehicle(TWIN)), twin)
    return {"nominal": nominal, "twin": twin}


def _point(report):
    assert len(report.points) == 1
    return report.points.iloc[0]


def test_a_log_of_the_same_car_agrees_and_one_of_another_car_does_not(logs):
    nominal = [("nominal", read_log_file(logs["nominal"]))]
    twin = [("twin", read_log_file(logs["twin"]))]
    same = _point(compare(nominal))
    assert same["throttle"] == 0.9 and same["steering"] == pytest.approx(-0.36)
    assert abs(same["dv"]) < 0.002 and abs(same["dw"]) < 0.005  # only sensor noise differs
    assert same["straight_source"] == "reference"  # no straight in the log: the reference map
    assert same["loss_sim"] > 0.005 and abs(same["dloss"]) < 0.002

    other = _point(compare(twin))  # the nominal simulator against the weaker, lower-grip twin
    assert other["dv"] > 0.02 and other["w_sim"] < other["w_log"] - 0.05  # cw: negative yaw rates

    matched = _point(compare(twin, vehicle=twin_vehicle(TWIN)))
    assert abs(matched["dv"]) < 0.002 and abs(matched["dw"]) < 0.005


def test_stretches_of_constant_commands_are_the_operating_points(logs):
    table = read_log_file(logs["nominal"])
    (found,) = stretches(table, "nominal", FidelitySettings(settle=1.0, min_window=1.0))
    assert found.start == pytest.approx(1.0) and found.end == pytest.approx(5.0)
    assert not stretches(table, "nominal", FidelitySettings(settle=3.0, min_window=2.5))


def test_cli_prints_a_table_writes_the_figure_and_a_bad_log_is_exit_2(logs, tmp_path, capsys):
    config = tmp_path / "twin.toml"
    config.write_text(SMOKE.read_text() + '\n[oracle]\nkind = "twin"\noverrides = '
                      + "{ " + ", ".join(f"{k} = {v}" for k, v in TWIN.items()) + " }\n")  # fmt: skip
    plot = tmp_path / "fidelity.png"
    assert cli.main(["fidelity", str(logs["twin"]), "--config", str(config), "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert "twin motor_gain=0.8, tire_friction=0.6" in out
    row = next(line for line in out.splitlines() if line.strip().startswith("0.90"))
    dv = float(row.split()[5])
    assert abs(dv) < 0.002
    assert plot.stat().st_size > 10_000

    bad = tmp_path / "cut.csv"
    lines = logs["nominal"].read_text().splitlines()
    bad.write_text("\n".join([*lines[:50], lines[50][:20]]) + "\n")  # cut in the middle of a row
    assert cli.main(["fidelity", str(logs["nominal"]), str(bad), "--plot", str(tmp_path / "no.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cut.csv" in err[0]
    assert not (tmp_path / "no.png").exists()

    short = tmp_path / "short.csv"
    short.write_text("\n".join(lines[:40]) + "\n")  # 1.3 s: too short to settle, not too short to replay
    assert cli.main(["fidelity", str(short)]) == 0
    out = capsys.readouterr().out
    assert f"note: {short}: no stretch of constant non-zero throttle lasts 2 s" in out
    assert "the steady table is empty" in out and "steady operating points:" not in out
    replayed = next(line for line in out.splitlines() if line.startswith(str(short)))
    assert float(replayed.split()[1]) == pytest.approx(1.3)  # the whole-log row: its seconds
    assert np.isfinite(dv)


def test_cli_settle_and_min_window_set_the_steady_windows(logs, capsys):
    """`--settle` drops that many seconds of each stretch; `--min-window` is the steady time it must keep."""
    log = str(logs["nominal"])  # one 5-s stretch
    for settle in ("1", "2"):
        assert cli.main(["fidelity", log, "--settle", settle]) == 0
        row = next(line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("0.90"))
        assert float(row.split()[2]) == 5 - float(settle)  # the seconds averaged
    assert cli.main(["fidelity", log, "--min-window", "4.5"]) == 0  # 4 s left after the default 1-s settle
    out = capsys.readouterr().out
    assert "no stretch of constant non-zero throttle lasts 5.5 s" in out
    assert "the steady table is empty" in out
