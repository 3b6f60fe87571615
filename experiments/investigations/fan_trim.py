"""Which rule for the prequential fan scale keeps every round's free-run fans within 85-99 %?

A round's fan scale changes no data (the strategies' and the safety's free runs use scale 1), so every
rule is judged exactly from one campaign per seed: each round's per-step widening needs on the test
set at scale 1 are recorded (`fan_widening_needed`; coverage at scale s is the share of needs <= s,
checked against the logged `rollout_coverage_95` at the applied scale), and each rule recomputes the
applied scale from the logged `prequential_fan_scale` and `n_maneuvers`. The rules (session 36,
declared before the runs): R0 the geometric mean of every need (before session 36); R1(n0) shrunk to 1
by n0 maneuvers; R2(n0) as R1 for narrowing only; R3 no narrowing until 6 maneuvers were measured
(`activelearn.loop.evaluation.applied_fan_scale` since). Printout: results/fan_trim.txt.

Usage: python experiments/investigations/fan_trim.py [--configs dynamics_bmw320i,dynamics_f1tenth]
       [--seeds 10] [--first-seed 0] [--out runs/fan_trim]   (uniform; about 2 min a campaign)
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np

from activelearn.config import load_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.evaluation import MIN_TRIM_MANEUVERS, Evaluation
from activelearn.numerics.diagnostics import fan_widening_needed, free_runs

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
BAND = (0.85, 0.99)
Rule = Callable[[list[float], list[int]], float]


def _mean(needs: list[float], _: list[int]) -> float:
    return float(np.exp(np.mean(np.log(needs)))) if needs else 1.0


def _shrunk(n0: int) -> Rule:
    def rule(needs: list[float], maneuvers: list[int]) -> float:
        if not needs:
            return 1.0
        return float(np.exp(np.sum(np.array(maneuvers) * np.log(needs)) / (n0 + np.sum(maneuvers))))

    return rule


def _shrunk_narrowing(n0: int) -> Rule:
    def rule(needs: list[float], maneuvers: list[int]) -> float:
        mean = _mean(needs, maneuvers)
        return mean if mean >= 1.0 else _shrunk(n0)(needs, maneuvers)

    return rule


def _held(needs: list[float], maneuvers: list[int]) -> float:
    mean = _mean(needs, maneuvers)
    return max(mean, 1.0) if sum(maneuvers) < MIN_TRIM_MANEUVERS else mean


RULES: dict[str, Rule] = {
    "R0": _mean, "R3": _held,
    **{f"R1({n})": _shrunk(n) for n in (2, 4, 8)}, **{f"R2({n})": _shrunk_narrowing(n) for n in (2, 4, 8)},
}  # fmt: skip


def campaign_needs(config: str, seed: int, out: Path) -> tuple[list[dict], list[np.ndarray]]:
    """One uniform campaign's rounds and, per round, its test set's widening needs at fan scale 1."""
    recorded: list[np.ndarray] = []
    original = Evaluation.evaluate

    def evaluate(self: Evaluation, model, *, rollouts: bool = True) -> dict[str, float]:
        metrics = original(self, model, rollouts=rollouts)
        if rollouts:
            test = self.test_set
            rollout = free_runs(model, test.logs, rate_hz=self.cfg.simulation.rate_hz,
                                n_samples=self.cfg.test.rollout_samples, seed=0, fan_scale=1.0)  # fmt: skip
            recorded.append(fan_widening_needed(rollout, test.truth_logs, None))
        return metrics

    overrides = {"seed": seed, "strategy": "uniform", "tracking": {"enabled": False}}
    cfg = load_config(CONFIGS / f"{config}.toml", overrides={**overrides, "output_dir": str(out / "runs")})
    Evaluation.evaluate = evaluate
    try:
        rounds = Campaign(cfg, out / config / f"seed{seed}").run(figures=False, log_model=False).state.rounds
    finally:
        Evaluation.evaluate = original
    for r, needs in zip(rounds, recorded, strict=True):  # the record reproduces the logged coverage
        assert abs(np.mean(needs <= r.get("fan_scale", 1.0)) - r["rollout_coverage_95"]) < 2e-3
    return rounds, recorded


def coverage_by_rule(rounds: list[dict], needs: list[np.ndarray]) -> dict[str, list[float]]:
    """Each rule's coverage of every round, from the needs measured before it."""
    counts = [r["n_maneuvers"] for r in rounds]
    out = {}
    for name, rule in RULES.items():
        shares = []
        for k, round_needs in enumerate(needs):
            done = [j for j in range(k) if np.isfinite(rounds[j].get("prequential_fan_scale", np.nan))]
            measured = [rounds[j]["prequential_fan_scale"] for j in done]
            scale = rule(measured, [counts[j + 1] - counts[j] for j in done])
            shares.append(float(np.mean(round_needs <= scale)))
        out[name] = shares
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", default="dynamics_bmw320i,dynamics_bmw320i_twin,dynamics_f1tenth")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--out", default="runs/fan_trim")
    args = parser.parse_args()
    totals = {name: [0, 0.0] for name in RULES}
    for config in args.configs.split(","):
        per_rule: dict[str, list[list[float]]] = {name: [] for name in RULES}
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            rounds, needs = campaign_needs(config, seed, Path(args.out))
            for name, shares in coverage_by_rule(rounds, needs).items():
                per_rule[name].append(shares)
        print(f"\n== {config}: seed-mean share of true positions in the fans per round [lowest seed]; "
              f"signals {[r['n_maneuvers'] for r in rounds]}")  # fmt: skip
        for name, table in per_rule.items():
            shares = np.array(table)
            mean = shares.mean(axis=0)
            cells = zip(mean, shares.min(axis=0), strict=True)
            print(f"{name:7s} " + " ".join(f"{m:.3f}[{low:.2f}]" for m, low in cells))
            below, above = np.clip(BAND[0] - mean, 0, None), np.clip(mean - BAND[1], 0, None)
            totals[name][0] += int(np.sum((below > 0) | (above > 0)))
            totals[name][1] += float(np.sum(below + above))
    print(f"\n== rounds whose seed mean lies outside {BAND}, and the summed distance outside")
    for name, (outside, distance) in totals.items():
        print(f"{name:7s} outside {outside:2d}  distance {distance:.3f}")


if __name__ == "__main__":
    main()
