"""The sizes of every benchmark's `--quick` mode: each part runs, on a handful of maneuvers and epochs.

A quick run measures nothing worth reporting; it shows the benchmark still runs end to end on the real
components (MuJoCo, training, the campaign loop), which `tests/test_benchmarks.py` checks. The output
directory and the simulation cache go where the caller says (the config's `output_dir`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from activelearn.config import CampaignConfig, validate_config

SECONDS = 10.0  # longest maneuver of a quick run


def shrink(cfg: CampaignConfig, output_dir: str | Path | None = None) -> CampaignConfig:
    """`cfg` at quick sizes: two rounds after the first, two epochs, a few short test maneuvers, and
    eager steps (`[training] compile = false`: a cold torch.compile of the dynamic core takes longer
    than the quick run itself; compiled and eager steps agree, tests/test_dynamic_physics.py)."""
    data: dict[str, Any] = cfg.model_dump(mode="json")
    if output_dir is not None:
        data["output_dir"] = str(output_dir)
    data["tracking"]["enabled"] = False
    pool = data["pool"]
    pool["duration"] = min(pool["duration"], SECONDS)
    pool["durations"] = {kind: min(seconds, SECONDS) for kind, seconds in pool["durations"].items()}
    if pool["size"] is not None:
        pool["size"] = min(pool["size"], 3)
    design = data["design"]
    design["initial"] = min(design["initial"], 2)
    design["per_round"] = 1
    design["max_maneuvers"] = design["initial"] + 2
    design["max_rounds"] = None
    prior = design["prior"]
    if prior is not None and prior["grid"] is not None:
        grid = prior["grid"]
        grid.update(throttles=grid["throttles"][:2], steerings=grid["steerings"][:1],
                    directions=grid["directions"][:1], duration=min(grid["duration"], SECONDS))  # fmt: skip
    test = data["test"]
    if test["logs"] is None:
        test.update(throttles=test["throttles"][:2], steerings=test["steerings"][:1],
                    directions=test["directions"][:1], duration=min(test["duration"], SECONDS))  # fmt: skip
    if test["rollout_samples"]:
        test["rollout_samples"] = 4
    data["training"]["epochs"] = 2
    data["training"]["compile"] = False
    data["training"]["warm_epochs"] = None
    data["training"]["rollout_horizon"] = min(data["training"]["rollout_horizon"], 10)
    data["model"]["ensemble_size"] = min(data["model"]["ensemble_size"], 2)
    data["acquisition"]["n_samples"] = min(data["acquisition"]["n_samples"], 8)
    if data["safety"] is not None:
        data["safety"]["n_samples"] = 8
    return validate_config(data)
