"""Strategy comparison: strategies × seeds under one parent MLflow run, curves, figure and table."""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from activelearn.config import CampaignConfig
from activelearn.data import atomic_write_bytes
from activelearn.errors import InputError
from activelearn.loop.campaign import Campaign
from activelearn.loop.lock import DEFAULT_WAIT
from activelearn.loop.state import STATE_FILE
from activelearn.names import (
    CURVE_METRICS,
    N_MANEUVERS,
    RANKING_METRICS,
    REFERENCE_STRATEGY,
    ROUND,
    TEST_NLL,
    TEST_RMSE,
    TEST_RMSE_V,
    TEST_RMSE_W,
    TRACK_SECONDS,
)
from activelearn.studies.executors import check_executor, run_jobs

Progress = Callable[[dict[str, Any]], None]
FIGURE_ARTIFACT = "comparison.png"  # the figure in the comparison directory and on the parent run


@dataclass(frozen=True)
class Comparison:
    """Per-round metrics of every campaign, the summary table and the figure's path."""

    curves: pd.DataFrame
    table: pd.DataFrame
    figure_path: Path | None
    directory: Path
    parent_run_id: str | None


def _run_job(
    cfg_json: str,
    directory: str,
    cache_dir: str,
    tracking: tuple[str, str] | None,
    parent_run_id: str | None,
    resume: bool,
    single_thread: bool,
    lock_wait: float = DEFAULT_WAIT,
) -> list[dict[str, Any]]:
    """Worker: run one campaign and return its per-round metrics."""
    import torch

    if single_thread:  # two busy processes on two cores: intra-op threads would only fight
        torch.set_num_threads(1)
    cfg = CampaignConfig.model_validate_json(cfg_json)
    tracker = None
    if tracking is not None:
        from activelearn.studies.tracking import Tracker

        tracker = Tracker(*tracking)
    campaign = Campaign(cfg, directory, cache_dir=cache_dir, tracker=tracker, parent_run_id=parent_run_id)
    campaign.lock_wait = lock_wait
    result = campaign.run(resume=resume, figures=True, log_model=False)
    return result.state.rounds


def first_reach(budget: np.ndarray, rmse: np.ndarray, target: float) -> float:
    """The smallest budget at which the curve is at or below `target` (NaN if never)."""
    hit = np.flatnonzero(rmse <= target)
    return float(budget[hit[0]]) if len(hit) else math.nan


def standard_error(values: np.ndarray) -> float:
    """The standard error of the mean (0 for a single value)."""
    return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else 0.0


