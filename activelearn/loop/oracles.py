"""Oracles: who answers the maneuvers a campaign proposes, and what the candidates and test set are.

The loop, its checkpoints and its MLflow records are the same whoever answers; only the oracle
differs between rehearsing in simulation and driving the real car:

- `SimulatorOracle`: the nominal MuJoCo model (noise-free logs cached, seeded sensor noise added);
- the same with a `twin` vehicle (MuJoCo with parameter overrides), a stand-in for a real car;
- `LogsOracle`: a folder of recorded logs is the finite pool (pool-based active learning on real data);
- `ExternalOracle`: a person or a script drives the proposals (`campaign propose` / `campaign ingest`).
"""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from activelearn.config import CampaignConfig
from activelearn.config.safety import settle_seconds
from activelearn.data import read_autodrive_log
from activelearn.errors import ActiveLearnError, DataFormatError, InputError
from activelearn.loop.collection import (
    SimulationCache,
    TestSet,
    build_test_set,
    car_cache,
    noisy_logs,
    test_set_from_logs,
)
from activelearn.loop.pool import KIND_ORDER, pool_maneuvers, test_maneuvers
from activelearn.names import CONTROLS, STEERING, THROTTLE
from activelearn.seeds import Stream, derived_rng

_LOG_FOLDER = re.compile(r"^(?P<kind>[a-z]+)_(?P<rate>\d+(?:\.\d+)?)_hz$")


class OracleUnavailable(ActiveLearnError):
    """The oracle cannot answer by itself (external): the campaign waits for `campaign ingest`."""


class Oracle(ABC):
    """Answers proposed maneuvers with their logs; knows the candidate pool and the test set."""

    kind: ClassVar[str]
    automatic: ClassVar[bool] = True  # answers by itself (False: a person drives, `ingest` answers)
    # its answers already hold a live stop's braking (simulated closed-loop); False: a log that passes
    # the trigger is cut there (`activelearn.loop.safety.live_stop.live_stop`)
    drives_stop: ClassVar[bool] = False

    @abstractmethod
    def candidates(self) -> list[Any]:
        """The candidate maneuvers, in a stable order."""

    @abstractmethod
    def answer(self, maneuvers: Sequence[Any], seed: int) -> list[pd.DataFrame]:
        """Logs (sample tables) of `maneuvers` as this oracle's system drives them; `seed` seeds noise."""

    @abstractmethod
    def test_set(self) -> TestSet:
        """The fixed test set: where the model's error is measured."""

    @abstractmethod
    def test_maneuvers(self) -> list[Any]:
        """The test set's maneuvers (their controls define the default target region)."""

    def truth(self, maneuvers: Sequence[Any]) -> list[pd.DataFrame] | None:
        """Noise-free logs of `maneuvers` where the oracle knows them (simulated systems), else None."""
        return None

    def simulations(self) -> list[tuple[SimulationCache, list[Any]]]:
        """What this oracle will simulate, as (cache, maneuvers) pairs: a comparison simulates them
        once, with every core, before its workers start. None for recorded logs."""
        return []

    def params(self) -> dict[str, Any]:
        """What MLflow records about the oracle."""
        return {"kind": self.kind}


class SimulatorOracle(Oracle):
    """The MuJoCo model (nominal, or a twin with overrides): simulated once per maneuver, noised per seed.

    Under an enforced live stop (`[safety] stop = "live"`) the answers are driven with the stop closed
    in MuJoCo (`activelearn.loop.safety.live_stop.stop_rule`): the car brakes near a wall and its log runs on
    until it stands. The test set is simulated without it.
    """

    kind = "simulator"
    drives_stop = True

    def __init__(self, cfg: CampaignConfig, cache: SimulationCache) -> None:
        from activelearn.loop.safety.live_stop import stop_rule

        self.cfg = cfg
        self.cache = cache
        rule = stop_rule(cfg.safety, settle_seconds(cfg.vehicle.spec, cfg.stopping_deceleration()))
        self.driven = cache if rule is None else cache.stopped(rule)  # the cache answers come from
        self._test: TestSet | None = None

    def candidates(self) -> list[Any]:
        return pool_maneuvers(self.cfg.pool)

    def answer(self, maneuvers: Sequence[Any], seed: int) -> list[pd.DataFrame]:
        return noisy_logs(self.driven.get(maneuvers), maneuvers, self.cfg.simulation.noise, seed)

    def truth(self, maneuvers: Sequence[Any]) -> list[pd.DataFrame] | None:
        return self.driven.get(maneuvers)

    def test_maneuvers(self) -> list[Any]:
        if self.cfg.test.logs is not None:
            return _recorded_tests(self.cfg.test.logs)
        return test_maneuvers(self.cfg.test)

    def simulations(self) -> list[tuple[SimulationCache, list[Any]]]:
        tests = [] if self.cfg.test.logs is not None else test_maneuvers(self.cfg.test)
        answers = self._simulated_candidates()
        if self.driven is self.cache:  # no live stop: one batch
            return [(self.cache, tests + answers)]
        return [(self.cache, tests), (self.driven, answers)]  # under the stop: entries of their own

    def _simulated_candidates(self) -> list[Any]:
        return self.candidates()

    def test_set(self) -> TestSet:
        if self._test is None:
            cfg = self.cfg
            if cfg.test.logs is not None:
                self._test = test_set_from_logs(read_logs(cfg.test.logs, "test.logs"), cfg.data)
            else:
                self._test = build_test_set(
                    test_maneuvers(cfg.test), self.cache, cfg.simulation.noise, cfg.data, cfg.test.noise_seed
                )
        return self._test


