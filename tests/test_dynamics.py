"""Dynamic surrogates: history inputs, the recurrent model, free-run metrics, multi-step training and
warm-started rounds. Real MuJoCo logs, real models, the real CLI."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

import simulator
from activelearn.config import RANKING_METRICS, DataConfig, ModelConfig, TrainingConfig, load_config
from activelearn.loop.campaign import Campaign, CampaignState
from activelearn.loop.collection import arrays, data_lags, feature_columns, training_rows, training_windows
from activelearn.loop.evaluation import MIN_TRIM_MANEUVERS
from activelearn.loop.fitting import load_model_copy
from activelearn.numerics.diagnostics import ROLLOUT_METRICS, free_run_metrics, free_runs
from activelearn.numerics.lags import Lags, model_lags
from activelearn.numerics.models import build_model, load_model, save_model
from activelearn.numerics.multistep import window_loss
from activelearn.numerics.paths import evenly_spaced_steps, path_inputs
from activelearn.numerics.surrogate import simulate, steady_state_inputs
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from simulator import Maneuver
from tests.conftest import predict_slalom_fan, smoke_file
from tests.test_campaign import SMOKE, _run_cli, _run_cli_signalled

HISTORY = {"inputs": "history", "history": 3, "history_step": 2}


@pytest.fixture(scope="module")
def slalom_log() -> pd.DataFrame:
    """Two short slaloms and a skidpad, noisy, as a campaign would collect them."""
    maneuvers = [
        Maneuver("slalom", 0.6, 0.4, "ccw", 8.0),
        Maneuver("slalom", 0.9, 0.25, "cw", 8.0),
        Maneuver("skidpad", 0.5, 0.3, "ccw", 8.0),
    ]
    return simulator.collect(maneuvers, seed=1)


def _rows(log: pd.DataFrame, data: DataConfig) -> tuple[np.ndarray, np.ndarray]:
    rows = pd.concat([training_rows(part, data) for _, part in log.groupby("run_id", sort=False)])
    return arrays(rows, data)


@pytest.fixture(scope="module")
def history_models(slalom_log):
    """A history hybrid and a recurrent model, briefly trained on the same rows."""
    data = DataConfig(stride=2, skip_seconds=0.0, **HISTORY)
    x, y = _rows(slalom_log, data)
    models = {}
    for kind, extra in (("hybrid", {}), ("recurrent", {"arch": "D16-V8-V", "hidden_size": 12})):
        model = build_model(ModelConfig(kind=kind, n_inputs=x.shape[1], history_step=2, **extra))
        fit(model, TrainingData(x, y), TrainingConfig(lr=3e-3, epochs=40, patience=None), seed=0)
        models[kind] = model
    return models


def test_history_columns_hold_the_lagged_log_values(slalom_log):
    lags = Lags(3, 2)
    assert lags.columns() == [
        "throttle", "steering", "throttle_lag2", "steering_lag2", "throttle_lag4", "steering_lag4",
        "speed_lag2", "angZ_lag2", "speed_lag4", "angZ_lag4", "speed_lag6", "angZ_lag6",
    ]  # fmt: skip
    # The Markov-state model is history 1 at step 1: the same inputs in the same order.
    markov = DataConfig(stride=5, skip_seconds=0.0, inputs="controls+rates")
    history1 = DataConfig(stride=5, skip_seconds=0.0, inputs="history", history=1, history_step=1)
    assert data_lags(history1) == Lags(1, 1) and data_lags(markov) is None
    assert feature_columns(history1) == ["throttle", "steering", "speed_lag1", "angZ_lag1"]
    assert Lags(1, 1).n_inputs == 4 and Lags(1, 1).rate_lags == (1,)
    x1, y1 = _rows(slalom_log, history1)
    xm, ym = _rows(slalom_log, markov)
    assert x1.shape == (len(y1), 4)
    np.testing.assert_array_equal(x1, xm)
    np.testing.assert_array_equal(y1, ym)
    part = next(iter(slalom_log.groupby("run_id", sort=False)))[1].reset_index(drop=True)
    rows = training_rows(part, DataConfig(stride=5, skip_seconds=0.0, **HISTORY))
    assert rows.index[0] == lags.span  # no row without a full history
    for t in rows.index[:5]:
        assert rows.loc[t, "steering_lag4"] == part.loc[t - 4, "steering"]
        assert rows.loc[t, "angZ_lag6"] == part.loc[t - 6, "angZ"]
        assert rows.loc[t, "speed_lag2"] == part.loc[t - 2, "speed"]


@pytest.mark.parametrize("kind", ["hybrid", "recurrent"])
def test_rollout_feeds_each_trajectory_its_own_lagged_rates(history_models, kind):
    """The per-step mean of a rollout is the mean over draws at inputs built from each draw's own path."""
    model = history_models[kind]
    lags = model_lags(model)
    assert lags == Lags(3, 2)
    controls = [np.column_stack([np.full(40, 0.7), 0.4 * np.sin(np.arange(40) / 5.0)])]
    initial = np.array([[0.1, 0.05]])
    rollout = simulate(model, controls, rate_hz=30.0, n_samples=4, seed=7, initial_rates=initial,
                       backend="reference")  # fmt: skip
    draw_seed = int(torch.randint(2**31 - 1, (1,), generator=torch.Generator().manual_seed(7)))
    draws = model.draw(4, seed=draw_seed, backend="reference")
    u, rates = controls[0], np.stack([rollout.v[:, 0], rollout.w[:, 0]], axis=-1)  # (S, T, 2)
    for t in (0, 1, 5, 6, 7, 30):
        ctrl = [u[max(t - d, 0)] for d in lags.control_lags]
        inputs = np.stack([
            np.concatenate(ctrl + [rates[s, t - d] if t >= d else initial[0] for d in lags.rate_lags])
            for s in range(4)
        ])[:, None, :]  # fmt: skip
        means, _ = draws(inputs)
        np.testing.assert_allclose(rollout.mean_rates[0, t], means[:, 0].mean(axis=0), rtol=1e-4, atol=1e-6)


