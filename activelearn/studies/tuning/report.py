"""What a study found: the best trials, a `--params` TOML snippet, the figures, and the summary of one
`tune` call (counts, best values) that also goes to its MLflow parent run."""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import optuna
import pandas as pd
from optuna.trial import FrozenTrial, TrialState

from activelearn.data import atomic_write_bytes
from activelearn.studies.tuning.storage import open_storage, redact, replaced
from activelearn.studies.tuning.workers import Job, Supervision


@dataclass(frozen=True)
class TuningResult:
    """What a `tune` call did and found."""

    study_name: str
    storage: str  # password hidden
    objectives: tuple[str, ...]
    states: dict[str, int]  # finished trials of this call, by state
    study_trials: int  # finished trials of the whole study
    best: pd.DataFrame  # best trials of the study (the Pareto front when multi-objective)
    best_params: dict[str, dict[str, Any]] | None
    best_values: tuple[float, ...] | None
    best_number: int | None
    best_path: Path | None
    figures: tuple[Path, ...]
    parent_run_id: str | None
    wall_seconds: float  # optimisation only (after the data are ready)
    notes: tuple[str, ...] = field(default_factory=tuple)
    # One line per worker lost mid-study (the study still got its trials; see `lost_trials`).
    warnings: tuple[str, ...] = field(default_factory=tuple)
    lost_trials: tuple[int, ...] = field(default_factory=tuple)  # failed with their worker, queued again

    @property
    def n_trials(self) -> int:
        """Finished trials of this call."""
        return sum(self.states.values())

    @property
    def trials_per_minute(self) -> float:
        """Finished trials of this call per minute of optimisation."""
        return 60.0 * self.n_trials / self.wall_seconds if self.wall_seconds > 0 else math.nan



def best_trials(study: optuna.Study, limit: int = 5) -> list[FrozenTrial]:
    """Best complete trials: lowest NLL first, or the Pareto front (by NLL) when multi-objective."""
    if len(study.directions) > 1:
        front = study.best_trials
        return sorted(front, key=lambda t: t.values[0])
    done = [t for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)) if t.values]
    return sorted(done, key=lambda t: (t.values[0], t.number))[:limit]


def study_trials(storage: str, study_name: str) -> list[dict[str, Any]]:
    """Trials of a stored study as plain dicts, by number (state, values, params, attrs, steps, seconds)."""
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    study = optuna.load_study(study_name=study_name, storage=open_storage(storage))
    return [
        {
            "number": t.number,
            "state": t.state.name,
            "values": list(t.values) if t.values is not None else None,
            "params": dict(t.params),
            "user_attrs": dict(t.user_attrs),
            "last_step": t.last_step,
            "seconds": t.duration.total_seconds() if t.duration is not None else None,
        }
        for t in sorted(study.get_trials(deepcopy=False), key=lambda t: t.number)
    ]


def _best_table(trials: Sequence[FrozenTrial], objectives: Sequence[str]) -> pd.DataFrame:
    rows = []
    for t in trials:
        model, training = t.user_attrs.get("model", {}), t.user_attrs.get("training", {})
        row: dict[str, Any] = {"trial": t.number}
        row.update({f"val_{name}": value for name, value in zip(objectives, t.values, strict=False)})
        row.update({"arch": model.get("arch"), "activation": model.get("activation"),
                    "posterior": model.get("posterior"), "kl": model.get("kl"),
                    "prior_scale": model.get("prior_scale"), "lr": training.get("lr"),
                    "optimizer": training.get("optimizer"), "loss": training.get("loss"),
                    "batch_size": training.get("batch_size"), "epochs": training.get("epochs"),
                    "best_epoch": t.user_attrs.get("best_epoch")})  # fmt: skip
        rows.append(row)
    return pd.DataFrame(rows)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return (
            repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf" if value < 0 else "nan")
        )
    return json.dumps(str(value))


def params_toml(model: Mapping[str, Any], training: Mapping[str, Any], header: Sequence[str] = ()) -> str:
    """A TOML snippet with [model] and [training] tables (what `campaign run --params` merges)."""
    lines = [f"# {h}" for h in header]
    for table, values in (("model", model), ("training", training)):
        lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in values.items()]
    return "\n".join(lines).lstrip("\n") + "\n"