class TwinOracle(SimulatorOracle):
    """MuJoCo with parameter overrides (friction, mass, motor, steering, latency): a rehearsal car."""

    kind = "twin"

    def params(self) -> dict[str, Any]:
        return {"kind": self.kind, **{f"overrides.{k}": v for k, v in self.cfg.oracle.overrides.items()}}


class ExternalOracle(SimulatorOracle):
    """A person or script drives the proposals; the logs come back through `campaign ingest`.

    Candidates are the configured pool; the test set is `[test] logs` when given (recorded), else
    the simulated grid (then it measures the model against the simulator: say so in reports).
    """

    kind = "external"
    automatic = False
    drives_stop = False  # a person's log ends where the car's own log ends

    def answer(self, maneuvers: Sequence[Any], seed: int) -> list[pd.DataFrame]:
        names = ", ".join(m.name for m in maneuvers)
        raise OracleUnavailable(
            f"oracle.kind = 'external' waits for logs of: {names} (activelearn campaign ingest)"
        )

    def truth(self, maneuvers: Sequence[Any]) -> list[pd.DataFrame] | None:
        return None

    def _simulated_candidates(self) -> list[Any]:
        return []  # a person drives them


@dataclass(frozen=True)
class RecordedManeuver:
    """A maneuver someone already drove: its log is the answer. Quacks like `simulator.Maneuver`."""

    kind: str
    throttle: float
    steering: float
    direction: str
    duration: float
    path: str
    recorded_controls: np.ndarray = field(repr=False, compare=False)

    @property
    def name(self) -> str:
        """The log's path relative to the pool folder: unique, readable."""
        return self.path

    @property
    def sign(self) -> int:
        """Steering sign of the direction: +1 for ccw (left), -1 for cw."""
        return 1 if self.direction == "ccw" else -1

    @property
    def op_steering(self) -> float:
        """Unsigned steering amplitude (0 for a straight)."""
        return 0.0 if self.kind == "straight" else self.steering


def recorded_maneuver(kind: str, table: pd.DataFrame, path: str) -> RecordedManeuver:
    """Describe a recorded log as a candidate: kind, median throttle, steering amplitude, direction."""
    steering = table[STEERING].to_numpy(dtype=np.float64)
    amplitude = (
        float(np.quantile(np.abs(steering), 0.95)) if kind != "fishhook" else float(np.abs(steering).max())
    )
    first_turn = steering[np.abs(steering) > 0.2 * max(amplitude, 1e-9)]
    direction = "cw" if len(first_turn) and first_turn[0] < 0 else "ccw"
    span = float(table["time"].iloc[-1] - table["time"].iloc[0]) if len(table) > 1 else 0.0
    controls = table[list(CONTROLS)].to_numpy(dtype=np.float64)
    return RecordedManeuver(
        kind,
        round(float(np.median(table[THROTTLE])), 4),
        round(amplitude if kind != "straight" else 0.0, 4),
        direction,
        span,
        path,
        controls,
    )


def read_logs(paths: Sequence[str], field: str) -> list[pd.DataFrame]:
    """Read logs from files and folders (every .csv/.parquet inside, recursively), in path order."""
    from activelearn.data import read_table

    frames = []
    for i, text in enumerate(paths):
        path = Path(text)
        files = (
            sorted(p for p in path.rglob("*") if p.suffix.lower() in (".csv", ".parquet"))
            if path.is_dir()
            else [path]
        )
        if not path.exists():
            raise InputError(f"{field}[{i}]", text, "no such file or directory")
        if not files:
            raise InputError(f"{field}[{i}]", text, "the folder holds no .csv or .parquet log")
        for f in files:
            frames.append(read_table(f) if f.suffix.lower() == ".parquet" else read_autodrive_log(f))
    return frames


