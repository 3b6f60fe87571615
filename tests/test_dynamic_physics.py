"""The physics kind on the dynamic single track (`[model] core = "dynamic"`): its step, free runs and
identification, against the dynamic core's own NumPy runs."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from activelearn.config import ModelConfig
from activelearn.errors import InputError
from activelearn.numerics.lags import model_lags
from activelearn.numerics.models import build_model, load_model, physics, save_model
from activelearn.numerics.models.dynamic_physics import DynamicPhysicsModel, identify_scales
from activelearn.numerics.models.dynamic_scales import dynamic_bounds, scaled
from activelearn.numerics.models.dynamic_track import DynamicCar, dynamic_step, rate_runs
from activelearn.numerics.models.single_track import Identified, _map_fit, widened
from activelearn.numerics.multistep import window_loss, windows_from_logs
from activelearn.numerics.surrogate import simulate
from activelearn.numerics.training_data import TrainingData
from simulator.vehicles import GRAVITY, load_vehicle
from tests.test_dynamic_track import twin_logs

DT = 1.0 / 30.0


def _config(vehicle: str = "f1tenth", **knobs) -> ModelConfig:
    base = {
        "kind": "physics", "core": "dynamic", "correction_inputs": "control", "arch": "D16-D16-V",
        "activation": "softplus", "n_inputs": 16, "history_step": 3, "vehicle": vehicle,
    }  # fmt: skip
    return ModelConfig(**{**base, **knobs})


def _untrained(vehicle: str = "f1tenth", **knobs) -> DynamicPhysicsModel:
    model = build_model(_config(vehicle, **knobs), seed=0)
    assert isinstance(model, DynamicPhysicsModel)
    car = model.car
    rng = np.random.default_rng(0)  # scalers over the car's operating box: the physics reads physical units
    low = np.array([-1.0, -car.steering_limit, -car.max_speed, -car.max_yaw_rate])
    box = rng.uniform(low, -low, (500, 4))
    x = np.column_stack([box[:, :2]] * 4 + [box[:, 2:]] * 4)  # four control pairs, then four rate pairs
    model.set_scalers(x, box[:, 2:])
    return model


def test_the_core_is_chosen_in_the_config_and_checked_there():
    assert type(build_model(_config(), seed=0)) is DynamicPhysicsModel
    assert type(build_model(_config(core="kinematic"), seed=0)) is physics.PhysicsModel
    with pytest.raises(ValidationError, match="core"):
        ModelConfig(kind="ensemble", core="dynamic")
    with pytest.raises(ValidationError, match="correction_inputs"):
        _config(correction_inputs="history")
    with pytest.raises(ValidationError, match="tyre_damping"):
        ModelConfig(kind="physics", tyre_damping="tangent")
    with pytest.raises(ValidationError, match="blend_share"):
        ModelConfig(kind="physics", blend_share=0.25)
    with pytest.raises(ValidationError, match="wheel_passes"):
        _config(wheel_passes=5)  # the axles' core has no wheels to pass over
    with pytest.raises(ValidationError, match="wheel_passes"):
        _config(wheel_forces=True, wheel_passes=4)  # no kernel variant of it
    with pytest.raises(ValidationError, match="blend_share"):
        _config(blend_share=0.0)
    model = build_model(_config("bmw320i", wheel_forces=True, wheel_passes=5, blend_share=0.25), seed=0)
    car = model.dynamic_car
    assert (car.wheel_passes, car.blend_share) == (5, 0.25)
    assert car.blend_speed == pytest.approx(0.25 * math.sqrt(GRAVITY * car.wheelbase))
    with pytest.raises(ValidationError, match="kinematic_blend"):
        ModelConfig(kind="physics", kinematic_blend="core")  # the kinematic core has no blend
    with pytest.raises(ValidationError, match="kinematic_blend"):
        _config(kinematic_blend="core", wheel_forces=True)
    model = build_model(_config("nigel", kinematic_blend="core"), seed=0)
    assert model.dynamic_car.kinematic_core
    assert model.parameter_names[5:] == ("understeer", "scrub", "yaw_lag", "reverse_understeer")
    assert model.theta.shape == (9,) and model.theta_scale.shape == (9, 9)


def test_implicit_tyre_damping_keeps_the_explicit_steps_steady_turns_in_a_few_substeps():
    """25-ms substeps with exponential damping against the explicit step's many: the same steady turn."""
    for name, throttle in (("f1tenth", 0.3), ("bmw320i", 0.25)):
        car = DynamicCar.of(load_vehicle(name))
        for steering in (0.02, 0.1, 0.3):
            explicit = np.zeros((1, 4))
            implicit = np.zeros((1, 4))
            for _ in range(300):  # 30 s of 0.1-s steps
                u = (np.array([throttle]), np.array([steering]))
                explicit = dynamic_step(car, explicit, *u, 0.1)
                implicit = dynamic_step(car, implicit, *u, 0.1, car.implicit_substeps(0.1), implicit=True)
            assert car.implicit_substeps(0.1) == 4 < car.substeps(0.1)
            assert implicit[0, 2] == pytest.approx(explicit[0, 2], rel=0.02, abs=1e-3), (name, steering)
            assert implicit[0, 0] == pytest.approx(explicit[0, 0], rel=0.01), (name, steering)


