"""Is the lookahead oracle's room its design's or its trials' luck? Replays finished designs under new seeds.

The lookahead oracle keeps, each round, the candidate batch whose retrained model has the lowest true test
error, and goes on with that very model: the room it shows over uniform is its design's worth plus the best
of its trials' luck (the training's draws and the logs' sensor noise, which no rule chooses). This drives
each finished campaign's design (its batches, in the order taken) again under other campaign seeds, which
redraw the training and the noise and keep the pool, the prior's grid and the test set, and prints each
design's test metric by round over the replays, then the room measured both ways:

  apparent room  the original campaigns' reference minus the other strategy, per seed (what the oracle shows);
  honest room    the same two designs' errors, each averaged over the same replay seeds.

Where the honest room is much smaller than the apparent one, the oracle's room is mostly its trials' luck.

Usage: python experiments/investigations/oracle_luck.py --runs OUT/dynamics_bmw320i_warm_twin
       --seeds 0,1,2 --replays 100,101,102,103 [--strategies uniform,oracle_lookahead] [--workers 2]
Replays go to RUNS/replays/<strategy>/seed<k>/replay<s> and are resumed if there.
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from activelearn.config import CampaignConfig, validate_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.history import NO_HISTORY, History
from activelearn.loop.state import CONFIG_FILE, CampaignState
from activelearn.loop.strategy import Pool, Strategy
from activelearn.names import N_MANEUVERS
from activelearn.studies.compare import first_reach, standard_error


class ReplayStrategy(Strategy):
    """Returns a finished campaign's batches in order: the batch it took after each round."""

    name = "replay"

    def __init__(self, batches: list[list[int]], first: int) -> None:
        super().__init__()
        self.batches = batches
        self.first = first  # the index in `batches` of the batch picked after round 0 (1 after an initial)

    def select(self, model: Any, pool: Pool, k: int, rng: np.random.Generator) -> list[int]:
        raise NotImplementedError("a replay needs the round (pick reads it from the history)")

    def pick(
        self, model: Any, pool: Pool, k: int, rng: np.random.Generator, history: History = NO_HISTORY
    ) -> list[int]:
        batch = self.batches[self.first + len(history.rounds)]
        missing = sorted(set(batch) - {int(i) for i in pool.available})
        if missing or len(batch) != k:
            raise RuntimeError(f"the recorded batch {batch} does not fit here (k={k}; not open: {missing})")
        return list(batch)


class ReplayCampaign(Campaign):
    """A campaign whose every batch, the initial design's too, is a recorded design's."""

    def __init__(self, cfg: CampaignConfig, directory: Path, batches: list[list[int]]) -> None:
        super().__init__(cfg, directory)
        self.batches = batches
        self.strategy = ReplayStrategy(batches, first=1 if cfg.design.initial > 0 else 0)

    def _propose(self, state: CampaignState, samples: pd.DataFrame, figures: bool) -> None:
        if not state.batches and self.cfg.design.initial > 0:
            self._set_pending(state, list(self.batches[0]), None)
            self._checkpoint(state, None, None)
            return
        super()._propose(state, samples, figures)


def replay(cfg_json: str, directory: str, batches: list[list[int]]) -> list[dict[str, Any]]:
    """Worker: one replay on one thread; its rounds' metrics."""
    import torch

    torch.set_num_threads(1)
    campaign = ReplayCampaign(CampaignConfig.model_validate_json(cfg_json), Path(directory), batches)
    return campaign.run(resume=True, figures=False, log_model=False).state.rounds


