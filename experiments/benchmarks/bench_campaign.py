"""Where a campaign's time goes: one campaign per config, its wall time split by section, per round.

Runs each config's campaign (one strategy and seed, no figures) with its sections timed:
the fit (identification, one-step steps, multi-step windows, the correction gate's probe, validation,
calibration), the evaluation (the test set's free runs), acquisition (candidates' predicted paths, the
strategy's pick), [safety], the oracle's simulations, checkpoints and, with `--tracking`, MLflow. A
section is timed where it is entered from outside itself (nested calls count once), so sub-sections sum
to at most their parent.
Prints, per config: a table of seconds, calls and share of the wall time, then each round's wall
seconds and the epochs its fits ran. The test set is simulated before the campaign starts (once per
config and cached: in a comparison every seed after the first finds it so) and its seconds are
printed apart, outside the wall.

With `--variant NAME:SECTION.KEY=VALUE[,...]` (repeatable; values in TOML) every config also runs with
those overrides, and the table puts the variants' seconds side by side and, per variant, the configured
campaign's seconds over the variant's ("conf/NAME"; 0.4: the configured one takes 0.4 of the time).

Usage: python experiments/benchmarks/bench_campaign.py [--configs dynamics,demo] [--strategy uniform]
       [--seed 1] [--variant fresh:training.warm_start=false] [--tracking] [--quick] [--out DIR]
"""

from __future__ import annotations

import argparse
import functools
import tempfile
import time
import tomllib
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from quick import shrink

from activelearn.config import CampaignConfig, load_config
from activelearn.loop import campaign as campaign_module
from activelearn.loop.evaluation import Evaluation
from activelearn.loop.fitting import Fitting
from activelearn.loop.run_log import RunLog
from activelearn.loop.strategy import Strategy
from activelearn.names import WALL_SECONDS
from activelearn.numerics import training
from activelearn.numerics.models.base import Model

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@dataclass
class Clock:
    """Seconds and calls per section; a section re-entered from inside itself counts once."""

    seconds: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    calls: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    depth: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    fits: list[tuple[float, int]] = field(default_factory=list)  # each round's fit: seconds, epochs

    def timed(self, section: str, function: Callable) -> Callable:
        @functools.wraps(function)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            self.calls[section] += 1
            if self.depth[section]:
                return function(*args, **kwargs)
            self.depth[section] += 1
            started = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                self.seconds[section] += time.perf_counter() - started
                self.depth[section] -= 1

        return wrapper


# (section, owner, attribute): what is timed. Owners are the classes and modules the loop calls
# through, so wrapping their attribute times every call the campaign makes.
SECTIONS: tuple[tuple[str, Any, str], ...] = (
    ("fit", Fitting, "fit"),
    ("fit / identification", Model, "identify"),
    ("fit / epochs", training._Stepper, "epoch"),
    ("fit / epochs / multi-step windows", training, "window_loss"),
    ("fit / correction gate's probe", training, "choose_correction_weight"),
    ("fit / validation", training, "_validate"),
    ("fit / calibration", training, "recalibrate_epistemic"),
    ("evaluation (test set's free runs)", Evaluation, "evaluate"),
    ("evaluation / prequential fans", Evaluation, "prequential"),
    ("acquisition / candidates' paths", campaign_module.Campaign, "pool"),
    ("acquisition / the strategy's pick", Strategy, "pick"),
    ("safety admission", campaign_module.Campaign, "admit"),
    ("oracle (simulations)", campaign_module.Campaign, "_answer"),
    ("checkpoints", campaign_module.Campaign, "_checkpoint"),
    ("tracking (MLflow, with --tracking)", RunLog, "flush"),
    ("tracking (MLflow, with --tracking)", RunLog, "start"),
    ("tracking (MLflow, with --tracking)", RunLog, "finish"),
)


def _instrumented(clock: Clock) -> list[tuple[Any, str, Any]]:
    """Wrap every section (and each subclass's override of it); returns what to restore."""
    saved = []
    owners: list[tuple[str, Any, str]] = []
    for section, owner, name in SECTIONS:
        owners.append((section, owner, name))
        if isinstance(owner, type):  # e.g. each model kind's own `identify`, each oracle's `test_set`
            owners += [(section, sub, name) for sub in _subclasses(owner) if name in vars(sub)]
    for section, owner, name in owners:
        original = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
        saved.append((owner, name, original))
        setattr(owner, name, clock.timed(section, getattr(owner, name)))
    return saved


def _subclasses(cls: type) -> list[type]:
    found = []
    for sub in cls.__subclasses__():
        found += [sub, *_subclasses(sub)]
    return found


def _restore(saved: list[tuple[Any, str, Any]]) -> None:
    for owner, name, original in reversed(saved):
        setattr(owner, name, original)


# clock, wall s, rounds' metrics, the ranking metric, seconds of the test set's simulation
Run = tuple[Clock, float, list[dict[str, Any]], str, float]