def figures_of(study: optuna.Study, directory: Path) -> tuple[list[Path], list[str]]:
    """Optimisation history and parameter importances as PNGs (skipped with a note when impossible)."""
    import matplotlib.pyplot as plt
    from optuna.visualization import matplotlib as ovm

    from activelearn.plots import save_figure

    kwargs: dict[str, Any] = {}
    if len(study.directions) > 1:
        kwargs = {"target": lambda t: t.values[0], "target_name": "validation NLL"}
    else:
        kwargs = {"target_name": "validation NLL"}
    paths, notes = [], []
    for name, plot in (("optimization_history", ovm.plot_optimization_history),
                       ("param_importances", ovm.plot_param_importances)):  # fmt: skip
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # Optuna marks its matplotlib plots experimental
                ax = plot(study, **kwargs)
        except (ValueError, RuntimeError, ZeroDivisionError) as exc:
            notes.append(f"no {name.replace('_', ' ')} figure: {exc}")
            continue
        fig = ax.figure
        fig.set_size_inches(8, 5)
        fig.tight_layout()
        path = save_figure(fig, directory / f"{name}.png", dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths, notes


def summarise(
    study: optuna.Study, job: Job, tracker: Any, out: str | Path | None, wall: float, notes: list[str],
    seen: Supervision,
) -> TuningResult:
    """Summarise the study: counts, best trials, best.toml, figures; log them to the parent run."""
    finished_states = (TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL)
    trials = study.get_trials(deepcopy=False, states=finished_states)
    lost = replaced(study.get_trials(deepcopy=False))
    # This call's trials, less those lost with their worker: each was queued again (or replaced by a
    # fresh trial) and its retry counts instead.
    mine = [t for t in trials if t.user_attrs.get("run") == job.run_token and t.number not in lost]
    states = {s.name: sum(t.state == s for t in mine) for s in finished_states}
    best = best_trials(study)
    table = _best_table(best, job.objectives)
    out_path = (
        Path(out) if out is not None else Path(job.cfg.output_dir) / "tuning" / job.study_name / "best.toml"
    )
    best_params = best_values = best_number = best_path = None
    figures: list[Path] = []
    if best:
        top = best[0]
        best_params = {"model": dict(top.user_attrs["model"]), "training": dict(top.user_attrs["training"])}
        best_values, best_number = tuple(top.values), top.number
        header = [
            f"Best trial {top.number} of Optuna study {job.study_name!r} ({redact(job.storage_url)}):",
            "validation "
            + ", ".join(f"{n.upper()} {v:.6g}" for n, v in zip(job.objectives, top.values, strict=True)),
            "Use: activelearn campaign run CONFIG --params " + out_path.name,
        ]
        atomic_write_bytes(
            out_path, params_toml(best_params["model"], best_params["training"], header).encode()
        )
        best_path = out_path
        figures, fig_notes = figures_of(study, out_path.parent)
        notes.extend(fig_notes)
    else:
        notes.append("no trial completed: no best parameters to write")
    result = TuningResult(
        study_name=job.study_name, storage=redact(job.storage_url), objectives=job.objectives,
        states=states, study_trials=len(trials), best=table, best_params=best_params,
        best_values=best_values, best_number=best_number, best_path=best_path, figures=tuple(figures),
        parent_run_id=job.parent_run_id, wall_seconds=wall, notes=tuple(notes),
        warnings=tuple(seen.warnings), lost_trials=tuple(seen.lost_trials),
    )  # fmt: skip
    if tracker is not None and job.parent_run_id is not None:
        run = job.parent_run_id
        metrics = {f"n_{k.lower()}": float(v) for k, v in states.items()}
        metrics.update({"study_trials": float(len(trials)), "trials_per_minute": result.trials_per_minute})
        if best_values is not None:
            metrics.update({f"best_val_{n}": v for n, v in zip(job.objectives, best_values, strict=True)})
            tracker.set_tags(run, {"best_trial": best_number})
        tracker.log_metrics(run, metrics, step=0)
        for path in [best_path, *figures]:
            if path is not None:
                tracker.log_artifact(run, path)
        if not table.empty:
            tracker.log_text(run, table.to_csv(index=False), "best_trials.csv")
    return result
