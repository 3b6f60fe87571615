"""A car whose tyres MuJoCo's contacts cannot be (the 1:10 and the full-size car): MuJoCo integrates a rigid
chassis on frictionless wheels; a magic-formula tyre computed here applies the forces every physics step.

What and why:
- Engine: MuJoCo, as for Nigel. One rigid body on a free joint carries the file's mass, yaw inertia and CG
  (lf, lr, CG height); four spheres of the wheel radius at the wheel centres touch the floor through
  frictionless contacts (condim 1; MuJoCo's default softness, solref 0.02 s critically damped, >= 2
  physics steps for both cars; 0.1 mm static penetration). MuJoCo's constraint solver gives the normal
  loads, so the load transfer front/rear and left/right comes out of the rigid-body dynamics. The
  contacts are the car's only compliance (no suspension, as the single track has none): the logged roll
  stays below 0.1 deg. Roll and pitch inertia are an assumption: a box of the car's length, width and
  twice its CG height, scaled to the file's yaw inertia (they only act in transients). Euler
  integration: inside MuJoCo nothing depends on velocity but the contacts, which its solver handles.
- Tyres: per wheel the simplified magic formula F_y = μ F_z sin(C atan(Bα − E(Bα − atan Bα))), C and E
  from the file, B per axle from its cornering stiffness per unit static load (B C μ = C_α / F_z,static),
  F_z the wheel's load MuJoCo measured on the step before (the usual one-step lag). The lateral force
  grows in proportion to the load (the file gives no degressive load sensitivity), so left/right load
  transfer changes no axle's grip; front/rear transfer (braking, driving, the drive that holds speed in
  a turn) does. The slip angle comes from the wheel centre's velocity in the wheel frame,
  α = atan(−v_lat / max(|v_long|, fade speed)): below the file's `tyre_fade_speed` the tyre is a lateral
  damper, stable at rest, and the car follows its wheels as the kinematic model does; explicit tyre
  forces are stable where the damping rate times the step, dt (C_αf + C_αr) / (m v_fade), stays below 1
  (0.17 for the 1:10 car, 0.72 for the full-size car; the yaw mode's 0.38 and 0.72). No relaxation
  length (its lag is a few milliseconds at these speeds).
- Longitudinal: the file's motor law on the car's forward speed v. Throttle u > 0: a = a_max (u − v/v_top),
  zero at v = u v_top (the steady straight speed); u < 0 mirrored with the reverse top speed; |a| ≤ a_max
  and ≤ a_max v_switch / |v| (power limit). The force m a (the file's mass: a payload slows the car) is
  split over the driven wheels (`driven`, `front_drive_share`), equal left/right (open differentials).
  u == 0 exactly brakes: m a_brake over the four wheels by their loads, against each wheel's rolling
  speed, fading linearly below a tenth of the fade speed so that the braked car stands still.
- Combined slip: Kamm's circle (the friction ellipse with the file's one μ both ways). Where the
  longitudinal demand and the pure-slip lateral force add up to more than μ F_z, both are scaled back
  onto the circle keeping their direction, so no longitudinal force exceeds μ F_z and a wheel at its
  longitudinal limit still resists sliding sideways. (The ellipse F_y √(1 − (F_x / μ F_z)²) with F_x
  capped drops the lateral force to zero at full drive: at full throttle and lock the 1:10 car then
  spun up undamped to 150 rad/s.)
- Steering: the bicycle angle, clipped to the file's limit (the rack's end stop) and rate-limited to its
  rate, split to the front wheels by true Ackermann (as Nigel's `ackermann_angles`). The state vector
  carries everything a step needs, so a run resumes bit for bit from any logged state: the bicycle
  angle and the four lagged loads are the activations of zero-gain integrator actuators; the front
  steering hinges (the Ackermann angles) and the rear spin hinges (the encoders: rolled distance over
  the radius) are set kinematically every step on wheel bodies of 1e-4 of the car's mass each.
- Stepping: `rollout` steps each run whole in C (`simulator.tyre_kernel`: the tyre forces as
  `xfrc_applied` on the chassis, then `mj_step`, a thread per MjData, 5-20x the NumPy path); the NumPy
  path (`tyre_forces`, every run's and wheel's forces at once, then one `mujoco.rollout` call a physics
  step) is the reference it is tested against, and what runs without a C compiler. Every solver step
  starts cold, so a run's result does not depend on its batch.
Twin overrides: tire_friction scales μ at the file's cornering stiffness (a slippery floor: the peak
drops, the linear range stays, as Pacejka's λ_μ); mass the chassis (a payload at the CG, inertia
unchanged); yaw_inertia the whole car's; motor_gain a_max and both top speeds together (a weaker motor
is slower at every throttle, with the same time constant v_top / a_max); steering_gain and
steering_offset act on the commanded angle; latency delays the commands (in `collect`).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from pathlib import Path

import mujoco
import mujoco.rollout
import numpy as np

from simulator import tyre_kernel
from simulator.twin import TWIN_PARAMETERS, check_overrides
from simulator.vehicle import Vehicle
from simulator.vehicles.spec import MujocoTyres, VehicleFileError, VehicleSpec, load_vehicle

WHEELS = ("fl", "fr", "rl", "rr")
WHEEL_MASS_SHARE = 1e-4  # each wheel body's share of the car's mass: it only holds angles (subtracted)
CONTACT_SOLREF = (0.02, 1.0)  # MuJoCo's default contact time constant (s) and damping ratio
BRAKE_FADE_SHARE = 0.1  # the brake force fades linearly below this share of the tyre fade speed
SETTLE_TIME = 0.5  # s the car settles on its wheels, braked, before every run
_STATE = mujoco.mjtState
_CONTROL_SPEC = _STATE.mjSTATE_CTRL.value | _STATE.mjSTATE_XFRC_APPLIED.value
_THREADED_BATCH = 48  # runs from which a step is split over the rollout's threads (below: faster serial)


def _quat_to_matrix() -> np.ndarray:
    """(16, 9): the rotation matrix (row-major) of a unit quaternion (w, x, y, z) from its outer product."""
    out = np.zeros((4, 4, 3, 3))
    w, x, y, z = range(4)
    terms = {
        (0, 0): [(1, w, w), (1, x, x), (-1, y, y), (-1, z, z)], (0, 1): [(2, x, y), (-2, w, z)],
        (0, 2): [(2, x, z), (2, w, y)], (1, 0): [(2, x, y), (2, w, z)],
        (1, 1): [(1, w, w), (-1, x, x), (1, y, y), (-1, z, z)], (1, 2): [(2, y, z), (-2, w, x)],
        (2, 0): [(2, x, z), (-2, w, y)], (2, 1): [(2, y, z), (2, w, x)],
        (2, 2): [(1, w, w), (-1, x, x), (-1, y, y), (1, z, z)],
    }  # fmt: skip
    for (i, j), products in terms.items():
        for coef, a, b in products:
            out[a, b, i, j] += coef
    return out.reshape(16, 9)


_QUAT_TO_MATRIX = _quat_to_matrix()
# actuators: the two commands (zero gain: ctrl only carries them), then the state memory (integrators)
ACTUATORS = ("throttle", "steering", "steer_angle", "load_fl", "load_fr", "load_rl", "load_rr")


def _fmt(value: float) -> str:
    return repr(float(value))


class TyreCar(Vehicle):
    """A 'mujoco-tyres' car built from its vehicle file: see the module docstring.

    `controls(throttle, steering)` gives (..., nu) rows (throttle, commanded bicycle angle after the
    twin's steering gain and offset, zeros); `rollout` steps a batch with them as `collect` needs.
    `backend`: "compiled" (the C loop, the NumPy path where it cannot be built) or "reference" (NumPy).
    """

    backend: str = "compiled"

    def __init__(self, spec: VehicleSpec | str | Path, overrides: Mapping[str, float] | None = None) -> None:
        self.spec = load_vehicle(spec)
        if not isinstance(self.spec.truth, MujocoTyres):
            raise VehicleFileError(self.spec.path or self.spec.name, "truth.engine", "must be 'mujoco-tyres'")
        values = check_overrides(overrides or {})
        self.overrides = values
        scale = {name: values.get(name, p.nominal) for name, p in TWIN_PARAMETERS.items()}
        s = self.spec
        g, d, t = s.geometry, s.drivetrain, s.tyres
        self.wheelbase = s.wheelbase
        self.track = g.track.value
        self.wheel_radius = g.wheel_radius.value
        self.cg_height = g.cg_height.value
        self.steering_limit = s.steering.limit.value
        self.steering_rate = s.steering.rate.value
        self.encoder_cpr = int(s.sensors.encoder_cpr.value)
        self.steering_gain = scale["steering_gain"]
        self.steering_offset = scale["steering_offset"]
        self.latency = scale["latency"]
        # tyres: B per axle from the cornering stiffness per unit static load, at the twin's friction
        self.friction = t.friction.value * scale["tire_friction"]
        self.shape = t.shape.value
        self.curvature = t.curvature.value
        front, rear = s.axle_loads()
        per_load = (t.cornering_stiffness_front.value / front, t.cornering_stiffness_rear.value / rear)
        self.stiffness_factor = np.repeat(per_load, 2) / (self.shape * self.friction)  # B of fl, fr, rl, rr
        self.fade_speed = s.truth.tyre_fade_speed.value
        # motor law (motor_gain scales the force and both top speeds)
        self.mass_nominal = s.inertia.mass.value
        self.max_acceleration = d.max_acceleration.value * scale["motor_gain"]
        self.top_speed = d.top_speed.value * scale["motor_gain"]
        self.reverse_top_speed = d.reverse_top_speed.value * scale["motor_gain"]
        self.power_limit_speed = d.power_limit_speed.value
        self.brake_deceleration = d.brake_deceleration.value
        if d.driven == "all":
            if d.front_drive_share is None:
                field = "drivetrain.front_drive_share"
                raise VehicleFileError(s.path or s.name, field, "needed by driven = 'all'")
            front_share = d.front_drive_share.value
        else:
            front_share = 1.0 if d.driven == "front" else 0.0
        self.drive_share = np.array([front_share / 2] * 2 + [(1.0 - front_share) / 2] * 2)
        self.mass = s.inertia.mass.value * scale["mass"]  # the chassis takes the payload (wheels: tiny)
        self.yaw_inertia = s.inertia.yaw_inertia.value * scale["yaw_inertia"]

        self.xml = self._mjcf(scale["mass"])
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        m = self.model
        self.actuator_ids = np.array([m.actuator(name).id for name in ACTUATORS])
        self._index_model()
        self._index_tyres()

    # ---- the model ----------------------------------------------------------------------------------
    def wheel_centres(self) -> np.ndarray:
        """(4, 3) wheel centres in the chassis frame (origin at the CG), order fl, fr, rl, rr."""
        lf, lr = self.spec.geometry.lf.value, self.spec.geometry.lr.value
        z = self.wheel_radius - self.cg_height
        half = self.track / 2
        return np.array([[lf, half, z], [lf, -half, z], [-lr, half, z], [-lr, -half, z]])

    def _mjcf(self, mass_scale: float) -> str:
        """The MJCF text of the car, every figure from the vehicle file (and the twin's scales)."""
        s = self.spec
        m_file = s.inertia.mass.value
        m_wheel = WHEEL_MASS_SHARE * m_file
        r = self.wheel_radius
        wheels = self.wheel_centres()
        m_chassis = m_file * mass_scale - 4 * m_wheel
        # chassis CoM offset that puts the whole car's CG at the body origin (the wheels are tiny)
        ipos = -m_wheel * wheels.sum(axis=0) / m_chassis
        length, width, height = s.geometry.length.value, s.geometry.width.value, 2.0 * self.cg_height
        # roll and pitch inertia: assumption, a box length x width x (2 x CG height) scaled to the yaw inertia
        box = self.yaw_inertia / (length**2 + width**2)
        whole = np.array([box * (width**2 + height**2), box * (length**2 + height**2), self.yaw_inertia])
        wheel_own = m_wheel * r**2 * np.array([0.25, 0.5, 0.25])  # a thin disc about x, y (spin), z
        def axes(points: np.ndarray) -> np.ndarray:  # squared distances from the x, y and z axes
            sq = points**2
            x, y, z = sq[..., 0], sq[..., 1], sq[..., 2]
            return np.stack([y + z, x + z, x + y], axis=-1)

        wheel_axes = axes(wheels).sum(axis=0)
        off = axes(ipos)
        chassis_inertia = whole - 4 * wheel_own - m_wheel * wheel_axes - m_chassis * off
        armature = 100.0 * m_wheel * r**2  # stiffens the kinematic hinges against the chassis' motion
        body = f"{_fmt(length / 2)} {_fmt(width / 2)} {_fmt(self.cg_height / 2)}"
        lines = [
            f'<mujoco model="{s.name}">',
            '  <compiler angle="radian" autolimits="true"/>',
            f'  <option timestep="{_fmt(s.truth.timestep.value)}" integrator="Euler"/>',
            "  <worldbody>",
            '    <light pos="0 0 30" dir="0 0 -1"/>',
            '    <geom name="floor" type="plane" size="0 0 1" condim="1" rgba="0.6 0.6 0.6 1"/>',
            f'    <body name="chassis" pos="0 0 {_fmt(self.cg_height)}">',
            '      <freejoint name="root"/>',
            f'      <inertial pos="{" ".join(_fmt(v) for v in ipos)}" mass="{_fmt(m_chassis)}"'
            f' diaginertia="{" ".join(_fmt(v) for v in chassis_inertia)}"/>',
            f'      <geom name="body" type="box" size="{body}" contype="0" conaffinity="0" mass="0"'
            ' rgba="0.2 0.3 0.8 1"/>',
            '      <site name="imu" pos="0 0 0" size="0.01"/>',
        ]
        solref = f"{_fmt(CONTACT_SOLREF[0])} {_fmt(CONTACT_SOLREF[1])}"
        for name, centre in zip(WHEELS, wheels, strict=True):
            pos = " ".join(_fmt(v) for v in centre)
            lines += [
                f'      <geom name="tyre_{name}" type="sphere" size="{_fmt(r)}" pos="{pos}" condim="1"'
                f' solref="{solref}" mass="0" rgba="0.1 0.1 0.1 1"/>',
                f'      <site name="load_{name}" type="sphere" size="{_fmt(1.2 * r)}" pos="{pos}"'
                ' rgba="0 0 0 0"/>',
                f'      <body name="wheel_{name}" pos="{pos}">',
                f'        <joint name="{"steer" if name[0] == "f" else "spin"}_{name}"'
                f' axis="{"0 0 1" if name[0] == "f" else "0 1 0"}" armature="{_fmt(armature)}"/>',
                f'        <inertial pos="0 0 0" mass="{_fmt(m_wheel)}"'
                f' diaginertia="{" ".join(_fmt(v) for v in wheel_own)}"/>',
                "      </body>",
            ]
        lines += ["    </body>", "  </worldbody>", "  <actuator>"]
        for name in ACTUATORS:
            dyn = ' dyntype="integrator"' if name not in ("throttle", "steering") else ""
            lines.append(f'    <general name="{name}" joint="spin_rl"{dyn} gainprm="0" biasprm="0"/>')
        lines += [
            "  </actuator>",
            "  <sensor>",
            '    <velocimeter name="velocity" site="imu"/>',
            '    <gyro name="gyro" site="imu"/>',
            '    <accelerometer name="accelerometer" site="imu"/>',
            '    <framepos name="position" objtype="site" objname="imu"/>',
            '    <framequat name="orientation" objtype="site" objname="imu"/>',
            '    <jointpos name="encoder_left" joint="spin_rl"/>',
            '    <jointpos name="encoder_right" joint="spin_rr"/>',
        ]
        for name in WHEELS:
            lines.append(f'    <contact name="contact_{name}" geom1="tyre_{name}" geom2="floor"'
                         ' data="found"/>')  # fmt: skip
        for name in WHEELS:
            lines.append(f'    <touch name="load_{name}" site="load_{name}"/>')
        lines += ["  </sensor>", "</mujoco>", ""]
        return "\n".join(lines)

    def _index_tyres(self) -> None:
        """Offsets of what the tyre step reads and writes in a state vector and in sensor data."""
        m = self.model
        qpos0 = self.state_offsets[_STATE.mjSTATE_QPOS.value]
        qvel0 = self.state_offsets[_STATE.mjSTATE_QVEL.value]
        act0 = self.state_offsets[_STATE.mjSTATE_ACT.value]
        root = m.joint("root")
        self._pos = qpos0 + int(root.qposadr[0]) + np.arange(3)
        self._quat = qpos0 + int(root.qposadr[0]) + 3 + np.arange(4)
        self._vel = qvel0 + int(root.dofadr[0]) + np.arange(3)
        self._omega = qvel0 + int(root.dofadr[0]) + 3 + np.arange(3)
        steer = [m.joint(f"steer_{w}") for w in ("fl", "fr")]
        spin = [m.joint(f"spin_{w}") for w in ("rl", "rr")]
        self._steer_qpos = np.array([qpos0 + int(j.qposadr[0]) for j in steer])
        self._spin_qpos = np.array([qpos0 + int(j.qposadr[0]) for j in spin])
        self._kin_qvel = np.array([qvel0 + int(j.dofadr[0]) for j in (*steer, *spin)])
        self._delta = act0 + int(m.actuator_actadr[m.actuator("steer_angle").id])
        self._loads = np.array([act0 + int(m.actuator_actadr[m.actuator(f"load_{w}").id]) for w in WHEELS])
        self._touch = np.array([self.sensors[f"load_{w}"].start for w in WHEELS])
        self._ncontrol = mujoco.mj_stateSize(m, _CONTROL_SPEC)
        self._xfrc = m.nu + 6 * m.body("chassis").id  # chassis force and torque inside a control row
        self._ipos = m.body_ipos[m.body("chassis").id].copy()
        self._centres = self.wheel_centres()
        self._half_track = 0.5 * self.track

    @functools.cached_property
    def kernel_figures(self) -> tyre_kernel._Car:
        """What the compiled step reads (`simulator.tyre_kernel`), built once per car."""
        return tyre_kernel.car_figures(self)

    # ---- commands -----------------------------------------------------------------------------------
    def controls(self, throttle: np.ndarray | float, steering: np.ndarray | float) -> np.ndarray:
        """Control rows (..., nu): throttle in [-1, 1] and the commanded bicycle angle (rad, + = left)."""
        u = np.asarray(throttle, dtype=float)
        u, delta = np.broadcast_arrays(u, np.asarray(steering, dtype=float))
        ctrl = np.zeros((*u.shape, self.model.nu))
        if self.steering_gain != 1.0 or self.steering_offset != 0.0:
            delta = self.steering_gain * delta + self.steering_offset
        ctrl[..., 0] = u
        ctrl[..., 1] = delta
        return ctrl

    @functools.cached_property
    def rest_state(self) -> np.ndarray:
        """FULLPHYSICS state of the car settled on its wheels (braked) at the origin, heading +x, time 0."""
        m = self.model
        d = mujoco.MjData(m)
        state = np.empty(self.nstate)
        mujoco.mj_getState(m, d, state, _STATE.mjSTATE_FULLPHYSICS.value)
        front, rear = self.spec.axle_loads()
        state[self._loads] = np.array([front, front, rear, rear]) / 2 * (self.mass / self.mass_nominal)
        nstep = round(SETTLE_TIME / m.opt.timestep)
        control = np.zeros((1, nstep, m.nu))
        states = np.empty((1, nstep, self.nstate))
        sens = np.empty((1, nstep, m.nsensordata))
        with mujoco.rollout.Rollout(nthread=0) as roller:
            self.rollout(roller, [d], state[None], control, nstep, states, sens)
        state = states[0, -1].copy()
        state[self.state_time] = 0.0
        qvel0 = self.state_offsets[_STATE.mjSTATE_QVEL.value]
        state[qvel0 : qvel0 + m.nv] = 0.0
        state[self._pos[:2]] = 0.0  # pin the planar pose exactly so every run starts identically
        return state

    # ---- the tyre step ------------------------------------------------------------------------------
    def tyre_forces(
        self, states: np.ndarray, throttle: np.ndarray, command: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Tyre forces of a batch of states (nb, nstate) under throttle and commanded angle (nb,).

        Returns the chassis' applied force and torque (nb, 6: world frame, about its CoM), the next
        steering angle (nb,), the rear wheels' next spin angles (nb, 2) and per wheel (nb, 4): the slip
        angle, the longitudinal and lateral force and the load.
        """
        nb = len(states)
        q = states[:, self._quat]
        rot = ((q[:, :, None] * q[:, None, :]).reshape(nb, 16) @ _QUAT_TO_MATRIX).reshape(nb, 3, 3)
        centres = rot @ self._centres.T  # (nb, 3, 4): wheel centres from the body origin, world frame
        omega = rot @ states[:, self._omega, None]  # (nb, 3, 1): angular velocity, world frame
        vel = states[:, self._vel, None]
        # the chassis' velocity at the wheel centres, horizontal components (nb, 4)
        ux = vel[:, 0] + omega[:, 1] * centres[:, 2] - omega[:, 2] * centres[:, 1]
        uy = vel[:, 1] + omega[:, 2] * centres[:, 0] - omega[:, 0] * centres[:, 2]
        # wheel headings in the floor plane: the chassis x axis turned by each wheel's angle
        delta = states[:, self._delta]
        tan_wheels = self._ackermann_tangents(delta)
        cos = 1.0 / np.sqrt(1.0 + tan_wheels * tan_wheels)
        sin = tan_wheels * cos
        hx = rot[:, 0, 0, None] * cos + rot[:, 0, 1, None] * sin
        hy = rot[:, 1, 0, None] * cos + rot[:, 1, 1, None] * sin
        norm = np.hypot(hx, hy)
        hx /= norm
        hy /= norm
        v_long = ux * hx + uy * hy
        v_lat = uy * hx - ux * hy  # along the wheel's left (z x heading)
        alpha = np.arctan(-v_lat / np.maximum(np.abs(v_long), self.fade_speed))
        load = np.maximum(states[:, self._loads], 0.0)
        grip = self.friction * load
        # longitudinal: the motor law on the car's forward speed, or the brake at throttle 0
        speed = (vel[:, :, 0] * rot[:, :, 0]).sum(axis=1)
        a_max = self.max_acceleration
        top = np.where(throttle > 0, self.top_speed, self.reverse_top_speed)
        limit = a_max * self.power_limit_speed / np.maximum(np.abs(speed), self.power_limit_speed)
        accel = np.minimum(np.maximum(a_max * (throttle - speed / top), -limit), limit)  # limit <= a_max
        total = load.sum(axis=1, keepdims=True)
        brake_force = self.mass_nominal * self.brake_deceleration / np.where(total > 0, total, 1.0)
        fade = np.minimum(np.maximum(v_long * (1.0 / (BRAKE_FADE_SHARE * self.fade_speed)), -1.0), 1.0)
        f_long = np.where((throttle == 0.0)[:, None], -brake_force * load * fade,
                          (self.mass_nominal * accel)[:, None] * self.drive_share)  # fmt: skip
        # lateral: the magic formula at pure slip
        b_alpha = self.stiffness_factor * alpha
        if self.curvature != 0.0:
            b_alpha = b_alpha - self.curvature * (b_alpha - np.arctan(b_alpha))
        f_lat = grip * np.sin(self.shape * np.arctan(b_alpha))
        # combined: the resultant scaled back onto the friction circle where it lies outside
        demand = np.hypot(f_long, f_lat)
        scale = np.where(demand > grip, grip / np.where(demand > 0, demand, 1.0), 1.0)
        f_long *= scale
        f_lat *= scale
        fx = f_long * hx - f_lat * hy
        fy = f_long * hy + f_lat * hx
        # torque about the chassis CoM of the forces at the contact points (a radius below the centres)
        arm = centres - rot @ self._ipos[:, None]
        out = np.empty((nb, 6))
        out[:, 0] = fx.sum(axis=1)
        out[:, 1] = fy.sum(axis=1)
        out[:, 2] = 0.0
        az = arm[:, 2] - self.wheel_radius
        out[:, 3] = -(az * fy).sum(axis=1)
        out[:, 4] = (az * fx).sum(axis=1)
        out[:, 5] = (arm[:, 0] * fy - arm[:, 1] * fx).sum(axis=1)
        # the next steering angle (the rack's end stop, the rate limit) and rear wheel angles (rolling)
        step = self.steering_rate * self.model.opt.timestep
        target = np.minimum(np.maximum(command, -self.steering_limit), self.steering_limit)
        next_delta = delta + np.minimum(np.maximum(target - delta, -step), step)
        spin = states[:, self._spin_qpos] + v_long[:, 2:] * (self.model.opt.timestep / self.wheel_radius)
        details = {"alpha": alpha, "f_long": f_long, "f_lat": f_lat, "load": load}
        return out, next_delta, spin, details

    def _ackermann_tangents(self, delta: np.ndarray) -> np.ndarray:
        """tan of each wheel's angle (nb, 4) for bicycle angles (nb,): fl, fr by true Ackermann, rear 0."""
        tan_delta = np.tan(delta)
        tangents = np.zeros((len(delta), 4))
        length, half = self.wheelbase, self._half_track
        tangents[:, 0] = length * tan_delta / (length - half * tan_delta)  # left: inner in a left turn
        tangents[:, 1] = length * tan_delta / (length + half * tan_delta)
        return tangents

    def rollout(
        self,
        roller: mujoco.rollout.Rollout,
        datas: Sequence[mujoco.MjData],
        initial_state: np.ndarray,
        control: np.ndarray,
        nstep: int,
        state: np.ndarray,
        sensordata: np.ndarray,
    ) -> None:
        """Step runs from FULLPHYSICS states (nb, nstate) under per-step controls (nb, nstep, nu), writing
        each step's state (nb, nstep, nstate) and sensor data (nb, nstep, nsensordata): what
        `mujoco.rollout` gives for a car without tyre forces, with the tyre forces applied every step.

        Compiled (`simulator.tyre_kernel`): every run stepped whole in C, a thread per MjData of `datas`.
        The NumPy path (no C compiler, or `backend = "reference"`): each step one `mujoco.rollout` call of
        the batch, in `roller`'s threads (two chunks) for a large batch, on the calling thread for a small
        one. Either way a run's result does not depend on its batch.
        """
        lib = tyre_kernel.library() if self.backend == "compiled" else None
        if lib is not None:
            tyre_kernel.rollout(lib, self, datas, initial_state, control, nstep, state, sensordata)
            return
        m = self.model
        nb = len(initial_state)
        current = np.array(initial_state, dtype=float)
        row = np.zeros((nb, 1, self._ncontrol))
        out = np.empty((nb, 1, self.nstate))
        sens = np.empty((nb, 1, m.nsensordata))
        models = [m] * nb
        chassis = slice(self._xfrc, self._xfrc + 6)
        threads = min(len(datas), getattr(roller, "nthread", 0))
        serial, chunk = None, None
        if threads < 2:
            datas = list(datas[:1])
        elif nb < _THREADED_BATCH:
            serial = mujoco.rollout.Rollout(nthread=0)
            roller, datas = serial, list(datas[:1])
        else:
            chunk = -(-nb // threads)  # one chunk a thread: the least hand-over a step
        delta_index, loads, touch = self._delta, self._loads, self._touch
        steer_index, spin_index, kin_index = self._steer_qpos, self._spin_qpos, self._kin_qvel
        try:
            for t in range(nstep):
                commands = control[:, t]
                force, delta, spin, _ = self.tyre_forces(current, commands[:, 0], commands[:, 1])
                row[:, 0, :2] = commands[:, :2]
                row[:, 0, chassis] = force
                roller.rollout(models, datas, current, row, control_spec=_CONTROL_SPEC, skip_checks=True,
                               nstep=1, state=out, sensordata=sens, chunk_size=chunk)  # fmt: skip
                current[:] = out[:, 0]
                current[:, delta_index] = delta
                current[:, loads] = sens[:, 0, touch]
                current[:, steer_index] = np.arctan(self._ackermann_tangents(delta)[:, :2])
                current[:, spin_index] = spin
                current[:, kin_index] = 0.0
                state[:, t] = current
                sensordata[:, t] = sens[:, 0]
        finally:
            if serial is not None:
                serial.close()

    def model_xml(self) -> str:
        """Text of the generated MJCF model (for fingerprints of cached simulations)."""
        return self.xml


__all__ = ["WHEELS", "TyreCar"]
