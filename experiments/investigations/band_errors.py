"""Where in the envelope strategies differ: each strategy's last-round models by lateral-acceleration band.

For a finished comparison (`bench_sample_efficiency.py --out OUT` leaves `OUT/<config>/<strategy>/seedK`),
every seed's last model runs free on the campaigns' test set (read from the control's stored config; the
mean path of its draws, as the campaign measures it). Each test maneuver falls in a band by its truth's
90th percentile of |v r| over μ g (below 0.3, 0.3-0.6, above 0.6; `bench_vehicle_baselines.py`'s bands,
the twin's grip on a twin config). Prints per strategy and band the mean 30-s error, then each strategy's
paired difference against uniform by band (the seed's mean over the band's maneuvers; mean ± s.e.m. over
seeds, and on how many seeds it is lower), and checks that the maneuvers' mean reproduces each campaign's
logged final error. `--correction-share 0` asks what the last models would do keeping none of their
correction's mean (the gate's choice aside): a what-if on the same models, not a campaign.

Issue 57 asks on which band a strategy reaches uniform's error; the campaigns log only the mean over all
test maneuvers.

Usage: python experiments/investigations/band_errors.py --runs OUT/dynamics_bmw320i_warm
       [--strategies uniform,regressor_maximin] [--correction-share 0]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from bench_vehicle_baselines import BANDS, band_table, trained_by_band

from activelearn.config import validate_config
from activelearn.loop.state import CONFIG_FILE, CampaignState
from activelearn.names import ROLLOUT_POS_ERR_30S

CONTROL = "uniform"


def paired_by_band(frame: pd.DataFrame) -> pd.DataFrame:
    """Each strategy's per-seed band means against uniform's on the same seed."""
    seeds = frame.groupby(["variant", "seed", "band"])["error"].mean().unstack("variant")
    rows = []
    for strategy in [c for c in seeds.columns if c != CONTROL]:
        for band in [b for b, _, _ in BANDS if b in seeds.index.get_level_values("band")]:
            diff = (seeds[strategy] - seeds[CONTROL]).xs(band, level="band").dropna()
            sem = diff.std(ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else np.nan
            rows.append({"strategy": strategy, "band": band, "seeds": len(diff), "mean_diff": diff.mean(),
                         "sem": sem, "lower": f"{int((diff < 0).sum())}/{len(diff)}"})  # fmt: skip
    return pd.DataFrame(rows)


def logged_final(runs: Path, strategy: str, seed: int) -> float:
    """The campaign's own last-round 30-s error."""
    return float(CampaignState.load(runs / strategy / f"seed{seed}").rounds[-1][ROLLOUT_POS_ERR_30S])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", required=True, type=Path, help="a comparison's directory (one config)")
    parser.add_argument("--strategies", default=None, help="default: every strategy directory under --runs")
    parser.add_argument("--correction-share", type=float, default=None,
                        help="each last model keeps this share of its correction's mean, not its gate's "
                             "(0: the identified core and the correction's band; a what-if)")  # fmt: skip
    args = parser.parse_args()
    stored = sorted((args.runs / CONTROL).glob(f"seed*/{CONFIG_FILE}"))
    if not stored:
        parser.error(f"--runs: no {CONTROL}/seed*/{CONFIG_FILE} under {args.runs} (uniform is the control)")
    cfg = validate_config(json.loads(stored[0].read_text()))
    twin = cfg.oracle.kind == "twin"
    found = sorted(p.name for p in args.runs.iterdir() if list(p.glob("seed*/model.pt")))
    strategies = args.strategies.split(",") if args.strategies else found
    if CONTROL not in strategies:
        strategies.insert(0, CONTROL)
    share = args.correction_share
    frame = pd.concat([trained_by_band(cfg, args.runs, s, twin, strategy=s, correction_weight=share)
                       for s in strategies], ignore_index=True)  # fmt: skip
    pd.set_option("display.width", 200)
    if share is None:
        worst = 0.0
        for (strategy, seed), group in frame.groupby(["variant", "seed"]):
            logged = logged_final(args.runs, strategy, seed)
            worst = max(worst, abs(group["error"].mean() - logged) / logged)
        kept = f"the maneuvers' mean reproduces the logged finals to {worst:.1e} relative"
    else:
        kept = f"every model keeps {share:g} of its correction's mean, whatever its gate chose"
    print(f"=== {cfg.name}: last-round models by band ({'twin' if twin else 'nominal'} grip; {kept}) ===")
    print("mean 30-s error, m (test maneuvers x seeds):")
    print(band_table(frame).to_string())
    print(f"\npaired against {CONTROL}, by band (negative = lower):")
    print(paired_by_band(frame).to_string(index=False, float_format="%.3f"))


if __name__ == "__main__":
    main()
