"""`activelearn predict`: a trained surrogate beside MuJoCo on one maneuver, or beside a recorded log, with
its fans."""

from __future__ import annotations

import argparse
from pathlib import Path

from activelearn.cli.common import PLOT_SUFFIXES, output_path, print_table
from activelearn.cli.maneuver_args import (
    add_maneuver_options,
    driven_from_args,
    no_maneuver_options,
    vehicle_from_args,
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("predict", help="forward-simulate a trained surrogate against MuJoCo on one maneuver, "
                                       "or against a recorded log",
                       description="Run the surrogate (with uncertainty fans) and MuJoCo on one maneuver: a "
                                   "reference kind (--maneuver) or a schedule file at 30 Hz (--schedule); or "
                                   "replay a recorded log's commands through the surrogate (--log) and "
                                   "compare with what the log recorded, listing where it leaves the fans.")
    p.add_argument("--model", required=True, metavar="URI|PATH",
                   help="model file (model.pt), campaign directory, or MLflow model URI (runs:/<id>/model)")
    add_maneuver_options(p, log=True)
    p.add_argument("--samples", type=int, default=32, metavar="S", help="sampled trajectories (default 32)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="noise and sampling seed (default 0)")
    p.add_argument("--out", default=None, metavar="PNG", help="write the figure here (.png, .pdf, .svg)")
    p.add_argument("--run-id", default=None, metavar="RUN",
                   help="also log metrics and figure to this MLflow run")
    p.add_argument("--tracking-uri", default="sqlite:///mlruns/mlflow.db", metavar="URI",
                   help="MLflow store for runs:/ URIs and --run-id (default sqlite:///mlruns/mlflow.db)")
    p.set_defaults(handler=_predict)


def _load_any_model(spec: str, tracking_uri: str):
    from pathlib import Path

    from activelearn.errors import InputError

    path = Path(spec)
    if path.is_dir():
        if not (path / "model.pt").is_file():
            raise InputError("--model", spec, "the folder holds no model.pt (a campaign directory has one "
                                              "once a round is fitted: after `campaign run` or an ingest)")
        path = path / "model.pt"
    if path.is_file():
        from activelearn.numerics.models import load_model  # torch: once there is a file to read

        try:
            return load_model(path)
        except Exception as exc:  # a foreign or truncated file: say which
            raise InputError("--model", spec, f"cannot read the model file: {exc}") from None
    if "://" not in spec and not spec.startswith(("runs:/", "models:/")):
        raise InputError("--model", spec, "no such file, directory or MLflow model URI")
    _existing_store(tracking_uri)
    from activelearn.studies.tracking import load_model as load_mlflow_model

    return load_mlflow_model(spec, tracking_uri)


def _existing_store(tracking_uri: str) -> None:
    """Refuse a local SQLite MLflow store that does not exist (MLflow would create it, empty)."""
    from activelearn.errors import InputError

    if tracking_uri.startswith("sqlite:///") and not Path(tracking_uri.removeprefix("sqlite:///")).is_file():
        raise InputError("--tracking-uri", tracking_uri,
                         "no MLflow store there; give the store that holds the run (the command that "
                         "logged it printed it)")


def _predict(args: argparse.Namespace) -> int:

    from activelearn.errors import InputError
    from simulator.datasheet import LOG_RATE_HZ as PREDICT_RATE  # MuJoCo's log and the surrogate's steps

    table = maneuver = None
    if args.log is not None:
        no_maneuver_options(args, "--log")
    else:
        maneuver = driven_from_args(args, PREDICT_RATE, fixed_rate=True)
    if args.samples < 2:
        raise InputError("--samples", args.samples, "must be at least 2")
    if not 0 <= args.seed < 2**32:  # torch's manual_seed overflows past 2**64
        raise InputError("--seed", args.seed, "must lie in [0, 2**32)")
    out = output_path("--out", args.out, suffixes=PLOT_SUFFIXES) if args.out else None
    if args.log is not None:
        from activelearn.fidelity import read_log_file

        if not Path(args.log).is_file():
            raise InputError("--log", args.log, "no such file")
        table = read_log_file(args.log)  # a damaged log is refused before the model is loaded
    if args.run_id is not None:
        _existing_store(args.tracking_uri)
    model = _load_any_model(args.model, args.tracking_uri)
    car = getattr(getattr(model, "config", None), "vehicle", "nigel")
    if maneuver is not None and args.vehicle is None and car != "nigel":
        args.vehicle = car  # the model's car: its maneuver is checked against that car's lock
        maneuver = driven_from_args(args, PREDICT_RATE, fixed_rate=True)
    tracker = None
    if args.run_id is not None:
        from activelearn.studies.tracking import Tracker

        tracker = Tracker(args.tracking_uri)
        tracker.run_status(args.run_id)  # fails early, naming the run, before simulating

    if table is not None:
        from activelearn.loop.benchmark import against_log

        result = against_log(model, table, args.log, rate_hz=PREDICT_RATE, n_samples=args.samples,
                             seed=args.seed)
        name, truth_label = Path(args.log).stem, "recorded log"
        seconds = float(table["time"].iloc[-1] - table["time"].iloc[0])
        print(f"{args.log}: surrogate ({args.samples} samples) against the recorded log ({seconds:.1f} s, "
              f"{len(table)} samples, {(len(table) - 1) / seconds:.3g} Hz on average; replayed at "
              f"{PREDICT_RATE:g} Hz)")
    else:
        from activelearn.loop.benchmark import against_simulator
        from simulator import build_vehicle

        vehicle = None if args.vehicle is None else build_vehicle(vehicle_from_args(args))
        result = against_simulator(model, [maneuver], rate_hz=PREDICT_RATE, n_samples=args.samples,
                                   seed=args.seed, vehicle=vehicle)
        name, truth_label = maneuver.name, "MuJoCo"
        print(f"{maneuver.name}: surrogate ({args.samples} samples) against MuJoCo")
    m = result.metrics[0]
    rows = [("RMSE v (m/s)", m.rmse_v), ("RMSE ω (rad/s)", m.rmse_w)]
    rows += [(f"position error at {t:g} s (m)", e) for t, e in m.position_error.items()]
    if table is not None:
        rows += [("position error, mean (m)", m.mean_position_error)]
    rows += [("steps inside 95% band: v", m.coverage_v), ("steps inside 95% band: ω", m.coverage_w),
             ("steps inside 95% band: position", m.coverage_position)]
    width = max(len(label) for label, _ in rows)
    for label, value in rows:
        print(f"  {label:<{width}}  {value:.4f}")
    if table is not None:
        _print_excursions(result.excursions)
    fig = None
    if out is not None or tracker is not None:
        from activelearn.plots import surrogate_figure

        title = f"{name}: surrogate vs {truth_label}"
        fig = surrogate_figure(result.rollout, 0, result.truth[0], title=title, truth_label=truth_label,
                               outside=result.excursions)
    if out is not None:
        from activelearn.plots import save_figure

        save_figure(fig, out, dpi=120)
        print(f"wrote {out}")
    if tracker is not None:
        metrics = {"predict_rmse_v": m.rmse_v, "predict_rmse_w": m.rmse_w, "predict_coverage_v": m.coverage_v,
                   "predict_coverage_w": m.coverage_w, "predict_coverage_position": m.coverage_position}
        metrics.update({f"predict_position_error_{t:g}s": e for t, e in m.position_error.items()})
        if table is not None:
            metrics["predict_position_error_mean"] = m.mean_position_error
            metrics["predict_outside_seconds"] = sum(e.seconds for e in result.excursions)
        tracker.log_metrics(args.run_id, metrics, step=0)
        tracker.log_figure(args.run_id, fig, f"predict/{name}.png")
        print(f"logged to MLflow run {args.run_id}")
    return 0


def _print_excursions(excursions) -> None:
    """The stretches where the log leaves the fans, as a table (or a line saying there are none)."""
    from activelearn.loop.benchmark import MIN_EXCURSION

    if not excursions:
        print(f"the log stays inside the 95% fans (no stretch outside lasts {MIN_EXCURSION:g} s)")
        return
    print(f"where the log leaves the 95% fans ({MIN_EXCURSION:g} s or longer: an anomaly in the log, or "
          "the model's error):")
    lines = [(e.channel, f"{e.start:.2f}", f"{e.end:.2f}", f"{e.seconds:.2f}") for e in excursions]
    print_table(("channel", "from (s)", "to (s)", "seconds"), lines, left=1, indent="  ")
