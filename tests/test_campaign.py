"""The outer loop end to end: real MuJoCo, real models, a real SQLite MLflow store."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from activelearn.cli import main
from activelearn.config import load_config, validate_config
from activelearn.errors import ConfigError
from activelearn.loop.campaign import Campaign, CampaignState
from activelearn.loop.state import CONFIG_FILE, MODEL_FILE
from activelearn.numerics.models import load_model
from activelearn.studies.compare import compare
from activelearn.studies.tracking import Tracker
from activelearn.studies.tuning import params_toml
from tests.conftest import UNREACHABLE_SECONDS, smoke_file

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"
ROUND_METRICS = (
    "test_rmse", "test_rmse_v", "test_rmse_w", "test_nll", "test_crps", "coverage_95",
    "epistemic_std_mean", "epistemic_std_max", "aleatoric_std_mean",
    "n_samples", "n_maneuvers", "sim_seconds", "wall_seconds",
)


def tiny_config(tmp_path: Path, **overrides):
    """The smoke config, shrunk further, writing under tmp_path."""
    data = {
        "output_dir": str(tmp_path / "runs"),
        "tracking": {"uri": f"sqlite:///{tmp_path}/mlruns/mlflow.db"},
        "training": {"epochs": 25},
        "design": {"initial": 3, "per_round": 2, "max_maneuvers": 5},
        **overrides,
    }
    return load_config(SMOKE, overrides=data)


@pytest.mark.slow
def test_smoke_campaign_logs_every_round_metric_to_sqlite(tmp_path):
    cfg = tiny_config(tmp_path)
    tracker = Tracker(cfg.tracking.uri, cfg.tracking.experiment)
    result = Campaign(cfg, tmp_path / "c", tracker=tracker).run()
    run_id = result.state.run_id
    assert tracker.run_status(run_id) == "FINISHED"
    for name in ROUND_METRICS:
        steps = [step for step, _ in tracker.metric_history(run_id, name)]
        assert len(steps) >= 2, name
    # step = maneuvers collected, growing with the budget; the training rows are a metric of their own
    steps = [step for step, _ in tracker.metric_history(run_id, "test_rmse")]
    assert steps == sorted(steps) and steps[0] < steps[-1]
    assert result.history["n_maneuvers"].tolist() == steps == [3, 5]
    rows = tracker.metric_history(run_id, "n_samples")
    assert rows == [(s, float(n)) for s, n in zip(steps, result.history["n_samples"], strict=True)]
    assert (tmp_path / "c" / "figures" / "epistemic_round01.png").exists()
    assert len(result.state.taken) == 5 and len(set(result.state.taken)) == 5


def tiny_file(tmp_path: Path) -> Path:
    """`tiny_config`'s sizes (two rounds, 25 epochs) as a config file for the CLI, writing under tmp_path."""
    path = smoke_file(tmp_path, max_maneuvers=5)
    path.write_text(path.read_text().replace("epochs = 60", "epochs = 25"))
    return path


def _run_cli(args, **kwargs):
    return subprocess.Popen([sys.executable, "-m", "activelearn.cli", *args], **kwargs)


# The real CLI in a process of its own that sends itself a signal the moment its campaign reports an
# event (through the public `Campaign.progress` hook, which the CLI's progress bar also uses).
# `signal.raise_signal` delivers it before returning, so the signal lands at exactly that point
# however loaded the machine is; waiting for a checkpoint file and signalling from outside raced
# with the campaign's last rounds (they take about a second).
_SIGNAL_AT_EVENT = """
import signal
import sys

from activelearn import cli
from activelearn.loop import campaign

name, event_name, event_round, *argv = sys.argv[1:]
# Ctrl-C raises KeyboardInterrupt, as in a terminal, even where the suite itself runs with SIGINT
# ignored (a background job of a non-interactive shell), which its children would inherit.
signal.signal(signal.SIGINT, signal.default_int_handler)


class SignalledCampaign(campaign.Campaign):
    @property
    def progress(self):
        return self._progress

    @progress.setter
    def progress(self, report):
        def progress(event):
            report(event)
            if event["event"] == event_name and event["round"] == int(event_round):
                signal.raise_signal(getattr(signal, name))

        self._progress = progress


campaign.Campaign = SignalledCampaign
raise SystemExit(cli.main(argv))
"""