def _summary(curves: pd.DataFrame, reference: str, metric: str = TEST_RMSE) -> pd.DataFrame:
    """Per strategy: final RMSE (standardised, and v in m/s, ω in rad/s), NLL, area under the RMSE
    curve, and the maneuvers and track seconds each seed needed to reach the reference's final value
    of `metric` (lower is better). Another metric than test_rmse adds its final mean, s.e.m. and
    area as `final_metric`, `final_metric_sem` and `metric_auc`."""
    rows = []
    ref = curves[curves["strategy"] == reference]
    ref_final = ref.sort_values(N_MANEUVERS).groupby("seed").last()
    target = float(ref_final[metric].mean()) if len(ref_final) else math.nan
    ref_budget = float(ref_final[N_MANEUVERS].mean()) if len(ref_final) else math.nan
    has_seconds = TRACK_SECONDS in curves
    ref_seconds = float(ref_final[TRACK_SECONDS].mean()) if has_seconds and len(ref_final) else math.nan
    for strategy, part in curves.groupby("strategy", sort=False):
        finals = part.sort_values(N_MANEUVERS).groupby("seed").last()
        aucs, metric_aucs, reach, reach_s = [], [], [], []
        for _, run in part.groupby("seed"):
            run = run.sort_values(N_MANEUVERS)
            n, rmse = run[N_MANEUVERS].to_numpy(float), run[TEST_RMSE].to_numpy(float)
            ranked = run[metric].to_numpy(float)
            aucs.append(_area(n, rmse))
            metric_aucs.append(_area(n, ranked))
            reach.append(first_reach(n, ranked, target))
            if has_seconds:
                reach_s.append(first_reach(run[TRACK_SECONDS].to_numpy(float), ranked, target))
        reach_arr = np.array(reach)
        reached = reach_arr[~np.isnan(reach_arr)]
        seconds = np.array(reach_s)
        seconds = seconds[~np.isnan(seconds)]
        row = {
            "strategy": strategy,
            "seeds": len(finals),
            "final_rmse": float(finals[TEST_RMSE].mean()),
            "final_rmse_sem": standard_error(finals[TEST_RMSE].to_numpy()),
            "final_rmse_v": float(finals[TEST_RMSE_V].mean()),
            "final_rmse_w": float(finals[TEST_RMSE_W].mean()),
            "final_nll": float(finals[TEST_NLL].mean()),
            "rmse_auc": float(np.mean(aucs)),
            **(
                {}
                if metric == TEST_RMSE
                else {
                    "final_metric": float(finals[metric].mean()),
                    "final_metric_sem": standard_error(finals[metric].to_numpy()),
                    "metric_auc": float(np.mean(metric_aucs)),
                }
            ),
            "reached": f"{len(reached)}/{len(reach_arr)}",
            "maneuvers_to_target": float(np.median(reached)) if len(reached) else math.nan,
            "ratio_to_reference": float(np.median(reached) / ref_budget) if len(reached) else math.nan,
        }
        if has_seconds:
            row["seconds_to_target"] = float(np.median(seconds)) if len(seconds) else math.nan
            row["seconds_ratio"] = float(np.median(seconds) / ref_seconds) if len(seconds) else math.nan
        rows.append(row)
    table = pd.DataFrame(rows)
    table.attrs["target_rmse"] = target  # the reference's final value of `metric`
    table.attrs["metric"] = metric
    table.attrs["reference"] = reference
    return table


def _area(budget: np.ndarray, values: np.ndarray) -> float:
    """Mean height of a learning curve over its budget span (its last value when the span is 0)."""
    span = budget[-1] - budget[0]
    return float(np.trapezoid(values, budget) / span) if span > 0 else float(values[-1])


