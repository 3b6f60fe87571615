"""The active-learning outer loop: fit, evaluate, propose, collect, checkpoint, repeat.

One campaign = one config, one strategy, one seed. Every strategy shares the initial design, the
budget, the candidate pool, the test set and the training recipe; only `Strategy.select` differs.

The loop is ask/tell. `propose()` fits the model on everything collected so far (round r, seeded by
(seed, r)), evaluates it on the fixed test set, logs the metrics at step = number of training rows and
proposes the next batch; `tell(logs)` takes the logs of that batch. `run()` is that loop with an
automatic oracle answering (the simulator, a twin of it, or a folder of recorded logs); with the
external oracle a person drives the proposals and `activelearn campaign ingest` tells.

After every step the directory holds a consistent checkpoint (samples.parquet, model.pt, state.json,
the latter written last as the commit point), so a campaign killed at any moment resumes from its
last step and ends with the same data and metrics as an uninterrupted run.

A warm start (`[design] prior`) adds rows that train every round without counting against the budget
(or, for sim-to-real, a prior model to fine-tune or to learn a residual on); learning curves then start
at the prior: round 0 is the prior alone when `design.initial` is 0.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import pandas as pd
import torch

from activelearn.config import CampaignConfig, validate_config
from activelearn.data import atomic_write_bytes, read_table, write_table
from activelearn.errors import ActiveLearnError, InputError
from activelearn.loop import lock
from activelearn.loop.acquisition import Pool, Strategy, greedy_maximin, make_strategy
from activelearn.loop.admission import Admission, Admitted
from activelearn.loop.budget import Budget, total_rounds
from activelearn.loop.collection import TestSet, cache_root, car_cache, truth_rows
from activelearn.loop.evaluation import Evaluation, applied_fan_scale, applied_scale
from activelearn.loop.fitting import Fitting
from activelearn.loop.history import CandidateTruth, History, Withheld
from activelearn.loop.oracles import Oracle, make_oracle
from activelearn.loop.pool import build_pool, maneuver_costs, path_points, target_points
from activelearn.loop.prior import PRIOR_FILE, Prior, load_prior, prior_from_rows
from activelearn.loop.proposals import proposal_path, write_proposals
from activelearn.loop.round_figure import draw_round
from activelearn.loop.run_log import CampaignInterrupted, Progress, RunLog
from activelearn.loop.safety.kinematic_bound import Car, turn_speed
from activelearn.loop.safety.limits import violations
from activelearn.loop.safety.live_stop import live_stop
from activelearn.loop.safety.risk import Assessment, assess
from activelearn.loop.state import (
    CONFIG_FILE,
    MODEL_FILE,
    PRIOR_MODEL_FILE,
    SAMPLES_FILE,
    STAGED_DIR,
    STATE_FILE,
    CampaignState,
)
from activelearn.names import (
    EPISTEMIC_SCALE,
    FAN_SCALE,
    N_MANEUVERS,
    POOL_EPISTEMIC_STD_MAX,
    ROLLOUT_METRICS,
    ROUND,
    TEST_RMSE,
    WALL_SECONDS,
)
from activelearn.numerics.models import load_model, save_model
from activelearn.numerics.surrogate import model_inputs
from activelearn.seeds import Stream, derived_rng, derived_seed

__all__ = [
    "MODEL_FILE",
    "SAMPLES_FILE",
    "STATE_FILE",
    "Campaign",
    "CampaignInterrupted",
    "CampaignResult",
    "CampaignState",
    "config_hash",
    "default_directory",
    "load_campaign_model",
    "total_rounds",
]


def config_hash(cfg: CampaignConfig) -> str:
    """Hash of everything that determines a campaign's data except strategy and seed.

    [safety] is left out: at the track the arena or delta may change between rounds (`--resume`).
    """
    exclude = {"strategy", "seed", "tracking", "output_dir", "name", "safety"}
    payload = cfg.model_dump(mode="json", exclude=exclude)
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class CampaignResult:
    """Outcome of one campaign: its directory, state and the metrics of every round."""

    directory: Path
    state: CampaignState

    @property
    def history(self) -> pd.DataFrame:
        """One row per round with every logged metric."""
        return pd.DataFrame(self.state.rounds)


class Campaign:
    """One strategy, one seed, one config: the loop and its checkpoints.

    The jobs of a round live in rooms of their own, reachable from the campaign: `fitting` (training
    data, the prior's model, the fit modes, the warm store), `evaluation` (test set, free runs,
    prequential checks), `budget`, `admission` ([safety]) and `run_log` (MLflow); proposal files are
    `activelearn.loop.proposals`. The campaign keeps the round itself and its checkpoints.
    """

    def __init__(
        self,
        cfg: CampaignConfig,
        directory: str | Path,
        *,
        cache_dir: str | Path | None = None,
        tracker: Any | None = None,
        parent_run_id: str | None = None,
        progress: Progress | None = None,
    ) -> None:
        self.cfg = cfg
        self.directory = Path(directory)
        self.strategy: Strategy = make_strategy(cfg.strategy, cfg.acquisition)
        cache = Path(cache_dir) if cache_dir else cache_root(cfg)
        self.nominal = car_cache(cache, cfg)  # prior grids: the car's nominal simulator
        self.oracle: Oracle = make_oracle(cfg, cache)
        self.progress: Progress = progress or (lambda event: None)
        self.run_log = RunLog(cfg, self.directory, tracker=tracker, parent_run_id=parent_run_id,
                              progress=lambda event: self.progress(event))  # fmt: skip
        self.lock_wait = lock.DEFAULT_WAIT  # s a second writer of the directory waits for the first
        self.maneuvers = self.oracle.candidates()
        if cfg.safety is not None and self.oracle.kind == "logs":
            raise InputError("safety", "[safety]", "judges maneuvers to drive, not oracle.kind = 'logs'")
        if len(self.maneuvers) < cfg.design.initial + 1:
            raise InputError(
                "pool", len(self.maneuvers), "the pool must hold more maneuvers than design.initial"
            )
        self.costs = maneuver_costs(cfg, self.maneuvers)
        self.fitting = Fitting(cfg, self.directory)
        self.evaluation = Evaluation(cfg, self.oracle, self.maneuvers, self.fitting.rows)
        self.budget = Budget(cfg, self.costs, self.maneuvers)
        self.admission = Admission(cfg, self.maneuvers)
        self._model: Any | None = None  # the model of the last fitted round, while in memory
        self._target: tuple[np.ndarray, np.ndarray] | None = None
        self._clock = (0.0, time.perf_counter())
        self._truth: CandidateTruth | None = None

    # Set after construction by commands and scripts; the rooms that use them read them here.
    @property
    def prior(self) -> Prior | None:
        """The warm start's data (None without one), loaded when the directory is opened."""
        return self.fitting.prior

    @prior.setter
    def prior(self, prior: Prior | None) -> None:
        self.fitting.prior = prior

    @property
    def tracker(self) -> Any | None:
        """The MLflow tracker the run is logged to (None: nothing is logged)."""
        return self.run_log.tracker

    @tracker.setter
    def tracker(self, tracker: Any | None) -> None:
        self.run_log.tracker = tracker

    # ------------------------------------------------------------------ data

    @property
    def test_set(self) -> TestSet:
        """The fixed test set (simulated once per config and cached, or recorded logs)."""
        return self.oracle.test_set()

    def label(self, frames: Sequence[pd.DataFrame], indices: Sequence[int], batch: int) -> pd.DataFrame:
        """Tag logs with the pool index they answer and the batch they belong to."""
        tagged = []
        for frame, index in zip(frames, indices, strict=True):
            frame = frame.copy()
            frame["pool_index"] = index
            frame["batch"] = batch
            tagged.append(frame)
        return pd.concat(tagged, ignore_index=True)

    def collect(self, indices: list[int], batch: int, state: CampaignState) -> pd.DataFrame:
        """Ask the oracle for the chosen maneuvers (simulated, noised with this campaign's seed), as driven
        under `state`'s [safety] cuts."""
        chosen = [self.driven(i, state) for i in indices]
        return self.label(self._stopped(self.oracle.answer(chosen, self.cfg.seed)), indices, batch)

    def _stopped(self, logs: list[pd.DataFrame]) -> list[pd.DataFrame]:
        """The oracle's logs as a live stop at the walls leaves them ([safety] stop = "live"): simulated
        oracles drive the stop closed-loop themselves; recorded logs are cut at the trigger."""
        safety = self.cfg.safety
        if safety is None or safety.stop != "live" or not safety.enforce or self.oracle.drives_stop:
            return logs
        return [live_stop(log, safety) for log in logs]

    def _answer(self, state: CampaignState) -> pd.DataFrame:
        """The pending batch's logs: those `ingest` took in already (staged), the oracle answers the rest."""
        assert state.pending is not None
        asked = [i for i in state.pending if str(i) not in state.staged]
        answered = self.oracle.answer([self.driven(i, state) for i in asked], self.cfg.seed) if asked else []
        answered = self._stopped(answered)
        answers = dict(zip(asked, answered, strict=True))
        frames = [
            answers[i] if i in answers else read_table(self.directory / STAGED_DIR / f"{i}.parquet")
            for i in state.pending
        ]
        return self.label(frames, state.pending, len(state.batches))

    def driven(self, index: int, state: CampaignState) -> Any:
        """Candidate `index` as it is driven: cut short where `state` records a [safety] cut."""
        cut = state.cuts.get(str(index))
        maneuver = self.maneuvers[index]
        return maneuver if cut is None else dataclasses.replace(maneuver, duration=cut)

    def target(self) -> tuple[np.ndarray, np.ndarray]:
        """Controls (and weights) of the target region (`[target]`, default: the test maneuvers')."""
        if self._target is None:
            self._target = target_points(self.cfg, self.maneuvers, self.oracle.test_maneuvers())
        return self._target

    def pool(
        self, taken: list[int], model: Any | None = None, affordable: np.ndarray | None = None,
        maneuvers: Sequence[Any] | None = None,
    ) -> Pool:  # fmt: skip
        """The candidate pool with `taken` marked as collected, its points as `model` inputs.

        `maneuvers`: the candidates as they would be driven (default: the pool's, whole).
        """
        maneuvers = self.maneuvers if maneuvers is None else maneuvers
        mask = np.zeros(len(maneuvers), dtype=bool)
        mask[taken] = True
        pool = build_pool(
            self.cfg,
            maneuvers,
            mask,
            self.test_set.scale,
            self.target(),
            self.cfg.seed,
            affordable=affordable,
            # what is known of this system counts as taken; a prior that only shapes a model (another
            # system's data: fine-tune, residual) does not
            prior=self.prior.runs if self.prior is not None and self.prior.trains else (),
        )
        if model is None or model.n_inputs == pool.points.shape[1]:
            return pool
        if self._scores_paths:
            fields = path_points(self.cfg, model, maneuvers, self.oracle.test_maneuvers(), self.target()[0])
            return dataclasses.replace(pool, **fields)
        return dataclasses.replace(
            pool, points=model_inputs(model, pool.points), target=model_inputs(model, pool.target)
        )

    def _scoring_model(self, model: Any | None) -> Any | None:
        """The model whose inputs the pool's points are (None: the candidates' own geometry). A strategy
        that never reads them (`Strategy.uses_model` false: uniform, random) is spared the model's
        free runs of every candidate, unless a stop rule reads them."""
        needed = self.strategy.uses_model or self.cfg.design.stop_epistemic_std is not None
        return model if needed else None

    @property
    def _scores_paths(self) -> bool:
        """Whether candidates are scored along the dynamic model's own free runs of them."""
        return self.cfg.data.inputs != "controls" and self.cfg.acquisition.dynamic_points == "path"

    def _candidate_truth(self) -> CandidateTruth:
        """Noise-free training rows of every candidate (`History.truth`: benchmark-only strategies)."""
        if self._truth is None:
            clean = self.oracle.truth(self.maneuvers)
            if clean is None:
                raise InputError(
                    "strategy", self.cfg.strategy, f"needs a simulated oracle, not {self.oracle.kind!r}"
                )
            self._truth = truth_rows(clean, self.cfg.data)
        return self._truth

    # ------------------------------------------------------------------ strategies and [safety]

    def strategy_history(
        self, state: CampaignState, withheld: Withheld | None = None,
        trial: Callable[[list[int]], float] | None = None,
    ) -> History:  # fmt: skip
        """What every strategy may read before this round's pick: the rounds so far, the kind of budget,
        the warm start, whether a dynamic model scores candidates along its free runs, what [safety]
        withholds, the candidates' truth (simulated oracles) and `trial`."""
        return History(
            rounds=tuple(MappingProxyType(dict(r)) for r in state.rounds),
            budget="seconds" if self.cfg.design.max_sim_seconds is not None else "maneuvers",
            prior=self.cfg.design.prior is not None,
            scores_paths=self._scores_paths,
            withheld=withheld,
            truth=self._candidate_truth,
            trial=trial,
        )

    def _trial(
        self, state: CampaignState, samples: pd.DataFrame, batch: list[int], round_index: int, model: Any
    ) -> float:
        """The config's test metric (`[test] metric`: a one-step error, or the free runs' the comparison
        ranks by) of the next round's model if `batch` were collected (`History.trial`)."""
        new = self.collect(batch, len(state.batches), state)
        more = pd.concat([samples, new], ignore_index=True)
        trial = self.fitting.fit(more, round_index + 1, previous=model)
        metric = self.cfg.test.metric
        return self.evaluation.evaluate(trial, rollouts=metric in ROLLOUT_METRICS)[metric]

    def assess(
        self, model: Any | None, round_index: int, open_: np.ndarray, samples: pd.DataFrame | None
    ) -> Assessment:
        """[safety]'s assessment of the open candidates (a benchmark's clairvoyant safe set overrides it)."""
        safety = self.cfg.safety
        assert safety is not None
        rate, car = self.cfg.simulation.rate_hz, Car.of(self.cfg.vehicle.spec)
        turn = None
        if safety.measured_turn_speed:
            turn = turn_speed(self.fitting.known_logs(samples), rate, safety.limit_window, car)
        seed = derived_seed(self.cfg.seed, Stream.ROUND, round_index)  # the fan of the round's model
        return assess(model, self.maneuvers, safety, rate_hz=rate, seed=seed, which=open_, turn=turn, car=car)

    def admit(
        self, state: CampaignState, pool: Pool, model: Any | None, round_index: int,
        samples: pd.DataFrame | None = None,
    ) -> tuple[Pool, Admitted | None]:  # fmt: skip
        """The pool cut down to what [safety] admits, and the admission (None: no [safety])."""
        if self.cfg.safety is None:
            return pool, None
        safe = self.assess(model, round_index, ~pool.taken, samples)
        admitted = self.admission.admit(pool, safe, self.budget.track_seconds(state))
        pool = admitted.pool
        if admitted.driven is not None:  # the points of the candidates as they would be driven
            taken = list(np.flatnonzero(pool.taken))
            rebuilt = self.pool(taken, self._scoring_model(model), maneuvers=admitted.driven)
            fields = {name: getattr(rebuilt, name) for name in ("points", "owner", "weights")}
            pool = dataclasses.replace(pool, **fields)
        return pool, admitted

    def _set_pending(self, state: CampaignState, picks: list[int], admitted: Admitted | None) -> None:
        """Propose `picks`; with [safety], record their risks and the shorter durations of those cut."""
        state.pending = picks
        if admitted is None:
            return
        risks, cuts = admitted.verdicts(picks, self.cfg.safety.enforce)  # type: ignore[union-attr]
        state.risks.update(risks)
        state.cuts.update(cuts)

    # ------------------------------------------------------------------ checkpoints

    def _stored_config_hash(self) -> str | None:
        """The hash of the checkpoint's own config as this version reads it, None where it cannot.

        A field added since the checkpoint (with a default that keeps the old behaviour) changes the
        hash of the whole config but not this one, so such a campaign still resumes after an upgrade.
        """
        try:
            stored = json.loads((self.directory / CONFIG_FILE).read_text())
            return config_hash(validate_config(stored))
        except (OSError, ValueError, ActiveLearnError):
            return None

    def _load(self, resume: bool) -> tuple[CampaignState, pd.DataFrame]:
        expected = config_hash(self.cfg)
        if (self.directory / STATE_FILE).exists():
            if not resume:
                raise InputError(
                    "--out",
                    str(self.directory),
                    "holds a campaign already; pass --resume or choose another --out",
                )
            state = CampaignState.load(self.directory)
            same_config = state.config_hash == expected or self._stored_config_hash() == expected
            if not same_config or (state.strategy, state.seed) != (self.cfg.strategy, self.cfg.seed):
                raise InputError(
                    "--resume",
                    str(self.directory),
                    "the checkpoint was made with another config, strategy or seed",
                )
            if state.prior_digest is not None:
                self.prior = prior_from_rows(
                    read_table(self.directory / PRIOR_FILE), self.cfg.design.prior.use
                )  # type: ignore[union-attr]
            samples = (
                read_table(self.directory / SAMPLES_FILE)
                if (self.directory / SAMPLES_FILE).exists()
                else pd.DataFrame()
            )
            if not samples.empty:
                # Rows of a batch whose state never committed are dropped; the step is redone identically.
                samples = samples[samples["batch"] < len(state.batches)].reset_index(drop=True)
            return state, samples
        # A new campaign: everything is checked before the directory is created.
        self.prior = load_prior(self.cfg, self.nominal)
        prior_model = self.fitting.prior_model()
        state = CampaignState(expected, self.cfg.strategy, self.cfg.seed)
        self.directory.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(self.directory / CONFIG_FILE, self.cfg.model_dump_json(indent=1).encode())
        if self.prior is not None:
            write_table(self.prior.rows, self.directory / PRIOR_FILE)
            state.prior_digest = self.prior.digest
        if prior_model is not None:
            save_model(prior_model, self.directory / PRIOR_MODEL_FILE)
        return state, pd.DataFrame()

    def _checkpoint(self, state: CampaignState, samples: pd.DataFrame | None, model: Any | None) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        if samples is not None and not samples.empty:
            write_table(samples, self.directory / SAMPLES_FILE)
        if model is not None:
            save_model(model, self.directory / MODEL_FILE)
        state.save(self.directory)  # last: the commit point

    def _params(self) -> dict[str, Any]:
        """What the MLflow run logs as params: the whole config, the oracle's and the prior's identity."""
        params: dict[str, Any] = self.cfg.model_dump(mode="json")
        params["oracle_info"] = self.oracle.params()
        if self.prior is not None:
            params["prior_info"] = {"maneuvers": len(self.prior.runs), "rows": len(self.prior.rows),
                                    "digest": self.prior.digest}  # fmt: skip
        return params

    def _finish(self, state: CampaignState, log_model: bool) -> None:
        self.run_log.finish(state, log_model, lambda: self._model or load_model(self.directory / MODEL_FILE))

    # ------------------------------------------------------------------ the round

    def _propose(self, state: CampaignState, samples: pd.DataFrame, figures: bool) -> None:
        """Fit and evaluate the round's model (or take the initial design), then propose the next batch."""
        if not state.batches and self.cfg.design.initial > 0:
            prior_model = self.fitting.prior_model()
            pool, admitted = self.admit(state, self.pool([]), prior_model, 0, samples)
            k = min(self.cfg.design.initial, len(pool.available))  # [safety] may admit fewer
            if k == 0:
                state.finished, state.stop_reason = True, "nothing_admissible"
                self._checkpoint(state, None, None)
                return
            initial = greedy_maximin(pool, k, derived_rng(self.cfg.seed, Stream.INITIAL),
                                     start=self.cfg.design.initial_start)
            self._set_pending(state, initial, admitted)
            self._checkpoint(state, None, None)
            return
        round_index = len(state.rounds)
        self.progress({"event": "fit", ROUND: round_index, N_MANEUVERS: len(state.taken)})
        scale = applied_scale(state) if self.cfg.design.recalibrate == "prequential" else 1.0
        previous = self.fitting.previous_model(round_index)
        model = self.fitting.fit(samples, round_index, scale, previous=previous)
        fans: dict[str, float] = {}
        if self.cfg.design.fan_calibration == "prequential":
            fans[FAN_SCALE] = applied_fan_scale(state)
            with torch.no_grad():
                model.fan_scale.fill_(fans[FAN_SCALE])
        x, _, _ = self.fitting.training_data(samples)
        metrics: dict[str, Any] = {ROUND: round_index, EPISTEMIC_SCALE: scale, **fans}
        metrics.update(model.round_metrics())  # what only some kinds record (a correction's kept share)
        metrics.update(self.evaluation.evaluate(model))
        metrics.update(
            n_samples=len(x),
            n_maneuvers=len(state.taken),
            sim_seconds=self.budget.sim_seconds(state),
            track_seconds=self.budget.track_seconds(state),
        )
        metrics[WALL_SECONDS] = state.wall_seconds = self._wall()
        k, reason = self.budget.next_batch_size(state)
        pool = self.pool(state.taken, self._scoring_model(model), self.budget.affordable(state))
        admitted: Admitted | None = None
        if reason is None:
            started = time.perf_counter()
            pool, admitted = self.admit(state, pool, model, round_index, samples)
            if admitted is not None:
                metrics.update(self.admission.metrics(state, admitted.safe, time.perf_counter() - started))
                k = min(k, len(pool.available))
                reason = "nothing_admissible" if k <= 0 else None
        elif self.cfg.safety is not None:
            metrics.update(self.admission.metrics(state, None, 0.0))
        if reason is None and self.cfg.design.stop_epistemic_std is not None:
            metrics[POOL_EPISTEMIC_STD_MAX] = self.evaluation.pool_epistemic_max(model, pool)
            if metrics[POOL_EPISTEMIC_STD_MAX] < self.cfg.design.stop_epistemic_std:
                reason = "stop_epistemic_std"
        picks: list[int] = []
        if reason is None:
            rng = derived_rng(self.cfg.seed, Stream.PICKS, round_index)
            withheld = admitted.withheld if admitted is not None else None
            history = self.strategy_history(
                state, withheld, trial=lambda batch: self._trial(state, samples, batch, round_index, model)
            )
            picks = self.strategy.pick(model, pool, k, rng, history)
            picks = self.budget.within_budget(state, picks, admitted.costs if admitted is not None else None)
            metrics.update(self.strategy.round_metrics())
        if figures:
            draw_round(self.cfg, self.directory, model, maneuvers=self.maneuvers, scale=self.test_set.scale,
                       taken=state.taken, picks=picks, driven=lambda i: self.driven(i, state),
                       prior=list(self.prior.runs) if self.prior is not None else (),
                       round_index=round_index)  # fmt: skip
        state.stamps.extend([int(time.time() * 1000)] * (len(state.rounds) + 1 - len(state.stamps)))
        state.rounds.append(metrics)
        if picks:
            self._set_pending(state, picks, admitted)
        else:
            state.finished, state.stop_reason = True, reason or "max_sim_seconds"
        self._model = model
        self.fitting.keep_warm_model(model, round_index)
        self._checkpoint(state, None, model)
        self.run_log.flush(state)
        self.progress({"event": "round", **metrics, "picks": [self.maneuvers[i].name for i in picks]})

    def _receive(self, state: CampaignState, samples: pd.DataFrame, new: pd.DataFrame) -> pd.DataFrame:
        """Append the logs of the pending batch; measure the prequential scale on them if asked."""
        assert state.pending is not None
        if self.cfg.safety is not None:  # what the car did: the true path against the arena and limits
            found = violations(new, self.cfg.safety, self.cfg.simulation.rate_hz)
            state.violated.update({str(i): reason for i, reason in found.items()})
        model = (self._model or load_model(self.directory / MODEL_FILE)) if state.rounds else None
        if model is not None and model.has_epistemic:
            # The model of the last round meets maneuvers it never saw: an honest calibration check.
            checks = self.evaluation.prequential(model, new)
            state.rounds[-1].update(checks)
            self.run_log.log_checks(state, checks)
        samples = pd.concat([samples, new], ignore_index=True)
        state.batches.append(state.pending)
        state.pending = None
        state.ingested.extend(state.staged.values())  # content hashes of the logs a person handed in
        state.staged = {}
        self._checkpoint(state, samples, None)
        return samples

    # ------------------------------------------------------------------ the loop

    def _open(self, resume: bool) -> tuple[CampaignState, pd.DataFrame]:
        """Load or create the directory's state, start the clock and the MLflow run."""
        state, samples = self._load(resume)
        if state.stop_reason == "nothing_admissible" and state.pending is None:
            # [safety] stopped it; [safety] may have changed since (it is not in the config hash):
            # the last round is fitted and judged again (its metrics are logged again at that step).
            state.finished, state.stop_reason = False, None
            if state.rounds and TEST_RMSE in state.rounds[-1]:
                state.rounds.pop()
            state.logged = min(state.logged, len(state.rounds))
        self._clock = (state.wall_seconds, time.perf_counter())
        self.run_log.start(state, self._params)
        if state.rounds:  # a resumed run may hold rounds that never reached MLflow
            self.run_log.flush(state)
        return state, samples

    def _wall(self) -> float:
        """Wall seconds spent on this campaign, over every command that worked on it."""
        base, started = self._clock
        return base + time.perf_counter() - started

    @lock.writer
    def run(self, *, resume: bool = False, figures: bool = True, log_model: bool = True) -> CampaignResult:
        """Run (or resume) the campaign to its budget or stop rule, the oracle answering every batch."""
        if not self.oracle.automatic:
            raise InputError(
                "oracle.kind", self.cfg.oracle.kind,
                "a person drives these maneuvers: use `activelearn campaign propose` and `campaign ingest`",
            )  # fmt: skip
        state, samples = self._open(resume)

        def loop() -> None:
            nonlocal samples
            while not state.finished:
                if state.pending is None:
                    self._propose(state, samples, figures)
                else:
                    new = self._answer(state)
                    samples = self._receive(state, samples, new)

        self.run_log.guarded(state, loop)
        self._finish(state, log_model)
        return CampaignResult(self.directory, state)

    @lock.writer
    def propose(self, *, resume: bool = False, figures: bool = True) -> list[Any]:
        """Ask: the maneuvers to drive next (written to proposals/round-NNN.csv); [] once finished."""
        state, samples = self._open(resume)
        if state.pending is None and not state.finished:
            self.run_log.guarded(state, lambda: self._propose(state, samples, figures))
        if state.finished:
            self._finish(state, log_model=True)
            return []
        assert state.pending is not None
        self._write_proposals(state)
        return [self.driven(i, state) for i in state.pending]

    def history(self) -> pd.DataFrame:
        """One row per fitted round with every logged metric (from the directory's state)."""
        return pd.DataFrame(CampaignState.load(self.directory).rounds)

    def proposal_path(self, state: CampaignState) -> Path:
        """proposals/round-NNN.csv of the pending batch (NNN = batches collected so far)."""
        return proposal_path(self.directory, state)

    def _write_proposals(self, state: CampaignState) -> Path:
        assert state.pending is not None
        driven = [self.driven(i, state) for i in state.pending]
        return write_proposals(self.cfg, self.directory, state, self.maneuvers, driven)

    @lock.writer
    def tell(self, logs: Sequence[pd.DataFrame], *, figures: bool = True) -> list[Any]:
        """Tell: logs of the pending batch, one per proposal, in proposal order; then propose the next.

        `activelearn campaign ingest` matches logs to proposals first (see `activelearn.loop.asktell`);
        this is the plain Python form. Returns the next proposals ([] once finished).
        """
        self.receive(logs)
        return self.propose(resume=True, figures=figures)

    @lock.writer
    def receive(self, logs: Sequence[pd.DataFrame]) -> None:
        """Tell without asking: take the pending batch's logs in (one per proposal, in proposal order) and
        commit them; the next batch is proposed by the next `propose()` (or `tell`'s second half)."""
        if not (self.directory / STATE_FILE).exists():
            raise InputError("directory", str(self.directory), "holds no campaign: call propose() first")
        state, samples = self._open(resume=True)
        if state.pending is None:
            raise InputError("logs", len(logs), "no batch is pending: call propose() first")
        if len(logs) != len(state.pending):
            raise InputError("logs", len(logs), f"the pending batch has {len(state.pending)} maneuvers")
        new = self.label(logs, state.pending, len(state.batches))
        self.run_log.guarded(state, lambda: self._receive(state, samples, new))


def load_campaign_model(directory: str | Path) -> Any:
    """The model of a campaign's last round."""
    return load_model(Path(directory) / MODEL_FILE)


def default_directory(cfg: CampaignConfig) -> Path:
    """runs/<config name>/<strategy>/seed<k>."""
    return Path(cfg.output_dir) / cfg.name / cfg.strategy / f"seed{cfg.seed}"
