"""The dynamic single track of a vehicle file (issue 56's core, run with the file's values)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from activelearn.errors import InputError
from activelearn.numerics.models.dynamic_fit import identify_dynamic, log_information
from activelearn.numerics.models.dynamic_scales import parameters_of, scaled
from activelearn.numerics.models.dynamic_track import DynamicCar, free_runs, quasi_static_lateral, rate_runs
from simulator.vehicles import GRAVITY, load_vehicle

DT = 1.0 / 30.0


def steady(car: DynamicCar, throttle: float, steering: float, seconds: float = 25.0) -> np.ndarray:
    controls = np.tile([throttle, steering], (1, round(seconds / DT), 1))
    return free_runs(car, controls, np.zeros((1, 4)), DT)[0, -1]


def test_the_one_tenth_car_turns_as_its_linear_single_track_below_its_grip_and_saturates_at_it():
    spec = load_vehicle("f1tenth")
    car = DynamicCar.of(spec)
    vx, _, r, _, _, _ = steady(car, 0.3, 0.01)  # about 0.13 μg at 6 m/s
    assert r == pytest.approx(float(spec.linear_yaw_gain(vx)) * 0.01, rel=0.01)
    assert r < 0.8 * vx * math.tan(0.01) / spec.wheelbase  # it understeers: far from the kinematic model
    vx, _, r, _, _, _ = steady(car, 0.3, 0.3)  # the kinematic model would ask about 6 g
    assert 0.8 < vx * r / (spec.tyres.friction.value * GRAVITY) <= 1.02


def test_nigel_sits_in_the_kinematic_blend_and_a_braked_car_stands():
    spec = load_vehicle("nigel")
    vx, vy, r, _, _, _ = steady(DynamicCar.of(spec), 0.6, 0.3)
    assert r == pytest.approx(vx * math.tan(0.3) / spec.wheelbase, rel=1e-3)
    assert vy == pytest.approx(spec.geometry.lr.value * r, rel=1e-3)
    car = DynamicCar.of(load_vehicle("bmw320i"))
    controls = np.zeros((1, 300, 2))
    out = free_runs(car, controls, np.array([[20.0, 0.0, 0.0, 0.0]]), DT)
    assert abs(out[0, -1, 0]) < 1e-9 and np.isfinite(out).all()  # 20 m/s braked to rest, not past it
    stopping = 20.0**2 / (2.0 * car.brake)
    assert out[0, -1, 4] == pytest.approx(stopping, rel=0.05)


def test_a_twin_with_less_grip_slides_earlier():
    spec = load_vehicle("f1tenth")
    full = steady(DynamicCar.of(spec), 0.3, 0.3)
    slippery = steady(DynamicCar.of(spec, tire_friction=0.8), 0.3, 0.3)
    assert slippery[0] * slippery[2] < 0.9 * full[0] * full[2]


def test_with_combined_slip_the_core_follows_a_braking_turn():
    """MuJoCo's 1:10 car in a steady turn, then braked (throttle 0) with the steering held: the brake takes
    its tyres' whole grip, so they keep no lateral force. The core with combined slip (each axle's circle
    shared with its share of the braking) follows the truth's speed and yaw rate; without it, its tyres
    keep their lateral grip and its yaw rate runs away from the truth's."""
    from simulator import Replay, build_vehicle, collect

    spec = load_vehicle("f1tenth")
    for throttle, steering in ((0.25, 0.05), (0.2, 0.15)):
        turn, braking = 150, 45
        throttles = np.r_[np.full(turn, throttle), np.zeros(braking)]
        controls = np.column_stack([throttles, np.full(turn + braking, steering)])
        log = collect(Replay("braking turn", *controls.T), noise=None, vehicle=build_vehicle(spec))
        v, r = log["speed"].to_numpy(), log["angZ"].to_numpy()
        k = turn - 1  # the last step of the turn: from its state, through the braking
        misses = {}
        for combined in (False, True):
            car = dataclasses.replace(DynamicCar.of(spec), combined_slip=combined)
            lateral = quasi_static_lateral(car, v[k : k + 1], r[k : k + 1])
            start = np.array([[v[k], lateral[0], r[k], steering]])
            rates = rate_runs(car, controls[k:][None], start, DT, implicit=True)[0]
            n = min(len(rates), len(v) - k)
            misses[combined] = np.sqrt(np.mean((rates[:n] - np.column_stack([v, r])[k : k + n]) ** 2, axis=0))
        assert misses[True][1] < 0.3 < 1.0 < misses[False][1], (throttle, steering, misses)  # yaw rate, rad/s
        assert misses[True][0] < 0.5 * misses[False][0]  # speed


