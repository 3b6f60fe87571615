"""Batch diversity ablation: max_epistemic with fantasised, penalised and plain top-k batches.

Runs the skidpad comparison once per batch rule (same seeds, initial designs and test set) and prints
per rule the final test RMSE, its area under the curve, and how spread each round's picks are (mean
distance between the two picks of a batch, in the [0, 1] operating-point cube). This is the
measurement behind the default `[acquisition] batch = "fantasy"`.

Usage: python experiments/investigations/batch_ablation.py [--seeds 5] [--workers 2] [--config skidpad]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from activelearn.config import load_config
from activelearn.loop.campaign import STATE_FILE, CampaignState
from activelearn.loop.pool import operating_features, pool_maneuvers
from activelearn.studies.compare import compare

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def batch_spread(directory: Path, features: np.ndarray) -> float:
    """Mean distance between picks of the same batch, over every batch after the initial design."""
    gaps = []
    for state_file in directory.glob(f"*/seed*/{STATE_FILE}"):
        for batch in CampaignState.load(state_file.parent).batches[1:]:
            if len(batch) > 1:
                f = features[batch]
                d = np.sqrt(((f[:, None] - f[None]) ** 2).sum(-1))
                gaps.append(d[np.triu_indices(len(batch), 1)].mean())
    return float(np.mean(gaps))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--config", default="skidpad")
    parser.add_argument("--out", default="runs/batch_ablation")
    args = parser.parse_args()
    rows = []
    for rule in ("fantasy", "penalty", "topk"):
        cfg = load_config(CONFIGS / f"{args.config}.toml", overrides={"acquisition": {"batch": rule}})
        directory = Path(args.out) / args.config / rule
        result = compare(
            cfg,
            ["max_epistemic"],
            list(range(args.seeds)),
            directory=directory,
            workers=args.workers,
            tracking=False,
            resume=True,
        )
        final = result.curves.sort_values("n_maneuvers").groupby("seed").last()["test_rmse"]
        features = operating_features(pool_maneuvers(cfg.pool))
        rows.append(
            {
                "batch": rule,
                "final_rmse": final.mean(),
                "sem": final.std(ddof=1) / np.sqrt(len(final)),
                "rmse_auc": result.table["rmse_auc"].iloc[0],
                "batch_spread": batch_spread(directory, features),
            }
        )
    print(pd.DataFrame(rows).to_string(index=False, float_format="%.4f"))


if __name__ == "__main__":
    main()
