"""[safety] (issue 23): the arena config, admissibility from the fans, cuts, violations, the stop.

Real MuJoCo, real models and a real SQLite MLflow store, on a tiny skidpad-and-straight pool.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from activelearn.config import (
    SafetyConfig,
    boundary_distance,
    load_config,
    polygon_clearance,
    polygon_self_crossing,
    validate_config,
)
from activelearn.errors import ConfigError
from activelearn.loop.acquisition import make_strategy
from activelearn.loop.admission import withhold
from activelearn.loop.campaign import Campaign, CampaignState, config_hash
from activelearn.loop.collection import rows_per_maneuver
from activelearn.loop.pool import maneuver_controls
from activelearn.loop.safety.kinematic_bound import (
    SPEED_PER_THROTTLE,
    circles_fit,
    kinematic_bound,
    monotone_steps,
    turn_speed,
)
from activelearn.loop.safety.limits import REASONS, log_violation, violating
from activelearn.loop.safety.live_stop import live_stop, stop_rule
from activelearn.loop.safety.risk import Assessment, admissible_duration, fan, relative_std, widened
from activelearn.numerics.models import build_model
from activelearn.numerics.surrogate import Rollout, simulate
from activelearn.numerics.training import fit
from activelearn.numerics.training_data import TrainingData
from activelearn.studies.tracking import Tracker
from simulator import FamilyManeuver, Maneuver, collect

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"
SQUARE = [[-1.5, -1.5], [1.5, -1.5], [1.5, 1.5], [-1.5, 1.5]]



def worst_case(maneuver, cfg, **options):
    """The kinematic bound of `maneuver` at the simulator's log rate."""
    return kinematic_bound(maneuver, cfg, rate_hz=30.0, **options)

def safe_config(tmp_path: Path, safety: dict | None = None, **overrides):
    """The smoke pool with straights, a 3 x 3 m arena around the start, writing under tmp_path."""
    data = {
        "output_dir": str(tmp_path / "runs"),
        "tracking": {"uri": f"sqlite:///{tmp_path}/mlruns/mlflow.db"},
        "pool": {"kinds": ["straight", "skidpad"]},
        "training": {"epochs": 25},
        "design": {"initial": 3, "per_round": 2, "max_maneuvers": 5},
        "safety": {"arena": SQUARE, "start": [0.0, 0.0, 0.0], "min_duration": 3.0, "n_samples": 16,
                   **(safety or {})},
        **overrides,
    }  # fmt: skip
    return load_config(SMOKE, overrides=data)


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "activelearn.cli", *args], capture_output=True, text=True,
                          timeout=300)  # fmt: skip


# ------------------------------------------------------------------------------------- the config


@pytest.mark.parametrize(
    ("safety", "field", "words"),
    [
        ({"arena": [[0, 0], [1, 0]]}, "safety.arena", "open"),
        ({"arena": [[0, 0], [1, 0], [2, 0]]}, "safety.arena", "open"),
        ({"arena": [[0, 0], [1, 1], [1, 0], [0, 1]]}, "safety.arena", "crosses itself"),
        ({"arena": SQUARE, "start": [2.0, 0.0, 0.0]}, "safety.start", "outside"),
        ({"arena": SQUARE, "start": [1.45, 0.0, 0.0]}, "safety.start", "margin"),
        ({"arena": SQUARE, "delta": 0.0}, "safety.delta", "(0, 1)"),
        ({"arena": SQUARE, "delta": 1.0}, "safety.delta", "(0, 1)"),
        ({"arena": SQUARE, "stop": "never"}, "safety.stop", "'planned' or 'live'"),
        ({"arena": SQUARE, "stop_buffer": -0.1}, "safety.stop_buffer", "greater than or equal to 0"),
        ({"arena": SQUARE, "stop": "live", "stop_buffer": 0.02}, "safety.stop_buffer", "needs to stop"),
    ],
)
def test_bad_safety_values_name_their_field(safety, field, words):
    with pytest.raises(ConfigError) as info:
        validate_config({"safety": safety})
    assert str(info.value).startswith(field) and words in str(info.value)