def test_the_kernels_wheel_passes_are_the_configs(c_kernels):
    """The kernel's fixed-point passes of the wheels' loads are compile-time constants (the pass loop
    unrolls, the lane loop vectorises), a variant each: those `[model] wheel_passes` offers, the shipped
    count first; a count it has no variant of is a clear error, not a silent other step."""
    from typing import get_args

    from activelearn.config import ModelConfig
    from activelearn.numerics import native
    from activelearn.numerics.models.dynamic_track import WHEEL_PASS_CHOICES, WHEEL_PASSES

    lib = native.library()
    found = tuple(lib.al_dynamic_wheel_pass_choice(i) for i in range(len(WHEEL_PASS_CHOICES) + 1))
    assert found == (*WHEEL_PASS_CHOICES, 0) and WHEEL_PASS_CHOICES[0] == WHEEL_PASSES
    assert get_args(ModelConfig.model_fields["wheel_passes"].annotation) == WHEEL_PASS_CHOICES
    car = dataclasses.replace(DynamicCar.of(load_vehicle("bmw320i")), wheel_forces=True, wheel_passes=4)
    with pytest.raises(ValueError, match="wheel passes"):
        rate_runs(car, np.zeros((1, 3, 2)), np.zeros((1, 4)), DT, True, backend="native")


def test_with_the_wheels_forces_the_full_size_core_turns_and_spins_with_the_truth():
    """MuJoCo's full-size car (rear drive) on a circle at a fixed steering: at throttle 0.4 it settles at
    about 0.9 μg; at 0.6 the inner rear wheel, unloaded by the turn, is driven past its circle and the
    car spins (power oversteer). The core with the wheels' forces (each wheel's load and circle) turns
    as the truth does (its yaw rate's rms miss a fifth of the axles' core's or less) and spins within a
    second of it; with one circle an axle it never spins."""
    from simulator import Replay, build_vehicle, collect

    spec = load_vehicle("bmw320i")
    n = round(16.0 / DT)
    cases = {0.4: "steady", 0.6: "spins"}
    logs = collect([Replay(kind, np.full(n, throttle), np.full(n, 0.08)) for throttle, kind in cases.items()],
                   noise=None, vehicle=build_vehicle(spec))  # fmt: skip
    truths = [t for _, t in logs.groupby("run_id", sort=False)]
    steady_truth, spin_truth = (t["angZ"].to_numpy() for t in truths)
    assert 0.85 < steady_truth[-1] * truths[0]["speed"].to_numpy()[-1] / (spec.tyres.friction.value * GRAVITY)
    spins_from = np.flatnonzero(spin_truth > 1.0)[0] * DT  # yaw rate past 1 rad/s
    controls = np.stack([t[["throttle", "steering"]].to_numpy(np.float64) for t in truths])
    miss, spins = {}, {}
    for wheels in (False, True):
        car = dataclasses.replace(DynamicCar.of(spec), wheel_forces=wheels)
        rates = rate_runs(car, controls, np.zeros((2, 4)), DT, implicit=True)
        miss[wheels] = np.sqrt(np.mean((rates[0, :, 1] - steady_truth) ** 2))
        spins[wheels] = np.flatnonzero(rates[1, :, 1] > 1.0) * DT
    assert miss[True] < 0.2 * miss[False], miss
    assert len(spins[True]) and abs(spins[True][0] - spins_from) < 1.0 and not len(spins[False]), spins


