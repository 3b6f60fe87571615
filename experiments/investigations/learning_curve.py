"""Why does uniform's learning curve go up in `make demo`? (issue 21, point 5)

In `make demo` (experiments/configs/demo.toml: warm start from a prior grid of forward skidpads and
straights, 2 new maneuvers a round, a deep ensemble of 5 PNNs) uniform's test RMSE rose from round 1
to round 2 on all three seeds. This script separates the candidate causes:

1. runs (or resumes) the uniform campaigns of the config, one per seed, without tracking or figures,
   and prints their curves and the maneuvers uniform took in every batch;
2. refits every round's data with several training seeds (the same seeds at every round, so rounds
   are paired) under controlled variants, one change at a time:
     base          the campaign's recipe (`Campaign.fitting.fit` with cfg.seed = training seed);
     fixed_scalers input scalers fitted on the candidate pool's inputs and output scalers on the last
                   round's data, the same at every round (are refitted scalers the cause?);
     pool_x_scaler input scalers fitted on the candidate pool's inputs, output scalers refitted as usual;
     equal_rows    every maneuver contributes the same number of rows (the median), long ones thinned
                   evenly (does a 90-s fishhook with 3x a skidpad's rows dominate?);
     const_steps   epochs scaled so that every round takes the optimizer steps of round 0;
     epochs300     twice the epochs (is a round under-trained?);
     alt_batch     the data control: the round's last batch replaced by other maneuvers (`--alt`,
                   default two reverse skidpads at throttle -0.4), trained as base;
3. breaks each fit's test error down by test region (kind x forward/reverse) and by ensemble member.

Every fit is cached in <out>/fits.json, so a rerun only fits what is missing.

    PYTHONPATH=. python experiments/investigations/learning_curve.py --out runs/lc --seeds 0 1 2 \\
        --train-seeds 4 --rounds 1 2 3 4 --variants base
    PYTHONPATH=. python experiments/investigations/learning_curve.py --out runs/lc --seeds 0 1 2 \\
        --train-seeds 3 --rounds 1 2 --variants base,fixed_scalers,equal_rows,const_steps,alt_batch

(a few minutes each on 2 cores; `--first-train-seed` adds further training seeds, `--no-fit` prints
the tables of what is cached).

Printout: experiments/results/learning_curve.txt.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from activelearn.config import CampaignConfig, load_config
from activelearn.data import read_table
from activelearn.loop.campaign import Campaign
from activelearn.loop.evaluation import EVAL_SAMPLES
from activelearn.loop.prior import PRIOR_FILE, prior_from_rows
from activelearn.loop.state import SAMPLES_FILE, CampaignState
from activelearn.numerics.models import build_model
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from activelearn.seeds import Stream, derived_seed

VARIANTS = ("base", "fixed_scalers", "pool_x_scaler", "equal_rows", "const_steps", "epochs300", "alt_batch")
# alt_batch: the round's last batch replaced by these (reverse, mid throttle: where the test error is)
ALT_BATCH = "skidpad_ccw_t-0.40_s0.3142_d30,skidpad_cw_t-0.40_s0.3142_d30"


def campaign_config(path: str, seed: int, strategy: str) -> CampaignConfig:
    return load_config(path, overrides={"strategy": strategy, "seed": seed, "tracking": {"enabled": False}})


def run_campaign(cfg: CampaignConfig, directory: Path) -> Campaign:
    """Run the campaign to its end (or resume it); return a Campaign whose prior is loaded."""
    campaign = Campaign(cfg, directory)
    state_file = directory / "state.json"
    if not (state_file.exists() and CampaignState.load(directory).finished):
        campaign.run(figures=False, resume=state_file.exists(), log_model=False)
    if campaign.prior is None and (directory / PRIOR_FILE).exists():
        campaign.prior = prior_from_rows(read_table(directory / PRIOR_FILE), cfg.design.prior.use)
    return campaign


def equalise_rows(x: np.ndarray, y: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, ...]:
    """Every maneuver thinned (evenly spaced rows) or repeated to the median rows per maneuver."""
    ids, counts = np.unique(groups, return_counts=True)
    m = int(np.median(counts))
    keep = []
    for g in ids:
        rows = np.flatnonzero(groups == g)
        keep.append(rows[np.round(np.linspace(0, len(rows) - 1, m)).astype(int)])
    idx = np.concatenate(keep)
    return x[idx], y[idx], groups[idx]


def fit_variant(
    campaign: Campaign,
    samples: pd.DataFrame,
    round_index: int,
    variant: str,
    train_seed: int,
    context: dict[str, Any],
) -> Any:
    """A model of one round's data under one variant, trained with seed (train_seed, round)."""
    cfg = campaign.cfg
    if variant == "base":  # exactly the campaign's recipe, with another seed
        campaign.cfg = cfg.model_copy(update={"seed": train_seed})
        try:
            return campaign.fitting.fit(samples, round_index)
        finally:
            campaign.cfg = cfg
    x, y, groups = campaign.fitting.training_data(samples)
    seed = derived_seed(train_seed, Stream.ROUND, round_index)
    training = cfg.training
    model = build_model(cfg.model)
    keep_scalers = False
    if variant in ("fixed_scalers", "pool_x_scaler"):
        model.set_scalers(context["final_x"] if variant == "fixed_scalers" else x,
                          context["final_y"] if variant == "fixed_scalers" else y)  # fmt: skip
        pool_x = torch.as_tensor(context["pool_x"], dtype=torch.float32)
        model.x_mean.copy_(pool_x.mean(dim=0))
        model.x_std.copy_(pool_x.std(dim=0, unbiased=False).clamp_min(1e-8))
        keep_scalers = True
    elif variant == "equal_rows":
        x, y, groups = equalise_rows(x, y, groups)
    elif variant == "const_steps":
        steps0 = math.ceil(context["rows0"] / training.batch_size)
        epochs = max(1, round(training.epochs * steps0 / math.ceil(len(x) / training.batch_size)))
        training = training.model_copy(update={"epochs": epochs})
    elif variant == "epochs300":
        training = training.model_copy(update={"epochs": 2 * training.epochs})
    elif variant != "base":
        raise ValueError(variant)
    fit(model, TrainingData(x, y, groups=groups), training, seed=seed, keep_scalers=keep_scalers)
    return model