def test_free_runs_carry_the_lateral_speed_as_the_cores_own_runs_do():
    """The bare core's free runs (no correction, no noise) are the core's NumPy runs step for step,
    the lateral speed carried; the pose follows the sideslip (a sliding car is not a kinematic one)."""
    model = _untrained()
    model.corrected = False
    model._variance_cap = lambda: torch.zeros(2)  # the sensors' noise off: the mean path is the core's
    n = 240
    t = np.arange(n) * DT
    controls = np.stack([np.full((3, n), 0.35), np.array([[0.02], [0.1], [0.25]]) * np.sin(0.5 * t)], axis=-1)
    start = np.zeros((3, 2))
    rollout = simulate(model, list(controls), rate_hz=30.0, n_samples=2, seed=0, initial_rates=start)
    # the NumPy core in the model's three interleaved chains of 0.1-s steps, each from the newest control
    car = model.dynamic_car
    states = np.zeros((3, n, 4))
    for k in range(n):
        past = states[:, k - 3] if k >= 3 else np.column_stack([np.zeros((3, 3)), controls[:, 0, 1]])
        states[:, k] = dynamic_step(car, past, controls[:, k, 0], controls[:, k, 1], 0.1, 4, implicit=True)
    assert np.allclose(rollout.mean_rates[..., 0], states[..., 0], atol=1e-3)
    assert np.allclose(rollout.mean_rates[..., 1], states[..., 2], atol=1e-3)
    # the pose: yaw from ω, positions with the rear axle's lateral speed v_y − l_r ω
    slip = states[..., 1] - car.lr * states[..., 2]
    assert np.abs(slip[2]).max() > 0.05  # the large steering slides
    yaw = np.concatenate([np.zeros((3, 1)), np.cumsum(states[:, :-1, 2], axis=1) * DT], axis=1)
    vx = states[..., 0] * np.cos(yaw) - slip * np.sin(yaw)
    x = np.concatenate([np.zeros((3, 1)), np.cumsum(vx[:, :-1], axis=1) * DT], axis=1)
    x += model.config.pose_lever_arm * (np.cos(yaw) - 1.0)
    assert np.allclose(rollout.x.mean(axis=0), x, atol=1e-2)


@pytest.mark.parametrize(("vehicle", "slip"), [("f1tenth", "axle"), ("nigel", "axle"), ("bmw320i", "axle"),
                                               ("f1tenth", "combined"), ("bmw320i", "wheels"),
                                               ("bmw320i", "wheels, tangent"), ("nigel", "axle, tangent"),
                                               ("bmw320i", "wheels, tangent, 5 passes, blend 0.25"),
                                               ("nigel", "axle, kinematic core"),
                                               ("f1tenth", "combined, kinematic core, blend 1.0")])
