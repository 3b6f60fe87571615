"""A campaign's MLflow run: opened (or resumed), every round logged once, finished or marked failed.

The tracker is handed in (`activelearn.studies.tracking.Tracker`, the only MLflow importer); without
one nothing is logged. A tracking server that goes away mid-campaign costs one warning: the campaign
goes on, counts in its state what reached MLflow (`state.logged`), and logs the rest once the server
answers again or at `--resume`.

Every round is logged at step = the maneuvers collected so far (`n_maneuvers`, the campaign's budget),
so the runs of a comparison line up on MLflow's charts whatever their rows per maneuver; the training
rows are a metric of their own (`n_samples`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from activelearn.config import CampaignConfig
from activelearn.errors import ActiveLearnError, CampaignStopped, TrackingUnavailable
from activelearn.loop.state import CampaignState
from activelearn.names import N_MANEUVERS, ROUND

Progress = Callable[[dict[str, Any]], None]


def round_step(record: dict[str, Any]) -> int:
    """The MLflow step of a round's metrics: the maneuvers collected so far."""
    return int(record[N_MANEUVERS])


class CampaignInterrupted(ActiveLearnError):
    """The campaign was stopped by the user; its directory can be resumed."""


class RunLog:
    """The MLflow run of one campaign directory.

    `progress` receives the notices (`tracking_down`); the campaign's `tracker` is this object's, so a
    command may set it after the campaign is built.
    """

    def __init__(
        self,
        cfg: CampaignConfig,
        directory: str | Path,
        *,
        tracker: Any | None = None,
        parent_run_id: str | None = None,
        progress: Progress | None = None,
    ) -> None:
        self.cfg = cfg
        self.directory = Path(directory)
        self.tracker = tracker
        self.parent_run_id = parent_run_id
        self.progress: Progress = progress or (lambda event: None)
        self._down = False  # the tracking server stopped answering (warned once)

    def track(self, call: Callable[[], Any]) -> bool:
        """Make a tracking call. A tracking server that went away is one warning and False: the campaign
        goes on, and what it missed is logged once the server is back (or at --resume)."""
        try:
            call()
        except TrackingUnavailable as exc:
            if not self._down:
                self.progress({"event": "tracking_down", "message": f"{exc}: the campaign goes on and logs "
                               "what it missed once the server is back (or at --resume)"})  # fmt: skip
            self._down = True
            return False
        self._down = False
        return True

    def start(self, state: CampaignState, params: Callable[[], dict[str, Any]]) -> None:
        """Open (or resume) the run of `state` and log the campaign's `params()`; a server that does not
        answer stops the campaign before anything is trained."""
        if self.tracker is None:
            return
        try:
            self._open_run(state, params)
        except TrackingUnavailable as exc:
            raise CampaignStopped(f"{exc}; nothing was trained or logged: rerun once it answers") from None

    def _open_run(self, state: CampaignState, params: Callable[[], dict[str, Any]]) -> None:
        assert self.tracker is not None
        # Nested under a comparison, the strategy first: MLflow's chart legends read `uniform/seed0`.
        name = (f"{self.cfg.strategy}/seed{self.cfg.seed}" if self.parent_run_id is not None
                else f"{self.cfg.name}-{self.cfg.strategy}-seed{self.cfg.seed}")  # fmt: skip
        state.run_id = self.tracker.start_run(
            name,
            parent_run_id=self.parent_run_id,
            resume_run_id=state.run_id,
            tags={"strategy": self.cfg.strategy, "seed": str(self.cfg.seed), "config": self.cfg.name},
        )
        self.tracker.log_params(state.run_id, params())

    def flush(self, state: CampaignState) -> None:
        """Log the rounds that have not reached MLflow yet, in order; stop at the first that fails."""
        if self.tracker is None or state.run_id is None:
            return
        for index in range(state.logged, len(state.rounds)):
            if not self.track(lambda index=index: self._log_round(state, index)):
                break
            state.logged += 1
        state.save(self.directory)

    def _log_round(self, state: CampaignState, index: int) -> None:
        assert self.tracker is not None and state.run_id is not None
        record = state.rounds[index]
        stamp = state.stamps[index] if index < len(state.stamps) else None
        self.tracker.log_metrics(state.run_id, record, step=round_step(record), timestamp=stamp)
        figure_path = self.directory / "figures" / f"epistemic_round{int(record[ROUND]):02d}.png"
        if figure_path.exists():
            self.tracker.log_artifact(state.run_id, figure_path, "figures")

    def log_checks(self, state: CampaignState, checks: dict[str, float]) -> None:
        """Log the prequential checks of the last round at its step (the round again, later, on failure)."""
        if self.tracker is None or state.run_id is None:
            return
        tracker, run_id, step = self.tracker, state.run_id, round_step(state.rounds[-1])
        stamp = state.stamps[-1] if len(state.stamps) == len(state.rounds) else None
        if not self.track(lambda: tracker.log_metrics(run_id, checks, step=step, timestamp=stamp)):
            state.logged = min(state.logged, len(state.rounds) - 1)  # the round again, later

    def finish(self, state: CampaignState, log_model: bool, model: Callable[[], Any]) -> None:
        """Log what is missing (rounds, the last round's `model()`) and end the run FINISHED; a server
        that does not answer stops the campaign with what is left to log."""
        if self.tracker is None or state.run_id is None:
            return
        tracker, run_id = self.tracker, state.run_id
        if state.logged < len(state.rounds):
            self.flush(state)
        if log_model and not state.model_logged and state.logged == len(state.rounds):
            last = model()
            if self.track(lambda: tracker.log_model(run_id, last)):
                state.model_logged = True
                state.save(self.directory)
        done = state.logged == len(state.rounds) and (state.model_logged or not log_model)
        if not (done and self.track(lambda: tracker.end_run(run_id, "FINISHED"))):
            unlogged = len(state.rounds) - state.logged
            missing = [f"{unlogged} round(s)"] if unlogged else []
            missing += ["the model"] if log_model and not state.model_logged else []
            raise CampaignStopped(
                f"the MLflow tracking server at {tracker.tracking_uri} does not answer: "
                f"{' and '.join(missing) or 'the end of the run'} not logged yet; the campaign's data is "
                f"complete in {self.directory}: rerun with --resume once the server answers"
            )

    def guarded(self, state: CampaignState, step: Callable[[], Any]) -> Any:
        """Run a step; Ctrl-C marks the MLflow run KILLED, any other error FAILED."""
        tracker, run_id = self.tracker, state.run_id
        try:
            return step()
        except KeyboardInterrupt:
            if tracker is not None and run_id is not None:
                self.track(lambda: tracker.end_run(run_id, "KILLED"))
            raise CampaignInterrupted(
                f"interrupted; {self.directory} holds the last finished step: rerun with --resume"
            ) from None
        except BaseException:
            if tracker is not None and run_id is not None:
                self.track(lambda: tracker.end_run(run_id, "FAILED"))
            raise
