"""The physics kind's free runs against each car's truth simulator: speed, side by side in one run.

For each fast car (`--cars`), the test maneuvers of its `dynamics_<car>.toml` (their commands, 30 s
at 30 Hz) are simulated by the truth (MuJoCo and the magic-formula tyres, `simulator.collect`, all
cores, no noise) and free-run by the physics kind with each core (an untrained model: the time does
not depend on the weights), S = `--samples` sampled trajectories each, as a campaign's evaluation
runs them; the dynamic core's recurrence in torch eagerly and compiled (torch.compile, as campaigns
that train windows ran it before the C kernel; its first call, which compiles, timed apart) and in C
(dynamic_rollout.c, what campaigns run now): bare; "widened", the draws' spread widened (epistemic
scale 4), which steps every draw twice (its own step and the step from the draws' mean past); and as
a calibrated campaign model runs it, widened and the model discrepancy in the pose fan. Prints per car
and core: wall seconds of each (best of `--repeats`), their ratio, the absolute rate in sample-steps
per second (S × maneuvers × steps / wall), and where the C variants' time goes (the kernel call, the
correction's network, the rest: Python, torch, the logs' columns). Within the kernel: the widened
run's extra time is one more pass of substeps (the substeps' own rate, in lane-substeps per second,
and their share of the bare kernel), the calibrated run's extra the discrepancy's second pose; the
rest of the bare kernel is per-step bookkeeping, the noise and the pose. Then the
identification's cost: one evaluation of its residuals (the core's rates along every 3-s window of
the test logs, for 6 parameter sets as a finite-difference Jacobian asks) by NumPy and by the C
kernel, side by side.

Usage: python experiments/benchmarks/bench_dynamic_speed.py [--cars f1tenth,bmw320i] [--samples 32]
       [--repeats 3] [--out DIR] [--quick]
`--quick` (what the test runs): the 1:10 car, quick.py's shrunk test set, S = 4, one repeat, and no
compiled variant (a cold torch.compile takes longer than the rest of the quick run; compiled and eager
steps agree, tests/test_dynamic_physics.py).
"""

from __future__ import annotations

import argparse
import time
from contextlib import contextmanager
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from quick import shrink

import simulator
from activelearn.config import load_config
from activelearn.loop.campaign import Campaign
from activelearn.names import CONTROLS, RATES
from activelearn.numerics import native
from activelearn.numerics.diagnostics import free_runs
from activelearn.numerics.models import build_model
from activelearn.numerics.models.dynamic_physics import IDENTIFY_HORIZON
from activelearn.numerics.models.dynamic_scales import scaled
from activelearn.numerics.models.dynamic_track import DynamicCar, quasi_static_lateral, rate_runs

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CARS = ("f1tenth", "bmw320i")
# the kinematic core (its compiled C kernel), the dynamic core in torch eager and compiled
# (`compile_steps`), and in C (dynamic_rollout.c), bare and as a calibrated campaign model runs it
VARIANTS = (
    "kinematic", "dynamic", "dynamic compiled", "dynamic C", "dynamic C, widened", "dynamic C, calibrated"
)
WIDENED_SCALE = 4.0  # the draws' spread widened (epistemic scale): every draw is stepped twice
CALIBRATED_DISCREPANCY = (0.12, 0.027)  # m/s, rad/s: the 1:10 car's cross-validated misfit after 4 signals
TIMED = {"kernel": (native, "dynamic_free_runs"), "network": (native.NetworkKernel, "forward")}


