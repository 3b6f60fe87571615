"""Input layouts of dynamic models: which past controls and rates a model reads (a delay embedding).

A static map reads the current controls u_t = (throttle, steering). A dynamic model with history k at
a step of s log steps reads

    u_t, u_{t-s}, ..., u_{t-(k-1)s}          (2k control inputs, newest first)
    y_{t-s}, y_{t-2s}, ..., y_{t-ks}         (2k rate inputs, y = (v, ω), newest first)

and predicts y_t. The Markov-state model is k = 1, s = 1. The layout is a pure function of the
model's input count (4k) and its `history_step`, so a saved model carries everything its forward
simulation needs; data tables, rollouts and acquisition all read it from here.
"""

from __future__ import annotations

from dataclasses import dataclass

from activelearn.names import CONTROLS, RATES

N_CONTROLS = 2
N_RATES = 2


@dataclass(frozen=True)
class Lags:
    """History k (past steps of controls and rates) at a step of `step` log steps."""

    history: int
    step: int = 1

    def __post_init__(self) -> None:
        if self.history < 1 or self.step < 1:
            raise ValueError(f"history and step must be >= 1, got {self.history}, {self.step}")

    @property
    def control_lags(self) -> tuple[int, ...]:
        """Log steps back of each control input pair, newest first: 0, s, ..., (k-1)s."""
        return tuple(range(0, self.history * self.step, self.step))

    @property
    def rate_lags(self) -> tuple[int, ...]:
        """Log steps back of each rate input pair, newest first: s, 2s, ..., ks."""
        return tuple(range(self.step, (self.history + 1) * self.step, self.step))

    @property
    def n_inputs(self) -> int:
        """Model inputs: 2k controls and 2k rates."""
        return (N_CONTROLS + N_RATES) * self.history

    @property
    def span(self) -> int:
        """Log steps of past a row needs: rows earlier than this in a log have no full history."""
        return self.history * self.step

    def inputs(self) -> list[tuple[str, str, int]]:
        """Every input in model order as (column name, the log column it reads, log steps back).

        Lagged columns are named `<name>_lag<d>`; the current controls keep their names.
        """
        pairs = [(c, d) for d in self.control_lags for c in CONTROLS]
        pairs += [(c, d) for d in self.rate_lags for c in RATES]
        return [(c if d == 0 else f"{c}_lag{d}", c, d) for c, d in pairs]

    def columns(self) -> list[str]:
        """Column names of the inputs in model order."""
        return [name for name, _, _ in self.inputs()]


def model_lags(model) -> Lags | None:
    """The input layout of a model: None for a static map (2 inputs), else its history and step."""
    n_inputs = int(model.n_inputs)
    if n_inputs == N_CONTROLS:
        return None
    if n_inputs % (N_CONTROLS + N_RATES):
        raise ValueError(f"a dynamic model has 4k inputs (k controls and rates), got {n_inputs}")
    return Lags(n_inputs // (N_CONTROLS + N_RATES), int(model.config.history_step))