def test_recurrent_model_splits_uncertainty_and_survives_a_round_trip(history_models, tmp_path):
    model = history_models["recurrent"]
    x = np.random.default_rng(0).normal(size=(50, 12))
    near, far = model.predict(x * 0.1, n_samples=32), model.predict(x * 20.0, n_samples=32)
    assert (near.epistemic_var > 0).all() and (near.aleatoric_var > 0).all()
    assert far.epistemic_std.mean() > 3 * near.epistemic_std.mean()  # wider away from the data
    save_model(model, tmp_path / "m.pt")
    again = load_model(tmp_path / "m.pt")
    assert type(again).__name__ == "RecurrentPBNN"
    np.testing.assert_array_equal(again.predict(x, n_samples=8).mean, model.predict(x, n_samples=8).mean)


def test_free_run_metrics_are_zero_error_for_the_truth_and_grow_with_a_bias(history_models, slalom_log):
    logs = [part.reset_index(drop=True) for _, part in slalom_log.groupby("run_id", sort=False)]
    metrics = free_run_metrics(history_models["hybrid"], logs, rate_hz=30.0, n_samples=8)
    assert set(metrics) == set(ROLLOUT_METRICS)
    assert set(ROLLOUT_METRICS) - {"rollout_coverage_95"} <= set(RANKING_METRICS)
    assert 0 <= metrics["rollout_coverage_95"] <= 1
    assert metrics["rollout_pos_err_10s"] == metrics["rollout_pos_err_30s"]  # 8-s maneuvers: their end
    # Judged against a truth that drives 10 % faster than recorded, the same run errs more.
    faster = [t.assign(posX=t["posX"][0] + 1.1 * (t["posX"] - t["posX"][0]),
                       posY=t["posY"][0] + 1.1 * (t["posY"] - t["posY"][0])) for t in logs]  # fmt: skip
    worse = free_run_metrics(history_models["hybrid"], logs, faster, rate_hz=30.0, n_samples=8)
    assert worse["rollout_pos_err_30s"] > metrics["rollout_pos_err_30s"]
    assert worse["rollout_rmse_v"] == metrics["rollout_rmse_v"]
    # Judged against its own mean run as the truth (the same draws: the same seed), every error is zero.
    rollout = free_runs(history_models["hybrid"], logs, rate_hz=30.0, n_samples=8)
    mean_x, mean_y = rollout.mean_path()
    own = [
        pd.DataFrame({"posX": mean_x[i, :n], "posY": mean_y[i, :n], "yaw": rollout.yaw[:, i, :n].mean(axis=0),
                      "speed": rollout.mean_rates[i, :n, 0], "angZ": rollout.mean_rates[i, :n, 1]})
        for i, n in enumerate(rollout.lengths)
    ]  # fmt: skip
    exact = free_run_metrics(history_models["hybrid"], logs, own, rate_hz=30.0, n_samples=8)
    errors = [name for name in ROLLOUT_METRICS if name != "rollout_coverage_95"]
    assert all(metrics[name] > 0 for name in errors), metrics  # against the log, the run errs
    assert {name: exact[name] for name in errors} == dict.fromkeys(errors, 0.0), exact


