"""experiments/investigations/nigel_blend.py: its NumPy copy of the dynamic core's implicit step is the
library's where the pilot changes nothing (D0), so its variants differ from the core only by what they
add; and its D5 is the library's kinematic core (`[model] kinematic_blend = "core"`)."""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

from activelearn.numerics.models.dynamic_scales import scaled
from activelearn.numerics.models.dynamic_track import DynamicCar, dynamic_step
from simulator.vehicles import load_vehicle

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments" / "investigations"))

from nigel_blend import Blend, cars_of, step  # noqa: E402

SETS = np.array([[1.0, 1.0, 1.0, 1.0, 1.0], [0.8, 1.3, 0.7, 0.9, 1.2], [1.5, 0.5, 2.0, 1.1, 0.6]])
# D5's four more: understeer, scrub, yaw lag (the pilot's in s, the library's a scale of Nigel's 0.05 s)
# and the understeer in reverse
BRANCH = np.array([[1.0, 0.0, 1.0, 1.0], [1.03, 1.25, 0.8, 1.05], [0.95, 2.0, 3.0, 1.2]])


def _random_steps(car: DynamicCar, mine, theirs, seed: int) -> tuple:
    """60 steps of the same random controls from the same random start through two steps."""
    rng = np.random.default_rng(seed)
    top = 0.27 if car.wheelbase < 0.2 else 8.0
    state = np.stack([rng.uniform(-0.3, 1.0, 4) * top, rng.normal(0, 0.02, 4) * top,
                      rng.normal(0, 0.5, 4), rng.uniform(-0.4, 0.4, 4)], axis=-1)  # fmt: skip
    a = b = np.broadcast_to(state, (3, 4, 4))
    for _ in range(60):
        throttle, steering = rng.uniform(-0.6, 1.0, 4), rng.uniform(-0.5, 0.5, 4)
        a, b = mine(a, throttle, steering), theirs(b, throttle, steering)
    return a, b


@pytest.mark.parametrize("name", ["nigel", "f1tenth"])
def test_the_pilots_step_without_its_changes_is_the_librarys_implicit_step(name):
    """Nigel below its blend speed and the 1:10 car through it, three parameter sets against four runs."""
    car = DynamicCar.of(load_vehicle(name))
    cars = scaled(car, SETS)
    dt = 1.0 / 30.0
    n = car.implicit_substeps(dt)
    mine, theirs = _random_steps(
        car, lambda s, t, d: step(cars, Blend(False), s, t, d, dt, n),
        lambda s, t, d: dynamic_step(cars, s, t, d, dt, n, implicit=True), 0,
    )
    np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-12)


def test_the_pilots_d5_is_the_librarys_kinematic_core():
    """The same runs of Nigel through the pilot's D5 and the library's core with `kinematic_core`: equal to
    rounding (the pilot's yaw lag in seconds, the library's a scale of the car's prior lag). Not a motor-law
    car: in reverse the library's scrub drag takes the drive's reverse lag, the pilot's the forward one."""
    car = dataclasses.replace(DynamicCar.of(load_vehicle("nigel")), kinematic_core=True)
    library = scaled(car, np.hstack([SETS, BRANCH]))
    seconds = BRANCH.copy()
    seconds[:, 2] *= car.yaw_lag
    pilot, blend = cars_of(dataclasses.replace(car, kinematic_core=False), np.hstack([SETS, seconds]), "D5")
    dt = 1.0 / 30.0
    n = car.implicit_substeps(dt)
    mine, theirs = _random_steps(
        car, lambda s, t, d: step(pilot, blend, s, t, d, dt, n),
        lambda s, t, d: dynamic_step(library, s, t, d, dt, n, implicit=True), 1,
    )
    np.testing.assert_allclose(mine, theirs, rtol=1e-10, atol=1e-12)


def test_a_variants_extra_scales_reach_its_kinematic_branch():
    """D5's nine scales: the five of the core, then understeer, scrub, yaw lag and the reverse understeer."""
    car = DynamicCar.of(load_vehicle("nigel"))
    sets = np.array([[1.0, 1.0, 1.0, 0.9, 1.0, 1.03, 1.25, 0.04, 1.05]])
    scaled_car, blend = cars_of(car, sets, "D5")
    assert blend.weighted and blend.speed_lag is None
    extra = (blend.understeer, blend.scrub, blend.yaw_lag, blend.reverse_understeer)
    assert [float(np.ravel(v)[0]) for v in extra] == [1.03, 1.25, 0.04, 1.05]
    assert float(np.asarray(scaled_car.table_gain).item()) == pytest.approx(0.9)
