"""The physics kind's free runs against each car's truth simulator: speed, side by side in one run.

For each fast car (`--cars`), the test maneuvers of its `dynamics_<car>.toml` (their commands, 30 s
at 30 Hz) are simulated by the truth (MuJoCo and the magic-formula tyres, `simulator.collect`, all
cores, no noise) and free-run by the physics kind with each core (an untrained model: the time does
not depend on the weights), S = `--samples` sampled trajectories each, as a campaign's evaluation
runs them; the dynamic core eagerly and compiled (torch.compile, as campaigns that train windows run
it; its first call, which compiles, timed apart). Prints per car and core: wall seconds of each (best
of `--repeats`), their ratio, and the absolute rate in sample-steps per second (S × maneuvers × steps
/ wall).

Usage: python experiments/benchmarks/bench_dynamic_speed.py [--cars f1tenth,bmw320i] [--samples 32]
       [--repeats 3] [--out DIR] [--quick]
`--quick` (what the test runs): the 1:10 car, quick.py's shrunk test set, S = 4, one repeat.
"""

from __future__ import annotations

import argparse
import time
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd
from quick import shrink

import simulator
from activelearn.config import load_config
from activelearn.loop.campaign import Campaign
from activelearn.numerics.diagnostics import free_runs
from activelearn.numerics.models import build_model

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CARS = ("f1tenth", "bmw320i")
# the kinematic core (its compiled C kernel), the dynamic core eager and compiled (`compile_steps`)
VARIANTS = ("kinematic", "dynamic", "dynamic compiled")


def best_of(repeats: int, run) -> float:
    """The shortest wall time of `repeats` calls of `run`."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cars", default=",".join(CARS))
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="runs/dynamic_speed", help="the test sets' simulation cache")
    parser.add_argument("--quick", action="store_true", help="the 1:10 car, quick.py's test set, S = 4, once")
    args = parser.parse_args()
    if args.quick:
        args.cars, args.samples, args.repeats = "f1tenth", 4, 1
    cars = [c for c in args.cars.split(",") if c]
    if not cars or set(cars) - set(CARS):
        parser.error(f"--cars: a subset of {', '.join(CARS)}")
    if args.samples < 2 or args.repeats < 1:
        parser.error("--samples: at least 2; --repeats: at least 1")
    rows = []
    for car in cars:
        cfg = load_config(CONFIGS / f"dynamics_{car}.toml")
        if args.quick:
            cfg = shrink(cfg, Path(args.out).resolve())
        else:
            data = cfg.model_dump(mode="json")
            data["output_dir"] = str(Path(args.out).resolve())
            cfg = type(cfg).model_validate(data)
        test = Campaign(cfg, Path(args.out) / car).evaluation.test_set
        logs = list(test.logs)
        vehicle = simulator.build_vehicle(cfg.vehicle.spec, {})
        replays = [simulator.Replay(f"replay{i}", t["throttle"].to_numpy(np.float64),
                                    t["steering"].to_numpy(np.float64))
                   for i, t in enumerate(logs)]  # fmt: skip
        truth = best_of(args.repeats, partial(simulator.collect, replays, noise=None, vehicle=vehicle))
        steps = sum(len(t) for t in logs)
        for core in VARIANTS:
            model = build_model(cfg.model.model_copy(update={"core": core.split()[0]}), seed=0)
            model.set_scalers(test.x, test.y_clean)
            run = partial(free_runs, model, logs, rate_hz=30.0, n_samples=args.samples)
            first = float("nan")
            if core.endswith("compiled"):
                model.compile_steps()
                first = best_of(1, run)  # compiles (torch's on-disk cache shortens a later process's)
            wall = best_of(args.repeats, run)
            rows.append({"car": car, "core": core, "maneuvers": len(logs), "truth s": round(truth, 2),
                         "free runs s": round(wall, 2), "first call s": round(first, 1),
                         "truth / free runs": round(truth / wall, 1),
                         "sample-steps/s": f"{args.samples * steps / wall:.3g}"})  # fmt: skip
            print(f"{car} {core}: free runs x{truth / wall:.3g} the truth's speed,"
                  f" {args.samples * steps / wall:.3g} sample-steps/s", flush=True)
    print("\n## The physics kind's free runs beside the truth simulator (best of", args.repeats, "each)")
    print(pd.DataFrame(rows).to_string(index=False))


if __name__ == "__main__":
    main()
