"""`TrainingData`: everything a model trains on, as one object (`training.fit` and model hooks read it)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from activelearn.numerics.multistep import Windows

Log = tuple[np.ndarray, np.ndarray]  # (controls (T, 2), rates (T, 2)) of one maneuver at the log rate


@dataclass(frozen=True)
class TrainingData:
    """One-step rows in physical units and, where a kind uses them, the maneuvers' windows and logs.

    `x` (N, n_inputs) and `y` (N, n_outputs) are the rows; `groups` each row's maneuver id (the KL
    count's maneuvers, the correction gate's held-out maneuvers); `windows` free runs for multi-step
    training (`[training] rollout_horizon`); `logs` each maneuver's whole log, for a kind that identifies
    itself on them (`Model.identify`); `log_groups` each log's id among `groups`; `of_another_car`, per
    log, whether it is another car's (a simulated prior grid), which then only centres the identification.
    """

    x: np.ndarray
    y: np.ndarray
    groups: np.ndarray | None = None
    windows: Windows | None = None
    logs: list[Log] | None = None
    log_groups: Sequence | None = None
    of_another_car: Sequence[bool] | None = None

    def without(self, held: np.ndarray) -> TrainingData:
        """These data without the maneuvers whose ids are in `held`: rows by `groups`, logs (and their
        windows and flags) by `log_groups`. Needs both."""
        assert self.groups is not None and self.log_groups is not None and self.logs is not None
        rows = ~np.isin(self.groups, held)
        keep = np.flatnonzero(~np.isin(np.asarray(self.log_groups), held))
        return TrainingData(
            self.x[rows], self.y[rows], self.groups[rows],
            windows=self.windows.of_logs(keep) if self.windows is not None else None,
            logs=[self.logs[i] for i in keep],
            log_groups=[self.log_groups[i] for i in keep],
            of_another_car=None if self.of_another_car is None else [self.of_another_car[i] for i in keep],
        )  # fmt: skip
