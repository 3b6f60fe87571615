"""Sample tables: schema, atomic CSV/Parquet IO and import of AutoDRIVE Nigel logs.

A sample table has one row per log sample: the AutoDRIVE columns in their order (AUTODRIVE_COLUMNS),
then `time` (s since the run started), `maneuver`, `direction`, `op_throttle`, `op_steering`,
`run_id` and `diverged` (SAMPLE_COLUMNS). The simulator writes the same layout.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pandas as pd

from activelearn.errors import DataFormatError, InputError
from activelearn.names import CONTROLS, RATES, RECORDED_COLUMNS, STEERING, THROTTLE
from simulator.collect import AUTODRIVE_COLUMNS, EXTRA_COLUMNS

# The AutoDRIVE layout is the simulator's own log layout: one definition, in `simulator`.
# The raw AutoDRIVE CSV ends with three perception columns this project does not use.
AUTODRIVE_UNUSED_COLUMNS = ("cam0", "cam1", "lidar")
SAMPLE_COLUMNS = AUTODRIVE_COLUMNS + EXTRA_COLUMNS

FEATURES = CONTROLS  # model inputs of the reference study
LABELS = RATES  # model outputs of the reference study

INT_COLUMNS = ("leftTicks", "rightTicks")
TEXT_COLUMNS = ("maneuver", "direction", "run_id")
BOOL_COLUMNS = ("diverged",)
FLOAT_COLUMNS = tuple(
    c for c in SAMPLE_COLUMNS if c not in INT_COLUMNS + TEXT_COLUMNS + BOOL_COLUMNS
)

TABLE_SUFFIXES = (".csv", ".parquet")
_AUTODRIVE_TIME_FORMAT = "%Y_%m_%d_%H_%M_%S_%f"  # e.g. 2023_04_12_15_30_07_123
_AUTODRIVE_TIME = re.compile(r"\d{4}_\d{2}_\d{2}_\d{2}_\d{2}_\d{2}_\d{1,6}")


def _suffix(path: Path, field: str) -> str:
    suffix = path.suffix.lower()
    if suffix not in TABLE_SUFFIXES:
        raise InputError(field, str(path), "must end in .csv or .parquet")
    return suffix


def write_atomically(path: str | Path, write: Callable[[Path], object]) -> Path:
    """Have `write` fill a hidden temporary file beside `path`, then rename it to `path` in one step, so
    a reader never finds half a file. The temporary name is unique to the call (two writers of one
    path, in two processes or two threads, never share it), keeps `path`'s suffix for writers that
    infer the format from the name (matplotlib), and is left to `write` to create, so the file gets
    the umask's permissions as `path` would. Nothing is left behind if `write` fails."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{uuid.uuid4().hex[:12]}.tmp{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write bytes to `path` atomically (`write_atomically`)."""
    return write_atomically(path, lambda tmp: tmp.write_bytes(data))


def write_table(df: pd.DataFrame, path: str | Path) -> Path:
    """Write a sample table to .csv (with header) or .parquet atomically (`write_atomically`)."""
    path = Path(path)
    suffix = _suffix(path, "path")
    extra = [c for c in df.columns if c not in SAMPLE_COLUMNS]
    df = df[[c for c in SAMPLE_COLUMNS if c in df.columns] + extra]
    if suffix == ".csv":
        return write_atomically(path, lambda tmp: df.to_csv(tmp, index=False))
    return write_atomically(path, lambda tmp: df.to_parquet(tmp, index=False))


def read_table(path: str | Path) -> pd.DataFrame:
    """Read a sample table written by write_table (.csv or .parquet)."""
    path = Path(path)
    suffix = _suffix(path, "path")
    if not path.is_file():
        raise InputError("path", str(path), "no such file")
    if suffix == ".parquet":
        # One open, then parse: pyarrow opens the path more than once (size, then pages), so a table
        # replaced by a writer's atomic rename in between read as a torn file (seen in test_ray).
        return pd.read_parquet(io.BytesIO(path.read_bytes()))
    dtypes: dict[str, object] = {c: "float64" for c in FLOAT_COLUMNS}
    dtypes.update({c: "int64" for c in INT_COLUMNS})
    dtypes.update({c: "str" for c in TEXT_COLUMNS})
    dtypes.update({c: "bool" for c in BOOL_COLUMNS})
    with open(path, newline="") as handle:
        header = next(csv.reader(handle), [])
    return pd.read_csv(path, dtype={c: t for c, t in dtypes.items() if c in header})


