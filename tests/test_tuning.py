"""Optuna studies end to end: real training, real SQLite/PostgreSQL storages, a real MLflow store.

Data are small (synthetic steady-state rows at 25 operating points) and trials short (a few epochs),
so every study here runs in seconds.
"""

from __future__ import annotations

import datetime
import os
import signal
import subprocess
import sys
import time
import tomllib
import uuid
from pathlib import Path

import numpy as np
import optuna
import pandas as pd
import pytest

from activelearn import cli
from activelearn.config import TuningConfig, load_config
from activelearn.data import write_table
from activelearn.errors import ConfigError, InputError
from activelearn.numerics import synthetic
from activelearn.studies.tracking import Tracker
from activelearn.studies.tuning import (
    DEFAULT_STORAGE,
    PRUNERS,
    collect_dataset,
    load_dataset,
    operating_points,
    split_data,
    study_trials,
    tune,
)
from activelearn.studies.tuning.storage import (
    SILENT_TRIAL_AGE,
    await_first_heartbeat,
    fail_silent_trials,
    open_storage,
)
from activelearn.studies.tuning.workers import RUN_TOKEN_TAG, close_lost_run
from tests.conftest import UNREACHABLE_SECONDS

ROWS_PER_POINT = 30  # logged rows per operating point
KEPT = ROWS_PER_POINT - 1  # training_rows drops each run's first row (it has no previous rates)


@pytest.fixture(scope="module")
def data_file(tmp_path_factory) -> Path:
    """Synthetic skidpad-like sample table: 25 operating points (cw and ccw), 30 noisy rows each."""
    points = synthetic.skidpad_points()[::2]
    x, y, groups = synthetic.repeated_rows(points, ROWS_PER_POINT, seed=1)
    table = pd.DataFrame({
        "time": np.tile(np.arange(ROWS_PER_POINT) * 0.1, len(points)),
        "throttle": x[:, 0], "steering": x[:, 1], "speed": y[:, 0], "angZ": y[:, 1],
        "maneuver": "skidpad", "direction": np.where(x[:, 1] < 0, "cw", "ccw"),
        "op_throttle": x[:, 0], "op_steering": np.abs(x[:, 1]),
        "run_id": [f"point{g}" for g in groups], "diverged": False,
    })  # fmt: skip
    return write_table(table, tmp_path_factory.mktemp("data") / "samples.parquet")


@pytest.fixture(scope="module")
def mlflow_uri(tmp_path_factory) -> str:
    """One MLflow store for the module (runs are found through their parent run id)."""
    return f"sqlite:///{tmp_path_factory.mktemp('mlruns')}/mlflow.db"


TINY_SPACE = """
[tuning]
sampler_startup_trials = 2
pruner_startup_trials = 2
pruner_warmup_epochs = 2

[tuning.space]
epochs = { low = 4, high = 8 }
batch_size = [32, 64]
n_layers = { low = 1, high = 2 }
width = [8, 16]
variational_width = [4, 8]
"""


def write_config(directory: Path, mlflow_uri: str, extra: str = TINY_SPACE) -> Path:
    """A config for the synthetic table: every row kept, tracking into `mlflow_uri`."""
    path = directory / "study.toml"
    path.write_text(
        f'name = "study"\noutput_dir = "{directory / "runs"}"\n'
        f'[data]\nstride = 1\nskip_seconds = 0.0\n'
        f'[training]\npatience = 100\n'
        f'[tracking]\nuri = "{mlflow_uri}"\n' + extra
    )
    return path


def sqlite_url(directory: Path, name: str = "optuna.db") -> str:
    return f"sqlite:///{directory / name}"


# ----------------------------------------------------------------------------------------- data
def test_validation_split_holds_out_whole_operating_points(tmp_path, data_file, mlflow_uri):
    cfg = load_config(write_config(tmp_path, mlflow_uri))
    data = load_dataset([data_file], cfg)
    assert data.n_groups == 25 and len(data.x) == 25 * KEPT
    split = split_data(data, 0.2, seed=0)
    assert len(split.val_points) == 5
    # Every operating point lies entirely on one side, and the sides share none.
    train_points = {tuple(r) for r in split.x_train}
    val_points = {tuple(r) for r in split.x_val}
    assert len(val_points) == 5 and len(train_points) == 20
    assert not train_points & val_points
    assert len(split.x_val) == 5 * KEPT
    assert not set(split.groups_train) & set(split.groups_val)
    # Seeded: the same seed gives the same split, another seed another one.
    assert split_data(data, 0.2, seed=0).val_points == split.val_points
    assert split_data(data, 0.2, seed=1).val_points != split.val_points


def test_operating_points_separate_directions_of_autodrive_logs(tmp_path, mlflow_uri):
    cfg = load_config(write_config(tmp_path, mlflow_uri))
    paths = []
    for name, steering in (("left", 0.3), ("right", -0.3), ("left_again", 0.3)):
        rows = [
            f"2023_04_12_15_30_{i // 10:02d}_{(i % 10) * 100:03d},0.5,{steering},0,0,0,0,0,0,0,0,"
            f"0.12,0,0,{0.4 if steering > 0 else -0.4},0,0,0,cam0,cam1,lidar"
            for i in range(40)
        ]
        path = tmp_path / name / "V1 Log.csv"
        path.parent.mkdir()
        path.write_text("\n".join(rows) + "\n")
        paths.append(path)
    data = load_dataset(paths, cfg)
    assert len(data.x) == 3 * 39
    # cw and ccw at the same amplitude are different points; two runs at one point are one group.
    assert data.n_groups == 2
    assert len(np.unique(data.groups[:39])) == 1
    assert data.groups[0] == data.groups[78] != data.groups[39]
    with pytest.raises(InputError, match="--data"):
        load_dataset([tmp_path / "missing.parquet"], cfg)


