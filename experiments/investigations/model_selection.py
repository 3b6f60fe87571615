"""Model-selection studies behind the defaults in activelearn/config/ (synthetic Ackermann data).

    python experiments/investigations/model_selection.py STUDY [--seeds 0 1], STUDY one of
        novelty     arrangement → 2-D novelty ratio
        gap         arrangement → 1-D gap/beyond ratio
        archfinal   finalists: calibration at defaults
        klsize      KL counting × data size
        levers      prior, init, tempering, training
        issuetests  values behind tests 1-3, 6, 7

novelty: train on forward throttle (0.2…1) × left steering (0…0.52); the novelty ratio is the mean
epistemic std on reverse-throttle × right-steering inputs over the mean std on the data box (per
output, then the mean and the min over outputs). RMSE is against the noise-free map on the data box.
gap: 1-D data on [-1, -0.3] ∪ [0.3, 1]; std in the gap and beyond the range over the std inside.
novelty/gap use 150 epochs at lr 3e-3 (no early stopping).

calibration studies (`synthetic.calibration_task`): noisy rows repeated at random operating points;
the epistemic diagnostic on 200 held-out points with noise-free targets, before and after fitting
`epistemic_scale` on 30 other held-out points. spearman_if_gaussian is the Spearman(std, |error|)
expected if errors were drawn from N(0, std²) with the model's own std: when the std varies little
across points, even a perfectly calibrated std ranks errors poorly (a reference, not a bound).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
from scipy import stats

from activelearn.config import ModelConfig, TrainingConfig
from activelearn.numerics import synthetic as syn
from activelearn.numerics.models import build_model
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from activelearn.numerics.uncertainty import epistemic_diagnostic, recalibrate_epistemic, rmse

STEER = syn.STEER_MAX

# (label, ModelConfig overrides) for the arrangement study.
ARRANGEMENTS: list[tuple[str, dict]] = [
    ("reference (V8:sigmoid-D32-D32-D8-V relu)", {"arch": "reference"}),
    ("V8-D32-D32-D8-V all relu", {"arch": "V8-D32-D32-D8-V"}),
    ("V8-D32-D32-D8-V all tanh", {"arch": "V8-D32-D32-D8-V", "activation": "tanh"}),
    ("D32-D32-D8-V (last only)", {"arch": "D32-D32-D8-V"}),
    ("D32-D32-V8-V relu", {"arch": "D32-D32-V8-V"}),
    ("D32-D32-V16-V relu", {"arch": "D32-D32-V16-V"}),
    ("D32-D32-V16-V elu", {"arch": "D32-D32-V16-V", "activation": "elu"}),
    ("D32-D32-V16-V tanh", {"arch": "D32-D32-V16-V", "activation": "tanh"}),
    ("D32-D32-V16-V softplus", {"arch": "D32-D32-V16-V", "activation": "softplus"}),
    ("D64-D64-V16-V relu", {"arch": "D64-D64-V16-V"}),
    ("V32-V32-V16-V relu (pbnn)", {"arch": "V32-V32-V16-V"}),
    ("D32-V32-V16-V relu", {"arch": "D32-V32-V16-V"}),
    ("D32-D32-V8-V full_cov", {"arch": "D32-D32-V8-V", "posterior": "full_cov"}),
    ("ensemble of 5 (D32-D32-D16-D)", {"kind": "ensemble", "arch": "D32-D32-D16-D"}),
]


def _train_cfg(**kw: object) -> TrainingConfig:
    base = {"epochs": 150, "batch_size": 64, "lr": 3e-3, "patience": None, "compile": False}
    base.update(kw)
    return TrainingConfig(**base)  # type: ignore[arg-type]


def novelty_run(overrides: dict, seed: int, train_kw: dict | None = None) -> dict[str, float]:
    """Novelty ratio and in-box RMSE of one configuration and seed."""
    x = syn.random_points(2000, throttle=(0.2, 1.0), steering=(0.0, STEER), seed=seed)
    y = syn.observe(x, np.random.default_rng(seed + 1))
    model = build_model(ModelConfig(**overrides))
    t0 = time.perf_counter()
    fit(model, TrainingData(x, y), _train_cfg(**(train_kw or {})), seed=seed)
    secs = time.perf_counter() - t0
    on = syn.grid(np.linspace(0.2, 1.0, 9), np.linspace(0.0, STEER, 9))
    off = syn.grid(np.linspace(-1.0, -0.2, 9), np.linspace(-STEER, 0.0, 9))
    p_on, p_off = model.predict(on, 64, seed=seed), model.predict(off, 64, seed=seed)
    ratio = p_off.epistemic_std.mean(axis=0) / p_on.epistemic_std.mean(axis=0)
    return {
        "ratio_mean": float(ratio.mean()),
        "ratio_min": float(ratio.min()),
        "rmse": float(rmse(syn.steady_state(on), p_on)),
        "train_s": secs,
    }


def gap_run(overrides: dict, seed: int, train_kw: dict | None = None) -> dict[str, float]:
    """1-D data on [-1, -0.3] ∪ [0.3, 1]: std in the gap and beyond, over the std inside."""
    rng = np.random.default_rng(seed)
    x = np.concatenate([rng.uniform(-1, -0.3, 500), rng.uniform(0.3, 1, 500)])[:, None]
    y = np.sin(2.5 * x) + 0.05 * rng.standard_normal(x.shape)
    model = build_model(ModelConfig(**{**overrides, "n_inputs": 1, "n_outputs": 1}))
    fit(model, TrainingData(x, y), _train_cfg(**(train_kw or {})), seed=seed)
    inside = np.concatenate([np.linspace(-0.95, -0.35, 20), np.linspace(0.35, 0.95, 20)])[:, None]
    gap = np.linspace(-0.15, 0.15, 20)[:, None]
    beyond = np.concatenate([np.linspace(-1.8, -1.3, 10), np.linspace(1.3, 1.8, 10)])[:, None]
    s_in, s_gap, s_out = (
        float(model.predict(z, 64, seed=seed).epistemic_std.mean()) for z in (inside, gap, beyond)
    )
    return {"gap_ratio": s_gap / s_in, "beyond_ratio": s_out / s_in}


def calibration_run(overrides: dict, seed: int, train_kw: dict | None = None) -> dict[str, float]:
    """Epistemic diagnostic on held-out points before/after recalibration."""
    overrides = dict(overrides)
    d = syn.calibration_task(
        seed, n_points=overrides.pop("_points", 40), rows_per_point=overrides.pop("_rows", 60)
    )
    model = build_model(ModelConfig(**overrides))
    t0 = time.perf_counter()
    fit(
        model,
        TrainingData(d["x"], d["y"], groups=d["groups"]),
        _train_cfg(**{"epochs": 200, "patience": 30, **(train_kw or {})}),
        validation=TrainingData(d["val_x"], d["val_y"]),
        seed=seed,
    )  # fmt: skip
    secs = time.perf_counter() - t0
    truth = d["test_truth"]
    before = epistemic_diagnostic(truth, model.predict(d["test_points"], 64, seed=seed))
    scale = recalibrate_epistemic(model, d["cal_points"], d["cal_truth"], noise_free=True, seed=seed)
    after = epistemic_diagnostic(truth, model.predict(d["test_points"], 64, seed=seed))
    # Spearman(std, |error|) expected if errors were N(0, std²): far below 1 when the std varies
    # little across points.
    std = np.sqrt(model.predict(d["test_points"], 64, seed=seed).epistemic_var)
    rng = np.random.default_rng(seed)
    ceiling = (
        np.mean(
            [
                np.mean(
                    [
                        stats.spearmanr(
                            std[:, j], std[:, j] * np.abs(rng.standard_normal(len(std)))
                        ).statistic
                        for j in range(std.shape[1])
                    ]
                )
                for _ in range(50)
            ]
        )
        if np.ptp(std) > 0
        else float("nan")
    )
    return {
        "rmse": before["rmse"],
        "z_before": before["z_spread"],
        "ratio_before": before["std_to_rmse"],
        "spearman": before["spearman"],
        "spearman_if_gaussian": float(ceiling),
        "scale": scale,
        "z_after": after["z_spread"],
        "ratio_after": after["std_to_rmse"],
        "train_s": secs,
    }


def _table(rows: list[tuple[str, dict[str, list[float]]]], keys: list[str]) -> str:
    head = "| variant | " + " | ".join(keys) + " |"
    lines = [head, "|" + "---|" * (len(keys) + 1)]
    for label, vals in rows:
        cells = []
        for k in keys:
            v = np.asarray(vals[k], dtype=float)
            cells.append(f"{v.mean():.3g}" + (f" ± {v.std():.2g}" if len(v) > 1 else ""))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _study(
    variants: list[tuple[str, dict, dict]],
    run: Callable[..., dict[str, float]],
    seeds: list[int],
    keys: list[str],
) -> str:
    rows = []
    for label, overrides, train_kw in variants:
        vals: dict[str, list[float]] = {}
        for seed in seeds:
            for k, v in run(overrides, seed, train_kw).items():
                vals.setdefault(k, []).append(v)
        rows.append((label, vals))
        print(_table([(label, vals)], keys).splitlines()[-1], flush=True)
    return _table(rows, keys)


KL_VARIANTS: list[tuple[str, dict, dict]] = [
    (f"{arch} kl_count={k}", {"arch": arch}, {"kl_count": k})
    for arch in ("default", "reference")
    for k in ("rows", "sqrt", "maneuvers")
] + [("ensemble of 5", {"kind": "ensemble"}, {})]


def main() -> None:
    """Run the chosen study and print a markdown table (mean ± std over seeds)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "study",
        choices=[
            "novelty",
            "gap",
            "calibration",
            "levers",
            "levers2",
            "klsize",
            "archfinal",
            "issuetests",
            "levers3",
        ],
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--only", default=None, help="substring filter on variant labels")
    args = parser.parse_args()
    if args.study in ("novelty", "gap"):
        variants = [(label, ov, {}) for label, ov in ARRANGEMENTS]
        if args.study == "novelty":
            run, keys = novelty_run, ["ratio_mean", "ratio_min", "rmse", "train_s"]
        else:
            run, keys = gap_run, ["gap_ratio", "beyond_ratio"]
    elif args.study == "issuetests":
        variants, run = [("default config", {}, {})], lambda _o, seed, _t: issue_tests(seed)
        keys = [
            "t1_ratio_min",
            "t1_ratio_mean",
            "t1_gap",
            "t1_beyond",
            "t2_corr_v",
            "t2_corr_w",
            "t3_coverage",
            "t6_rmse_ratio",
            "t7_z_before",
            "t7_z_after",
        ]
    elif args.study == "calibration":
        variants, run = KL_VARIANTS, calibration_run
        keys = ["rmse", "z_before", "ratio_before", "spearman", "scale", "z_after", "ratio_after", "train_s"]
    else:
        variants = {
            "levers": LEVERS,
            "levers2": LEVERS2,
            "klsize": KL_SIZE,
            "archfinal": ARCH_FINAL,
            "levers3": LEVERS3,
        }[args.study]
        run = calibration_run
        keys = [
            "rmse",
            "z_before",
            "ratio_before",
            "spearman",
            "spearman_if_gaussian",
            "scale",
            "z_after",
            "ratio_after",
            "train_s",
        ]
    if args.only:
        variants = [v for v in variants if args.only in v[0]]
    print(_study(variants, run, args.seeds, keys))


