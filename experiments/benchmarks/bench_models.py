"""Model benchmark: training speed, prediction speed, and hybrid vs ensemble calibration.

    python experiments/benchmarks/bench_models.py [--quick] [--skip-naive] [--seeds 0 1] [--rounds 3]
                                                  [--sections 1234]

1. Where the training time goes: the reference arrangement (V8-D32-D32-D8-V, 60,000 rows, batch 32)
   trained by a straightforward PyTorch loop, then with each fix applied in turn.
2. Training time per epoch on 60,000 rows for every model kind, batch 32 and 256, eager and compiled.
3. `predict` time with S = 32 posterior samples over 2,700 inputs (one 90-s maneuver at 30 Hz), compiled
   kernel and torch; then paired rounds of MuJoCo simulating one such maneuver and `predict`, with ratios.
4. Hybrid (default) vs deep ensemble vs the reference hybrid: accuracy and the epistemic calibration
   diagnostic on held-out operating points, before and after recalibration.

The machine is shared, so every timing is the median of repeats; treat differences below ~15% as noise.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.distributions import Normal, kl_divergence
from torch.utils.data import DataLoader, TensorDataset

from activelearn.config import ModelConfig, TrainingConfig
from activelearn.numerics import synthetic as syn
from activelearn.numerics.models import build_model
from activelearn.numerics.threads import intra_op_threads
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from activelearn.numerics.uncertainty import coverage, epistemic_diagnostic, recalibrate_epistemic

N_ROWS = 60_000
QUICK = False  # `--quick`: 2,000 rows, eager only, two epochs: checks every section runs (not a measurement)
MANEUVER_ROWS = 2_700  # 90 s at 30 Hz


# ----------------------------------------------------------------------------- naive baseline
class _NaiveVariational(nn.Module):
    """A direct port of a TFP DenseVariational layer: distribution objects, one weight draw per batch."""

    def __init__(self, n_in: int, n_out: int) -> None:
        super().__init__()
        self.w_mu = nn.Parameter(torch.empty(n_in, n_out).uniform_(-(n_in**-0.5), n_in**-0.5))
        self.w_rho = nn.Parameter(torch.full((n_in, n_out), -4.6))
        self.b_mu = nn.Parameter(torch.zeros(n_out))
        self.b_rho = nn.Parameter(torch.full((n_out,), -4.6))
        self.kl = torch.zeros(())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        qw = Normal(self.w_mu, F.softplus(self.w_rho))
        qb = Normal(self.b_mu, F.softplus(self.b_rho))
        pw = Normal(torch.zeros_like(self.w_mu), torch.ones_like(self.w_mu))
        pb = Normal(torch.zeros_like(self.b_mu), torch.ones_like(self.b_mu))
        self.kl = kl_divergence(qw, pw).sum() + kl_divergence(qb, pb).sum()
        return x @ qw.rsample() + qb.rsample()


class _NaiveHybrid(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.v1 = _NaiveVariational(2, 8)
        self.dense = nn.Sequential(
            nn.Linear(8, 32), nn.ReLU(), nn.Linear(32, 32), nn.ReLU(), nn.Linear(32, 8), nn.ReLU()
        )
        self.v2 = _NaiveVariational(8, 4)

    def forward(self, x: torch.Tensor) -> Normal:
        h = self.v2(self.dense(torch.sigmoid(self.v1(x))))
        return Normal(h[:, :2], F.softplus(h[:, 2:]) + 1e-3)


def _naive_epoch(x: torch.Tensor, y: torch.Tensor, *, dataloader: bool, batch: int = 32) -> float:
    """Seconds for one epoch of the straightforward loop (optionally with slicing instead of DataLoader)."""
    torch.manual_seed(0)
    model = _NaiveHybrid()
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    n = len(x)
    t0 = time.perf_counter()
    if dataloader:
        batches = DataLoader(TensorDataset(x, y), batch_size=batch, shuffle=True)
    else:
        perm = torch.randperm(n)
        xs, ys = x[perm], y[perm]
        batches = ((xs[i : i + batch], ys[i : i + batch]) for i in range(0, n, batch))
    total = 0.0
    for xb, yb in batches:
        dist = model(xb)
        loss = -dist.log_prob(yb).sum(-1).mean() + (model.v1.kl + model.v2.kl) / n
        opt.zero_grad()
        loss.backward()
        opt.step()
        total += loss.item()
    return time.perf_counter() - t0


# ----------------------------------------------------------------------------- helpers
def _median_epoch(
    kind: str, arch: str, batch: int, compiled: bool, threads: int | None, epochs: int
) -> tuple[float, float]:
    """Median seconds per epoch after the first, and the first epoch (includes any compile)."""
    x, y = syn.uniform_rows(N_ROWS, steering=(-syn.STEER_MAX, syn.STEER_MAX), seed=0)
    model = build_model(ModelConfig(kind=kind, arch=arch))
    cfg = TrainingConfig(
        epochs=epochs, batch_size=batch, patience=None, compile=compiled, num_threads=threads
    )
    h = fit(model, TrainingData(x, y), cfg)
    return statistics.median(h.epoch_time[1:]), h.epoch_time[0]


def _median_time(fn: Callable[[], object], repeats: int = 7) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _row(cells: list[object]) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


# ----------------------------------------------------------------------------- sections
def where_time_goes(epochs: int, skip_naive: bool) -> None:
    """Section 1: the reference arrangement at batch 32, one fix at a time."""
    print("\n## 1. Where the time goes (reference V8-D32-D32-D8-V, 60,000 rows, batch 32)\n")
    print(_row(["variant", "s/epoch"]))
    print(_row(["---", "---"]))
    x, y = syn.uniform_rows(N_ROWS, steering=(-syn.STEER_MAX, syn.STEER_MAX), seed=0)
    xt, yt = torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(y, dtype=torch.float32)
    old = torch.get_num_threads()
    if not skip_naive:
        t = statistics.median(_naive_epoch(xt, yt, dataloader=True) for _ in range(2))
        print(
            _row(
                ["naive: DataLoader, torch.distributions, Adam (for-loop), loss.item() per step", f"{t:.2f}"]
            )
        )
        t = statistics.median(_naive_epoch(xt, yt, dataloader=False) for _ in range(2))
        print(_row(["+ pre-shuffled tensors, index slicing instead of DataLoader", f"{t:.2f}"]))
        torch.set_num_threads(1)
        t = statistics.median(_naive_epoch(xt, yt, dataloader=False) for _ in range(2))
        torch.set_num_threads(old)
        print(_row(["+ torch.set_num_threads(1)", f"{t:.2f}"]))
    t, _ = _median_epoch("hybrid", "reference", 32, False, 1, epochs)
    print(_row(["activelearn eager: + addmm/local reparam., closed-form KL tensors, fused Adam", f"{t:.2f}"]))
    if QUICK:
        print(_row(["activelearn compiled: skipped (--quick)", "-"]))
        return
    t, first = _median_epoch("hybrid", "reference", 32, True, 1, epochs)
    print(
        _row(
            [
                f"activelearn compiled: whole step in one graph (first epoch incl. compile {first:.1f} s)",
                f"{t:.2f}",
            ]
        )
    )
    print("\nReference study (TFP, graph mode, batch 32): ~1.3 s/epoch; target ~0.4 s/epoch.")


def training_speed(epochs: int, quick: bool) -> None:
    """Section 2: every kind, batch 32 and 256, eager and compiled."""
    print("\n## 2. Training time per epoch, 60,000 rows (s/epoch; compile = one-off first-epoch cost)\n")
    print(_row(["model", "arch", "eager b32", "eager b256", "compiled b32", "compiled b256", "compile s"]))
    print(_row(["---"] * 7))
    kinds = [("hybrid", "default"), ("hybrid", "reference"), ("pbnn", "default"), ("pnn", "default"),
             ("bnn", "default"), ("dnn", "default"), ("ensemble", "default")]  # fmt: skip
    if quick:
        kinds = kinds[:2]
    for kind, arch in kinds:
        cells: list[object] = [kind, arch]
        first_compile = 0.0
        for compiled in (False,) if QUICK else (False, True):
            for batch in (32, 256):
                t, first = _median_epoch(kind, arch, batch, compiled, 1, epochs)
                cells.append(f"{t:.3f}")
                if compiled:
                    first_compile = max(first_compile, first - t)
        cells += ["-", "-", "-"] if QUICK else [f"{first_compile:.1f}"]
        print(_row(cells), flush=True)


def predict_speed(quick: bool) -> None:
    """Section 3: predict(S=32) on 2,700 distinct inputs per kind, compiled kernel and torch."""
    all_threads = torch.get_num_threads()
    print(f"\n## 3. predict(S=32) over {MANEUVER_ROWS} distinct inputs (one 90-s maneuver at 30 Hz)\n")
    print("Median of 51 calls. Distinct random inputs are the worst case: a maneuver's repeated control")
    print("rows would be cheaper, but fishhooks and slaloms change steering at almost every step.")
    print("native = the compiled tile kernel (activelearn/numerics/native/network.c), reference = torch.\n")
    threads = sorted({1, all_threads})
    backends = ("native", "reference")
    cells = [f"{backend} ms, {n} thread{'s' * (n > 1)}" for backend in backends for n in threads]
    print(_row(["model", *cells]))
    print(_row(["---"] * (len(cells) + 1)))
    x, y = syn.uniform_rows(2000, seed=0)
    pts = syn.random_points(MANEUVER_ROWS, steering=(-syn.STEER_MAX, syn.STEER_MAX), seed=1)
    kinds = ["hybrid", "pbnn", "pnn", "bnn", "dnn", "ensemble"]
    hybrid = None
    for kind in kinds[:2] if quick else kinds:
        model = build_model(ModelConfig(kind=kind))
        fit(model, TrainingData(x, y), TrainingConfig(epochs=1, patience=None))
        hybrid = model if kind == "hybrid" else hybrid
        times = []
        for backend in ("native", "reference"):
            for n in threads:
                with intra_op_threads(n):
                    call = lambda m=model, b=backend: m.predict(pts, 32, backend=b)  # noqa: E731
                    times.append(f"{1000 * _median_time(call, repeats=51):.2f}")
        print(_row([kind, *times]))
    xt = torch.as_tensor(pts, dtype=torch.float32)
    with torch.no_grad(), intra_op_threads(1):
        t_mean = _median_time(lambda m=hybrid, xt=xt: m(xt), repeats=51)
    label = "hybrid posterior-mean network only (torch forward, S=1, 1 thread)"
    print(_row([label, f"{1000 * t_mean:.2f}"]))


def simulator_ratio(rounds: int) -> None:
    """MuJoCo time for one 90-s maneuver vs the default hybrid's predict, in paired rounds."""
    try:
        import simulator
    except Exception as exc:  # the simulator is optional for this benchmark
        print(f"\nsimulator unavailable ({type(exc).__name__}: {exc}); no MuJoCo comparison")
        return
    all_threads = torch.get_num_threads()
    threads = sorted({1, all_threads})
    x, y = syn.uniform_rows(2000, seed=0)
    pts = syn.random_points(MANEUVER_ROWS, steering=(-syn.STEER_MAX, syn.STEER_MAX), seed=1)
    model = build_model(ModelConfig())
    fit(model, TrainingData(x, y), TrainingConfig(epochs=1, patience=None))
    maneuvers = [simulator.Maneuver(kind, 0.6, steering, "ccw", 90.0)
                 for kind, steering in (("skidpad", 0.3142), ("slalom", 0.4))]  # fmt: skip
    print(f"\n## 3b. Against MuJoCo: one 90-s maneuver ({MANEUVER_ROWS} steps at 30 Hz) vs predict(S=32)\n")
    print("One maneuver runs on one MuJoCo thread. Each round times MuJoCo (median of 3 runs of a skidpad")
    print("and of a slalom; the faster kind counts) and then predict (median of 51 calls) back to back:")
    print("this machine's speed drifts within minutes. Goal: predict >= 100x faster.\n")
    heads = [f"predict {n} thr ms" for n in threads] + [f"ratio {n} thr" for n in threads]
    print(_row(["round", "MuJoCo s", *heads]))
    print(_row(["---"] * (2 + 2 * len(threads))))
    ratios: dict[int, list[float]] = {n: [] for n in threads}
    for r in range(rounds):
        mujoco = min(_median_time(lambda m=m: simulator.collect(m, threads=1), repeats=3) for m in maneuvers)
        times = {}
        for n in threads:
            with intra_op_threads(n):
                times[n] = _median_time(lambda: model.predict(pts, 32), repeats=51)
            ratios[n].append(mujoco / times[n])
        cells = [f"{1000 * times[n]:.2f}" for n in threads] + [f"{ratios[n][-1]:.0f}x" for n in threads]
        print(_row([r + 1, f"{mujoco:.3f}", *cells]), flush=True)
    medians = ", ".join(f"{n} thread(s) {np.median(v):.0f}x" for n, v in ratios.items())
    print(f"\nmedian ratio over rounds: {medians}")