def test_the_compiled_free_runs_are_torchs(vehicle: str, slip: str, c_kernels):
    """dynamic_rollout.c's free runs against the torch loop: each draw its own scales, the correction
    widened about the draws' mean (epistemic scale 3), the sensors' noise, the model discrepancy in the
    pose fan, the three interleaved chains of history_step 3, 12 draws (not whole blocks): rates, moments
    and poses to float rounding. The kernel computes in float, the reference partly in double (its
    controls are), so float rounding is 1e-4 of a quantity's scale, or in a chaotic run (the 1:10 car
    spinning at throttle 0.8) twice what the reference itself moves when its controls move by 1e-7. With the
    kinematic core below the blend speed too (Nigel always; the 1:10 car with its blend raised to √(g L))."""
    model = _untrained(vehicle, parameter_uncertainty="by_log", discrepancy="identification",
                       combined_slip=slip.startswith("combined"), wheel_forces=slip.startswith("wheels"),
                       tyre_damping="tangent" if "tangent" in slip else "linear",
                       kinematic_blend="core" if "kinematic core" in slip else "plain",
                       **({"wheel_passes": 5, "blend_share": 0.25} if slip.endswith("0.25") else {}),
                       **({"blend_share": 1.0} if slip.endswith("1.0") else {}))
    model.theta_scale.copy_(0.1 * torch.eye(len(model.parameter_names)))
    model.epistemic_scale.fill_(3.0)
    model.discrepancy.copy_(torch.tensor([0.05, 0.02]))
    model.discrepancy_logs.fill_(4.0)  # each draw its own discrepancy size
    t = np.arange(150) * DT
    controls = [np.column_stack([np.full_like(t, throttle), steering * np.sin(0.8 * t)])
                for throttle, steering in ((0.4, 0.1), (0.8, 0.3), (-0.5, 0.2), (0.0, 0.05))]  # fmt: skip
    nudged = [u * (1.0 + 1e-7) for u in controls]
    reference, compiled, moved = (simulate(model, u, rate_hz=30.0, n_samples=12, seed=3, backend=backend)
                                  for u, backend in ((controls, "reference"), (controls, "native"),
                                                     (nudged, "reference")))  # fmt: skip
    assert np.abs(reference.epistemic_var).max() > 1e-6  # the draws differ: the spread is compared too
    scale = np.abs(reference.mean_rates).max(axis=(0, 1))
    reach = max(np.abs(reference.x).max(), np.abs(reference.y).max())
    scales = {"mean_rates": None, "aleatoric_var": None, "epistemic_var": None, "v": scale[0], "w": scale[1],
              "x": reach, "y": reach}  # fmt: skip
    loose = 0
    for name, size in scales.items():
        expected, got, nearby = (getattr(r, name) for r in (reference, compiled, moved))
        axis = 0 if size is None else 1  # moments (M, T, 2), draws (S, M, T)
        size = float(np.abs(expected).max()) if size is None else size
        for m in range(len(controls)):
            e, g, n = (np.take(a, m, axis=axis) for a in (expected, got, nearby))
            rounding = max(1e-4 * size, 2.0 * float(np.abs(n - e).max()))
            loose += rounding > 1e-4 * size
            relative = 1e-3 if axis == 0 else 0.0
            np.testing.assert_allclose(g, e, rtol=relative, atol=rounding, err_msg=(name, m))
    assert loose <= 2 * len(scales)  # the conditioning excuses one or two runs, not all


@pytest.mark.parametrize("vehicle", ["f1tenth", "bmw320i"])
def test_untrained_it_never_leaves_physics_on_the_cars_control_box(vehicle: str):
    model = _untrained(vehicle, parameter_uncertainty="by_log")
    model.theta_scale.copy_(0.3 * torch.eye(5))  # wide parameter draws
    sweep = physics.control_box_sweep(30.0, car=model.car)
    rollout = simulate(model, sweep, rate_hz=30.0, n_samples=8, seed=0)
    assert physics.runs_out_of_bounds(rollout.v, rollout.w, car=model.car) == 0


def test_it_identifies_a_twins_grip_and_motor_and_saves_them(tmp_path):
    """Logs of the core with less grip and a weaker motor: the model identifies both (the untouched
    scales stay near 1), and a saved model loads with its identified scales."""
    model = _untrained(parameter_uncertainty="by_log")
    logs = twin_logs(model.dynamic_car, implicit=True)
    model.identify(TrainingData(x=np.zeros((0, 16)), y=np.zeros((0, 2)), logs=logs))
    found = model.physical_parameters()
    assert found["friction"] == pytest.approx(0.8, abs=0.04)
    assert found["motor"] == pytest.approx(0.9, abs=0.02)
    assert model.has_parameter_spread
    assert model.round_metrics()["identified_friction"] == found["friction"]  # the campaign's curves show it
    save_model(model, tmp_path / "model.pt")
    loaded = load_model(tmp_path / "model.pt")
    assert isinstance(loaded, DynamicPhysicsModel) and loaded.physical_parameters() == found


def _two_basins(sets: np.ndarray) -> np.ndarray:
    """(P, 2, 2) errors whose squares are 0 at x = 1 (the prior's centre) and about 0.02 near x = 2.5,
    a hump of 0.37 between: the second basin holds a search started in it."""
    x = sets[:, 0]
    rows = np.stack([(x - 1.0) * (x - 2.5), 0.3 * (x - 1.0)], axis=-1)  # (P, 2)
    return np.stack([rows, rows], axis=-1)


