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
    "regressor_maximin",
    "joint_maximin",
    "fisher",
    "auto",
    "switch",
    "oracle_error",
    "oracle_lookahead",
)
# The model-based rules `switch` can hand over to after its maximin maneuvers (`[acquisition]
# switch_to`): every strategy that reads the model, but the deciders and the benchmark-only oracles.
# They stand together in STRATEGY_NAMES (a test checks them against the registry's model-based ones).
SWITCH_TARGETS: tuple[str, ...] = STRATEGY_NAMES[
    STRATEGY_NAMES.index("max_epistemic") : STRATEGY_NAMES.index("fisher") + 1
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
    Metric("sim_seconds", "simulated seconds of the maneuvers taken", "s"),
    Metric("wall_seconds", "wall-clock seconds of the campaign so far", "s"),
    Metric("rollout_seconds", "seconds the round's free runs took", "s"),
    # the model's own scales and gates as the round fitted them
    Metric("epistemic_scale", "epistemic scale applied to the round's model"),
    Metric("fan_scale", "fan scale applied to the round's model"),
    Metric("correction_weight", "share of the physics kind's correction kept"),
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
    Metric("calib_spearman", "rank correlation of epistemic std and error on the test set"),
    Metric("calib_rmse", "test RMSE of the mean against noise-free truth (standardised)"),
    Metric("calib_mean_std", "mean epistemic std on the test set (standardised)"),
    Metric("epistemic_std_max", "largest epistemic std on the grid (standardised)"),
    Metric("aleatoric_std_mean", "mean aleatoric std on the grid (standardised)"),
    Metric("pool_epistemic_std_max", "largest epistemic std over the open candidates (standardised)"),
    # prequential checks: the model of a round on the batch collected after it
    Metric("prequential_spearman", "rank correlation of epistemic std and error on the next batch"),
    Metric("prequential_points", "distinct operating points of the next batch"),
    Metric("prequential_scale", "epistemic scale that would have calibrated the next batch"),
    Metric("prequential_fan_scale", "fan scale that would have covered the next batch"),
    # [safety]
    Metric("violations", "maneuvers of the round that left the arena or broke a limit"),
    # free runs of the whole test maneuvers (`activelearn.numerics.diagnostics.free_run_metrics`)
    Metric("rollout_pos_err_10s", "free-run position error at 10 s (m)", "m", "pos 10s m"),
    Metric("rollout_pos_err_30s", "free-run position error at 30 s (m)", "m", "pos 30s m"),
    Metric("rollout_heading_err_30s", "free-run heading error at 30 s (rad)", "rad", "yaw 30s"),
    Metric("rollout_rmse_v", "free-run RMSE of v (m/s)", "m/s", "free v"),
    Metric("rollout_rmse_w", "free-run RMSE of ω (rad/s)", "rad/s", "free ω"),
    Metric("rollout_coverage_95", "share of true positions inside the 95 % fan", column="fan95"),
)
METRICS: dict[str, Metric] = {m.name: m for m in _ALL}

# The budget's and the test set's metrics by name (the loop writes them; studies and figures read them).
ROUND = "round"
N_SAMPLES = "n_samples"
N_MANEUVERS = "n_maneuvers"
SIM_SECONDS = "sim_seconds"
TRACK_SECONDS = "track_seconds"
WALL_SECONDS = "wall_seconds"
TEST_RMSE = "test_rmse"
TEST_RMSE_V = "test_rmse_v"
TEST_RMSE_W = "test_rmse_w"
TEST_NLL = "test_nll"
TEST_CRPS = "test_crps"
COVERAGE_95 = "coverage_95"
EPISTEMIC_STD_MEAN = "epistemic_std_mean"
EPISTEMIC_STD_MAX = "epistemic_std_max"
ALEATORIC_STD_MEAN = "aleatoric_std_mean"
POOL_EPISTEMIC_STD_MAX = "pool_epistemic_std_max"
ROLLOUT_SECONDS = "rollout_seconds"
# The free-run metrics by name (`activelearn.numerics.diagnostics.free_run_metrics` writes them).
ROLLOUT_POS_ERR_10S = "rollout_pos_err_10s"
ROLLOUT_POS_ERR_30S = "rollout_pos_err_30s"
ROLLOUT_HEADING_ERR_30S = "rollout_heading_err_30s"
ROLLOUT_RMSE_V = "rollout_rmse_v"
ROLLOUT_RMSE_W = "rollout_rmse_w"
ROLLOUT_COVERAGE_95 = "rollout_coverage_95"
# The prequential checks' names (`activelearn.loop.evaluation`) and the round's applied scales.
PREQUENTIAL_SPEARMAN = "prequential_spearman"
PREQUENTIAL_POINTS = "prequential_points"
PREQUENTIAL_SCALE = "prequential_scale"
PREQUENTIAL_FAN_SCALE = "prequential_fan_scale"
EPISTEMIC_SCALE = "epistemic_scale"
FAN_SCALE = "fan_scale"
CORRECTION_WEIGHT = "correction_weight"
IDENTIFIED_PREFIX = "identified_"  # a round's identified core parameter, one metric per parameter name
VIOLATIONS = "violations"
CALIB_PREFIX = "calib_"  # the test set's epistemic diagnostic, one metric per key it returns

# Free-running rollout metrics a campaign logs every round (MLflow and curves.csv).
ROLLOUT_METRICS: tuple[str, ...] = (
    ROLLOUT_POS_ERR_10S,
    ROLLOUT_POS_ERR_30S,
    ROLLOUT_HEADING_ERR_30S,
    ROLLOUT_RMSE_V,
    ROLLOUT_RMSE_W,
    ROLLOUT_COVERAGE_95,
)
# Metrics a comparison can rank strategies by (lower is better): one-step test errors, and the free
# runs of the test maneuvers (their fan coverage is not an error, so it does not rank).
RANKING_METRICS: tuple[str, ...] = (
    "test_rmse",
    "test_rmse_v",
    "test_rmse_w",
    "test_nll",
    "test_crps",
    *(m for m in ROLLOUT_METRICS if m != ROLLOUT_COVERAGE_95),
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

TIME = "time"  # s since the run started
THROTTLE, STEERING = "throttle", "steering"  # the commands (steering in rad, signed)
SPEED, YAW_RATE = "speed", "angZ"  # forward speed (m/s) and yaw rate (rad/s)
POS_X, POS_Y, YAW = "posX", "posY", "yaw"  # the logged point (m, m) and heading (rad)
CONTROLS: tuple[str, ...] = (THROTTLE, STEERING)  # what the car is told: the model's inputs
RATES: tuple[str, ...] = (SPEED, YAW_RATE)  # its outputs
POSE: tuple[str, ...] = (POS_X, POS_Y, YAW)  # where the logged point is
PREVIOUS_RATES: tuple[str, ...] = ("prev_speed", "prev_angZ")  # a Markov model's extra inputs
# What a recorded drive must hold to say what the car did: time, the commands and the two rates.
RECORDED_COLUMNS: tuple[str, ...] = (TIME, *CONTROLS, *RATES)
# A free run's ground truth: the rates and the pose along the log.
TRUTH_COLUMNS: tuple[str, ...] = (*RATES, *POSE)
# A control schedule (a CSV a person or planner hands to `simulate --schedule`).
SCHEDULE_COLUMNS: tuple[str, ...] = (TIME, *CONTROLS)
# A proposals/round-NNN.csv of reference maneuvers (the values `activelearn simulate` takes).
PROPOSAL_COLUMNS: tuple[str, ...] = ("maneuver", "direction", "throttle", "steering", "duration")
