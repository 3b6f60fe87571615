"""A car whose tyres are MuJoCo's contacts (Nigel): loading, the (throttle, steering) -> actuator map, rest
state and sensor decoding. The car's figures come from its vehicle file (`simulator.vehicles`)."""

from __future__ import annotations

import functools
import string
from pathlib import Path

import mujoco
import numpy as np

# Nigel's limits and facts (simulator.datasheet reads them from its vehicle file; re-exported here).
from simulator.datasheet import (  # noqa: F401
    MAX_SPEED,
    MAX_YAW_RATE,
    NIGEL,
    REFERENCE_SPEED,
    REFERENCE_THROTTLE,
    STEERING_LIMIT,
    THROTTLE_LIMIT,
    TRACK,
    WHEEL_RADIUS,
    WHEELBASE,
)
from simulator.vehicles.spec import VehicleFileError, VehicleSpec, load_vehicle

ENCODER_CPR = int(NIGEL.sensors.encoder_cpr.value)  # Nigel's encoder counts per revolution

# Calibration target of issue 15: steady turn speeds (steering rad, speed m/s) of the real car at
# throttle 1.0, read from the public AutoDRIVE Nigel parking log. The model is fitted to within 0.01 m/s.
_TURNS = NIGEL.truth.reference_turns
REFERENCE_TURNS_THROTTLE = _TURNS.throttle
REFERENCE_TURNS = tuple(zip(_TURNS.steering, _TURNS.speed, strict=True))

# Actuator order of the control vector (see assets/nigel.xml).
ACTUATORS = (
    "steer_left",
    "steer_right",
    "drive_fwd",
    "drive_rev",
    "brake_fl",
    "brake_fr",
    "brake_rl",
    "brake_rr",
)
CONTACT_SENSORS = ("contact_fl", "contact_fr", "contact_rl", "contact_rr")

# How long the car settles on its wheels (brakes on) before every run starts.
_SETTLE_TIME = 0.5  # s


def model_xml(spec: VehicleSpec | str | Path = "nigel") -> str:
    """The car's MJCF text, its template filled from the vehicle file (also the simulation cache's key)."""
    spec = load_vehicle(spec)
    template = string.Template(spec.truth_file().read_text())
    try:
        return template.substitute(_mjcf_figures(spec))
    except (KeyError, ValueError) as exc:
        reason = f"template placeholder {exc} not filled"
        raise VehicleFileError(spec.truth_file(), "truth.model", reason) from None


def _mjcf_figures(spec: VehicleSpec) -> dict[str, str]:
    """The template's figures: the file's, and the chassis's share of mass and inertia after the wheels.

    The chassis's inertial puts the whole car's CG at the body origin (x) and at the file's CG height,
    and gives the whole car the file's yaw inertia. Derived values are written to the precision the
    model has always used (so Nigel's model, and its logs, stay the same to the last bit).
    """
    g, truth = spec.geometry, spec.truth
    lf, lr, half_track = g.lf.value, g.lr.value, 0.5 * g.track.value
    mass, wheel = spec.inertia.mass.value, truth.wheel_mass.value
    chassis = mass - 4.0 * wheel
    chassis_x = -2.0 * wheel * (lf - lr) / chassis
    chassis_z = (g.cg_height.value - g.wheel_radius.value) * mass / chassis
    wheels_izz = wheel * 2.0 * (lf**2 + lr**2 + 2.0 * half_track**2) + 4.0 * truth.wheel_yaw_inertia.value
    chassis_izz = spec.inertia.yaw_inertia.value - wheels_izz - chassis * chassis_x**2
    return {
        "wheel_radius": repr(g.wheel_radius.value), "friction": repr(spec.tyres.friction.value),
        "lf": repr(lf), "lr": repr(lr), "half_track": repr(half_track),
        "wheel_mass": repr(wheel), "wheel_izz": repr(truth.wheel_yaw_inertia.value),
        "chassis_mass": f"{chassis:.10g}", "chassis_x": f"{chassis_x:.8f}", "chassis_z": f"{chassis_z:.6f}",
        "chassis_izz": f"{chassis_izz:.6f}",
    }