def test_a_search_also_from_the_priors_centre_leaves_a_basin_the_last_rounds_start_is_in():
    """`_map_fit`'s `also_from_prior` (`[model] identification_starts = "last_and_prior"`): a search from
    a start in the shallower basin stays there; searched from the prior's centre too, the lower objective
    wins. Without a start of its own the search is the prior centre's either way."""
    prior = Identified(np.array([1.0]), np.array([[100.0]]))  # centre 1, wide: the data decide
    car = SimpleNamespace(low=np.array([0.0]), high=np.array([4.0]), width=np.array([1.0]), prior=prior)
    spread, clusters = np.ones(2), np.arange(2)
    stuck = _map_fit(_two_basins, spread, clusters, search_from=np.array([2.4]), car=car)
    assert stuck.values[0] == pytest.approx(2.5, abs=0.1)
    found = _map_fit(_two_basins, spread, clusters, search_from=np.array([2.4]), car=car,
                     also_from_prior=True)
    assert found.values[0] == pytest.approx(1.0, abs=1e-3)
    alone = _map_fit(_two_basins, spread, clusters, car=car, also_from_prior=True)
    np.testing.assert_array_equal(alone.values, _map_fit(_two_basins, spread, clusters, car=car).values)


def test_a_warm_identification_from_an_astray_round_finds_the_twin_when_it_also_searches_from_the_file():
    """`identification_starts = "last_and_prior"`: three 12-s logs of the full-size core with the twin's
    grip (0.8) and motor (0.9), steered in sines at 0.4-0.6 throttle, identified warm from where an
    astray twin campaign's last round ended (stiffness 2.3-2.5, yaw inertia 2.7): from there alone the
    search stays (yaw inertia at its bound 3); searching from the file too, it finds the twin. The
    dynamic core's option only."""
    with pytest.raises(ValidationError, match="identification_starts"):
        ModelConfig(kind="physics", identification_starts="last_and_prior")
    knobs = {"wheel_forces": True, "wheel_passes": 5, "blend_share": 0.25, "tyre_damping": "tangent",
             "identification_loss": "cauchy"}  # fmt: skip
    car = _untrained("bmw320i", **knobs).dynamic_car
    t = np.arange(round(12.0 / DT)) * DT
    controls = np.zeros((3, len(t), 2))
    controls[:, :, 0] = [[0.5], [0.6], [0.4]]
    controls[:, :, 1] = np.array([[0.05], [0.12], [0.08]]) * np.sin(np.array([[0.8], [1.2], [2.0]]) * t)
    twin = scaled(car, np.array([[0.8, 1.0, 1.0, 0.9, 1.0]]))
    rates = rate_runs(twin, controls, np.zeros((3, 4)), DT, True)[0]
    logs = [(controls[i], rates[i]) for i in range(3)]
    found = {}
    for starts in ("last", "last_and_prior"):
        model = _untrained("bmw320i", identification_starts=starts, **knobs)
        model.theta.copy_(torch.tensor([0.78, 2.34, 2.45, 0.89, 2.7]))
        model.identify(TrainingData(x=np.zeros((0, 16)), y=np.zeros((0, 2)), logs=logs), warm=True)
        found[starts] = model.theta.double().numpy()
    assert found["last"][4] > 2.5 and found["last"][1] > 2.0  # stayed in the astray basin
    np.testing.assert_allclose(found["last_and_prior"], [0.8, 1.0, 1.0, 0.9, 1.0], atol=0.03)


def _identify(model: DynamicPhysicsModel, logs, of_another_car=None) -> None:
    empty = TrainingData(x=np.zeros((0, 16)), y=np.zeros((0, 2)), logs=logs, of_another_car=of_another_car)
    model.identify(empty)


def _covariance(model: DynamicPhysicsModel) -> np.ndarray:
    scale = model.theta_scale.double()
    return (scale @ scale.T).numpy()


def test_another_cars_logs_centre_the_identification_and_stand_alone_widened():
    """Logs flagged as another car's (a grid of the nominal simulator): identified alone, their scales,
    widened by the file's widths, are the prior this car's logs are identified under; with no log of this
    car that prior stands, its width in the draws. The other car's grip is not pooled with the twin's."""
    model = _untrained(parameter_uncertainty="by_log")
    car = model.dynamic_car
    others = twin_logs(car, implicit=True, scales=(1.2, 1.0, 1.0, 1.0, 1.0))
    own = twin_logs(car, implicit=True)[2:3]  # one log of this car (the twin): throttle 0.4
    prior = widened(identify_scales(others, car, DT), dynamic_bounds().width)

    _identify(model, others, [True] * 4)
    np.testing.assert_allclose(model.theta.numpy(), prior.values, rtol=1e-6)
    np.testing.assert_allclose(_covariance(model), prior.covariance, rtol=1e-4, atol=1e-9)
    assert model.physical_parameters()["friction"] == pytest.approx(1.2, abs=0.05)

    _identify(model, others + own, [True] * 4 + [False])
    expected = identify_scales(own, car, DT, prior=prior)
    np.testing.assert_allclose(model.theta.numpy(), expected.values, rtol=1e-5)
    pooled = identify_scales(others + own, car, DT)
    assert abs(model.physical_parameters()["motor"] - 0.9) < abs(pooled.values[3] - 0.9)