@pytest.mark.parametrize("name", ["nigel", "f1tenth", "bmw320i"])
def test_the_tangent_damping_is_the_tyres_slope_and_zero_past_the_peak(name):
    """`tyre_damping = "tangent"`: each axle's damping slope is ∂(F_y / F_z)/∂α of its pure-slip force
    (the central difference of `_lateral_force`, to 1e-5 of the cornering stiffness), the stiffness at
    α = 0, and 0 past the peak (the magic formula's, or the linear tyre's cap)."""
    from activelearn.numerics.models.dynamic_track import _damping_slopes, _lateral_force

    car = dataclasses.replace(DynamicCar.of(load_vehicle(name)), tangent_damping=True)
    static = car.mass * GRAVITY * car.lr / car.wheelbase
    k = car.stiffness_front / static
    alpha = np.linspace(-0.4, 0.4, 801)
    alpha = alpha[np.abs(np.abs(k * alpha) - car.friction) > 1e-3]  # off the linear tyre's kink
    slope = _damping_slopes(car, alpha, alpha)[0]
    step = 1e-6
    force = [_lateral_force(car, alpha + d, static, static, car.stiffness_front) / static
             for d in (step, -step)]  # fmt: skip
    np.testing.assert_allclose(slope, np.maximum((force[0] - force[1]) / (2 * step), 0.0), atol=1e-5 * k)
    assert _damping_slopes(car, np.zeros(1), np.zeros(1))[0][0] == pytest.approx(k)
    peak = abs(alpha[np.argmax(force[0])])  # the end of the range where the force never falls (C <= 1)
    past = np.abs(alpha) > peak + 0.01
    assert np.all(slope[past] == 0.0) and np.all(slope[np.abs(alpha) < min(peak, 0.4) - 0.01] > 0.0)
    assert _damping_slopes(dataclasses.replace(car, tangent_damping=False), alpha, alpha) is None