def test_window_loss_of_one_step_is_the_one_step_nll(history_models, slalom_log):
    model = history_models["hybrid"]
    data = DataConfig(stride=1, skip_seconds=0.0, **HISTORY)
    frames = [part for _, part in slalom_log.groupby("run_id", sort=False)]
    windows = training_windows(frames, data, horizon=1)
    x, y = _rows(slalom_log, data)
    assert len(windows) == len(x)  # one window per row with a full history
    model.eval()
    with torch.no_grad():
        torch.manual_seed(0)
        loss = window_loss(model, windows, torch.arange(len(windows)))
        torch.manual_seed(0)
        xs = (torch.tensor(x, dtype=torch.float32) - model.x_mean) / model.x_std
        mean, var = model.train_forward(xs)
        ys = (torch.tensor(y, dtype=torch.float32) - model.y_mean) / model.y_std
        one_step = (0.5 * (var.log() + (ys - mean).square() / var)).sum(dim=-1).mean()
    assert float(loss) == pytest.approx(float(one_step), rel=1e-5)
    longer = training_windows(frames, data, horizon=30)
    assert longer.horizon == 30 and longer.controls.shape[1] == 30 + 2 * 2


def test_multi_step_training_changes_the_fit_and_is_seeded(slalom_log):
    data = DataConfig(stride=2, skip_seconds=0.0, **HISTORY)
    x, y = _rows(slalom_log, data)
    windows = training_windows([p for _, p in slalom_log.groupby("run_id", sort=False)], data, 10)
    fits = []
    for horizon in (0, 10, 10):
        model = build_model(ModelConfig(n_inputs=12, history_step=2))
        cfg = TrainingConfig(epochs=5, patience=None, rollout_horizon=horizon, rollout_batch=8)
        fit(model, TrainingData(x, y, windows=windows), cfg, seed=3)
        fits.append(model.predict(x[:20], n_samples=4).mean)
    assert not np.allclose(fits[0], fits[1])  # the window loss took part
    np.testing.assert_array_equal(fits[1], fits[2])  # and the same seed gives the same weights


def test_a_window_with_a_non_finite_gradient_is_skipped_not_trained_on(slalom_log, monkeypatch):
    """A free run that leaves every bound gives a non-finite window loss (seen on the full-size car's
    dynamic core at its extreme scales, which turned every weight into NaN): its step is skipped and
    counted, the one-step steps still train, the weights stay finite. Injected: the real window loss
    times NaN every other window step."""
    import activelearn.numerics.training as training

    data = DataConfig(stride=2, skip_seconds=0.0, **HISTORY)
    x, y = _rows(slalom_log, data)
    windows = training_windows([p for _, p in slalom_log.groupby("run_id", sort=False)], data, 10)
    cfg = TrainingConfig(epochs=3, patience=None, rollout_horizon=10, rollout_batch=8)
    clean = build_model(ModelConfig(n_inputs=12, history_step=2))
    assert fit(clean, TrainingData(x, y, windows=windows), cfg, seed=3).skipped_steps == 0
    calls = []

    def every_other_nan(model, windows, rows):
        calls.append(1)
        loss = window_loss(model, windows, rows)
        return loss * float("nan") if len(calls) % 2 else loss

    monkeypatch.setattr(training, "window_loss", every_other_nan)
    model = build_model(ModelConfig(n_inputs=12, history_step=2))
    before = [p.detach().clone() for p in model.parameters()]
    history = fit(model, TrainingData(x, y, windows=windows), cfg, seed=3)
    assert history.skipped_steps == (len(calls) + 1) // 2 > 0
    assert all(torch.isfinite(p).all() for p in model.parameters())
    assert any(not torch.equal(a, b) for a, b in zip(before, model.parameters(), strict=True))  # it trained
    assert all(np.isfinite(history.train_loss))