def test_it_starts_from_another_cars_model_its_core_as_the_prior_and_its_correction(tmp_path):
    """`start_from_another_car`: the donor's identified scales and covariance, widened by the file's
    widths, are the recipient's prior (standing alone before it has logs); with `correction` the
    recipient's correction is the donor's. A donor of another core is refused, naming the field."""
    donor = _untrained(parameter_uncertainty="by_log")
    _identify(donor, twin_logs(donor.dynamic_car, implicit=True, scales=(1.2, 1.0, 1.0, 1.0, 1.0)))
    save_model(donor, tmp_path / "donor.pt")
    donor = load_model(tmp_path / "donor.pt")
    recipient = build_model(_config(parameter_uncertainty="by_log"), seed=1)
    recipient.start_from_another_car(donor, correction=False)
    prior = widened(Identified(donor.theta.double().numpy(), _covariance(donor)), dynamic_bounds().width)
    np.testing.assert_allclose(recipient.core_prior.values, prior.values)
    np.testing.assert_allclose(recipient.core_prior.covariance, prior.covariance)
    _identify(recipient, [])
    np.testing.assert_allclose(recipient.theta.numpy(), donor.theta.numpy(), rtol=1e-6)
    assert np.all(np.diag(_covariance(recipient)) > np.diag(_covariance(donor)))  # the car is another
    own = twin_logs(recipient.dynamic_car, implicit=True)[2:3]
    _identify(recipient, own)
    expected = identify_scales(own, recipient.dynamic_car, DT, prior=prior)
    np.testing.assert_allclose(recipient.theta.numpy(), expected.values, rtol=1e-5)

    different = [n for n, a in recipient.correction.state_dict().items()
                 if not torch.equal(a, donor.correction.state_dict()[n])]  # fmt: skip
    assert different  # another seed's correction ...
    recipient.start_from_another_car(donor, correction=True)
    for name, array in recipient.correction.state_dict().items():  # ... until it starts from the donor's
        assert torch.equal(array, donor.correction.state_dict()[name]), name
    kinematic = build_model(ModelConfig(kind="physics", arch="D16-V", n_inputs=16, history_step=3), seed=0)
    with pytest.raises(InputError, match=r"design\.prior\.model"):
        recipient.start_from_another_car(kinematic, correction=False)
    # scales carry to another vehicle file; the kinematic core's own gains and lags do not
    full_size = build_model(_config("bmw320i", parameter_uncertainty="by_log"), seed=0)
    full_size.start_from_another_car(donor, correction=False)
    np.testing.assert_allclose(full_size.core_prior.values, prior.values)
    kinematic_f1tenth = build_model(kinematic.config.model_copy(update={"vehicle": "f1tenth"}), seed=0)
    with pytest.raises(InputError, match="another vehicle"):
        kinematic_f1tenth.start_from_another_car(kinematic, correction=False)


