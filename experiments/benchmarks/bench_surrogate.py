"""Surrogate versus MuJoCo: speed on 256 maneuvers of 90 s, and accuracy of both model variants.

1. Trains the static map (controls -> rates) and the Markov-state variant (controls + previous rates
   -> rates) on one set of simulated maneuvers of all five kinds.
2. Simulates 256 other maneuvers of 90 s at 30 Hz with MuJoCo on all cores, and runs the surrogate
   (S = 32 sampled trajectories, uncertainty included) on the same control sequences, in one run;
   prints both wall times and their ratio (target: surrogate >= 100x faster).
3. Prints the accuracy table of both variants per maneuver kind: RMSE of v and omega, position
   error at 10 s, 30 s and the end, and the fraction of ground-truth steps inside the 95% band.

Usage: python experiments/benchmarks/bench_surrogate.py [--maneuvers 256] [--samples 32] [--epochs 120]
       [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import pandas as pd

import simulator
from activelearn.collection import arrays, training_rows
from activelearn.config import DataConfig, ModelConfig, TrainingConfig
from activelearn.models import build_model
from activelearn.surrogate import simulate, track_metrics
from activelearn.training import fit
from simulator import Maneuver

KINDS = ("straight", "skidpad", "fishhook", "slalom", "eight")


def maneuver_set(n: int, seed: int, duration: float = 90.0) -> list[Maneuver]:
    """n maneuvers cycling through the five kinds at random forward operating points."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        kind = KINDS[i % len(KINDS)]
        throttle = float(np.round(rng.uniform(0.2, 1.0), 3))
        steering = 0.0 if kind == "straight" else float(np.round(rng.uniform(0.1, 0.5236), 4))
        if kind == "fishhook":
            steering = simulator.STEERING_LIMIT
        out.append(Maneuver(kind, throttle, steering, str(rng.choice(["ccw", "cw"])), duration))
    return out


def train(log: pd.DataFrame, inputs: str, epochs: int, seed: int):
    """Fit the default hybrid on a log, as a static map or a Markov-state model."""
    data = DataConfig(stride=3, skip_seconds=0.0, inputs=inputs)  # keep the transients: Markov needs them
    rows = pd.concat([training_rows(part, data) for _, part in log.groupby("run_id", sort=False)])
    x, y = arrays(rows, data)
    model = build_model(ModelConfig(n_inputs=x.shape[1]))
    started = time.perf_counter()
    fit(
        model,
        x,
        y,
        TrainingConfig(lr=3e-3, epochs=epochs, batch_size=256, patience=None, lr_schedule="cosine"),
        seed=seed,
    )
    return model, time.perf_counter() - started, len(x)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maneuvers", type=int, default=256)
    parser.add_argument("--train-maneuvers", type=int, default=60)
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--epochs", type=int, default=120)
    parser.add_argument("--repeats", type=int, default=5, help="timed surrogate calls per variant")
    args = parser.parse_args()
    threads = os.cpu_count() or 1

    train_log = simulator.collect(maneuver_set(args.train_maneuvers, seed=1), seed=1)
    models = {}
    for name, inputs in (("static", "controls"), ("markov", "controls+rates")):
        model, seconds, rows = train(train_log, inputs, args.epochs, seed=0)
        models[name] = model
        print(f"trained {name} model on {rows} rows of {args.train_maneuvers} maneuvers in {seconds:.1f} s")

    test = maneuver_set(args.maneuvers, seed=2)
    started = time.perf_counter()
    log = simulator.collect(test, seed=3, threads=threads)
    sim_seconds = time.perf_counter() - started
    truth = [part.reset_index(drop=True) for _, part in log.groupby("run_id", sort=False)]
    controls = [t[["throttle", "steering"]].to_numpy() for t in truth]
    initial = np.array([[t["speed"].iloc[0], t["angZ"].iloc[0]] for t in truth])

    timings: dict[str, list[float]] = {}
    rollouts = {}
    # The static map twice: its compiled kernel ("auto" where a C compiler built it) and the
    # NumPy/torch reference that draws the same numbers. The Markov variant has one path.
    runs = (("static", "auto"), ("static", "reference"), ("markov", "auto"))
    for name, backend in runs:
        model, label = models[name], name if backend == "auto" else f"{name}/{backend}"
        call = dict(n_samples=args.samples, backend=backend)
        simulate(model, controls[:4], initial_rates=initial[:4], **call)  # warm-up
        timings[label] = []
        for _ in range(args.repeats):
            rollouts.pop(label, None)  # free the last result first: the timed call allocates afresh
            started = time.perf_counter()
            rollouts[label] = simulate(model, controls, initial_rates=initial, **call)
            timings[label].append(time.perf_counter() - started)
    del rollouts["static/reference"]  # same numbers as "static": one accuracy row is enough

    steps = sum(len(c) for c in controls)
    print(
        f"\n{args.maneuvers} maneuvers x 90 s at 30 Hz ({steps} steps), {threads} threads, "
        f"S = {args.samples}; surrogate: {args.repeats} timed calls after a small warm-up "
        "(first / median / min)"
    )
    print(f"  MuJoCo                       {sim_seconds:8.2f} s")
    for name, runs in timings.items():
        first, median, best = runs[0], float(np.median(runs)), min(runs)
        print(
            f"  surrogate ({name:16s}) {first:6.2f} / {median:.2f} / {best:.2f} s   speed-up (median)"
            f" x{sim_seconds / median:6.1f}   (first call x{sim_seconds / first:.1f})"
        )

    rows = []
    for name, rollout in rollouts.items():
        for i, (m, t) in enumerate(zip(test, truth, strict=True)):
            tm = track_metrics(
                rollout, i, {c: t[c].to_numpy() for c in ("speed", "angZ", "posX", "posY", "yaw")}
            )
            marks = list(tm.position_error.values())
            rows.append(
                {
                    "variant": name,
                    "kind": m.kind,
                    "rmse_v": tm.rmse_v,
                    "rmse_w": tm.rmse_w,
                    "pos_10s": marks[0],
                    "pos_30s": marks[1],
                    "pos_end": marks[-1],
                    "cover_v": tm.coverage_v,
                    "cover_w": tm.coverage_w,
                }
            )
    table = pd.DataFrame(rows).groupby(["kind", "variant"]).mean().reindex(KINDS, level=0)
    pd.set_option("display.width", 160)
    print("\naccuracy against MuJoCo (means over maneuvers of each kind; positions in m, rates in SI):")
    print(table.to_string(float_format="%.4f"))


if __name__ == "__main__":
    main()
