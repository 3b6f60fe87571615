"""What a newcomer trips over (issue 26): output paths, --resume, silent defaults, help texts, figures.

Every mistake is one error line naming the option, exit code 2, and nothing written anywhere: neither
next to the output nor in the current directory (no runs/, no mlruns/).
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from activelearn.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ROOT / "experiments" / "configs" / "smoke.toml"
SKIDPAD = ["--maneuver", "skidpad", "--throttle", "0.6", "--steering", "0.3", "--duration", "2"]


def run(argv: list[str]) -> int:
    """Exit code of the CLI, whether it returns or exits."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


def rejected(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one error line of a command that must fail with exit code 2."""
    assert run(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:"), err
    return err[0]


@pytest.fixture
def cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, default_cache: None) -> Path:
    """A fresh current directory holding one plain file, `afile` (the simulation cache where a user's
    would be: under it)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("not a folder")
    return tmp_path


def untouched(directory: Path) -> bool:
    return sorted(p.name for p in directory.iterdir()) == ["afile"]


# --- 1. output paths are checked before any work --------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["simulate", *SKIDPAD, "--out", "afile/sub.csv"], "--out"),
        (["simulate", *SKIDPAD, "--out", "ok.csv", "--plot", "afile/sub.png"], "--plot"),
        (["predict", "--model", "none.pt", *SKIDPAD, "--out", "afile/sub.png"], "--out"),
        (["campaign", "run", str(SMOKE), "--no-tracking", "--out", "afile/sub"], "--out"),
        (["campaign", "run", str(SMOKE), "--no-tracking", "--out", "afile"], "--out"),
        (["campaign", "propose", str(SMOKE), "--no-tracking", "--out", "afile/sub"], "--out"),
        (["compare", str(SMOKE), "--no-tracking", "--seeds", "1", "--out", "afile/sub"], "--out"),
        (["fidelity", "afile", "--plot", "afile/sub.png"], "--plot"),
        (["tune", str(SMOKE), "--n-trials", "1", "--no-tracking", "--out", "afile/best.toml"], "--out"),
    ],
)
def test_an_output_path_through_a_file_is_one_line_before_any_work(
    cwd: Path, capsys: pytest.CaptureFixture[str], argv: list[str], option: str
) -> None:
    line = rejected(argv, capsys)
    assert option in line and "afile" in line and "not a folder" in line
    assert untouched(cwd)


# --- 2. --resume needs something to resume --------------------------------------------------------


