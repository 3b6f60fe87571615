"""The three cars' handling diagrams: steady yaw rate and lateral acceleration against steering.

For each shipped car, steady turns (skidpads, ccw) at the forward throttles of its cold-start dynamics
config's test set (`experiments/configs/dynamics*.toml`: Nigel's `dynamics.toml`), over steering from a
hundredth of full lock to full lock. Per turn the truth's steady speed v and yaw rate r (the mean of
its last 2 s; a hollow marker where it is not steady: the car slides or spins), beside the two models
at that same v: the kinematic single track, r = v tan δ / L, and the linear single track with the
vehicle file's cornering stiffnesses, r = v δ / (L + K v²). Nigel's three curves lie on one another;
the 1:10 car's linear model leaves the kinematic one at once (it understeers) and its truth leaves
both near μ g; the full-size car's stay together until its tyres saturate.

The dynamic core (`[model] core = "dynamic"`) runs the same turns at its own steady state: with the
file's values (no data), and for a car given a trained physics model (`--models car=model.pt`, a
campaign's last model) with its identified scales alone and with its correction on top.

Usage: python experiments/docs/handling_diagram.py [--out docs/img/handling_diagram.png] [--points 12]
       [--models f1tenth=runs/dynamics_f1tenth/uniform/seed0/model.pt]
"""

from __future__ import annotations

import argparse
import math
import warnings
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from activelearn.config import load_config
from activelearn.numerics.models import load_model
from activelearn.numerics.models.dynamic_physics import DynamicPhysicsModel
from activelearn.numerics.models.dynamic_track import DynamicCar, rate_runs
from activelearn.numerics.surrogate import simulate
from simulator import DivergenceWarning, Maneuver, build_vehicle, collect, shipped_vehicles
from simulator.vehicles import GRAVITY, load_vehicle

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SETTLE = 4.0  # s of the turn after the speed has settled; the last 2 s are averaged
RATE = 30.0  # Hz, the logs' and the models' controls
# the dynamic core's curves: (label, line style) at each one's own steady speed
CORES = (("file core", "-."), ("identified core", (0, (1, 1))), ("corrected", "-"))


def config_for(car: str) -> Path:
    """The car's cold-start dynamics config (Nigel's is dynamics.toml)."""
    own = CONFIGS / f"dynamics_{car}.toml"
    return own if own.is_file() else CONFIGS / "dynamics.toml"


def steady_turns(car: str, points: int, model_path: Path | None = None) -> list[dict]:
    """Steady turns of the car's truth at its test throttles over a steering grid, and the dynamic core's
    (the file's; a trained model's identified core and corrected model, each at its own speed)."""
    spec, cfg = load_vehicle(car), load_config(config_for(car))
    throttles = [u for u in cfg.test.throttles if u > 0]
    lock = spec.steering.limit.value
    steerings = lock * np.geomspace(0.01, 1.0, points)
    top = spec.max_speed
    launch = 5.0 * (spec.drivetrain.top_speed.value / spec.drivetrain.max_acceleration.value
                    if spec.drivetrain.top_speed is not None else 0.1)  # fmt: skip
    seconds = launch + SETTLE
    maneuvers = [Maneuver("skidpad", u, float(d), "ccw", seconds) for u in throttles for d in steerings]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DivergenceWarning)
        table = collect(maneuvers, vehicle=build_vehicle(spec), noise=None)
    commands = np.array([[m.throttle, m.steering] for m in maneuvers])
    controls = np.repeat(commands[:, None, :], round(seconds * RATE), axis=1)  # (M, T, 2)
    # the file's core under the slip law the car's dynamics config runs (`[model] wheel_forces`)
    file_core = replace(DynamicCar.of(spec), wheel_forces=cfg.model.wheel_forces)
    models = {"file core": _steady(rate_runs(file_core, controls, np.zeros((len(maneuvers), 4)),
                                             1.0 / RATE, implicit=True))}  # fmt: skip
    if model_path is not None:
        model = load_model(model_path)
        if not isinstance(model, DynamicPhysicsModel) or model.car.spec.name != car:
            raise SystemExit(f"--models: {model_path} is not a dynamic-core physics model of {car}")
        for name, corrected in (("identified core", False), ("corrected", True)):
            model.corrected = corrected
            rollout = simulate(model, list(controls), rate_hz=RATE, n_samples=8, seed=0)
            models[name] = _steady(rollout.mean_rates)
    out = []
    for m, (_, run) in zip(maneuvers, table.groupby("run_id", sort=False), strict=True):
        last = run[run.time >= run.time.max() - 2.0]
        v, r = float(last.speed.mean()), float(last.angZ.mean())
        out.append({
            "throttle": m.throttle, "nominal": float(spec.steady_speed(m.throttle)), "delta": m.steering,
            "v": v, "r": r, "steady": bool(last.angZ.std() <= 0.02 * abs(r) + 1e-3 and abs(v) < 1.5 * top),
            "kinematic": v * math.tan(m.steering) / spec.wheelbase,
            "linear": float(spec.linear_yaw_gain(v)) * m.steering,
        })  # fmt: skip
        for name, (speeds, yaw_rates) in models.items():
            out[-1][name] = (float(speeds[len(out) - 1]), float(yaw_rates[len(out) - 1]))
    return out


