"""The truth simulators of the tyre-model cars (`simulator.tyre_car`): built from their vehicle files, they
drive as the files say (the motor law, the brake, the linear single track's range, saturation near μ g),
stay stable over the control box, log the AutoDRIVE columns like Nigel, resume bit for bit from any
logged state and take the twin's overrides; the compiled stepping loop follows the NumPy reference. Real
MuJoCo, small sizes (the measurements at full size are experiments/benchmarks/bench_vehicles.py's)."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import mujoco
import mujoco.rollout
import numpy as np
import pandas as pd
import pytest

from simulator import (
    COLUMNS,
    Maneuver,
    Replay,
    StopRule,
    Vehicle,
    ackermann_angles,
    cbuild,
    collect,
    tyre_kernel,
)
from simulator.build import build_vehicle, truth_text
from simulator.twin import _yaw_inertia
from simulator.tyre_car import TyreCar
from simulator.vehicles.spec import GRAVITY, VEHICLE_DIR, VehicleFileError, load_vehicle

CARS = ("f1tenth", "bmw320i")
DELTA = math.atan(1.0 / 15.5)  # ISO 4138's 40 m radius at a 2.6 m wheelbase, the same angle for every car
RATE = 30


@pytest.fixture(scope="module")
def cars() -> dict[str, TyreCar]:
    return {name: build_vehicle(name) for name in CARS}


def mu_g(car: TyreCar) -> float:
    return car.friction * GRAVITY


def low_turn(car: TyreCar) -> Maneuver:
    """A steady turn at about 0.15 μg (the linear range), long enough for the speed to settle."""
    speed = math.sqrt(0.15 * mu_g(car) * car.wheelbase / DELTA)
    return Maneuver("skidpad", round(speed / car.top_speed, 3), DELTA, "ccw", 5 * tau(car))


# Steering and speed (a multiple of the kinematic turn's speed at μ g) of the turn past the limit: the
# 1:10 car at full lock; the full-size car at half its lock, since at its full 1.066 rad (61 deg) the
# front tyres' force points mostly backwards and the driven rear saturates first (about 0.55 μg there).
SATURATING = {"f1tenth": (1.0, 3.0), "bmw320i": (0.5, 2.0)}


def saturating_turn(car: TyreCar) -> Maneuver:
    """A steady turn well past the limit: the straight speed a multiple of the kinematic turn's at μ g."""
    lock, multiple = SATURATING[car.spec.name]
    steering = lock * car.steering_limit
    speed = multiple * math.sqrt(mu_g(car) * car.wheelbase / math.tan(steering))
    return Maneuver("skidpad", round(speed / car.top_speed, 3), steering, "ccw", 4 * tau(car))


def tau(car: TyreCar) -> float:
    """The motor law's time constant v_top / a_max (s)."""
    return car.top_speed / car.max_acceleration


def brake_replay(seconds: float = 3.0) -> Replay:
    n = round(seconds * RATE)
    throttle = np.r_[np.full(n, 0.5), np.zeros(n)]
    return Replay("brake", throttle, np.zeros_like(throttle))


def last(table: pd.DataFrame, run_id: str, seconds: float = 1.0) -> pd.DataFrame:
    run = table[table.run_id == run_id]
    return run[run.time >= run.time.max() - seconds]


@pytest.fixture(scope="module")
def drives(cars: dict[str, TyreCar]) -> dict[str, pd.DataFrame]:
    """Per car, one collection: throttle 0.5 straight, a brake from speed, a low and a saturating turn."""
    out = {}
    for name, car in cars.items():
        maneuvers = [Maneuver("straight", 0.5, duration=6 * tau(car)), brake_replay(), low_turn(car),
                     saturating_turn(car)]  # fmt: skip
        out[name] = collect(maneuvers, vehicle=car, noise=None)
    return out


@pytest.mark.parametrize("name", CARS)
def test_the_model_carries_the_files_mass_inertia_cg_and_step(name: str, cars: dict[str, TyreCar]) -> None:
    car = cars[name]
    spec = car.spec
    m = car.model
    assert car.timestep == spec.truth.timestep.value
    assert m.body_subtreemass[m.body("chassis").id] == pytest.approx(spec.inertia.mass.value, rel=1e-12)
    assert _yaw_inertia(m) == pytest.approx(spec.inertia.yaw_inertia.value, rel=1e-9)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert d.subtree_com[m.body("chassis").id] == pytest.approx([0.0, 0.0, spec.geometry.cg_height.value])
    # settled on its wheels: the loads MuJoCo measures are the static axle loads
    loads = car.rest_state[car._loads]
    front, rear = spec.axle_loads()
    assert loads[:2].sum() == pytest.approx(front, rel=1e-3)
    assert loads[2:].sum() == pytest.approx(rear, rel=1e-3)
    assert isinstance(car, Vehicle) and not isinstance(build_vehicle("nigel"), TyreCar)