def test_dataset_from_the_config_pool_is_simulated_once_and_cached(tmp_path, mlflow_uri, default_cache):
    extra = """
[pool]
kinds = ["skidpad"]
throttles = [0.4, 0.8]
steerings = [0.3]
duration = 4.0
[simulation]
threads = 1
"""
    cfg = load_config(write_config(tmp_path, mlflow_uri, extra))
    events = []
    data = collect_dataset(cfg, progress=events.append)
    cached = list((tmp_path / "runs" / "cache").glob("tuning-data-*.parquet"))
    assert len(cached) == 1 and events
    assert data.n_groups == 4  # 2 throttles x 1 steering x cw/ccw
    stamp = cached[0].stat().st_mtime_ns
    again = collect_dataset(cfg, progress=events.append)
    assert cached[0].stat().st_mtime_ns == stamp
    np.testing.assert_array_equal(again.x, data.x)
    np.testing.assert_array_equal(again.y, data.y)
    assert again.key == data.key
    assert operating_points(pd.read_parquet(cached[0])).tolist() == data.groups.tolist()


# -------------------------------------------------------------------------------------- studies
def _children(tracker: Tracker, parent: str) -> list:
    return tracker.client.search_runs(
        [tracker.experiment_id], filter_string=f"tags.mlflow.parentRunId = '{parent}'"
    )


def _parent_id(text: str) -> str:
    return text.split("MLflow parent run ")[1].split()[0]


@pytest.mark.slow
def test_sqlite_study_logs_nested_runs_and_resumes(tmp_path, data_file, mlflow_uri, capsys):
    config = write_config(tmp_path, mlflow_uri)
    storage = sqlite_url(tmp_path)
    args = ["tune", str(config), "--n-trials", "4", "--storage", storage, "--study-name", "s1",
            "--data", str(data_file), "--seed", "0"]  # fmt: skip
    assert cli.main(args) == 0
    out = capsys.readouterr().out
    trials = study_trials(storage, "s1")
    assert len(trials) == 4
    assert all(t["state"] in ("COMPLETE", "PRUNED") for t in trials)
    assert [t["number"] for t in trials] == [0, 1, 2, 3]

    tracker = Tracker(mlflow_uri)
    parent = _parent_id(out)
    children = _children(tracker, parent)
    assert len(children) == 4
    assert {c.data.tags["optuna.trial"] for c in children} == {"0", "1", "2", "3"}
    for child in children:
        assert child.data.tags["optuna.state"] in ("COMPLETE", "PRUNED")
        assert {"model.arch", "training.lr", "training.batch_size"} <= set(child.data.params)
        curve = tracker.metric_history(child.info.run_id, "val_nll")
        assert [step for step, _ in curve] == list(range(len(curve))) and curve
        for name in ("val_rmse", "train_loss"):  # the other per-epoch curves, on the same epochs
            steps = [step for step, _ in tracker.metric_history(child.info.run_id, name)]
            assert steps == list(range(len(curve))), name
        if child.data.tags["optuna.state"] == "COMPLETE":
            assert "objective_nll" in child.data.metrics
    best = tmp_path / "runs" / "tuning" / "s1"
    assert (best / "best.toml").is_file()
    assert (best / "optimization_history.png").stat().st_size > 0
    assert (best / "param_importances.png").stat().st_size > 0
    artifacts = {a.path for a in tracker.client.list_artifacts(parent)}
    assert {"best.toml", "optimization_history.png", "param_importances.png", "best_trials.csv"} <= artifacts
    # the best-trials table: the complete trials, lowest validation NLL first
    table = pd.read_csv(tracker.client.download_artifacts(parent, "best_trials.csv", str(tmp_path)))
    complete = sorted((t["values"][0], t["number"]) for t in trials if t["state"] == "COMPLETE")
    assert table["trial"].tolist() == [number for _, number in complete]
    np.testing.assert_allclose(table["val_nll"], [value for value, _ in complete])
    assert "best trials:" in out

    # Same study name: the study continues (new trials, numbered on), under a new parent run.
    assert cli.main([*args[:3], "2", *args[4:]]) == 0
    out = capsys.readouterr().out
    trials = study_trials(storage, "s1")
    assert [t["number"] for t in trials] == list(range(6))
    second = _parent_id(out)
    assert second != parent and len(_children(tracker, second)) == 2
    tagged = tracker.client.search_runs([tracker.experiment_id], filter_string="tags.`optuna.study` = 's1'")
    assert {r.info.run_id for r in tagged} >= {parent, second}

    # It refuses to continue on another search space or on other data, and adds no trial.
    other_space = write_config(tmp_path / "runs", mlflow_uri, TINY_SPACE.replace("high = 8", "high = 6"))
    other_data = write_table(pd.read_parquet(data_file).iloc[ROWS_PER_POINT:], tmp_path / "other.parquet")
    for changed, option in (([*args[:1], str(other_space), *args[2:]], "tuning.space"),
                            ([*args[:-3], str(other_data), *args[-2:]], "--data")):  # fmt: skip
        assert cli.main(changed) == 2, option
        err = capsys.readouterr().err
        assert option in err and "another --study-name" in err and len(err.strip().splitlines()) == 1
    assert len(study_trials(storage, "s1")) == 6