def compare(
    cfg: CampaignConfig,
    strategies: Sequence[str],
    seeds: Sequence[int],
    *,
    directory: str | Path | None = None,
    workers: int | None = None,
    tracking: bool = True,
    resume: bool = False,
    progress: Progress | None = None,
    executor: str = "process",
    ray_address: str | None = None,
    metric: str | None = None,
    lock_wait: float = DEFAULT_WAIT,
) -> Comparison:
    """Run every strategy with every seed on one config and compare them against `uniform`.

    `metric` (default: the config's `[test] metric`) is what the table ranks by and the figure shows
    first: a one-step test error, or a free-running rollout error for dynamics models.

    `tracking` False, or `[tracking] enabled = false`, logs nothing to MLflow.

    `executor` "process" runs `workers` local processes; "ray" one task per campaign on the Ray
    cluster at `ray_address` (see `activelearn.studies.executors`). Each campaign holds its directory's
    lock while it runs; one another command writes waits up to `lock_wait` s. The output directory, the
    simulation cache (under `cfg.output_dir`) and the tracking store must be reachable by every node.
    """
    from activelearn.loop.acquisition import STRATEGIES

    metric = metric or cfg.test.metric
    if metric not in RANKING_METRICS:
        raise InputError("--metric", metric, f"unknown metric; choose from {', '.join(RANKING_METRICS)}")
    if metric.startswith("rollout_") and not cfg.test.rollout_samples:
        raise InputError("--metric", metric, "needs rollouts: the config sets [test] rollout_samples = 0")
    for name in strategies:
        if name not in STRATEGIES:
            raise InputError("--strategies", name, f"unknown strategy; choose from {', '.join(STRATEGIES)}")
    if not strategies:
        raise InputError("--strategies", "", "name at least one strategy")
    if not seeds:
        raise InputError("--seeds", 0, "must be at least 1")
    check_executor(executor, ray_address)
    progress = progress or (lambda event: None)
    directory = Path(directory or Path(cfg.output_dir) / cfg.name / "compare")
    if (directory / "curves.csv").exists() and not resume:
        raise InputError(
            "--out", str(directory), "holds a comparison already; pass --resume or another --out"
        )
    if not resume:
        for strategy in strategies:
            for seed in seeds:
                if (directory / strategy / f"seed{seed}" / STATE_FILE).exists():
                    raise InputError(
                        "--out", str(directory), "holds campaigns already; pass --resume or another --out"
                    )
    workers = max(1, min(workers or os.cpu_count() or 1, len(strategies) * len(seeds)))
    reference = REFERENCE_STRATEGY if REFERENCE_STRATEGY in strategies else strategies[0]

    tracker, parent_run_id = None, None
    tracking = tracking and cfg.tracking.enabled  # `[tracking] enabled = false` holds here too
    if tracking:  # an unreachable store fails here, before anything is simulated or written
        from activelearn.studies.tracking import Tracker

        tracker = Tracker(cfg.tracking.uri, cfg.tracking.experiment)
    # Simulate the whole pool and the test set once, with every core, before the workers start.
    # The oracle says what it simulates (the nominal simulator or a twin, the pool under a live stop).
    from activelearn.loop.collection import cache_root
    from activelearn.loop.oracles import make_oracle

    cache_dir = cache_root(cfg)
    jobs = make_oracle(cfg, cache_dir).simulations()

    def sim_progress(done: int, total: int) -> None:
        progress({"event": "sim_progress", "done": done, "total": total})

    for store, maneuvers in jobs:
        todo = store.missing(maneuvers)
        if todo:
            progress({"event": "simulate", "n": len(todo)})
            store.get(todo, progress=sim_progress)

    manifest = directory / "compare.json"
    if tracker is not None:
        previous = (
            json.loads(manifest.read_text()).get("parent_run_id") if resume and manifest.exists() else None
        )
        # A resumed comparison reopens its parent run, so resumed children stay nested under it.
        parent_run_id = tracker.start_run(
            f"compare-{cfg.name}", tags={"kind": "comparison"}, resume_run_id=previous
        )
        tracker.log_params(parent_run_id, comparison_params(cfg, strategies, seeds, metric, reference))
        tracker.set_note(parent_run_id, comparison_note(cfg, strategies, seeds, metric, reference))
    directory.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(
        manifest,
        json.dumps(
            {"parent_run_id": parent_run_id, "strategies": list(strategies), "seeds": list(seeds)}
        ).encode(),
    )

    jobs = [(s, seed) for s in strategies for seed in seeds]
    tracking_args = (cfg.tracking.uri, cfg.tracking.experiment) if tracking else None

    def job_args(strategy: str, seed: int) -> tuple:
        return (
            cfg.model_copy(update={"strategy": strategy, "seed": seed}).model_dump_json(),
            str(directory / strategy / f"seed{seed}"),
            str(cache_dir),
            tracking_args,
            parent_run_id,
            # A Ray task may be a retry after its worker died: it continues the campaign's checkpoint
            # (the directories were checked above, so nothing else can be there).
            resume or executor == "ray",
            workers > 1 or executor == "ray",
            lock_wait,
        )

    results: dict[tuple[str, int], list[dict[str, Any]]] = {}

    def finished(key: tuple[str, int], rounds: list[dict[str, Any]]) -> None:
        results[key] = rounds
        progress(
            {
                "event": "job",
                "done": len(results),
                "total": len(jobs),
                "strategy": key[0],
                "seed": key[1],
                TEST_RMSE: rounds[-1][TEST_RMSE],
            }
        )

    try:
        keyed = [(key, job_args(*key)) for key in jobs]
        for key, rounds in run_jobs(
            _run_job, keyed, executor=executor, workers=workers, ray_address=ray_address, on_start=progress
        ):
            finished(key, rounds)
    except BaseException:
        if tracker is not None and parent_run_id is not None:
            tracker.end_run(parent_run_id, "KILLED")
        raise

    records = [{"strategy": s, "seed": seed, **r} for (s, seed), rounds in results.items() for r in rounds]
    curves = pd.DataFrame(records).sort_values(["strategy", "seed", ROUND]).reset_index(drop=True)
    if metric not in curves:
        raise InputError("--metric", metric, "these campaigns did not log it (a test set without logs?)")
    table = _summary(curves, reference, metric)
    curves.to_csv(directory / "curves.csv", index=False)
    table.to_csv(directory / "summary.csv", index=False)

    from activelearn.plots import comparison_figure, save_figure

    shown = (metric, *(m for m in CURVE_METRICS if m != metric and m in curves))
    fig = comparison_figure(
        curves, shown, reference=reference, title=cfg.name,
        seconds=TRACK_SECONDS in curves,
    )  # fmt: skip
    figure_path = save_figure(fig, directory / FIGURE_ARTIFACT, dpi=110)
    if tracker is not None and parent_run_id is not None:
        tracker.log_figure(parent_run_id, fig, FIGURE_ARTIFACT)
        tracker.log_artifact(parent_run_id, directory / "summary.csv")
        tracker.log_artifact(parent_run_id, directory / "curves.csv")
        tracker.log_metric_series(parent_run_id, band_series(curves, dict.fromkeys((metric, TEST_RMSE))))
        for row in table.itertuples():
            tracker.log_metrics(
                parent_run_id,
                {
                    f"summary/{row.strategy}_final_rmse": row.final_rmse,
                    f"summary/{row.strategy}_final_rmse_v_mps": row.final_rmse_v,
                    f"summary/{row.strategy}_final_rmse_w_radps": row.final_rmse_w,
                    f"summary/{row.strategy}_rmse_auc": row.rmse_auc,
                },
                step=0,
            )
        note = comparison_note(cfg, strategies, seeds, metric, reference, table, parent_run_id)
        tracker.set_note(parent_run_id, note)
        tracker.end_run(parent_run_id, "FINISHED")
    return Comparison(curves, table, figure_path, directory, parent_run_id)


