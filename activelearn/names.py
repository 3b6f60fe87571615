"""The names every room shares: the strategies, the metrics (label, unit) and the log columns.

One definition each, imported by the config (what it validates), the loop (what a round logs), the
studies (what a comparison ranks and draws), the figures and the CLI (help texts, table headers).
It imports nothing, so the CLI's help reads it without loading torch, pandas or MuJoCo.

The full AutoDRIVE log layout belongs to the simulator (`simulator.collect.AUTODRIVE_COLUMNS`, which
`simulator` owns because it writes it); the columns here are the ones the learning side reads.
"""

from __future__ import annotations

from dataclasses import dataclass

# ------------------------------------------------------------------------------------------ strategies

# Every acquisition strategy by name, in the order help texts list them. The registry of their
# classes (`activelearn.loop.acquisition.STRATEGIES`) holds exactly these (a test checks it).
STRATEGY_NAMES: tuple[str, ...] = (
    "grid",
    "uniform",
    "random",
    "sobol",
    "lhs",
    "max_epistemic",
    "epistemic_maximin",
    "max_total",
    "bald",
    "integrated_variance",
    "safe_expander",
    "igs",
    "lcmd",
    "auto",
    "switch",
    "oracle_error",
    "oracle_lookahead",
)
# The model-based rules `switch` can hand over to after its maximin maneuvers (`[acquisition]
# switch_to`): every strategy that reads the model, but the deciders and the benchmark-only oracles.
# They stand together in STRATEGY_NAMES (a test checks them against the registry's model-based ones).
SWITCH_TARGETS: tuple[str, ...] = STRATEGY_NAMES[
    STRATEGY_NAMES.index("max_epistemic") : STRATEGY_NAMES.index("lcmd") + 1
]
# What `switch` can run on either side of its switch (`switch_first`, `switch_to`): greedy maximin or
# one of those rules.
SWITCH_RULES: tuple[str, ...] = ("uniform", *SWITCH_TARGETS)
# What a comparison measures every strategy against: greedy maximin, the strong space-filling baseline.
REFERENCE_STRATEGY = "uniform"

# ------------------------------------------------------------------------------------------- metrics


@dataclass(frozen=True)
class Metric:
    """A number a round logs: its figure label, its unit ("" when standardised or a ratio) and the
    short header of the CLI's per-round table ("" when the table leaves it out)."""

    name: str
    label: str
    unit: str = ""
    column: str = ""


_ALL: tuple[Metric, ...] = (
    # where the round stands
    Metric("round", "round", column="round"),
    Metric("n_maneuvers", "maneuvers collected", column="maneuvers"),
    Metric("n_samples", "training rows", column="samples"),
    Metric("track_seconds", "track seconds (durations + set-up)", "s"),
    # one-step accuracy on the fixed test set
    Metric("test_rmse", "test RMSE (standardised, v and ω)", column="RMSE"),
    Metric("test_rmse_v", "test RMSE of v (m/s)", "m/s", "RMSE v"),
    Metric("test_rmse_w", "test RMSE of ω (rad/s)", "rad/s", "RMSE ω"),
    Metric("test_nll", "test NLL (standardised)", column="NLL"),
    Metric("test_crps", "test CRPS (standardised)"),
    Metric("coverage_95", "share of test targets inside the 95 % band", column="cover95"),
    # uncertainty over the evaluation grid and its calibration
    Metric("epistemic_std_mean", "mean epistemic std on the grid (standardised)", column="epi std"),
    Metric("calib_std_to_rmse", "epistemic std over error", column="epi/err"),
    Metric("calib_z_spread", "spread of the standardised errors", column="z spread"),
    # free runs of the whole test maneuvers (`activelearn.numerics.diagnostics.free_run_metrics`)
    Metric("rollout_pos_err_10s", "free-run position error at 10 s (m)", "m", "pos 10s m"),
    Metric("rollout_pos_err_30s", "free-run position error at 30 s (m)", "m", "pos 30s m"),
    Metric("rollout_heading_err_30s", "free-run heading error at 30 s (rad)", "rad", "yaw 30s"),
    Metric("rollout_rmse_v", "free-run RMSE of v (m/s)", "m/s", "free v"),
    Metric("rollout_rmse_w", "free-run RMSE of ω (rad/s)", "rad/s", "free ω"),
    Metric("rollout_coverage_95", "share of true positions inside the 95 % fan", column="fan95"),
)
METRICS: dict[str, Metric] = {m.name: m for m in _ALL}

# Free-running rollout metrics a campaign logs every round (MLflow and curves.csv).
ROLLOUT_METRICS: tuple[str, ...] = (
    "rollout_pos_err_10s",
    "rollout_pos_err_30s",
    "rollout_heading_err_30s",
    "rollout_rmse_v",
    "rollout_rmse_w",
    "rollout_coverage_95",
)
# Metrics a comparison can rank strategies by (lower is better): one-step test errors, and the free
# runs of the test maneuvers (their fan coverage is not an error, so it does not rank).
RANKING_METRICS: tuple[str, ...] = (
    "test_rmse",
    "test_rmse_v",
    "test_rmse_w",
    "test_nll",
    "test_crps",
    *(m for m in ROLLOUT_METRICS if m != "rollout_coverage_95"),
)
# What a comparison's figure draws besides the metric it ranks by.
CURVE_METRICS: tuple[str, ...] = ("test_rmse", "test_rmse_v", "test_rmse_w", "epistemic_std_mean", "test_nll")
# The CLI's per-round table: one-step metrics always, the free-run ones when the config ranks by one.
ROUND_TABLE: tuple[str, ...] = (
    "round",
    "n_maneuvers",
    "n_samples",
    "test_rmse",
    "test_rmse_v",
    "test_rmse_w",
    "test_nll",
    "coverage_95",
    "epistemic_std_mean",
    "calib_std_to_rmse",
    "calib_z_spread",
)


def metric_label(name: str) -> str:
    """A metric's figure label (its name where it has none)."""
    metric = METRICS.get(name)
    return metric.label if metric is not None else name


# --------------------------------------------------------------------------------------- log columns

CONTROLS: tuple[str, ...] = ("throttle", "steering")  # what the car is told: the model's inputs
RATES: tuple[str, ...] = ("speed", "angZ")  # forward speed (m/s) and yaw rate (rad/s): its outputs
POSE: tuple[str, ...] = ("posX", "posY", "yaw")  # where the logged point is (m, m, rad)
PREVIOUS_RATES: tuple[str, ...] = ("prev_speed", "prev_angZ")  # a Markov model's extra inputs
# What a recorded drive must hold to say what the car did: time, the commands and the two rates.
RECORDED_COLUMNS: tuple[str, ...] = ("time", *CONTROLS, *RATES)
# A free run's ground truth: the rates and the pose along the log.
TRUTH_COLUMNS: tuple[str, ...] = (*RATES, *POSE)
# A control schedule (a CSV a person or planner hands to `simulate --schedule`).
SCHEDULE_COLUMNS: tuple[str, ...] = ("time", *CONTROLS)
# A proposals/round-NNN.csv of reference maneuvers (the values `activelearn simulate` takes).
PROPOSAL_COLUMNS: tuple[str, ...] = ("maneuver", "direction", "throttle", "steering", "duration")