@pytest.mark.slow
def test_best_params_round_trip_into_campaign_config(tmp_path, data_file, mlflow_uri):
    config = write_config(tmp_path, mlflow_uri)
    cfg = load_config(config)
    out = tmp_path / "best.toml"
    result = tune(cfg, n_trials=3, storage=sqlite_url(tmp_path), data=[data_file], tracking=False, out=out)
    assert result.best_path == out and out.is_file()
    merged = load_config(config, params=out)
    best = result.best_params
    assert best is not None
    for key, value in best["model"].items():
        assert getattr(merged.model, key) == value, key
    for key, value in best["training"].items():
        assert getattr(merged.training, key) == value, key
    # Everything else is the config's own.
    assert merged.training.patience == cfg.training.patience
    assert merged.model.kind == cfg.model.kind


PRUNING_SPACE = """
[tuning]
pruner_startup_trials = 2
pruner_warmup_epochs = 3

[tuning.space]
lr = { low = 1e-6, high = 0.05, log = true }
epochs = 25
batch_size = 32
optimizer = "adam"
loss = "nll"
posterior = "mean_field"
kl = "exact"
activation = "tanh"
prior_scale = 1.0
n_layers = 1
width = 16
variational = false
"""


@pytest.mark.slow
def test_pruning_stops_a_clearly_worse_trial(tmp_path, data_file, mlflow_uri):
    cfg = load_config(write_config(tmp_path, mlflow_uri, PRUNING_SPACE))
    # Two good trials complete first; then a learning rate far too small to learn in 25 epochs.
    result = tune(cfg, n_trials=3, storage=sqlite_url(tmp_path), data=[data_file],
                  enqueue=[{"lr": 0.02}, {"lr": 0.01}, {"lr": 1e-6}])  # fmt: skip
    trials = study_trials(sqlite_url(tmp_path), cfg.name)
    assert [t["state"] for t in trials] == ["COMPLETE", "COMPLETE", "PRUNED"]
    assert trials[2]["params"]["lr"] == 1e-6
    assert trials[2]["last_step"] < 24  # stopped long before its last epoch
    tracker = Tracker(mlflow_uri)
    pruned = [c for c in _children(tracker, result.parent_run_id) if c.data.tags["optuna.trial"] == "2"]
    assert pruned[0].data.tags["optuna.state"] == "PRUNED"
    assert len(tracker.metric_history(pruned[0].info.run_id, "val_nll")) == trials[2]["last_step"] + 1


@pytest.mark.slow
def test_hyperband_prunes_at_its_rungs(tmp_path, data_file, mlflow_uri):
    cfg = load_config(write_config(tmp_path, mlflow_uri, PRUNING_SPACE))
    storage = sqlite_url(tmp_path)
    tune(cfg, n_trials=3, storage=storage, data=[data_file], pruner="hyperband", tracking=False,
         enqueue=[{"lr": 0.02}, {"lr": 0.01}, {"lr": 1e-6}])  # fmt: skip
    trials = optuna.load_study(study_name=cfg.name, storage=storage).get_trials()
    # Successive halving records each trial at its bracket's first rung: hyperband_min_epochs epochs
    # in, times 3 per bracket (two brackets for 5 to 25 epochs); the median pruner records no rungs.
    # A trial is pruned only at a rung.
    rungs = (cfg.tuning.hyperband_min_epochs, 3 * cfg.tuning.hyperband_min_epochs)
    for t in trials:
        at_rungs = [t.intermediate_values[r] for r in rungs if r in t.intermediate_values]
        assert t.system_attrs["completed_rung_0"] in at_rungs, t.number
    pruned = [t for t in trials if t.state == optuna.trial.TrialState.PRUNED]
    assert pruned and all(t.last_step in rungs for t in pruned)


@pytest.mark.slow
def test_same_seed_and_storage_state_give_the_same_suggestions(tmp_path, data_file, mlflow_uri):
    cfg = load_config(write_config(tmp_path, mlflow_uri, TINY_SPACE.replace("high = 8", "high = 4")))

    def params(name: str, seed: int) -> list[dict]:
        storage = sqlite_url(tmp_path, f"{name}.db")
        tune(cfg, n_trials=3, storage=storage, data=[data_file], seed=seed, tracking=False, pruner="none")
        return [t["params"] for t in study_trials(storage, cfg.name)]

    first = params("a", 7)
    assert params("b", 7) == first
    assert params("c", 8) != first


