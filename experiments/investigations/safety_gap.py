"""Where does the safe campaigns' test error come from? (issue 23, after bench_safety.py)

Reads a bench_safety.py output directory (safe/ and unconstrained/ campaigns of the same seeds) and
prints which test maneuvers' true rates break a limit of [safety] (no safe campaign may drive
there), then per variant: the final models' test RMSE (also over the test maneuvers within the
limits), their squared test error (standardised, as `test_rmse`) split by
test maneuver kind and sign of throttle (forward / reverse), the share of the total each part
carries, and the picks (kind and sign, median driven seconds, share cut). Then, per seed, which
test maneuvers the safe model misses most, and whether the safe campaign drove anything at that
operating point (same kind, or a family member for a skidpad; sign and throttle within 0.2), with the
largest steering it reached as driven.

Usage: python experiments/investigations/safety_gap.py [--bench runs/bench_safety] [--config FILE] [--top 3]
"""

from __future__ import annotations

import argparse
import dataclasses
from collections import defaultdict
from pathlib import Path

import numpy as np

from activelearn.config import load_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import cache_root
from activelearn.loop.pool import maneuver_controls
from activelearn.loop.safety.limits import violating
from activelearn.loop.state import MODEL_FILE, CampaignState
from activelearn.numerics.models import load_model
from simulator.families import FAMILIES

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
EVAL_SAMPLES = 64


def driven_as(campaign: Campaign, index: int, state: CampaignState):
    """Pick `index` as the campaign drove it (cut to its shorter duration where [safety] said so)."""
    m = campaign.maneuvers[index]
    return dataclasses.replace(m, duration=state.cuts.get(str(index), m.duration))


def part(m) -> str:
    """A maneuver's kind and driving direction (fwd / rev by the throttle's sign)."""
    return f"{m.kind}/{'rev' if m.throttle < 0 else 'fwd'}"


def nearby(driven, test) -> bool:
    """A pick at the test maneuver's operating point: same kind (a skidpad also from a slalom at f = 0 or a
    staircase, any family member that steers), sign and throttle within 0.2."""
    same = driven.kind == test.kind or (test.kind == "skidpad" and driven.kind in FAMILIES)
    side = (driven.throttle < 0) == (test.throttle < 0)
    return same and side and abs(driven.throttle - test.throttle) <= 0.2


def reached(m, rate: float) -> float:
    """The largest |steering| a pick applied as driven (a cut ramp stops short of its amplitude)."""
    return float(np.abs(maneuver_controls(m, rate)[:, 1]).max())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bench", default="runs/bench_safety")
    parser.add_argument("--config", default=str(CONFIGS / "safe_track.toml"))
    parser.add_argument("--top", type=int, default=3)
    args = parser.parse_args()
    cfg = load_config(args.config)
    campaign = Campaign(cfg, Path(args.bench) / "gap", cache_dir=cache_root(cfg))
    test, tests = campaign.test_set, campaign.oracle.test_maneuvers()
    parts = sorted({part(m) for m in tests})
    # test maneuvers whose true rates break a limit (arena aside: the test set is a map, not a drive)
    safety, rate = cfg.safety, cfg.simulation.rate_hz
    beyond = np.array([
        bool(violating(np.zeros(len(t)), np.zeros(len(t)), t["speed"].to_numpy(np.float64),
                       t["angZ"].to_numpy(np.float64), safety, rate).any())
        for t in test.truth_logs
    ])  # fmt: skip
    print(f"# test maneuvers whose true rates break a limit of [safety]: {int(beyond.sum())} of {len(tests)} "
          f"({np.isin(test.groups, np.flatnonzero(beyond)).mean():.0%} of the test rows): "
          + ", ".join(m.name for m, b in zip(tests, beyond, strict=True) if b))  # fmt: skip
    within_rows = ~np.isin(test.groups, np.flatnonzero(beyond))
    worst: dict[str, dict[int, list]] = {}
    for variant in ("unconstrained", "safe"):
        sq: dict[str, list[float]] = defaultdict(list)
        totals, within, picks, per_seed = [], [], defaultdict(list), {}
        for state_file in sorted(Path(args.bench, variant).glob("*/seed*/state.json")):
            directory = state_file.parent
            state = CampaignState.load(directory)
            model = load_model(directory / MODEL_FILE)
            pred = model.predict(test.x, n_samples=EVAL_SAMPLES, seed=0).mean
            err = ((pred - test.y_clean) / test.scale) ** 2  # (N, 2) standardised squared error
            totals.append(err.mean())
            within.append(err[within_rows].mean())
            by_test = np.array([err[test.groups == g].mean() for g in range(len(tests))])
            for p in parts:
                rows = np.isin(test.groups, [g for g, m in enumerate(tests) if part(m) == p])
                sq[p].append(err[rows].sum() / err.size)  # share of the mean squared error
            for i in state.taken:
                m = campaign.maneuvers[i]
                picks[part(m)].append((state.cuts.get(str(i), m.duration), str(i) in state.cuts))
            per_seed[state.seed] = (by_test, [driven_as(campaign, i, state) for i in state.taken])
        worst[variant] = per_seed
        rmse = np.sqrt(np.mean(totals))
        print(f"## {variant}: {len(totals)} seeds, final test RMSE {np.mean(np.sqrt(totals)):.4f} "
              f"(root of the mean MSE {rmse:.4f}); on the test maneuvers within the limits "
              f"{np.mean(np.sqrt(within)):.4f}")  # fmt: skip
        header = f"{'part':<16} {'test rows':>9} {'MSE share':>9} {'RMSE alone':>10}"
        print(f"  {header}   picks (n, median s, cut)")
        for p in parts:
            n_rows = int(np.isin(test.groups, [g for g, m in enumerate(tests) if part(m) == p]).sum())
            share = np.sum(sq[p]) / np.sum(totals)
            alone = np.sqrt(np.mean(sq[p]) * test.groups.size / n_rows)
            driven = picks.get(p, [])
            seconds = np.median([d for d, _ in driven]) if driven else float("nan")
            cut = np.mean([c for _, c in driven]) if driven else float("nan")
            print(f"  {p:<16} {n_rows:>9} {share:>9.0%} {alone:>10.4f}   {len(driven):>3} {seconds:5.0f} s "
                  f"{cut:4.0%}")  # fmt: skip
        other = sorted(set(picks) - set(parts))
        for p in other:
            seconds, cut = (np.median([d for d, _ in picks[p]]), np.mean([c for _, c in picks[p]]))
            print(f"  {p:<16} {'(no test)':>9} {'':>20}   {len(picks[p]):>3} {seconds:5.0f} s {cut:4.0%}")
    print(f"## per seed: the safe models' {args.top} worst test maneuvers (RMSE; unconstrained's), "
          "and the nearest pick the safe campaign drove there")  # fmt: skip
    for seed, (by_test, driven) in sorted(worst["safe"].items()):
        free = worst["unconstrained"].get(seed, (np.full(len(tests), np.nan), []))[0]
        line = []
        for g in np.argsort(by_test)[::-1][: args.top]:
            m = tests[g]
            near = [d for d in driven if nearby(d, m)]
            got = ",".join(f"{d.kind} {d.throttle:+.2f}/{reached(d, rate):.2f}@{d.duration:g}s" for d in near)
            got = got or "none"
            line.append(f"{m.name} {np.sqrt(by_test[g]):.3f} ({np.sqrt(free[g]):.3f}) [{got}]")
        print(f"  seed {seed}: " + "; ".join(line))


if __name__ == "__main__":
    main()
