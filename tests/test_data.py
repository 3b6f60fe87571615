"""Sample-table schema, atomic IO and import of AutoDRIVE logs (files written by the tests)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import simulator
from activelearn.data import (
    AUTODRIVE_COLUMNS,
    SAMPLE_COLUMNS,
    atomic_write_bytes,
    read_autodrive_log,
    read_table,
    write_table,
)
from activelearn.errors import DataFormatError, InputError

ROWS = [
    "2023_04_12_15_30_07_000,0.5,0.1,0,0,0.0,0.0,0.03,0.0,0.0,0.0,0.0,0.0,0.0,0.0,0.0,0.0,9.81,"
    "cam0/1.png,cam1/1.png,[1.0 2.0]",
    "2023_04_12_15_30_07_033,0.5,0.1,12,13,0.004,0.0,0.03,0.0,0.0,0.01,0.12,0.0,0.0,0.3,0.5,0.0,9.81,"
    "cam0/2.png,cam1/2.png,[1.0 2.0]",
    "2023_04_12_15_30_07_067,0.5,0.1,25,27,0.008,0.001,0.03,0.0,0.0,0.02,0.13,0.0,0.0,0.31,0.4,0.0,9.81,"
    "cam0/3.png,cam1/3.png,[1.0 2.0]",
]


def write_lines(path: Path, lines: list[str]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def test_schema_matches_the_simulator() -> None:
    assert SAMPLE_COLUMNS == simulator.COLUMNS
    assert AUTODRIVE_COLUMNS == simulator.AUTODRIVE_COLUMNS


def test_reads_a_headerless_autodrive_log(tmp_path: Path) -> None:
    path = write_lines(tmp_path / "clean_t_0_5_run_01" / "V1 Log.csv", ROWS)
    table = read_autodrive_log(path)
    assert tuple(table.columns) == SAMPLE_COLUMNS
    assert len(table) == 3
    np.testing.assert_allclose(table["time"], [0.0, 0.033, 0.067], atol=1e-6)
    assert table["rightTicks"].tolist() == [0, 13, 27] and table["rightTicks"].dtype == np.int64
    assert table["angZ"].iloc[2] == pytest.approx(0.31)
    assert (table["run_id"] == "clean_t_0_5_run_01/V1 Log").all()
    assert (table["maneuver"] == "unknown").all()
    assert (table["op_throttle"] == 0.5).all() and (table["op_steering"] == 0.1).all()
    assert not table["diverged"].any()
    assert "cam0" not in table.columns and "lidar" not in table.columns


def test_lidar_array_spread_over_unquoted_fields_is_tolerated(tmp_path: Path) -> None:
    lines = [row.replace("[1.0 2.0]", "1.0,2.0,3.0") for row in ROWS]
    table = read_autodrive_log(write_lines(tmp_path / "log.csv", lines))
    assert len(table) == 3 and table["accZ"].iloc[0] == pytest.approx(9.81)


@pytest.mark.parametrize(
    ("line", "bad"),
    [
        (2, ROWS[1].replace(",0.12,", ",fast,")),  # a non-number
        (3, ",".join(ROWS[2].split(",")[:10])),  # a truncated row
        (2, ROWS[1].replace("2023_04_12_15_30_07_033", "yesterday")),  # a bad timestamp
        (3, ROWS[2].replace(",25,", ",25.5,")),  # a fractional tick count
    ],
)
def test_malformed_row_names_file_and_line(tmp_path: Path, line: int, bad: str) -> None:
    lines = list(ROWS)
    lines[line - 1] = bad
    path = write_lines(tmp_path / "broken.csv", lines)
    with pytest.raises(DataFormatError) as info:
        read_autodrive_log(path)
    assert f"{path}:{line}:" in str(info.value)


def test_malformed_row_in_our_csv_counts_the_header_line(tmp_path: Path) -> None:
    table = simulator.collect([simulator.Maneuver("straight", 0.4, duration=0.1)], noise=None)
    path = tmp_path / "run.csv"
    write_table(table, path)
    lines = path.read_text().splitlines()
    lines[2] = lines[2].replace(",straight,", ",straight,extra,")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=re.escape(f"{path}:3:")):
        read_autodrive_log(path)


def test_empty_file_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "empty.csv"
    path.write_text("")
    with pytest.raises(DataFormatError, match=r"empty\.csv:1"):
        read_autodrive_log(path)


def test_our_csv_reads_back_identically(tmp_path: Path) -> None:
    maneuvers = [
        simulator.Maneuver("slalom", 0.6, 0.3, "cw", 4.0),
        simulator.Maneuver("straight", 0.3, duration=1.0),
    ]
    table = simulator.collect(maneuvers, seed=5)
    path = write_table(table, tmp_path / "sub" / "log.csv")
    assert path.read_text().splitlines()[0] == ",".join(SAMPLE_COLUMNS)
    pd.testing.assert_frame_equal(read_table(path), table)
    pd.testing.assert_frame_equal(read_autodrive_log(path), table)


def test_parquet_round_trip_is_exact(tmp_path: Path) -> None:
    table = simulator.collect([simulator.Maneuver("eight", 0.5, 0.4, "ccw", 2.0)], seed=2)
    path = write_table(table, tmp_path / "log.parquet")
    pd.testing.assert_frame_equal(read_table(path), table, check_exact=True)


def test_write_table_rejects_other_extensions_and_leaves_nothing(tmp_path: Path) -> None:
    table = simulator.collect([simulator.Maneuver("straight", 0.4, duration=0.1)], noise=None)
    with pytest.raises(InputError) as info:
        write_table(table, tmp_path / "log.txt")
    assert info.value.field == "path"
    assert list(tmp_path.iterdir()) == []


def test_writes_are_atomic_and_leave_no_temporary_files(tmp_path: Path) -> None:
    table = simulator.collect([simulator.Maneuver("straight", 0.4, duration=0.1)], noise=None)
    write_table(table, tmp_path / "log.csv")
    write_table(table.iloc[:1], tmp_path / "log.csv")  # replaces the file in one step
    atomic_write_bytes(tmp_path / "state.json", b"{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.csv", "state.json"]
    assert len(read_table(tmp_path / "log.csv")) == 1


def test_read_table_of_a_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        read_table(tmp_path / "nope.csv")


def test_concurrent_writers_of_one_path_never_share_a_temporary_file(tmp_path: Path) -> None:
    """Two benchmark processes summarising one comparison wrote its figure at once; with one fixed
    temporary name, one renamed the other's file away and crashed. Threads share a pid, so they race
    harder: every write must land whole and leave nothing behind."""
    from concurrent.futures import ThreadPoolExecutor

    from matplotlib.figure import Figure

    from activelearn.plots import save_figure

    fig = Figure(figsize=(2.0, 2.0))  # no layout engine: eight threads draw the one figure at once
    fig.add_subplot().plot([0, 1], [0, 1])
    figure = tmp_path / "comparison.png"

    def write(_: int) -> None:
        save_figure(fig, figure, dpi=40)
        atomic_write_bytes(tmp_path / "state.json", b"{}")

    with ThreadPoolExecutor(8) as pool:
        list(pool.map(write, range(48)))
    assert figure.read_bytes().startswith(b"\x89PNG")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["comparison.png", "state.json"]
