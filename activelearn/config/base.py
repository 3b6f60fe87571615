"""What every config section shares: the strict base model, the default car's figures, constrained types."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from simulator.families import ANGLE_MAX
from simulator.vehicles import load_vehicle

_NIGEL = load_vehicle("nigel")  # the default car ([vehicle] sets another; its file holds every figure)
MAX_STEERING = _NIGEL.steering.limit.value  # rad, the default car's full lock
POSE_LEVER_ARM = _NIGEL.geometry.lr.value  # m, the default car's CG (its logged pose) ahead of its rear axle


class _Section(BaseModel):
    """Base of every config section: unknown keys are errors, values are re-validated on assignment."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)



# Shared constrained types: pydantic names the key and the bound in its error message.
Count = Annotated[int, Field(ge=1)]
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]
# Seeds reach numpy's SeedSequence (non-negative only) and torch's manual_seed (scaled per round by
# the campaign; below 2**64): 32 bits keep every derived seed in range.
Seed = Annotated[int, Field(ge=0, lt=2**32)]
Throttle = Annotated[float, Field(ge=-1.0, le=1.0)]
Steering = Annotated[float, Field(ge=0.0, lt=ANGLE_MAX)]  # within the car's lock: [vehicle]
Kind = Literal["straight", "skidpad", "fishhook", "slalom", "eight"]
# The families of simulator.families.FAMILIES (tests/test_families.py keeps the two lists equal).
FamilyName = Literal[
    "slalom", "fishhook", "throttle_step", "chirp", "multisine", "prbs", "staircase", "figure_eight",
    "ramp_steer", "step_steer", "sine_with_dwell", "double_lane_change",
]
Direction = Literal["ccw", "cw"]


def _unique(values: list[Any], field: str) -> list[Any]:
    if not values:
        raise ValueError(f"{field} must not be empty")
    if len(set(values)) != len(values):
        raise ValueError(f"{field} has duplicates: {values}")
    return values

