"""The physics-structured model kind: Nigel's single track plus a bounded Bayesian correction (MuJoCo)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch

import simulator
from activelearn.config import DataConfig, ModelConfig, TrainingConfig, load_config
from activelearn.errors import ConfigError, InputError
from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import arrays, control_rate_logs, training_rows
from activelearn.numerics import correction_gate
from activelearn.numerics.models import PhysicsModel, build_model, load_model, physics, save_model
from activelearn.numerics.models import single_track as st
from activelearn.numerics.models.base import Model
from activelearn.numerics.surrogate import STEADY_STATES, model_inputs, simulate, steady_state_inputs
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from simulator import Maneuver, datasheet
from tests.conftest import SMOKE, predict_slalom_fan

DATA = DataConfig(stride=10, skip_seconds=0.0, inputs="history", history=4, history_step=3)
SPEED_BOUND = 1.5 * datasheet.MAX_SPEED
YAW_BOUND = 1.5 * datasheet.MAX_YAW_RATE


def _logs(frame: pd.DataFrame) -> list[tuple[np.ndarray, np.ndarray]]:
    return control_rate_logs([g for _, g in frame.groupby("run_id", sort=False)])


def _config(**knobs) -> ModelConfig:
    base = {
        "kind": "physics",
        "arch": "D16-D16-V",
        "activation": "softplus",
        "n_inputs": 16,
        "history_step": 3,
    }
    return ModelConfig(**{**base, **knobs})


@pytest.fixture(scope="module")
def forward_grid() -> pd.DataFrame:
    """A shrunk forward reference grid: straights and skidpads both ways, forward throttles only."""
    maneuvers = [Maneuver("straight", t, 0.0, "ccw", 12.0) for t in (0.2, 0.6, 1.0)]
    maneuvers += [
        Maneuver("skidpad", t, d, direction, 12.0)
        for t in (0.2, 0.6, 1.0)
        for d in (0.3142, 0.5236)
        for direction in ("ccw", "cw")
    ]
    return simulator.collect(maneuvers, seed=0)


@pytest.fixture(
    scope="module",
    params=[
        ("ensemble", "history", "none"),
        ("hybrid", "history", "none"),
        ("hybrid", "control", "none"),
        ("hybrid", "control", "mirror"),
    ],
    ids=["ensemble", "hybrid", "hybrid-on-control", "mirror-on-control"],
)
def forward_model(request, forward_grid: pd.DataFrame) -> PhysicsModel:
    """The physics model of each correction kind (and the correction on the control alone, whose free
    runs are computed whole, also mirror-symmetric), trained on the forward grid alone."""
    rows = pd.concat([training_rows(g, DATA) for _, g in forward_grid.groupby("run_id", sort=False)])
    x, y = arrays(rows, DATA)
    kind, inputs, symmetry = request.param
    knobs = {"correction": kind, "correction_inputs": inputs, "correction_symmetry": symmetry}
    model = build_model(_config(**knobs, ensemble_size=3), seed=0)
    fit(
        model,
        TrainingData(x, y, logs=_logs(forward_grid)),
        TrainingConfig(epochs=30, batch_size=64, patience=None),
        seed=0,
    )
    return model


def test_the_bare_single_track_drives_the_datasheet_table():
    theta = torch.as_tensor(st.NOMINAL)
    v, w = torch.zeros(()), torch.zeros(())
    for _ in range(100):  # 10 s at 0.1 s
        v, w = st.single_track_step(torch.tensor(0.6), torch.tensor(0.0), v, w, theta, 0.1)
    assert float(v) == pytest.approx(0.16516, rel=1e-4)
    assert float(w) == pytest.approx(0.0, abs=1e-9)
    for _ in range(100):  # reverse mirrors the table
        v, w = st.single_track_step(torch.tensor(-0.6), torch.tensor(0.2), v, w, theta, 0.1)
    assert float(v) == pytest.approx(-0.16516, rel=1e-4)
    assert float(w) == pytest.approx(
        float(v) * np.tan(0.2) / (datasheet.WHEELBASE * st.NOMINAL[4]), rel=1e-4
    )
    v, _ = st.single_track_step(torch.tensor(0.0), torch.tensor(0.0), v, w, theta, 0.01)
    assert float(v) == pytest.approx(-0.16516 + 0.01 * datasheet.FRICTION * datasheet.GRAVITY, rel=1e-4)


def _box_controls(seed: int, n_logs: int) -> np.ndarray:
    """Piecewise-constant controls over the box (6 levels of 3 s each per log), brake phases included."""
    rng = np.random.default_rng(seed)
    controls = []
    for _ in range(n_logs):
        levels = rng.uniform([-1.0, -0.5236], [1.0, 0.5236], size=(6, 2))
        levels[rng.integers(6), 0] = 0.0
        controls.append(np.repeat(levels, 90, axis=0))
    return np.stack(controls)


def test_identification_recovers_the_parameters_of_its_own_structure():
    truth = np.array([0.8, 1.1, 0.2, 1.2, 1.15, 0.08, 3.0])
    controls = _box_controls(0, 6)
    runs = st.run_single_track(controls, np.zeros((6, 2)), truth, 1 / 30)[0]
    found = st.identify_from_logs([(u, y) for u, y in zip(controls, runs, strict=True)])
    np.testing.assert_allclose(found.values, truth, rtol=0.02)
    assert np.all(found.stderr < 0.05 * np.maximum(truth, 0.1))


def test_free_runs_of_many_parameter_sets_are_the_step_by_steps_to_the_last_bit():
    """`run_single_track` computes the table's speed once for all steps of the controls: the same
    numbers as the step computes by itself (throttle 0, the brake, included)."""
    rng = np.random.default_rng(3)
    controls = rng.uniform([-1.0, -0.52], [1.0, 0.52], (7, 300, 2))
    controls[:, ::17, 0] = 0.0
    sets = st.NOMINAL * rng.uniform(0.8, 1.2, (5, 7))
    start = rng.normal(0.0, 0.1, (7, 2))
    runs = st.run_single_track(controls, start, sets, 1 / 30, backend="reference")
    v, w = (np.broadcast_to(start[:, j], (5, 7)) for j in range(2))
    for k in range(1, 300):
        v, w = st.single_track_step(controls[:, k, 0], controls[:, k, 1], v, w, sets[:, None], 1 / 30)
        assert np.array_equal(runs[:, :, k, 0], v) and np.array_equal(runs[:, :, k, 1], w)


@pytest.mark.usefixtures("c_kernels")
@pytest.mark.parametrize("vehicle", ["nigel", "f1tenth", "bmw320i"])
def test_the_compiled_free_runs_are_numpys_to_float64_rounding(vehicle: str):
    """The identification's free runs by physics_rollout.c's kernel (`backend="native"`, what "auto" takes)
    are the NumPy loop's to float64 rounding on every car: braking at throttle 0, a throttle beyond the
    table, both directions, the yaw cap."""
    car = st.car_prior(vehicle)
    rng = np.random.default_rng(4)
    held = rng.uniform([-1.2, -1.5 * car.steering_limit], [1.2, 1.5 * car.steering_limit], (6, 10, 2))
    controls = np.repeat(held, 40, axis=1)  # each control held 1.2 s: steady turns reach the yaw cap
    controls[:, ::13, 0] = 0.0
    sets = car.nominal * rng.uniform(0.7, 1.3, (4, 7))
    start = rng.normal(0.0, [0.3 * car.max_speed, 0.3 * car.max_yaw_rate], (6, 2))
    compiled, numpy = (st.run_single_track(controls, start, sets, 0.03, car, backend=backend)
                       for backend in ("native", "reference"))  # fmt: skip
    assert compiled.shape == (4, 6, 400, 2)
    assert np.allclose(compiled, numpy, rtol=1e-12, atol=1e-12 * np.abs(numpy).max())
    capped = np.abs(numpy[..., 1]).max()
    assert capped == pytest.approx(car.yaw_cap) and not np.array_equal(compiled, np.zeros_like(compiled))
    with pytest.raises(InputError, match="backend"):
        st.run_single_track(controls, start, sets, 0.03, car, backend="fast")


def test_a_search_from_the_last_solution_lands_where_the_datasheets_does_in_fewer_runs():
    """A warm-started round searches from the last round's parameters: same objective and prior, so the
    same optimum (to the solver's tolerance), reached with fewer free runs of the logs."""
    truth = np.array([0.8, 1.1, 0.2, 1.2, 1.15, 0.08, 3.0])
    controls = _box_controls(4, 8)
    noise = np.random.default_rng(1)
    runs = st.run_single_track(controls, np.zeros((8, 2)), truth, 1 / 30)[0]
    runs = runs + noise.normal(0.0, [0.005, 0.02], runs.shape)
    logs = list(zip(controls, runs, strict=True))
    last_round = st.identify_from_logs(logs[:6])  # the round before had six of the eight logs
    counted = {"runs": 0}
    original = st.run_single_track

    def counting(*args, **kwargs):
        counted["runs"] += 1
        return original(*args, **kwargs)

    cold_runs, warm_runs = 0, 0
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(st, "run_single_track", counting)
        cold = st.identify_from_logs(logs)
        cold_runs, counted["runs"] = counted["runs"], 0
        warm = st.identify_from_logs(logs, search_from=last_round.values)
        warm_runs = counted["runs"]
    np.testing.assert_allclose(warm.values, cold.values, rtol=2e-3, atol=1e-4)
    np.testing.assert_allclose(warm.stderr, cold.stderr, rtol=0.05)
    assert warm_runs < cold_runs


def test_another_cars_estimate_is_computed_once_per_set_of_logs():
    """A campaign's prior grid is the same every round: its estimate is reused, the car's own refitted."""
    car = np.array([1.0, 1.1, 0.1, 1.2, 1.15, 0.05, 3.0])
    controls = _box_controls(5, 4)
    rates = st.run_single_track(controls, np.zeros((4, 2)), car, 1 / 30)[0]
    rates = rates + np.random.default_rng(2).normal(0.0, [0.005, 0.02], rates.shape)
    logs = list(zip(controls, rates, strict=True))
    own, others = logs[:1], logs[1:]
    fits = []
    original = st.identify_from_logs

    def counting(fitted, **kwargs):
        fits.append(len(fitted))
        return original(fitted, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(st, "identify_from_logs", counting)
        first = st.identify_on_another_car(own, others)
        again = st.identify_on_another_car(own, others)
        moved = st.identify_on_another_car(own, [(u, y + 0.01) for u, y in others])
    assert fits == [3, 1, 1, 3, 1]  # the other car's 3 logs fitted once until they change
    np.testing.assert_array_equal(again.values, first.values)
    np.testing.assert_array_equal(again.covariance, first.covariance)
    assert not np.array_equal(moved.values, first.values)


def test_the_covariance_widens_where_the_logs_disagree():
    """Half the logs from a car with scrub 0.8, half from one with 1.6: the single track fits neither,
    and the cluster-robust standard error of the scrub is of the size of that disagreement (the
    spread of the two halves' fits over the root of the number of logs), not of the noise-free fit's."""
    controls = _box_controls(1, 12)
    cars = np.array([[0.8, 1.1, 0.2, scrub, 1.15, 0.08, 3.0] for scrub in (0.8, 1.6)])
    runs = [st.run_single_track(controls[i::2], np.zeros((6, 2)), car, 1 / 30)[0]
            for i, car in enumerate(cars)]  # fmt: skip
    logs = [(u, y) for i in range(2) for u, y in zip(controls[i::2], runs[i], strict=True)]
    both = st.identify_from_logs(logs)
    halves = [st.identify_from_logs(logs[:6]).values[3], st.identify_from_logs(logs[6:]).values[3]]
    assert halves == pytest.approx([0.8, 1.6], rel=0.05)
    disagreement = np.std(halves) / np.sqrt(len(logs))  # ~0.12
    assert 0.5 * disagreement < both.stderr[3] < 4 * disagreement
    one_car = st.identify_from_logs(logs[:6])
    assert one_car.stderr[3] < 0.1 * both.stderr[3]  # one car's logs agree: no such spread


def _forward_only(controls: np.ndarray) -> np.ndarray:
    forward = controls.copy()
    forward[..., 0] = np.abs(forward[..., 0])
    return forward


def test_another_cars_logs_centre_the_prior_instead_of_outvoting_this_cars():
    """Twelve logs of a simulator (motor 1.0, reverse 1.1) and two forward-only logs of the car (motor
    0.85): pooled as data, the simulator's logs outvote the car's; as another car's, they only centre
    the prior, so the car's logs set its motor, and its reverse gain, which they do not excite, stays
    the simulator's, as uncertain as the datasheet says two cars may differ."""
    simulator_car = np.array([1.0, 1.1, 0.1, 1.2, 1.15, 0.05, 3.0])
    this_car = simulator_car * np.array([0.85, 1, 1, 1, 1, 1, 1])
    others_controls, own_controls = _box_controls(2, 12), _forward_only(_box_controls(3, 2))
    noise = np.random.default_rng(0)  # sensor noise: noise-free logs leave the covariance degenerate
    others = st.run_single_track(others_controls, np.zeros((12, 2)), simulator_car, 1 / 30)[0]
    own = st.run_single_track(own_controls, np.zeros((2, 2)), this_car, 1 / 30)[0]
    others, own = (rates + noise.normal(0.0, [0.005, 0.02], rates.shape) for rates in (others, own))
    other_logs = list(zip(others_controls, others, strict=True))
    own_logs = list(zip(own_controls, own, strict=True))

    pooled = st.identify_from_logs(other_logs + own_logs)
    assert pooled.values[0] > 0.93  # nearer the simulator's 1.0 than the car's 0.85
    found = st.identify_on_another_car(own_logs, other_logs)
    assert found.values[0] == pytest.approx(0.85, rel=0.01)
    alone = st.identify_from_logs(other_logs)
    assert found.values[1] == pytest.approx(alone.values[1], abs=0.01)  # the simulator's reverse gain, 1.1
    assert found.stderr[1] == pytest.approx(np.hypot(alone.stderr[1], st.WIDTH[1]), rel=0.05)
    assert found.stderr[0] < 0.05  # the motor the car's logs measured
    # no log of the car yet: the simulator's identification stands
    before = st.identify_on_another_car([], other_logs)
    np.testing.assert_array_equal(before.values, alone.values)


def test_the_model_identifies_on_its_own_logs_where_the_others_are_flagged(forward_grid: pd.DataFrame):
    """`PhysicsModel.identify` with `of_another_car` is `identify_on_another_car`, also through `fit`
    with the correction gate (whose probe keeps the flags of the logs it keeps)."""
    rows = pd.concat([training_rows(g, DATA) for _, g in forward_grid.groupby("run_id", sort=False)])
    x, y = arrays(rows, DATA)
    logs = _logs(forward_grid)
    flags = [i >= 3 for i in range(len(logs))]  # the first three logs (the straights) are this car's
    expected = st.identify_on_another_car(logs[:3], logs[3:])
    model = build_model(_config(), seed=0)
    model.identify(TrainingData(x, y, logs=logs, of_another_car=flags))
    np.testing.assert_allclose(model.theta.numpy(), expected.values, rtol=1e-5)
    assert not np.allclose(expected.values, st.identify_from_logs(logs).values, rtol=1e-3)
    gated = build_model(_config(correction_gate=True), seed=0)
    frames = [g for _, g in forward_grid.groupby("run_id", sort=False)]
    history = fit(
        gated,
        TrainingData(x, y, groups=rows["run_id"].to_numpy(), logs=logs,
                     log_groups=[g["run_id"].iloc[0] for g in frames], of_another_car=flags),
        TrainingConfig(epochs=2, batch_size=64, patience=None),
        seed=0,
    )  # fmt: skip
    assert set(history.gate_errors) == set(correction_gate.GATE_WEIGHTS)
    np.testing.assert_allclose(gated.theta.numpy(), expected.values, rtol=1e-5)


@pytest.mark.slow
def test_identification_on_the_twin_recovers_its_weaker_motor_and_grip():
    """The twin's change (weaker motor, less grip) is found within 10 % of the change MuJoCo shows."""
    maneuvers = [Maneuver("straight", t, 0.0, "ccw", 10.0) for t in (0.3, 0.6, 0.9, -0.5)]
    maneuvers += [Maneuver("skidpad", t, d, "ccw", 10.0) for t in (0.4, 0.8) for d in (0.2094, 0.5236)]
    nominal = simulator.collect(maneuvers, seed=0)
    car = simulator.twin_vehicle({"motor_gain": 0.9, "tire_friction": 0.55})
    twin = simulator.collect(maneuvers, seed=0, vehicle=car)
    found_nominal, _ = st.identify_from_logs(_logs(nominal))
    found_twin, _ = st.identify_from_logs(_logs(twin))

    def steady(frame: pd.DataFrame) -> np.ndarray:
        return np.array([g["speed"].to_numpy()[-60:].mean() for _, g in frame.groupby("run_id", sort=False)])

    true_ratio = steady(twin) / steady(nominal)
    # the straights: the motor's change, forward and reverse
    for index, gain in ((slice(0, 3), 0), (slice(3, 4), 1)):
        change = true_ratio[index].mean() - 1.0
        assert abs(change) > 0.05  # the twin is measurably slower
        found = found_twin[gain] / found_nominal[gain] - 1.0
        assert abs(found - change) <= 0.1 * abs(change), (st.PARAMETER_NAMES[gain], found, change)

    # full lock: grip gives back part of the speed; the identified scrub and gain predict how much
    def full_lock(theta: np.ndarray) -> float:
        return theta[0] / (1.0 + theta[3] * np.tan(0.5236) ** 2)

    change = true_ratio[[5, 7]].mean() - 1.0
    found = full_lock(found_twin) / full_lock(found_nominal) - 1.0
    assert abs(found - change) <= 0.1 * abs(change), (found, change)


@pytest.mark.slow
def test_trained_forward_only_it_never_leaves_physics(forward_model: PhysicsModel):
    """Every draw of every 60-s free run over the control box stays finite and within 1.5x Nigel's limits."""
    draws = forward_model.n_members or 32  # an ensemble's S = K draws are all its members
    sweep = physics.control_box_sweep(60.0)
    rollout = simulate(forward_model, sweep, rate_hz=30.0, n_samples=max(draws, 2), seed=0)
    assert np.isfinite(rollout.v).all() and np.isfinite(rollout.w).all()
    assert np.abs(rollout.v).max() <= SPEED_BOUND
    assert np.abs(rollout.w).max() <= YAW_BOUND
    assert physics.runs_out_of_bounds(rollout.v, rollout.w) == 0
    # the counter counts: the same runs pushed past the bound are all found
    assert physics.runs_out_of_bounds(rollout.v * 10.0, rollout.w) > 0
    # and throttle 0 brakes to a stand whatever the draw: the last second of the brake runs
    brake = [i for i, c in enumerate(sweep) if (c[-30:, 0] == 0.0).all()]
    assert np.abs(rollout.mean_rates[brake, -30:, 0]).max() < 0.01


def test_far_from_its_data_it_falls_back_to_the_datasheet(forward_model: PhysicsModel):
    """Trained forward only, a reverse straight runs at the datasheet's mirrored speed, not a guess."""
    rollout = simulate(forward_model, [np.tile([-0.6, 0.0], (600, 1))], rate_hz=30.0, n_samples=32, seed=0)
    assert forward_model.physical_parameters()["reverse_gain"] == pytest.approx(1.0, abs=0.05)  # untouched
    mean_v = rollout.mean_rates[0, -150:, 0].mean()
    assert abs(mean_v - (-0.16516)) <= forward_model.config.residual_bound * datasheet.MAX_SPEED
    assert abs(rollout.mean_rates[0, -150:, 1]).max() < 0.05  # a straight line stays straight


def test_it_saves_loads_and_replays_identically(forward_model: PhysicsModel, tmp_path):
    save_model(forward_model, tmp_path / "physics.pt")
    again = load_model(tmp_path / "physics.pt")
    assert again.physical_parameters() == forward_model.physical_parameters()
    controls = [np.tile([0.5, 0.3], (300, 1))]
    first = simulate(forward_model, controls, rate_hz=30.0, seed=3)
    second = simulate(again, controls, rate_hz=30.0, seed=3)
    np.testing.assert_array_equal(first.x, second.x)


def test_bad_settings_name_their_field(tmp_path):
    with pytest.raises(ValueError, match="kinematic_feature"):
        _config(kinematic_feature=True)
    with pytest.raises(ValueError, match="residual_bound"):
        _config(residual_bound=0.9)
    with pytest.raises(InputError, match=r"model\.kind"):
        PhysicsModel(_config(n_inputs=2))
    path = tmp_path / "static.toml"
    path.write_text('name = "x"\n[model]\nkind = "physics"\n')
    with pytest.raises(ConfigError, match=r"model\.kind = 'physics' needs data\.inputs"):
        load_config(path)


def test_identify_command_prints_the_fit_beside_the_datasheet(tmp_path, capsys):
    from activelearn.cli import main

    car = simulator.twin_vehicle({"motor_gain": 0.9})
    frame = simulator.collect([Maneuver("straight", 0.6, 0.0, "ccw", 8.0)], seed=0, vehicle=car)
    frame.to_parquet(tmp_path / "twin.parquet")
    assert main(["identify", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    row = next(line.split() for line in out.splitlines() if line.strip().startswith("speed_gain"))
    datasheet_value, fitted = float(row[1]), float(row[2])
    assert datasheet_value == 1.0 and 0.85 < fitted < 0.95  # the weaker motor, found in its own log
    assert "Gauss-Newton from one log" in out
    # beside logs of another car (nominal Nigel): still the twin's motor, and the printout says so
    (tmp_path / "nominal").mkdir()
    for throttle in (0.4, 0.8):  # one log a file
        log = simulator.collect([Maneuver("straight", throttle, 0.0, "ccw", 8.0)], seed=0)
        log.to_parquet(tmp_path / "nominal" / f"straight{throttle}.parquet")
    twin_log, other = str(tmp_path / "twin.parquet"), str(tmp_path / "nominal")
    assert main(["identify", twin_log, "--other-car", other]) == 0
    out = capsys.readouterr().out
    row = next(line.split() for line in out.splitlines() if line.strip().startswith("speed_gain"))
    assert 0.85 < float(row[2]) < 0.95 and "from 2 log(s) of another car" in out
    assert main(["identify", str(tmp_path / "missing.csv")]) == 2
    assert "LOG" in capsys.readouterr().err


@pytest.mark.slow
def test_a_campaign_scores_along_paths_with_it_and_predict_draws_its_fans(tmp_path):
    """Wherever a model kind works: a campaign (max_epistemic along the free runs), its saved model in
    `predict`, and the identified parameters carried along."""
    cfg = load_config(
        SMOKE,
        overrides={
            "output_dir": str(tmp_path / "runs"),
            "tracking": {"enabled": False},
            "strategy": "max_epistemic",
            "pool": {"kinds": ["skidpad", "slalom"], "duration": 8.0},
            "data": {"stride": 5, "skip_seconds": 0.0, "inputs": "history", "history": 3, "history_step": 2},
            "model": {"kind": "physics", "arch": "D16-V8-V"},
            "training": {"epochs": 15},
            "design": {"initial": 2, "per_round": 1, "max_maneuvers": 3},
            "acquisition": {"dynamic_points": "path", "score_points": 6},
            "test": {"kinds": ["slalom"], "throttles": [0.6], "steerings": [0.3], "duration": 8.0,
                     "metric": "rollout_pos_err_30s", "rollout_samples": 8},
        },
    )  # fmt: skip
    result = Campaign(cfg, tmp_path / "c").run(figures=False)
    assert len(result.state.rounds) == 2
    for record in result.state.rounds:
        assert np.isfinite(record["rollout_pos_err_30s"]) and record["rollout_pos_err_30s"] < 1.0
    model = load_model(tmp_path / "c" / "model.pt")
    assert isinstance(model, PhysicsModel)
    # identified on the campaign's skidpads and slaloms: they excite the scrub, which moves off 0
    assert model.physical_parameters()["scrub"] > 0.3
    done = predict_slalom_fan(tmp_path / "c", tmp_path)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "fan.png").stat().st_size > 10_000


def _perturbed_control_model(correction_inputs: str = "control", symmetry: str = "none") -> PhysicsModel:
    """An untrained physics model whose correction reads the control alone (or the whole window), its
    weights shaken so the correction and its spread over draws are far from zero."""
    model = build_model(_config(correction_inputs=correction_inputs, correction_symmetry=symmetry), seed=0)
    rng = np.random.default_rng(0)
    model.set_scalers(rng.normal(size=(400, 16)), 0.3 * rng.normal(size=(400, 2)))
    generator = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for weight in model.correction.parameters():
            weight.add_(0.5 * torch.randn(weight.shape, generator=generator))
    return model


def _busy_controls() -> list[np.ndarray]:
    """Held steps, a brake, a slow sine of the steering: constant and distinct rows, across tiles."""
    rng = np.random.default_rng(2)
    out = []
    for _ in range(6):
        throttle = np.repeat(rng.uniform(-1.0, 1.0, 14), 50)[:700]
        steering = np.repeat(rng.uniform(-0.5236, 0.5236, 28), 25)[:700]
        out.append(np.column_stack([throttle, steering]))
    out[0][100:300, 0] = 0.0
    out[1][:, 1] = 0.5 * np.sin(np.arange(700) / 30.0)
    return out


@pytest.mark.parametrize(
    ("weight", "symmetry", "scale"),
    [(1.0, "none", 1.0), (0.5, "none", 1.0), (0.0, "none", 1.0), (1.0, "mirror", 1.0), (0.5, "mirror", 1.0),
     (1.0, "none", 9.0), (0.5, "mirror", 9.0)],
)  # fmt: skip
@pytest.mark.usefixtures("c_kernels")
def test_free_runs_of_a_control_correction_agree_between_the_kernel_and_torch(weight, symmetry, scale):
    """physics_rollout.c and its torch twin draw the same free runs (float rounding apart), with the
    gate at any share, the correction mirror-symmetric or not, the draws widened (the [safety] fan's
    epistemic scale of 9) or not, and the pose (headings, lever arm) integrated inside the kernel."""
    model, controls = _perturbed_control_model(symmetry=symmetry), _busy_controls()
    model.correction_weight.fill_(weight)
    model.epistemic_scale.fill_(scale)
    headings = np.linspace(-2.0, 2.5, len(controls))
    kwargs = dict(rate_hz=30.0, n_samples=8, seed=3, initial_yaw=headings, lever_arm=0.08)
    kernel = simulate(model, controls, backend="native", **kwargs)
    torch_runs = simulate(model, controls, backend="reference", **kwargs)
    assert kernel.epistemic_var.max() > 1e-4  # the draws do differ
    assert np.abs(kernel.x).max() > 1.0 and np.abs(kernel.yaw[:, :, 0] - headings).max() < 1e-6
    for name in ("v", "w", "x", "y", "yaw", "mean_rates", "aleatoric_var", "epistemic_var"):
        np.testing.assert_allclose(getattr(kernel, name), getattr(torch_runs, name), atol=2e-5, err_msg=name)


@pytest.mark.parametrize(("inputs", "backend"), [("history", "reference"), ("control", "reference"),
                                               ("control", "native")])  # fmt: skip
def test_a_widened_fan_stays_as_bounded_as_its_draws(inputs, backend, request):
    """The [safety] fan widens the draws' epistemic spread (scale 9, a std x 3). Widening each draw's
    whole deviation from the average at every step compounded the deviations its past already
    carried (the aleatoric noise fed back), and the free runs ran to infinity; widened as a
    correction, they stay within the physical bounds of the unwidened draws."""
    if backend == "native":
        request.getfixturevalue("c_kernels")
    model, controls = _perturbed_control_model(inputs), _busy_controls()
    plain = simulate(model, controls, rate_hz=30.0, n_samples=16, seed=3, backend=backend)
    model.epistemic_scale.fill_(9.0)
    wide = simulate(model, controls, rate_hz=30.0, n_samples=16, seed=3, backend=backend)
    for name, limit in (("v", datasheet.MAX_SPEED), ("w", datasheet.MAX_YAW_RATE)):
        bound = max(1.5, np.abs(getattr(plain, name)).max() / limit)
        assert np.isfinite(getattr(wide, name)).all(), name
        assert np.abs(getattr(wide, name)).max() <= bound * limit, name
    assert np.isfinite(wide.epistemic_var).all()
    # the widening widens: the draws' spread at the end of each run is at least the unwidened one
    assert (wide.epistemic_var.mean(axis=1) >= plain.epistemic_var.mean(axis=1) * 0.99).all()


@pytest.mark.slow
@pytest.mark.parametrize("scale", [1.0, 9.0])
def test_free_runs_computed_whole_are_the_step_loops(monkeypatch, scale):
    """Without noise, the whole-run path and the generic step loop through `columns_forward` give the
    same free runs, the draws widened or not: the shortcut is exact, not an approximation."""
    monkeypatch.setattr(physics, "NOISE_CAP", 0.0)
    model, controls = _perturbed_control_model(), _busy_controls()
    model.epistemic_scale.fill_(scale)
    whole = simulate(model, controls, rate_hz=30.0, n_samples=8, seed=3)
    monkeypatch.setattr(PhysicsModel, "open_loop_free_runs", Model.open_loop_free_runs)
    stepped = simulate(model, controls, rate_hz=30.0, n_samples=8, seed=3)
    assert np.abs(whole.v).max() > 0.1 and whole.epistemic_var.max() > 1e-4
    for name in ("v", "w", "mean_rates", "epistemic_var"):
        np.testing.assert_allclose(getattr(whole, name), getattr(stepped, name), atol=2e-5, err_msg=name)


@pytest.mark.parametrize("inputs", ["control", "history"])
def test_a_mirror_symmetric_correction_mirrors_every_draw(inputs):
    """With `correction_symmetry = "mirror"` every draw's next rates at the mirror image of its inputs
    (every steering and yaw rate negated) are the same speed and the opposite yaw rate, and at zero
    steering and yaw rate the draws' yaw rate is 0; without it, a shaken correction is not symmetric."""
    rng = np.random.default_rng(4)
    x = rng.normal(size=(64, 16)) * 0.3
    x[:, 0:8:2] = rng.uniform(-1.0, 1.0, size=(64, 4))  # throttles
    mirror = x.copy()
    mirror[:, 1::2] *= -1.0
    straight = x.copy()
    straight[:, 1::2] = 0.0
    for symmetry in ("mirror", "none"):
        model = _perturbed_control_model(inputs, symmetry)
        sampled = model.draw(8, seed=0, backend="reference")
        (means, var), (mirrored, mirrored_var) = sampled(x), sampled(mirror)
        asymmetry = np.abs(means[..., 1] + mirrored[..., 1]).max()
        if symmetry == "none":
            assert asymmetry > 1e-2  # the shaken correction is far from symmetric on its own
            continue
        assert asymmetry < 1e-5
        np.testing.assert_allclose(means[..., 0], mirrored[..., 0], atol=1e-5)
        np.testing.assert_allclose(var, mirrored_var, atol=1e-6)
        assert np.abs(sampled(straight)[0][..., 1]).max() < 1e-5
        assert np.abs(means[..., 1]).max() > 0.1  # not symmetric by being zero


def test_mirror_symmetric_free_runs_computed_whole_are_the_step_loops(monkeypatch):
    """The whole-run path (torch) of a mirror-symmetric correction equals the generic step loop, and
    a free run of mirrored controls from mirrored rates is the mirror image of the free run."""
    monkeypatch.setattr(physics, "NOISE_CAP", 0.0)
    model, controls = _perturbed_control_model(symmetry="mirror"), _busy_controls()
    start = np.tile([0.3, 0.5], (len(controls), 1))
    whole = simulate(model, controls, rate_hz=30.0, n_samples=8, seed=3, initial_rates=start)
    mirrored = [c * [1.0, -1.0] for c in controls]
    image = simulate(model, mirrored, rate_hz=30.0, n_samples=8, seed=3, initial_rates=start * [1.0, -1.0])
    np.testing.assert_allclose(image.v, whole.v, atol=2e-5)
    np.testing.assert_allclose(image.w, -whole.w, atol=2e-5)
    monkeypatch.setattr(PhysicsModel, "open_loop_free_runs", Model.open_loop_free_runs)
    stepped = simulate(model, controls, rate_hz=30.0, n_samples=8, seed=3, initial_rates=start)
    assert np.abs(whole.w).max() > 0.1 and whole.epistemic_var.max() > 1e-5  # the draws do differ
    for name in ("v", "w", "mean_rates", "epistemic_var"):
        np.testing.assert_allclose(getattr(whole, name), getattr(stepped, name), atol=2e-5, err_msg=name)


def test_a_gated_correction_keeps_its_spread_and_a_share_of_its_mean():
    """`correction_weight` scales the correction's mean over draws and leaves each draw's deviation."""
    model = _perturbed_control_model()
    params = model.correction.sample_params(16, 0)
    inputs = torch.randn(2, 50, generator=torch.Generator().manual_seed(0))
    z, _ = model.correction.columns_forward(inputs, model.correction.columns_params(params), 16)
    assert z.mean(dim=0).abs().max() > 0.1  # a correction whose mean matters
    for weight in (0.0, 0.5):
        model.correction_weight.fill_(weight)
        gated = model._gate(z)
        torch.testing.assert_close(gated.mean(dim=0), weight * z.mean(dim=0), atol=1e-5, rtol=0)
        torch.testing.assert_close(gated - gated.mean(dim=0), z - z.mean(dim=0), atol=1e-5, rtol=0)


def test_gated_free_runs_computed_whole_are_the_step_loops(monkeypatch):
    """With a share of the correction kept, the whole-run path (torch) still equals the step loop."""
    monkeypatch.setattr(physics, "NOISE_CAP", 0.0)
    model, controls = _perturbed_control_model(), _busy_controls()
    model.correction_weight.fill_(0.5)
    whole = simulate(model, controls, rate_hz=30.0, n_samples=8, seed=3)
    full = simulate(_perturbed_control_model(), controls, rate_hz=30.0, n_samples=8, seed=3)
    monkeypatch.setattr(PhysicsModel, "open_loop_free_runs", Model.open_loop_free_runs)
    stepped = simulate(model, controls, rate_hz=30.0, n_samples=8, seed=3)
    assert np.abs(whole.mean_rates - full.mean_rates).max() > 1e-2  # the gate moved the mean
    for name in ("v", "w", "mean_rates", "epistemic_var"):
        np.testing.assert_allclose(getattr(whole, name), getattr(stepped, name), atol=2e-5, err_msg=name)


def _with_parameter_spread(model: PhysicsModel) -> PhysicsModel:
    """The model with the scrub and the understeer uncertain (s.e. 0.3 and 0.1, correlated)."""
    covariance = np.diag(np.full(len(st.PARAMETERS), 1e-8))
    covariance[3, 3], covariance[4, 4], covariance[3, 4] = 0.09, 0.01, 0.015
    covariance[4, 3] = covariance[3, 4]
    with torch.no_grad():
        model.theta_scale.copy_(torch.as_tensor(st.cholesky_factor(covariance), dtype=torch.float32))
    return model


def test_each_draw_has_its_own_parameters_from_the_covariance():
    model = _with_parameter_spread(_perturbed_control_model())
    draws = model.parameter_draws(4000, seed=5)
    np.testing.assert_array_equal(draws.numpy(), model.parameter_draws(4000, seed=5).numpy())  # seeded
    assert not torch.equal(draws, model.parameter_draws(4000, seed=6))
    assert (draws >= torch.as_tensor(st.LOW, dtype=torch.float32)).all()
    assert (draws <= torch.as_tensor(st.HIGH, dtype=torch.float32)).all()
    # scrub's nominal 0 sits on its lower bound: clipped there; the understeer is inside its range
    assert np.std(draws[:, 4].numpy()) == pytest.approx(0.1, rel=0.1)
    assert float(draws[:, 0].std()) < 1e-3  # the others stay put
    assert torch.equal(_perturbed_control_model().parameter_draws(3, seed=5), model.theta.expand(3, -1))


@pytest.mark.parametrize("inputs", ["control", "history"])
def test_the_parameter_spread_widens_the_fans_and_whole_runs_still_are_the_step_loops(monkeypatch, inputs):
    """The draws' parameters enter both free-run paths alike (the kernel reads one set: torch steps
    them), and the fans at full lock are wider with them than with the correction's spread alone."""
    monkeypatch.setattr(physics, "NOISE_CAP", 0.0)
    controls = [np.tile([0.8, 0.5236], (300, 1)), np.tile([0.6, 0.2], (300, 1))]
    plain = simulate(_perturbed_control_model(inputs), controls, rate_hz=30.0, n_samples=16, seed=3)
    model = _with_parameter_spread(_perturbed_control_model(inputs))
    spread = simulate(model, controls, rate_hz=30.0, n_samples=16, seed=3)
    assert (spread.epistemic_var[0, -60:].mean(axis=0) > 2 * plain.epistemic_var[0, -60:].mean(axis=0)).all()
    monkeypatch.setattr(PhysicsModel, "open_loop_free_runs", Model.open_loop_free_runs)
    stepped = simulate(model, controls, rate_hz=30.0, n_samples=16, seed=3)
    for name in ("v", "w", "mean_rates", "epistemic_var"):
        np.testing.assert_allclose(getattr(spread, name), getattr(stepped, name), atol=2e-5, err_msg=name)


def test_identification_sets_the_spread_only_when_asked(forward_grid: pd.DataFrame, tmp_path):
    rows = pd.concat([training_rows(g, DATA) for _, g in forward_grid.groupby("run_id", sort=False)])
    x, y = arrays(rows, DATA)
    logs = _logs(forward_grid)
    found = st.identify_from_logs(logs)
    for setting in ("none", "by_log"):
        model = build_model(_config(parameter_uncertainty=setting), seed=0)
        model.identify(TrainingData(x, y, logs=logs))
        scale = model.theta_scale.double().numpy()
        if setting == "none":
            assert not scale.any()
            continue
        np.testing.assert_allclose(scale @ scale.T, found.covariance, rtol=1e-3, atol=1e-6)
        save_model(model, tmp_path / "spread.pt")
        torch.testing.assert_close(load_model(tmp_path / "spread.pt").theta_scale, model.theta_scale)
    # a model saved before the spread existed loads without one
    state = build_model(_config(), seed=0).state_dict()
    del state["theta_scale"]
    older = build_model(_config(), seed=0)
    older.theta_scale.fill_(1.0)
    older.load_state_dict(state)
    assert not older.theta_scale.any()


def test_the_gate_keeps_the_correction_only_where_held_out_maneuvers_want_it(monkeypatch):
    """On logs of the bare single track the gate drops a correction that shifts the mean; on logs the
    corrected model drives itself it keeps all of it."""
    monkeypatch.setattr(physics, "NOISE_CAP", 1e-4)
    model, controls = _perturbed_control_model(), _busy_controls()
    start = np.zeros((len(controls), 2))
    core = st.run_single_track(np.stack(controls), start, model.theta.numpy().astype(float), model.dt)[0]
    gated = simulate(model, controls, rate_hz=30.0, n_samples=correction_gate.GATE_SAMPLES, seed=0)
    corrected = gated.mean_rates
    ids = list(range(len(controls)))
    for rates, expected in ((core, 0.0), (corrected, 1.0)):
        logs = [(u, r[: len(u)]) for u, r in zip(controls, rates, strict=True)]
        trained_on = []
        rows = np.zeros((10 * len(ids), 1))  # ten rows per maneuver: the probe ignores them
        data = TrainingData(rows, rows, groups=np.repeat(ids, 10), logs=logs, log_groups=ids)

        def probe(held_in, trained_on=trained_on):
            assert len(held_in.x) == 10 * len(held_in.logs) and set(held_in.groups) == set(held_in.log_groups)
            trained_on.append(len(held_in.logs))
            return model

        chosen = correction_gate.choose_correction_weight(probe, data, seed=0)
        assert chosen is not None and trained_on == [len(controls) - 2]  # a quarter of 6 held out
        weight, errors = chosen
        assert weight == expected, errors
        assert errors[weight] < 0.5 * max(errors.values())
        # Two held out of six: judged with at least two; closed (the core, no probe) when three are asked.
        trained_on.clear()
        two = correction_gate.choose_correction_weight(probe, data, seed=0, min_held_out=2)
        assert two == chosen and trained_on == [len(controls) - 2]
        closed = correction_gate.choose_correction_weight(probe, data, seed=0, min_held_out=3)
        assert closed == (0.0, {}) and trained_on == [len(controls) - 2]


def test_fit_gates_the_correction_and_the_choice_is_saved(forward_grid: pd.DataFrame, tmp_path):
    """`[model] correction_gate` through `fit`: a probe without a quarter of the maneuvers picks a share,
    the model keeps it, and saving and loading keep it too (a state dict from before loads whole)."""
    frames = [g for _, g in forward_grid.groupby("run_id", sort=False)]
    rows = pd.concat([training_rows(g, DATA) for g in frames])
    x, y = arrays(rows, DATA)
    model = build_model(_config(correction_gate=True), seed=0)
    history = fit(
        model,
        TrainingData(x, y, groups=rows["run_id"].to_numpy(), logs=_logs(forward_grid),
                     log_groups=[g["run_id"].iloc[0] for g in frames]),
        TrainingConfig(epochs=4, batch_size=64, patience=None),
        seed=0,
    )  # fmt: skip
    assert set(history.gate_errors) == set(correction_gate.GATE_WEIGHTS)
    assert history.correction_weight == min(history.gate_errors, key=lambda w: (history.gate_errors[w], w))
    assert float(model.correction_weight) == history.correction_weight
    assert model.round_metrics() == {"correction_weight": history.correction_weight}  # what a round logs
    assert model.identifies_on_logs and set(model.physical_parameters()) == set(st.PARAMETER_NAMES)
    save_model(model, tmp_path / "gated.pt")
    assert float(load_model(tmp_path / "gated.pt").correction_weight) == history.correction_weight
    state = {k: v for k, v in model.state_dict().items() if k != "correction_weight"}
    fresh = build_model(_config(correction_gate=True), seed=1)
    fresh.correction_weight.fill_(0.0)
    fresh.load_state_dict(state)
    assert float(fresh.correction_weight) == 1.0
    # Asked to judge on more held-out maneuvers than a quarter of these: closed, no probe trained.
    closed = build_model(_config(correction_gate=True, correction_gate_min_held_out=100), seed=0)
    history = fit(
        closed,
        TrainingData(x, y, groups=rows["run_id"].to_numpy(), logs=_logs(forward_grid),
                     log_groups=[g["run_id"].iloc[0] for g in frames]),
        TrainingConfig(epochs=4, batch_size=64, patience=None),
        seed=0,
    )  # fmt: skip
    assert (history.correction_weight, history.gate_errors) == (0.0, {})
    assert float(closed.correction_weight) == 0.0


def test_steady_state_inputs_are_the_held_control_loop_and_computed_once_per_model_state(tmp_path):
    """The quasi-steady inputs: each control held from standstill for 60 steps, the posterior-mean rates
    fed back (written out here on the model's own draws). Asked again for the same model state and
    controls (a round asks for its grid twice, its target twice with [safety] cuts), they are not
    recomputed; a model changed in place, or other controls, are."""
    model = _perturbed_control_model("history").eval()  # its correction reads the window, as in safe_track
    throttles, steerings = np.meshgrid(np.linspace(-1.0, 1.0, 9), np.linspace(-0.5236, 0.5236, 7))
    controls = np.column_stack([throttles.ravel(), steerings.ravel()])  # throttle 0 (the brake) included
    sampled = model.draw(8, seed=0)
    rates = np.zeros((len(controls), 2), dtype=np.float32)
    window = lambda: np.hstack([np.tile(controls, 4), np.tile(rates, 4)]).astype(np.float32)  # noqa: E731
    for _ in range(60):
        rates = sampled(window())[0].mean(axis=0)
    reference = window()
    assert np.abs(reference[:, 8:10]).max() > 0.05  # the rates did move off standstill

    before = STEADY_STATES.misses
    first = model_inputs(model, controls)
    np.testing.assert_allclose(first, reference, rtol=0, atol=1e-6)
    assert STEADY_STATES.misses == before + 1
    computed, first[:] = first.copy(), np.nan  # a caller's changes stay its own
    again = steady_state_inputs(model, controls.copy())
    assert STEADY_STATES.misses == before + 1  # not computed again
    np.testing.assert_array_equal(again, computed)
    save_model(model, tmp_path / "m.pt")  # the same state in another object: the same key
    np.testing.assert_array_equal(steady_state_inputs(load_model(tmp_path / "m.pt"), controls), again)
    assert STEADY_STATES.misses == before + 1

    with torch.no_grad():
        model.theta[0] *= 0.8  # the forward gain, in place
    slower = steady_state_inputs(model, controls)
    assert STEADY_STATES.misses == before + 2
    assert np.abs(slower - again).max() > 1e-3
    steady_state_inputs(model, controls[:5])
    assert STEADY_STATES.misses == before + 3


def test_distinct_rows_are_numpys_unique_rows_in_its_order():
    """`physics.distinct_rows` (one sort of 64-bit keys) against `np.unique(axis=0)`: the same rows, order
    and inverse, signed zeros, tiny and repeated values included."""
    rng = np.random.default_rng(0)
    grid = np.array([-1, -0.5, -0.0, 0.0, 1e-8, -1e-8, 0.3, 0.25, 1.0], np.float32)
    for trial in range(40):
        n = int(rng.integers(1, 2000))
        pairs = rng.choice(grid, (n, 2)) if trial % 2 else rng.normal(size=(n, 2)).astype(np.float32)
        pairs[n // 2 :] = pairs[: n - n // 2]
        rows, index = physics.distinct_rows(pairs)
        expected, inverse = np.unique(pairs, axis=0, return_inverse=True)
        assert np.array_equal(rows, expected) and np.array_equal(index, inverse.reshape(-1))