@pytest.mark.slow
def test_two_workers_on_sqlite_finish_exactly_the_requested_trials(tmp_path, data_file, mlflow_uri):
    cfg = load_config(write_config(tmp_path, mlflow_uri))
    storage = sqlite_url(tmp_path)
    result = tune(cfg, n_trials=5, storage=storage, data=[data_file], workers=2)
    trials = study_trials(storage, cfg.name)
    assert [t["number"] for t in trials] == list(range(5))
    # every trial trained (none failed), at least one to the end, and both processes took trials
    assert all(t["state"] in ("COMPLETE", "PRUNED") for t in trials)
    assert any(t["state"] == "COMPLETE" for t in trials)
    assert {t["user_attrs"]["worker"] for t in trials} == {0, 1}
    assert result.n_trials == 5
    children = _children(Tracker(mlflow_uri), result.parent_run_id)
    assert sorted(int(c.data.tags["optuna.trial"]) for c in children) == list(range(5))


def _pop_queued_trials(url: str, queue) -> None:
    study = optuna.load_study(study_name="race", storage=open_storage(url))
    popped = []
    while (trial_id := study._pop_waiting_trial_id()) is not None:  # what every `study.ask()` does first
        popped.append(trial_id)
    queue.put(popped)


def test_sqlite_workers_never_take_the_same_queued_trial(tmp_path):
    # Optuna's row lock is a no-op on SQLite; without IMMEDIATE transactions 4 processes popping 300
    # queued trials took 19-24 of them twice (two workers then trained one trial, and the second
    # to finish failed the study with "Cannot tell a COMPLETE trial").
    import multiprocessing

    url = sqlite_url(tmp_path)
    study = optuna.create_study(study_name="race", storage=open_storage(url))
    for i in range(200):
        study.enqueue_trial({"x": float(i)}, skip_if_exists=False)
    context = multiprocessing.get_context("fork")  # the popper needs nothing of a fresh interpreter
    queue = context.Queue()
    workers = [context.Process(target=_pop_queued_trials, args=(url, queue)) for _ in range(4)]
    for worker in workers:
        worker.start()
    popped = [trial_id for _ in workers for trial_id in queue.get(timeout=120)]
    for worker in workers:
        worker.join(timeout=30)
    assert sorted(popped) == sorted(t._trial_id for t in study.get_trials(deepcopy=False))


def test_postgres_study_with_two_workers_records_every_trial_once(
    tmp_path, data_file, mlflow_uri, postgres_url
):
    cfg = load_config(write_config(tmp_path, mlflow_uri))
    name = f"pg-{uuid.uuid4().hex[:8]}"
    n_trials = 6
    result = tune(cfg, n_trials=n_trials, storage=postgres_url, study_name=name, data=[data_file], workers=2)
    trials = study_trials(postgres_url, name)
    assert len(trials) == n_trials
    assert sorted(t["number"] for t in trials) == list(range(n_trials))
    assert all(t["state"] in ("COMPLETE", "PRUNED", "FAIL") for t in trials)
    assert {t["user_attrs"]["worker"] for t in trials} == {0, 1}  # both processes took trials
    # One MLflow run per trial, each linked from its trial, all under the one parent run.
    run_ids = [t["user_attrs"]["mlflow_run_id"] for t in trials]
    assert len(set(run_ids)) == n_trials
    children = _children(Tracker(mlflow_uri), result.parent_run_id)
    assert {c.info.run_id for c in children} == set(run_ids)
    assert sorted(int(c.data.tags["optuna.trial"]) for c in children) == list(range(n_trials))
    assert result.storage.count("***") == 1 and "***" not in postgres_url  # password never shown


@pytest.mark.slow
def test_multi_objective_study_does_not_prune(tmp_path, data_file, mlflow_uri, capsys):
    config = write_config(tmp_path, mlflow_uri, TINY_SPACE + 'loss = ["nll", "mse"]\n')
    storage = sqlite_url(tmp_path)
    args = ["tune", str(config), "--n-trials", "3", "--storage", storage, "--data", str(data_file),
            "--seed", "1", "--objectives", "nll,rmse", "--no-tracking"]  # fmt: skip
    assert cli.main(args) == 0
    captured = capsys.readouterr()
    assert "pruning is disabled" in captured.err + captured.out
    assert "Pareto front" in captured.out
    trials = study_trials(storage, "study")
    assert all(t["state"] == "COMPLETE" and len(t["values"]) == 2 for t in trials)
    # best.toml holds the Pareto-front trial with the lowest NLL (seed 1: the front's lowest RMSE is
    # another trial, so picking by RMSE would fail)
    front = [t for t in trials if not any(_dominates(o["values"], t["values"]) for o in trials)]
    lowest_nll = min(front, key=lambda t: t["values"])
    assert lowest_nll != min(front, key=lambda t: t["values"][::-1])
    best = tomllib.loads((tmp_path / "runs" / "tuning" / "study" / "best.toml").read_text())
    assert best == {key: lowest_nll["user_attrs"][key] for key in ("model", "training")}
    # Continuing it as a single-objective study is refused, naming the option.
    assert cli.main([*args[:-3], "--no-tracking"]) == 2
    assert "--objectives" in capsys.readouterr().err


def _dominates(a: list[float], b: list[float]) -> bool:
    """Whether values `a` are no worse than `b` in every objective and better in one (minimising)."""
    return all(x <= y for x, y in zip(a, b, strict=True)) and a != b


