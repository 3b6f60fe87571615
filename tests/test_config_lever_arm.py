"""`pose_lever_arm` lives in one section, [model]; a config that still sets it in [data] is read so."""

from __future__ import annotations

import pytest

from activelearn.config import DataConfig, validate_config
from activelearn.errors import ConfigError


def test_the_lever_arm_lives_in_model_only():
    assert "pose_lever_arm" not in DataConfig.model_fields
    assert validate_config({"model": {"pose_lever_arm": 0.05}}).model.pose_lever_arm == 0.05


def test_a_lever_arm_set_in_data_moves_to_model():
    cfg = validate_config({"data": {"pose_lever_arm": 0.05, "stride": 2}})
    assert cfg.model.pose_lever_arm == 0.05 and cfg.data.stride == 2
    same = validate_config({"data": {"pose_lever_arm": 0.05}, "model": {"pose_lever_arm": 0.05}})
    assert same.model.pose_lever_arm == 0.05


def test_two_lever_arms_are_an_error_naming_the_field():
    with pytest.raises(ConfigError, match="pose_lever_arm"):
        validate_config({"data": {"pose_lever_arm": 0.05}, "model": {"pose_lever_arm": 0.0}})
