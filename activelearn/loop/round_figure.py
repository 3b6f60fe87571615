"""The figure a campaign draws each round: the model's epistemic std over the evaluation grid, with
the collected maneuvers, the picks and the model's predicted free runs of them."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from activelearn.config import CampaignConfig
from activelearn.loop.evaluation import EVAL_SAMPLES, standardise
from activelearn.loop.pool import evaluation_grid, maneuver_controls
from activelearn.numerics.surrogate import model_inputs, simulate


def figure_path(directory: str | Path, round_index: int) -> Path:
    """figures/epistemic_roundNN.png of a campaign directory (MLflow logs it with the round)."""
    return Path(directory) / "figures" / f"epistemic_round{round_index:02d}.png"


def plans(
    cfg: CampaignConfig, model: Any, driven: Sequence[Any]
) -> tuple[list[str], list[np.ndarray], Any]:
    """Names, control signals and the model's predicted free runs of the chosen maneuvers (as driven)."""
    rate = cfg.simulation.rate_hz
    controls = [maneuver_controls(m, rate) for m in driven]
    return (
        [m.name for m in driven],
        controls,
        simulate(model, controls, rate_hz=rate, n_samples=16, seed=0),
    )


def draw_round(
    cfg: CampaignConfig, directory: str | Path, model: Any, *, maneuvers: Sequence[Any], scale: np.ndarray,
    taken: Sequence[int], picks: Sequence[int], driven: Callable[[int], Any], prior: Sequence[Any],
    round_index: int,
) -> Path:  # fmt: skip
    """Draw round `round_index`'s figure into the campaign directory (atomically)."""
    from activelearn.plots import epistemic_map, save_figure  # matplotlib only when figures are drawn

    throttles, steerings, grid = evaluation_grid(cfg, maneuvers)
    pred = standardise(model.predict(model_inputs(model, grid), n_samples=EVAL_SAMPLES, seed=0), scale)
    std = np.sqrt(pred.epistemic_var).mean(axis=1).reshape(len(throttles), len(steerings))
    fig = epistemic_map(
        throttles,
        steerings,
        std,
        taken=[maneuvers[i] for i in taken],
        picks=[maneuvers[i] for i in picks],
        prior=prior,
        title=f"{cfg.strategy}, seed {cfg.seed}, round {round_index}",
        plans=plans(cfg, model, [driven(i) for i in picks]) if picks else None,
    )
    return save_figure(fig, figure_path(directory, round_index), dpi=90)