def reference_speed(throttle: np.ndarray | float) -> np.ndarray:
    """Steady straight-line speed (m/s) of the reference table, interpolated; negative throttle mirrors."""
    u = np.asarray(throttle, dtype=float)
    return np.sign(u) * np.interp(np.abs(u), REFERENCE_THROTTLE, REFERENCE_SPEED)


def ackermann_angles(
    steering: np.ndarray | float, wheelbase: float = WHEELBASE, track: float = TRACK
) -> tuple[np.ndarray, np.ndarray]:
    """Left and right front-wheel angles (rad) for a bicycle-model steering angle, by true Ackermann.

    The bicycle angle delta turns the rear-axle centre on radius R = L / tan(delta); each front wheel
    points at the same centre, so tan(delta_in) = L / (R - t/2) and tan(delta_out) = L / (R + t/2).
    Positive steering turns left, so the left wheel is then the inner one and turns more.
    """
    tan_delta = np.tan(np.asarray(steering, dtype=float))
    left = np.arctan(wheelbase * tan_delta / (wheelbase - 0.5 * track * tan_delta))
    right = np.arctan(wheelbase * tan_delta / (wheelbase + 0.5 * track * tan_delta))
    return left, right


def quat_to_rpy(quat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roll, pitch, yaw (rad, ROS/ZYX convention, yaw in (-pi, pi]) of (w, x, y, z) quaternions."""
    w, x, y, z = (quat[..., i] for i in range(4))
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


class Vehicle:
    """One car of a 'mujoco-contacts' truth (Nigel): its control map, rest state, state and sensor layout.

    `model` is a private copy; tests and studies may edit it (friction, gains, ...) before the first
    rollout. The rest state is computed lazily, so it reflects such edits.

    Three properties of the control path are not in the model (simulator.twin sets them): the
    bicycle steering angle the wheels get is `steering_gain * steering + steering_offset`, and
    `latency` (s) delays every command inside `collect` (the control applied at time t is the
    command of t - latency, rounded to physics steps; before a run starts the command is the brake).
    """

    def __init__(self, xml_path: str | Path | None = None, spec: VehicleSpec | str | Path = "nigel") -> None:
        self.spec = load_vehicle(spec)
        if xml_path is not None:
            self.model = mujoco.MjModel.from_xml_path(str(xml_path))
        else:
            self.model = mujoco.MjModel.from_xml_string(model_xml(self.spec))
        self.steering_limit = self.spec.steering.limit.value  # rad
        self.encoder_cpr = int(self.spec.sensors.encoder_cpr.value)
        self.steering_gain = 1.0
        self.steering_offset = 0.0  # rad
        self.latency = 0.0  # s
        m = self.model
        self.actuator_ids = np.array([m.actuator(name).id for name in ACTUATORS])
        # Ackermann geometry from the model itself, so the split always matches the wheels.
        front = m.body("wheel_fl").pos
        rear = m.body("wheel_rl").pos
        self.wheelbase = float(front[0] - rear[0])
        self.track = float(2.0 * abs(front[1]))
        self.wheel_radius = float(m.geom("tyre_rl").size[0])
        self._index_model()

    def _index_model(self) -> None:
        """Sensor slices and the offsets of time, the root's quaternion and yaw rate in a state vector."""
        m = self.model
        self.sensors = {
            m.sensor(i).name: slice(int(m.sensor_adr[i]), int(m.sensor_adr[i] + m.sensor_dim[i]))
            for i in range(m.nsensor)
        }
        self.nstate = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS.value)
        # Offsets of time, qpos and qvel inside a FULLPHYSICS state vector (components in bit order).
        offsets: dict[int, int] = {}
        offset = 0
        for bit in range(mujoco.mjtState.mjNSTATE.value):
            flag = 1 << bit
            if flag & mujoco.mjtState.mjSTATE_FULLPHYSICS.value:
                offsets[flag] = offset
                offset += mujoco.mj_stateSize(m, flag)
        self.state_offsets = offsets
        self.state_time = offsets[mujoco.mjtState.mjSTATE_TIME.value]
        qpos0 = offsets[mujoco.mjtState.mjSTATE_QPOS.value]
        qvel0 = offsets[mujoco.mjtState.mjSTATE_QVEL.value]
        root = m.joint("root")
        self.state_root_quat = slice(qpos0 + int(root.qposadr[0]) + 3, qpos0 + int(root.qposadr[0]) + 7)
        # free-joint angular velocity is in the body frame: index 5 is the yaw rate on flat ground
        self.state_root_yaw_rate = qvel0 + int(root.dofadr[0]) + 5

    @property
    def timestep(self) -> float:
        """Physics time step (s)."""
        return float(self.model.opt.timestep)

    @property
    def latency_steps(self) -> int:
        """Actuation delay in whole physics steps (`latency` rounded to the nearest step)."""
        return round(self.latency / self.model.opt.timestep)

    def controls(self, throttle: np.ndarray | float, steering: np.ndarray | float) -> np.ndarray:
        """Actuator controls (..., nu) for throttle in [-1, 1] and signed steering (rad, + = left)."""
        u = np.asarray(throttle, dtype=float)
        u, delta = np.broadcast_arrays(u, np.asarray(steering, dtype=float))
        ctrl = np.zeros((*u.shape, self.model.nu))
        if self.steering_gain != 1.0 or self.steering_offset != 0.0:  # nominal stays bit-identical
            delta = self.steering_gain * delta + self.steering_offset
        left, right = ackermann_angles(delta, self.wheelbase, self.track)
        ids = self.actuator_ids
        ctrl[..., ids[0]] = left
        ctrl[..., ids[1]] = right
        ctrl[..., ids[2]] = np.maximum(u, 0.0)
        ctrl[..., ids[3]] = np.maximum(-u, 0.0)
        brake = (u == 0.0).astype(float)  # exactly zero throttle is the brake command
        for k in range(4, 8):
            ctrl[..., ids[k]] = brake
        return ctrl

    @functools.cached_property
    def rest_state(self) -> np.ndarray:
        """FULLPHYSICS state of the car settled on its wheels at the origin, heading +x, time 0."""
        m = self.model
        d = mujoco.MjData(m)
        d.ctrl[:] = self.controls(0.0, 0.0)
        for _ in range(round(_SETTLE_TIME / m.opt.timestep)):
            mujoco.mj_step(m, d)
        d.time = 0.0
        d.qvel[:] = 0.0
        d.qacc_warmstart[:] = 0.0
        # settling is symmetric, but pin the planar pose exactly so every run starts identically
        root = m.joint("root")
        adr = int(root.qposadr[0])
        d.qpos[adr : adr + 2] = 0.0
        state = np.empty(self.nstate)
        mujoco.mj_getState(m, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS.value)
        return state

    def yaw_and_rate(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Yaw (rad, wrapped) and yaw rate (rad/s) of the chassis from FULLPHYSICS state vectors."""
        _, _, yaw = quat_to_rpy(states[..., self.state_root_quat])
        return yaw, states[..., self.state_root_yaw_rate]

    def decode(self, sensordata: np.ndarray) -> dict[str, np.ndarray]:
        """Log channels (speed, gyro, accelerometer, pose, wheel angles, tyre contacts) from sensor data."""
        s = self.sensors
        vel = sensordata[..., s["velocity"]]
        gyro = sensordata[..., s["gyro"]]
        acc = sensordata[..., s["accelerometer"]]
        pos = sensordata[..., s["position"]]
        roll, pitch, yaw = quat_to_rpy(sensordata[..., s["orientation"]])
        contacts = np.stack([sensordata[..., s[name]][..., 0] for name in CONTACT_SENSORS], axis=-1)
        return {
            "speed": vel[..., 0],
            "angX": gyro[..., 0],
            "angY": gyro[..., 1],
            "angZ": gyro[..., 2],
            "accX": acc[..., 0],
            "accY": acc[..., 1],
            "accZ": acc[..., 2],
            "posX": pos[..., 0],
            "posY": pos[..., 1],
            "posZ": pos[..., 2],
            "roll": roll,
            "pitch": pitch,
            "yaw": yaw,
            "wheel_left": sensordata[..., s["encoder_left"]][..., 0],
            "wheel_right": sensordata[..., s["encoder_right"]][..., 0],
            "contacts": contacts,
        }
