"""Maneuver validation, names and the control schedules computed without simulating."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from simulator import STEERING_LIMIT, Maneuver, ManeuverError, nominal_controls, sample_times


@pytest.mark.parametrize(
    ("kwargs", "field", "value"),
    [
        ({"kind": "donut"}, "kind", "donut"),
        ({"kind": 3}, "kind", 3),
        ({"throttle": 1.01}, "throttle", 1.01),
        ({"throttle": -1.5}, "throttle", -1.5),
        ({"throttle": float("nan")}, "throttle", None),
        ({"throttle": "0.5"}, "throttle", "0.5"),
        ({"throttle": True}, "throttle", True),
        ({"steering": -0.1}, "steering", -0.1),
        ({"steering": 1.6}, "steering", 1.6),
        ({"steering": float("inf")}, "steering", float("inf")),
        ({"direction": "left"}, "direction", "left"),
        ({"duration": 0.0}, "duration", 0.0),
        ({"duration": -5}, "duration", -5),
    ],
)
def test_invalid_values_raise_an_error_naming_field_and_value(kwargs: dict, field: str, value: Any) -> None:
    args = {"kind": "skidpad", "throttle": 0.5, "steering": 0.2, "direction": "ccw", "duration": 10} | kwargs
    with pytest.raises(ManeuverError) as info:
        Maneuver(**args)
    assert info.value.field == field
    assert str(info.value).startswith(f"{field}:")
    if value is not None:
        assert info.value.value == value
        assert repr(value) in str(info.value)


def test_collect_checks_steering_against_the_cars_own_limit() -> None:
    """A maneuver is built before the car is known: collect refuses one beyond the car's lock, naming it."""
    from simulator import collect

    with pytest.raises(ManeuverError) as info:
        collect([Maneuver("skidpad", 0.5, 0.5237, "ccw", 0.1)], noise=None)
    assert info.value.field == "steering" and "0.5236" in str(info.value) and "skidpad_ccw" in str(info.value)


def test_limits_are_inclusive() -> None:
    Maneuver("skidpad", 1.0, STEERING_LIMIT, "cw", 0.01)
    Maneuver("skidpad", -1.0, 0.0, "ccw", 1)


def test_maneuver_is_frozen_and_normalised() -> None:
    m = Maneuver("slalom", 1, 0, "cw", 90)
    assert isinstance(m.throttle, float) and isinstance(m.duration, float)
    assert m == Maneuver("slalom", 1.0, 0.0, "cw", 90.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.throttle = 0.2  # type: ignore[misc]


def test_name_is_readable_stable_and_unique() -> None:
    assert Maneuver("skidpad", 0.6, 0.3142, "ccw").name == "skidpad_ccw_t0.60_s0.3142_d90"
    assert Maneuver("straight", -0.5, duration=2.5).name == "straight_ccw_t-0.50_s0.0000_d2.5"
    # values that do not fit the short format keep their full precision
    a = Maneuver("skidpad", 0.612345678, 0.3, "cw")
    b = Maneuver("skidpad", 0.612345679, 0.3, "cw")
    assert a.name != b.name
    names = {Maneuver(k, 0.5, 0.2, d).name for k in ("skidpad", "slalom", "eight") for d in ("cw", "ccw")}
    assert len(names) == 6


def test_sign_and_operating_steering() -> None:
    assert Maneuver("skidpad", 0.5, 0.2, "ccw").sign == 1
    assert Maneuver("skidpad", 0.5, 0.2, "cw").sign == -1
    assert Maneuver("straight", 0.5, 0.2, "cw").op_steering == 0.0  # straight ignores steering
    assert Maneuver("skidpad", 0.5, 0.2, "cw").op_steering == 0.2


def test_sample_times_include_both_ends() -> None:
    np.testing.assert_allclose(sample_times(1.0, 30.0), np.arange(31) / 30.0)
    assert len(sample_times(90.0, 30.0)) == 2701
    assert len(sample_times(0.01, 30.0)) == 1


def test_straight_and_skidpad_schedules() -> None:
    u = nominal_controls(Maneuver("straight", 0.7, 0.3, "cw", 2.0))
    assert u.shape == (61, 2)
    assert (u[:, 0] == 0.7).all() and (u[:, 1] == 0.0).all()
    ccw = nominal_controls(Maneuver("skidpad", 0.7, 0.3, "ccw", 2.0))
    cw = nominal_controls(Maneuver("skidpad", 0.7, 0.3, "cw", 2.0))
    assert (ccw[:, 1] == 0.3).all()
    np.testing.assert_array_equal(cw[:, 1], -ccw[:, 1])


def test_fishhook_ramps_at_the_reference_rate_up_to_the_amplitude() -> None:
    u = nominal_controls(Maneuver("fishhook", 0.5, STEERING_LIMIT, "ccw", 90.0), rate_hz=10.0)
    t = np.arange(len(u)) / 10.0
    np.testing.assert_allclose(u[:, 1], np.minimum(0.006 * t, STEERING_LIMIT))
    assert u[-1, 1] == pytest.approx(STEERING_LIMIT)
    capped = nominal_controls(Maneuver("fishhook", 0.5, 0.1, "cw", 90.0), rate_hz=10.0)
    assert capped[:, 1].min() == pytest.approx(-0.1)


def test_slalom_drives_straight_then_follows_a_cosine() -> None:
    u = nominal_controls(Maneuver("slalom", 0.5, 0.4, "cw", 20.0))
    t = np.arange(len(u)) / 30.0
    assert (u[t < 3.0, 1] == 0.0).all()
    late = t >= 3.0
    np.testing.assert_allclose(u[late, 1], -0.4 * np.cos(0.9 * (t[late] - 3.0)))


def test_eight_alternates_full_turns() -> None:
    u = nominal_controls(Maneuver("eight", 0.8, 0.4, "ccw", 60.0))
    signs = np.sign(u[:, 1])
    flips = np.nonzero(np.diff(signs))[0] + 1
    assert signs[0] == 1 and len(flips) >= 3
    periods = np.diff(flips)
    assert periods.max() - periods.min() <= 1  # equal loops
    # one loop takes 2 pi / w at a plausible yaw rate: kinematic at most, and not below half of it
    loop = periods[0] / 30.0
    v = 0.8 * 0.267
    kinematic = v * math.tan(0.4) / 0.14155
    assert 2 * math.pi / kinematic < loop < 2 * 2 * math.pi / kinematic


def test_nominal_controls_rejects_bad_rate() -> None:
    with pytest.raises(ManeuverError) as info:
        nominal_controls(Maneuver("skidpad", 0.5, 0.2), rate_hz=0.0)
    assert info.value.field == "rate_hz"
