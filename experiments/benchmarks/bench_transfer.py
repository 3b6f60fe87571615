"""Transfer across cars (issue 57, part 4): does a campaign that starts from another car's trained model
(`[design.prior] model`, `same_car = false`) need fewer signals than its vehicle file alone?

Donors: the `--donor` config's uniform campaigns, seeds `--donor-offset` + k (other picks than the
recipient's own, so a donor has not driven its recipient's maneuvers). Recipients: the `--recipient`
config, uniform, seeds k, one arm each:
  * file       no prior: the vehicle file (the control);
  * core       the donor's identified core, widened by the file's widths, as the prior (use = "data");
  * finetune   the donor's core and its correction's weights to start from (use = "finetune").
The physics kind's core must be the same in both configs; the dynamic core's scales carry across
vehicle files, so the donor may be another car.

Prints per arm and signal count the 30-s position error (mean ± s.e.m. over seeds), its paired
difference from the file arm (and on how many seeds it is lower), the 95 % fans' share of the true
positions and the identified friction and motor scales; then at which signal count each arm's mean first
reaches the file arm's final error.

Usage: python experiments/benchmarks/bench_transfer.py [--donor dynamics_f1tenth]
       [--recipient dynamics_f1tenth_twin] [--seeds 10] [--first-seed 0] [--donor-offset 100]
       [--arms file,core,finetune] [--workers 2] [--out DIR] [--quick]
`--quick` (what the test runs): one seed at quick.py's sizes.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from quick import shrink

from activelearn.config import CampaignConfig, load_config, validate_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.state import STATE_FILE
from activelearn.names import IDENTIFIED_PREFIX, ROLLOUT_COVERAGE_95, ROLLOUT_POS_ERR_30S
from activelearn.studies.compare import compare
from activelearn.studies.executors import run_jobs

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
USES = {"core": "data", "finetune": "finetune"}  # each transfer arm's `[design.prior] use`
ARMS = ("file", *USES)
COLUMNS = {"30-s error": ROLLOUT_POS_ERR_30S, "fans": ROLLOUT_COVERAGE_95,
           "friction": IDENTIFIED_PREFIX + "friction", "motor": IDENTIFIED_PREFIX + "motor"}  # fmt: skip


def config_of(name: str, out: Path, quick: bool) -> CampaignConfig:
    """A shipped config by name, its outputs (and simulation cache) under `out`."""
    cfg = load_config(CONFIGS / f"{name}.toml")
    if quick:
        return shrink(cfg, out)
    data = cfg.model_dump(mode="json")
    data["output_dir"], data["tracking"]["enabled"] = str(out), False
    return validate_config(data)


def donors(cfg: CampaignConfig, seeds: list[int], workers: int, out: Path) -> dict[int, Path]:
    """The donor car's uniform campaigns (resumed where they ran): each seed's directory."""
    compare(cfg, ["uniform"], seeds, directory=out, workers=workers, tracking=False, resume=True)
    return {seed: out / "uniform" / f"seed{seed}" for seed in seeds}


def recipient_config(cfg: CampaignConfig, arm: str, donor: Path) -> CampaignConfig:
    """The recipient's config of an arm: no prior (`file`), or the donor's model as another car's."""
    if arm == "file":
        return cfg
    data = cfg.model_dump(mode="json")
    data["design"]["prior"] = {"model": str(donor), "same_car": False, "use": USES[arm]}
    return validate_config(data)


def run_campaign(cfg_data: dict[str, Any], directory: str, seed: int) -> pd.DataFrame:
    """One recipient campaign (resumed where it ran): its rounds' metrics."""
    cfg = validate_config({**cfg_data, "seed": seed})
    resume = (Path(directory) / STATE_FILE).exists()
    history = Campaign(cfg, directory).run(resume=resume, figures=False, log_model=False).history
    return history.assign(seed=seed)


def recipients(
    cfg: CampaignConfig, arms: list[str], seeds: list[int], donor_of: dict[int, Path], workers: int, out: Path
) -> pd.DataFrame:
    """Every arm on every seed, `workers` spawned processes at a time: their rounds, one row each."""
    jobs = [
        ((arm, seed), (recipient_config(cfg, arm, donor_of[seed]).model_dump(mode="json"),
                       str(out / arm / f"seed{seed}"), seed))
        for seed in seeds for arm in arms
    ]  # fmt: skip
    frames = [history.assign(arm=arm) for (arm, _), history in run_jobs(run_campaign, jobs, workers=workers)]
    return pd.concat(frames, ignore_index=True)


