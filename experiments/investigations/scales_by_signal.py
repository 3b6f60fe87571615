"""Which scales each kind of signal pins: the dynamic core identified on a config's noise-free truth logs
of its test maneuvers and of its pool's families, one group at a time (session 49).

The Fisher rules of session 49 picked chirps and PRBS and ended with the stiffness and yaw-inertia scales
low; this asks whether those signals pin other scales than the test's maneuvers do. The identification is
the model's own (`identify_scales`, the file's prior, the config's loss); ± the cluster-robust standard
errors. The truth logs come from the simulation cache (simulated first where missing: minutes per car).

    python experiments/investigations/scales_by_signal.py experiments/configs/dynamics_bmw320i_warm_twin.toml
"""

from __future__ import annotations

import argparse
import time

from activelearn.config import load_config
from activelearn.loop.collection import cache_root, control_rate_logs
from activelearn.loop.oracles import make_oracle
from activelearn.numerics.models import build_model
from activelearn.numerics.models.dynamic_physics import before_a_stop, identify_scales

GROUPS = {
    "chirp+prbs": ("chirp", "prbs"),
    "step+fishhook": ("throttle_step", "fishhook"),
    "slalom": ("slalom",),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("config", help="a family-pool config with [model] core = \"dynamic\"")
    args = parser.parse_args()
    cfg = load_config(args.config)
    if cfg.model.kind != "physics" or cfg.model.core != "dynamic" or not cfg.pool.families:
        parser.error("config: needs a family pool and [model] kind = \"physics\" with core = \"dynamic\"")
    oracle = make_oracle(cfg, cache_root(cfg))
    model = build_model(cfg.model, seed=0)
    pool = oracle.candidates()
    sets = {"test maneuvers": list(oracle.test_set().truth_logs)}
    for label, families in GROUPS.items():
        members = [m for m in pool if m.family in families]
        if members:
            sets[f"pool {label}"] = oracle.truth(members)
    dt = 1.0 / model.car.log_rate_hz
    for label, frames in sets.items():
        start = time.time()
        logs = [before_a_stop(log) for log in control_rate_logs(frames)]
        found = identify_scales(logs, model.dynamic_car, dt, None, None, cfg.model.identification_loss)
        scales = "  ".join(
            f"{name} {value:.3f} ± {error:.3f}"
            for name, value, error in zip(model.parameter_names, found.values, found.stderr, strict=True)
        )
        print(f"{label:20s} ({len(logs)} logs, {time.time() - start:.0f} s): {scales}", flush=True)


if __name__ == "__main__":
    main()
