"""Fuzzed input: random configs and mutated AutoDRIVE logs load, or fail with one clear error.

Every input either loads or raises one ConfigError / InputError / DataFormatError; through the CLI
(called in-process) it is exit code 2 with one error line on stderr, no traceback and no file
written. Configs are built from the real schema (`CampaignConfig` and every section under it, found
by walking the pydantic models) and from the shipped `experiments/configs/*.toml`, so sections added
later are fuzzed without changes here. Logs start from a real MuJoCo maneuver, written both as a
headerless AutoDRIVE log and as our CSV with a header. The examples are derandomized (the hypothesis
profile in conftest.py), so every run tries the same inputs.
"""

from __future__ import annotations

import contextlib
import copy
import csv
import io
import math
import tempfile
import tomllib
import types
import typing
import warnings
from collections.abc import Iterator
from datetime import UTC, date, datetime, time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel

import simulator
from activelearn import cli
from activelearn.config import CampaignConfig, ConfigError, load_config, validate_config
from activelearn.data import AUTODRIVE_COLUMNS, SAMPLE_COLUMNS, read_autodrive_log, write_table
from activelearn.errors import ActiveLearnError, DataFormatError, InputError
from activelearn.loop.campaign import Campaign, total_rounds
from activelearn.studies.tuning import load_dataset
from simulator.errors import SimulatorError

CONFIGS = sorted((Path(__file__).resolve().parents[1] / "experiments" / "configs").glob("*.toml"))
SMOKE = CONFIGS[[p.stem for p in CONFIGS].index("smoke")]


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_every_shipped_config_loads(path: Path) -> None:
    """Each of experiments/configs passes the checks a run starts with (safe_track_twin.toml failed the
    live stop's braking check, added after it, unnoticed for a session)."""
    assert load_config(path).name == path.stem

# ----------------------------------------------------------------------------------------- the schema


def _models_in(annotation: Any) -> Iterator[type[BaseModel]]:
    """The pydantic models an annotation mentions (X, X | None, list[X], ...)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield annotation
    for arg in typing.get_args(annotation):
        yield from _models_in(arg)


def _literals_in(annotation: Any) -> Iterator[Any]:
    """The allowed values of every Literal an annotation mentions."""
    if typing.get_origin(annotation) is typing.Literal:
        yield from typing.get_args(annotation)
        return
    for arg in typing.get_args(annotation):
        yield from _literals_in(arg)


def _walk(model: type[BaseModel], prefix: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], Any]]:
    """(path, field info) of every field under `model`, sections included, depth first.

    A field's sections are the models its annotation names or its default is (`Any` fields whose
    default is a model, such as the search space's ranges, count too).
    """
    for name, info in model.model_fields.items():
        path = (*prefix, name)
        yield path, info
        nested = {*_models_in(info.annotation)}
        default = info.get_default(call_default_factory=True)
        if isinstance(default, BaseModel):
            nested.add(type(default))
        for sub in nested:
            yield from _walk(sub, path)


FIELDS = dict(_walk(CampaignConfig))
SECTIONS = [(), *sorted({path[:i] for path in FIELDS for i in range(1, len(path))})]  # tables
CHOICES = sorted({repr(v): v for info in FIELDS.values() for v in _literals_in(info.annotation)}.values(),
                 key=repr)


def _bases() -> list[dict[str, Any]]:
    """Starting points: no config (all defaults), every shipped config, and smoke with a continuous pool."""
    shipped = [tomllib.loads(path.read_text()) for path in CONFIGS]
    ranged = tomllib.loads(SMOKE.read_text())
    ranged["pool"] = {k: v for k, v in ranged["pool"].items() if k not in ("throttles", "steerings")}
    ranged["pool"].update(throttle_range=[0.2, 0.9], steering_range=[0.1, 0.5], size=12)
    return [{}, *shipped, ranged]


BASES = _bases()


def _examples(factor: float) -> int:
    """Examples per test: a share of the profile's count (conftest.py: "ci" 100, "explore" 2000)."""
    return max(1, int(settings.default.max_examples * factor))