# Levers on calibration of the default hybrid (kl_count rows unless stated).
LEVERS: list[tuple[str, dict, dict]] = [
    ("default", {}, {}),
    ("prior_scale 0.3", {"prior_scale": 0.3}, {}),
    ("prior_scale 3", {"prior_scale": 3.0}, {}),
    ("prior trainable", {"prior_trainable": True}, {}),
    ("init std 0.1", {"posterior_init_std": 0.1}, {}),
    ("init std 0.001", {"posterior_init_std": 0.001}, {}),
    ("kl_weight 0.1 (cold)", {}, {"kl_weight": 0.1}),
    ("kl_count sqrt", {}, {"kl_count": "sqrt"}),
    ("3 V layers D32-V32-V16-V", {"arch": "D32-V32-V16-V"}, {}),
    ("full_cov D32-D32-V8-V", {"arch": "D32-D32-V8-V", "posterior": "full_cov"}, {}),
    ("more training 400 ep", {}, {"epochs": 400, "patience": 60}),
    ("no early stop 300 ep", {}, {"epochs": 300, "patience": None}),
    ("lr 1e-3 400 ep", {}, {"lr": 1e-3, "epochs": 400, "patience": 60}),
    ("pnn (single, dense)", {"kind": "pnn"}, {}),
    ("D64-D64-V16-V", {"arch": "D64-D64-V16-V"}, {}),
    ("ensemble of 5", {"kind": "ensemble"}, {}),
]

