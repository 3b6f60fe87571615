"""[safety] stop = "live" driven closed-loop in MuJoCo (issue 35 points 4 and 5).

The car brakes (throttle 0) once its pose comes within `margin + stop_buffer` of a wall and the log
runs on until it stands, so the violations count the braking too. Real MuJoCo and real campaigns on
the smoke pool with straights.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from activelearn.config import SafetyConfig, SimulationConfig, load_config, polygon_clearance, validate_config
from activelearn.config.safety import braking_distance, car_braking, settle_seconds
from activelearn.errors import ConfigError
from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import SimulationCache
from activelearn.loop.safety.limits import log_violation, placed_path, violations
from activelearn.loop.safety.live_stop import braked_paths, live_stop, stop_rule
from activelearn.loop.state import STATE_FILE, CampaignState
from simulator import Maneuver, NoiseConfig, StopRule, build_vehicle, collect, load_vehicle, twin_vehicle

SMOKE = Path(__file__).resolve().parents[1] / "experiments" / "configs" / "smoke.toml"
SQUARE = [[-1.5, -1.5], [1.5, -1.5], [1.5, 1.5], [-1.5, 1.5]]
SMALL = [[-0.6, -0.6], [0.6, -0.6], [0.6, 0.6], [-0.6, 0.6]]
# experiments/configs/safe_track.toml's arena (4.75 x 5 m) halved about its start [0.775, 2.15]
HALF_TRACK = [[-0.4125, 0.9], [1.9625, 0.9], [1.9625, 3.4], [-0.4125, 3.4]]
STRAIGHT = Maneuver("straight", 1.0, 0.0, "ccw", 20.0)  # top speed (0.267 m/s) after ~1 s


def live_config(**update) -> SafetyConfig:
    return SafetyConfig(arena=SQUARE, stop="live", min_duration=3.0, **update)


def campaign_config(tmp_path: Path, safety: dict, **overrides):
    data = {
        "output_dir": str(tmp_path / "runs"),
        "tracking": {"enabled": False},
        "strategy": "uniform",
        "pool": {"kinds": ["straight", "skidpad"]},
        "training": {"epochs": 25},
        "design": {"initial": 3, "per_round": 2, "max_maneuvers": 3},
        "safety": {"arena": SQUARE, "start": [0.0, 0.0, 0.0], "min_duration": 3.0, "n_samples": 16, **safety},
        **overrides,
    }
    return load_config(SMOKE, overrides=data)


def trigger_row(log: pd.DataFrame) -> int:
    """The row whose pose triggered the stop: the last before the throttle first becomes 0."""
    braked = np.flatnonzero(log["throttle"].to_numpy() == 0.0)
    assert len(braked), "the stop never triggered"
    return int(braked[0]) - 1


def clearance_at_end(log: pd.DataFrame, cfg: SafetyConfig) -> float:
    x, y = placed_path(log, cfg)
    return float(StopRule(tuple(map(tuple, cfg.arena))).clearance(x[-1:], y[-1:])[0])


# --------------------------------------------------------------------------------- the simulator


def test_a_live_stop_brakes_in_mujoco_until_the_car_stands():
    live = live_config()
    rule = stop_rule(live)
    assert rule is not None and rule.distance == pytest.approx(live.margin + live.stop_buffer)
    free = collect(STRAIGHT, noise=None)
    log = collect(STRAIGHT, noise=None, stop=rule)
    cut = live_stop(free, live)  # what the log was before: cut at the trigger, no braking in it
    j = trigger_row(log)
    assert len(cut) == j and len(log) > len(cut) + 2
    # until the trigger, the run is the free run's; then throttle 0 (the brake) to the end
    pd.testing.assert_frame_equal(log.iloc[: j + 1], free.iloc[: j + 1])
    assert (log["throttle"].iloc[: j + 1] == 1.0).all() and (log["throttle"].iloc[j + 1 :] == 0.0).all()
    speed = log["speed"].to_numpy()
    assert speed[j] > 0.25 and abs(speed[-1]) < rule.still_speed  # from top speed to standing
    assert (np.abs(speed[-3:-1]) >= rule.still_speed).all()  # and the log ends where it stands
    # the car ends outside the margin: no violation, braking included; the free run left the arena
    assert log_violation(log, live, 30.0) == "" and log_violation(free, live, 30.0) == "arena"
    travel = log["posX"].iloc[-1] - log["posX"].iloc[j]
    assert 0.015 < travel < live.stop_buffer  # 2.4 cm from top speed (one 30-Hz pose late, then braking)
    assert travel <= braking_distance(speed[j], 1.9)
    assert live.margin < clearance_at_end(log, live) < live.margin + live.stop_buffer
    # deterministic, and the noise never feeds the stop: noisy and clean logs share one trajectory
    pd.testing.assert_frame_equal(collect(STRAIGHT, noise=None, stop=rule), log)
    noisy = collect(STRAIGHT, noise=NoiseConfig(), seed=3, stop=rule)
    assert len(noisy) == len(log) and np.array_equal(noisy["throttle"], log["throttle"])
    # a maneuver that ends while braking runs on past its end until the car stands
    short = Maneuver("straight", 1.0, 0.0, "ccw", 5.0)  # 151 rows; the stop triggers at row 148
    ended = collect(short, noise=None, stop=rule)
    assert len(ended) > 151 and abs(ended["speed"].iloc[-1]) < rule.still_speed
    # a run that never comes near a wall is simulated as without the stop
    inside = Maneuver("skidpad", 0.3, 0.5236, "ccw", 10.0)
    pd.testing.assert_frame_equal(collect(inside, noise=None, stop=rule), collect(inside, noise=None))


def test_the_stop_holds_wherever_the_trigger_falls_in_a_batch():
    # Triggers on either side of a 2-s chunk boundary, several maneuvers and threads at once.
    free = collect(STRAIGHT, noise=None)
    base = StopRule(tuple(map(tuple, SQUARE)))
    x, y = base.placed(free["posX"], free["posY"], free["yaw"], (0.0, 0.0, 0.0))
    clearance = base.clearance(x, y)
    for row in (59, 60, 119):
        rule = StopRule(base.polygon, distance=0.5 * (clearance[row] + clearance[row - 1]))
        log = collect(STRAIGHT, noise=None, stop=rule)
        assert trigger_row(log) == row
        pd.testing.assert_frame_equal(log.iloc[: row + 1], free.iloc[: row + 1])
    batch = [STRAIGHT, Maneuver("straight", -1.0, 0.0, "ccw", 20.0),
             Maneuver("skidpad", 1.0, 0.3, "ccw", 20.0), Maneuver("eight", 0.8, 0.4, "cw", 30.0)]  # fmt: skip
    rule = StopRule(tuple(map(tuple, SMALL)), distance=0.21)
    together = collect(batch, noise=None, stop=rule, threads=2)
    pd.testing.assert_frame_equal(together, collect(batch, noise=None, stop=rule, threads=1))
    for m, (_, part) in zip(batch, together.groupby("run_id", sort=False), strict=True):
        alone = collect(m, noise=None, stop=rule)
        np.testing.assert_array_equal(part["posX"].to_numpy(), alone["posX"].to_numpy())
        trigger_row(part)
        assert abs(part["speed"].iloc[-1]) < rule.still_speed
        x, y = rule.placed(part["posX"], part["posY"], part["yaw"], (0.0, 0.0, 0.0))
        assert rule.clearance(x, y).min() > 0.16, m.name


def test_a_stop_buffer_the_car_cannot_stop_in_is_refused_or_counted():
    # At config time: below the braking distance from max_speed, one error naming the field.
    with pytest.raises(ConfigError) as info:
        validate_config({"safety": {"arena": SQUARE, "stop": "live", "stop_buffer": 0.02}})
    assert str(info.value).startswith("safety.stop_buffer") and "0.034 m" in str(info.value)
    assert braking_distance(0.3, 1.9) == pytest.approx(0.0337, abs=1e-4)
    validate_config({"safety": {"arena": SQUARE, "stop": "live", "stop_buffer": 0.02, "max_speed": 0.1}})
    validate_config({"safety": {"arena": SQUARE, "stop": "planned", "stop_buffer": 0.0}})  # unused
    # Where it gets through (a config built without validation, a car slower to stop than the model
    # assumes), the closed loop shows it: the braking ends within the margin, an arena violation.
    live = live_config()
    tiny = live.model_copy(update={"stop_buffer": 0.0})
    log = collect(STRAIGHT, noise=None, stop=stop_rule(tiny))
    assert clearance_at_end(log, live) < live.margin
    assert log_violation(log, tiny, 30.0) == "arena"
    assert violations(log.assign(pool_index=7), tiny, 30.0) == {7: "arena"}
    # a twin with 0.1 s of actuation latency needs 5.1 cm from top speed: the default 5 cm is not enough
    late = collect(STRAIGHT, noise=None, stop=stop_rule(live), vehicle=twin_vehicle({"latency": 0.1}))
    assert log_violation(late, live, 30.0) == "arena"
    assert log_violation(collect(STRAIGHT, noise=None, stop=stop_rule(live)), live, 30.0) == ""


def test_stopped_logs_have_cache_entries_of_their_own(tmp_path):
    cache = SimulationCache(tmp_path, SimulationConfig())
    rule = stop_rule(live_config())
    stopped = cache.stopped(rule)
    other = cache.stopped(stop_rule(live_config(stop_buffer=0.08)))
    assert len({cache.root, stopped.root, other.root}) == 3 and cache.stopped(None).root == cache.root
    assert stopped.root == cache.stopped(stop_rule(live_config())).root  # keyed by the rule, stable
    plain, braked = cache.get([STRAIGHT])[0], stopped.get([STRAIGHT])[0]
    assert len(plain) == 601 and len(braked) < len(plain)
    assert len(cache.get([STRAIGHT])[0]) == 601 and stopped.get([STRAIGHT])[0].equals(braked)
    assert stop_rule(live_config(enforce=False)) is None and stop_rule(SafetyConfig(arena=SQUARE)) is None


# ------------------------------------------------------------------------------------- campaigns


def test_the_same_arena_and_seed_with_and_without_enforcement(tmp_path):
    # A 1.2 x 1.2 m arena: 20-s straights and skidpads leave it. Enforced, the live stop brakes every
    # one in time (0 violations); unconstrained, the same picks drive through the walls.
    counts = {}
    for enforce in (True, False):
        cfg = campaign_config(tmp_path / str(enforce), {"arena": SMALL, "stop": "live", "enforce": enforce})
        result = Campaign(cfg, tmp_path / str(enforce) / "c").run(figures=False, log_model=False)
        state = result.state
        assert len(state.taken) == 3 and len(state.violated) == 3
        counts[enforce] = int(result.history["violations_total"].iloc[-1])
        assert counts[enforce] == sum(1 for reason in state.violated.values() if reason)
        samples = pd.read_parquet(tmp_path / str(enforce) / "c" / "samples.parquet")
        braked = samples.groupby("pool_index")["throttle"].apply(lambda t: bool((t == 0).any()))
        assert braked.all() if enforce else not braked.any()
    assert counts == {True: 0, False: counts[False]} and counts[False] > 0


def test_a_tight_arena_triggers_the_stop_and_keeps_the_walls(tmp_path):
    # safe_track.toml's arena halved: the straights and fast skidpads meet its walls within 20 s.
    cfg = campaign_config(tmp_path, {"arena": HALF_TRACK, "start": [0.775, 2.15, 0.0], "stop": "live"},
                          design={"initial": 3, "per_round": 2, "max_maneuvers": 5})  # fmt: skip
    result = Campaign(cfg, tmp_path / "c").run(figures=False, log_model=False)
    state = result.state
    assert len(state.taken) == 5 and not state.cuts  # the walls cut nothing in advance
    assert all(reason == "" for reason in state.violated.values()) and len(state.violated) == 5
    assert result.history["violations_total"].iloc[-1] == 0
    samples = pd.read_parquet(tmp_path / "c" / "samples.parquet")
    stopped = 0
    for _, log in samples.groupby("pool_index"):
        if (log["throttle"] == 0).any():
            stopped += 1
            assert log["time"].max() < 19.0 and abs(log["speed"].iloc[-1]) < 0.02  # it stood (noisy speed)
            assert log_violation(log.reset_index(drop=True), cfg.safety, 30.0) == ""
    assert stopped >= 1, "some maneuver met a wall"


# ----------------------------------------------------------------------- [safety] on the command line

BAD_SAFETY = {
    "arena": ("arena = [[0, 0], [1, 1], [1, 0], [0, 1]]", "crosses itself"),
    "start": ("start = [2.0, 0.0, 0.0]", "outside"),
    "max_speed": ("max_speed = 0", "greater than 0"),
    "max_yaw_rate": ("max_yaw_rate = -1.0", "greater than 0"),
    "max_lateral_acceleration": ("max_lateral_acceleration = 0.0", "greater than 0"),
    "delta": ("delta = 1.0", "(0, 1)"),
    "margin": ("margin = -0.1", "greater than or equal to 0"),
    "path_tolerance": ("path_tolerance = -0.01", "greater than or equal to 0"),
    "min_duration": ("min_duration = 0", "greater than 0"),
    "n_samples": ("n_samples = 4", "greater than or equal to 8"),
    "fan_scale": ("fan_scale = 0.5", "greater than or equal to 1"),
    "trust_std": ("trust_std = 0", "greater than 0"),
    "trust_rates": ('trust_rates = ["speed", "lateral"]', "'speed' or 'yaw_rate'"),
    "limit_window": ("limit_window = -0.5", "greater than or equal to 0"),
    "measured_turn_speed": ('measured_turn_speed = "sometimes"', "boolean"),
    "stop": ('stop = "never"', "'planned' or 'live'"),
    "stop_buffer": ('stop = "live"\nstop_buffer = 0.01', "needs to stop"),
    "enforce": ('enforce = "sometimes"', "boolean"),
}


def test_every_safety_field_is_covered():
    assert set(BAD_SAFETY) == set(SafetyConfig.model_fields)


@pytest.mark.parametrize("field", sorted(BAD_SAFETY))
def test_a_bad_safety_value_on_the_command_line_is_one_line_exit_2_nothing_written(field, tmp_path, capsys):
    from activelearn.cli import main

    line, words = BAD_SAFETY[field]
    arena = "" if field == "arena" else f"arena = {SQUARE}\n"
    config = tmp_path / "bad.toml"
    config.write_text(SMOKE.read_text() + f"\n[safety]\n{arena}{line}\n")
    out = tmp_path / "out"
    assert main(["campaign", "run", str(config), "--no-tracking", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"safety.{field}" in err and words in err, err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


def test_a_comparison_simulates_the_pool_under_the_live_stop_before_its_workers(tmp_path):
    from activelearn.loop.collection import cache_root
    from activelearn.loop.oracles import SimulatorOracle
    from activelearn.studies.compare import compare

    cfg = campaign_config(tmp_path, {"arena": SMALL, "stop": "live"},
                          design={"initial": 2, "per_round": 1, "max_maneuvers": 2})  # fmt: skip
    result = compare(cfg, ["uniform"], [0], directory=tmp_path / "cmp", workers=1, tracking=False)
    assert len(result.table) >= 1
    oracle = SimulatorOracle(cfg, SimulationCache(cache_root(cfg), cfg.simulation))
    assert oracle.driven.root != oracle.cache.root and oracle.driven.stop == stop_rule(cfg.safety)
    assert oracle.driven.missing(oracle.candidates()) == []  # the whole pool, braked, in its own entries
    assert oracle.cache.missing(oracle.test_maneuvers()) == []  # the test set without the stop


# --- `campaign propose --plot` under the live stop (issue 35 point 6) --------------------------------


def test_braked_paths_end_each_sampled_path_where_the_car_would_brake():
    cfg = live_config()  # the 3 x 3 m square from the centre; brakes within 0.16 + 0.05 m of a wall
    t = np.linspace(0.0, 2.0, 201) + 0.005  # 1-cm steps, none on the brake line itself
    x = np.stack([t, 0.5 * t, np.zeros_like(t)])  # towards the wall at x = 1.5, half as far, standing
    y = np.zeros_like(x)
    cut_x, cut_y, trigger = braked_paths(x, y, cfg)
    line = 1.5 - cfg.margin - cfg.stop_buffer
    k = int(trigger[0])
    assert k > 0 and x[0, k - 1] <= line < x[0, k] <= line + 0.01  # the first point past the line
    assert np.isfinite(cut_x[0, : k + 1]).all() and np.isnan(cut_x[0, k + 1 :]).all()
    assert np.isnan(cut_y[0, k + 1 :]).all()
    assert (trigger[1:] == -1).all()  # 1 m and 0 m from the centre: never within the brake line
    np.testing.assert_array_equal(cut_x[1:], x[1:])


def test_propose_plot_draws_where_the_live_stop_brakes(tmp_path, monkeypatch):
    import activelearn.plots as plots
    from activelearn.loop.asktell import proposal_figure

    cfg = campaign_config(tmp_path, {"stop": "live", "arena": SMALL},
                          design={"initial": 2, "per_round": 2, "max_maneuvers": 4})  # fmt: skip
    campaign = Campaign(cfg, tmp_path / "c")
    assert campaign.propose(figures=False)  # the initial design: no model yet
    state = CampaignState.load(campaign.directory)
    logs = campaign.oracle.answer([campaign.driven(i, state) for i in state.pending], cfg.seed)
    assert campaign.tell(logs, figures=False)  # round 0's model judges the next batch
    drawn = {}
    arena_figure = plots.arena_figure

    def spy(*args, **kwargs):
        drawn.update(proposals=args[2], brake_line=kwargs.get("brake_line"), title=kwargs.get("title"))
        return arena_figure(*args, **kwargs)

    monkeypatch.setattr(plots, "arena_figure", spy)
    committed = (campaign.directory / STATE_FILE).read_bytes()
    path = proposal_figure(campaign, tmp_path / "p.png")
    assert (campaign.directory / STATE_FILE).read_bytes() == committed  # a figure draws, changes nothing
    assert path.stat().st_size > 10_000
    assert drawn["brake_line"] is not None and drawn["brake_line"][3] == pytest.approx(0.21)
    assert "live stop" in drawn["title"] and "limits only" in drawn["title"]
    proposals = [p for p in drawn["proposals"] if "x" in p]
    assert proposals, "a model judged the batch: its fans are drawn"
    safety = cfg.safety
    for proposal in proposals:
        x, y = proposal["x"], proposal["y"]
        # no drawn point lies past the brake line by more than one step of travel
        inside = polygon_clearance(safety.arena, np.nan_to_num(x, nan=0.0), np.nan_to_num(y, nan=0.0))
        assert inside.min() > safety.margin + safety.stop_buffer - 0.02
        assert len(proposal["brakes"][0]) <= proposal["n_paths"]
    # in the 1.2 x 1.2 m arena some fan reaches the brake line
    assert sum(len(p["brakes"][0]) for p in proposals) > 0


# --------------------------------------------------------------------------------- other cars


F1TENTH_ARENA = [[-5.0, -5.0], [60.0, -5.0], [60.0, 5.0], [-5.0, 5.0]]


def test_the_stop_buffer_is_checked_against_the_cars_own_braking(tmp_path):
    # The 1:10 car brakes at its grip (0.95 x 0.65 g = 6.06 m/s²): from 6 m/s it needs 0.2 + 2.97 m.
    spec = load_vehicle("f1tenth")
    assert car_braking(spec) == pytest.approx(0.95 * 0.65 * 9.81)
    assert car_braking(spec, {"tire_friction": 0.8}) == pytest.approx(0.8 * car_braking(spec))
    assert car_braking(spec, {"tire_friction": 1.5}) == car_braking(spec)  # a brake limit is not lifted
    assert car_braking(load_vehicle("nigel")) == 1.9  # the file's measured figure
    safety = {"arena": F1TENTH_ARENA, "stop": "live", "max_speed": 6.0, "margin": 0.3}
    base = {"vehicle": {"name": "f1tenth"}, "test": {"kinds": ["straight"]}}
    with pytest.raises(ConfigError) as info:
        validate_config({**base, "safety": {**safety, "stop_buffer": 3.0}})
    assert str(info.value).startswith("safety.stop_buffer") and "3.171 m" in str(info.value)
    assert "f1tenth" in str(info.value)
    validate_config({**base, "safety": {**safety, "stop_buffer": 3.2}})
    # on the twin with less grip it needs more room
    twin = {"oracle": {"kind": "twin", "overrides": {"tire_friction": 0.8}}}
    with pytest.raises(ConfigError, match=r"3\.914 m"):
        validate_config({**base, **twin, "safety": {**safety, "stop_buffer": 3.2}})
    assert settle_seconds(spec, car_braking(spec)) == pytest.approx(5.0)  # 20 m/s: 3.3 s to stand
    # a speed-table car whose file gives no braking cannot have a live stop checked: refused, named
    nigel = Path(load_vehicle("nigel").path).read_text()
    unbraked = tmp_path / "unbraked.toml"
    unbraked.write_text("\n".join(line for line in nigel.splitlines() if "stopping_deceleration" not in line)
                        .replace('"../assets/nigel.xml"', f'"{Path(load_vehicle("nigel").path).parent.parent}'
                                 '/assets/nigel.xml"'))
    assert load_vehicle(unbraked).stopping_deceleration is None
    with pytest.raises(ConfigError, match="gives no braking") as info:
        validate_config({"vehicle": {"name": str(unbraked)}, "safety": {"arena": SQUARE, "stop": "live"}})
    assert info.value.field == "safety.stop_buffer"
    validate_config({"vehicle": {"name": str(unbraked)}, "safety": {"arena": SQUARE}})  # planned: fine
    assert settle_seconds(load_vehicle("nigel"), 1.9) == 1.0  # Nigel's stop rule (and cache key) as before


def test_a_fast_car_brakes_until_it_stands_within_its_braking_distance():
    # MuJoCo's 1:10 car at 10 m/s, the stop triggered as the maneuver ends: it brakes for 1.6 s, longer
    # than Nigel's one-second settle, and stands inside the arena within the braking distance the
    # config is checked with.
    spec = load_vehicle("f1tenth")
    arena = [[-15.0, -15.0], [109.8, -15.0], [109.8, 15.0], [-15.0, 15.0]]  # the trigger at x = 100 m
    live = SafetyConfig(arena=arena, stop="live", max_speed=10.5, margin=0.3, stop_buffer=9.5)
    rule = stop_rule(live, settle_seconds(spec, car_braking(spec)))
    assert rule is not None and rule.settle == pytest.approx(5.0)
    straight = Maneuver("straight", 0.5, 0.0, "ccw", 12.1)  # 9.97 m/s at 99 m after 12 s
    vehicle = build_vehicle(spec)
    log = collect(straight, noise=None, stop=rule, vehicle=vehicle)
    j = trigger_row(log)
    speed = log["speed"].to_numpy()
    assert j >= 360 and speed[j] > 9.9 and abs(speed[-1]) < rule.still_speed
    travel = log["posX"].iloc[-1] - log["posX"].iloc[j]
    assert 7.5 < travel <= braking_distance(speed[j], car_braking(spec), 1.0 / 30.0)
    assert log_violation(log, live, 30.0) == ""
    # Nigel's one-second settle would have ended the log while the car still ran at about 4 m/s
    short = collect(straight, noise=None, stop=stop_rule(live), vehicle=vehicle)
    assert abs(short["speed"].iloc[-1]) > 3.0