@pytest.mark.slow
def test_timeout_stops_starting_trials(tmp_path, data_file, mlflow_uri):
    cfg = load_config(write_config(tmp_path, mlflow_uri))
    started = time.perf_counter()
    storage = sqlite_url(tmp_path)
    timeout = 2.0
    result = tune(cfg, n_trials=500, storage=storage, data=[data_file], timeout=timeout, tracking=False)
    finished = time.perf_counter()
    trials = optuna.load_study(study_name=cfg.name, storage=storage).get_trials()
    assert 1 <= result.n_trials == len(trials) < 500
    # No trial started after the timeout, and the command ended with the last trial it had started.
    first = min(t.datetime_start for t in trials)
    assert max(t.datetime_start for t in trials) - first < datetime.timedelta(seconds=timeout)
    last = max(t.datetime_complete for t in trials)
    longest = max((t.datetime_complete - t.datetime_start).total_seconds() for t in trials)
    assert (last - first).total_seconds() < timeout + longest
    assert finished - started < 30


# --------------------------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    ("space", "field"),
    [
        ("learning_rate = 0.01", "tuning.space.learning_rate"),  # unknown name
        ("activation = []", "tuning.space.activation"),  # empty list of choices
        ("lr = { low = 0.1, high = 0.001 }", "tuning.space.lr"),  # low > high
        ("epochs = { low = 0, high = 10 }", "tuning.space.epochs"),  # out of bounds
        ("loss = { low = 1, high = 2 }", "tuning.space.loss"),  # a range for a categorical
        ("optimizer = [\"adam\", \"lbfgs\"]", "tuning.space.optimizer"),  # unknown choice
        ("correction = [\"hybrid\", \"gp\"]", "tuning.space.correction"),  # the physics kind's knobs
        ("residual_bound = { low = 0.01, high = 0.9 }", "tuning.space.residual_bound"),  # past 0.5
    ],
)
def test_bad_search_space_is_rejected_before_anything_runs(tmp_path, data_file, space, field, capsys):
    mlflow_db = tmp_path / "mlflow.db"
    config = write_config(tmp_path, f"sqlite:///{mlflow_db}", f"[tuning.space]\n{space}\n")
    with pytest.raises(ConfigError) as info:
        load_config(config)
    assert info.value.field == field
    storage = tmp_path / "optuna.db"
    code = cli.main(["tune", str(config), "--n-trials", "2", "--storage", f"sqlite:///{storage}",
                     "--data", str(data_file)])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert field in err and len(err.strip().splitlines()) == 1
    assert not storage.exists() and not mlflow_db.exists()


# Heartbeats every second; a trial silent for 3 s is stale.
HEARTBEATS = TuningConfig(heartbeat_interval=1, grace_period=3)
HEARTBEAT_SPACE = TINY_SPACE.replace(
    "[tuning]\n", f"[tuning]\nheartbeat_interval = {HEARTBEATS.heartbeat_interval}\n"
    f"grace_period = {HEARTBEATS.grace_period}\n", 1,
)  # fmt: skip
# Trials of a few seconds (80-100 epochs, no pruning: 1.4-3.9 s each, two workers on an idle 2-core machine;
# the kill lands within 0.1 s of the trial being seen), so a worker can be caught in the middle of one.
SLOW_SPACE = HEARTBEAT_SPACE.replace("epochs = { low = 4, high = 8 }", "epochs = { low = 80, high = 100 }")


def _running_trial(storage: str, name: str, deadline: float) -> dict:
    """The first trial seen RUNNING with its worker's pid and its parameters recorded."""
    while time.time() < deadline:
        try:
            for trial in study_trials(storage, name):
                attrs = trial["user_attrs"]
                if trial["state"] == "RUNNING" and "pid" in attrs and "model" in attrs:
                    return trial
        except KeyError:  # the study does not exist yet
            pass
        time.sleep(0.05)
    raise AssertionError("no trial started in time")


