"""Why does Nigel's dynamic core miss (0.26 m against the kinematic core's 0.030 after a campaign), and
does a kinematic blend that is the kinematic core close the gap? A pilot for issue 56's "no regression
on Nigel" (the cores alone, no correction, no fans).

Nigel's whole range (top speed 0.27 m/s) sits below the dynamic core's blend speed (0.59 m/s), where
each substep pulls v_y and r to the kinematic turn. There the slip angles are 0, so the tyres give no
force, and v_x keeps the body frame's v_y r = l_r r² that, in the truth, the front tyre's drag
(F_yf sin δ) cancels; and the kinematic branch has neither the kinematic core's understeer nor its
scrub. Variants, each identified from the same logs as the model identifies (restarts every 3 s, every
3rd step, the implicit step):

- K: the kinematic core (`identify_from_logs`), Nigel's model core today;
- D0: the dynamic core today (`identify_dynamic`, five scales);
- D1: D0 with v_x's dynamic terms (−F_yf sin δ / m + v_y r) weighted by the blend's w;
- D2: D1 with the kinematic core's understeer (r = v_x tan δ / (L u)) and scrub (a drag
  s tan² δ v_x / T_v, whose steady state is the kinematic core's v / (1 + s tan² δ)) in the kinematic
  branch, identified with the five (seven scales);
- D3: D2 with the kinematic core's yaw lag (r follows r_kin with the lag T_w); D4: D3 with a scale of
  the drive's time constant; D5: D3 with a second understeer for v_x < 0;
- K8: the kinematic core with a second understeer for v < 0 (session 39's eighth parameter), whole logs.

Per seed: `--signals` maneuvers drawn at random from the config's pool, answered by its truth with
sensor noise; the 30-s error of the CG's path on the config's test set. Pre-registration:
`experiments/results/nigel_blend.txt`.

Usage: python experiments/investigations/nigel_blend.py [--seeds 0-4] [--signals 16]
       [--configs dynamics,dynamics_twin] [--variants K,D0,D1,D2] [--horizon S]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_vehicle_baselines import _kinematic_paths, log_controls

from activelearn.config import load_config
from activelearn.loop.campaign import Campaign
from activelearn.loop.collection import control_rate_logs
from activelearn.numerics.models import dynamic_track as dt_
from activelearn.numerics.models.dynamic_fit import identify_dynamic
from activelearn.numerics.models.dynamic_physics import IDENTIFICATION
from activelearn.numerics.models.dynamic_scales import dynamic_bounds, scaled
from activelearn.numerics.models.single_track import (
    Identified,
    _map_fit,
    car_prior,
    identify_from_logs,
    run_single_track,
    single_track_step,
    stacked_logs,
    usable_logs,
)
from activelearn.replay import relative_pose
from simulator.vehicles import GRAVITY

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
# The kinematic branch's parameters beyond the dynamic core's five: (nominal, low, high, prior width), the
# kinematic core's priors for Nigel (single_track.car_parameters); the understeer in reverse its forward one's
EXTRA = {
    "understeer": (1.0, 0.7, 2.0, 0.5),
    "scrub": (0.0, 0.0, 3.0, 1.0),
    "yaw_lag": (0.05, 0.005, 1.0, 0.2),  # s
    "speed_lag": (1.0, 0.1, 10.0, 2.0),  # scale of the drive's time constant
    "reverse_understeer": (1.0, 0.7, 2.0, 0.5),
}
# each dynamic variant: whether v_x's dynamic terms are weighted by the blend, and its extra parameters
VARIANTS = {
    "D0": (False, ()),
    "D1": (True, ()),
    "D2": (True, ("understeer", "scrub")),
    "D3": (True, ("understeer", "scrub", "yaw_lag")),
    "D4": (True, ("understeer", "scrub", "yaw_lag", "speed_lag")),
    "D5": (True, ("understeer", "scrub", "yaw_lag", "reverse_understeer")),
}


@dataclasses.dataclass(frozen=True)
class Blend:
    """The kinematic branch's figures (numbers, or (P, 1) arrays of parameter sets)."""

    weighted: bool  # v_x's dynamic terms weighted by the blend's w
    understeer: object = 1.0
    scrub: object = 0.0
    yaw_lag: object = None  # s: r follows r_kin with this lag (None: at once)
    speed_lag: object = None  # scale of the drive's time constant (None: the file's)
    reverse_understeer: object = None  # the understeer at v_x < 0 (None: the one understeer)


