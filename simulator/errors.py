"""Exceptions of the simulator: each names the offending field and value."""

from __future__ import annotations

from typing import Any


class SimulatorError(Exception):
    """Base class of every error the simulator raises."""


class ManeuverError(SimulatorError, ValueError):
    """A maneuver or collection argument is invalid; `field` names it and `value` holds it."""

    def __init__(self, field: str, value: Any, reason: str) -> None:
        self.field = field
        self.value = value
        self.reason = reason
        super().__init__(f"{field}: {reason} (got {value!r})")


class DivergenceError(SimulatorError, RuntimeError):
    """A rollout blew up (NaN, flipped or airborne); `maneuvers` names the runs affected.

    `data` holds the collected table (diverged runs flagged and truncated) when it exists.
    """

    def __init__(self, maneuvers: list[str], reason: str, data: Any = None) -> None:
        self.maneuvers = maneuvers
        self.reason = reason
        self.data = data
        super().__init__(f"diverged: {', '.join(maneuvers)}: {reason}")


class DivergenceWarning(RuntimeWarning):
    """Some maneuvers diverged; their rows are flagged in the `diverged` column."""


class OverrideError(SimulatorError, ValueError):
    """A twin parameter override is unknown or out of range; `field` names it and `value` holds it."""

    def __init__(self, field: str, value: Any, reason: str) -> None:
        self.field = field
        self.value = value
        self.reason = reason
        super().__init__(f"{field}: {reason} (got {value!r})")