# ------------------------------------------------------------------------------- the parent MLflow run

def config_hash(cfg: CampaignConfig) -> str:
    """A short hash of what every campaign of a comparison shares: the config without strategy and seed."""
    shared = cfg.model_dump(mode="json", exclude={"strategy", "seed"})
    return hashlib.sha256(json.dumps(shared, sort_keys=True).encode()).hexdigest()[:12]


def comparison_params(
    cfg: CampaignConfig, strategies: Sequence[str], seeds: Sequence[int], metric: str, reference: str
) -> dict[str, Any]:
    """The parent run's params: what is true of the whole comparison (the strategies, the seeds, the
    config every campaign shares, its hash), never one campaign's `strategy` or `seed`."""
    return {
        "strategies": list(strategies),
        "seeds": list(seeds),
        "campaigns": len(strategies) * len(seeds),
        "config": cfg.name,
        "config_hash": config_hash(cfg),
        "metric": metric,
        "reference": reference,
        **cfg.model_dump(mode="json", exclude={"strategy", "seed", "name"}),
    }


def _budget(cfg: CampaignConfig) -> str:
    design = cfg.design
    parts = [f"{design.initial} initial maneuvers, then {design.per_round} a round"]
    if design.max_maneuvers is not None:
        parts.append(f"up to {design.max_maneuvers} maneuvers")
    if design.max_rounds is not None:
        parts.append(f"up to {design.max_rounds} rounds")
    if design.max_sim_seconds is not None:
        parts.append(f"up to {design.max_sim_seconds:g} track seconds")
    prior = " (on top of a prior the model already knows)" if design.prior is not None else ""
    return ", ".join(parts) + prior


