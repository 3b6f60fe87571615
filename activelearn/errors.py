"""Exceptions for user mistakes: each names the offending field and value."""

from __future__ import annotations

from typing import Any


class ActiveLearnError(Exception):
    """Base class of every error activelearn raises for bad input or state."""


class InputError(ActiveLearnError, ValueError):
    """A user-supplied value is invalid; `field` names it and `value` holds it."""

    def __init__(self, field: str, value: Any, reason: str) -> None:
        self.field = field
        self.value = value
        self.reason = reason
        super().__init__(f"{field}: {reason} (got {value!r})")

    def __reduce__(self):
        """Rebuilt from its three fields: an error raised in a worker process reaches the caller whole
        (pickled by its message alone it could not be rebuilt, and the pool broke instead)."""
        return type(self), (self.field, self.value, self.reason)


class ConfigError(InputError):
    """A configuration key is unknown, mistyped or out of range."""


class DataFormatError(ActiveLearnError, ValueError):
    """A data file is malformed; the message names the file and line."""


class TrackingUnavailable(ActiveLearnError):
    """The MLflow tracking server does not answer; the call logged nothing."""


class CampaignStopped(ActiveLearnError):
    """A campaign stopped for a cause outside it (a write failed, the tracking server is gone); its
    directory holds its last finished step and resumes with --resume."""