def _run_cli_signalled(signal_name: str, at: tuple[str, int], args, **kwargs):
    """`_run_cli`, but the CLI process signals itself when its campaign reports event `at` (name, round)."""
    command = [sys.executable, "-c", _SIGNAL_AT_EVENT, signal_name, at[0], str(at[1]), *args]
    return subprocess.Popen(command, **kwargs)


@pytest.mark.slow
def test_killed_campaign_resumes_to_identical_data(tmp_path):
    common = ["campaign", "run", str(tiny_file(tmp_path)), "--no-tracking", "--seed", "3"]
    assert main([*common, "--out", str(tmp_path / "ref")]) == 0  # in this process: only the victim is killed

    # Killed as round 1 starts: round 0 is checkpointed, round 1's work is lost and redone on resume.
    victim = _run_cli_signalled("SIGKILL", ("fit", 1), [*common, "--out", str(tmp_path / "kill")])
    assert victim.wait(timeout=300) == -signal.SIGKILL
    killed_state = CampaignState.load(tmp_path / "kill")
    assert not killed_state.finished, "the kill came too late to test anything"
    assert len(killed_state.rounds) == 1

    assert main([*common, "--out", str(tmp_path / "kill"), "--resume"]) == 0
    ref_samples = pd.read_parquet(tmp_path / "ref" / "samples.parquet")
    resumed_samples = pd.read_parquet(tmp_path / "kill" / "samples.parquet")
    pd.testing.assert_frame_equal(ref_samples, resumed_samples)
    ref_state, res_state = CampaignState.load(tmp_path / "ref"), CampaignState.load(tmp_path / "kill")
    assert ref_state.batches == res_state.batches
    for a, b in zip(ref_state.rounds, res_state.rounds, strict=True):
        assert a["test_rmse"] == b["test_rmse"] and a["test_nll"] == b["test_nll"]


def test_a_checkpoint_from_before_a_new_config_field_resumes_and_a_changed_config_does_not(tmp_path, capsys):
    """An upgrade that adds a config field (at a default that keeps the old behaviour) changes the
    whole config's hash: the checkpoint is still resumed, since its own config read by this version is
    this config. A checkpoint whose config really differs is refused, naming --resume."""
    out = tmp_path / "c"
    common = ["campaign", "run", str(tiny_file(tmp_path)), "--no-tracking", "--seed", "3", "--out", str(out)]
    assert main(common) == 0
    samples = pd.read_parquet(out / "samples.parquet")
    stored = json.loads((out / CONFIG_FILE).read_text())
    del stored["model"]["correction_symmetry"]  # as a version before the field wrote it
    (out / CONFIG_FILE).write_text(json.dumps(stored))
    state_file = out / "state.json"
    state = json.loads(state_file.read_text())
    state["config_hash"] = "0" * 16  # that version's hash of its (smaller) config
    state_file.write_text(json.dumps(state))
    assert main([*common, "--resume"]) == 0
    pd.testing.assert_frame_equal(pd.read_parquet(out / "samples.parquet"), samples)

    stored["training"]["epochs"] += 1  # a checkpoint of another campaign
    (out / CONFIG_FILE).write_text(json.dumps(stored))
    capsys.readouterr()
    assert main([*common, "--resume"]) == 2
    assert "--resume" in capsys.readouterr().err


@pytest.mark.slow
def test_ctrl_c_marks_the_run_killed_and_leaves_a_resumable_directory(tmp_path):
    uri = f"sqlite:///{tmp_path}/mlruns/mlflow.db"
    out, config = tmp_path / "c", tiny_file(tmp_path)
    # Ctrl-C as round 1 starts (after round 0's checkpoint), wherever the machine's load would put it.
    proc = _run_cli_signalled("SIGINT", ("fit", 1),
                              ["campaign", "run", str(config), "--out", str(out), "--tracking-uri", uri],
                              stderr=subprocess.PIPE, text=True)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err
    assert "--resume" in err
    state = CampaignState.load(out)
    assert not state.finished
    assert len(state.rounds) == 1
    assert Tracker(uri).run_status(state.run_id) == "KILLED"
    assert main(["campaign", "run", str(config), "--out", str(out), "--tracking-uri", uri, "--resume"]) == 0
    assert CampaignState.load(out).finished
    assert Tracker(uri).run_status(state.run_id) == "FINISHED"