def _parse_timestamp(text: str) -> float:
    """Seconds: AutoDRIVE's yyyy_MM_dd_HH_mm_ss_fff wall clock (as UTC), or a plain number."""
    text = text.strip()
    if _AUTODRIVE_TIME.fullmatch(text):
        return datetime.strptime(text, _AUTODRIVE_TIME_FORMAT).replace(tzinfo=UTC).timestamp()
    return _parse_number(text)


def _parse_number(text: str) -> float:
    if "_" in text:  # float() would read "1_000" as 1000
        raise ValueError("not a number")
    value = float(text)
    if not math.isfinite(value):
        raise ValueError("not finite")
    return value


def read_autodrive_log(path: str | Path) -> pd.DataFrame:
    """Read an AutoDRIVE Nigel log (headerless, 21 columns) or one of our CSVs into a sample table.

    The headerless format is `timestamp, throttle, ..., accZ, cam0, cam1, lidar`; the last three are
    dropped (a lidar array spread over several unquoted fields is tolerated: only the first 18
    fields are read). Missing table columns are filled: `time` = timestamp - first timestamp,
    `maneuver` and `direction` "unknown", `op_throttle` the median throttle, `op_steering` the
    largest |steering|, `run_id` "<parent dir>/<file stem>" (AutoDRIVE names every log "V1 Log"),
    `diverged` False. A malformed row raises DataFormatError naming the file and its 1-based line.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("path", str(path), "no such file")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")  # UTF-8, whatever the locale; a leading byte-order mark is dropped
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise DataFormatError(f"{path}:{line}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    rows = list(csv.reader(io.StringIO(text, newline="")))
    if not rows or not any(field.strip() for field in rows[0]):
        raise DataFormatError(f"{path}:1: empty file, expected an AutoDRIVE log")
    has_header = rows[0][0].strip() == "timestamp"
    if has_header:
        header = [h.strip() for h in rows[0]]
        missing = [c for c in AUTODRIVE_COLUMNS if c not in header]
        if missing:
            raise DataFormatError(f"{path}:1: header lacks column(s) {', '.join(missing)}")
        index = {c: header.index(c) for c in header}
        body, first_line, width = rows[1:], 2, len(header)
    else:
        index = {c: i for i, c in enumerate(AUTODRIVE_COLUMNS)}
        body, first_line, width = rows, 1, len(AUTODRIVE_COLUMNS) + len(AUTODRIVE_UNUSED_COLUMNS)

    columns: dict[str, list] = {c: [] for c in index}
    for line_no, row in enumerate(body, start=first_line):
        if not row or not any(field.strip() for field in row):
            continue  # blank lines (e.g. a trailing newline) carry no sample
        if (has_header and len(row) != width) or (not has_header and len(row) < width):
            raise DataFormatError(
                f"{path}:{line_no}: expected {width} fields{'' if has_header else ' or more'}, got {len(row)}"
            )
        for column, i in index.items():
            text = row[i]
            try:
                if column == "timestamp":
                    value: object = _parse_timestamp(text)
                elif column in INT_COLUMNS:
                    number = _parse_number(text)
                    if number != int(number):
                        raise ValueError("not a whole count")
                    value = int(number)
                elif column in AUTODRIVE_COLUMNS or column in ("time", "op_throttle", "op_steering"):
                    value = _parse_number(text)
                elif column == "diverged":
                    if text.strip() not in ("True", "False", "true", "false", "1", "0"):
                        raise ValueError("not a boolean")
                    value = text.strip() in ("True", "true", "1")
                else:
                    value = text
            except ValueError as exc:
                message = f"{path}:{line_no}: column {column}: bad value {text!r} ({exc})"
                raise DataFormatError(message) from exc
            columns[column].append(value)
    if not columns["timestamp"]:
        raise DataFormatError(f"{path}:{first_line}: no data rows")

    table = pd.DataFrame({c: columns[c] for c in index if c in SAMPLE_COLUMNS})
    n = len(table)
    if "time" not in table:
        table["time"] = table["timestamp"] - table["timestamp"].iloc[0]
    if "maneuver" not in table:
        table["maneuver"] = "unknown"
    if "direction" not in table:
        table["direction"] = "unknown"
    if "op_throttle" not in table:
        table["op_throttle"] = float(np.median(table[THROTTLE]))
    if "op_steering" not in table:
        table["op_steering"] = float(np.max(np.abs(table[STEERING])))
    if "run_id" not in table:
        table["run_id"] = f"{path.parent.name}/{path.stem}" if path.parent.name else path.stem
    if "diverged" not in table:
        table["diverged"] = np.zeros(n, dtype=bool)
    for c in INT_COLUMNS:
        table[c] = table[c].astype("int64")
    for c in FLOAT_COLUMNS:
        table[c] = table[c].astype("float64")
    for c in TEXT_COLUMNS:
        table[c] = table[c].astype("str")
    table["diverged"] = table["diverged"].astype(bool)
    return table[list(SAMPLE_COLUMNS)]


def write_autodrive_log(table: pd.DataFrame, path: str | Path, start: datetime | None = None) -> Path:
    """Write a sample table as an AutoDRIVE Nigel log: headerless CSV, 21 fields, atomically.

    Timestamps are wall-clock strings (yyyy_MM_dd_HH_mm_ss_fff) from `start` (default 2026-01-01 UTC)
    plus `time`; the perception columns (cam0, cam1, lidar) stay empty. `read_autodrive_log` reads it.
    """
    start = start or datetime(2026, 1, 1, tzinfo=UTC)
    stamps = [
        (start + pd.Timedelta(seconds=float(t))).strftime(_AUTODRIVE_TIME_FORMAT)[:-3] for t in table["time"]
    ]
    out = table[list(AUTODRIVE_COLUMNS)].copy()
    out["timestamp"] = stamps
    for column in AUTODRIVE_UNUSED_COLUMNS:
        out[column] = ""
    return atomic_write_bytes(path, out.to_csv(index=False, header=False, float_format="%.9g").encode())


def read_recorded_log(path: str | Path) -> pd.DataFrame:
    """One recorded log (AutoDRIVE CSV, our CSV or Parquet) with finite time, commands and rates.

    A missing file is an InputError, a damaged one a DataFormatError naming it.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("LOG", str(path), "no such file")
    if path.suffix.lower() == ".parquet":
        try:
            table = read_table(path)
        except Exception as exc:  # pyarrow raises several types for a damaged file
            raise DataFormatError(f"{path}: unreadable Parquet log ({exc})") from None
    else:
        table = read_autodrive_log(path)
    missing = [c for c in RECORDED_COLUMNS if c not in table]
    if missing:
        raise DataFormatError(f"{path}: lacks the column(s) {', '.join(missing)}")
    if not np.isfinite(table[list(RECORDED_COLUMNS)].to_numpy(dtype=np.float64)).all():
        raise DataFormatError(f"{path}: has missing or non-finite values")
    return table


def log_rate_hz(tables: list[pd.DataFrame]) -> float:
    """The logs' rate (Hz) read off their `time` columns: one over the median step (to 1e-6 Hz)."""
    steps = np.concatenate([np.diff(np.asarray(t["time"], dtype=np.float64)) for t in tables])
    steps = steps[np.isfinite(steps) & (steps > 0)]
    if steps.size == 0:
        raise InputError("logs", "time", "no two rows a positive time apart: the log rate is unknown")
    return round(1.0 / float(np.median(steps)), 6)
