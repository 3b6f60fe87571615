"""Sensor noise of the simulated logs: seeded Gaussian noise per channel group (`NoiseConfig`),
drawn as one stream per log in a fixed channel order (`add_noise`, which `collect` applies too)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from numbers import Integral, Real

import numpy as np
import pandas as pd

from simulator.errors import ManeuverError
from simulator.vehicle import MAX_SPEED
from simulator.vehicles.spec import VehicleSpec

_SENSOR_FIGURES = ("speed", "yaw_rate", "acceleration", "position", "angle")  # [sensors] <name>_noise


def is_real(value: object) -> bool:
    """A real number, not a bool."""
    return isinstance(value, Real) and not isinstance(value, bool)


def is_int(value: object) -> bool:
    """An integer, not a bool."""
    return isinstance(value, Integral) and not isinstance(value, bool)


@dataclass(frozen=True)
class NoiseConfig:
    """Seeded Gaussian sensor noise: one standard deviation per channel group.

    With `heteroscedastic`, every standard deviation is scaled by (1 + speed_gain * |v| / v_ref),
    v being the true forward speed of the sample and v_ref the car's top speed (`reference_speed`,
    default the default car's), so noise at full speed is (1 + speed_gain) times the noise at rest.
    Encoder tick noise is rounded to whole counts. `for_vehicle` gives a car's own sensors.
    """

    enabled: bool = True
    speed: float = 0.002  # m/s, forward speed
    yaw_rate: float = 0.005  # rad/s, all three gyro axes
    acceleration: float = 0.02  # m/s^2, all three accelerometer axes
    position: float = 0.002  # m, posX/posY/posZ
    angle: float = 0.002  # rad, roll/pitch/yaw
    ticks: float = 1.0  # counts, left/right encoders
    heteroscedastic: bool = False
    speed_gain: float = 2.0
    reference_speed: float = MAX_SPEED  # m/s

    @classmethod
    def for_vehicle(cls, spec: VehicleSpec, **overrides: object) -> NoiseConfig:
        """The sensor noise of a vehicle file (its [sensors] noise figures where given, its top speed as
        the reference speed), with `overrides` on top."""
        figures = {
            name: getattr(spec.sensors, f"{name}_noise").value
            for name in _SENSOR_FIGURES
            if getattr(spec.sensors, f"{name}_noise") is not None
        }
        return cls(**{**figures, "reference_speed": spec.max_speed, **overrides})  # type: ignore[arg-type]

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("enabled", "heteroscedastic"):
                if not isinstance(value, bool):
                    raise ManeuverError(f"noise.{f.name}", value, "must be true or false")
            elif not is_real(value) or not math.isfinite(value) or value < 0:
                raise ManeuverError(f"noise.{f.name}", value, "must be a finite number >= 0")
        if self.reference_speed <= 0:
            raise ManeuverError("noise.reference_speed", self.reference_speed, "must be > 0")


# (column, NoiseConfig field) in the fixed order noise is drawn: changing one std never changes the
# noise drawn for another channel.
_NOISE_CHANNELS = (
    ("speed", "speed"),
    ("angX", "yaw_rate"),
    ("angY", "yaw_rate"),
    ("angZ", "yaw_rate"),
    ("accX", "acceleration"),
    ("accY", "acceleration"),
    ("accZ", "acceleration"),
    ("posX", "position"),
    ("posY", "position"),
    ("posZ", "position"),
    ("roll", "angle"),
    ("pitch", "angle"),
    ("yaw", "angle"),
    ("leftTicks", "ticks"),
    ("rightTicks", "ticks"),
)


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Wrap angles to (-pi, pi]."""
    return np.pi - np.mod(np.pi - angle, 2.0 * np.pi)


def noise_std(noise: NoiseConfig, field: str, speed: np.ndarray) -> np.ndarray:
    """Per row, the std of `field`'s noise (a NoiseConfig field, e.g. "position") at forward speeds
    `speed` (m/s): scaled by 1 + speed_gain |v| / reference_speed when heteroscedastic. Zero when disabled."""
    speed = np.asarray(speed, dtype=float)
    if not noise.enabled:
        return np.zeros(speed.shape)
    scale = np.ones(speed.shape)
    if noise.heteroscedastic:
        scale = 1.0 + noise.speed_gain * np.abs(np.nan_to_num(speed)) / noise.reference_speed
    return getattr(noise, field) * scale


def noisy_columns(cols: dict[str, np.ndarray], noise: NoiseConfig, rng: np.random.Generator) -> None:
    """Replace the sensor channels in `cols` by noisy copies (one stream, fixed channel order)."""
    true_speed = cols["speed"].copy()  # every channel's std follows the true speed, not the noisy one
    draws = rng.standard_normal((len(true_speed), len(_NOISE_CHANNELS)))
    for j, (column, field) in enumerate(_NOISE_CHANNELS):
        delta = noise_std(noise, field, true_speed) * draws[:, j]
        if column in ("leftTicks", "rightTicks"):
            cols[column] = cols[column] + np.rint(delta).astype(np.int64)
        else:
            cols[column] = cols[column] + delta
    cols["yaw"] = wrap_angle(cols["yaw"])


def add_noise(
    frame: pd.DataFrame,
    noise: NoiseConfig,
    seed: int | np.random.SeedSequence | np.random.Generator,
) -> pd.DataFrame:
    """Copy of a noise-free log with seeded sensor noise added (the noise `collect` itself adds).

    All rows form one noise stream drawn in a fixed channel order, so changing one channel's std
    never changes another channel's noise. `collect(ms, seed=s, noise=cfg)` equals `add_noise` of
    the noise-free log of run i with seed `SeedSequence(s).spawn(len(ms))[i]`. Encoder noise is
    whole counts; yaw is re-wrapped to (-pi, pi]. Disabled noise returns an unchanged copy.
    """
    out = frame.copy()
    if not noise.enabled or len(out) == 0:
        return out
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    cols = {
        column: out[column].to_numpy(np.int64 if column.endswith("Ticks") else float)
        for column, _ in _NOISE_CHANNELS
    }
    noisy_columns(cols, noise, rng)
    for column, values in cols.items():
        out[column] = values
    return out