def _recorded_tests(paths: Sequence[str]) -> list[RecordedManeuver]:
    return [
        recorded_maneuver("unknown", t, f"test[{i}]") for i, t in enumerate(read_logs(paths, "test.logs"))
    ]


def scan_log_folder(root: Path) -> list[tuple[str, Path]]:
    """(kind, file) of the logs in an AutoDRIVE folder: `<maneuver>_<rate>_hz/<variation> Log.csv`."""
    if not root.is_dir():
        raise InputError("oracle.path", str(root), "no such folder")
    found: list[tuple[str, Path]] = []
    for folder in sorted(p for p in root.iterdir() if p.is_dir()):
        match = _LOG_FOLDER.match(folder.name.lower())
        if match is None or match["kind"] not in KIND_ORDER:
            raise InputError(
                "oracle.path",
                str(folder),
                f"expected folders named <maneuver>_<rate>_hz with maneuver in {', '.join(KIND_ORDER)}",
            )
        found.extend((match["kind"], f) for f in sorted(folder.glob("*.csv")))
    if not found:
        raise InputError("oracle.path", str(root), "holds no <maneuver>_<rate>_hz/*.csv log")
    return found


class LogsOracle(Oracle):
    """Recorded logs as a finite pool: every log is a candidate, its file the answer.

    The test set is `[test] logs` when given; otherwise a seeded share (`oracle.test_fraction`) of the
    recorded maneuvers is held out, the same for every campaign seed and strategy of the config.
    """

    kind = "logs"

    def __init__(self, cfg: CampaignConfig) -> None:
        self.cfg = cfg
        self.root = Path(cfg.oracle.path or "")
        entries = scan_log_folder(self.root)
        tables: list[pd.DataFrame] = []
        maneuvers: list[RecordedManeuver] = []
        for kind, path in entries:
            try:
                table = read_autodrive_log(path)
            except DataFormatError as exc:
                raise InputError("oracle.path", str(path), f"unreadable log: {exc}") from None
            tables.append(table.assign(maneuver=kind))
            maneuvers.append(recorded_maneuver(kind, table, str(path.relative_to(self.root))))
        order = np.arange(len(maneuvers))
        if cfg.test.logs is None:
            held = derived_rng(cfg.pool.seed, Stream.TEST_SPLIT).permutation(len(maneuvers))
            n_test = max(1, round(cfg.oracle.test_fraction * len(maneuvers)))
            if len(maneuvers) - n_test < cfg.design.initial + 1:
                raise InputError(
                    "oracle.path",
                    str(self.root),
                    f"{len(maneuvers)} logs leave too few candidates after the test share",
                )
            test_rows = np.sort(held[:n_test])
            order = np.setdiff1d(order, test_rows)
            self._test_tables = [tables[i] for i in test_rows]
        else:
            self._test_tables = read_logs(cfg.test.logs, "test.logs")
        self._maneuvers = [maneuvers[i] for i in order]
        self._tables = {maneuvers[i].name: tables[i] for i in order}
        self._test: TestSet | None = None

    def candidates(self) -> list[Any]:
        return list(self._maneuvers)

    def answer(self, maneuvers: Sequence[Any], seed: int) -> list[pd.DataFrame]:
        return [self._tables[m.name].copy() for m in maneuvers]  # recorded: the noise is in the log

    def test_set(self) -> TestSet:
        if self._test is None:
            self._test = test_set_from_logs(self._test_tables, self.cfg.data)
        return self._test

    def test_maneuvers(self) -> list[Any]:
        return [recorded_maneuver("unknown", t, f"test[{i}]") for i, t in enumerate(self._test_tables)]

    def params(self) -> dict[str, Any]:
        return {"kind": self.kind, "path": str(self.root), "recorded": len(self._tables)}


def make_oracle(cfg: CampaignConfig, cache_root: Path) -> Oracle:
    """The oracle of a config; simulated ones share a cache of noise-free logs under `cache_root`."""
    kind = cfg.oracle.kind
    if kind == "logs":
        return LogsOracle(cfg)
    if kind == "twin":
        from activelearn.loop.collection import twin_cache

        return TwinOracle(cfg, twin_cache(cache_root, cfg))
    cache = car_cache(cache_root, cfg)
    return ExternalOracle(cfg, cache) if kind == "external" else SimulatorOracle(cfg, cache)