def breakdown(campaign: Campaign, model: Any) -> dict[str, Any]:
    """Test RMSE (standardised, as `evaluate`), per region and per ensemble member."""
    test = campaign.test_set
    pred = model.predict(test.x, n_samples=EVAL_SAMPLES, seed=0, return_samples=True)
    sq = (((pred.mean - test.y_clean) / test.scale) ** 2).mean(axis=1)  # per row, mean over outputs
    out: dict[str, Any] = {"test_rmse": float(np.sqrt(sq.mean()))}
    tests = campaign.oracle.test_maneuvers()
    region = np.array([f"{tests[g].kind}/{'rev' if tests[g].throttle < 0 else 'fwd'}" for g in test.groups])
    out["regions"] = {r: [float(np.sqrt(sq[region == r].mean())), float(sq[region == r].sum() / sq.sum())]
                      for r in sorted(set(region))}  # fmt: skip
    throttle = np.array([tests[g].throttle for g in test.groups])
    out["throttles"] = {f"{t:+.1f}": float(np.sqrt(sq[throttle == t].mean())) for t in sorted(set(throttle))}
    if pred.sample_means is not None and model.n_members is not None:
        members = pred.sample_means  # (K, N, outputs)
        out["members"] = [float(np.sqrt((((m - test.y_clean) / test.scale) ** 2).mean())) for m in members]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    parser.add_argument("--config", default="experiments/configs/demo.toml")
    parser.add_argument("--strategy", default="uniform")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="campaign seeds")
    parser.add_argument(
        "--train-seeds", type=int, default=3, help="training seeds per fit (first, first + 1, ...)"
    )
    parser.add_argument("--first-train-seed", type=int, default=100, help="the first training seed")
    parser.add_argument("--rounds", type=int, nargs="+", default=[1, 2], help="rounds to refit")
    parser.add_argument("--variants", default="base", help=f"comma list of {', '.join(VARIANTS)}")
    parser.add_argument("--alt", default=ALT_BATCH, help="maneuvers of alt_batch, comma separated")
    parser.add_argument("--no-fit", action="store_true", help="print the tables from the cache only")
    parser.add_argument("--out", default="runs/learning_curve", help="campaigns and the fit cache")
    args = parser.parse_args()
    variants = args.variants.split(",")
    for v in variants:
        if v not in VARIANTS:
            parser.error(f"--variants: unknown {v!r}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cache_file = out / "fits.json"
    cache: dict[str, Any] = json.loads(cache_file.read_text()) if cache_file.exists() else {}
    train_seeds = [args.first_train_seed + t for t in range(args.train_seeds)]

    print(f"# {args.config}: {args.strategy}, campaign seeds {args.seeds}, training seeds {train_seeds}")
    campaigns = {}
    for seed in args.seeds:
        cfg = campaign_config(args.config, seed, args.strategy)
        campaigns[seed] = run_campaign(cfg, out / args.strategy / f"seed{seed}")

    print("\n## Campaign curves (test RMSE as logged) and the maneuvers each batch added")
    for seed, campaign in campaigns.items():
        state = CampaignState.load(campaign.directory)
        curve = " ".join(f"{r['test_rmse']:.4f}" for r in state.rounds)
        print(f"seed {seed}: rows {[int(r['n_samples']) for r in state.rounds]}  rmse {curve}")
        for b, batch in enumerate(state.batches):
            print(f"  batch {b} (-> round {b + 1}): {', '.join(campaign.maneuvers[i].name for i in batch)}")

    for seed, campaign in campaigns.items():
        samples = read_table(campaign.directory / SAMPLES_FILE)
        state = CampaignState.load(campaign.directory)
        final_x, final_y, _ = campaign.fitting.training_data(samples)
        context = {
            "pool_x": campaign.pool([]).points,
            "final_x": final_x,
            "final_y": final_y,
            "rows0": len(campaign.fitting.training_data(samples.iloc[:0])[0]),
        }
        for r in args.rounds:
            if r >= len(state.rounds):
                continue
            part = samples[samples["batch"] < r].reset_index(drop=True)
            for v in variants:
                data = part
                if v == "alt_batch":
                    if r == 0:
                        continue
                    names = [m.name for m in campaign.maneuvers]
                    picks = [names.index(name) for name in args.alt.split(",")]
                    alt = campaign.collect(picks, r - 1, state)
                    data = pd.concat([samples[samples["batch"] < r - 1], alt], ignore_index=True)
                for t in train_seeds:
                    key = f"{seed}|{r}|{v}|{t}"
                    if key in cache or args.no_fit:
                        continue
                    started = time.perf_counter()
                    variant = "base" if v == "alt_batch" else v
                    model = fit_variant(campaign, data, r, variant, t, context)
                    cache[key] = {**breakdown(campaign, model), "fit_seconds": time.perf_counter() - started}
                    cache_file.write_text(json.dumps(cache, indent=0))
                    print(f"  fitted seed {seed} round {r} {v} t{t}: {cache[key]['test_rmse']:.4f}",
                          flush=True)  # fmt: skip
    report(cache, args.seeds, args.rounds, variants, train_seeds)


def _get(cache: dict, seed: int, r: int, v: str, seeds: list[int]) -> list[dict]:
    return [cache[k] for t in seeds if (k := f"{seed}|{r}|{v}|{t}") in cache]


def _cell(vals: list[float]) -> str:
    if not vals:
        return "-"
    return f"{np.mean(vals):.4f} ± {np.std(vals, ddof=1) if len(vals) > 1 else 0:.4f} ({len(vals)})"


def report(cache: dict, seeds: list[int], rounds: list[int], variants: list[str], tseeds: list[int]) -> None:
    """The tables: RMSE per variant and round (mean ± sd over training seeds), regions, members."""
    print("\n## Test RMSE per round: mean ± sd over training seeds (number of fits)")
    print("variant        seed " + "".join(f"{'round ' + str(r):>26s}" for r in rounds))
    for v in variants:
        for seed in [*seeds, "all"]:
            cells = []
            for r in rounds:
                fits = [f for s in seeds for f in _get(cache, s, r, v, tseeds)] if seed == "all" else (
                    _get(cache, seed, r, v, tseeds))  # fmt: skip
                cells.append(_cell([f["test_rmse"] for f in fits]))
            print(f"{v:<14s} {seed!s:>4s} " + "".join(f"{c:>26s}" for c in cells))

    print("\n## Change round a -> b. paired: same campaign and training seed, mean ± s.e.m. and rises/pairs;")
    print("## unpaired: P(rise) when the two rounds use different training seeds, as a campaign does")
    for v in variants:
        parts = []
        for a, b in itertools.pairwise(rounds):
            diffs, ups = [], []
            for s in seeds:
                keys = [(f"{s}|{a}|{v}|{t}", f"{s}|{b}|{v}|{t}") for t in tseeds]
                pairs = [(cache[ka]["test_rmse"], cache[kb]["test_rmse"])
                         for ka, kb in keys if ka in cache and kb in cache]  # fmt: skip
                if not pairs:
                    continue
                xa, xb = np.array(pairs).T
                diffs.extend(xb - xa)
                ups.append(np.mean(xb[:, None] > xa[None, :]))
            if diffs:
                d = np.array(diffs)
                sem = d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else float("nan")
                parts.append(f"{a}->{b}: {d.mean():+.4f} ± {sem:.4f} ({int((d > 0).sum())}/{len(d)} up), "
                             f"unpaired P(rise) {np.mean(ups):.2f}")  # fmt: skip
        print(f"{v:<14s} " + "   ".join(parts))

    print("\n## Variants against base, paired (same campaign seed, training seed and round): mean ± s.e.m.")
    print("## of variant - base and how many fits the variant made worse; alt_batch also against base one")
    print("## round earlier (what the replaced batch would have changed)")
    for v in variants:
        if v == "base":
            continue
        parts = []
        for r in rounds:
            for lag in (0, 1) if v == "alt_batch" else (0,):
                keys = [(f"{s}|{r}|{v}|{t}", f"{s}|{r - lag}|base|{t}") for s in seeds for t in tseeds]
                d = np.array([cache[a]["test_rmse"] - cache[b]["test_rmse"]
                              for a, b in keys if a in cache and b in cache])  # fmt: skip
                if len(d) > 1:
                    sem = d.std(ddof=1) / np.sqrt(len(d))
                    parts.append(f"round {r} vs base round {r - lag}: {d.mean():+.4f} ± {sem:.4f} "
                                 f"({int((d > 0).sum())}/{len(d)} worse)")  # fmt: skip
        print(f"{v:<14s} " + "   ".join(parts))

    print("\n## Base fits: RMSE per test region (share of the squared error), mean over training seeds")
    regions = sorted({k for f in cache.values() for k in f.get("regions", {})})
    print("seed round  fits" + "".join(f"{r:>22s}" for r in regions))
    for seed in seeds:
        for r in rounds:
            fits = _get(cache, seed, r, "base", tseeds)
            if not fits:
                continue
            cells = []
            for reg in regions:
                vals = np.array([f["regions"][reg] for f in fits if reg in f["regions"]])
                cells.append(f"{vals[:, 0].mean():.4f} ({100 * vals[:, 1].mean():4.1f} %)")
            print(f"{seed:>4d} {r:>5d} {len(fits):>5d}" + "".join(f"{c:>22s}" for c in cells))

    print("\n## Base fits: RMSE per test throttle, mean over training seeds (fits that recorded it)")
    throttles = sorted({k for f in cache.values() for k in f.get("throttles", {})}, key=float)
    print("seed round  fits" + "".join(f"{t:>9s}" for t in throttles))
    for seed in seeds:
        for r in rounds:
            fits = [f for f in _get(cache, seed, r, "base", tseeds) if "throttles" in f]
            if fits:
                cells = [f"{np.mean([f['throttles'][t] for f in fits]):.4f}" for t in throttles]
                print(f"{seed:>4d} {r:>5d} {len(fits):>5d}" + "".join(f"{c:>9s}" for c in cells))

    print("\n## Base fits: ensemble members. Mean over fits of the best, median and worst member's RMSE,")
    print("## the ensemble's; 'failed': fits whose worst member is over 3x the ensemble's RMSE")
    print("seed round  fits     best   median    worst ensemble  failed")
    for seed in seeds:
        for r in rounds:
            fits = [f for f in _get(cache, seed, r, "base", tseeds) if "members" in f]
            if not fits:
                continue
            m = np.sort(np.array([f["members"] for f in fits]), axis=1)
            ens = np.array([f["test_rmse"] for f in fits])
            failed = int((m[:, -1] > 3 * ens).sum())
            stats = (m[:, 0].mean(), np.median(m, axis=1).mean(), m[:, -1].mean(), ens.mean())
            print(
                f"{seed:>4d} {r:>5d} {len(fits):>5d}" + "".join(f"{x:9.4f}" for x in stats) + f"{failed:>8d}"
            )


if __name__ == "__main__":
    main()