def curve(rounds: list[dict[str, Any]], metric: str) -> pd.Series:
    """The metric by the number of maneuvers collected."""
    return pd.Series({int(r[N_MANEUVERS]): float(r[metric]) for r in rounds if metric in r})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", required=True, type=Path, help="a comparison's directory (one config)")
    parser.add_argument("--strategies", default="uniform,oracle_lookahead", help="the reference first")
    parser.add_argument("--seeds", required=True, help="the finished seeds whose designs are replayed")
    parser.add_argument("--replays", default="100,101,102,103", help="the campaign seeds of the replays")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    strategies = args.strategies.split(",")
    seeds = [int(s) for s in args.seeds.split(",")]
    replays = [int(s) for s in args.replays.split(",")]
    if set(seeds) & set(replays):
        parser.error("--replays must differ from --seeds (a replay redraws the luck)")
    designs: dict[tuple[str, int], list[list[int]]] = {}
    originals: dict[tuple[str, int], pd.Series] = {}
    cfg = None
    for strategy in strategies:
        for seed in seeds:
            directory = args.runs / strategy / f"seed{seed}"
            state = CampaignState.load(directory) if (directory / CONFIG_FILE).exists() else None
            if state is None or not state.finished:
                parser.error(f"--runs: {directory} is not a finished campaign")
            cfg = cfg or validate_config(json.loads((directory / CONFIG_FILE).read_text()))
            designs[strategy, seed] = state.batches
            originals[strategy, seed] = curve(state.rounds, cfg.test.metric)
    assert cfg is not None
    if cfg.safety is not None:
        parser.error("--runs: a [safety] config (a replay drives what was admitted then, unjudged)")
    jobs = {}
    with ProcessPoolExecutor(args.workers) as pool:
        for (strategy, seed), batches in designs.items():
            for s in replays:
                directory = args.runs / "replays" / strategy / f"seed{seed}" / f"replay{s}"
                run_cfg = cfg.model_copy(update={"seed": s, "strategy": strategy})
                job = pool.submit(replay, run_cfg.model_dump_json(), str(directory), batches)
                jobs[strategy, seed, s] = job
        results = {key: curve(job.result(), cfg.test.metric) for key, job in jobs.items()}
    report(strategies, seeds, replays, originals, results)


def report(
    strategies: list[str], seeds: list[int], replays: list[int],
    originals: dict[tuple[str, int], pd.Series], results: dict[tuple[str, int, int], pd.Series],
) -> None:  # fmt: skip
    """Each design's curve (original, replays' mean and s.d.), then the room both ways at the last round and
    the reach: after how many maneuvers a design's replayed mean is at or below the reference's replayed
    final error (the reference's design of the same seed)."""
    pd.set_option("display.width", 200)
    rows, means = [], {}
    for strategy in strategies:
        for seed in seeds:
            runs = pd.DataFrame({s: results[strategy, seed, s] for s in replays})
            means[strategy, seed] = runs.mean(axis=1)
            design = f"{strategy} seed {seed}"
            rows.append({"design": design, "what": "original", **originals[strategy, seed]})
            rows.append({"design": design, "what": "replays' mean", **means[strategy, seed]})
            rows.append({"design": design, "what": "replays' s.d.", **runs.std(axis=1, ddof=1)})
    print(pd.DataFrame(rows).round(2).to_string(index=False))
    reference = strategies[0]
    for other in strategies[1:]:
        apparent = np.array([originals[reference, k].iloc[-1] - originals[other, k].iloc[-1] for k in seeds])
        honest = np.array([means[reference, k].iloc[-1] - means[other, k].iloc[-1] for k in seeds])
        print(f"\n{reference} - {other} at the last round, by seed {seeds}:")
        print(f"  apparent (the original campaigns): {np.round(apparent, 2)}, mean {apparent.mean():.2f}")
        print(f"  honest (each design's replays' mean): {np.round(honest, 2)}, mean {honest.mean():.2f}"
              f" +- {standard_error(honest):.2f} (s.e.m. over designs)")  # fmt: skip
        if apparent.mean() > 0:
            print(f"  honest / apparent: {honest.mean() / apparent.mean():.2f}")
        for k in seeds:
            final = means[reference, k].iloc[-1]
            reach, own = (first_reach(means[s, k].index.to_numpy(), means[s, k].to_numpy(), final)
                          for s in (other, reference))  # fmt: skip
            print(f"  reach, seed {k}: at or below {reference}'s replayed final ({final:.2f}) after "
                  f"{reach:.0f} maneuvers ({reference} itself: {own:.0f})")


if __name__ == "__main__":
    sys.exit(main())