def calibration(seeds: list[int]) -> None:
    """Section 4: hybrid vs ensemble on the calibration task (mean ± std over seeds)."""
    print("\n## 4. Accuracy and epistemic calibration on held-out operating points (noise-free targets)\n")
    print("40 operating points x 60 noisy rows; recalibration fitted on 30 other points; 200 test points.\n")
    keys = [
        "rmse",
        "coverage95",
        "z_before",
        "ratio_before",
        "spearman",
        "scale",
        "z_after",
        "ratio_after",
        "fit_s",
    ]
    print(_row(["model", *keys]))
    print(_row(["---"] * (len(keys) + 1)))
    variants = [
        ("hybrid default (kl_count=sqrt)", {}, {}),
        ("hybrid default, kl_count=rows", {}, {"kl_count": "rows"}),
        ("hybrid reference", {"arch": "reference"}, {}),
        ("deep ensemble (5 PNNs)", {"kind": "ensemble"}, {}),
    ]
    for label, mkw, tkw in variants[:2] if QUICK else variants:
        tkw = {**tkw, "epochs": 2} if QUICK else tkw
        vals: dict[str, list[float]] = {k: [] for k in keys}
        for seed in seeds:
            d = syn.calibration_task(seed)
            model = build_model(ModelConfig(**mkw))
            t0 = time.perf_counter()
            fit(
                model,
                TrainingData(d["x"], d["y"], groups=d["groups"]),
                TrainingConfig(**tkw),
                validation=TrainingData(d["val_x"], d["val_y"]),
                seed=seed,
            )  # fmt: skip
            vals["fit_s"].append(time.perf_counter() - t0)
            before = epistemic_diagnostic(d["test_truth"], model.predict(d["test_points"], 64, seed=seed))
            noisy_test, noisy_y, _ = syn.repeated_rows(d["test_points"], 5, seed=seed + 3)
            vals["coverage95"].append(coverage(noisy_y, model.predict(noisy_test, 64, seed=seed)))
            scale = recalibrate_epistemic(model, d["cal_points"], d["cal_truth"], noise_free=True, seed=seed)
            after = epistemic_diagnostic(d["test_truth"], model.predict(d["test_points"], 64, seed=seed))
            for k, v in (
                ("rmse", before["rmse"]),
                ("z_before", before["z_spread"]),
                ("ratio_before", before["std_to_rmse"]),
                ("spearman", before["spearman"]),
                ("scale", scale),
                ("z_after", after["z_spread"]),
                ("ratio_after", after["std_to_rmse"]),
            ):
                vals[k].append(v)  # fmt: skip
        cells = [f"{np.mean(v):.3g}" + (f" ± {np.std(v):.2g}" if len(v) > 1 else "") for v in vals.values()]
        print(_row([label, *cells]), flush=True)


def main() -> None:
    """Run every section and print markdown tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes: checks every section still runs (tests/test_benchmarks.py)")
    parser.add_argument("--skip-naive", action="store_true", help="skip the slow naive baseline")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--rounds", type=int, default=3, help="paired MuJoCo/predict rounds (section 3b)")
    parser.add_argument(
        "--sections", default="1234", help="which sections to run, e.g. 3 for predict and MuJoCo only"
    )
    args = parser.parse_args()
    if args.quick:
        global N_ROWS, QUICK
        N_ROWS, QUICK = 2_000, True
        args.skip_naive, args.rounds = True, 1
    epochs = 2 if args.quick else 3
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads available")
    if "1" in args.sections:
        where_time_goes(epochs, args.skip_naive)
    if "2" in args.sections:
        training_speed(epochs, args.quick)
    if "3" in args.sections:
        predict_speed(args.quick)
        simulator_ratio(args.rounds)
    if "4" in args.sections:
        calibration(args.seeds[:1] if args.quick else args.seeds)


if __name__ == "__main__":
    main()