@pytest.mark.parametrize("name", CARS)
def test_top_speed_at_half_throttle_is_the_files(name: str, cars: dict, drives: dict) -> None:
    car = cars[name]
    speed = last(drives[name], Maneuver("straight", 0.5, duration=6 * tau(car)).name).speed.mean()
    assert speed == pytest.approx(float(car.spec.steady_speed(0.5)), rel=0.01)
    assert speed == pytest.approx(0.5 * car.spec.drivetrain.top_speed.value, rel=0.01)


@pytest.mark.parametrize("name", CARS)
def test_braking_decelerates_at_the_file_or_the_grip_and_stands_still(
    name: str, cars: dict, drives: dict
) -> None:
    car = cars[name]
    run = drives[name][drives[name].run_id == "brake"]
    top = run.speed.max()
    braking = run[(run.throttle == 0.0) & (run.speed < 0.9 * top) & (run.speed > 0.1 * top)]
    decel = -np.polyfit(braking.time, braking.speed, 1)[0]
    assert decel == pytest.approx(min(car.brake_deceleration, mu_g(car)), rel=0.03)
    assert abs(run.speed.iloc[-1]) < 1e-6 and abs(run.angZ.iloc[-1]) < 1e-6


@pytest.mark.parametrize("name", CARS)
def test_a_steady_turn_in_the_linear_range_has_the_linear_single_tracks_yaw_gain(
    name: str, cars: dict, drives: dict
) -> None:
    car = cars[name]
    turn = last(drives[name], low_turn(car).name, 2.0)
    v, r = turn.speed.mean(), turn.angZ.mean()
    assert 0.05 < v * r / mu_g(car) < 0.3
    assert r / DELTA == pytest.approx(float(car.spec.linear_yaw_gain(v)), rel=0.10)


@pytest.mark.parametrize("name", CARS)
def test_lateral_acceleration_saturates_near_mu_g(name: str, cars: dict, drives: dict) -> None:
    car = cars[name]
    turn = last(drives[name], saturating_turn(car).name, 2.0)
    v, r = turn.speed.mean(), turn.angZ.mean()
    assert 0.85 < v * r / mu_g(car) < 1.05
    assert v * r < 0.95 * v * v * math.tan(turn.steering.iloc[-1]) / car.wheelbase  # sliding: a wider circle


