"""A write that fails (disk full) at each write of a campaign's checkpoints, through the real CLI.

The n-th write into the campaign directory raises OSError(ENOSPC), for every n the campaign makes: the
command stops with one line saying to resume (exit 75), the directory keeps its last finished step, and
`--resume` ends with the same data and metrics as a run without faults, each round in MLflow once.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pandas as pd
import pytest

from activelearn.cli import EXIT_STOPPED, main
from activelearn.loop.lock import HOLDER_FILE
from activelearn.loop.state import CampaignState
from activelearn.studies.tracking import Tracker

pytestmark = pytest.mark.slow  # a campaign for every checkpoint write that fails

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"
# By default the writes up to the end of the first round (config, state, samples, figure, model, the
# state after the metrics reached MLflow): the second round repeats them. ACTIVELEARN_FAULTS=all: all.
ALL = os.environ.get("ACTIVELEARN_FAULTS") == "all"


class FailingWrites:
    """os.replace (the last step of every atomic write) failing at the n-th write into a directory."""

    def __init__(self, directory: Path, fail_at: int | None) -> None:
        self.directory, self.fail_at, self.count = directory.absolute(), fail_at, 0
        self.names: list[str] = []
        self.replace = os.replace

    def __call__(self, src, dst, **kwargs):
        target = Path(dst).absolute()
        if target.is_relative_to(self.directory) and target.name != HOLDER_FILE:
            self.count += 1
            self.names.append(target.name)
            if self.count == self.fail_at:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(src))
        return self.replace(src, dst, **kwargs)


def _settled(rounds: list[dict]) -> list[dict]:
    """Round metrics without the wall-clock ones (they measure this machine, not the campaign)."""
    clock = ("wall_seconds", "rollout_seconds", "safety_seconds")
    return [{k: v for k, v in r.items() if k not in clock} for r in rounds]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("faults")
    config = root / "tiny.toml"
    text = SMOKE.read_text().replace("max_maneuvers = 7", "max_maneuvers = 5")
    text = text.replace("epochs = 60", "epochs = 20")
    config.write_text(f'output_dir = "{root / "runs"}"\n' + text)
    uri = f"sqlite:///{root}/mlruns/mlflow.db"
    reference = root / "reference"
    writes = FailingWrites(reference, None)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(os, "replace", writes)
        assert main(["campaign", "run", str(config), "--out", str(reference), "--tracking-uri", uri]) == 0
    return root, config, uri, reference, writes.count


def test_a_failed_write_at_each_checkpoint_write_resumes_to_the_same_campaign(setup, capsys, monkeypatch):
    root, config, uri, reference, n_writes = setup
    assert n_writes >= 12  # config, state, samples, model, figures, ... of two rounds
    ref_state = CampaignState.load(reference)
    ref_samples = pd.read_parquet(reference / "samples.parquet")
    tracker = Tracker(uri)
    capsys.readouterr()
    for fail_at in range(1, n_writes + 1 if ALL else n_writes // 2 + 2):
        out = root / f"fail{fail_at:02d}"
        command = ["campaign", "run", str(config), "--out", str(out), "--tracking-uri", uri]
        with monkeypatch.context() as patch:
            patch.setattr(os, "replace", FailingWrites(out, fail_at))
            assert main(command) == EXIT_STOPPED, fail_at
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "No space left on device" in err[0], (fail_at, err)
        if (out / "state.json").exists():  # a step was committed: resume it
            assert "rerun with --resume" in err[0], (fail_at, err)
            assert main([*command, "--resume"]) == 0, fail_at
        else:  # the very first write failed: nothing to resume (--resume would be refused), run again
            assert "no --resume" in err[0], (fail_at, err)
            assert main(command) == 0, fail_at
        capsys.readouterr()
        state = CampaignState.load(out)
        assert state.batches == ref_state.batches, fail_at
        assert _settled(state.rounds) == _settled(ref_state.rounds), fail_at
        pd.testing.assert_frame_equal(pd.read_parquet(out / "samples.parquet"), ref_samples)
        assert tracker.run_status(state.run_id) == "FINISHED" and state.model_logged
        for record in state.rounds:
            for key in ("test_rmse", "n_maneuvers", "prequential_spearman"):
                if key in record:
                    steps = [s for s, _ in tracker.metric_history(state.run_id, key)]
                    assert steps.count(record["n_maneuvers"]) == 1, (fail_at, key, steps)
