"""Twins: MuJoCo with parameter overrides, validated at the edge, honoured by collect, tracked in MLflow."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from activelearn.config import load_config
from activelearn.errors import ConfigError
from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import SimulationCache, twin_cache
from activelearn.studies.tracking import Tracker
from simulator import (
    TWIN_PARAMETERS,
    Maneuver,
    OverrideError,
    check_overrides,
    collect,
    twin_vehicle,
)

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"


def _twin_toml(tmp_path: Path, overrides: str) -> Path:
    """The smoke config with a twin oracle, writing under tmp_path (top-level keys before the tables)."""
    path = tmp_path / "twin.toml"
    path.write_text(
        f'output_dir = "{tmp_path / "runs"}"\n'
        + SMOKE.read_text()
        + f'\n[tracking]\nuri = "sqlite:///{tmp_path}/mlruns/mlflow.db"\n'
        + f'\n[oracle]\nkind = "twin"\noverrides = {{ {overrides} }}\n'
    )
    return path


@pytest.mark.slow
@pytest.mark.parametrize(
    ("overrides", "field", "reason", "cli"),
    [
        ("tire_grip = 0.5", "oracle.overrides.tire_grip", "unknown twin parameter; known: tire_friction", 1),
        ("latency = 0.5", "oracle.overrides.latency", "must lie in [0, 0.2] (s)", 1),
        ("motor_gain = -1.0", "oracle.overrides.motor_gain", "must lie in [0.25, 2]", 0),
        ('mass = "heavy"', "oracle.overrides.mass", "must be a finite number", 0),
    ],
)
def test_a_bad_override_is_one_config_error_and_exit_2_with_nothing_written(
    tmp_path, overrides, field, reason, cli
):
    path = _twin_toml(tmp_path, overrides)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert info.value.field == field
    assert reason in str(info.value)
    if not cli:  # the CLI path is the same for every reason: run it for two
        return
    before = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "activelearn.cli", "campaign", "run", str(path), "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and field in lines[0], proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no output dir, no MLflow store


def test_check_overrides_names_the_parameter_and_the_table_documents_every_one():
    with pytest.raises(OverrideError, match="steering_offset"):
        check_overrides({"steering_offset": float("inf")})
    assert check_overrides({"latency": 0}) == {"latency": 0.0}
    for spec in TWIN_PARAMETERS.values():
        assert spec.meaning and spec.unit and spec.low <= spec.nominal <= spec.high
        check_overrides({spec.name: spec.low})
        check_overrides({spec.name: spec.high})


def _steady(frame, column: str, after: float = 2.0) -> float:
    return float(frame.loc[frame["time"] >= after, column].mean())


def test_lower_grip_and_a_weaker_motor_turn_slower_than_nominal():
    turn = [Maneuver("skidpad", 1.0, 0.5236, "ccw", 4.0)]
    nominal = collect(turn, noise=None, threads=1)
    same = collect(turn, noise=None, threads=1, vehicle=twin_vehicle({}))
    assert same.equals(nominal)  # no overrides: the nominal car, bit for bit
    weaker = twin_vehicle({"tire_friction": 0.5, "motor_gain": 0.7})
    twin = collect(turn, noise=None, threads=1, vehicle=weaker)
    v0, w0 = _steady(nominal, "speed"), _steady(nominal, "angZ")
    v1, w1 = _steady(twin, "speed"), _steady(twin, "angZ")
    assert v1 < 0.85 * v0
    assert w1 < 0.85 * w0


def test_latency_delays_the_response_by_about_the_latency():
    launch = [Maneuver("straight", 0.8, 0.0, "ccw", 1.5)]
    latency = 0.1
    nominal = collect(launch, noise=None, threads=1, rate_hz=300.0)
    late = collect(launch, noise=None, threads=1, rate_hz=300.0, vehicle=twin_vehicle({"latency": latency}))
    assert np.array_equal(late["throttle"], nominal["throttle"])  # the log holds the commands sent

    def crossing(frame) -> float:
        half = 0.5 * _steady(frame, "speed", after=1.0)
        return float(frame["time"].to_numpy()[np.argmax(frame["speed"].to_numpy() >= half)])

    assert crossing(late) - crossing(nominal) == pytest.approx(latency, abs=2.0 / 300.0)
    assert _steady(late, "speed", after=1.0) == pytest.approx(_steady(nominal, "speed", after=1.0), rel=1e-3)


@pytest.mark.slow
def test_twin_logs_have_their_own_cache_and_a_tiny_campaign_records_the_overrides(tmp_path):
    overrides = {"tire_friction": 0.6, "motor_gain": 0.8, "latency": 0.05}
    data = {
        "output_dir": str(tmp_path / "runs"),
        "tracking": {"uri": f"sqlite:///{tmp_path}/mlruns/mlflow.db"},
        "training": {"epochs": 10},
        "design": {"initial": 2, "per_round": 1, "max_maneuvers": 3},
        "pool": {"duration": 6.0},
        "test": {"duration": 6.0, "throttles": [0.75], "steerings": [0.45]},
        "oracle": {"kind": "twin", "overrides": overrides},
    }
    cfg = load_config(SMOKE, overrides=data)
    cache = twin_cache(tmp_path / "cache", cfg)
    assert cache.root != SimulationCache(tmp_path / "cache", cfg.simulation).root
    assert cache.root == twin_cache(tmp_path / "cache", cfg).root  # stable
    other = load_config(SMOKE, overrides={**data, "oracle": {"kind": "twin", "overrides": {"latency": 0.05}}})
    assert twin_cache(tmp_path / "cache", other).root != cache.root

    tracker = Tracker(cfg.tracking.uri, cfg.tracking.experiment)
    result = Campaign(cfg, tmp_path / "c", tracker=tracker).run()
    params = tracker.client.get_run(result.state.run_id).data.params
    assert params["oracle.kind"] == "twin"
    for name, value in overrides.items():
        assert float(params[f"oracle_info.overrides.{name}"]) == value
        assert float(params[f"oracle.overrides.{name}"]) == value


@pytest.mark.parametrize("kind", ["simulator", "twin", "external"])
def test_a_comparison_simulates_beforehand_what_the_oracle_will_simulate(tmp_path, kind):
    """compare asks the oracle: a twin's maneuvers in the twin's cache (not the nominal simulator's),
    a person's candidates not at all (only the simulated test set)."""
    from activelearn.loop.oracles import make_oracle
    from activelearn.loop.pool import pool_maneuvers, test_maneuvers

    overrides = {"oracle": {"kind": kind, **({"overrides": {"motor_gain": 0.9}} if kind == "twin" else {})}}
    cfg = load_config(SMOKE, overrides={"output_dir": str(tmp_path / "runs"), **overrides})
    oracle = make_oracle(cfg, tmp_path / "cache")
    ((cache, maneuvers),) = oracle.simulations()
    tests, pool = test_maneuvers(cfg.test), pool_maneuvers(cfg.pool)
    assert maneuvers == (tests if kind == "external" else tests + pool)
    nominal = SimulationCache(tmp_path / "cache", cfg.simulation)
    assert cache.root == (twin_cache(tmp_path / "cache", cfg) if kind == "twin" else nominal).root


def test_the_twins_dynamics_config_is_dynamics_toml_answered_by_sim_to_reals_twin():
    """dynamics_twin.toml repeats dynamics.toml (issue 35's cold-start comparison runs on both): every
    section but the name and the oracle equal, the oracle sim_to_real's twin."""
    configs = SMOKE.parent
    twin, nominal = (load_config(configs / f"{n}.toml") for n in ("dynamics_twin", "dynamics"))
    real = load_config(configs / "sim_to_real.toml")
    assert twin.oracle == real.oracle and twin.oracle.kind == "twin" and nominal.oracle.kind == "simulator"
    assert twin.model_copy(update={"name": nominal.name, "oracle": nominal.oracle}) == nominal


@pytest.mark.parametrize("car", ["f1tenth", "bmw320i"])
def test_the_fast_cars_twin_and_warm_configs_repeat_its_cold_start(car):
    """dynamics_<car>_twin.toml, dynamics_<car>_warm.toml and dynamics_<car>_warm_twin.toml (issue 57's
    settings, the 1:10 and the full-size car) are dynamics_<car>.toml but for the oracle (the twin: less
    grip, a weaker motor) and/or the design (a low-lateral-acceleration grid already driven, 12 new
    signals; on the twin that grid is another car's, `same_car = false`)."""
    configs = SMOKE.parent
    cold, twin, warm, warm_twin = (load_config(configs / f"dynamics_{car}{s}.toml")
                                   for s in ("", "_twin", "_warm", "_warm_twin"))  # fmt: skip
    assert cold.oracle.kind == "simulator"
    assert twin.oracle.kind == "twin" and twin.oracle.overrides == {"tire_friction": 0.8, "motor_gain": 0.9}
    assert twin.model_copy(update={"name": cold.name, "oracle": cold.oracle}) == cold
    assert warm.design.prior is not None and warm.design.prior.grid is not None and warm.design.initial == 0
    # the full-size car's warm starts keep the correction's gate shut (session 40); the 1:10 car's as cold
    gate = cold.model.correction_gate_min_held_out
    assert warm.model.correction_gate_min_held_out == {"bmw320i": 100}.get(car, gate)
    as_cold = warm.model.model_copy(update={"correction_gate_min_held_out": gate})
    assert warm.model_copy(update={"name": cold.name, "design": cold.design, "model": as_cold}) == cold
    assert warm_twin.design.prior is not None and not warm_twin.design.prior.same_car
    prior = warm_twin.design.prior.model_copy(update={"same_car": True})
    design = warm_twin.design.model_copy(update={"prior": prior})
    assert warm_twin.model_copy(update={"name": warm.name, "design": design, "oracle": warm.oracle}) == warm
    assert warm_twin.oracle == twin.oracle