def test_multi_step_training_runs_each_ensemble_member_on_its_own_predictions(slalom_log):
    data = DataConfig(stride=2, skip_seconds=0.0, **HISTORY)
    x, y = _rows(slalom_log, data)
    windows = training_windows([p for _, p in slalom_log.groupby("run_id", sort=False)], data, 10)
    spec = ModelConfig(kind="ensemble", ensemble_size=3, n_inputs=12, history_step=2, kinematic_feature=True)
    fits = []
    for horizon in (0, 10, 10):
        model = build_model(spec)
        fit(
            model,
            TrainingData(x, y, windows=windows),
            TrainingConfig(epochs=3, patience=None, rollout_horizon=horizon, rollout_batch=8),
            seed=3,
        )  # fmt: skip
        fits.append(model.predict(x[:20], n_samples=3).mean)
    assert not np.allclose(fits[0], fits[1])  # the window loss took part
    np.testing.assert_array_equal(fits[1], fits[2])  # seeded
    # The ensemble's window loss is the sum of its members' own: member k alone, fed its own means.
    rows = torch.arange(6)
    with torch.no_grad():
        total = float(window_loss(model, windows, rows))
        alone = 0.0
        for k in range(3):
            member = _Member(model, k)
            alone += float(window_loss(member, windows, rows))
    assert total == pytest.approx(alone, rel=1e-5)


class _Member(torch.nn.Module):
    """Member k of an ensemble as a model of its own (for the window loss)."""

    def __init__(self, ensemble, k: int) -> None:
        super().__init__()
        self.ensemble, self.k, self.n_members = ensemble, k, None
        self.y_mean, self.y_std = ensemble.y_mean, ensemble.y_std

    def standardise_inputs(self, x):
        return self.ensemble.standardise_inputs(x)

    def train_forward(self, x):
        stacked = x.expand(self.ensemble.n_members, *x.shape)
        mean, var = self.ensemble.train_forward(stacked)
        return mean[self.k], var[self.k]


def test_multi_step_training_clips_the_gradient_norm(slalom_log):
    data = DataConfig(stride=2, skip_seconds=0.0, **HISTORY)
    x, y = _rows(slalom_log, data)
    windows = training_windows([p for _, p in slalom_log.groupby("run_id", sort=False)], data, 10)
    moved = {}
    for clip in (0.0, 1e-6):
        model = build_model(ModelConfig(n_inputs=12, history_step=2))
        fit(model, TrainingData(x, y), TrainingConfig(epochs=1, patience=None), seed=3)  # scalers and a start
        start = [p.detach().clone() for p in model.parameters()]
        cfg = TrainingConfig(epochs=2, patience=None, rollout_horizon=10, rollout_batch=8,
                             rollout_clip=clip, reinit=False, optimizer="sgd", momentum=0.0)  # fmt: skip
        fit(model, TrainingData(x, y, windows=windows), cfg, seed=3, keep_scalers=True)
        now = [p.detach() for p in model.parameters()]
        moved[clip] = sum(float((p - q).norm()) for p, q in zip(now, start, strict=True))
    # plain SGD moves each step by lr x the gradient: clipped to a norm of 1e-6 it barely moves
    assert moved[1e-6] < 1e-3 * moved[0.0], moved


def _dynamic_config(tmp_path: Path, **overrides):
    data = {
        "output_dir": str(tmp_path / "runs"),
        "tracking": {"enabled": False},
        "pool": {"kinds": ["skidpad", "slalom"], "duration": 8.0},
        "data": {"stride": 5, "skip_seconds": 0.0, **HISTORY},
        "training": {"epochs": 15},
        "design": {"initial": 2, "per_round": 1, "max_maneuvers": 4},
        "test": {"kinds": ["slalom"], "throttles": [0.6], "steerings": [0.3], "duration": 8.0,
                 "metric": "rollout_pos_err_30s", "rollout_samples": 8},
        **overrides,
    }  # fmt: skip
    return load_config(SMOKE, overrides=data)