@pytest.mark.parametrize(
    ("patch", "key"),
    [
        ({"pool": {"kinds": ["drift"]}}, "pool.kinds.0"),
        ({"pool": {"throttles": [0.5, 1.5]}}, "pool.throttles.1"),
        ({"design": {"initial": 0}}, "design.initial"),
        ({"design": {"per_round": "two"}}, "design.per_round"),
        ({"design": {"initial_start": "edge"}}, "design.initial_start"),
        ({"training": {"lr": -1.0}}, "training.lr"),
        ({"model": {"kind": "gp"}}, "model.kind"),
        ({"acquisition": {"batchsize": 3}}, "acquisition.batchsize"),
        ({"strategy": "psychic"}, "strategy"),
        ({"colour": "red"}, "colour"),
    ],
)
def test_bad_configs_are_rejected_naming_the_key(patch, key):
    with pytest.raises(ConfigError) as info:
        validate_config(patch)
    assert info.value.field == key
    assert key in str(info.value)


@pytest.mark.slow
def test_cli_rejects_a_bad_config_with_exit_code_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(SMOKE.read_text().replace("initial = 3", "initial = -3"))
    proc = _run_cli(["campaign", "run", str(bad), "--no-tracking", "--out", str(tmp_path / "o")],
                    stderr=subprocess.PIPE, text=True)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2
    assert "design.initial" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
@pytest.mark.parametrize("command", ["campaign run", "compare"])
def test_an_unreachable_tracking_server_is_one_error_within_5_s_and_nothing_runs(
    tmp_path, capsys, silent_server, command, default_cache
):
    config = smoke_file(tmp_path)
    extra = ["--strategies", "uniform", "--seeds", "1"] if command == "compare" else []
    started = time.perf_counter()
    code = main([*command.split(), str(config), *extra, "--out", str(tmp_path / "out"),
                 "--tracking-uri", f"http://127.0.0.1:{silent_server}"])  # fmt: skip
    assert code == 2 and time.perf_counter() - started < UNREACHABLE_SECONDS
    err = capsys.readouterr().err
    assert "tracking.uri" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists() and not (tmp_path / "runs").exists()  # nothing simulated


def test_campaign_run_with_params_trains_the_tuned_model(tmp_path):
    config = smoke_file(tmp_path, max_maneuvers=3)  # one round
    params = tmp_path / "best.toml"  # written as `tune` writes best.toml
    params.write_text(params_toml({"arch": "D8-V4-V", "activation": "tanh"}, {"epochs": 7, "lr": 0.0123}))
    out = tmp_path / "out"
    args = ["campaign", "run", str(config), "--params", str(params), "--out", str(out), "--no-tracking"]
    assert main(args) == 0
    used = json.loads((out / CONFIG_FILE).read_text())
    assert (used["model"]["arch"], used["model"]["activation"]) == ("D8-V4-V", "tanh")
    assert (used["training"]["epochs"], used["training"]["lr"]) == (7, 0.0123)
    assert used["training"]["batch_size"] == 64  # the rest is the config's own
    assert load_model(out / MODEL_FILE).config.arch == "D8-V4-V"


@pytest.mark.slow
def test_comparison_produces_its_table_and_figure(tmp_path):
    cfg = tiny_config(tmp_path)
    result = compare(cfg, ["uniform", "max_epistemic"], [0, 1], directory=tmp_path / "cmp", workers=2)
    assert result.figure_path is not None and result.figure_path.stat().st_size > 10_000
    table = result.table.set_index("strategy")
    assert set(table.index) == {"uniform", "max_epistemic"}
    assert np.isfinite(table[["final_rmse", "final_nll", "rmse_auc"]].to_numpy()).all()
    # uniform reaches its own final RMSE by definition of the target, at its full budget or earlier
    assert table.loc["uniform", "maneuvers_to_target"] <= 5
    tracker = Tracker(cfg.tracking.uri, cfg.tracking.experiment)
    assert len(tracker.child_runs(result.parent_run_id)) == 4
    assert tracker.run_status(result.parent_run_id) == "FINISHED"


def test_stop_rule_ends_the_campaign_early(tmp_path):
    cfg = tiny_config(tmp_path, design={"initial": 3, "per_round": 2, "max_maneuvers": 9,
                                        "stop_epistemic_std": 10.0})
    result = Campaign(cfg, tmp_path / "c").run(figures=False)
    assert result.state.stop_reason == "stop_epistemic_std"
    assert len(result.state.taken) == 3