def test_the_discrepancy_is_the_cores_misfit_of_its_logs_and_widens_the_fan_not_the_path(tmp_path):
    """`discrepancy = "identification"`: the core's rms misfit of its own logs (small where the logs are
    a core's own runs, larger where they hold what no scale explains) sets an OU error on each draw's
    rates, so the pose fan widens about the mean path the core without it runs."""
    from activelearn.numerics.models.discrepancy import discrepancy_paths
    from activelearn.numerics.models.dynamic_physics import identification_misfit

    with pytest.raises(ValidationError, match="discrepancy"):
        ModelConfig(kind="ensemble", discrepancy="identification")  # a black box has no core
    with pytest.raises(ValidationError, match="combined_slip"):
        ModelConfig(kind="physics", combined_slip=True)  # nor combined slip
    with pytest.raises(ValidationError, match="wheel_forces"):
        ModelConfig(kind="physics", wheel_forces=True)  # nor the wheels' forces
    with pytest.raises(ValidationError, match="wheel_forces"):  # two slip laws at once
        ModelConfig(kind="physics", core="dynamic", correction_inputs="control", combined_slip=True,
                    wheel_forces=True)
    model = _untrained(parameter_uncertainty="by_log", discrepancy="identification")
    car = model.dynamic_car
    logs = twin_logs(car, implicit=True)
    own = identification_misfit(logs, car, DT, np.array([0.8, 1.0, 1.0, 0.9, 1.0]))
    file = identification_misfit(logs, car, DT, np.ones(5))
    assert (own < 0.5 * file).all()  # not 0: each 3-s restart starts from a steady turn's v_y
    # what no scale explains: a slow yaw-rate error the truth has and the core cannot
    t = np.arange(len(logs[0][0])) * DT
    logs = [(u, y + np.column_stack([0 * t, 0.3 * np.sin(0.3 * t)])) for u, y in logs]
    model.identify(TrainingData(x=np.zeros((0, 16)), y=np.zeros((0, 2)), logs=logs))
    expected = identification_misfit(logs, car, DT, model.theta.double().numpy())
    assert np.allclose(model.discrepancy.numpy(), expected, rtol=1e-5) and expected[1] > 0.1
    assert float(model.discrepancy_logs) == len(logs)
    bare = copy.deepcopy(model)
    bare.discrepancy.zero_()
    controls = [u for u, _ in logs]
    wide, plain = (simulate(m, controls, rate_hz=30.0, n_samples=16, seed=3) for m in (model, bare))
    for a, b in zip(wide.mean_path(), plain.mean_path(), strict=True):
        assert np.allclose(a, b, atol=1e-4)  # the path is the core's
    width = [np.quantile(r.y[:, :, -1], 0.975, axis=0) - np.quantile(r.y[:, :, -1], 0.025, axis=0)
             for r in (wide, plain)]  # fmt: skip
    assert (width[0] > 2 * width[1]).all()
    again = simulate(model, controls, rate_hz=30.0, n_samples=16, seed=3)
    assert np.array_equal(again.y, wide.y)  # a seed fixes the discrepancy's draws
    save_model(model, tmp_path / "model.pt")
    loaded = load_model(tmp_path / "model.pt")
    assert torch.equal(loaded.discrepancy, model.discrepancy)
    assert torch.equal(loaded.discrepancy_logs, model.discrepancy_logs)
    # the size's uncertainty: each draw's size ŝ √(n / X), X ~ χ²(n), so (ŝ / size)² averages 1; the
    # fewer the logs, the more the sizes spread; a file saved before the count existed: every draw ŝ
    for n in (4.0, 64.0):
        model.discrepancy_logs.fill_(n)
        ratio = (model.discrepancy.double().numpy() / model.discrepancy_sizes(20000, seed=1)) ** 2
        assert ratio.mean() == pytest.approx(1.0, abs=0.03)
        assert ratio[:, 0].std() == pytest.approx(np.sqrt(2.0 / n), rel=0.1)  # X / n: variance 2 / n
    payload = torch.load(tmp_path / "model.pt", weights_only=True)
    del payload["state_dict"]["discrepancy_logs"]
    torch.save(payload, tmp_path / "old.pt")
    old = load_model(tmp_path / "old.pt")
    assert float(old.discrepancy_logs) == 0.0
    assert np.array_equal(old.discrepancy_sizes(5, seed=1), np.tile(old.discrepancy.double().numpy(), (5, 1)))
    # the process: from zero, stationary at its size, correlated over the identification's horizon
    dv, dw = discrepancy_paths(np.array([0.5, 2.0]), list(range(4000)), 1, 600, DT)
    assert (dv[..., 0] == 0).all() and (dw[..., 0] == 0).all()
    assert float(dv[..., -1].std()) == pytest.approx(0.5, rel=0.05)
    assert float(dw[..., -1].std()) == pytest.approx(2.0, rel=0.05)
    late = dw[..., 300:].reshape(-1, 300)
    lag = float((late[:, 1:] * late[:, :-1]).mean() / (late**2).mean())
    assert lag == pytest.approx(np.exp(-DT / 3.0), abs=0.01)


