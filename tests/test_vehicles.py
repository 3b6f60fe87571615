"""Vehicles as data: the shipped files, their validation, and that no vehicle figure is written in code."""

from __future__ import annotations

import io
import re
import tokenize
from pathlib import Path

import pytest

from activelearn.cli import main
from activelearn.config import validate_config
from activelearn.errors import ConfigError
from simulator.vehicles import VehicleFileError, load_vehicle, shipped_vehicles

ROOT = Path(__file__).resolve().parents[1]
NIGEL_TOML = ROOT / "simulator" / "vehicles" / "nigel.toml"


def run(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


def test_three_cars_ship_and_every_figure_names_its_source() -> None:
    assert {"nigel", "f1tenth", "bmw320i"} <= set(shipped_vehicles())
    for name in shipped_vehicles():
        spec = load_vehicle(name)
        figures = spec.figures()
        assert len(figures) >= 15, name
        assert all(len(source) >= 3 for _, source in figures.values()), name


def test_the_new_cars_leave_the_kinematic_regime_on_paper() -> None:
    """At 5 m/s the 1:10 car's linear single track turns at 12.5 1/s per rad, the kinematic 15.1; the
    full-size car's equal tyres per unit load are neutral (issue 55)."""
    f1 = load_vehicle("f1tenth")
    assert float(f1.linear_yaw_gain(5.0)) == pytest.approx(12.5, abs=0.05)
    assert 5.0 / f1.wheelbase == pytest.approx(15.14, abs=0.01)
    bmw = load_vehicle("bmw320i")
    assert abs(bmw.understeer_gradient()) < 1e-6


def _distinctive_figures() -> dict[float, str]:
    """Every figure of every shipped car with at least three significant digits (1.0, 0.5 … are not)."""
    found: dict[float, str] = {}
    for name in shipped_vehicles():
        spec = load_vehicle(name)
        values = {key: value for key, (value, _) in spec.figures().items()}
        values["wheelbase"] = spec.wheelbase
        table = spec.drivetrain.speed_table
        for i, speed in enumerate(table.speed if table is not None else ()):
            values[f"speed_table[{i}]"] = speed
        for key, value in values.items():
            digits = re.sub(r"[^0-9]", "", repr(float(value)).rstrip("0")).lstrip("0")
            if len(digits) >= 3:
                found.setdefault(float(value), f"{name}: {key}")
    return found


_NUMBER = re.compile(r"(?<![\w.])\d+\.\d+(?:e-?\d+)?|(?<![\w.])\d{3,}(?![\w.])")


def _literals(path: Path) -> list[tuple[int, str]]:
    """Numbers written in a module's code and in its non-docstring strings (comments are prose)."""
    out: list[tuple[int, str]] = []
    previous = None
    for token in tokenize.generate_tokens(io.StringIO(path.read_text()).readline):
        if token.type == tokenize.NUMBER:
            out.append((token.start[0], token.string))
        elif token.type == tokenize.STRING:
            statement_start = previous is None or previous.type in (
                tokenize.INDENT, tokenize.DEDENT, tokenize.NEWLINE, tokenize.NL
            )
            if not statement_start:  # a docstring is a statement of its own: prose, like a comment
                out += [(token.start[0], text) for text in _NUMBER.findall(token.string)]
        if token.type not in (tokenize.COMMENT, tokenize.NL):
            previous = token
    return out


def test_no_vehicle_figure_is_written_in_the_code() -> None:
    """A car's figures live in its vehicle file only: the code reads them (issue 55)."""
    figures = _distinctive_figures()
    assert 0.14155 in figures and 0.4189 in figures and 1093.3 in figures  # the scan sees the files
    bad = []
    for room in ("activelearn", "simulator"):
        for path in sorted((ROOT / room).rglob("*.py")):
            for line, text in _literals(path):
                try:
                    value = float(text)
                except ValueError:
                    continue
                if value in figures:
                    bad.append(f"{path.relative_to(ROOT)}:{line}: {text} is {figures[value]}")
    assert bad == []


def test_a_bad_vehicle_file_names_the_file_and_the_field(tmp_path: Path) -> None:
    text = NIGEL_TOML.read_text()
    cases = {
        "negative.toml": (text.replace("lf = { value = 0.06226", "lf = { value = -1"), "geometry.lf.value"),
        "unsourced.toml": (
            text.replace('mass = { value = 2.68, source = "nigel.md" }', "mass = { value = 2.68 }"),
            "inertia.mass.source",
        ),
        "unknown.toml": (text.replace("[inertia]", "[inertia]\nwheels = 4"), "inertia.wheels"),
        "broken.toml": (text.replace("[inertia]", "[inertia"), ""),
    }
    for name, (content, field) in cases.items():
        path = tmp_path / name
        path.write_text(content)
        with pytest.raises(VehicleFileError) as info:
            load_vehicle(path)
        assert info.value.field == field and str(path) in str(info.value), name
    with pytest.raises(VehicleFileError, match="shipped: bmw320i, f1tenth, nigel"):
        load_vehicle("nosuchcar")


def test_a_config_takes_the_car_and_its_grids(tmp_path: Path) -> None:
    nigel = validate_config({})
    assert nigel.vehicle.name == "nigel" and nigel.pool.steerings == [0.1047, 0.2094, 0.3142, 0.4189, 0.5236]
    assert nigel.test.steerings == [0.05, 0.1571, 0.2618, 0.3665, 0.4712]
    f1 = validate_config({"vehicle": {"name": "f1tenth"}})
    assert max(f1.pool.steerings) == 0.4189 and f1.pool.full_lock == 0.4189
    assert f1.model.vehicle == "f1tenth" and f1.model.pose_lever_arm == 0.17145
    assert f1.simulation.noise.reference_speed == 20.0
    with pytest.raises(ConfigError) as info:
        validate_config({"vehicle": {"name": "f1tenth"}, "pool": {"steerings": [0.5236]}})
    assert info.value.field == "pool.steerings" and "0.4189" in str(info.value)
    bad = tmp_path / "car.toml"
    bad.write_text(NIGEL_TOML.read_text().replace("limit = { value = 0.5236", "limit = { value = -1"))
    with pytest.raises(ConfigError) as info:
        validate_config({"vehicle": {"name": str(bad)}})
    assert info.value.field == "vehicle.name" and "steering.limit" in str(info.value)


def test_simulate_refuses_a_bad_vehicle_file_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "car.toml"
    bad.write_text(NIGEL_TOML.read_text().replace("mass = { value = 2.68", "mass = { value = 0.0"))
    out = tmp_path / "run.csv"
    argv = ["simulate", "--maneuver", "straight", "--throttle", "0.5", "--duration", "1", "--out", str(out)]
    assert run([*argv, "--vehicle", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "inertia.mass" in err[0]
    assert not out.exists()
    assert run([*argv[:-2], "--steering", "0.45", "--maneuver", "skidpad", "--vehicle", "f1tenth",
                "--out", str(out)]) == 2  # beyond the 1:10 car's 0.4189 rad
    assert "0.4189" in capsys.readouterr().err and not out.exists()
