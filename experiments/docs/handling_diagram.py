"""The three cars' handling diagrams: steady yaw rate and lateral acceleration against steering.

For each shipped car, steady turns (skidpads, ccw) at the forward throttles of its cold-start dynamics
config's test set (`experiments/configs/dynamics*.toml`: Nigel's `dynamics.toml`), over steering from a
hundredth of full lock to full lock. Per turn the truth's steady speed v and yaw rate r (the mean of
its last 2 s; a hollow marker where it is not steady: the car slides or spins), beside the two models
at that same v: the kinematic single track, r = v tan δ / L, and the linear single track with the
vehicle file's cornering stiffnesses, r = v δ / (L + K v²). Nigel's three curves lie on one another;
the 1:10 car's linear model leaves the kinematic one at once (it understeers) and its truth leaves
both near μ g; the full-size car's stay together until its tyres saturate.

Usage: python experiments/docs/handling_diagram.py [--out docs/img/handling_diagram.png] [--points 12]
"""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from activelearn.config import load_config
from simulator import DivergenceWarning, Maneuver, build_vehicle, collect, shipped_vehicles
from simulator.vehicles import GRAVITY, load_vehicle

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SETTLE = 4.0  # s of the turn after the speed has settled; the last 2 s are averaged


def config_for(car: str) -> Path:
    """The car's cold-start dynamics config (Nigel's is dynamics.toml)."""
    own = CONFIGS / f"dynamics_{car}.toml"
    return own if own.is_file() else CONFIGS / "dynamics.toml"


def steady_turns(car: str, points: int) -> list[dict[str, float]]:
    """Steady turns of the car's truth at its test throttles over a steering grid."""
    spec = load_vehicle(car)
    throttles = [u for u in load_config(config_for(car)).test.throttles if u > 0]
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
    return out


def draw(cars: list[str], points: int, out: Path) -> None:
    fig, axes = plt.subplots(2, len(cars), figsize=(4.6 * len(cars), 7.2), squeeze=False)
    for col, car in enumerate(cars):
        spec = load_vehicle(car)
        mug = spec.tyres.friction.value * GRAVITY
        turns = steady_turns(car, points)
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
    fig.text(0.5, 0.005, "dots: the truth (hollow: not steady); dotted: kinematic single track; dashed: "
             "linear single track (the file's cornering stiffnesses), both at the truth's speed",
             ha="center", fontsize=8)  # fmt: skip
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/img/handling_diagram.png")
    parser.add_argument("--points", type=int, default=12, help="steering values per speed")
    parser.add_argument("--cars", default="nigel,f1tenth,bmw320i")
    args = parser.parse_args()
    cars = [c for c in args.cars.split(",") if c]
    unknown = set(cars) - set(shipped_vehicles())
    if unknown or args.points < 2:
        parser.error(f"--cars: shipped ones ({', '.join(shipped_vehicles())}); --points: at least 2")
    draw(cars, args.points, Path(args.out))


if __name__ == "__main__":
    main()
