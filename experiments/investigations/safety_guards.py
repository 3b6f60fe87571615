"""How often do [safety]'s guards admit a candidate whose true MuJoCo path hits a wall? (issue 23)

The measurement behind the defaults of `[safety] path_tolerance`, `fan_scale` and `trust_std`. For
each seed, a round's model (default: the first round's, trained on the warm start's prior grid
only, as the campaign trains it; `--campaigns DIR`: the last model of each seed's campaign under a
benchmark directory, judged on the candidates it had not taken) assesses every candidate of the
pool under each combination of the guards (`activelearn.loop.safety.risk.assess`, the campaign's
code). Every admissible candidate is then driven as it would be proposed (cut short where the
assessment says so): its noise-free MuJoCo log (cached, full length; a cut maneuver is open-loop,
so its log is the full log's first rows) with the campaign seed's sensor noise, judged by
`log_violation` against the config's arena and limits, as the campaign counts violations.

Prints per variant and seed: admissible candidates, of them cut short, violations (arena / limits),
the track seconds admitted (sum of admissible durations: what conservatism costs), and the smallest
slack to a wall of an admitted true path (clearance - margin, m; negative = violation).

With `--worst-case`, rows with fan_scale "none" judge by the kinematic worst case alone (no model:
what a cold start's initial design gets, and the bound every untrusted candidate must meet too).

Usage: python experiments/investigations/safety_guards.py [--config FILE] [--seeds 3] [--fan-scales 1,3]
       [--tolerances 0,0.04,0.08,0.16] [--trust 0.02] [--campaigns DIR] [--worst-case]
       [--turn-speed measured|none]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import pandas as pd

from activelearn.config import load_config, polygon_clearance
from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import noisy_logs
from activelearn.loop.prior import load_prior
from activelearn.loop.safety.kinematic_bound import turn_speed
from activelearn.loop.safety.limits import log_violation, placed_path
from activelearn.loop.safety.risk import assess
from activelearn.loop.state import MODEL_FILE, SAMPLES_FILE, CampaignState
from activelearn.numerics.models import load_model
from activelearn.seeds import Stream, derived_seed
from simulator.maneuvers import sample_times

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
NO_GUARD = 1e9  # trust_std so large that the kinematic worst case never applies


def slack(log: pd.DataFrame, cfg) -> float:
    """Smallest clearance to a wall minus the margin along a log placed at the start pose (m)."""
    clearance = polygon_clearance(cfg.arena, *placed_path(log, cfg))
    return float(np.min(clearance) - cfg.margin)


def drive(campaign: Campaign, clean: list[pd.DataFrame], index: int, duration: float) -> pd.DataFrame:
    """The noisy log candidate `index` leaves when driven for `duration` seconds (cut: a prefix)."""
    maneuver = campaign.maneuvers[index]
    if duration < maneuver.duration - 1e-9:
        maneuver = dataclasses.replace(maneuver, duration=duration)
    rows = len(sample_times(maneuver.duration, campaign.cfg.simulation.rate_hz))
    frame = clean[index].iloc[:rows].reset_index(drop=True)
    return noisy_logs([frame], [maneuver], campaign.cfg.simulation.noise, campaign.cfg.seed)[0]


def models(cfg, seeds: list[int], campaigns: str | None, work: Path):
    """(seed, campaign, model, taken, round, logs) per seed: the first round's model or a campaign's last,
    and the logs the campaign held then (the prior's, and its collected maneuvers')."""
    for seed in seeds:
        seeded = cfg.model_copy(update={"seed": seed})
        campaign = Campaign(seeded, work / f"seed{seed}", cache_dir=Path("runs/cache"))
        campaign.prior = load_prior(seeded, campaign.nominal)
        if campaigns is None:
            fitting = campaign.fitting
            yield seed, campaign, fitting.fit(pd.DataFrame(), 0), [], 0, fitting.known_logs(None)
            continue
        found = sorted(Path(campaigns).glob(f"*/seed{seed}/{MODEL_FILE}"))
        if not found:
            raise SystemExit(f"no {MODEL_FILE} for seed {seed} under {campaigns}")
        state = CampaignState.load(found[0].parent)
        samples = found[0].parent / SAMPLES_FILE
        logs = campaign.fitting.known_logs(pd.read_parquet(samples) if samples.exists() else None)
        yield seed, campaign, load_model(found[0]), list(state.taken), len(state.rounds) - 1, logs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(CONFIGS / "safe_track.toml"))
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--fan-scales", default="1,3")
    parser.add_argument("--tolerances", default="0,0.04,0.08,0.16")
    parser.add_argument("--trust", type=float, default=0.02, help="trust_std of the kinematic guard")
    parser.add_argument("--campaigns", default=None, help="a benchmark directory: each seed's last model")
    parser.add_argument("--work", default="runs/safety_guards")
    parser.add_argument("--worst-case", action="store_true", help="also the kinematic worst case alone")
    parser.add_argument("--turn-speed", choices=("measured", "none"), default="measured",
                        help="the worst case's speed in turns: measured on the logs (default) or none lost")
    args = parser.parse_args()

    cfg = load_config(args.config)
    if cfg.safety is None:
        raise SystemExit(f"{args.config} has no [safety] section")
    base = cfg.safety
    rate = cfg.simulation.rate_hz
    scales = [float(s) for s in args.fan_scales.split(",")]
    tolerances = [float(t) for t in args.tolerances.split(",")]
    variants: list[tuple] = [(f, t, k) for f in scales for k in (False, True) for t in tolerances]
    if args.worst_case:
        variants += [("none", t, True) for t in tolerances]
    print(f"# {cfg.name}: {'first-round (prior-only) models' if args.campaigns is None else args.campaigns}, "
          f"seeds 0-{args.seeds - 1}, margin {base.margin} m, delta {base.delta}, "
          f"{base.n_samples} trajectories, pose_lever_arm {cfg.model.pose_lever_arm} m")  # fmt: skip
    print(f"{'fan_scale':>9} {'tol':>5} {'kin':>4} {'seed':>4} {'adm':>4} {'cut':>4} {'viol':>4} "
          f"{'arena':>5} {'limit':>5} {'track_s':>8} {'min_slack':>9}  violating candidates")  # fmt: skip
    totals: dict[tuple, list] = {v: [0, 0, 0, 0.0] for v in variants}
    started = time.perf_counter()
    chosen = models(cfg, list(range(args.seeds)), args.campaigns, Path(args.work))
    for seed, campaign, model, taken, round_index, logs in chosen:
        turn = turn_speed(logs, rate, base.limit_window) if args.turn_speed == "measured" else None
        open_ = np.ones(len(campaign.maneuvers), dtype=bool)
        open_[taken] = False
        clean = campaign.oracle.truth(campaign.maneuvers)
        for variant in variants:
            fan_scale, tolerance, kinematic = variant
            trust = args.trust if kinematic else NO_GUARD
            update = {"path_tolerance": tolerance, "trust_std": trust}
            if fan_scale != "none":
                update["fan_scale"] = fan_scale
            safety = base.model_copy(update=update)
            fan_seed = derived_seed(seed, Stream.ROUND, round_index)
            safe = assess(None if fan_scale == "none" else model, campaign.maneuvers, safety, rate_hz=rate,
                          seed=fan_seed, which=open_, turn=turn)  # fmt: skip
            bad, reasons, slacks = [], [], []
            for i in np.flatnonzero(safe.admissible):
                log = drive(campaign, clean, int(i), float(safe.duration[i]))
                reason = log_violation(log, base, rate)
                slacks.append(slack(log, base))
                if reason:
                    bad.append(f"{campaign.maneuvers[i].name}@{safe.duration[i]:g}s:{reason}")
                    reasons.append(reason)
            arena = sum(r == "arena" for r in reasons)
            seconds = float(safe.duration[safe.admissible].sum())
            nearest = min(slacks) if slacks else float("nan")
            print(f"{fan_scale:>9} {tolerance:>5g} {'yes' if kinematic else 'no':>4} {seed:>4} "
                  f"{safe.size:>4} {int(safe.cut.sum()):>4} {len(bad):>4} {arena:>5} {len(bad) - arena:>5} "
                  f"{seconds:>8.0f} {nearest:>9.3f}  {' '.join(bad)}", flush=True)  # fmt: skip
            total = totals[variant]
            total[0] += safe.size
            total[1] += len(bad)
            total[2] += arena
            total[3] += seconds
    print("# totals over seeds (fan_scale, path_tolerance, kinematic guard): violating / admissible")
    for (fan_scale, tolerance, kinematic), (size, bad, arena, seconds) in totals.items():
        guard = "yes" if kinematic else "no"
        print(f"  fan_scale {fan_scale}  path_tolerance {tolerance:<5g} kinematic {guard:<3}  "
              f"{bad:>3} / {size:<4} ({arena} arena)  {seconds:7.0f} s admitted")  # fmt: skip
    print(f"wall time {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
