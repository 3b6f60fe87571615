"""What a campaign learnt, as a fingerprint: the maneuvers each round took, the rows collected and every
round's metrics. A refactor that changes no arithmetic leaves it unchanged (tests/test_fingerprint.py
compares today's with the one stored in tests/data/campaign_fingerprints.json).

`python -m tests.fingerprint --write` records it anew, for a change meant to alter what is learnt.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STORED = ROOT / "tests" / "data" / "campaign_fingerprints.json"
SIGNIFICANT = 9  # metrics rounded to this many significant digits (the stored file is JSON text)
# Metrics agree to this relative tolerance, the data exactly. Two CPU families give the same maneuvers
# and rows but float32 sums in other orders: metrics differ by up to 2.7e-5 relative (session 37,
# all six settings, every round; the largest is a 30-s heading error), so 9 digits held on one only.
RELATIVE = 2e-4
TIMINGS = ("wall_seconds", "rollout_seconds", "safety_seconds", "fit_seconds")  # measured, not learnt

# (name, config, overrides): each small, together the loop's paths: a black box chosen by uncertainty,
# auto with a warm start, the physics kind, and the safety admission with the live stop.
_SMALL = {"training": {"epochs": 25}, "design": {"initial": 3, "per_round": 2, "max_maneuvers": 5}}
_PRIOR_GRID = {"kinds": ["skidpad"], "throttles": [0.3, 0.6], "steerings": [0.15], "duration": 10.0}
_SQUARE = [[-1.5, -1.5], [1.5, -1.5], [1.5, 1.5], [-1.5, 1.5]]
_DYNAMIC = {
    "pool": {"kinds": ["skidpad", "slalom"], "duration": 8.0},
    "data": {"stride": 5, "skip_seconds": 0.0, "inputs": "history", "history": 3, "history_step": 2},
    "training": {"epochs": 15},
    "design": {"initial": 2, "per_round": 1, "max_maneuvers": 4},
    "test": {"kinds": ["slalom"], "throttles": [0.6], "steerings": [0.3], "duration": 8.0,
             "metric": "rollout_pos_err_30s", "rollout_samples": 8},
}  # fmt: skip

# (name, config, overrides): each small, together the loop's paths: a black box chosen by uncertainty
# and by space filling, auto with a warm start, the physics kind free-running (chosen by uncertainty,
# and warm-started rounds chosen by maximin), the safety admission.
SETTINGS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("smoke_max_epistemic", "smoke.toml", {"strategy": "max_epistemic", **_SMALL}),
    ("smoke_uniform", "smoke.toml", {"strategy": "uniform", **_SMALL}),
    ("warm_auto", "smoke.toml", {"strategy": "auto", "training": {"epochs": 20}, "design": {
        "initial": 0, "per_round": 2, "max_maneuvers": 4, "prior": {"grid": _PRIOR_GRID}}}),
    ("physics_dynamic", "smoke.toml", {"strategy": "max_epistemic", **_DYNAMIC, "model": {
        "kind": "physics", "kinematic_feature": False, "correction_gate": True,
        "correction_gate_min_held_out": 2, "arch": "D16-V8-V"}}),
    ("physics_dynamic_warm_uniform", "smoke.toml", {"strategy": "uniform", **_DYNAMIC, "model": {
        "kind": "physics", "kinematic_feature": False, "arch": "D16-V8-V"},
        "training": {"epochs": 15, "warm_start": True}}),
    ("safety_uniform", "smoke.toml", {"strategy": "uniform", **_SMALL, "pool": {
        "kinds": ["straight", "skidpad"]}, "safety": {"arena": _SQUARE, "start": [0.0, 0.0, 0.0],
        "min_duration": 3.0, "n_samples": 16}}),
)


def _rounded(value: Any) -> Any:
    if isinstance(value, float):
        return float(f"{value:.{SIGNIFICANT}g}") if np.isfinite(value) else str(value)  # JSON: no nan
    return value


def fingerprint(directory: Path) -> dict[str, Any]:
    """The fingerprint of a finished campaign directory."""
    from activelearn.data import read_table
    from activelearn.loop.state import SAMPLES_FILE, CampaignState

    state = CampaignState.load(directory)
    samples = read_table(directory / SAMPLES_FILE)
    # the logs' `timestamp` runs on across a batch simulated together, so it depends on what the cache
    # already held; `time` is each log's own clock
    numbers = samples.select_dtypes("number").drop(columns="timestamp")
    digest = hashlib.sha256(np.ascontiguousarray(numbers.to_numpy()).tobytes())
    rounds = [{k: _rounded(v) for k, v in sorted(r.items()) if k not in TIMINGS} for r in state.rounds]
    return {"batches": state.batches, "cuts": state.cuts, "samples_sha256": digest.hexdigest(),
            "n_rows": len(samples), "rounds": rounds}


def differences(now: dict[str, Any], stored: dict[str, Any]) -> list[str]:
    """What differs between two fingerprints: the data exactly, the metrics beyond `RELATIVE`."""
    keys = ("batches", "cuts", "n_rows", "samples_sha256")
    differ = [f"{k}: {now.get(k)} != {stored.get(k)}" for k in keys if now.get(k) != stored.get(k)]
    if len(now["rounds"]) != len(stored["rounds"]):
        return [*differ, f"rounds: {len(now['rounds'])} != {len(stored['rounds'])}"]
    for index, (got, want) in enumerate(zip(now["rounds"], stored["rounds"], strict=True)):
        for key in sorted(set(got) | set(want)):
            a, b = got.get(key), want.get(key)
            close = isinstance(a, float) and isinstance(b, float) and math.isclose(a, b, rel_tol=RELATIVE)
            if a != b and not close:
                differ.append(f"round {index} {key}: {a} != {b}")
    return differ


def run(name: str) -> dict[str, Any]:
    """Run one setting in a temporary directory and fingerprint it."""
    from activelearn.config import load_config
    from activelearn.loop.campaign import Campaign

    _, config, overrides = next(s for s in SETTINGS if s[0] == name)
    with tempfile.TemporaryDirectory() as tmp:
        cfg = load_config(ROOT / "experiments" / "configs" / config,
                          overrides={**overrides, "output_dir": tmp, "tracking": {"enabled": False}})
        Campaign(cfg, Path(tmp) / "c").run(figures=False, log_model=False)
        return fingerprint(Path(tmp) / "c")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--write", action="store_true", help="store the fingerprints anew")
    parser.add_argument("names", nargs="*", help="settings to run (default: all)")
    args = parser.parse_args()
    names = args.names or [s[0] for s in SETTINGS]
    stored = json.loads(STORED.read_text()) if STORED.exists() else {}
    differ = []
    for name in names:
        now = run(name)
        if args.write:
            stored[name] = now
        elif name not in stored or differences(now, stored[name]):
            differ.append(name)
        print(name, "written" if args.write else ("DIFFERS" if name in differ else "same"), flush=True)
    if args.write:
        STORED.write_text(json.dumps(stored, indent=1, sort_keys=True) + "\n")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
