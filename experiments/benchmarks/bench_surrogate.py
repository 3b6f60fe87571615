"""Surrogate versus MuJoCo: speed on 256 maneuvers of 90 s, and free-run accuracy of every model kind.

1. Trains the static map (controls -> rates), the Markov-state variant (controls + previous rates
   -> rates), the delay-embedded history model and the recurrent (GRU trunk) model on one set of
   simulated maneuvers of all five kinds (`--models` picks).
2. Simulates 256 other maneuvers of 90 s at 30 Hz with MuJoCo on all cores, and runs the surrogate
   (S = 32 sampled trajectories, uncertainty included) on the same control sequences, in rounds of
   MuJoCo then surrogate; prints both wall times and their ratio per round (target: surrogate >= 100x
   faster).
3. Prints the accuracy table of every model per maneuver kind: RMSE of v and omega, position
   error at 10 s, 30 s and the end, and the fraction of ground-truth steps inside the 95% band
   (v, ω and the position), then each dynamic model's 30-s position error as a ratio of the
   static map's per kind.
4. With `--calibration-maneuvers N`, first fits each model's free-run fan scale on N more maneuvers
   (`surrogate.calibrate_fan`: split-conformal, held out from both sets); the table's coverage is
   then the calibrated fans', and `cover_raw` the uncalibrated ones' (scale 1).
5. `--train-seeds N` trains every variant N times (initial weights and batches from seeds 0..N-1, or
   S..S+N-1 with `--first-train-seed S`) and
   reports means over them, the ratios as mean ± s.e.m. over seeds: one training run's 30-s errors
   vary 2-3x between seeds, so a one-seed ratio is mostly that noise. `--ensemble K` adds a deep
   ensemble of K members of each kind (`<kind>/ens`). `--attribution` splits each variant's 30-s
   error: the path integrated from its mean rates, then with MuJoCo's true v or true ω in their place.

6. Drives every model over Nigel's whole control box for 60 s (`physics.control_box_sweep`: constants
   and steps, throttle 0 and reverse included, though training saw forward driving only) and prints
   how many sampled runs leave 1.5x the datasheet's speed or yaw-rate limit or are not finite.
   `physics` is the physics-structured model (`[model] kind = "physics"`).

Usage: python experiments/benchmarks/bench_surrogate.py [--maneuvers 256] [--samples 32] [--epochs 120]
       [--rounds 3] [--repeats 3] [--models static,markov,history,recurrent] [--horizons 10,30]
       [--calibration-maneuvers 10] [--train-seeds 3] [--ensemble 5] [--attribution]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

import simulator
from activelearn.config import DataConfig, ModelConfig, TrainingConfig
from activelearn.loop.collection import arrays, control_rate_logs, training_rows, training_windows
from activelearn.numerics.diagnostics import calibrate_fan, relative_pose, track_metrics
from activelearn.numerics.models import build_model
from activelearn.numerics.models.physics import control_box_sweep, runs_out_of_bounds
from activelearn.numerics.surrogate import path_from_rates, simulate
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from simulator import Maneuver
from simulator.datasheet import LOG_RATE_HZ

KINDS = ("straight", "skidpad", "fishhook", "slalom", "eight")
# Every model kind the surrogate runs: its data inputs and model settings.
MODELS: dict[str, tuple[dict, dict]] = {
    "static": ({"inputs": "controls"}, {}),
    "markov": ({"inputs": "controls+rates"}, {}),
    "history": ({"inputs": "history", "history": 4, "history_step": 3}, {}),
    "recurrent": (
        {"inputs": "history", "history": 4, "history_step": 3},
        {"kind": "recurrent", "arch": "D32-V16-V", "hidden_size": 32},
    ),
    # Nigel's single track (identified on the training logs) + its default bounded correction
    "physics": (
        {"inputs": "history", "history": 4, "history_step": 3},
        {"kind": "physics", "arch": "D32-D32-V16-V", "activation": "softplus"},
    ),
    # the same with the correction on the control alone, as dynamics.toml sets it: free runs computed whole
    # (physics_rollout.c)
    "physics-control": (
        {"inputs": "history", "history": 4, "history_step": 3},
        {"kind": "physics", "arch": "D32-D32-V16-V", "activation": "softplus",
         "correction_inputs": "control"},
    ),
    # and mirror-symmetric: the correction reads (throttle, steering²), its yaw residual times the steering
    "physics-mirror": (
        {"inputs": "history", "history": 4, "history_step": 3},
        {"kind": "physics", "arch": "D32-D32-V16-V", "activation": "softplus",
         "correction_inputs": "control", "correction_symmetry": "mirror"},
    ),
}


# Kinds with no deep-ensemble or kinematic-feature form here (the GRU's tokens, the physics kinds' own)
NO_ENSEMBLE = ("recurrent", "physics", "physics-control", "physics-mirror")


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


def train(
    log: pd.DataFrame, name: str, epochs: int, seed: int, horizon: int = 0, ensemble: int = 0,
    kinematic: bool = False,
):  # fmt: skip
    """Fit one model kind of `MODELS` on a log (dynamic models: with `horizon`-step windows if > 0).

    `seed` draws the initial weights and the batches; `ensemble` > 0 makes it a deep ensemble of that
    many members (the kind's inputs, the default member network); `kinematic` adds the kinematic
    feature (`ModelConfig.kinematic_feature`).
    """
    data_knobs, model_knobs = MODELS[name]
    if ensemble:
        model_knobs = {**model_knobs, "kind": "ensemble", "ensemble_size": ensemble}
    if kinematic:
        model_knobs = {**model_knobs, "kinematic_feature": True}
    # keep the transients: dynamic models need them
    data = DataConfig(stride=3, skip_seconds=0.0, **data_knobs)
    rows = pd.concat([training_rows(part, data) for _, part in log.groupby("run_id", sort=False)])
    x, y = arrays(rows, data)
    model = build_model(
        ModelConfig(n_inputs=x.shape[1], history_step=data.history_step if data.inputs == "history" else 1,
                    **model_knobs),
        seed=seed,
    )  # fmt: skip
    frames = [part for _, part in log.groupby("run_id", sort=False)]
    windows = training_windows(frames, data, horizon) if horizon else None
    started = time.perf_counter()
    fit(
        model,
        TrainingData(x, y, windows=windows, logs=control_rate_logs(frames)),
        TrainingConfig(lr=3e-3, epochs=epochs, batch_size=256, patience=None, lr_schedule="cosine",
                       rollout_horizon=horizon),
        seed=seed,
    )  # fmt: skip
    return model, time.perf_counter() - started, len(x)


def attribution(rollout, index: int, truth: pd.DataFrame, lever_arm: float, at: float = 30.0) -> list[float]:
    """30-s position error of the path from the mean rates, then with the true v, then with the true ω."""
    n = int(rollout.lengths[index])
    k = min(round(at / rollout.dt), n - 1)
    mean_v, mean_w = rollout.mean_rates[index, :n, 0], rollout.mean_rates[index, :n, 1]
    true_v, true_w = truth["speed"].to_numpy()[:n], truth["angZ"].to_numpy()[:n]
    tx, ty, _ = relative_pose({c: truth[c].to_numpy() for c in ("posX", "posY", "yaw")}, n)
    out = []
    for v, w in ((mean_v, mean_w), (true_v, mean_w), (mean_v, true_w)):
        x, y, _ = path_from_rates(v, w, dt=rollout.dt, lever_arm=lever_arm)
        out.append(float(np.hypot(x[k] - tx[k], y[k] - ty[k])))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maneuvers", type=int, default=256)
    parser.add_argument("--train-maneuvers", type=int, default=60)
    parser.add_argument("--samples", type=int, default=32)
    parser.add_argument("--epochs", type=int, default=120)
    parser.add_argument("--rounds", type=int, default=3, help="rounds of MuJoCo then surrogate timings")
    parser.add_argument("--repeats", type=int, default=3, help="timed surrogate calls per variant and round")
    parser.add_argument("--models", default=",".join(MODELS), help="comma-separated model kinds to compare")
    parser.add_argument("--figure", type=Path, default=None, metavar="PNG",
                        help="draw one maneuver of each kind, every model side by side, here")
    parser.add_argument("--figure-variants", default="", metavar="LABEL,...",
                        help="only these variants in the figure (default: all)")
    parser.add_argument("--horizons", default="", metavar="H,H,...",
                        help="also train each dynamic model with multi-step windows of these lengths "
                             "(log steps), named <kind>+h<H>")
    parser.add_argument("--calibration-maneuvers", type=int, default=0, metavar="N",
                        help="fit each model's free-run fan scale on N more maneuvers (0: off)")
    parser.add_argument("--train-seeds", type=int, default=1, metavar="N",
                        help="train every variant from seeds 0..N-1 and average the accuracy over them")
    parser.add_argument("--first-train-seed", type=int, default=0, metavar="S",
                        help="training seeds S..S+N-1 (fresh seeds to confirm a choice made on others)")
    parser.add_argument("--ensemble", type=int, default=0, metavar="K",
                        help="also train each MLP kind as a deep ensemble of K members, named <kind>/ens")
    parser.add_argument("--kinematic", action="store_true",
                        help="also train every MLP variant with the kinematic feature, named <label>+kin")
    parser.add_argument("--variants", default="", metavar="LABEL,...",
                        help="train and compare only these variants (labels as printed, e.g. markov/ens+kin; "
                             "the static baseline always)")
    parser.add_argument("--attribution", action="store_true",
                        help="split the 30-s error: mean-rate path, with the true v, with the true ω")
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes: checks every part still runs (tests/test_benchmarks.py)")
    args = parser.parse_args()  # fmt: skip
    if args.quick:  # one maneuver of each kind, every model kind, two epochs, one timed call
        args.maneuvers, args.train_maneuvers, args.samples, args.epochs = len(KINDS), len(KINDS), 4, 2
        args.rounds, args.repeats = 1, 1
    length, sweep_seconds = (35.0, 5.0) if args.quick else (90.0, 60.0)  # maneuvers; control-box sweeps
    kinds = [m for m in args.models.split(",") if m]
    unknown = set(kinds) - set(MODELS)
    if unknown or "static" not in kinds:
        parser.error(f"--models: choose from {', '.join(MODELS)} (static, the baseline, included)")
    if args.train_seeds < 1:
        parser.error("--train-seeds: at least 1")
    if args.ensemble == 1 or args.ensemble < 0:
        parser.error("--ensemble: 0 (off) or at least 2 members")
    horizons = [int(h) for h in args.horizons.split(",") if h]
    # (label, kind, horizon, ensemble, kinematic): every kind as is, each dynamic kind once per
    # multi-step horizon, each MLP kind as a deep ensemble (the GRU trunk has no ensemble form), and
    # every MLP variant with the kinematic feature (the GRU's tokens have no room for it)
    variants = [(k, k, 0, 0, False) for k in kinds] + [
        (f"{k}+h{h}", k, h, 0, False) for h in horizons for k in kinds if k != "static"
    ]
    if args.ensemble:  # each MLP variant, multi-step ones included, also as an ensemble (<kind>/ens...)
        variants += [(label.replace(k, f"{k}/ens", 1), k, h, args.ensemble, False)
                     for label, k, h, _, _ in variants if k not in NO_ENSEMBLE]  # fmt: skip
    if args.kinematic:
        variants += [(f"{label}+kin", k, h, e, True)
                     for label, k, h, e, _ in variants if k not in NO_ENSEMBLE]  # fmt: skip
    if args.variants:
        wanted = {v for v in args.variants.split(",") if v} | {"static"}
        missing = wanted - {label for label, *_ in variants}
        if missing:
            parser.error(f"--variants: not built by these options: {', '.join(sorted(missing))}")
        variants = [v for v in variants if v[0] in wanted]
    names = [label for label, *_ in variants]
    shown = [v for v in args.figure_variants.split(",") if v] or names
    if set(shown) - set(names):
        parser.error(f"--figure-variants: not in this run: {', '.join(sorted(set(shown) - set(names)))}")
    if args.first_train_seed < 0:
        parser.error("--first-train-seed: at least 0")
    seeds = range(args.first_train_seed, args.first_train_seed + args.train_seeds)
    threads = os.cpu_count() or 1

    train_log = simulator.collect(maneuver_set(args.train_maneuvers, seed=1, duration=length), seed=1)
    models: dict[tuple[str, int], object] = {}
    for seed in seeds:
        for name, kind, horizon, ensemble, kinematic in variants:
            model, seconds, rows = train(train_log, kind, args.epochs, seed=seed, horizon=horizon,
                                         ensemble=ensemble, kinematic=kinematic)  # fmt: skip
            models[name, seed] = model
            print(f"trained {name} model (seed {seed}) on {rows} rows of {args.train_maneuvers} maneuvers "
                  f"in {seconds:.1f} s")  # fmt: skip

    if args.calibration_maneuvers > 0:
        held_out = simulator.collect(maneuver_set(args.calibration_maneuvers, seed=4), seed=4)
        held_out = [part.reset_index(drop=True) for _, part in held_out.groupby("run_id", sort=False)]
        for (name, seed), model in models.items():
            scale = calibrate_fan(model, held_out, n_samples=args.samples, rate_hz=LOG_RATE_HZ)
            print(f"free-run fan scale of {name} (seed {seed}): {scale:.2f} "
                  f"(on {len(held_out)} held-out maneuvers)")  # fmt: skip

    test = maneuver_set(args.maneuvers, seed=2, duration=length)
    # Rounds of (MuJoCo, then every surrogate variant): this machine's speed drifts by a quarter
    # within minutes, so each round's ratio pairs times taken back to back. Timed: the seed-0 models.
    runs = (("static", "auto"), ("static", "reference"), *((n, "auto") for n in names if n != "static"))
    labels = [name if backend == "auto" else f"{name}/{backend}" for name, backend in runs]
    sim_seconds: list[float] = []
    timings: dict[str, list[list[float]]] = {label: [] for label in labels}
    rollouts = {}
    for round_ in range(args.rounds):
        started = time.perf_counter()
        log = simulator.collect(test, seed=3, threads=threads)
        sim_seconds.append(time.perf_counter() - started)
        truth = [part.reset_index(drop=True) for _, part in log.groupby("run_id", sort=False)]
        controls = [t[["throttle", "steering"]].to_numpy() for t in truth]
        initial = np.array([[t["speed"].iloc[0], t["angZ"].iloc[0]] for t in truth])
        del log
        # The static map twice: its compiled kernel ("auto" where a C compiler built it) and the
        # NumPy/torch reference that draws the same numbers. The dynamic models have one path each.
        for (name, backend), label in zip(runs, labels, strict=True):
            call = dict(rate_hz=LOG_RATE_HZ, n_samples=args.samples, backend=backend)
            if round_ == 0:
                simulate(models[name, seeds[0]], controls[:4], initial_rates=initial[:4], **call)  # warm-up
            times = []
            for _ in range(args.repeats):
                rollouts.pop(label, None)  # free the last result first: the timed call allocates afresh
                started = time.perf_counter()
                rollouts[label] = simulate(models[name, seeds[0]], controls, initial_rates=initial, **call)
                times.append(time.perf_counter() - started)
            timings[label].append(times)
    del rollouts["static/reference"]  # same numbers as "static": one accuracy row is enough

    steps = sum(len(c) for c in controls)
    print(
        f"\n{args.maneuvers} maneuvers x {length:g} s at 30 Hz ({steps} steps), {threads} threads, "
        f"S = {args.samples}. {args.rounds} rounds of MuJoCo then {args.repeats} surrogate calls per "
        "variant;\na round's ratio is MuJoCo's time over the median call. 'first' is the run's first "
        "full-size call (after a small warm-up)."
    )
    print("  round  MuJoCo [s]" + "".join(f"  {label:>18s}" for label in labels))
    ratios: dict[str, list[float]] = {label: [] for label in labels}
    for r in range(args.rounds):
        cells = ""
        for label in labels:
            median = float(np.median(timings[label][r]))
            ratios[label].append(sim_seconds[r] / median)
            cells += f"  {median:6.2f} s x{ratios[label][-1]:6.1f}"
        print(f"  {r + 1:5d}  {sim_seconds[r]:10.2f}{cells}")
    print("  median ratio over rounds:" + "".join(f"  {k} x{np.median(v):.1f}" for k, v in ratios.items()))
    first = {label: timings[label][0][0] for label in labels}
    print("  first call:" + "".join(f"  {k} {v:.2f} s (x{sim_seconds[0] / v:.1f})" for k, v in first.items()))

    if args.figure is not None:
        from activelearn.plots import paths_figure, save_figure

        cases = [(f"{test[i].kind} {test[i].direction}", i) for i in range(len(KINDS))]
        save_figure(paths_figure({v: rollouts[v] for v in shown}, cases, truth), args.figure, dpi=100)
        print(f"figure: {args.figure}")
    rows = []
    for seed in seeds:
        for name in names:
            model = models[name, seed]
            call = dict(rate_hz=LOG_RATE_HZ, initial_rates=initial, n_samples=args.samples)
            rollout = rollouts[name] if seed == seeds[0] else simulate(model, controls, **call)
            # the same rollout with the uncalibrated fan, where calibration moved it
            raw = simulate(model, controls, fan_scale=1.0, **call) if args.calibration_maneuvers > 0 else None
            lever_arm = float(model.config.pose_lever_arm)
            for i, (m, t) in enumerate(zip(test, truth, strict=True)):
                columns = {c: t[c].to_numpy() for c in ("speed", "angZ", "posX", "posY", "yaw")}
                tm = track_metrics(rollout, i, columns)
                extra = {"cover_raw": track_metrics(raw, i, columns).coverage_position} if raw else {}
                if args.attribution:
                    extra.update(zip(("rates_30s", "true_v_30s", "true_w_30s"),
                                     attribution(rollout, i, t, lever_arm), strict=True))  # fmt: skip
                marks = list(tm.position_error.values())
                rows.append(
                    {
                        "seed": seed,
                        "variant": name,
                        "kind": m.kind,
                        "rmse_v": tm.rmse_v,
                        "rmse_w": tm.rmse_w,
                        "pos_10s": marks[0],
                        "pos_30s": marks[1],
                        "pos_end": marks[-1],
                        "cover_v": tm.coverage_v,
                        "cover_w": tm.coverage_w,
                        "cover_pos": tm.coverage_position,
                        **extra,
                    }
                )
        if seed == seeds[0]:
            rollouts.clear()  # the timed rollouts are scored: free them before the next seed's
    frame = pd.DataFrame(rows)
    table = frame.drop(columns="seed").groupby(["kind", "variant"]).mean().reindex(KINDS, level=0)
    pd.set_option("display.width", 180)
    over = f" and {args.train_seeds} training seeds" if args.train_seeds > 1 else ""
    print(f"\naccuracy against MuJoCo (means over maneuvers of each kind{over}; positions in m, rates in SI):"
          )  # fmt: skip
    print(table.to_string(float_format="%.4f"))
    if args.attribution:
        print("\nwhere the 30-s error comes from (m; paths integrated from the mean rates): rates_30s as the")
        print("model gives them, true_v_30s with MuJoCo's v in place of the model's, true_w_30s with its ω:")
        split = table[["rates_30s", "true_v_30s", "true_w_30s"]].unstack("variant")
        print(split.to_string(float_format="%.4f"))
    per_seed = frame.groupby(["seed", "kind", "variant"])["pos_30s"].mean().unstack("variant")
    baselines = ["static"] + (["static/ens"] if "static/ens" in names else [])
    for baseline in baselines:
        ratio = per_seed.div(per_seed[baseline], axis=0).drop(columns=[b for b in baselines])
        mean = ratio.groupby("kind").mean().reindex(KINDS)
        print(f"\n30-s position error as a ratio of the {baseline} map's (target for the best dynamic model:")
        over = f"; mean ± s.e.m. of the per-seed ratios over {len(seeds)} seeds" if len(seeds) > 1 else ""
        print(f"<= 0.5 on slalom and eight, <= 1 elsewhere){over}:")
        if args.train_seeds > 1:
            sem = ratio.groupby("kind").sem().reindex(KINDS)
            cells = mean.map(lambda v: f"{v:.3f}") + " ± " + sem.map(lambda v: f"{v:.3f}")
            print(cells.to_string())
        else:
            print(mean.to_string(float_format="%.3f"))
    # Trained on forward driving (the training set's throttles are 0.2-1.0), every model is driven over
    # the whole control box for 60 s: how many sampled runs are not finite or leave 1.5x the limits
    sweep = control_box_sweep(sweep_seconds)
    print(f"\nruns leaving 1.5x Nigel's speed or yaw-rate limit (or not finite) over the control box: "
          f"{len(sweep)} sweeps x S = {args.samples}, {sweep_seconds:g} s, per training seed")  # fmt: skip
    for name in names:
        counts = []
        for seed in seeds:
            model = models[name, seed]
            sweep_run = simulate(model, sweep, rate_hz=LOG_RATE_HZ, n_samples=args.samples, seed=0)
            counts.append(runs_out_of_bounds(sweep_run.v, sweep_run.w))
        print(f"  {name:24s} {' '.join(str(c) for c in counts)} of {len(sweep) * args.samples}")
    speed = {k: float(np.median(v)) for k, v in ratios.items()}
    print("\nspeed against MuJoCo (median over rounds):")
    for label, value in speed.items():
        print(f"  {label} x{value:.1f}")


if __name__ == "__main__":
    main()