@pytest.mark.slow
def test_a_worker_killed_mid_trial_costs_no_trial(tmp_path, data_file, mlflow_uri):
    config = write_config(tmp_path, mlflow_uri, SLOW_SPACE)
    storage = sqlite_url(tmp_path)
    proc = subprocess.Popen(
        [sys.executable, "-m", "activelearn.cli", "tune", str(config), "--n-trials", "4", "--workers", "2",
         "--storage", storage, "--data", str(data_file), "--pruner", "none"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    victim = _running_trial(storage, "study", time.time() + 180)
    os.kill(victim["user_attrs"]["pid"], signal.SIGKILL)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    warnings = [line for line in err.splitlines() if "warning:" in line]
    assert len(warnings) == 1 and f"during trial {victim['number']}" in warnings[0], err

    trials = {t["number"]: t for t in study_trials(storage, "study")}
    assert not [t for t in trials.values() if t["state"] in ("RUNNING", "WAITING")]
    lost = trials.pop(victim["number"])
    assert lost["state"] == "FAIL" and "killed by SIGKILL" in lost["user_attrs"]["lost"]
    # Exactly the requested trials finished besides the lost one, and one of them is its retry.
    assert len(trials) == 4 and all(t["state"] in ("COMPLETE", "PRUNED", "FAIL") for t in trials.values())
    assert [t for t in trials.values() if t["params"] == lost["params"]]
    assert "4 trials this run" in out
    # The lost trial's MLflow run is closed, not left RUNNING, even when the worker died between
    # creating the run and recording its id on the trial; no other trial's run is left open either.
    tracker, token = Tracker(mlflow_uri), lost["user_attrs"]["run"]
    lost_runs = tracker.runs_tagged({RUN_TOKEN_TAG: token, "optuna.trial": str(lost["number"])})
    statuses = {run_id: tracker.run_status(run_id) for run_id in lost_runs}
    assert set(statuses.values()) <= {"KILLED"}, (statuses, lost["user_attrs"])
    if "mlflow_run_id" in lost["user_attrs"]:
        assert lost_runs == [lost["user_attrs"]["mlflow_run_id"]]
    assert tracker.runs_tagged({RUN_TOKEN_TAG: token}, status="RUNNING") == []


def test_a_lost_trial_whose_run_id_was_never_recorded_has_its_run_closed(tmp_path, mlflow_uri):
    # The worker died after MLflow created the trial's run but before the id reached Optuna.
    tracker = Tracker(mlflow_uri)
    token = uuid.uuid4().hex
    tags = {"optuna.study": "study", "optuna.trial": "3", RUN_TOKEN_TAG: token}
    orphan = tracker.start_run("trial-3", tags=tags)
    other = tracker.start_run("trial-4", tags={**tags, "optuna.trial": "4"})
    # The same study name and trial number from another `tune` command (another storage) is not ours.
    stranger = tracker.start_run("trial-3", tags={**tags, RUN_TOKEN_TAG: uuid.uuid4().hex})
    lost = {"lost": "killed by SIGKILL"}
    trial = optuna.trial.create_trial(state=optuna.trial.TrialState.FAIL, user_attrs=lost)
    trial.number = 3
    close_lost_run(tracker, token, trial)
    assert tracker.run_status(orphan) == "KILLED"
    assert tracker.run_status(other) == tracker.run_status(stranger) == "RUNNING"
    assert tracker.client.get_run(orphan).data.tags["lost"] == "killed by SIGKILL"


def test_a_trial_waits_for_its_first_heartbeat(tmp_path):
    # Optuna's stale check skips a RUNNING trial with no heartbeat at all, and its heartbeat thread
    # writes the first one asynchronously (measured: 3 of 150 trials still had none after six writes
    # of the objective). The objective waits for it before marking the trial as picked up.
    storage = open_storage(sqlite_url(tmp_path), HEARTBEATS)
    with pytest.warns(UserWarning, match="Heartbeat"):  # ask() outside optimize(): Optuna says so
        trial = optuna.create_study(storage=storage, study_name="s").ask()
    started = time.monotonic()
    assert not await_first_heartbeat(storage, trial._trial_id, timeout=0.3)  # none yet: gives up
    assert time.monotonic() - started >= 0.3
    storage.record_heartbeat(trial._trial_id)
    assert await_first_heartbeat(storage, trial._trial_id, timeout=0.3)
    # A storage without heartbeats has nothing to wait for.
    plain = open_storage(sqlite_url(tmp_path, "plain.db"))
    other = optuna.create_study(storage=plain, study_name="s").ask()
    started = time.monotonic()
    assert not await_first_heartbeat(plain, other._trial_id, timeout=5) and time.monotonic() - started < 1


def _add_running_trial(storage: optuna.storages.RDBStorage, study: optuna.Study, age: float) -> int:
    """A RUNNING trial started `age` seconds ago by a worker that never got further (its id)."""
    template = optuna.trial.FrozenTrial(
        number=0, state=optuna.trial.TrialState.RUNNING, value=None, params={}, distributions={},
        datetime_start=datetime.datetime.now() - datetime.timedelta(seconds=age), datetime_complete=None,
        user_attrs={}, system_attrs={}, intermediate_values={}, trial_id=0,
    )  # fmt: skip
    return storage.create_new_trial(study._study_id, template_trial=template)


@pytest.mark.slow
def test_a_lost_trial_is_retried_at_most_retry_lost_times(tmp_path):
    tuning = TuningConfig(heartbeat_interval=1, grace_period=2, retry_lost=1)
    storage = open_storage(sqlite_url(tmp_path), tuning)
    study = optuna.create_study(storage=storage, study_name="s")
    for _ in range(2):  # a trial, then its retry, each lose their machine after one heartbeat
        with pytest.warns(UserWarning, match="Heartbeat"):  # ask() outside optimize(): Optuna says so
            trial = study.ask()  # the second time: the queued retry
        storage.record_heartbeat(trial._trial_id)
        time.sleep(tuning.grace_period + 1.5)  # SQLite keeps heartbeats to the whole second
        with pytest.warns(optuna.exceptions.ExperimentalWarning):
            optuna.storages.fail_stale_trials(study)  # what every worker does before its next trial
    trials = study.get_trials()
    assert [t.state for t in trials] == [optuna.trial.TrialState.FAIL] * 2  # no second retry queued
    assert trials[1].system_attrs["failed_trial"] == trials[0].number


def test_trials_silent_since_they_started_are_failed_once_old_enough(tmp_path):
    storage = open_storage(sqlite_url(tmp_path), HEARTBEATS)
    study = optuna.create_study(storage=storage, study_name="s")
    silent = _add_running_trial(storage, study, SILENT_TRIAL_AGE + 5)
    beating = _add_running_trial(storage, study, SILENT_TRIAL_AGE + 5)
    storage.record_heartbeat(beating)  # Optuna's own stale check is for this one
    young = _add_running_trial(storage, study, 1.0)  # may still be waiting for its first beat
    numbers = {storage.get_trial(i).number: i for i in (silent, beating, young)}
    failed = fail_silent_trials(study, storage, "lost before its first heartbeat")
    assert [numbers[n] for n in failed] == [silent]
    assert storage.get_trial(silent).state == optuna.trial.TrialState.FAIL
    assert storage.get_trial(silent).user_attrs["lost"] == "lost before its first heartbeat"
    assert {storage.get_trial(i).state for i in (beating, young)} == {optuna.trial.TrialState.RUNNING}
    retries = study.get_trials(states=(optuna.trial.TrialState.WAITING,))  # queued again
    assert [t.system_attrs["failed_trial"] for t in retries] == [storage.get_trial(silent).number]


@pytest.mark.slow
def test_the_next_command_fails_a_trial_lost_before_its_first_heartbeat(tmp_path, data_file, mlflow_uri):
    cfg = load_config(write_config(tmp_path, mlflow_uri, HEARTBEAT_SPACE))
    storage = sqlite_url(tmp_path)
    tune(cfg, n_trials=1, storage=storage, data=[data_file], tracking=False, pruner="none")
    rdb = open_storage(storage, cfg.tuning)
    silent = _add_running_trial(rdb, optuna.load_study(study_name="study", storage=rdb), SILENT_TRIAL_AGE + 5)
    events: list[dict] = []
    tune(cfg, n_trials=1, storage=storage, data=[data_file], tracking=False, pruner="none",
         progress=events.append)  # fmt: skip
    trials = study_trials(storage, "study")
    lost = trials[rdb.get_trial(silent).number]
    assert lost["state"] == "FAIL" and "first heartbeat" in lost["user_attrs"]["lost"]
    assert not [t for t in trials if t["state"] in ("RUNNING", "WAITING")] and len(trials) == 3
    warnings = [e["message"] for e in events if e["event"] == "warning"]
    assert len(warnings) == 1 and f"trial {lost['number']} " in warnings[0]


@pytest.mark.slow
def test_a_trial_whose_machine_died_is_retried_by_the_next_worker(tmp_path, data_file, mlflow_uri):
    # A whole `tune` command killed (its machine lost): no supervisor sees it, Optuna's heartbeat does.
    config = write_config(tmp_path, mlflow_uri, SLOW_SPACE)
    storage = sqlite_url(tmp_path)
    args = [sys.executable, "-m", "activelearn.cli", "tune", str(config), "--storage", storage,
            "--data", str(data_file), "--pruner", "none", "--no-tracking"]  # fmt: skip
    proc = subprocess.Popen([*args, "--n-trials", "3"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    victim = _running_trial(storage, "study", time.time() + 180)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    time.sleep(3.5)  # the grace period passes without a heartbeat
    again = subprocess.run([*args, "--n-trials", "1"], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    trials = study_trials(storage, "study")
    assert not [t for t in trials if t["state"] in ("RUNNING", "WAITING")]
    lost = trials[victim["number"]]
    assert lost["state"] == "FAIL"
    retry = trials[-1]  # the second command's one trial is the dead one, queued again
    # Compared with the lost trial as stored now: the poll that found it may have read its params
    # and attributes at different moments (SQLite reads them in separate statements).
    assert retry["params"] == lost["params"] and retry["state"] in ("COMPLETE", "PRUNED")
    assert retry["user_attrs"]["model"] == lost["user_attrs"]["model"]


@pytest.mark.slow
def test_unreachable_tracking_server_fails_fast_and_creates_nothing(
    tmp_path, data_file, capsys, silent_server
):
    config = write_config(tmp_path, f"http://127.0.0.1:{silent_server}")
    started = time.perf_counter()
    code = cli.main(["tune", str(config), "--n-trials", "2", "--data", str(data_file),
                     "--storage", sqlite_url(tmp_path)])  # fmt: skip
    assert code == 2 and time.perf_counter() - started < UNREACHABLE_SECONDS
    err = capsys.readouterr().err
    assert "tracking.uri" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "optuna.db").exists()


@pytest.mark.slow
def test_unreachable_storage_fails_fast_and_creates_nothing(tmp_path, data_file, capsys, silent_server):
    mlflow_db = tmp_path / "mlflow.db"
    config = write_config(tmp_path, f"sqlite:///{mlflow_db}")
    started = time.perf_counter()
    code = cli.main(["tune", str(config), "--n-trials", "2", "--data", str(data_file),
                     "--storage", f"postgresql://user:secret@127.0.0.1:{silent_server}/db"])  # fmt: skip
    assert code == 2 and time.perf_counter() - started < UNREACHABLE_SECONDS
    err = capsys.readouterr().err
    assert "--storage" in err and "secret" not in err and len(err.strip().splitlines()) == 1
    assert not mlflow_db.exists()  # no MLflow run for a study that never started

    # A SQLite file whose directory cannot exist (its parent is a file).
    (tmp_path / "a_file").write_text("")
    code = cli.main(["tune", str(config), "--n-trials", "2", "--data", str(data_file),
                     "--storage", f"sqlite:///{tmp_path / 'a_file' / 'optuna.db'}"])  # fmt: skip
    assert code == 2 and "--storage" in capsys.readouterr().err
    assert not mlflow_db.exists()


def test_bad_arguments_are_clean_errors(tmp_path, data_file, mlflow_uri, capsys):
    config = str(write_config(tmp_path, mlflow_uri))
    for extra, option in ((["--n-trials", "0"], "--n-trials"),
                          (["--n-trials", "2", "--workers", "0"], "--workers"),
                          (["--n-trials", "2", "--objectives", "rmse"], "--objectives"),
                          (["--n-trials", "2", "--data", str(tmp_path / "nope.parquet")], "--data"),
                          (["--n-trials", "2", "--storage", "not a url"], "--storage")):  # fmt: skip
        args = ["tune", config, *extra]
        if "--data" not in extra:
            args += ["--data", str(data_file)]
        if "--storage" not in extra:
            args += ["--storage", sqlite_url(tmp_path)]
        assert cli.main(args) == 2, extra
        assert option in capsys.readouterr().err
    assert not (tmp_path / "optuna.db").exists()
    # The CLI's copies of the defaults (kept to avoid importing Optuna at start-up) agree.
    assert cli.tune.TUNE_STORAGE == DEFAULT_STORAGE and cli.tune.TUNE_PRUNERS == PRUNERS


def test_the_physics_corrections_knobs_are_searched_only_when_asked():
    """Unset, a trial keeps the config's correction (and the study's signature is the one stored before
    the knobs existed); set, trials sample them."""
    from activelearn.config import SearchSpace
    from activelearn.studies.tuning.space import sample_params, space_signature, trial_configs

    default = SearchSpace()
    trial = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0)).ask()
    model, _ = sample_params(trial, default)
    assert not {"correction", "correction_inputs", "residual_bound"} & set(model)
    assert "residual_bound" not in space_signature(default)
    cfg = load_config_text('[model]\nkind = "physics"\ncorrection = "ensemble"\nresidual_bound = 0.1\n')
    model_cfg, _ = trial_configs(cfg, model, {})
    assert (model_cfg.correction, model_cfg.residual_bound) == ("ensemble", 0.1)  # the config's, untouched

    searched = SearchSpace(
        correction=["ensemble", "hybrid"], correction_inputs=["control", "history"],
        residual_bound={"low": 0.01, "high": 0.2, "log": True},
    )  # fmt: skip
    studies = [optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=s)) for s in range(12)]
    drawn = [sample_params(study.ask(), searched)[0] for study in studies]
    assert {d["correction"] for d in drawn} == {"ensemble", "hybrid"}
    assert {d["correction_inputs"] for d in drawn} == {"control", "history"}
    assert all(0.01 <= d["residual_bound"] <= 0.2 for d in drawn)
    assert space_signature(searched) != space_signature(default)