@pytest.mark.parametrize("name", CARS)
def test_no_divergence_over_a_coarse_control_box(name: str, cars: dict) -> None:
    car = cars[name]
    lim = car.steering_limit
    box = [Maneuver("straight", u, duration=3.0) for u in (-1.0, 0.0, 1.0)]
    box += [Maneuver("skidpad", u, lim, d, 3.0) for u in (-1.0, 0.0, 1.0) for d in ("ccw", "cw")]
    box += [Maneuver("slalom", 1.0, lim, "ccw", 3.0), Maneuver("eight", 1.0, lim, "cw", 3.0)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a DivergenceWarning fails
        table = collect(box, vehicle=car, noise=None)
    assert not table.diverged.any()
    assert np.isfinite(table[["speed", "angZ", "posX", "posY"]].to_numpy()).all()
    assert table.roll.abs().max() < 0.05 and table.pitch.abs().max() < 0.05
    braked = table[table.throttle == 0.0]
    assert braked.speed.abs().max() < 1e-6  # braked from rest at any steering: it stands still


def test_collect_logs_the_autodrive_columns_deterministically_for_a_seed(cars: dict) -> None:
    car = cars["f1tenth"]
    maneuvers = [Maneuver("skidpad", 0.2, 0.2, "cw", 2.0), Maneuver("straight", -0.4, duration=1.0)]
    first = collect(maneuvers, vehicle=car, seed=3)
    again = collect(maneuvers, vehicle=car, seed=3, threads=1)
    other = collect(maneuvers, vehicle=car, seed=4)
    assert tuple(first.columns) == COLUMNS
    assert len(first) == 61 + 31 and not first.diverged.any()
    pd.testing.assert_frame_equal(first, again)
    assert not np.allclose(first.speed, other.speed)
    turn = first[first.run_id == maneuvers[0].name]
    assert turn.angZ.iloc[-1] < -0.5
    assert turn.leftTicks.iloc[-1] > turn.rightTicks.iloc[-1] > 1000  # turning right: the left wheel outside
    back = first[first.run_id == maneuvers[1].name]
    assert back.speed.iloc[-1] < -1.0 and back.leftTicks.iloc[-1] < 0
    assert turn.accZ.iloc[-1] == pytest.approx(GRAVITY, abs=0.05)


def test_a_run_alone_equals_the_run_in_a_large_threaded_batch(cars: dict) -> None:
    car = cars["f1tenth"]
    rng = np.random.default_rng(0)
    throttles, steerings = rng.uniform(0.05, 0.6, 50), rng.uniform(0.0, car.steering_limit, 50)
    pairs = zip(throttles, steerings, strict=True)
    maneuvers = [Maneuver("skidpad", float(u), float(s), "ccw", 1.0) for u, s in pairs]
    batch = collect(maneuvers, vehicle=car, noise=None, threads=2)
    alone = collect(maneuvers[7:8], vehicle=car, noise=None, threads=1)
    seventh = batch[batch.run_id == maneuvers[7].name].drop(columns="timestamp").reset_index(drop=True)
    pd.testing.assert_frame_equal(seventh, alone.drop(columns="timestamp"), check_exact=True)


def test_the_state_carries_everything_a_step_needs(cars: dict) -> None:
    car = cars["bmw320i"]
    nstep = 400
    control = car.controls(np.full(nstep, 0.6), np.linspace(0.0, 0.3, nstep))[None]

    def roll(state: np.ndarray, ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = ctrl.shape[1]
        states, sens = np.empty((1, n, car.nstate)), np.empty((1, n, car.model.nsensordata))
        with mujoco.rollout.Rollout(nthread=0) as roller:
            data = [mujoco.MjData(car.model)]
            car.rollout(roller, data, state[None], np.ascontiguousarray(ctrl), n, states, sens)
        return states[0], sens[0]

    whole, whole_sens = roll(car.rest_state, control)
    half, _ = roll(car.rest_state, control[:, :150])
    rest, rest_sens = roll(half[-1], control[:, 150:])
    assert np.array_equal(whole[150:], rest) and np.array_equal(whole_sens[150:], rest_sens)
    # the steering follows the command at the file's rate; the hinges hold its Ackermann split
    delta = whole[:, car._delta]
    assert np.all(np.abs(np.diff(delta)) <= car.steering_rate * car.timestep * (1 + 1e-12))
    left, right = ackermann_angles(delta, car.wheelbase, car.track)
    assert np.allclose(whole[:, car._steer_qpos[0]], left)
    assert np.allclose(whole[:, car._steer_qpos[1]], right)


@pytest.mark.parametrize("name", CARS)
def test_the_compiled_step_follows_the_numpy_reference(name: str, cars: dict) -> None:
    """The C loop and the NumPy path through mujoco.rollout compute the same equations: the logs of runs
    through the tyres' limit, the brake and reverse agree to rounding (libm's atan, sin, tan against
    NumPy's), in a batch stepped by two threads."""
    compiled = cars[name]
    assert tyre_kernel.library() is not None  # the suite's machines have a C compiler
    reference = build_vehicle(name)
    reference.backend = "reference"
    maneuvers = [saturating_turn(compiled), Maneuver("fishhook", 1.0, compiled.steering_limit, "cw", 2.0),
                 Maneuver("slalom", -0.5, 0.5 * compiled.steering_limit, "ccw", 2.0), brake_replay(1.0)]
    maneuvers[0] = Maneuver("skidpad", maneuvers[0].throttle, maneuvers[0].steering, "ccw", 2.0)
    fast = collect(maneuvers, vehicle=compiled, noise=None, threads=2).drop(columns="timestamp")
    slow = collect(maneuvers, vehicle=reference, noise=None, threads=2).drop(columns="timestamp")
    numbers = fast.select_dtypes("number").columns
    assert (fast.angZ.abs() > 0.5).any() and (fast.speed < -0.5).any()  # they turned hard and reversed
    np.testing.assert_allclose(fast[numbers].to_numpy(), slow[numbers].to_numpy(), rtol=1e-9, atol=1e-9)
    pd.testing.assert_frame_equal(fast.drop(columns=numbers), slow.drop(columns=numbers))


def test_without_a_compiler_the_cars_take_the_numpy_path_and_the_cache_key_says_so(
    cars: dict, failing_compiler
) -> None:
    car = cars["f1tenth"]
    maneuver = Maneuver("skidpad", 0.5, 0.3, "ccw", 1.0)
    compiled_key = truth_text("f1tenth")
    compiled = collect([maneuver], vehicle=car, noise=None)
    with failing_compiler(cbuild, tyre_kernel.library):
        with pytest.warns(RuntimeWarning, match="tyre step unavailable"):
            assert tyre_kernel.library() is None
        fallback = collect([maneuver], vehicle=car, noise=None)
        assert truth_text("f1tenth") != compiled_key  # a cache never mixes the two paths' last bits
    assert truth_text("f1tenth") == compiled_key
    numbers = compiled.select_dtypes("number").columns.drop("timestamp")
    np.testing.assert_allclose(fallback[numbers].to_numpy(), compiled[numbers].to_numpy(), rtol=1e-9,
                               atol=1e-9)  # fmt: skip


def test_the_tyre_forces_are_a_scalar_reference_computed_on_mujocos_kinematics(cars: dict) -> None:
    car = cars["bmw320i"]
    m = car.model
    state = car.rest_state.copy()
    quat = np.array([1.0, 0.01, -0.02, 0.3])
    state[car._quat] = quat / np.linalg.norm(quat)
    state[car._vel], state[car._omega] = [5.0, -1.0, 0.1], [0.05, -0.03, 0.4]
    state[car._delta], state[car._loads] = 0.2, [3000.0, 2500.0, 2600.0, 2200.0]
    d = mujoco.MjData(m)
    mujoco.mj_setState(m, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS.value)
    mujoco.mj_forward(m, d)
    chassis = m.body("chassis").id
    rot = d.xmat[chassis].reshape(3, 3)
    angles = [*ackermann_angles(0.2, car.wheelbase, car.track), 0.0, 0.0]
    forward = rot[:, 0] @ d.qvel[:3]
    loads = state[car._loads]
    for throttle in (0.7, 0.0, -0.4):
        expected = np.zeros(6)
        for i, wheel in enumerate(("fl", "fr", "rl", "rr")):
            geom = m.geom(f"tyre_{wheel}").id
            velocity = np.zeros(6)
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_GEOM, geom, velocity, 0)
            heading = rot @ np.array([math.cos(angles[i]), math.sin(angles[i]), 0.0])
            heading[2] = 0.0
            heading /= np.linalg.norm(heading)
            side = np.array([-heading[1], heading[0], 0.0])
            v_long, v_lat = velocity[3:] @ heading, velocity[3:] @ side
            alpha = math.atan(-v_lat / max(abs(v_long), car.fade_speed))
            grip = car.friction * loads[i]
            b_alpha = car.stiffness_factor[i] * alpha
            phi = b_alpha - car.curvature * (b_alpha - math.atan(b_alpha))
            f_lat = grip * math.sin(car.shape * math.atan(phi))
            if throttle == 0.0:
                f_long = -car.mass_nominal * car.brake_deceleration * loads[i] / loads.sum() * float(
                    np.clip(v_long / (0.1 * car.fade_speed), -1, 1))
            else:
                top = car.top_speed if throttle > 0 else car.reverse_top_speed
                a_max = car.max_acceleration
                power = a_max * car.power_limit_speed / max(abs(forward), car.power_limit_speed)
                a = float(np.clip(a_max * (throttle - forward / top), -power, power))
                f_long = car.mass_nominal * a * car.drive_share[i]
            if math.hypot(f_long, f_lat) > grip:
                f_long, f_lat = np.array([f_long, f_lat]) * grip / math.hypot(f_long, f_lat)
            force = f_long * heading + f_lat * side
            point = d.geom_xpos[geom] - np.array([0.0, 0.0, car.wheel_radius])
            expected += np.r_[force, np.cross(point - d.xipos[chassis], force)]
        got, _, _, _ = car.tyre_forces(state[None], np.array([throttle]), np.array([0.3]))
        assert np.allclose(got[0], expected, rtol=1e-10, atol=1e-8)


def test_twin_overrides_change_what_they_name(cars: dict) -> None:
    nominal = cars["f1tenth"]
    turn = saturating_turn(nominal)
    straight = Maneuver("straight", 0.5, duration=6 * tau(nominal))
    launch = Maneuver("straight", 0.5, duration=1.0)

    def drive(car: TyreCar) -> pd.DataFrame:
        return collect([turn, straight, launch, brake_replay(1.0)], vehicle=car, noise=None)

    base = drive(nominal)

    def a_y(table: pd.DataFrame) -> float:
        late = last(table, turn.name, 2.0)
        return float((late.speed * late.angZ).mean())

    slippery = drive(TyreCar("f1tenth", {"tire_friction": 0.8}))
    assert a_y(slippery) < 0.85 * a_y(base)
    weak = drive(TyreCar("f1tenth", {"motor_gain": 0.8}))
    assert last(weak, straight.name).speed.mean() == pytest.approx(0.8 * 10.0, rel=0.01)
    heavy = drive(TyreCar("f1tenth", {"mass": 1.5}))
    # a payload: the same motor force on 1.5 times the mass, v = 10 m/s (1 - exp(-t / 1.5 tau))
    end = last(heavy, straight.name, 0.0)
    expected = 10.0 * (1 - math.exp(-end.time.iloc[0] / (1.5 * tau(nominal))))
    assert end.speed.iloc[0] == pytest.approx(expected, rel=0.005)
    assert last(heavy, launch.name, 0.0).speed.iloc[0] < 0.8 * last(base, launch.name, 0.0).speed.iloc[0]
    offset = collect([launch], vehicle=TyreCar("f1tenth", {"steering_offset": 0.05}), noise=None)
    assert offset.angZ.iloc[-1] > 0.3  # a misaligned servo turns a straight left
    late = collect([brake_replay(1.0)], vehicle=TyreCar("f1tenth", {"latency": 0.1}), noise=None)
    braking = base[base.run_id == "brake"].speed.to_numpy()
    assert late.speed.to_numpy()[33] > braking[33] + 0.5  # 0.1 s after the brake command it still drives
    inertia = TyreCar("f1tenth", {"yaw_inertia": 2.0})
    assert _yaw_inertia(inertia.model) == pytest.approx(2 * nominal.spec.inertia.yaw_inertia.value, rel=1e-9)


def test_a_stop_rule_brakes_a_tyre_car_to_a_stand(cars: dict) -> None:
    car = cars["f1tenth"]
    arena = StopRule(((-5.0, -10.0), (12.0, -10.0), (12.0, 10.0), (-5.0, 10.0)), distance=1.0, settle=3.0)
    table = collect([Maneuver("straight", 0.4, duration=6.0)], vehicle=car, noise=None, stop=arena)
    assert table.throttle.iloc[-1] == 0.0 and abs(table.speed.iloc[-1]) < arena.still_speed
    brake = int(np.argmax(table.throttle.to_numpy() == 0.0))
    assert table.posX.iloc[brake - 1] > 11.0 > table.posX.iloc[brake - 2]  # the sample within 1 m, then brake
    v = table.speed.iloc[brake]  # braking at μ g: it stands v² / 2 μ g further on
    assert table.posX.iloc[-1] == pytest.approx(table.posX.iloc[brake] + v * v / (2 * mu_g(car)), abs=0.05)


def test_build_vehicle_builds_the_tyre_car_of_a_file(tmp_path: Path) -> None:
    car = build_vehicle("f1tenth", {"tire_friction": 0.9})
    assert isinstance(car, TyreCar) and car.friction == pytest.approx(0.9 * 0.65)
    path = tmp_path / "light.toml"
    path.write_text((VEHICLE_DIR / "f1tenth.toml").read_text().replace('name = "f1tenth"', 'name = "light"')
                    .replace("mass = { value = 3.74", "mass = { value = 3.0"))  # fmt: skip
    light = build_vehicle(path)
    assert light.spec.name == "light" and light.model.body_subtreemass[1] == pytest.approx(3.0)


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("friction = { value = 0.65", "friction = { value = -0.65", "tyres.friction.value"),
        ("shape = { value = 1.5", "shap = { value = 1.5", "tyres.shap"),
        ('engine = "mujoco-tyres"', 'engine = "mujoco-tires"', "truth"),
    ],
)
def test_a_vehicle_file_with_a_bad_field_fails_naming_the_file_and_the_field(
    tmp_path: Path, old: str, new: str, field: str
) -> None:
    text = (VEHICLE_DIR / "f1tenth.toml").read_text()
    assert old in text
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new))
    with pytest.raises(VehicleFileError) as info:
        load_vehicle(path)
    assert info.value.path == str(path) and info.value.field.startswith(field)
    assert str(path) in str(info.value) and field in str(info.value)