def test_the_cross_validated_misfit_is_each_folds_at_the_scales_identified_without_it():
    """`discrepancy = "cross_validated"`: four folds of the logs, each's errors at the scales identified on
    the others; out of sample the core misses more than in its own logs; one log: the in-sample misfit."""
    from activelearn.numerics.models.dynamic_fit import identify_dynamic, misfit
    from activelearn.numerics.models.dynamic_physics import (
        IDENTIFY_EVERY,
        IDENTIFY_HORIZON,
        identification_misfit,
    )

    model = _untrained(discrepancy="cross_validated")
    car = model.dynamic_car
    t = np.arange(round(12.0 / DT)) * DT
    logs = [(u, y + np.column_stack([0 * t, 0.2 * np.sin(0.3 * t + i)])) for i, (u, y) in
            enumerate(twin_logs(car, implicit=True))]  # fmt: skip
    model.identify(TrainingData(x=np.zeros((0, 16)), y=np.zeros((0, 2)), logs=logs))
    theta = model.theta.double().numpy()
    how = dict(every=IDENTIFY_EVERY, horizon=IDENTIFY_HORIZON, implicit=True)
    squares = []  # by hand: each log (a fold of one) at the scales identified on the other three
    for i in range(4):
        found = identify_dynamic(logs[:i] + logs[i + 1 :], car, DT, search_from=theta, **how)
        squares.append(misfit([logs[i]], car, DT, found.values, **how) ** 2)
    expected = np.sqrt(np.mean(squares, axis=0))  # the folds hold equally many compared steps
    assert np.allclose(model.discrepancy.numpy(), expected, rtol=1e-4)
    assert (expected > identification_misfit(logs, car, DT, theta)).all()
    one = identification_misfit(logs[:1], car, DT, theta, cross_validated=True)
    assert np.array_equal(one, identification_misfit(logs[:1], car, DT, theta))


def test_the_core_is_identified_on_a_log_up_to_its_live_stop():
    """A live stop's braking (a trailing block of throttle 0 after the maneuver's own throttle) is left
    out of the identification: the core has no combined slip to follow it with. Logs without one stay
    whole, a maneuver that never drives as well; the identification then sees the cut log alone."""
    from activelearn.numerics.models.dynamic_physics import before_a_stop

    model = _untrained(parameter_uncertainty="by_log")
    car = model.dynamic_car
    u, y = twin_logs(car, implicit=True)[0]
    braking = np.column_stack([np.zeros(40), np.full(40, u[-1, 1])])
    stopped = (np.vstack([u, braking]), np.vstack([y, np.linspace(y[-1], 0.0, 40)]))
    cut = before_a_stop(stopped)
    assert np.array_equal(cut[0], u) and np.array_equal(cut[1], y)
    assert before_a_stop((u, y))[0] is u  # ends driven: whole
    idle = (np.zeros((30, 2)), np.zeros((30, 2)))
    assert before_a_stop(idle)[0] is idle[0]  # never driven: whole
    empty = TrainingData(x=np.zeros((0, 16)), y=np.zeros((0, 2)), logs=[stopped])
    model.identify(empty)
    alone = _untrained(parameter_uncertainty="by_log")
    alone.identify(TrainingData(x=np.zeros((0, 16)), y=np.zeros((0, 2)), logs=[(u, y)]))
    assert torch.equal(model.theta, alone.theta)


@pytest.mark.parametrize("vehicle", ["nigel", "f1tenth", "bmw320i", "nigel, kinematic core"])
def test_the_step_traces_whole_on_every_car(vehicle: str):
    """torch.compile fuses the model's step only where dynamo traces it whole: a speed-table car's step
    (Nigel) broke its graph 15 times at the table's bounds (a scalar read from a tensor)."""
    from activelearn.numerics.models.dynamic_physics import corrected_step

    name, _, branch = vehicle.partition(", ")
    model = _untrained(name, kinematic_blend="core" if branch else "plain")
    n = 8
    state, zs = torch.zeros(n, 4), tuple(torch.zeros(n) for _ in range(4))
    explained = torch._dynamo.explain(corrected_step)(
        model.dynamic_car, state, torch.full((n,), 0.5), torch.full((n,), 0.1), zs, model.limits
    )
    assert explained.graph_break_count == 0, explained.break_reasons


@pytest.mark.slow  # compiles (about 40 s on a fresh machine, a few from torch's on-disk cache)
def test_the_compiled_core_trains_and_runs_free_as_the_eager_one():
    """`compile_steps` (torch.compile of the core's step): a window loss, its gradient and free runs are
    the eager core's up to float rounding."""
    eager = _untrained(parameter_uncertainty="by_log")
    logs = twin_logs(eager.dynamic_car, implicit=True)
    eager.identify(TrainingData(x=np.zeros((0, 16)), y=np.zeros((0, 2)), logs=logs))
    compiled = copy.deepcopy(eager)
    compiled.compile_steps()
    windows = windows_from_logs(logs, model_lags(eager), horizon=30, every=40)
    rows = torch.arange(len(windows))
    losses, grads = [], []
    for model in (eager, compiled):
        model.zero_grad()
        torch.manual_seed(0)  # the correction's training noise: the same draws for both
        loss = window_loss(model, windows, rows)
        loss.backward()
        losses.append(loss.item())
        grads.append(torch.cat([p.grad.reshape(-1) for p in model.parameters() if p.grad is not None]))
    assert losses[1] == pytest.approx(losses[0], rel=1e-4)
    assert torch.allclose(grads[1], grads[0], rtol=1e-3, atol=1e-5 * float(grads[0].abs().max()))
    controls = [log[0] for log in logs]
    runs = [simulate(m, controls, rate_hz=30.0, n_samples=4, seed=0) for m in (eager, compiled)]
    assert compiled.compiled  # compiling worked here (else the core steps eagerly, with a warning)
    assert np.allclose(runs[1].mean_rates, runs[0].mean_rates, rtol=1e-3, atol=1e-3)
    assert np.allclose(runs[1].x, runs[0].x, atol=1e-2)