@contextmanager
def timed_calls(spent: dict[str, float]):
    """Adds the wall seconds spent in each of `TIMED`'s functions to `spent` while the block runs."""
    originals = {name: getattr(owner, attribute) for name, (owner, attribute) in TIMED.items()}

    def timing(name, function):
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                spent[name] = spent.get(name, 0.0) + time.perf_counter() - start

        return wrapper

    for name, (owner, attribute) in TIMED.items():
        setattr(owner, attribute, timing(name, originals[name]))
    try:
        yield spent
    finally:
        for name, (owner, attribute) in TIMED.items():
            setattr(owner, attribute, originals[name])


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
    parser.add_argument("--quick", action="store_true", help="the 1:10 car at quick sizes, not compiled")
    args = parser.parse_args()
    if args.quick:
        args.cars, args.samples, args.repeats = "f1tenth", 4, 1
    cars = [c for c in args.cars.split(",") if c]
    if not cars or set(cars) - set(CARS):
        parser.error(f"--cars: a subset of {', '.join(CARS)}")
    if args.samples < 2 or args.repeats < 1:
        parser.error("--samples: at least 2; --repeats: at least 1")
    variants = [v for v in VARIANTS if not (args.quick and v.endswith("compiled"))]
    rows, identification, split = [], [], []
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
        kernel_walls, car_split = {}, {}
        for core in variants:
            update = {"core": core.split()[0]}
            if core.endswith("calibrated"):  # the discrepancy carried, as the 1:10 configs do
                update["discrepancy"] = "identification"
            model = build_model(cfg.model.model_copy(update=update), seed=0)
            model.set_scalers(test.x, test.y_clean)
            if core.endswith(("widened", "calibrated")):
                model.epistemic_scale.fill_(WIDENED_SCALE)
            if core.endswith("calibrated"):
                model.discrepancy.copy_(torch.tensor(CALIBRATED_DISCREPANCY))
            backend = "reference" if core in ("dynamic", "dynamic compiled") else "auto"
            run = partial(free_runs, model, logs, rate_hz=30.0, n_samples=args.samples, backend=backend)
            first = float("nan")
            if core.endswith("compiled"):
                model.compile_steps()
                first = best_of(1, run)  # compiles (torch's on-disk cache shortens a later process's)
            wall = best_of(args.repeats, run)
            if core.startswith("dynamic C"):
                with timed_calls({}) as spent:
                    best = best_of(1, run)
                kernel, network = spent["kernel"], spent.get("network", 0.0)
                kernel_walls[core] = kernel
                car_split[core] = {"car": car, "core": core, "wall s": round(best, 3),
                                   "kernel s": round(kernel, 3), "correction network s": round(network, 3),
                                   "the rest s": round(best - kernel - network, 3)}  # fmt: skip
            rows.append({"car": car, "core": core, "maneuvers": len(logs), "truth s": round(truth, 2),
                         "free runs s": round(wall, 2), "first call s": round(first, 1),
                         "truth / free runs": round(truth / wall, 1),
                         "sample-steps/s": f"{args.samples * steps / wall:.3g}"})  # fmt: skip
            print(f"{car} {core}: free runs x{truth / wall:.3g} the truth's speed,"
                  f" {args.samples * steps / wall:.3g} sample-steps/s", flush=True)
        bare, widened = kernel_walls["dynamic C"], kernel_walls["dynamic C, widened"]
        lane_substeps = args.samples * steps * model.substeps
        extra = widened - bare  # one more pass of substeps
        car_split["dynamic C"]["substeps' share of the kernel"] = round(extra / bare, 2)
        car_split["dynamic C"]["substeps: lane-substeps/s"] = f"{lane_substeps / max(extra, 1e-9):.3g}"
        car_split["dynamic C, calibrated"]["discrepancy's pose s"] = round(
            kernel_walls["dynamic C, calibrated"] - widened, 3
        )
        split.extend(car_split.values())
        costs = identification_evaluation(DynamicCar.of(cfg.vehicle.spec), logs, args.repeats)
        identification.append({"car": car, "NumPy s": round(costs["reference"], 4),
                               "C s": round(costs["native"], 4),
                               "NumPy / C": round(costs["reference"] / costs["native"], 1)})  # fmt: skip
    print("\n## The physics kind's free runs beside the truth simulator (best of", args.repeats, "each)")
    print(pd.DataFrame(rows).to_string(index=False))
    print("\n## Where the C kernel's free runs spend their time (one call each)")
    print(pd.DataFrame(split).to_string(index=False))
    print("\n## One residual evaluation of the dynamic core's identification (6 parameter sets, every 3-s"
          " window of the test logs; best of", args.repeats, "each)")
    print(pd.DataFrame(identification).to_string(index=False))


if __name__ == "__main__":
    main()