def twin_logs(
    car: DynamicCar, implicit: bool = False, scales: tuple[float, ...] = (0.8, 1.0, 1.0, 0.9, 1.0)
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Four 12-s logs (controls, rates) of the core itself with less grip (0.8) and a weaker motor (0.9),
    or other `scales`: sine steering at three throttles forward and one in reverse (`implicit`: the
    physics kind's step)."""
    twin = scaled(car, np.array([scales]))
    n = round(12.0 / DT)
    t = np.arange(n) * DT
    controls = np.zeros((4, n, 2))
    controls[:, :, 0] = [[0.2], [0.3], [0.4], [-0.3]]
    controls[:, :, 1] = np.array([[0.05], [0.15], [0.3], [0.1]]) * np.sin(0.8 * t)[None]
    rates = rate_runs(twin, controls, np.zeros((4, 4)), DT, implicit)[0]
    return [(controls[i], rates[i]) for i in range(4)]


def test_identification_recovers_a_twins_grip_and_motor_from_its_own_logs():
    """Logs of the dynamic core with less grip and a weaker motor (its own free runs, so the core can fit
    them exactly): the identified scales come back near the twin's, the untouched ones near 1."""
    car = DynamicCar.of(load_vehicle("f1tenth"))
    found = identify_dynamic(twin_logs(car), car, DT)
    friction, _, _, motor, _ = found.values
    assert friction == pytest.approx(0.8, abs=0.04) and motor == pytest.approx(0.9, abs=0.02)


@pytest.mark.parametrize("slip", ["axle", "combined", "wheels", "wheels, 5 passes, blend 0.25",
                                  "axle, kinematic core", "combined, kinematic core, blend 1.0"])
@pytest.mark.parametrize("step", ["implicit", "explicit", "tangent"])
@pytest.mark.parametrize("name", ["nigel", "f1tenth", "bmw320i"])
def test_the_compiled_rate_runs_are_numpys(name, step, slip, c_kernels):
    """dynamic_rollout.c against the NumPy loop: random controls with braking steps, starts forward and
    reversing, one car and a batch of scaled ones (the identification's shapes), under each slip law
    (the rear drive's share of its axle's circle, combined slip, the wheels' forces with 3 or 5 passes
    of their loads) and each step (explicit, implicit, implicit with the tangent damping), other blend
    speeds, and the kinematic core below the blend speed, equal to rounding."""
    rng = np.random.default_rng(7)
    other = slip.endswith("0.25")
    blend = 0.25 if other else 1.0 if slip.endswith("1.0") else 0.5
    car = dataclasses.replace(DynamicCar.of(load_vehicle(name)), combined_slip=slip.startswith("combined"),
                              wheel_forces=slip.startswith("wheels"), tangent_damping=step == "tangent",
                              wheel_passes=5 if other else 3, blend_share=blend,
                              kinematic_core="kinematic core" in slip)  # fmt: skip
    implicit = step != "explicit"
    n_runs, n_steps = 21, 46  # lanes not a multiple of the kernel's block of 8
    shape = (n_runs, n_steps)
    controls = np.stack([rng.uniform(-1, 1, shape), rng.uniform(-0.5, 0.5, shape)], -1)
    controls[:, ::5, 0] = 0.0
    top = car.top_speed or float(car.table_speed[-1])
    start = np.stack([rng.uniform(-0.3, 1, n_runs) * top, rng.normal(0, 0.1, n_runs) * top,
                      rng.uniform(-1, 1, n_runs), rng.uniform(-0.3, 0.3, n_runs)], -1)  # fmt: skip
    sets = np.clip(1 + 0.3 * rng.standard_normal((6, len(parameters_of(car)))), 0.4, 1.2)
    for cars in (car, scaled(car, sets)):
        reference = rate_runs(cars, controls, start, DT, implicit, backend="reference")
        compiled = rate_runs(cars, controls, start, DT, implicit, backend="native")
        assert compiled.shape == reference.shape
        np.testing.assert_allclose(compiled, reference, rtol=1e-9, atol=1e-9 * top)


def test_rate_runs_name_a_backend_they_do_not_know():
    car = DynamicCar.of(load_vehicle("f1tenth"))
    with pytest.raises(InputError, match="backend"):
        rate_runs(car, np.zeros((1, 3, 2)), np.zeros((1, 4)), DT, backend="cuda")


def test_a_logs_information_is_its_sensitivity_to_the_scales_and_adds_up():
    """`log_information`: symmetric and positive semi-definite, each log's alone as in a batch, scaled by
    the noise's inverse square; a straight at steady throttle tells nothing of the yaw inertia, a slalom
    does."""
    car = DynamicCar.of(load_vehicle("f1tenth"))
    logs = twin_logs(car, implicit=True)
    n = round(12.0 / DT)
    straight = np.tile([0.3, 0.0], (n, 1))
    logs.append((straight, rate_runs(car, straight[None], np.zeros((1, 4)), DT, True)[0]))
    settings = {"every": 3, "horizon": 3.0, "implicit": True}
    noise, theta = np.array([0.05, 0.1]), np.ones(5)
    info = log_information(logs, car, DT, theta, noise, **settings)
    alone = np.concatenate([log_information([log], car, DT, theta, noise, **settings) for log in logs])
    np.testing.assert_allclose(info, alone, rtol=1e-9, atol=1e-9 * np.abs(info).max())
    np.testing.assert_allclose(info, info.transpose(0, 2, 1))
    assert np.linalg.eigvalsh(info).min() >= -1e-9 * np.abs(info).max()
    halved = log_information(logs, car, DT, theta, noise / 2, **settings)
    np.testing.assert_allclose(halved, 4 * info, rtol=1e-9)
    yaw_inertia = 4  # DYNAMIC_PARAMETERS' order
    slalom, steady = info[2, yaw_inertia, yaw_inertia], info[-1, yaw_inertia, yaw_inertia]
    assert slalom > 1.0 and steady < 1e-6 * slalom