def test_every_shipped_config_is_named_after_its_file():
    """A config's name places its outputs (`runs/<name>/...`) and names its MLflow runs: two files with one
    name would write into each other's comparison directory."""
    assert {path.stem: tomllib.loads(path.read_text())["name"] for path in CONFIGS} == {
        path.stem: path.stem for path in CONFIGS}


def test_the_schema_walk_sees_every_section():
    """The fuzzer reaches nested sections (and so will reach sections added later)."""
    for path in [("pool", "throttles"), ("simulation", "noise", "speed"), ("tuning", "space", "lr"),
                 ("tuning", "space", "lr", "low"), ("model", "arch"), ("test", "kinds")]:
        assert path in FIELDS, path
    assert ("simulation", "noise") in SECTIONS and ("tuning", "space") in SECTIONS
    assert {"skidpad", "cw", "relu", "full_cov", "cosine"} <= set(CHOICES)


# ------------------------------------------------------------------------------------- config strategies

EDGE_NUMBERS = [0, 1, -1, 2, 3, 10, 0.5, -0.5, 1e-12, 1e12, 2**31, 2**53 + 1, 2**63, 2**64, -(2**63) - 1,
                10**30, math.nan, math.inf, -math.inf, -0.0, 1e308, 5e-324]
numbers = st.one_of(
    st.sampled_from(EDGE_NUMBERS),
    st.integers(-100, 1000),
    st.floats(allow_nan=True, allow_infinity=True),
)
text = st.text(max_size=12)
# What TOML can hold (no null), mixed freely.
leaves = st.one_of(
    st.booleans(),
    numbers,
    text,
    st.sampled_from(CHOICES),
    st.sampled_from([date(2024, 2, 29), time(12, 30), datetime(2024, 1, 1, 8, 0, tzinfo=UTC)]),
)
garbage = st.recursive(
    leaves,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4),
        st.dictionaries(st.one_of(text, st.sampled_from(sorted({p[-1] for p in FIELDS}))), inner, max_size=3),
    ),
    max_leaves=8,
)


def _bounds(metadata: list[Any]) -> tuple[float, float]:
    """The [low, high] a field's constraints allow (annotated_types Ge/Gt/Le/Lt, or a pydantic Field's)."""
    low, high = -1e6, 1e6
    for item in metadata:
        for constraint in [item, *getattr(item, "metadata", [])]:
            for name, side in (("ge", 0), ("gt", 0), ("le", 1), ("lt", 1)):
                value = getattr(constraint, name, None)
                if isinstance(value, int | float):
                    low, high = (value, high) if side == 0 else (low, value)
    return low, high