@pytest.mark.slow
def test_a_history_campaign_logs_free_run_metrics_every_round(tmp_path):
    cfg = _dynamic_config(tmp_path, model={"kind": "recurrent", "arch": "D16-V8-V", "hidden_size": 8})
    assert cfg.model.n_inputs == 12 and cfg.model.history_step == 2  # the data section sets the layout
    result = Campaign(cfg, tmp_path / "c").run(figures=False)
    assert len(result.state.rounds) == 3
    for record in result.state.rounds:
        for name in (*ROLLOUT_METRICS, "rollout_seconds"):
            assert np.isfinite(record[name]), name
    # The campaign's model drives `predict` (fan figure, metrics) like any other.
    done = predict_slalom_fan(tmp_path / "c", tmp_path)
    assert done.returncode == 0, done.stderr
    assert "position error" in done.stdout and (tmp_path / "fan.png").stat().st_size > 0


@pytest.mark.slow
def test_compare_ranks_by_the_chosen_metric(tmp_path):
    out, config = tmp_path / "cmp", smoke_file(tmp_path, max_maneuvers=5)  # two rounds
    args = ["compare", str(config), "--strategies", "uniform,random", "--seeds", "1", "--first-seed", "3",
            "--workers", "1", "--no-tracking", "--out", str(out),
            "--metric", "rollout_pos_err_30s"]  # fmt: skip
    done = subprocess.run([sys.executable, "-m", "activelearn.cli", *args], capture_output=True, text=True,
                          timeout=600, cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "final rollout_pos_err_30s" in done.stdout
    table = pd.read_csv(out / "summary.csv")
    curves = pd.read_csv(out / "curves.csv")
    assert set(curves["seed"]) == {3}  # --first-seed: seeds 3..3
    uniform = curves[curves["strategy"] == "uniform"].sort_values("round")
    assert table.set_index("strategy").loc["uniform", "final_metric"] == pytest.approx(
        uniform["rollout_pos_err_30s"].iloc[-1]
    )
    bad = subprocess.run([sys.executable, "-m", "activelearn.cli", *args[:-1], "rollout_nonsense"],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)  # fmt: skip
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and "--metric" in bad.stderr
    negative = [*args[:7], "-1", *args[8:]]  # --first-seed -1
    bad = subprocess.run([sys.executable, "-m", "activelearn.cli", *negative], capture_output=True, text=True,
                         timeout=120, cwd=tmp_path)  # fmt: skip
    assert bad.returncode == 2 and "--first-seed" in bad.stderr


@pytest.mark.slow
@pytest.mark.parametrize(
    ("section", "patch", "field"),
    [
        ("test", 'metric = "rmse_of_everything"', "test.metric"),
        ("data", 'inputs = "history"\nhistory = 0', "data.history"),
        ("data", "history_step = 2", "data"),
        ("model", 'kind = "recurrent"', "config"),
        ("model", 'kinematic_feature = "often"', "model.kinematic_feature"),
        ("model", 'kind = "recurrent"\nkinematic_feature = true', "kinematic_feature"),
        ("training", "rollout_horizon = -1", "training.rollout_horizon"),
    ],
)
def test_bad_dynamics_settings_are_one_line_and_exit_2(tmp_path, section, patch, field):
    text = SMOKE.read_text()
    header = f"[{section}]\n"
    text = text.replace(header, header + patch + "\n") if header in text else text + f"\n{header}{patch}\n"
    path = tmp_path / "bad.toml"
    path.write_text(text)
    done = subprocess.run(
        [sys.executable, "-m", "activelearn.cli", "campaign", "run", str(path), "--no-tracking",
         "--out", str(tmp_path / "never")],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and field in done.stderr
    assert not (tmp_path / "never").exists()


@pytest.mark.slow
def test_warm_started_rounds_start_from_the_last_model_and_resume_exactly(tmp_path):
    cfg = tmp_path / "warm.toml"
    warm = "[training]\nwarm_start = true\nwarm_epochs = 10\n"
    # the smoke campaign with its first fit cheaper (what is tested is where each round starts, not the fit)
    cfg.write_text(SMOKE.read_text().replace("[training]\n", warm).replace("epochs = 60", "epochs = 15"))
    common = ["campaign", "run", str(cfg), "--no-tracking", "--seed", "1"]
    assert _run_cli([*common, "--out", str(tmp_path / "ref")]).wait(timeout=300) == 0
    victim = _run_cli_signalled("SIGKILL", ("fit", 2), [*common, "--out", str(tmp_path / "kill")])
    assert victim.wait(timeout=300) == -signal.SIGKILL
    assert len(CampaignState.load(tmp_path / "kill").rounds) == 2
    assert _run_cli([*common, "--out", str(tmp_path / "kill"), "--resume"]).wait(timeout=300) == 0
    ref, res = CampaignState.load(tmp_path / "ref"), CampaignState.load(tmp_path / "kill")
    assert ref.batches == res.batches and len(ref.rounds) == 3
    for a, b in zip(ref.rounds, res.rounds, strict=True):
        assert a["test_rmse"] == b["test_rmse"] and a["test_nll"] == b["test_nll"]
    # The last round's model is a warm fit from round 1's weights, not a fresh one.
    assert sorted(p.name for p in (tmp_path / "ref" / "warm").iterdir()) == ["round001.pt", "round002.pt"]
    campaign = Campaign(load_config(cfg).model_copy(update={"seed": 1}), tmp_path / "ref")
    samples = pd.read_parquet(tmp_path / "ref" / "samples.parquet")
    final = load_model(tmp_path / "ref" / "model.pt")
    x = campaign.test_set.x
    warm = campaign.fitting.fit(samples, 2, previous=load_model(tmp_path / "ref" / "warm" / "round001.pt"))
    np.testing.assert_array_equal(warm.predict(x, n_samples=8).mean, final.predict(x, n_samples=8).mean)
    fresh = campaign.fitting.fit(samples, 2)
    assert not np.allclose(fresh.predict(x, n_samples=8).mean, final.predict(x, n_samples=8).mean)


@pytest.mark.slow
def test_tune_searches_the_recurrent_trunk_width(tmp_path, slalom_log):
    import optuna

    from activelearn import cli
    from activelearn.data import write_table

    data = write_table(slalom_log, tmp_path / "samples.parquet")
    config = tmp_path / "rec.toml"
    config.write_text(
        f'name = "rec"\noutput_dir = "{tmp_path / "runs"}"\n'
        '[data]\nstride = 2\nskip_seconds = 0.0\ninputs = "history"\nhistory = 3\nhistory_step = 2\n'
        '[model]\nkind = "recurrent"\n'
        f'[tracking]\nuri = "sqlite:///{tmp_path}/mlflow.db"\n'
        "[tuning]\nsampler_startup_trials = 2\n"
        "[tuning.space]\nepochs = 3\nbatch_size = [64]\nn_layers = 1\nwidth = [8]\n"
        "variational = false\nhidden_size = [6, 10]\n"
    )
    storage = f"sqlite:///{tmp_path}/optuna.db"
    args = ["tune", str(config), "--n-trials", "3", "--storage", storage, "--data", str(data), "--seed", "0"]
    assert cli.main(args) == 0
    trials = optuna.load_study(study_name="rec", storage=storage).trials
    assert len(trials) == 3 and all(t.state.name == "COMPLETE" for t in trials)
    assert {t.params["hidden_size"] for t in trials} <= {6, 10}
    assert "hidden_size" in (tmp_path / "runs" / "tuning" / "rec" / "best.toml").read_text()


def test_a_residual_models_free_run_adds_the_base_mean(history_models, slalom_log):
    """Sim-to-real campaigns run their test maneuvers free too: base mean + residual draws per step."""
    from activelearn.numerics.models import ResidualModel

    base, residual = history_models["hybrid"], build_model(ModelConfig(n_inputs=12, history_step=2))
    model = ResidualModel(base, residual)
    controls = [np.column_stack([np.full(12, 0.5), np.linspace(-0.3, 0.3, 12)])]
    rollout = simulate(model, controls, rate_hz=30.0, n_samples=4, seed=2)
    draw_seed = int(torch.randint(2**31 - 1, (1,), generator=torch.Generator().manual_seed(2)))
    draws = model.draw(4, seed=draw_seed)
    rates = np.stack([rollout.v[:, 0], rollout.w[:, 0]], axis=-1)
    lags = Lags(3, 2)
    for t in (0, 3, 9):
        inputs = np.stack([
            np.concatenate([controls[0][max(t - d, 0)] for d in lags.control_lags]
                           + [rates[s, t - d] if t >= d else np.zeros(2) for d in lags.rate_lags])
            for s in range(4)
        ])[:, None, :]  # fmt: skip
        means, _ = draws(inputs)
        np.testing.assert_allclose(rollout.mean_rates[0, t], means[:, 0].mean(axis=0), rtol=1e-4, atol=1e-6)
    assert np.abs(rollout.mean_rates[0]).max() > 0
    # widened (the [safety] fan's scale): the residual's draws widen about the same base mean
    with torch.no_grad():
        model.epistemic_scale.fill_(9.0)
    wide = simulate(model, controls, rate_hz=30.0, n_samples=4, seed=2)
    assert np.isfinite(wide.v).all() and np.isfinite(wide.w).all()
    assert wide.epistemic_var[0, 1:].sum() > rollout.epistemic_var[0, 1:].sum()


@pytest.mark.slow
def test_prequential_fan_calibration_widens_each_rounds_fans_by_the_measured_need(tmp_path):
    cfg = _dynamic_config(tmp_path, design={"initial": 2, "per_round": 1, "max_maneuvers": 5,
                                            "fan_calibration": "prequential"})  # fmt: skip
    result = Campaign(cfg, tmp_path / "c").run(figures=False)
    rounds = result.state.rounds
    assert len(rounds) == 4
    needs = [r["prequential_fan_scale"] for r in rounds[:-1]]  # each model against the next batch
    assert all(np.isfinite(n) and n > 0 for n in needs) and "prequential_fan_scale" not in rounds[-1]
    assert rounds[0]["fan_scale"] == 1.0  # nothing measured yet
    for k in range(1, 4):  # the geometric mean of every need measured before round k's fit (on k
        expected = float(np.exp(np.mean(np.log(needs[:k]))))  # maneuvers: too few to narrow the fans)
        expected = max(expected, 1.0) if k < MIN_TRIM_MANEUVERS else expected
        assert rounds[k]["fan_scale"] == pytest.approx(expected)
    assert max(needs) / min(needs) > 1.05 or abs(np.log(needs[0])) > 0.1  # the check measured something
    final = load_model(tmp_path / "c" / "model.pt")
    assert float(final.fan_scale) == pytest.approx(rounds[-1]["fan_scale"])
    # The same campaign without calibration logs neither and keeps the posterior's own fans.
    plain_cfg = _dynamic_config(tmp_path, design={"initial": 2, "per_round": 1, "max_maneuvers": 5,
                                                  "fan_calibration": "none"})  # fmt: skip
    plain = Campaign(plain_cfg, tmp_path / "p").run(figures=False).state.rounds
    assert all("fan_scale" not in r and "prequential_fan_scale" not in r for r in plain)
    assert float(load_model(tmp_path / "p" / "model.pt").fan_scale) == 1.0
    # The calibrated fans hold the true test positions better than the raw ones where they differ.
    cover = {"calibrated": rounds[-1]["rollout_coverage_95"], "raw": plain[-1]["rollout_coverage_95"]}
    assert abs(cover["calibrated"] - 0.95) < abs(cover["raw"] - 0.95), cover
    # and prequential is what a config gets without asking
    assert _dynamic_config(tmp_path).design.fan_calibration == "prequential"


def test_path_inputs_follow_the_models_own_free_run(history_models):
    model = history_models["hybrid"]
    lags = model_lags(model)
    t = np.arange(240)
    slalom = np.column_stack([np.full(240, 0.7), np.where((t // 40) % 2 == 0, 0.4, -0.4)])
    skidpad = np.tile([0.6, 0.3], (240, 1))
    inputs = path_inputs(model, [slalom, skidpad], 12, rate_hz=30.0)
    assert [a.shape for a in inputs] == [(12, lags.n_inputs)] * 2
    steps = evenly_spaced_steps(240, 12)
    np.testing.assert_array_equal(inputs[0][:, :2], slalom[steps])  # the newest controls as scheduled
    # Held controls settle: the late path inputs are the model's quasi-steady state there.
    steady = steady_state_inputs(model, skidpad[:1], steps=120)
    np.testing.assert_allclose(inputs[1][-1], steady[0], atol=0.02)
    # A slalom's rate inputs are its own free run's mean rates, lagged as the model reads them
    # the same draws
    run = simulate(model, [slalom, skidpad], rate_hz=30.0, n_samples=8, seed=0, fan_scale=1.0)
    newest_rate = 2 * lags.history  # the first rate input pair: one step of the layout back
    back = lags.rate_lags[0]
    np.testing.assert_allclose(
        inputs[0][3:, newest_rate + 1], run.w.mean(axis=0)[0, steps[3:] - back], atol=1e-6
    )
    # ... which, unlike a steady state, lag the steering: right after a switch the yaw rate still
    # has the old sign (the static stand-in would flip at once).
    flips = [k for k in range(1, 240) if slalom[k, 1] != slalom[k - 1, 1]]
    just_after = path_inputs(model, [slalom], 240, rate_hz=30.0)[0][[f + back for f in flips[:3]]]
    assert (np.sign(just_after[:, newest_rate + 1]) != np.sign(slalom[[f for f in flips[:3]], 1])).all()
    # A static map's path inputs are its controls.
    static = build_model(ModelConfig())
    static_inputs = path_inputs(static, [slalom], 5, rate_hz=30.0)[0]
    np.testing.assert_array_equal(static_inputs, slalom[evenly_spaced_steps(240, 5)])


def test_a_campaign_scores_dynamic_candidates_along_their_paths(tmp_path):
    cfg = _dynamic_config(tmp_path, acquisition={"dynamic_points": "path", "score_points": 6},
                          design={"initial": 2, "per_round": 1, "max_maneuvers": 3})  # fmt: skip
    campaign = Campaign(cfg, tmp_path / "c")
    result = campaign.run(figures=False)
    assert len(result.state.rounds) == 2
    model = load_model(tmp_path / "c" / "model.pt")
    pool = campaign.pool(result.state.taken, model)
    n = len(campaign.maneuvers)
    assert pool.points.shape == (6 * n, cfg.model.n_inputs)
    np.testing.assert_array_equal(pool.owner, np.repeat(np.arange(n), 6))
    # the target holds the test slalom's path: its steering flips sign along the way
    assert pool.target.shape[1] == cfg.model.n_inputs and {-1.0, 1.0} <= set(np.sign(pool.target[:, 1]))
    update = {"acquisition": cfg.acquisition.model_copy(update={"dynamic_points": "steady_state"})}
    steady = cfg.model_copy(update=update)
    other = Campaign(steady, tmp_path / "s").pool(result.state.taken, model)
    assert other.points.shape[0] < pool.points.shape[0]  # steady state: distinct control points only
    # `auto` learns from the history that candidates are scored along paths (it then seeks max_epistemic)
    assert campaign.strategy_history(result.state).scores_paths
    assert not Campaign(steady, tmp_path / "s").strategy_history(result.state).scores_paths


def test_a_free_run_that_blows_up_scores_infinity_not_nan(history_models, slalom_log):
    model = load_model_copy(history_models["hybrid"])
    with torch.no_grad():  # an output scale no feedback loop survives: the run overflows to inf, then nan
        model.y_std.mul_(1e30)
    logs = [part.reset_index(drop=True) for _, part in slalom_log.groupby("run_id", sort=False)]
    metrics = free_run_metrics(model, logs, rate_hz=30.0, n_samples=4)
    for name in ("rollout_pos_err_10s", "rollout_pos_err_30s", "rollout_heading_err_30s", "rollout_rmse_v"):
        assert metrics[name] == np.inf, (name, metrics[name])


def test_the_lookahead_oracle_judges_a_batch_by_the_configs_metric(tmp_path):
    """`oracle_lookahead` keeps the batch whose retrained model is best by the config's `[test] metric`:
    here the 30-s free-run error the comparison ranks by, not the one-step RMSE (a dynamic model's
    one-step error and its free runs can rank batches differently)."""
    from activelearn.data import read_table
    from activelearn.loop.campaign import SAMPLES_FILE

    cfg = _dynamic_config(tmp_path, strategy="oracle_lookahead",
                          design={"initial": 2, "per_round": 1, "max_maneuvers": 3})  # fmt: skip
    campaign = Campaign(cfg, tmp_path / "c")
    state = campaign.run(figures=False).state
    samples = read_table(tmp_path / "c" / SAMPLES_FILE)
    model = load_model(tmp_path / "c" / "model.pt")
    batch = [int(np.flatnonzero(~campaign.pool(state.taken, model).taken)[0])]
    score = campaign._trial(state, samples, batch, len(state.rounds) - 1, model)
    new = campaign.collect(batch, len(state.batches), state)
    more = pd.concat([samples, new], ignore_index=True)
    retrained = campaign.fitting.fit(more, len(state.rounds), previous=model)
    metrics = campaign.evaluation.evaluate(retrained)
    assert score == pytest.approx(metrics["rollout_pos_err_30s"]) and score != metrics["test_rmse"]
