"""`activelearn simulate`: outputs, and user errors giving one line, exit code 2 and no file."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from activelearn.cli import main
from activelearn.data import AUTODRIVE_COLUMNS, SAMPLE_COLUMNS


def run(argv: list[str]) -> int:
    """Exit code of the CLI, whether it returns or exits."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


BASE = ["simulate", "--maneuver", "skidpad", "--throttle", "0.6", "--steering", "0.3142", "--duration", "2"]


def test_writes_csv_in_autodrive_order_with_a_plot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, plot = tmp_path / "run.csv", tmp_path / "fig" / "run.png"
    assert run([*BASE, "--direction", "cw", "--out", str(out), "--plot", str(plot)]) == 0
    header = out.read_text().splitlines()[0].split(",")
    assert header[: len(AUTODRIVE_COLUMNS)] == list(AUTODRIVE_COLUMNS)
    assert tuple(header) == SAMPLE_COLUMNS
    table = pd.read_csv(out)
    assert len(table) == 61
    assert (table["steering"] < 0).all() and table["angZ"].iloc[-1] < 0  # cw
    assert plot.stat().st_size > 10_000
    stdout = capsys.readouterr().out
    assert "61 rows" in stdout and "mean speed" in stdout and "mean yaw rate" in stdout and str(out) in stdout


def test_parquet_output_and_options(tmp_path: Path) -> None:
    out = tmp_path / "run.parquet"
    argv = [*BASE, "--rate", "10", "--seed", "4", "--no-noise", "--out", str(out)]
    assert run(argv) == 0
    table = pd.read_parquet(out)
    assert len(table) == 21
    assert abs(table["posX"].iloc[0]) < 1e-5  # no noise (the default position noise is 2 mm)


def test_same_seed_same_file(tmp_path: Path) -> None:
    a, b = tmp_path / "a.csv", tmp_path / "b.csv"
    assert run([*BASE, "--seed", "9", "--out", str(a)]) == 0
    assert run([*BASE, "--seed", "9", "--out", str(b)]) == 0
    assert a.read_bytes() == b.read_bytes()


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"--throttle": "1.5"}, "--throttle"),
        ({"--throttle": "fast"}, "--throttle"),
        ({"--steering": "-0.1"}, "--steering"),
        ({"--steering": "0.6"}, "--steering"),
        ({"--maneuver": "donut"}, "--maneuver"),
        ({"--direction": "left"}, "--direction"),
        ({"--duration": "0"}, "--duration"),
        ({"--duration": "nan"}, "--duration"),
        ({"--rate": "0"}, "--rate"),
        ({"--rate": "5000"}, "--rate"),
        ({"--seed": "-3"}, "--seed"),
        ({"--out": "run.txt"}, "--out"),
        ({"--plot": "run.gif"}, "--plot"),
    ],
)
def test_bad_values_give_one_line_exit_2_and_no_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], changes: dict[str, str], field: str
) -> None:
    options = {
        "--maneuver": "skidpad", "--throttle": "0.6", "--steering": "0.3", "--direction": "ccw",
        "--duration": "2", "--rate": "30", "--seed": "0", "--out": "run.csv",
    }
    options.update(changes)
    argv = ["simulate"]
    for key, value in options.items():
        argv += [key, str(tmp_path / value) if key in ("--out", "--plot") else value]
    assert run(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and field in err[0]
    assert list(tmp_path.iterdir()) == []


def test_missing_required_option_is_a_usage_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(["simulate", "--maneuver", "skidpad", "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--throttle" in err[0]
    assert list(tmp_path.iterdir()) == []


def test_fishhook_defaults_to_full_lock(tmp_path: Path) -> None:
    out = tmp_path / "hook.csv"
    argv = ["simulate", "--maneuver", "fishhook", "--throttle", "0.5", "--duration", "1", "--out", str(out)]
    assert run(argv) == 0
    table = pd.read_csv(out)
    assert (table["op_steering"] == 0.5236).all()