def comparison_note(
    cfg: CampaignConfig,
    strategies: Sequence[str],
    seeds: Sequence[int],
    metric: str,
    reference: str,
    table: pd.DataFrame | None = None,
    run_id: str | None = None,
) -> str:
    """The parent run's description (MLflow's note, Markdown): what was compared, where the figure and
    the charts are; with the summary `table`, each strategy's final value of `metric`, and with the
    parent's `run_id` the figure itself (MLflow's page draws an image of the run's own artifact)."""
    lines = [
        f"**Strategy comparison** on config `{cfg.name}` (hash `{config_hash(cfg)}`): "
        f"{', '.join(f'`{s}`' for s in strategies)} × seeds {', '.join(map(str, seeds))} "
        f"({len(strategies) * len(seeds)} campaigns, the nested runs `<strategy>/seed<k>`), "
        f"ranked by `{metric}` against `{reference}`.",
        "",
        f"Budget: {_budget(cfg)}.",
        "",
        f"**Figure**: at the end of this description (*Show more*), and the artifact `{FIGURE_ARTIFACT}` "
        "(Artifacts tab): learning curves, mean ± 1 s.e. over seeds.",
        "",
        f"**Charts**: this run's *Model metrics* tab holds each strategy's `<strategy>/{metric}_mean`, `_lo` "
        "and `_hi` (mean ± 1 s.e. over seeds) at step = maneuvers collected. The nested runs log every "
        "round at the same steps: on the experiment's *Chart* view, *Group by* → tag `strategy` draws one "
        "line and band per strategy.",
    ]
    if table is not None and "final_rmse" in table:
        final = "final_rmse" if metric == TEST_RMSE else "final_metric"
        spread = "final_rmse_sem" if metric == TEST_RMSE else "final_metric_sem"
        lines += ["", f"| strategy | final {metric} | ± s.e. | maneuvers to reach {reference} |",
                  "|---|---|---|---|"]  # fmt: skip
        for row in table.itertuples():
            lines.append(
                f"| {row.strategy} | {getattr(row, final):.4g} | {getattr(row, spread):.2g} "
                f"| {row.maneuvers_to_target:.3g} ({row.reached}) |"
            )
    if run_id is not None:
        lines += ["", f"![learning curves, mean ± 1 s.e. over seeds](get-artifact?path={FIGURE_ARTIFACT}"
                      f"&run_uuid={run_id})"]  # fmt: skip
    return "\n".join(lines)


def band_series(curves: pd.DataFrame, metrics: Sequence[str]) -> list[tuple[int, dict[str, float]]]:
    """Each strategy's mean ± 1 s.e. over seeds of `metrics`, as (step, metrics) rows for MLflow.

    Step = maneuvers collected (`n_maneuvers`), the step of every round of the nested runs; a step is
    averaged over the seeds that reached it. Keys `<strategy>/<metric>_mean`, `_lo`, `_hi`; one seed
    gives a band of width 0.
    """
    rows: dict[int, dict[str, float]] = {}
    for (strategy, step), part in curves.groupby(["strategy", N_MANEUVERS], sort=True):
        values = rows.setdefault(int(step), {})
        for metric in metrics:
            if metric not in part:
                continue
            column = part[metric].to_numpy(float)
            column = column[np.isfinite(column)]
            if not len(column):
                continue
            mean, sem = float(column.mean()), standard_error(column)
            values.update({f"{strategy}/{metric}_mean": mean, f"{strategy}/{metric}_lo": mean - sem,
                           f"{strategy}/{metric}_hi": mean + sem})  # fmt: skip
    return sorted(rows.items())