def profile(cfg: CampaignConfig, directory: Path, tracking: str | None = None) -> Run:
    """Run one campaign with its sections timed: the clock, wall seconds and the rounds' metrics;
    `tracking`: an MLflow store URI to log it to, as `activelearn campaign run` does (None: not logged)."""
    clock = Clock()
    saved = _instrumented(clock)
    fit = Fitting.fit

    def counted_fit(self: Fitting, *args: Any, **kwargs: Any) -> Any:
        epochs = clock.calls["fit / epochs"]
        started = time.perf_counter()
        try:
            return fit(self, *args, **kwargs)
        finally:
            clock.fits.append((time.perf_counter() - started, clock.calls["fit / epochs"] - epochs))

    Fitting.fit = counted_fit  # type: ignore[method-assign]
    try:
        tracker = None
        if tracking is not None:
            from activelearn.studies.tracking import Tracker

            tracker = Tracker(tracking, cfg.tracking.experiment)
        campaign = campaign_module.Campaign(cfg, directory, tracker=tracker)
        started = time.perf_counter()
        campaign.test_set  # noqa: B018 (simulated once per config and cached)
        test_set = time.perf_counter() - started
        started = time.perf_counter()
        result = campaign.run(figures=False, log_model=False)
        wall = time.perf_counter() - started
    finally:
        Fitting.fit = fit  # type: ignore[method-assign]
        _restore(saved)
    return clock, wall, list(result.state.rounds), cfg.test.metric, test_set


def _config(
    name: str, seed: int, strategy: str, overrides: dict[str, Any], out: Path, quick: bool
) -> CampaignConfig:
    cfg = load_config(CONFIGS / f"{name}.toml", overrides={
        **overrides, "seed": seed, "strategy": strategy, "output_dir": str(out),
        "tracking": {"enabled": False}})  # fmt: skip
    return shrink(cfg, out) if quick else cfg


def _table(name: str, runs: dict[str, Run]) -> str:
    variants = list(runs)
    first = variants[0]
    sections = list(dict.fromkeys(s for s, _, _ in SECTIONS))  # a section may wrap several methods
    head = f"{'section':42s}" + "".join(f"{v + ' s':>12s}{'share':>7s}" for v in variants)
    if len(variants) > 1:
        head += "".join(f"{'conf/' + v:>11s}" for v in variants[1:])
    lines = [head]
    for section in ["wall", *sections]:
        cells, base = "", None
        for variant in variants:
            clock, wall, _, _, _ = runs[variant]
            seconds = wall if section == "wall" else clock.seconds.get(section, 0.0)
            base = seconds if variant == first else base
            cells += f"{seconds:12.1f}{100 * seconds / wall:6.0f}%"
        if all(section != "wall" and runs[v][0].calls.get(section, 0) == 0 for v in variants):
            continue  # a section this config never enters
        ratios = ""
        for variant in variants[1:]:
            clock, wall, _, _, _ = runs[variant]
            seconds = wall if section == "wall" else clock.seconds.get(section, 0.0)
            ratios += f"{(base / seconds if seconds > 0 else float('nan')):11.2f}"
        lines.append(f"{section:42s}{cells}{ratios}")
    for variant in variants:
        clock, wall, rounds, metric, test_set = runs[variant]
        walls = [r[WALL_SECONDS] for r in rounds]
        per_round = [b - a for a, b in zip([0.0, *walls[:-1]], walls, strict=True)]
        fits = clock.fits[: len(rounds)]
        mean = sum(per_round) / max(len(per_round), 1)
        walls_text = " ".join(f"{s:.1f}" for s in per_round)
        lines.append(f"{variant}: {len(rounds)} rounds, wall s by round {walls_text} (mean {mean:.1f})")
        lines.append(f"{variant}: fit s by round " + " ".join(f"{s:.1f}" for s, _ in fits)
                     + "; epochs by round " + " ".join(str(e) for _, e in fits))  # fmt: skip
        lines.append(f"{variant}: the test set's simulation before the campaign {test_set:.1f} s")
        if rounds and metric in rounds[-1]:
            lines.append(f"{variant}: final {metric} {rounds[-1][metric]:.4g}")
    return f"== {name}\n" + "\n".join(lines)


def overrides_of(spec: str) -> tuple[str, dict[str, Any]]:
    """`NAME:section.key=value,...` as (NAME, nested overrides); values are TOML (true, 37, "x")."""
    name, _, assignments = spec.partition(":")
    overrides: dict[str, Any] = {}
    for assignment in filter(None, assignments.split(",")):
        path, _, value = assignment.partition("=")
        *sections, key = path.strip().split(".")
        node = overrides
        for section in sections:
            node = node.setdefault(section, {})
        node[key] = tomllib.loads(f"v = {value.strip()}")["v"]
    return name, overrides


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--configs", default="dynamics,demo", help="comma-separated config names")
    parser.add_argument("--strategy", default="uniform")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--variant", action="append", default=[], metavar="NAME:SECTION.KEY=VALUE[,...]",
        help="also run every config with these overrides (values in TOML)",
    )  # fmt: skip
    parser.add_argument(
        "--tracking", action="store_true", help="log each campaign to MLflow (SQLite, in the scratch dir)"
    )
    parser.add_argument("--quick", action="store_true", help="quick sizes (checks the benchmark runs)")
    parser.add_argument("--out", type=Path, default=None, help="scratch directory (default: a temporary one)")
    args = parser.parse_args()
    variants: dict[str, dict[str, Any]] = {"as configured": {}}
    for spec in args.variant:
        name, overrides = overrides_of(spec)
        variants[name] = overrides
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        for config in args.configs.split(","):
            runs = {}
            for variant, overrides in variants.items():
                directory = out / config / variant.replace(" ", "_")
                cfg = _config(config, args.seed, args.strategy, overrides, directory, args.quick)
                store = f"sqlite:///{out / 'mlruns.db'}" if args.tracking else None
                runs[variant] = profile(cfg, directory / "campaign", store)
            print(_table(f"{config}: {args.strategy}, seed {args.seed}", runs), flush=True)


if __name__ == "__main__":
    main()