def speed_lag(car: dt_.DynamicCar) -> float:
    """The drivetrain's time constant: the table's lag, or the motor law's v_top / a_max."""
    if car.max_acceleration is not None and car.top_speed is not None:
        return car.top_speed / car.max_acceleration
    return car.speed_time_constant


def step(car: dt_.DynamicCar, blend: Blend, state, throttle, steering, dt: float, substeps: int):
    """`dynamic_track.dynamic_step` (implicit, one track, no combined slip) with the blend's variants."""
    n, h = substeps, dt / substeps
    vx, vy, r, delta = (state[..., i] for i in range(4))
    m, L = car.mass, car.wheelbase
    static_f, static_r = car.static_loads
    target = np.clip(steering, -car.steering_limit, car.steering_limit)
    if blend.speed_lag is not None:
        car = dataclasses.replace(car, speed_time_constant=car.speed_time_constant * blend.speed_lag)
    lag, blend_speed = speed_lag(car), car.blend_speed
    follow = 1.0 if blend.yaw_lag is None else -np.expm1(-h / blend.yaw_lag)
    for _ in range(n):
        delta = delta + np.clip(target - delta, -car.steering_rate * h, car.steering_rate * h)
        r_prev = r
        a = dt_._acceleration(car, throttle, vx, h)
        load_f = np.maximum(m * (GRAVITY * car.lr - a * car.cg_height) / L, 0.0)
        load_r = np.maximum(m * (GRAVITY * car.lf + a * car.cg_height) / L, 0.0)
        cos, sin = np.cos(delta), np.sin(delta)
        alpha_f, alpha_r = dt_._slip_angles(car, vx, vy, r, (cos, sin))
        f_f = dt_._lateral_force(car, alpha_f, load_f, static_f, car.stiffness_front)
        f_r = dt_._lateral_force(car, alpha_r, load_r, static_r, car.stiffness_rear)
        room = np.sqrt(np.maximum((car.friction * load_r) ** 2 - (m * a * car.rear_drive_share) ** 2, 0.0))
        f_r = np.clip(f_r, -room, room)
        dvy = (f_f * cos + f_r) / m
        dr = (car.lf * f_f * cos - car.lr * f_r) / car.yaw_inertia
        speed = np.maximum(np.abs(vx), 0.5 * blend_speed)
        c_f, c_r = car.stiffness_front * load_f / static_f, car.stiffness_rear * load_r / static_r
        x_lat = h * (c_f + c_r) / (m * speed)
        x_yaw = h * (car.lf**2 * c_f + car.lr**2 * c_r) / (car.yaw_inertia * speed)
        w_now = 0.5 * (1.0 + np.tanh((np.abs(vx) - blend_speed) / (0.25 * blend_speed)))
        vy = vy + h * (dvy - vx * r) * dt_._relaxed(x_lat)
        dynamic_x = -f_f * sin / m + vy * r
        if blend.weighted:
            drag = blend.scrub * np.tan(delta) ** 2 * vx / lag
            vx = vx + h * (a + w_now * dynamic_x - (1.0 - w_now) * drag)
        else:
            vx = vx + h * (a + dynamic_x)
        r = r + h * dr * dt_._relaxed(x_yaw)
        w = 0.5 * (1.0 + np.tanh((np.abs(vx) - blend_speed) / (0.25 * blend_speed)))
        understeer = blend.understeer
        if blend.reverse_understeer is not None:
            understeer = np.where(vx >= 0.0, blend.understeer, blend.reverse_understeer)
        r_kin = r_prev + follow * (vx * np.tan(delta) / (L * understeer) - r_prev)
        vy, r = w * vy + (1.0 - w) * car.lr * r_kin, w * r + (1.0 - w) * r_kin
    return np.stack(np.broadcast_arrays(vx, vy, r, delta), axis=-1)


def runs(car, blend: Blend, controls: np.ndarray, start: np.ndarray, dt: float) -> np.ndarray:
    """(..., M, T, 5) = (v_x, v_y, r, x, y) free runs of controls (M, T, 2) from start (..., M, 4)."""
    substeps = car.implicit_substeps(dt)
    state = np.asarray(start, np.float64)
    x = y = heading = np.zeros(state.shape[:-1])
    out = [np.concatenate([state[..., :3], np.stack([x, y], -1)], -1)]
    for k in range(1, controls.shape[1]):
        nxt = step(car, blend, state, controls[:, k - 1, 0], controls[:, k - 1, 1], dt, substeps)
        mid = heading + 0.25 * dt * (state[..., 2] + nxt[..., 2])
        vx, vy = 0.5 * (state[..., 0] + nxt[..., 0]), 0.5 * (state[..., 1] + nxt[..., 1])
        x = x + dt * (vx * np.cos(mid) - vy * np.sin(mid))
        y = y + dt * (vx * np.sin(mid) + vy * np.cos(mid))
        heading = heading + 0.5 * dt * (state[..., 2] + nxt[..., 2])
        state = nxt
        out.append(np.concatenate([state[..., :3], np.stack([x, y], -1)], -1))
    return np.stack(out, axis=-2)