def _sem(values: np.ndarray) -> float:
    return float(values.std(ddof=1) / np.sqrt(len(values))) if len(values) > 1 else float("nan")


def table(rounds: pd.DataFrame, arms: list[str]) -> str:
    """Per arm and signal count: each column's mean (the error ± s.e.m.) and the paired difference
    from the file arm; then where each arm's mean first reaches the file arm's final error."""
    error = COLUMNS["30-s error"]
    base = rounds[rounds["arm"] == "file"].set_index(["seed", "n_maneuvers"])[error]
    final = base.groupby(level="n_maneuvers").mean().iloc[-1]
    lines = [f"{'arm':<10}{'signals':>8}{'30-s error, m':>18}{'minus file':>18}{'lower':>7}"
             f"{'fans':>7}{'friction':>10}{'motor':>7}"]  # fmt: skip
    reach = []
    for arm in arms:
        own = rounds[rounds["arm"] == arm]
        for n, part in own.groupby("n_maneuvers"):
            values = part[error].to_numpy()
            paired = values - base.loc[list(zip(part["seed"], [n] * len(part), strict=True))].to_numpy()
            means = [part[c].mean() if c in part else float("nan") for c in (*COLUMNS.values(),)[1:]]
            lower = f"{int((paired < 0).sum())}/{len(paired)}"
            lines.append(f"{arm:<10}{n:>8}{values.mean():>10.3f} ± {_sem(values):<5.3f}"
                         f"{paired.mean():>+10.3f} ± {_sem(paired):<5.3f}{lower:>6}"
                         f"{means[0]:>7.3f}{means[1]:>10.3f}{means[2]:>7.3f}")  # fmt: skip
        curve = own.groupby("n_maneuvers")[error].mean()
        hit = curve[curve <= final + 1e-12]
        reach.append(f"{arm}: {hit.index[0] if len(hit) else 'never'}")
    lines.append(f"first signal count at which an arm's mean reaches the file arm's final {final:.3f} m: "
                 + ", ".join(reach))  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--donor", default="dynamics_f1tenth", help="the donor config (experiments/configs)")
    parser.add_argument("--recipient", default="dynamics_f1tenth_twin", help="the recipient's config")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--donor-offset", type=int, default=100, help="donor seed = offset + recipient seed")
    parser.add_argument("--arms", default=",".join(ARMS), help=f"from {', '.join(ARMS)} (file always runs)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("runs/bench_transfer"))
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    arms = ["file", *[a for a in args.arms.split(",") if a != "file"]]
    unknown = sorted(set(arms) - set(ARMS))
    if unknown:
        parser.error(f"--arms: unknown {', '.join(unknown)}; choose from {', '.join(ARMS)}")
    seeds = list(range(args.first_seed, args.first_seed + (1 if args.quick else args.seeds)))
    donor_cfg = config_of(args.donor, args.out, args.quick)
    recipient_cfg = config_of(args.recipient, args.out, args.quick)
    if donor_cfg.model.core != recipient_cfg.model.core or recipient_cfg.model.kind != "physics":
        parser.error("--donor and --recipient must both run the physics kind on the same core")
    start = time.perf_counter()
    donor_of = donors(donor_cfg, [args.donor_offset + s for s in seeds], args.workers, args.out / "donors")
    donor_of = {s: donor_of[args.donor_offset + s] for s in seeds}
    rounds = recipients(recipient_cfg, arms, seeds, donor_of, args.workers, args.out / "recipients")
    print(f"## Transfer: {args.recipient} from {args.donor}'s models, uniform, seeds {seeds[0]}-{seeds[-1]} "
          f"(donors {args.donor_offset + seeds[0]}-{args.donor_offset + seeds[-1]}), "
          f"{time.perf_counter() - start:.0f} s")  # fmt: skip
    print(table(rounds, arms))


if __name__ == "__main__":
    main()
