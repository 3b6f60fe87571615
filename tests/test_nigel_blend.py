"""experiments/investigations/nigel_blend.py: its NumPy copy of the dynamic core's implicit step is the
library's where the pilot changes nothing (D0), so its variants differ from the core only by what they
add."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from activelearn.numerics.models.dynamic_track import DynamicCar, dynamic_step, scaled
from simulator.vehicles import load_vehicle

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "experiments" / "investigations"))

from nigel_blend import Blend, cars_of, step  # noqa: E402


@pytest.mark.parametrize("name", ["nigel", "f1tenth"])
def test_the_pilots_step_without_its_changes_is_the_librarys_implicit_step(name):
    """Nigel below its blend speed and the 1:10 car through it, three parameter sets against four runs."""
    car = DynamicCar.of(load_vehicle(name))
    sets = np.array([[1.0, 1.0, 1.0, 1.0, 1.0], [0.8, 1.3, 0.7, 0.9, 1.2], [1.5, 0.5, 2.0, 1.1, 0.6]])
    cars = scaled(car, sets)
    rng = np.random.default_rng(0)
    top = 0.27 if name == "nigel" else 8.0
    state = np.stack([rng.uniform(-0.3, 1.0, 4) * top, rng.normal(0, 0.02, 4) * top,
                      rng.normal(0, 0.5, 4), rng.uniform(-0.4, 0.4, 4)], axis=-1)  # fmt: skip
    theirs = mine = np.broadcast_to(state, (3, 4, 4))
    dt = 1.0 / 30.0
    substeps = car.implicit_substeps(dt)
    for _ in range(60):
        throttle, steering = rng.uniform(-0.6, 1.0, 4), rng.uniform(-0.5, 0.5, 4)
        theirs = dynamic_step(cars, theirs, throttle, steering, dt, substeps, implicit=True)
        mine = step(cars, Blend(False), mine, throttle, steering, dt, substeps)
    np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-12)


def test_a_variants_extra_scales_reach_its_kinematic_branch():
    """D5's nine scales: the five of the core, then understeer, scrub, yaw lag and the reverse understeer."""
    car = DynamicCar.of(load_vehicle("nigel"))
    sets = np.array([[1.0, 1.0, 1.0, 0.9, 1.0, 1.03, 1.25, 0.04, 1.05]])
    scaled_car, blend = cars_of(car, sets, "D5")
    assert blend.weighted and blend.speed_lag is None
    extra = (blend.understeer, blend.scrub, blend.yaw_lag, blend.reverse_understeer)
    assert [float(np.ravel(v)[0]) for v in extra] == [1.03, 1.25, 0.04, 1.05]
    assert float(np.asarray(scaled_car.table_gain).item()) == pytest.approx(0.9)