@pytest.mark.slow
def test_bad_arena_on_the_command_line_is_one_line_exit_2_nothing_written(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(SMOKE.read_text() + '\n[safety]\narena = [[0, 0], [1, 1], [1, 0], [0, 1]]\n')
    out = tmp_path / "o"
    plot = str(tmp_path / "p.png")
    done = _cli("campaign", "propose", str(bad), "--no-tracking", "--out", str(out), "--plot", plot)
    assert done.returncode == 2
    assert "safety.arena" in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert not out.exists() and not (tmp_path / "p.png").exists()


def test_polygon_geometry():
    assert polygon_self_crossing([(0, 0), (2, 0), (2, 2), (0, 2)]) is None
    assert polygon_self_crossing([(0, 0), (2, 0), (2, 2), (1, 2), (1, -1)]) is not None
    d = boundary_distance(SQUARE, np.array([0.0, 1.0, 2.0]), np.array([0.0, 0.0, 0.0]))
    assert np.allclose(d, [1.5, 0.5, -0.5])
    # a concave arena (an L): the notch is outside
    ell = [(0, 0), (2, 0), (2, 1), (1, 1), (1, 2), (0, 2)]
    assert boundary_distance(ell, 1.5, 1.5) < 0 < boundary_distance(ell, 0.5, 1.5)
    # the fast clearance of convex arenas (either orientation) agrees with it inside, and in sign
    x, y = np.random.default_rng(0).uniform(-2, 3, (2, 5000))
    for arena in (SQUARE, SQUARE[::-1], [(0, 0), (2, 0), (3, 1), (1, 3), (-1, 1)], ell):
        exact, fast = boundary_distance(arena, x, y), polygon_clearance(arena, x, y)
        assert np.allclose(fast[exact >= 0], exact[exact >= 0]) and ((fast >= 0.1) == (exact >= 0.1)).all()


def test_admissible_duration_keeps_cuts_or_drops():
    cfg = SafetyConfig(arena=SQUARE, delta=0.1, min_duration=5.0)
    never = np.full(20, np.inf)
    assert admissible_duration(never, 30.0, cfg) == (0.0, 30.0, 0.0)
    # 2 of 20 trajectories violate (10 % <= delta): the whole maneuver
    two = never.copy()
    two[:2] = [3.0, 4.0]
    assert admissible_duration(two, 30.0, cfg)[1] == 30.0
    # 5 of 20 violate, the third earliest at 12.7 s: cut to 12 s, where only 2 have
    five = never.copy()
    five[:5] = [3.0, 4.0, 12.7, 20.0, 25.0]
    risk, duration, cut_risk = admissible_duration(five, 30.0, cfg)
    assert (risk, duration, cut_risk) == (0.25, 12.0, 0.1)
    # ... unless that is shorter than min_duration
    early = never.copy()
    early[:5] = [1.0, 2.0, 3.0, 4.0, 5.0]
    assert admissible_duration(early, 30.0, cfg)[1] == 0.0


def test_the_safe_set_shares_count_open_candidates_and_their_seconds():
    # four candidates of 30 s: one taken (not assessed), one whole, one cut to 12 s, one refused
    nan = float("nan")
    safe = Assessment(
        risk=np.array([nan, 0.0, 0.25, 0.5]), duration=np.array([0.0, 30.0, 12.0, 0.0]),
        cut_risk=np.array([nan, 0.0, 0.1, nan]), full=np.full(4, 30.0),
    )  # fmt: skip
    assert safe.size == 2 and safe.cut.sum() == 1
    assert safe.share == pytest.approx(2 / 3)  # the taken one counts in neither share
    assert safe.time_share == pytest.approx(42 / 90)
    # the cut one trusted whole: the count stays, the seconds grow
    grown = dataclasses.replace(safe, duration=np.array([0.0, 30.0, 30.0, 0.0]))
    assert grown.share == safe.share and grown.time_share == pytest.approx(60 / 90)
    none = dataclasses.replace(safe, risk=np.full(4, nan))
    assert np.isnan(none.share) and np.isnan(none.time_share)


def test_the_fan_is_trusted_by_the_relative_std_of_the_rates_trust_rates_names():
    # two maneuvers of 4 steps, the second only 3 long (its 4th step is padding)
    mean = np.zeros((2, 4, 2))
    mean[..., 0], mean[..., 1] = 0.2, 0.5  # m/s, rad/s
    mean[0, 0] = 0.0  # standing: the floors (0.02 m/s, 0.05 rad/s) stand in
    var = np.zeros((2, 4, 2))
    var[0, :, 0] = 0.002**2  # speed std 2 mm/s: 10 % of the floor at standstill, 1 % of 0.2 m/s
    var[1, 1, 1] = 0.02**2  # yaw-rate std 0.02 rad/s: 4 % of 0.5 rad/s
    var[1, 3, :] = 1.0  # padding: never read
    empty = np.zeros((1, 2, 4))
    rollout = Rollout(1 / 30, empty, empty, empty, empty, empty, mean, var, var, np.array([4, 3]))
    assert relative_std(rollout) == pytest.approx([0.1, 0.0])
    assert relative_std(rollout, ("yaw_rate",)) == pytest.approx([0.0, 0.04])
    assert relative_std(rollout, ("speed", "yaw_rate")) == pytest.approx([0.1, 0.04])
    with pytest.raises(ConfigError, match=r"safety\.trust_rates"):
        validate_config({"safety": {"arena": SQUARE, "trust_rates": ["lateral"]}})


def test_a_skidpad_whose_every_circle_fits_is_driven_whole_before_the_model_knows_it():
    # Start 0.8 m from the left wall (y = 1.5), facing +x, in a 3 x 3 m arena: a straight or a
    # wide skidpad may reach a wall within seconds at any heading, a tight one goes round a circle
    # (radius L / tan(0.5236) = 0.25 m to twice that) whatever its speed, forward or in reverse.
    cfg = SafetyConfig(arena=SQUARE, start=(0.0, 0.7, 0.0), margin=0.16, path_tolerance=0.04, delta=0.05,
                       max_lateral_acceleration=0.2)  # fmt: skip
    tight = Maneuver("skidpad", 0.4, 0.5236, "cw", 30.0)  # centre 0.25-0.5 m to the right: fits
    assert circles_fit(tight, cfg) and worst_case(tight, cfg) == (0.0, 30.0, 0.0)
    reverse = dataclasses.replace(tight, throttle=-0.4)
    assert worst_case(reverse, cfg) == (0.0, 30.0, 0.0)
    left = dataclasses.replace(tight, direction="ccw")  # the circle reaches y = 0.7 + 1.0: the wall
    assert not circles_fit(left, cfg) and worst_case(left, cfg)[1] < 30.0
    wide = dataclasses.replace(tight, steering=0.1047)  # radius 1.35-2.7 m
    straight = Maneuver("straight", 0.4, 0.0, "ccw", 30.0)
    for other in (wide, straight, dataclasses.replace(tight, kind="fishhook")):
        assert not circles_fit(other, cfg) and worst_case(other, cfg)[1] < 30.0, other
    fast = dataclasses.replace(tight, throttle=1.0)  # fits, but its worst-case rates break a limit
    assert circles_fit(fast, cfg) and worst_case(fast, cfg)[1] == 0.0


def test_the_worst_case_reads_a_family_schedule_step_by_step():
    # A throttle step from 0.2 to 1.0 after 20 of 30 s: its median throttle is 0.2, but the worst case
    # takes the fastest throttle so far, so the car may not drive past the limit (speed 0.287 > 0.25).
    cfg = SafetyConfig(arena=[[-5, -5], [5, -5], [5, 5], [-5, 5]], start=(0.0, 0.0, 0.0), max_speed=0.25,
                       min_duration=5.0)  # fmt: skip
    step = FamilyManeuver("throttle_step", {"throttle_start": 0.2, "throttle_end": 1.0, "switch_time": 20.0,
                                            "ramp_time": 0.0, "steering": 0.0}, "ccw", 30.0)  # fmt: skip
    assert step.throttle == pytest.approx(0.2)
    assert worst_case(step, cfg) == (1.0, 19.0, 0.0)  # the old bound (median throttle) said 30 s
    # Staircases whose steering only grows stay inside their first circle: whole, forward or in reverse,
    # where a skidpad at the first level fits; a staircase that eases its steering is no spiral.
    box = SafetyConfig(arena=SQUARE, start=(0.0, 0.0, 0.0), margin=0.16, path_tolerance=0.04,
                       max_lateral_acceleration=0.2)  # fmt: skip

    def stairs(start: float, amplitude: float) -> FamilyManeuver:
        params = {"throttle": -0.6, "start": start, "amplitude": amplitude, "hold": 4.0}
        return FamilyManeuver("staircase", params, "cw", 30.0)

    up = stairs(0.45, 0.52)
    assert monotone_steps(up.controls(30.0)) == len(up.controls(30.0))
    assert circles_fit(up, box, steering=0.45, nested=True) and worst_case(up, box) == (0.0, 30.0, 0.0)
    wider = stairs(0.3, 0.52)  # its first circle (centre 0.46-0.91 m aside, radius up to 1 m) does not fit
    assert not circles_fit(wider, box, steering=0.3, nested=True) and worst_case(wider, box)[1] < 30.0
    down = stairs(0.52, 0.45)
    assert monotone_steps(down.controls(30.0)) == 4 * 30 and worst_case(down, box)[1] < 30.0
    # A fishhook: its ramp reaches 0.5 rad within 2.5 s at 0.2 rad/s (the rest is a tight circle within
    # reach of the start: whole); at the reference 0.006 rad/s it is a long spiral, cut by its reach.
    fast = FamilyManeuver("fishhook", {"throttle": 0.4, "rate": 0.2, "amplitude": 0.5}, "ccw", 60.0)
    slow = FamilyManeuver("fishhook", {"throttle": 0.4, "rate": 0.006, "amplitude": 0.5}, "ccw", 60.0)
    roomy = box.model_copy(update={"arena": [(-2.0, -2.0), (2.0, -2.0), (2.0, 2.0), (-2.0, 2.0)]})
    assert worst_case(fast, roomy) == (0.0, 60.0, 0.0)  # within 0.29 m + 2 (0.52 + 0.08) m of the start
    assert worst_case(fast, box)[1] < 60.0  # 1.48 m: more than the 1.3 m of room in the small box
    room = 2.0 - box.margin
    reach = float(np.floor(room / (0.287 * 0.4) - 1 / 30))  # the last whole second before it, a step short
    assert worst_case(slow, roomy) == (1.0, reach, 0.0)


def test_the_speed_kept_in_turns_is_measured_on_the_logs_and_bounds_reverse_turns_in_mujoco():
    # Forward straights and skidpads (a prior grid) give the share of the speed envelope the car keeps
    # at each steering; the worst case then takes it for reverse turns too (an assumption, checked
    # here in MuJoCo) and admits a reverse skidpad that the no-loss bound refuses.
    forward = [Maneuver("straight", u, 0.0, "ccw", 10.0) for u in (0.2, 0.6, 1.0)]
    forward += [Maneuver("skidpad", u, s, "ccw", 10.0) for u in (0.2, 0.6, 1.0) for s in (0.2094, 0.3142)]
    logs = collect(forward, rate_hz=30.0, noise=None)
    turn = turn_speed(logs, 30.0, 0.5)
    assert turn is not None and turn.runs == 9 and list(turn.steerings) == [0.0, 0.2094, 0.3142]
    assert turn.keep[2] < turn.keep[1] < turn.keep[0] <= 1.0 and turn.keep[2] < 0.95
    assert list(turn.factor(np.array([0.0, 0.25, 0.5]))) == list(turn.keep)
    # runs whose commands change, or too short to settle, do not count; without any: None
    changing, short = Maneuver("slalom", 0.6, 0.3, "ccw", 10.0), Maneuver("skidpad", 0.6, 0.5236, "ccw", 3.0)
    others = collect([changing, short], rate_hz=30.0, noise=None)
    assert turn_speed(pd.concat([logs, others]), 30.0, 0.5).runs == 9
    assert turn_speed(others, 30.0, 0.5) is None and turn_speed(None, 30.0, 0.5) is None
    reverse = [Maneuver("skidpad", u, s, d, 20.0) for u in (-0.4, -0.7, -1.0) for s in (0.3142, 0.43, 0.5236)
               for d in ("ccw", "cw")]  # fmt: skip
    driven = collect(reverse, rate_hz=30.0, noise=None)
    for m in reverse:
        speed = driven[driven["run_id"] == m.name]["speed"].abs().rolling(15, min_periods=1).mean().max()
        bound = SPEED_PER_THROTTLE * abs(m.throttle) * turn.factor(np.array([m.steering]))[0]
        assert speed <= bound, m.name
    cfg = SafetyConfig(arena=[[-5, -5], [5, -5], [5, 5], [-5, 5]], start=(0.0, 0.0, 0.0),
                       max_lateral_acceleration=0.12)  # fmt: skip
    tight = Maneuver("skidpad", -0.7, 0.43, "cw", 30.0)  # no loss: 0.201 m/s x 0.65 rad/s = 0.131 m/s^2
    assert worst_case(tight, cfg)[1] == 0.0
    assert worst_case(tight, cfg, turn=turn) == (0.0, 30.0, 0.0)


def test_log_violation_reads_the_path_in_the_arena_frame():
    cfg = SafetyConfig(arena=SQUARE, start=(1.0, 0.0, 0.0), margin=0.1)
    t = np.arange(0, 10, 1 / 30)
    log = pd.DataFrame({"posX": 5.0 + 0.05 * t, "posY": 7.0 + 0 * t, "yaw": 0 * t, "speed": 0.05 + 0 * t,
                        "angZ": 0 * t})  # fmt: skip
    # from x = 1.0 at 0.05 m/s for 10 s: to 1.5, beyond the wall at 1.5 less the margin
    assert log_violation(log, cfg, 30.0) == "arena"
    assert log_violation(log[t < 5], cfg, 30.0) == ""
    fast = log[t < 5].assign(speed=0.5)
    assert log_violation(fast, cfg, 30.0) == "speed"


def test_a_live_stop_keeps_the_walls_at_run_time_and_leaves_the_limits_to_the_plan():
    # A straight at full throttle leaves the 3 x 3 m arena after ~5 s: planned, it is cut there; with a
    # live stop it may be driven whole (the car brakes at the wall), unless a limit binds.
    straight = Maneuver("straight", 1.0, 0.0, "ccw", 20.0)
    planned = SafetyConfig(arena=SQUARE, min_duration=3.0)
    live = planned.model_copy(update={"stop": "live"})
    assert 0.0 < worst_case(straight, planned)[1] < 10.0
    assert worst_case(straight, live) == (0.0, 20.0, 0.0)
    slow = live.model_copy(update={"max_speed": 0.2})  # 0.287 m/s at full throttle breaks it at once
    assert worst_case(straight, slow)[1] == 0.0
    # In MuJoCo, closed-loop: the car brakes (throttle 0) once its pose comes within margin + stop_buffer
    # of the wall, the log runs on until it stands, and the whole of it, braking included, violates nothing.
    log = collect(straight, rate_hz=30.0, noise=None)
    assert log_violation(log, live, 30.0) == "arena"
    stopped = collect(straight, rate_hz=30.0, noise=None, stop=stop_rule(live))
    cut = live_stop(log, live)  # a recorded log that cannot be driven again: cut at the trigger
    assert 30 < len(cut) < len(stopped) < len(log)
    assert log_violation(stopped, live, 30.0) == "" and log_violation(cut, live, 30.0) == ""
    braked = stopped["throttle"].to_numpy() == 0.0
    assert not braked[: len(cut) + 1].any() and braked[len(cut) + 1 :].all()
    x = stopped["posX"].to_numpy() - stopped["posX"].iloc[0]
    wall = 1.5 - live.margin - live.stop_buffer  # from the start at the centre, facing +x
    assert wall < x[len(cut)] < wall + 0.01  # the pose that triggered: one step (< 1 cm) past the line
    assert wall < x[-1] < 1.5 - live.margin  # it stood between the line and the margin
    assert abs(stopped["speed"].iloc[-1]) < 0.002
    assert live_stop(log.iloc[:30], live) is not None and len(live_stop(log.iloc[:30], live)) == 30


def test_a_diverged_fan_trajectory_is_a_violation():
    cfg = SafetyConfig(arena=SQUARE)
    zeros = np.zeros((2, 60))
    x = zeros.copy()
    x[1, 30:] = np.nan  # the second trajectory blew up half-way (a Markov rollout can)
    code = violating(x, zeros, zeros + 0.1, zeros, cfg, 30.0)
    assert not code[0].any()
    assert REASONS[code[1, 30] - 1] == "diverged" and not code[1, :30].any()


def test_fans_place_the_path_where_the_car_logs_it(tmp_path):
    # The fan's path is the logged point's (l_r ahead of a rear axle that does not slip, the model's
    # pose_lever_arm), so the CG's side slip is in the fan and `path_tolerance` only keeps a few cm
    # (true rates retrace the logged path to ~1 cm: tests/test_surrogate.py).
    cfg = safe_config(tmp_path, {"start": [0.3, -0.2, 0.5], "fan_scale": 1.0}, tracking={"enabled": False})
    assert cfg.safety.path_tolerance < 0.05 and cfg.model.pose_lever_arm > 0
    campaign = Campaign(cfg, tmp_path / "c")
    model = build_model(cfg.model)
    test = campaign.test_set
    fit(model, TrainingData(test.x, test.y_noisy, groups=test.groups), cfg.training, seed=0)
    skidpads = [m for m in campaign.maneuvers if m.kind == "skidpad"][:2]
    rollout = fan(model, skidpads, cfg.safety, 30.0, seed=4)
    # [safety] fan_scale widens a copy of the model: the round's model keeps its own scale
    scale, wider = float(model.epistemic_scale), cfg.safety.model_copy(update={"fan_scale": 3.0})
    wide = fan(model, skidpads, wider, 30.0, seed=4)
    assert float(model.epistemic_scale) == scale and not np.allclose(wide.x, rollout.x)
    copied = widened(model, 3.0)
    assert copied is not model and float(copied.epistemic_scale) == pytest.approx(9.0 * scale)
    np.testing.assert_array_equal(fan(copied, skidpads, wider, 30.0, seed=4, widen=False).x, wide.x)
    controls = [maneuver_controls(m, 30.0) for m in skidpads]
    call = dict(rate_hz=30.0, n_samples=cfg.safety.n_samples, seed=4, initial_yaw=0.5)
    at_cg = simulate(model, controls, lever_arm=cfg.model.pose_lever_arm, **call)
    np.testing.assert_allclose(rollout.x, at_cg.x + 0.3, atol=1e-6)
    np.testing.assert_allclose(rollout.y, at_cg.y - 0.2, atol=1e-6)
    at_axle = simulate(model, controls, lever_arm=0.0, **call)
    assert np.nanmax(np.hypot(rollout.x - 0.3 - at_axle.x, rollout.y + 0.2 - at_axle.y)) > 0.1
    # The model's own fan calibration (`fan_scale`, for predictions) does not widen the safety fan on
    # top of [safety] fan_scale, the margin the safety numbers were measured with.
    with torch.no_grad():
        model.fan_scale.fill_(4.0)
    again = fan(model, skidpads, cfg.safety, 30.0, seed=4)
    np.testing.assert_array_equal(again.x, rollout.x)
    assert not np.allclose(simulate(model, controls, lever_arm=cfg.model.pose_lever_arm, **call).x, at_cg.x)


# ------------------------------------------------------------------------------------- campaigns


@pytest.mark.slow
def test_safe_campaign_drives_admissible_cuts_and_logs_safety(tmp_path):
    cfg = safe_config(tmp_path)
    tracker = Tracker(cfg.tracking.uri, cfg.tracking.experiment)
    result = Campaign(cfg, tmp_path / "c", tracker=tracker).run(figures=False)
    state = result.state
    assert len(state.taken) == 5
    samples = pd.read_parquet(tmp_path / "c" / "samples.parquet")
    for index in state.taken:
        driven = samples[samples["pool_index"] == index]
        seconds = driven["time"].max()
        if str(index) in state.cuts:  # cut short: driven (and logged) for the shorter duration only
            assert state.cuts[str(index)] < 20.0
            assert seconds <= state.cuts[str(index)] + 0.05
        else:
            assert seconds > 19.0
        assert state.risks[str(index)] <= cfg.safety.delta
    assert state.cuts, "the 3 x 3 m arena cuts the fast maneuvers"
    history = result.history
    assert {"safe_set_size", "violations", "violations_total"} <= set(history)
    assert (history["safe_set_size"].dropna() > 0).all()
    shares = history[["safe_set_share", "safe_time_share"]].dropna()
    assert len(shares) and ((shares > 0) & (shares <= 1)).all().all()
    for name in ("safe_set_size", "violations", "violations_total", "safety_seconds"):
        assert len(tracker.metric_history(state.run_id, name)) >= 1, name
    assert history["violations_total"].iloc[-1] == sum(1 for r in state.violated.values() if r)


def test_a_live_stop_campaign_drives_to_the_walls_without_a_violation(tmp_path):
    cfg = safe_config(tmp_path, {"stop": "live"}, tracking={"enabled": False})
    result = Campaign(cfg, tmp_path / "c").run(figures=False)
    state = result.state
    assert len(state.taken) == 5
    assert all(reason == "" for reason in state.violated.values()) and len(state.violated) == 5
    samples = pd.read_parquet(tmp_path / "c" / "samples.parquet")
    seconds = samples.groupby("pool_index")["time"].max()
    # the straights and fast skidpads that the planned stop cuts in advance are driven until the wall,
    # where the car brakes (throttle 0, logged) until it stands
    stopped = [i for i in state.taken if str(i) not in state.cuts and seconds[i] < 19.0]
    assert stopped, "some maneuver ended at the wall"
    for i in stopped:
        log = samples[samples["pool_index"] == i]
        throttle = log["throttle"].to_numpy()
        assert throttle[0] != 0.0 and throttle[-1] == 0.0 and abs(log["speed"].iloc[-1]) < 0.02
    assert len(state.cuts) < len(state.taken)


def test_a_cut_candidate_is_scored_as_it_would_be_driven(tmp_path):
    # Strategies score a candidate by the controls and rows it would give: a cut one by its first
    # seconds only (a fishhook cut before its ramp ends never reaches its full steering).
    pool = {"kinds": ["straight", "skidpad", "fishhook"]}
    cfg = safe_config(tmp_path, pool=pool, tracking={"enabled": False})
    campaign = Campaign(cfg, tmp_path / "c")
    whole = campaign.pool([])
    state = CampaignState(config_hash(cfg), cfg.strategy, cfg.seed)
    pool, admitted = campaign.admit(state, whole, None, 0)  # before any model: the kinematic worst case
    safe = admitted.safe
    cut = np.flatnonzero(safe.cut)
    assert len(cut) and np.array_equal(pool.affordable, safe.admissible)
    for i in cut:
        rows = rows_per_maneuver(safe.duration[i], cfg.simulation, cfg.data)
        assert pool.weights[pool.owner == i].sum() == pytest.approx(rows)
        assert whole.weights[whole.owner == i].sum() > rows + 1
        m = campaign.maneuvers[i]
        driven = dataclasses.replace(m, duration=safe.duration[i])
        reached = np.abs(maneuver_controls(driven, rate_hz=30.0)[:, 1]).max()
        assert np.abs(pool.points[pool.owner == i, 1]).max() == pytest.approx(reached, abs=1e-6)
    hook = [i for i in cut if campaign.maneuvers[i].kind == "fishhook"]
    assert hook
    steering = [np.abs(p.points[p.owner == hook[0], 1]).max() for p in (pool, whole)]
    assert steering[0] < steering[1] - 0.005  # the ramp, cut, stops short of where it would have gone
    kept = np.flatnonzero(~safe.cut)
    same = pool.points[np.isin(pool.owner, kept)], whole.points[np.isin(whole.owner, kept)]
    np.testing.assert_array_equal(*same)
    # what [safety] withholds (safe_expander's target): a refused candidate's points whole, a cut one's
    # by the share of its seconds after the cut, nothing of one admitted whole
    withheld = 1.0 - safe.duration / safe.full
    expected = sum(whole.weights[whole.owner == i].sum() * withheld[i] for i in range(len(withheld)))
    held = withhold(whole, safe)
    assert (~safe.admissible).any() and held.weights.sum() == pytest.approx(expected)
    assert len(held.points) == np.isin(whole.owner, np.flatnonzero(withheld > 1e-9)).sum()


def test_every_strategy_picks_among_admissible_candidates_only(tmp_path):
    # a 2 x 2 m arena: part of the pool is not admissible, part only when cut short
    cfg = safe_config(tmp_path, {"arena": [[-1, -1], [1, -1], [1, 1], [-1, 1]]}, tracking={"enabled": False})
    campaign = Campaign(cfg, tmp_path / "c")
    model = build_model(cfg.model)
    test = campaign.test_set
    fit(model, TrainingData(test.x, test.y_noisy, groups=test.groups), cfg.training, seed=0)
    state = CampaignState(config_hash(cfg), cfg.strategy, cfg.seed)
    pool, admitted = campaign.admit(state, campaign.pool([], model), model, 1)
    safe = admitted.safe
    admissible = set(np.flatnonzero(safe.admissible).tolist())
    assert 2 <= len(admissible) < len(campaign.maneuvers) and safe.cut.any()
    assert set(pool.available.tolist()) == admissible
    for name in ("grid", "random", "sobol", "lhs", "uniform", "max_epistemic", "max_total", "bald",
                 "epistemic_maximin", "integrated_variance", "safe_expander", "auto"):  # fmt: skip
        picks = make_strategy(name, n_samples=16).select(model, pool, 2, np.random.default_rng(0))
        assert set(picks) <= admissible, name


def test_unconstrained_campaign_counts_its_violations(tmp_path):
    # a 1.2 x 1.2 m arena: 20-s skidpads and straights leave it; enforce = false picks them anyway
    small = [[-0.6, -0.6], [0.6, -0.6], [0.6, 0.6], [-0.6, 0.6]]
    cfg = safe_config(tmp_path, {"arena": small, "enforce": False}, strategy="uniform",
                      design={"initial": 3, "per_round": 2, "max_maneuvers": 3})  # fmt: skip
    result = Campaign(cfg, tmp_path / "c").run(figures=False, log_model=False)
    assert not result.state.cuts  # nothing cut: the strategy drives what it picked
    assert result.history["violations_total"].iloc[-1] >= 1
    assert set(result.state.violated.values()) <= {"", "arena", "speed", "yaw_rate", "lateral"}


@pytest.mark.slow
def test_nothing_admissible_stops_cleanly_and_resumes_with_a_relaxed_arena(tmp_path):
    out = tmp_path / "c"
    tight = tmp_path / "tight.toml"
    base = SMOKE.read_text().replace('strategy = "max_epistemic"', 'strategy = "uniform"')
    tracking = "\n[tracking]\nenabled = false\n"
    # 0.8 m from the walls, 19-s minimum: before any model no candidate can be driven that long
    arena = [[-0.8, -0.8], [0.8, -0.8], [0.8, 0.8], [-0.8, 0.8]]
    tight.write_text(base + tracking + f"\n[safety]\narena = {arena}\nmin_duration = 19.0\n")
    done = _cli("campaign", "propose", str(tight), "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert "no candidate is admissible" in done.stdout and "--resume" in done.stdout
    state = CampaignState.load(out)
    assert state.finished and state.stop_reason == "nothing_admissible" and state.pending is None
    # the person widens the arena and lowers the minimum: the same directory continues
    wide = tmp_path / "wide.toml"
    wide.write_text(base + tracking + f"\n[safety]\narena = {SQUARE}\nmin_duration = 3.0\n")
    plot = str(tmp_path / "p.png")
    done = _cli("campaign", "propose", str(wide), "--out", str(out), "--resume", "--plot", plot)
    assert done.returncode == 0, done.stderr
    assert "drive these 3 maneuvers" in done.stdout and "risk" in done.stdout
    state = CampaignState.load(out)
    assert not state.finished and len(state.pending) == 3
    proposals = pd.read_csv(out / "proposals" / "round-000.csv")
    assert {"risk", "cut_from"} <= set(proposals.columns)
    assert (tmp_path / "p.png").stat().st_size > 10_000


@pytest.mark.slow
def test_plot_needs_an_arena(tmp_path):
    done = _cli("campaign", "propose", str(SMOKE), "--no-tracking", "--out", str(tmp_path / "o"),
                "--plot", str(tmp_path / "p.png"))  # fmt: skip
    assert done.returncode == 2 and "--plot" in done.stderr
    assert not (tmp_path / "o").exists()


def test_a_cut_proposal_is_driven_short_and_ingested(tmp_path, capsys):
    from activelearn.cli import main

    config = tmp_path / "car.toml"
    config.write_text(SMOKE.read_text().replace('strategy = "max_epistemic"', 'strategy = "uniform"')
                      + '\n[oracle]\nkind = "external"\n[tracking]\nenabled = false\n'
                      + f"[safety]\narena = {SQUARE}\nmin_duration = 3.0\nn_samples = 16\n")  # fmt: skip
    directory = tmp_path / "campaign"
    assert main(["campaign", "propose", str(config), "--out", str(directory)]) == 0
    assert "cut from 20 s" in capsys.readouterr().out
    proposals = pd.read_csv(directory / "proposals" / "round-000.csv")
    # before any model the kinematic worst case cuts every proposal, except a skidpad whose every
    # possible circle fits the arena: that one is driven whole
    cut = proposals["cut_from"].notna()
    assert cut.any() and (proposals.loc[cut, "duration"] < proposals.loc[cut, "cut_from"]).all()
    whole = proposals[~cut]
    assert (whole["maneuver"] == "skidpad").all() and (whole["duration"] == 20.0).all()
    logs = []
    for i, row in proposals.iterrows():
        out = tmp_path / f"log{i}.csv"
        assert main(["simulate", "--maneuver", row["maneuver"], "--direction", row["direction"],
                     "--throttle", str(row["throttle"]), "--steering", str(row["steering"]),
                     "--duration", str(row["duration"]), "--autodrive", "--out", str(out)]) == 0  # fmt: skip
        logs.append(str(out))
    assert main(["campaign", "ingest", str(directory), *logs]) == 0
    assert "[safety]" in capsys.readouterr().out
    state = CampaignState.load(directory)
    assert len(state.batches) == 1 and len(state.rounds) == 1 and state.violated
    assert all(reason == "" for reason in state.violated.values())


def test_a_log_ended_by_a_live_stop_is_ingested(tmp_path, capsys):
    # At the track the driver brakes near a wall: the log is shorter than the proposal and still matches.
    from activelearn.cli import main
    from activelearn.loop.asktell import read_log

    config = tmp_path / "car.toml"
    config.write_text(SMOKE.read_text().replace('strategy = "max_epistemic"', 'strategy = "uniform"')
                      + '\n[oracle]\nkind = "external"\n[tracking]\nenabled = false\n'
                      + f"[safety]\narena = {SQUARE}\nmin_duration = 3.0\nn_samples = 16\n"
                      + 'stop = "live"\n')  # fmt: skip
    directory = tmp_path / "campaign"
    assert main(["campaign", "propose", str(config), "--out", str(directory)]) == 0
    capsys.readouterr()
    proposals = pd.read_csv(directory / "proposals" / "round-000.csv")
    assert (proposals["brake_within_m"] > 0.16).all()
    safety = load_config(config).safety
    logs, short = [], 0
    for i, row in proposals.iterrows():
        out = tmp_path / f"log{i}.csv"
        assert main(["simulate", "--maneuver", row["maneuver"], "--direction", row["direction"],
                     "--throttle", str(row["throttle"]), "--steering", str(row["steering"]),
                     "--duration", str(row["duration"]), "--autodrive", "--out", str(out)]) == 0  # fmt: skip
        full = read_log(out).table  # the AutoDRIVE CSV in the simulator's columns
        stopped = live_stop(full, safety)
        short += len(stopped) < len(full)
        stopped.to_parquet(out.with_suffix(".parquet"), index=False)
        logs.append(str(out.with_suffix(".parquet")))
    assert short, "some proposal meets a wall of the 3 x 3 m arena"
    assert main(["campaign", "ingest", str(directory), *logs]) == 0
    state = CampaignState.load(directory)
    assert len(state.batches) == 1 and len(state.rounds) == 1
    assert all(reason == "" for reason in state.violated.values())