def test_identify_command_prints_the_dynamic_cores_scales_beside_the_file(tmp_path, capsys):
    """`activelearn identify --core dynamic` on the truth's logs of the 1:10 car's twin (less grip, a weaker
    motor): the five scales and the figures they scale; the twin's grip and motor found."""
    from activelearn.cli import main
    from simulator import Maneuver, build_vehicle, collect

    twin = build_vehicle(load_vehicle("f1tenth"), {"tire_friction": 0.8, "motor_gain": 0.9})
    for i, (kind, throttle, steering) in enumerate([("slalom", 0.3, 0.1), ("skidpad", 0.4, 0.08)]):
        log = collect([Maneuver(kind, throttle, steering, "ccw", 12.0)], seed=0, vehicle=twin)
        log.to_parquet(tmp_path / f"log{i}.parquet")
    assert main(["identify", str(tmp_path), "--core", "dynamic", "--vehicle", "f1tenth"]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines()[2:] if line.startswith("  ")}
    assert set(rows) >= {"friction", "stiffness_front", "stiffness_rear", "motor", "yaw_inertia"}
    _, scale, _, _, figure, fitted = rows["motor"][:6]
    assert float(scale) == pytest.approx(0.9, abs=0.03)  # the twin's motor
    assert float(fitted) == pytest.approx(float(scale) * float(figure), rel=1e-3)
    assert float(rows["friction"][1]) == pytest.approx(0.8, abs=0.06)  # its grip
    assert "cluster-robust" in out and "f1tenth" in out
    # under the scales of the nominal car's log (another car of the file): the twin's motor still found
    nominal_car = build_vehicle(load_vehicle("f1tenth"))
    nominal = collect([Maneuver("slalom", 0.3, 0.1, "ccw", 12.0)], seed=0, vehicle=nominal_car)
    nominal.to_parquet(tmp_path / "nominal.parquet")
    logs = [str(tmp_path / f"log{i}.parquet") for i in range(2)]
    command = ["identify", *logs, "--core", "dynamic", "--vehicle", "f1tenth"]
    assert main([*command, "--other-car", str(tmp_path / "nominal.parquet")]) == 0
    out = capsys.readouterr().out
    assert "under the scales of 1 log(s) of another car" in out
    motor = next(line.split() for line in out.splitlines() if line.strip().startswith("motor"))
    assert float(motor[1]) == pytest.approx(0.9, abs=0.03)
    # the full-size config's law and loss: four wheels' forces, the Cauchy loss; the twin's motor still found
    assert main([*command, "--wheel-forces", "--loss", "cauchy"]) == 0
    out = capsys.readouterr().out
    motor = next(line.split() for line in out.splitlines() if line.strip().startswith("motor"))
    assert float(motor[1]) == pytest.approx(0.9, abs=0.03)
    assert main(["identify", *logs, "--wheel-forces", "--vehicle", "f1tenth"]) != 0  # the kinematic core's
    assert "--wheel-forces" in capsys.readouterr().err  # no wheels: the flag is named


def test_the_shipped_overlay_puts_nigels_dynamics_config_on_the_kinematic_branch():
    """experiments/params/nigel_dynamic_core.toml over dynamics.toml (what the results page ran): a valid
    config whose model is the dynamic core with the kinematic core below its blend speed."""
    from activelearn.config import load_config

    root = Path(__file__).resolve().parents[1]
    cfg = load_config(root / "experiments" / "configs" / "dynamics.toml",
                      params=root / "experiments" / "params" / "nigel_dynamic_core.toml")  # fmt: skip
    assert (cfg.model.core, cfg.model.kinematic_blend, cfg.model.parameter_uncertainty) == (
        "dynamic", "core", "by_log")
    model = build_model(cfg.model.model_copy(update={"n_inputs": 16}), seed=0)
    assert isinstance(model, DynamicPhysicsModel) and model.dynamic_car.kinematic_core