_SLOW = {"lr": 1e-3, "epochs": 400, "patience": 60}
LEVERS2: list[tuple[str, dict, dict]] = [
    ("D32-D32-V16-V prior 0.3 lr 1e-3", {"arch": "D32-D32-V16-V", "prior_scale": 0.3}, _SLOW),
    ("D32-V32-V16-V prior 0.3 lr 1e-3", {"arch": "D32-V32-V16-V", "prior_scale": 0.3}, _SLOW),
    ("D64-D64-V16-V prior 0.3 lr 1e-3", {"arch": "D64-D64-V16-V", "prior_scale": 0.3}, _SLOW),
    ("D32-V32-V16-V lr 1e-3", {"arch": "D32-V32-V16-V"}, _SLOW),
    (
        "D32-V32-V16-V prior 0.3 lr 1e-3 sqrt",
        {"arch": "D32-V32-V16-V", "prior_scale": 0.3},
        {**_SLOW, "kl_count": "sqrt"},
    ),
    ("ensemble of 5 lr 1e-3", {"kind": "ensemble"}, _SLOW),
]

# KL counting across data sizes: (operating points, rows per point).
KL_SIZE: list[tuple[str, dict, dict]] = [
    (f"{pts} pts x {rows} rows, {k}", {"_points": pts, "_rows": rows}, {**_SLOW, "kl_count": k})
    for pts, rows in ((8, 60), (40, 60), (40, 600))
    for k in ("rows", "sqrt", "maneuvers")
] + [
    (f"{pts} pts x {rows} rows, ensemble", {"_points": pts, "_rows": rows, "kind": "ensemble"}, _SLOW)
    for pts, rows in ((8, 60), (40, 60), (40, 600))
]