def cars_of(car: dt_.DynamicCar, sets: np.ndarray, variant: str) -> tuple[dt_.DynamicCar, Blend]:
    """The car and its kinematic branch at parameter sets (P, 5 + the variant's extra)."""
    sets = np.atleast_2d(sets)
    weighted, extra = VARIANTS[variant]
    figures = {name: sets[:, 5 + i : 6 + i] for i, name in enumerate(extra)}
    return scaled(car, sets[:, :5]), Blend(weighted, **figures)


def identify(logs, car: dt_.DynamicCar, dt: float, variant: str, horizon: float | None = None) -> np.ndarray:
    """The variant's scales from logs, as `identify_dynamic` with the model's settings (`horizon`: its
    restarts, default the model's)."""
    if variant == "D0":
        return identify_dynamic(logs, car, dt, **IDENTIFICATION).values
    logs = usable_logs(logs)
    every, horizon = IDENTIFICATION["every"], horizon or IDENTIFICATION["horizon"]
    steps = max(2, round(horizon / dt))
    cut = [(i, u[k : k + steps + 1], y[k : k + steps + 1], u[max(k - 1, 0), 1])
           for i, (u, y) in enumerate(logs) for k in range(0, len(u) - 1, steps)]  # fmt: skip
    cut = [piece for piece in cut if len(piece[1]) > 1]
    owners, wheels = [i for i, *_ in cut], np.array([wheel for *_, wheel in cut])
    controls, rates, valid, keep = stacked_logs([(u, y) for _, u, y, _ in cut], every)
    v, r = rates[:, 0, 0], rates[:, 0, 1]

    def errors_of(sets: np.ndarray) -> np.ndarray:
        cars, blend = cars_of(car, sets, variant)
        lateral = dt_.quasi_static_lateral(cars, v, r)
        start = np.stack(np.broadcast_arrays(v, lateral, r, wheels), axis=-1)
        predicted = runs(cars, blend, controls, start, dt)[..., [0, 2]]
        return np.nan_to_num(predicted - rates, nan=1e3, posinf=1e3, neginf=-1e3)[:, keep]

    base = dynamic_bounds()
    extra = np.array([EXTRA[name] for name in VARIANTS[variant][1]]).reshape(-1, 4)
    nominal, width = np.r_[base.prior.values, extra[:, 0]], np.r_[base.width, extra[:, 3]]
    bounds = SimpleNamespace(low=np.r_[base.low, extra[:, 1]], high=np.r_[base.high, extra[:, 2]],
                             width=width, prior=Identified(nominal, np.diag(width**2)))  # fmt: skip
    clusters = np.asarray(owners)[np.nonzero(keep)[0]]
    return _map_fit(errors_of, rates[valid].std(axis=0), clusters, bounds.prior, None, bounds).values


def kinematic_runs(controls: np.ndarray, start: np.ndarray, sets: np.ndarray, dt: float, prior) -> np.ndarray:
    """K8's free runs: the kinematic core (`single_track_step`) with its understeer taken from the eighth
    parameter where v < 0 (session 39's what-if), rates (P, M, T, 2)."""
    sets = np.atleast_2d(sets)
    v = np.broadcast_to(start[:, 0], (len(sets), len(start))).copy()
    w = np.broadcast_to(start[:, 1], v.shape).copy()
    out = [np.stack([v, w], -1)]
    for k in range(1, controls.shape[1]):
        theta = np.broadcast_to(sets[:, None, :7], (*v.shape, 7)).copy()
        theta[..., 4] = np.where(v >= 0.0, sets[:, None, 4], sets[:, None, 7])
        v, w = single_track_step(controls[:, k - 1, 0], controls[:, k - 1, 1], v, w, theta, dt, car=prior)
        out.append(np.stack([v, w], -1))
    return np.stack(out, axis=-2)