def _steady(rates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steady (v, r) of runs' rates (M, T, 2): the mean of their last 2 s."""
    last = rates[:, -round(2.0 * RATE) :]
    return last[..., 0].mean(axis=1), last[..., 1].mean(axis=1)


def draw(cars: list[str], points: int, out: Path, models: dict[str, Path]) -> None:
    fig, axes = plt.subplots(2, len(cars), figsize=(4.6 * len(cars), 7.2), squeeze=False)
    for col, car in enumerate(cars):
        spec = load_vehicle(car)
        mug = spec.tyres.friction.value * GRAVITY
        turns = steady_turns(car, points, models.get(car))
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for k, u in enumerate(sorted({t["throttle"] for t in turns})):
            rows = [t for t in turns if t["throttle"] == u]
            d = np.array([t["delta"] for t in rows])
            v = np.array([t["v"] for t in rows])
            c = colors[k % len(colors)]
            label = f"{rows[0]['nominal']:.3g} m/s"
            for row, (key, scale) in enumerate((("r", 1.0), ("a_y", 1.0 / mug))):
                ax = axes[row, col]
                truth = np.array([t["r"] for t in rows]) * (v * scale if key == "a_y" else 1.0)
                steady = np.array([t["steady"] for t in rows])
                ax.plot(d[steady], truth[steady], "o", color=c, label=f"truth, {label}" if row == 0 else None)
                ax.plot(d[~steady], truth[~steady], "o", mfc="none", color=c)
                for model, style in (("kinematic", ":"), ("linear", "--")):  # at the steady turns' speeds
                    values = np.array([t[model] for t in rows]) * (v * scale if key == "a_y" else 1.0)
                    ax.plot(d[steady], values[steady], style, color=c, lw=1)
                for model, style in CORES:  # each at its own steady speed
                    if model in rows[0]:
                        own_v, own_r = np.array([t[model] for t in rows]).T
                        ax.plot(d, own_r * (own_v * scale if key == "a_y" else 1.0), linestyle=style, color=c,
                                lw=1.6 if model == "corrected" else 1, alpha=0.8)  # fmt: skip
        top, bottom = axes[0, col], axes[1, col]
        top.set_title(f"{spec.title}")
        top.set_ylabel("steady yaw rate r (rad/s)")
        bottom.set_ylabel("lateral acceleration v r / (μ g)")
        bottom.axhline(1.0, color="grey", lw=0.8)
        for ax in (top, bottom):
            ax.set_xscale("log")
            ax.set_xlabel("steering δ (rad)")
            ax.grid(True, alpha=0.3)
        limit = 1.3 * max(abs(t["r"] * t["v"]) / mug for t in turns if t["steady"])
        bottom.set_ylim(0.0, max(1.3, limit) if spec.max_speed**2 > mug * spec.wheelbase else limit)
        top.set_ylim(0.0, 1.3 * max(abs(t["r"]) for t in turns if t["steady"]))
        top.legend(fontsize=7, loc="upper left")
    fig.text(0.5, 0.022, "dots: the truth (hollow: not steady); dotted: kinematic single track; dashed: "
             "linear single track (the file's cornering stiffnesses), both at the truth's speed",
             ha="center", fontsize=8)  # fmt: skip
    given = ", ".join(models) or "no model given"
    fig.text(0.5, 0.004, "dash-dot: the dynamic core with the file's values; fine dots: its identified "
             f"scales ({given}); solid: with the correction; each at its own speed",
             ha="center", fontsize=8)  # fmt: skip
    fig.tight_layout(rect=(0, 0.035, 1, 1))
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/img/handling_diagram.png")
    parser.add_argument("--points", type=int, default=12, help="steering values per speed")
    parser.add_argument("--cars", default="nigel,f1tenth,bmw320i")
    parser.add_argument("--models", default="", metavar="CAR=MODEL,...",
                        help="trained dynamic-core physics models (a campaign's model.pt) per car")
    args = parser.parse_args()
    cars = [c for c in args.cars.split(",") if c]
    unknown = set(cars) - set(shipped_vehicles())
    if unknown or args.points < 2:
        parser.error(f"--cars: shipped ones ({', '.join(shipped_vehicles())}); --points: at least 2")
    models = {}
    for item in (m for m in args.models.split(",") if m):
        car, _, path = item.partition("=")
        if car not in cars or not Path(path).is_file():
            parser.error(f"--models: CAR=MODEL with CAR one of --cars and MODEL a file, got {item!r}")
        models[car] = Path(path)
    draw(cars, args.points, Path(args.out), models)


if __name__ == "__main__":
    main()