# Final arrangement choice at the default training schedule (lr 1e-3, up to 400 epochs, patience 60).
ARCH_FINAL: list[tuple[str, dict, dict]] = [
    (f"{arch} prior {prior}", {"arch": arch, "prior_scale": prior}, _SLOW)
    for arch in ("D64-D64-V16-V", "D32-V32-V16-V", "D32-D32-V16-V")
    for prior in (1.0, 0.3)
]

# Accuracy levers for the default hybrid (defaults: kl_count sqrt, lr 1e-3, 400 epochs, patience 60).
LEVERS3: list[tuple[str, dict, dict]] = [
    ("default", {}, _SLOW),
    ("batch 32", {}, {**_SLOW, "batch_size": 32}),
    ("batch 256, lr 3e-3", {}, {**_SLOW, "batch_size": 256, "lr": 3e-3}),
    ("kl_weight 0.3", {}, {**_SLOW, "kl_weight": 0.3}),
    ("prior 0.3", {"prior_scale": 0.3}, _SLOW),
    ("init std 0.001", {"posterior_init_std": 0.001}, _SLOW),
    ("D64-D64-V32-V", {"arch": "D64-D64-V32-V"}, _SLOW),
    ("D128-D128-V16-V", {"arch": "D128-D128-V16-V"}, _SLOW),
    ("patience 150", {}, {**_SLOW, "patience": 150, "epochs": 600}),
    ("single PNN (same widths)", {"kind": "pnn"}, _SLOW),
    ("ensemble of 5", {"kind": "ensemble"}, _SLOW),
]


def issue_tests(seed: int) -> dict[str, float]:
    """The measured values behind tests 1-3, 6 and 7 (same data and schedules as the test suite)."""
    from activelearn.numerics.uncertainty import coverage

    fast = {"epochs": 150, "batch_size": 64, "lr": 3e-3, "patience": None}
    nov = novelty_run({}, seed, fast)
    gap = gap_run({}, seed, fast)
    x, y = syn.uniform_rows(3000, steering=(-STEER, STEER), seed=seed)
    model = build_model(ModelConfig())
    fit(model, TrainingData(x, y), TrainingConfig(**fast), seed=seed)
    pts = syn.random_points(300, steering=(-STEER, STEER), seed=seed + 10)
    pred = model.predict(pts, 32)
    true = syn.noise_std(pts)
    corr = [np.corrcoef(pred.aleatoric_std[:, j], true[:, j])[0, 1] for j in range(2)]
    xt, yt = syn.uniform_rows(3000, steering=(-STEER, STEER), seed=seed + 20)
    cov = coverage(yt, model.predict(xt, 32), 0.95)
    xs, ys, _ = syn.repeated_rows(syn.skidpad_points(), 60, seed=seed)
    test = syn.random_points(300, steering=(-STEER, STEER), seed=seed + 1)
    err = {}
    for kind in ("hybrid", "dnn"):
        m = build_model(ModelConfig(kind=kind))
        fit(m, TrainingData(xs, ys), TrainingConfig(**fast), seed=seed)
        err[kind] = rmse(syn.steady_state(test), m.predict(test, 32))
    cal = calibration_run({}, seed, _SLOW)  # the default TrainingConfig schedule
    return {
        "t1_ratio_min": nov["ratio_min"],
        "t1_ratio_mean": nov["ratio_mean"],
        "t1_gap": gap["gap_ratio"],
        "t1_beyond": gap["beyond_ratio"],
        "t2_corr_v": float(corr[0]),
        "t2_corr_w": float(corr[1]),
        "t3_coverage": float(cov),
        "t6_rmse_ratio": float(err["hybrid"] / err["dnn"]),
        "t7_z_before": cal["z_before"],
        "t7_z_after": cal["z_after"],
    }


if __name__ == "__main__":
    main()