def _typed(annotation: Any, metadata: list[Any] = ()) -> st.SearchStrategy:
    """Values of a field's declared type, mostly inside its bounds and sometimes just outside them."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Literal:
        return st.sampled_from(args)
    if origin is typing.Annotated:
        return _typed(args[0], [*metadata, *args[1:]])
    if origin in (typing.Union, types.UnionType):
        return st.one_of([_typed(a, metadata) for a in args if a is not type(None)])
    if origin in (list, tuple):
        element = args[0] if args else Any
        size = (len(args), len(args)) if origin is tuple and ... not in args else (1, 4)
        return st.lists(_typed(element, []), min_size=size[0], max_size=size[1])
    if annotation is bool:
        return st.booleans()
    if annotation in (int, float):
        low, high = _bounds(list(metadata))
        near = [low, high, low - 1, high + 1, low + 0.5, high - 0.5]
        if annotation is int:
            inside = st.integers(int(max(low, -1e6)), int(min(high, 1e6)))
            return st.one_of(inside, st.sampled_from([int(v) for v in near]))
        inside = st.floats(max(low, -1e6), min(high, 1e6))
        return st.one_of(inside, st.sampled_from(near))
    if annotation is str:
        return st.one_of(text, st.sampled_from(CHOICES))
    return garbage  # Any, or a section (garbled whole)


def _table(config: dict[str, Any], path: tuple[str, ...]) -> dict[str, Any]:
    """The table at `path`, created (or replacing garbage) on the way."""
    table = config
    for key in path:
        if not isinstance(table.get(key), dict):
            table[key] = {}
        table = table[key]
    return table


ALL_OPERATIONS = ("plausible", "plausible", "set", "unknown", "delete", "garble")


@st.composite
def configs(draw: st.DrawFn, operations: tuple[str, ...] = ALL_OPERATIONS) -> dict[str, Any]:
    """A base config with up to four mutations: a value of the field's type (`plausible`), garbage
    (`set`), an unknown key, a deleted key, or a whole section replaced by garbage (`garble`)."""
    config = copy.deepcopy(draw(st.sampled_from(BASES)))
    for _ in range(draw(st.integers(0, 4))):
        operation = draw(st.sampled_from(operations))
        if operation in ("plausible", "set"):
            path = draw(st.sampled_from(list(FIELDS)))
            info = FIELDS[path]
            value = _typed(info.annotation, info.metadata) if operation == "plausible" else garbage
            _table(config, path[:-1])[path[-1]] = draw(value)
        elif operation == "unknown":
            section = draw(st.sampled_from(SECTIONS))
            known = {p[-1] for p in FIELDS if p[:-1] == section}
            key = draw(text.filter(lambda k, known=known: k not in known))
            _table(config, section)[key] = draw(garbage)
        elif operation == "delete":
            path = draw(st.sampled_from(list(FIELDS)))
            _table(config, path[:-1]).pop(path[-1], None)
        else:
            section = draw(st.sampled_from(SECTIONS[1:]))
            _table(config, section[:-1])[section[-1]] = draw(garbage)
    return config


# --------------------------------------------------------------------------------------------- helpers


@contextlib.contextmanager
def _scratch() -> Iterator[Path]:
    """A fresh empty directory, also the working directory (so relative defaults land in it)."""
    with tempfile.TemporaryDirectory() as name, contextlib.chdir(name):
        yield Path(name)


def _cheap_pool(cfg: CampaignConfig) -> bool:
    """Whether the config's pool builds in a fraction of a second: at most 5 000 members (a family pool
    draws `size` signals per family, each in every direction) and 2e6 control samples in all, a 30-s pool
    of 2 000 members (each member's operating point reads its whole schedule at 30 Hz: 4 000 members of
    30 s take 0.4 s; in the suite the test's examples reached durations that made it take 300 s)."""
    members = max(1, cfg.pool.size or 0) * max(1, len(cfg.pool.families)) * len(cfg.pool.directions)
    longest = max([cfg.pool.duration, *cfg.pool.durations.values()])
    return members <= 5_000 and members * longest * 30.0 <= 2e6


def _files(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def _cli_rejects(args: list[str], root: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """Run the CLI in-process; assert exit 2, one error line, no traceback, nothing new under root."""
    before = _files(root)
    capsys.readouterr()
    code = cli.main(args)
    out, err = capsys.readouterr()
    assert code == 2, (code, out, err)
    assert len(err.strip().splitlines()) == 1 and err.startswith("error: "), err
    assert "Traceback" not in err and out == "", out
    assert _files(root) == before, _files(root) - before
    return err


# ------------------------------------------------------------------------------------------- configs


@pytest.mark.slow
@given(config=configs())
@settings(max_examples=_examples(4))
def test_a_fuzzed_config_validates_or_is_one_config_error(config):
    try:
        cfg = validate_config(config)
    except ConfigError as exc:
        event("ConfigError")
        assert exc.field and str(exc).startswith(exc.field)
        return
    event("valid")
    assert isinstance(cfg, CampaignConfig)


@pytest.mark.slow
@given(config=configs(), command=st.sampled_from(["campaign", "compare", "tune"]))
@settings(max_examples=_examples(3), suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_a_fuzzed_config_file_loads_or_the_cli_exits_2_writing_nothing(config, command, capsys):
    with _scratch() as root:
        path = root / "fuzzed.toml"
        path.write_text(tomli_w.dumps(config))
        try:
            cfg = load_config(path)
        except ConfigError as exc:
            event(f"ConfigError ({command})")
            args = {
                "campaign": ["campaign", "run", str(path), "--out", str(root / "out")],
                "compare": ["compare", str(path), "--out", str(root / "out"), "--seeds", "1"],
                "tune": ["tune", str(path), "--n-trials", "1", "--storage", f"sqlite:///{root}/optuna.db"],
            }[command]
            err = _cli_rejects(args, root, capsys)
            assert cli.one_line(exc.field) in err  # the field as printed (escaped)
            return
        event("valid")
        # What the CLI builds before any long work (no simulation yet): its pool and budget.
        if _cheap_pool(cfg):
            try:
                campaign = Campaign(cfg, root / "out")
            except (ActiveLearnError, SimulatorError):
                return
            assert total_rounds(cfg, len(campaign.maneuvers)) >= 1
        assert _files(root) == {"fuzzed.toml"}


@given(config=configs(operations=("plausible",)))
@settings(max_examples=_examples(3))
def test_a_config_of_well_typed_values_validates_and_builds_its_campaign_or_is_one_config_error(config):
    """Values of each field's own type, inside and just outside its bounds: what the loop builds before
    it simulates (pool, strategy, budget) must work for every config that validates."""
    try:
        cfg = validate_config(config)
    except ConfigError as exc:
        event("ConfigError")
        assert exc.field
        return
    event("valid")
    if not _cheap_pool(cfg):  # a valid but slow pool: not what this test is about
        return
    with _scratch() as root:
        try:
            campaign = Campaign(cfg, root / "out")
        except (ActiveLearnError, SimulatorError) as exc:
            event(f"rejected by Campaign: {type(exc).__name__}")
            return
        assert total_rounds(cfg, len(campaign.maneuvers)) >= 1
        assert _files(root) == set()


# ---------------------------------------------------------------------------------------------- logs


@pytest.fixture(scope="module")
def real_log() -> list[list[str]]:
    """A short real skidpad from MuJoCo as headerless AutoDRIVE rows (wall-clock timestamps, cam, lidar)."""
    table = simulator.collect([simulator.Maneuver("skidpad", 0.5, 0.3, duration=3.0)], noise=None)
    start = datetime(2024, 5, 17, 9, 30, tzinfo=UTC).timestamp()
    rows = []
    for i, record in enumerate(table[list(AUTODRIVE_COLUMNS)].itertuples(index=False)):
        stamp = datetime.fromtimestamp(start + record.timestamp, UTC)
        fields = [stamp.strftime("%Y_%m_%d_%H_%M_%S_") + f"{stamp.microsecond // 1000:03d}"]
        fields += [repr(float(v)) if isinstance(v, float) else str(v) for v in record[1:]]
        rows.append([*fields, f"cam0/{i}.png", f"cam1/{i}.png", "[1.0 2.0 3.0]"])
    return rows


@pytest.fixture(scope="module")
def our_csv(tmp_path_factory) -> list[list[str]]:
    """The same kind of maneuver as our CSV (header row and all sample columns)."""
    table = simulator.collect([simulator.Maneuver("skidpad", 0.6, 0.2, duration=3.0)], noise=None)
    path = write_table(table, tmp_path_factory.mktemp("csv") / "run.csv")
    return list(csv.reader(io.StringIO(path.read_text())))


BAD_FIELDS = ["nan", "NaN", "inf", "-inf", "", " ", "fast", "1_000", "1e999", "0x10", "1,5", "True",
              "2023_13_45_99_99_99_999", "１２", "\x00", "\"", "None", "[1 2]", "-", "+1e-3"]


@st.composite
def mutated_logs(draw: st.DrawFn, rows: list[list[str]]) -> bytes:
    """A log's rows with one to three mutations, written as CSV, possibly cut or garbled as bytes."""
    rows = [list(r) for r in rows]
    has_header = rows[0][0] == "timestamp"
    first = 1 if has_header else 0
    for _ in range(draw(st.integers(1, 3))):
        operation = draw(st.sampled_from(
            ["field", "field", "drop_column", "truncate_row", "extend_row", "drop_rows", "duplicate_row",
             "blank", "header"]))  # fmt: skip
        width = max(len(r) for r in rows) or 1
        line = draw(st.integers(0, len(rows) - 1))
        column = draw(st.integers(0, width - 1))
        if operation == "field" and column < len(rows[line]):
            rows[line][column] = draw(st.one_of(st.sampled_from(BAD_FIELDS), st.text(max_size=6)))
        elif operation == "drop_column":
            rows = [r[:column] + r[column + 1:] for r in rows]
        elif operation == "truncate_row":
            rows[line] = rows[line][: draw(st.integers(0, len(rows[line])))]
        elif operation == "extend_row":
            rows[line] = rows[line] + draw(st.lists(st.sampled_from(BAD_FIELDS), min_size=1, max_size=3))
        elif operation == "drop_rows":
            keep = draw(st.integers(0, len(rows)))
            rows = rows[:keep] if draw(st.booleans()) else rows[:first] + rows[first + keep:]
        elif operation == "duplicate_row":
            rows.insert(line, list(rows[line]))
        elif operation == "blank":
            rows.insert(line, [] if draw(st.booleans()) else [" ", ""])
        elif operation == "header" and has_header and rows and rows[0]:
            rows[0][column % len(rows[0])] = draw(st.sampled_from(["", "timestamp", "speed", "Speed", "x"]))
        if not rows:
            break
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator=draw(st.sampled_from(["\n", "\r\n"]))).writerows(rows)
    data = buffer.getvalue().encode()
    byte_operation = draw(st.sampled_from(["none", "none", "cut", "insert", "bom"]))
    if byte_operation == "cut" and data:
        data = data[: draw(st.integers(0, len(data) - 1))]
    elif byte_operation == "insert":
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.binary(min_size=1, max_size=4)) + data[at:]
    elif byte_operation == "bom":
        data = b"\xef\xbb\xbf" + data
    return data


def _check_log(data: bytes, capsys: pytest.CaptureFixture[str]) -> None:
    """A log either loads (finite, complete table and training arrays) or fails cleanly, CLI included."""
    cfg = load_config(SMOKE)
    with _scratch() as root:
        path = root / "log.csv"
        path.write_bytes(data)
        try:
            table = read_autodrive_log(path)
            assert tuple(table.columns) == SAMPLE_COLUMNS and len(table) >= 1
            numeric = table.select_dtypes("number").to_numpy(dtype=np.float64)
            assert np.isfinite(numeric).all()
            dataset = load_dataset([path], cfg)
            assert np.isfinite(dataset.x).all() and np.isfinite(dataset.y).all() and len(dataset.x) >= 1
            event("loads")
        except (InputError, DataFormatError) as exc:
            event(type(exc).__name__)
            args = ["tune", str(SMOKE), "--n-trials", "1", "--data", str(path),
                    "--storage", f"sqlite:///{root}/optuna.db", "--out", str(root / "out")]  # fmt: skip
            _cli_rejects(args, root, capsys)


@pytest.mark.slow
@given(data=st.data())
@settings(max_examples=_examples(3), suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_a_mutated_autodrive_log_loads_or_the_cli_exits_2_writing_nothing(real_log, data, capsys):
    _check_log(data.draw(mutated_logs(real_log)), capsys)


@pytest.mark.slow
@given(data=st.data())
@settings(max_examples=_examples(2), suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_a_mutated_csv_with_header_loads_or_the_cli_exits_2_writing_nothing(our_csv, data, capsys):
    _check_log(data.draw(mutated_logs(our_csv)), capsys)


# ------------------------------------------------------------------- regressions: what fuzzing found


@pytest.mark.parametrize(
    ("space", "field"),
    [({"batch_size": math.inf}, "tuning.space.batch_size"),  # int(inf) overflowed: a traceback
     ({"epochs": {"low": 10, "high": math.inf}}, "tuning.space.epochs"),
     ({"lr": {"low": 1e-4, "high": math.inf}}, "tuning.space.lr"),  # accepted, unsampleable
     ({"prior_scale": math.nan}, "tuning.space.prior_scale")],
)
def test_a_non_finite_search_space_value_is_a_config_error(space, field):
    with pytest.raises(ConfigError) as info:
        validate_config({"tuning": {"space": space}})
    assert info.value.field == field and "finite" in str(info.value)


@pytest.mark.parametrize(
    ("config", "field"),
    [({"seed": 2**32}, "seed"),  # passed validation, then overflowed torch.manual_seed in the first fit
     ({"seed": 10**18}, "seed"),
     ({"pool": {"seed": -1}}, "pool.seed"),  # a continuous pool's Sobol set refused it: a traceback
     ({"test": {"noise_seed": -1}}, "test.noise_seed")],  # SeedSequence refused it after simulating
)
def test_seeds_outside_32_bits_are_config_errors(config, field):
    with pytest.raises(ConfigError) as info:
        validate_config(config)
    assert info.value.field == field
    validate_config({"seed": 2**32 - 1, "pool": {"seed": 0}, "test": {"noise_seed": 2**32 - 1}})


def test_a_campaign_with_the_largest_seed_fits_its_rounds():
    """The bound is enough: the largest seed's per-round fit seeds are still valid torch seeds."""
    cfg = validate_config({"seed": 2**32 - 1, "training": {"epochs": 1, "compile": False}})
    campaign = Campaign(cfg, "unused")
    samples = simulator.collect([simulator.Maneuver("skidpad", 0.5, 0.3, duration=3.0)], noise=None)
    samples["pool_index"], samples["batch"] = 0, 0
    assert campaign.fitting.fit(samples, round_index=1000).n_inputs == 2


def test_an_unknown_key_with_control_characters_is_printed_as_one_escaped_line(tmp_path, capsys):
    path = tmp_path / "odd.toml"
    path.write_text('"bad\\nkey\\u001b[2J" = 1\n')
    with contextlib.chdir(tmp_path):
        err = _cli_rejects(["campaign", "run", str(path), "--out", str(tmp_path / "o")], tmp_path, capsys)
    assert "bad\\nkey\\x1b[2J" in err and "\x1b" not in err


def test_a_log_that_is_not_utf8_is_a_data_format_error_naming_its_line(tmp_path, real_log, capsys):
    lines = [",".join(row).encode() for row in real_log[:5]]
    lines[2] = lines[2].replace(b"cam0", b"cam\xff")  # a Latin-1 byte in line 3
    path = tmp_path / "latin1.csv"
    path.write_bytes(b"\n".join(lines) + b"\n")
    with pytest.raises(DataFormatError, match=f"{path}:3: not UTF-8"):
        read_autodrive_log(path)
    bom = tmp_path / "bom.csv"  # a byte-order mark (spreadsheet exports) is not an error
    bom.write_bytes(b"\xef\xbb\xbf" + b"\n".join(ln for i, ln in enumerate(lines) if i != 2) + b"\n")
    assert len(read_autodrive_log(bom)) == 4


def test_tune_with_a_malformed_data_file_creates_no_storage(tmp_path, real_log, capsys):
    path = tmp_path / "short.csv"
    path.write_text("\n".join(",".join(row[:10]) for row in real_log[:3]) + "\n")  # truncated rows
    args = ["tune", str(SMOKE), "--n-trials", "1", "--data", str(path), "--no-tracking",
            "--storage", f"sqlite:///{tmp_path}/optuna.db"]  # fmt: skip
    with contextlib.chdir(tmp_path):
        err = _cli_rejects(args, tmp_path, capsys)  # optuna.db used to be created before the data was read
    assert f"{path}:1" in err


def test_a_continuous_pool_of_any_size_builds_without_warnings():
    cfg = validate_config({"pool": {"throttle_range": [0.2, 0.9], "steering_range": [0.1, 0.5], "size": 12}})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # scipy warned that 12 is not a power of 2
        assert len(Campaign(cfg, "unused").maneuvers) == 24


def test_predict_rejects_a_seed_torch_cannot_take(tmp_path, capsys):
    args = ["predict", "--model", str(tmp_path / "none.pt"), "--maneuver", "skidpad", "--throttle", "0.5",
            "--steering", "0.3", "--seed", str(2**64)]  # fmt: skip
    with contextlib.chdir(tmp_path):
        assert "--seed" in _cli_rejects(args, tmp_path, capsys)