def identify_k8(logs, prior, dt: float) -> np.ndarray:
    """K8's eight parameters from whole logs (`identify_from_logs`' fit, every step compared)."""
    controls, rates, valid, keep = stacked_logs(usable_logs(logs), 1)

    def errors_of(sets: np.ndarray) -> np.ndarray:
        return (kinematic_runs(controls, rates[:, 0], sets, dt, prior) - rates)[:, keep]

    u = prior.parameters[4]
    nominal, width = np.r_[prior.nominal, u.nominal], np.r_[prior.width, u.width]
    bounds = SimpleNamespace(low=np.r_[prior.low, u.low], high=np.r_[prior.high, u.high], width=width,
                             prior=Identified(nominal, np.diag(width**2)))  # fmt: skip
    clusters = np.nonzero(keep)[0]  # each log a cluster, as identify_from_logs
    return _map_fit(errors_of, rates[valid].std(axis=0), clusters, bounds.prior, None, bounds).values


def test_error(campaign: Campaign, variant: str, found: np.ndarray, car: dt_.DynamicCar) -> np.ndarray:
    """The 30-s error of the CG's path on each test maneuver."""
    test, cfg = campaign.evaluation.test_set, campaign.cfg
    controls, start = log_controls(test)
    dt = 1.0 / cfg.simulation.rate_hz
    k = min(round(30.0 / dt), controls.shape[1] - 1)
    columns = ("posX", "posY", "yaw")
    truth = np.array([relative_pose({c: t[c].to_numpy(np.float64) for c in columns}, k + 1)[:2]
                      for t in test.truth_logs])[:, :, k]  # fmt: skip
    if variant in ("K", "K8"):
        prior = car_prior(cfg.vehicle.spec)
        if variant == "K":
            rates = run_single_track(controls, start[:, [0, 2]], found[None], dt, prior)[0]
        else:
            rates = kinematic_runs(controls, start[:, [0, 2]], found, dt, prior)[0]
        path = _kinematic_paths(rates, cfg.vehicle.spec.geometry.lr.value, dt)[:, k]
    else:
        cars, blend = cars_of(car, found, variant)
        path = runs(cars, blend, controls, start[None], dt)[0, :, k, 3:5]
    return np.nan_to_num(np.hypot(*(path - truth).T), nan=np.inf)


def seeds_of(text: str) -> list[int]:
    first, _, last = text.partition("-")
    return list(range(int(first), int(last or first) + 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-4")
    parser.add_argument("--signals", type=int, default=16)
    parser.add_argument("--configs", default="dynamics,dynamics_twin")
    parser.add_argument("--variants", default="K,D0,D1,D2")
    parser.add_argument("--out", default="runs/nigel_blend")
    parser.add_argument("--horizon", type=float, default=None, help="restarts every S s (the model's: 3)")
    args = parser.parse_args()
    variants = args.variants.split(",")
    rows = []
    for name in args.configs.split(","):
        cfg = load_config(CONFIGS / f"{name}.toml")
        campaign = Campaign(cfg, Path(args.out).resolve() / name)
        car = dt_.DynamicCar.of(cfg.vehicle.spec)
        dt = 1.0 / cfg.simulation.rate_hz
        candidates = campaign.oracle.candidates()
        for seed in seeds_of(args.seeds):
            rng = np.random.default_rng(seed)
            chosen = sorted(rng.choice(len(candidates), args.signals, replace=False))
            logs = control_rate_logs(campaign.oracle.answer([candidates[i] for i in chosen], seed))
            row: dict[str, object] = {"config": name, "seed": seed}
            for variant in variants:
                started = time.perf_counter()
                if variant == "K":
                    found = identify_from_logs(logs, car=car_prior(cfg.vehicle.spec)).values
                elif variant == "K8":
                    found = identify_k8(logs, car_prior(cfg.vehicle.spec), dt)
                else:
                    found = identify(logs, car, dt, variant, args.horizon)
                row[variant] = float(test_error(campaign, variant, found, car).mean())
                row[f"{variant} s"] = round(time.perf_counter() - started, 1)
                if variant != "K":
                    row[f"{variant} scales"] = " ".join(f"{v:.2f}" for v in found)
            rows.append(row)
            print(" ".join(f"{k}={v:.4f}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()),
                  flush=True)
    frame = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    print(f"\n## {args.signals} random signals a seed: the identified cores' mean 30-s test error (m)")
    print(frame.to_string(index=False, float_format=lambda x: f"{x:.4f}"))
    print("\n## means over seeds, and each dynamic variant over K")
    means = frame.groupby("config")[variants].mean()
    for variant in variants[1:]:
        means[f"{variant}/K"] = means[variant] / means["K"]
    print(means.to_string(float_format=lambda x: f"{x:.4f}"))


if __name__ == "__main__":
    main()
