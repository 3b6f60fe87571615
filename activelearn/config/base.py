"""What every config section shares: the strict base model, Nigel's limits and constrained types."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

MAX_STEERING = 0.5236  # rad, Nigel's steering limit
POSE_LEVER_ARM = 0.07929  # m, Nigel's CG (where its pose is logged) ahead of the rear axle


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
Steering = Annotated[float, Field(ge=0.0, le=MAX_STEERING)]
Kind = Literal["straight", "skidpad", "fishhook", "slalom", "eight"]
# The families of simulator.families.FAMILIES (tests/test_families.py keeps the two lists equal).
FamilyName = Literal[
    "slalom", "fishhook", "throttle_step", "chirp", "multisine", "prbs", "staircase", "figure_eight"
]
Direction = Literal["ccw", "cw"]


def _unique(values: list[Any], field: str) -> list[Any]:
    if not values:
        raise ValueError(f"{field} must not be empty")
    if len(set(values)) != len(values):
        raise ValueError(f"{field} has duplicates: {values}")
    return values