def load_config_text(text: str):
    """A campaign config from TOML text (defaults elsewhere), through the real loader."""
    import tempfile

    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "c.toml"
        path.write_text('name = "c"\n[data]\ninputs = "history"\n' + text)
        return load_config(path)


@pytest.mark.slow
def test_a_physics_study_identifies_each_trial_on_the_training_maneuvers_whole_logs(tmp_path, mlflow_uri):
    """Tuning a physics-structured model: its parameters come from the free runs of the training
    split's whole logs (never a held-out maneuver's), as a campaign's do, not from strided rows."""
    from activelearn.numerics.models.single_track import PARAMETER_NAMES, identify_from_logs

    extra = TINY_SPACE + """
[pool]
kinds = ["skidpad"]
throttles = [0.4, 0.8]
steerings = [0.2, 0.5]
duration = 6.0
[simulation]
threads = 1
[model]
kind = "physics"
"""
    config = write_config(tmp_path, mlflow_uri, extra)
    history = 'stride = 3\ninputs = "history"\nhistory = 2\n'
    config.write_text(config.read_text().replace("stride = 1\n", history))
    cfg = load_config(config)
    data = collect_dataset(cfg)
    assert len(data.logs) == 8 and all(len(u) >= 180 for _, u, _ in data.logs)  # whole 6-s logs at 30 Hz
    split = split_data(data, cfg.tuning.val_fraction, cfg.seed)
    logs = split.training_logs()
    assert len(logs) == 8 - len(split.val_points) and len(split.val_points) >= 1
    held_out = [u for point, u, _ in data.logs if point in split.val_points]
    assert not any(np.array_equal(u, v) for u, _ in logs for v in held_out)

    storage = sqlite_url(tmp_path)
    assert cli.main(["tune", str(config), "--n-trials", "2", "--storage", storage, "--study-name", "p",
                     "--seed", "0", "--no-tracking"]) == 0  # fmt: skip
    expected, _ = identify_from_logs(logs)
    for trial in study_trials(storage, "p"):
        found = trial["user_attrs"]["physical_parameters"]
        assert list(found) == list(PARAMETER_NAMES)
        np.testing.assert_allclose(list(found.values()), expected, rtol=1e-5)
    assert abs(expected[PARAMETER_NAMES.index("scrub")]) > 0.1  # identified: the datasheet says 0
