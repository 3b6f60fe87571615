"""The physics kind's free runs against each car's truth simulator: speed, side by side in one run.

For each fast car (`--cars`), the test maneuvers of its `dynamics_<car>.toml` (their commands, 30 s
at 30 Hz) are simulated by the truth (MuJoCo and the magic-formula tyres, `simulator.collect`, all
cores, no noise) and free-run by the physics kind with each core (an untrained model: the time does
not depend on the weights), S = `--samples` sampled trajectories each, as a campaign's evaluation
runs them; the dynamic core's recurrence in torch eagerly and compiled (torch.compile, as campaigns
that train windows ran it before the C kernel; its first call, which compiles, timed apart) and in C
(dynamic_rollout.c, what campaigns run now). Prints per car and core: wall seconds of each (best of
`--repeats`), their ratio, and the absolute rate in sample-steps per second (S × maneuvers × steps /
wall). Then the identification's cost: one evaluation of its residuals (the core's rates along every
3-s window of the test logs, for 6 parameter sets as a finite-difference Jacobian asks) by NumPy and
by the C kernel, side by side.

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
from activelearn.names import CONTROLS, RATES
from activelearn.numerics.diagnostics import free_runs
from activelearn.numerics.models import build_model
from activelearn.numerics.models.dynamic_physics import IDENTIFY_HORIZON
from activelearn.numerics.models.dynamic_track import DynamicCar, quasi_static_lateral, rate_runs, scaled

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CARS = ("f1tenth", "bmw320i")
# the kinematic core (its compiled C kernel), the dynamic core in torch eager and compiled
# (`compile_steps`), and in C (dynamic_rollout.c)
VARIANTS = ("kinematic", "dynamic", "dynamic compiled", "dynamic C")


def identification_evaluation(car: DynamicCar, logs: list, repeats: int) -> dict[str, float]:
    """Wall seconds of one residual evaluation of an identification (`identify_dynamic`'s free runs of
    every `IDENTIFY_HORIZON`-s window of `logs`, 6 parameter sets, the implicit step) by each backend."""
    dt, steps = 1.0 / 30.0, round(IDENTIFY_HORIZON * 30.0)
    controls, starts = [], []
    for t in logs:
        u, y = t[list(CONTROLS)].to_numpy(np.float64), t[list(RATES)].to_numpy(np.float64)
        for k in range(0, len(u) - steps, steps):
            controls.append(u[k : k + steps + 1])
            starts.append((y[k, 0], y[k, 1], u[max(k - 1, 0), 1]))
    controls, starts = np.stack(controls), np.array(starts)
    sets = scaled(car, 1.0 + 1e-5 * np.vstack([np.zeros(5), np.eye(5)]))  # a point and its 5 steps
    lateral = quasi_static_lateral(sets, starts[:, 0], starts[:, 1])
    start = np.stack(np.broadcast_arrays(starts[:, 0], lateral, starts[:, 1], starts[:, 2]), axis=-1)
    return {backend: best_of(repeats, partial(rate_runs, sets, controls, start, dt, True, backend))
            for backend in ("reference", "native")}  # fmt: skip


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
    rows, identification = [], []
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
            backend = "reference" if core in ("dynamic", "dynamic compiled") else "auto"
            run = partial(free_runs, model, logs, rate_hz=30.0, n_samples=args.samples, backend=backend)
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
        costs = identification_evaluation(DynamicCar.of(cfg.vehicle.spec), logs, args.repeats)
        identification.append({"car": car, "NumPy s": round(costs["reference"], 4),
                               "C s": round(costs["native"], 4),
                               "NumPy / C": round(costs["reference"] / costs["native"], 1)})  # fmt: skip
    print("\n## The physics kind's free runs beside the truth simulator (best of", args.repeats, "each)")
    print(pd.DataFrame(rows).to_string(index=False))
    print("\n## One residual evaluation of the dynamic core's identification (6 parameter sets, every 3-s"
          " window of the test logs; best of", args.repeats, "each)")
    print(pd.DataFrame(identification).to_string(index=False))


if __name__ == "__main__":
    main()