@pytest.mark.parametrize(
    "argv",
    [
        ["campaign", "run", str(SMOKE), "--no-tracking", "--resume", "--out", "mistyped"],
        ["campaign", "propose", str(SMOKE), "--no-tracking", "--resume", "--out", "mistyped"],
        ["compare", str(SMOKE), "--no-tracking", "--seeds", "1", "--resume", "--out", "mistyped"],
    ],
)
def test_resume_of_a_directory_without_a_campaign_is_an_error(
    cwd: Path, capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    line = rejected(argv, capsys)
    assert "--resume" in line and "mistyped" in line and "to resume" in line
    assert untouched(cwd)


# --- 3. and 4. predict: what a model folder lacks; no store created ---------------------------------


def test_predict_names_what_a_model_folder_lacks(cwd: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (cwd / "proposed").mkdir()  # e.g. a campaign directory before its first fitted round
    (cwd / "proposed" / "state.json").write_text("{}")
    line = rejected(["predict", "--model", "proposed", *SKIDPAD], capsys)
    assert "--model" in line and "no model.pt" in line
    assert sorted(p.name for p in cwd.iterdir()) == ["afile", "proposed"]


def test_predict_of_a_run_in_a_missing_store_creates_no_store(
    cwd: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    line = rejected(["predict", "--model", "runs:/deadbeef/model", *SKIDPAD], capsys)
    assert "--tracking-uri" in line and "mlruns/mlflow.db" in line
    line = rejected(["predict", "--model", "none.pt", *SKIDPAD, "--run-id", "deadbeef"], capsys)
    assert "--tracking-uri" in line
    assert untouched(cwd)


def test_a_compare_that_cannot_reach_its_tracking_server_writes_no_cache(
    cwd: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import socket

    with socket.socket() as probe:  # a loopback port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    line = rejected(["compare", str(SMOKE), "--seeds", "1", "--tracking-uri", f"http://127.0.0.1:{port}",
                     "--out", "cmp"], capsys)  # fmt: skip
    assert "tracking" in line
    assert untouched(cwd)  # no runs/cache, no cmp/


def test_help_says_where_the_simulation_cache_goes(capsys: pytest.CaptureFixture[str]) -> None:
    for command in (["compare"], ["campaign", "run"], ["campaign", "propose"]):
        assert run([*command, "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        assert "output_dir/cache (default ./runs/cache), whatever --out says" in text
        assert "ACTIVELEARN_CACHE_DIR" in text


def test_a_campaign_caches_in_the_folder_activelearn_cache_dir_names(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from activelearn.config import load_config
    from activelearn.loop.campaign import Campaign
    from activelearn.loop.collection import CACHE_ENV, cache_root

    cfg = load_config(SMOKE, overrides={"output_dir": str(tmp_path / "runs"), "tracking": {"enabled": False}})
    monkeypatch.delenv(CACHE_ENV, raising=False)
    assert cache_root(cfg) == tmp_path / "runs" / "cache"
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "shared"))
    assert cache_root(cfg) == tmp_path / "shared"
    campaign = Campaign(cfg, tmp_path / "c")
    assert campaign.nominal.root.parent == campaign.oracle.cache.root.parent == tmp_path / "shared"


# --- 5. no silent defaults for the steering ---------------------------------------------------------


@pytest.mark.parametrize(
    ("maneuver", "steering", "reason"),
    [
        ("skidpad", None, "needs its steering amplitude"),
        ("slalom", None, "needs its steering amplitude"),
        ("eight", None, "needs its steering amplitude"),
        ("straight", "0.3", "does not steer"),
    ],
)
@pytest.mark.parametrize("command", ["simulate", "predict"])
def test_steering_is_never_silently_dropped_or_defaulted(
    cwd: Path, capsys: pytest.CaptureFixture[str], command: str, maneuver: str, steering: str | None,
    reason: str,
) -> None:
    argv = [command, "--maneuver", maneuver, "--throttle", "0.5", "--duration", "1"]
    argv += ["--steering", steering] if steering is not None else []
    argv += ["--out", "run.csv"] if command == "simulate" else ["--model", "none.pt"]
    line = rejected(argv, capsys)
    assert "--steering" in line and reason in line
    assert untouched(cwd)


def test_a_straight_without_steering_still_drives(cwd: Path) -> None:
    argv = ["simulate", "--maneuver", "straight", "--throttle", "0.5", "--duration", "1", "--out", "s.csv"]
    assert run(argv) == 0
    assert (pd.read_csv(cwd / "s.csv")["op_steering"] == 0.0).all()


# --- 6. help texts and the README ---------------------------------------------------------------------


def test_help_lists_every_strategy_and_the_out_defaults_of_the_command_reference(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Each --out default the help gives is the command reference's, which the tools are held to below."""
    from activelearn.loop.acquisition import STRATEGIES
    from activelearn.names import STRATEGY_NAMES

    assert STRATEGY_NAMES == tuple(STRATEGIES)
    table = _outputs_table()
    for command, default in (("campaign run", table["campaign run"][0]),
                             ("campaign propose", table["campaign propose"][0]),
                             ("compare", table["compare"][0]),
                             ("tune", table["tune"][0] + "best.toml")):  # fmt: skip
        assert run([*command.split(), "--help"]) == 0
        text = " ".join(capsys.readouterr().out.split())
        if command != "tune":
            assert all(re.search(rf"\b{name}\b", text) for name in STRATEGIES), command
        assert f"default {default}" in text, (command, default)


def test_top_level_help_describes_the_tool_not_the_module(capsys: pytest.CaptureFixture[str]) -> None:
    assert run(["--help"]) == 0
    out = capsys.readouterr().out
    assert "only module" not in out and "Nigel" in out
    assert re.search(r"campaign\s+run, propose or ingest", out)


@pytest.mark.parametrize(
    ("argv", "choices"), [([], "simulate, campaign"), (["campaign"], "run, propose, ingest")]
)
def test_a_missing_sub_command_names_the_choices(
    capsys: pytest.CaptureFixture[str], argv: list[str], choices: str
) -> None:
    line = rejected(argv, capsys)
    assert "campaign_command" not in line and choices in line


def test_a_typo_in_a_config_key_suggests_the_nearest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "typo.toml"
    config.write_text(SMOKE.read_text().replace("initial = 3", "inital = 3"))
    line = rejected(["campaign", "run", str(config), "--no-tracking", "--out", str(tmp_path / "o")], capsys)
    assert "design.inital" in line and "did you mean design.initial?" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["typo.toml"]


def _documentation() -> str:
    """The README and every page of the documentation (docs/), as one text."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return "\n".join(page.read_text() for page in pages if "results/files" not in page.as_posix())


def _readme_commands() -> list[list[str]]:
    """Every `$A ...`, `activelearn ...` or `.venv/bin/activelearn ...` command the README or docs/ quote."""
    text = _documentation().replace("\\\n", " ")
    found = []
    for line in text.splitlines():
        match = re.match(r"\s*(?:\$A|(?:\.venv/bin/)?activelearn)\s+([a-z].*)", line)
        if match:
            found.append(shlex.split(match.group(1).split("#")[0].replace("…", "x").replace("...", "x")))
    for match in re.finditer(r"`activelearn ([a-z][^`]*)`", text):
        found.append(shlex.split(match.group(1)))
    return found


def test_every_option_the_readme_quotes_exists() -> None:
    parser = build_parser()
    commands = _readme_commands()
    assert len(commands) > 15
    readme = ROOT.joinpath("README.md").read_text()
    assert "$A campaign ingest" in readme and "$A fidelity" in readme  # the README keeps its command tour
    for words in commands:
        sub = parser._subparsers._group_actions[0].choices[words[0]]  # type: ignore[union-attr]
        if words[0] == "campaign" and len(words) > 1 and not words[1].startswith("-"):
            sub = sub._subparsers._group_actions[0].choices[words[1]]  # type: ignore[union-attr]
        known = {s for action in sub._actions for s in action.option_strings}
        for word in words:
            option = word.strip("[]").split("=")[0]
            if option.startswith("--"):
                assert option in known, (words, option)


def _outputs_table() -> dict[str, tuple[str, list[str]]]:
    """docs/reference/commands.md's "Where outputs go": command -> (default directory, files it writes there).

    A row reads `DIR`: `FILE`, `FILE`, ...; free text after a ";" and rows naming no directory (the
    commands that write the file --out names) are not read.
    """
    text = (ROOT / "docs" / "reference" / "commands.md").read_text()
    section = text.split("## Where outputs go", 1)[1].split("\n## ", 1)[0]
    table, unread = {}, []
    for line in section.splitlines():
        if not line.startswith("| `"):
            continue
        cells = [cell.strip() for cell in line.strip("| ").split(" | ")]
        commands = re.findall(r"`([^`]+)`", cells[0])
        match = re.match(r"`([^`]+)`: ([^;]*)", cells[1])
        if match is None:
            unread += commands
            continue
        for command in commands:
            table[command] = (match.group(1), re.findall(r"`([^`]+)`", match.group(2)))
    assert unread == ["simulate", "predict", "fidelity --plot"], unread
    return table


def _placed(path: str, values: dict[str, str]) -> str:
    """A path of the table with its placeholders filled in, round numbers as glob digits."""
    for placeholder, value in values.items():
        path = path.replace(placeholder, value)
    return path.replace("NNN", "[0-9]" * 3).replace("NN", "[0-9]" * 2)


# The smoke config, smaller still: 5 maneuvers (2 rounds), 5 epochs, a tuning space of short trials. Its
# output_dir is not the default (runs), so a path the table spells `runs/` where it means <output_dir> fails.
TINY = 'output_dir = "outputs"\n' + SMOKE.read_text().replace("max_maneuvers = 7", "max_maneuvers = 5")
TINY = TINY.replace("epochs = 60", "epochs = 5") + """
[tuning.space]
epochs = { low = 3, high = 5 }
n_layers = 1
width = [8, 16]
"""


@pytest.mark.slow
def test_each_command_writes_its_files_where_the_command_reference_says(
    cwd: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    table = _outputs_table()
    (cwd / "tiny.toml").write_text(TINY)
    assert 'name = "smoke"' in TINY
    commands = {  # each command the table lists, with no --out, and the strategy it runs
        "campaign run": (["campaign", "run", "tiny.toml"], "max_epistemic"),  # the config's strategy
        "campaign propose": (["campaign", "propose", "tiny.toml", "--strategy", "uniform"], "uniform"),
        "compare": (["compare", "tiny.toml", "--strategies", "uniform", "--seeds", "1"], "uniform"),
        "tune": (["tune", "tiny.toml", "--n-trials", "2"], None),  # 2 trials: a parameter importance
    }
    assert set(table) == set(commands)
    for command, (argv, strategy) in commands.items():
        assert run([*argv, "--no-tracking"]) == 0, capsys.readouterr().err
        capsys.readouterr()
        values = {"<output_dir>": "outputs", "<name>": "smoke", "<study>": "smoke", "<N>": "0"}
        values |= {"<strategy>": strategy} if strategy else {}
        base, files = table[command]
        directory = cwd / _placed(base, values)
        assert directory.is_dir(), (command, directory)
        assert files, command
        for name in files:
            found = sorted(directory.glob(_placed(name, values)))
            assert found, (command, directory, name, sorted(p.name for p in directory.iterdir()))
        if command == "compare":  # the seed's campaign holds what `campaign run` writes
            seed = directory / _placed("<strategy>/seed<N>", values)
            assert all(list(seed.glob(_placed(name, values))) for name in table["campaign run"][1])


def test_readme_paths_are_the_ones_the_tools_write() -> None:
    readme = ROOT.joinpath("README.md").read_text()
    text = _documentation()  # the README and docs/
    assert "runs/tune/" not in text  # tune writes <output_dir>/tuning/<study>/best.toml (checked above)
    makefile = ROOT.joinpath("Makefile").read_text()
    demo = re.search(r"^demo:.*\n((?:\t.*\n)+)", makefile, re.M).group(1)  # type: ignore[union-attr]
    assert "--out runs/demo/" in demo and "--out runs/demo/<time>" in " ".join(readme.split())
    for flag in ("--no-tracking", "--run-id", "--samples", "--rate", "--noise", "--no-noise"):
        assert flag in text, flag
    assert "oracle_lookahead" in text


# --- 7. figures -----------------------------------------------------------------------------------------


def test_simulate_plot_draws_throttle_and_steering_on_panels_of_their_own() -> None:
    from activelearn.plots import plot_log

    t = np.arange(0, 2, 0.1)
    table = pd.DataFrame({"timestamp": t, "posX": t, "posY": 0 * t, "speed": t, "angZ": t, "yaw": t,
                          "throttle": 0.6 + 0 * t, "steering": 0.6 + 0 * t})  # equal values: drawn apart
    fig = plot_log(table, title="one run")
    labels = [ax.get_ylabel() for ax in fig.axes]
    throttle = next(ax for ax in fig.axes if ax.get_ylabel() == "throttle")
    steering = next(ax for ax in fig.axes if ax.get_ylabel().startswith("steering"))
    assert throttle is not steering and len(throttle.lines) == len(steering.lines) == 1, labels
    assert fig.axes[0].get_legend() is None  # one run: the title names it


def test_epistemic_map_legend_shows_only_what_is_drawn() -> None:
    from activelearn.plots import epistemic_map
    from simulator import Maneuver

    grid = np.linspace(0.3, 0.9, 3)
    taken = [Maneuver("skidpad", 0.6, 0.3, "ccw", 10.0)]
    fig = epistemic_map(grid, grid - 0.6, np.ones((3, 3)), taken=taken, picks=[], title="last round")
    labels = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    assert labels == ["collected (skidpad)"]
    mixed = [Maneuver("straight", 0.4, 0.0, "ccw", 10.0)]
    fig = epistemic_map(grid, grid - 0.6, np.ones((3, 3)), taken=taken, picks=mixed, title="round 1")
    labels = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    assert labels == ["collected", "chosen this round", "shape: skidpad", "shape: straight"]


def test_round_figure_shows_the_chosen_signals_and_their_predicted_paths(tmp_path) -> None:
    from activelearn.config import ModelConfig
    from activelearn.numerics.models import build_model
    from activelearn.numerics.surrogate import simulate
    from activelearn.plots import epistemic_map
    from simulator import FamilyManeuver, Maneuver, nominal_controls

    picks = [
        FamilyManeuver("chirp", {"throttle": 0.6, "amplitude": 0.3, "f0": 0.05, "f1": 0.5}, "ccw", 6.0),
        Maneuver("skidpad", 0.5, 0.4, "cw", 4.0),
    ]
    controls = [nominal_controls(m) for m in picks]
    rollout = simulate(build_model(ModelConfig()), controls, rate_hz=30.0, n_samples=4)
    grid = np.linspace(0.3, 0.9, 3)
    plans = ([m.name for m in picks], controls, rollout)
    fig = epistemic_map(grid, grid - 0.6, np.ones((3, 3)), taken=[], picks=picks[1:], plans=plans)
    titles = {ax.get_title() for ax in fig.axes}
    assert {"chosen control signals", "predicted paths (mean, fan)"} <= titles
    labels = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    assert picks[0].name in labels and picks[1].name in labels  # one colour per chosen signal
    signals = next(ax for ax in fig.axes if ax.get_title() == "chosen control signals")
    np.testing.assert_array_equal(signals.lines[0].get_ydata(), controls[0][:, 0])
    path = next(ax for ax in fig.axes if ax.get_title() == "predicted paths (mean, fan)")
    assert len(path.lines) == 2 * (4 + 2) + 1  # per pick: 4 sampled paths, the mean, its end; the start
    fig.savefig(tmp_path / "round.png", dpi=60)
    assert (tmp_path / "round.png").stat().st_size > 0
    assert len(epistemic_map(grid, grid - 0.6, np.ones((3, 3)), taken=[], picks=[]).axes) == 2  # map only


@pytest.mark.parametrize("n_picks", [1, 8])
def test_the_round_figures_text_stays_inside_it_and_off_the_other_panels(n_picks: int) -> None:
    """The round figure is laid out by hand (no constrained layout): its labels, ticks, titles and
    legends must fit, also with a batch of 8 long names, a fast car's paths (hundreds of metres) and
    every family's shape in the map's legend."""
    import dataclasses

    from activelearn.config import ModelConfig
    from activelearn.numerics.models import build_model
    from activelearn.numerics.surrogate import simulate
    from activelearn.plots import epistemic_map
    from simulator import FamilyManeuver, nominal_controls
    from simulator.families import FAMILIES

    picks = [FamilyManeuver("chirp", {"throttle": 0.6, "amplitude": 0.3, "f0": 0.05 + 0.01 * k, "f1": 0.5},
                            "ccw", 6.0) for k in range(n_picks)]  # fmt: skip
    controls = [nominal_controls(m) for m in picks]
    rollout = simulate(build_model(ModelConfig()), controls, rate_hz=30.0, n_samples=4)
    rollout = dataclasses.replace(rollout, x=rollout.x * -400.0, y=rollout.y * 400.0)  # −1000 m and more
    taken = [FamilyManeuver(name, {p.name: p.pool[0] for p in family.parameters}, "cw", 10.0)
             for name, family in FAMILIES.items()]  # fmt: skip
    steerings = np.linspace(-0.52, 0.52, 5)
    plans = ([m.name * 2 for m in picks], controls, rollout)
    fig = epistemic_map(np.linspace(-1.0, 1.0, 5), steerings, np.full((5, 5), 1e-3), taken=taken, picks=picks,
                        title="integrated_variance, seed 12, round 16", plans=plans)  # fmt: skip
    renderer = fig.canvas.get_renderer()
    page = fig.bbox
    boxes = [ax.get_tightbbox(renderer) for ax in fig.axes]
    boxes += [legend.get_window_extent(renderer) for legend in fig.legends]
    for box in boxes:
        inside = page.x0 <= box.x0 and box.x1 <= page.x1 and page.y0 <= box.y0 and box.y1 <= page.y1
        assert inside, (box, page)
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert not a.overlaps(b), (a, b)


@pytest.mark.parametrize(("seeds", "says"), [(1, "1 seed (no band)"), (3, "mean ± 1 s.e. over 3 seeds")])
def test_comparison_figure_has_one_legend_and_says_what_the_band_is(seeds: int, says: str) -> None:
    from activelearn.plots import comparison_figure

    curves = pd.DataFrame([
        {"strategy": s, "seed": seed, "round": r, "n_maneuvers": 3 + 2 * r, "track_seconds": 60.0 + 40 * r,
         "test_rmse": 0.5 / (r + 1) + 0.01 * seed, "test_nll": 1.0 - r}
        for s in ("uniform", "auto") for seed in range(seeds) for r in range(3)
    ])  # fmt: skip
    fig = comparison_figure(curves, ["test_rmse", "test_nll"], title="demo", seconds=True)
    assert fig.get_suptitle() == f"demo: {says}"
    assert all(ax.get_legend() is None for ax in fig.axes) and len(fig.legends) == 1
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["uniform (reference)", "auto"]
    assert fig.legends[0].get_texts()[0].get_fontsize() >= 10


def test_fidelity_legend_names_simulator_and_log(tmp_path: Path) -> None:
    from activelearn.plots import fidelity_figure

    points = pd.DataFrame({"throttle": [1.0, 1.0], "steering": [0.0, 0.21], "v_sim": [0.25, 0.23],
                           "v_log": [0.26, 0.24], "w_sim": [0.0, 0.33], "w_log": [0.0, 0.37],
                           "loss_sim": [np.nan, 0.01], "loss_log": [np.nan, 0.02]})
    fig = fidelity_figure(points, title="t")
    labels = [t.get_text() for legend in fig.legends for t in legend.get_texts()]
    assert labels == ["throttle 1", "simulator (line, ×)", "recorded log (○)"]
    assert all(ax.get_legend() is None for ax in fig.axes)


@pytest.mark.slow
def test_an_mlflow_model_loads_without_leaving_files_behind(tmp_path: Path, monkeypatch) -> None:
    import tempfile

    from activelearn.config import ModelConfig
    from activelearn.errors import ConfigError
    from activelearn.numerics.models import build_model
    from activelearn.studies.tracking import Tracker, load_model, model_requirements

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "scratch"))
    (tmp_path / "scratch").mkdir()
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    tracker = Tracker(uri)
    run_id = tracker.start_run("m")
    model = build_model(ModelConfig())
    model_uri = tracker.log_model(run_id, model)
    x = np.array([[0.5, 0.1], [0.2, -0.3]])
    loaded = load_model(model_uri, uri)
    np.testing.assert_array_equal(loaded.predict(x, n_samples=4).mean, model.predict(x, n_samples=4).mean)
    [requirements] = (tmp_path / "artifacts").rglob("requirements.txt")
    assert requirements.read_text().split() == model_requirements()  # named, not inferred (~10 s)
    with pytest.raises(ConfigError, match="--model"):
        load_model("runs:/deadbeef/model", uri)
    assert list((tmp_path / "scratch").iterdir()) == []  # no activelearn-model-* folders left


def test_experiments_say_they_hold_model_training_runs(tmp_path: Path) -> None:
    """MLflow >= 3 records an experiment's type in its `mlflow.experimentKind` tag (else it guesses):
    experiments the project creates are "custom_model_development" (model training, not GenAI), an
    existing one without the tag gets it, and a kind someone chose is left alone."""
    from mlflow.tracking import MlflowClient

    from activelearn.studies.tracking import EXPERIMENT_KIND, EXPERIMENT_KIND_TAG, Tracker

    assert (EXPERIMENT_KIND_TAG, EXPERIMENT_KIND) == ("mlflow.experimentKind", "custom_model_development")
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    Tracker(uri)  # the default experiment, "activelearn"
    client = MlflowClient(uri)
    assert client.get_experiment_by_name("activelearn").tags[EXPERIMENT_KIND_TAG] == EXPERIMENT_KIND
    old = client.create_experiment("older-store")  # as an earlier version of activelearn made it
    assert EXPERIMENT_KIND_TAG not in client.get_experiment(old).tags
    Tracker(uri, "older-store")
    assert client.get_experiment(old).tags[EXPERIMENT_KIND_TAG] == EXPERIMENT_KIND
    client.set_experiment_tag(old, EXPERIMENT_KIND_TAG, "genai_development")
    Tracker(uri, "older-store")
    assert client.get_experiment(old).tags[EXPERIMENT_KIND_TAG] == "genai_development"


# Bad input is answered before torch and the loop are imported (a third of the time of a command that
# imports them first: about 1 s, not 4).
_BEFORE_TORCH = """
import sys
from activelearn import cli

for argv in sys.argv[1:]:
    assert cli.main(argv.split("|")) == 2, argv
    assert "torch" not in sys.modules, argv
"""


def test_bad_input_is_refused_before_torch_is_imported(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(SMOKE.read_text().replace("epochs = 60", "epochs = -1"))
    out = str(tmp_path / "out")
    commands = [
        ["campaign", "run", str(bad), "--no-tracking", "--out", out],
        ["campaign", "propose", str(bad), "--no-tracking", "--out", out],
        ["compare", str(bad), "--no-tracking", "--out", out],
        ["compare", str(SMOKE), "--no-tracking", "--out", out, "--resume"],
        ["predict", "--model", str(tmp_path / "missing.pt"), *SKIDPAD],
    ]
    done = subprocess.run([sys.executable, "-c", _BEFORE_TORCH, *("|".join(c) for c in commands)],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    fields = [error.split(":")[1].strip() for error in errors]
    assert fields == ["training.epochs"] * 3 + ["--resume", "--model"], errors
    assert not (tmp_path / "out").exists()


def test_ctrl_c_outside_a_campaign_is_one_line_and_exit_130(tmp_path, monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("activelearn.config.load_config", interrupted)  # Ctrl-C while the config loads
    assert run(["compare", str(SMOKE), "--no-tracking", "--out", str(tmp_path / "out")]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "interrupted" in err[0], err


# A Ctrl-C while the command line itself imports (its first second: pandas, MuJoCo), raised where the
# import reaches the simulator's log writer; then the console script's entry point as it runs.
_INTERRUPTED_IMPORT = """
import sys

class CtrlC:
    def find_spec(self, name, path=None, target=None):
        if name == "simulator.collect":
            raise KeyboardInterrupt
        return None

sys.meta_path.insert(0, CtrlC())
from activelearn.console import main
sys.exit(main(["--help"]))
"""


def test_a_ctrl_c_while_the_command_line_imports_is_one_line_and_exit_130():
    from importlib.metadata import entry_points

    (script,) = entry_points(group="console_scripts", name="activelearn")
    assert script.value == "activelearn.console:main"  # what `activelearn` runs
    done = subprocess.run([sys.executable, "-c", _INTERRUPTED_IMPORT], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert done.returncode == 130 and done.stderr == "interrupted\n", done.stderr
