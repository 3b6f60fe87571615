"""Marks that can be told apart: one colour per strategy in every figure, one marker per maneuver kind."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.colors import to_hex
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from activelearn.names import STRATEGY_NAMES
from activelearn.plots import _KIND_MARKERS, STRATEGY_COLOURS, comparison_figure, epistemic_map
from simulator import KINDS, FamilyManeuver, Maneuver
from simulator.families import FAMILIES


def test_every_strategy_has_a_colour_of_its_own() -> None:
    assert set(STRATEGY_COLOURS) == set(STRATEGY_NAMES)
    assert len({to_hex(c) for c in STRATEGY_COLOURS.values()}) == len(STRATEGY_COLOURS)


def test_a_strategy_keeps_its_colour_whatever_else_is_compared() -> None:
    def colours(strategies: tuple[str, ...]) -> dict[str, str]:
        curves = pd.DataFrame([{"strategy": s, "seed": 0, "round": r, "n_maneuvers": r,
                                "test_rmse": 1.0 / (r + 1)} for s in strategies for r in range(2)])
        fig = comparison_figure(curves, ["test_rmse"])
        return {line.get_label().split(" ")[0]: to_hex(line.get_color()) for line in fig.axes[0].lines}

    first, second = colours(("uniform", "max_epistemic", "auto")), colours(("auto", "bald"))
    assert first["auto"] == second["auto"] == to_hex(STRATEGY_COLOURS["auto"])
    assert first["uniform"] == to_hex(STRATEGY_COLOURS["uniform"])


def test_every_maneuver_kind_has_a_marker_of_its_own() -> None:
    kinds = set(KINDS) | set(FAMILIES)
    assert kinds <= set(_KIND_MARKERS)
    assert len(set(_KIND_MARKERS.values())) == len(_KIND_MARKERS)


def test_a_dynamics_map_tells_collected_and_each_family_apart() -> None:
    def member(family: str) -> FamilyManeuver:
        values = {p.name: float(round(sum(p.pool) / 2)) if p.integer else sum(p.pool) / 2
                  for p in FAMILIES[family].parameters}  # fmt: skip
        return FamilyManeuver(family, values, "ccw", 10.0)

    taken = [member("chirp"), member("prbs"), member("throttle_step")]
    picks = [Maneuver("skidpad", 0.6, 0.3, "ccw", 10.0)]
    grid = np.linspace(0.3, 0.9, 3)
    fig = epistemic_map(grid, grid - 0.6, np.ones((3, 3)), taken=taken, picks=picks)
    legend = fig.legends[0]
    entries = dict(zip([t.get_text() for t in legend.get_texts()], legend.legend_handles, strict=True))
    assert list(entries) == ["collected", "chosen this round", "shape: chirp", "shape: prbs",
                             "shape: skidpad", "shape: throttle_step"]  # fmt: skip
    # the groups are fills (no shape that could be read as a kind); each kind an outline of its own
    collected = entries["collected"]
    assert isinstance(collected, Patch) and to_hex(collected.get_facecolor()) == "#ffffff"
    shapes = [h.get_marker() for label, h in entries.items() if label.startswith("shape:")]
    assert all(isinstance(entries[k], Line2D) for k in entries if k.startswith("shape:"))
    assert len(set(shapes)) == 4
    # on the map, each family's points carry its own marker
    drawn = {tuple(c.get_paths()[0].vertices.round(3).ravel()) for c in fig.axes[0].collections[1:]}
    assert len(drawn) == 4
