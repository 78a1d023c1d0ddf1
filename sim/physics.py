"""Physics wrapper: named accessors on the MuJoCo car (pose, speed, wheels) and command input."""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from common.car_calibration import CarCalibration
from sim.actuation import Actuation
from sim.world import PHYSICS_SUBSTEPS

WHEEL_RADIUS_M = 0.035
WHEELBASE_M = 0.164
TRACK_WIDTH_M = 0.16
FRONT_POINT_M = 0.14
"""DeepRacer reports x, y at this distance ahead of base_link (the midpoint between the axles)."""
MAX_STEERING_DEG = 30.0
SPEED_RANGE_MPS = (0.1, 4.0)
_WHEELS = ("fl", "fr", "rl", "rr")
_CAR_FIELDS = (
    "body_mass",
    "body_inertia",
    "body_ipos",
    "body_iquat",
    "actuator_gainprm",
    "actuator_biasprm",
    "actuator_forcerange",
)
"""The model fields a car file's model effects write (``CarPhysics.set_calibration``)."""


@dataclass(frozen=True)
class Pose:
    """Planar pose of base_link: position (m) and yaw (rad, counter-clockwise from +x)."""

    x: float
    y: float
    yaw: float

    def ahead(self, distance: float) -> np.ndarray:
        """The point ``distance`` metres ahead along the car's heading."""
        return np.array([self.x + distance * math.cos(self.yaw), self.y + distance * math.sin(self.yaw)])


@dataclass(frozen=True)
class PhysicsSnapshot:
    """A saved state of one :class:`CarPhysics` (see :meth:`CarPhysics.snapshot`)."""

    data: mujoco.MjData
    target: tuple[float, float]
    effects: object | None
    """The calibrated effects' state (``sim.actuation``'s), None for a car without them."""


def yaw_of_quaternion(w, x, y, z):
    """Yaw (rad) of a MuJoCo quaternion (w, x, y, z): floats, or numpy arrays element by element."""
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


class CarPhysics:
    """The car in its world. Commands are steering angle (deg, + = left) and speed (m/s)."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self._root_q = model.jnt_qposadr[model.joint("car_root").id]
        self._root_v = model.jnt_dofadr[model.joint("car_root").id]
        self._drive = [model.actuator(f"{w}_drive").id for w in _WHEELS]
        self._steer = [model.actuator(f"{w}_steer").id for w in ("fl", "fr")]
        self._steer_q = [model.jnt_qposadr[model.joint(f"{w}_steer").id] for w in ("fl", "fr")]
        self._car_body = model.body("car").id
        self._wheel_bodies = [model.body(f"{w}_wheel").id for w in _WHEELS]
        self._hinge_bodies = [model.body(f"{w}_steer").id for w in ("fl", "fr")]
        self._tyres = [model.geom(f"{w}_tyre").id for w in _WHEELS]
        self._tyre_friction = model.geom_friction[self._tyres, 0].copy()
        # The compiled car, restored before each calibration writes its own values over it.
        self._compiled = {name: getattr(model, name).copy() for name in _CAR_FIELDS}
        self._model_changed = False  # whether a calibration changed the compiled masses or drives
        self._mass = model.body_mass.copy()
        self._inertia = model.body_inertia.copy()
        self._height = float(model.body_pos[self._car_body, 2])
        self._pose: Pose | None = None  # cached until the state changes
        self._actuation: Actuation | None = None
        self._target = (0.0, 0.0)

    def set_calibration(self, calibration: CarCalibration | None) -> None:
        """Apply a car file (a preset, or ``racer calibrate``'s): its model effects (tyre friction, body masses
        and inertias, wheel drives) on the MuJoCo model, and its effects between the command and the servos.
        None or no effects: the car as modelled. Undoes any earlier calibration and domain randomization."""
        calibration = calibration or CarCalibration()
        self._tyre_friction[:] = calibration.value("tyre_friction", "mu")
        self.model.geom_friction[self._tyres, 0] = self._tyre_friction
        self._set_model_effects(calibration)
        if calibration.is_identity or not calibration.acts_on_commands:
            self._actuation = None
        else:
            self._actuation = Actuation(calibration, float(self.model.opt.timestep))

    def _set_model_effects(self, cal: CarCalibration) -> None:
        """Write the car file's masses, inertias and drives into the model (the compiled values where absent)."""
        changes = any(cal.has(e) for e in ("chassis", "wheels", "drive"))
        if not (changes or self._model_changed):
            return  # the compiled car, untouched: bit for bit the model of sim/assets/car.xml
        m = self.model
        for name, value in self._compiled.items():
            getattr(m, name)[:] = value
        if cal.has("chassis"):
            c = self._car_body
            m.body_mass[c] = cal.value("chassis", "mass_kg")
            m.body_ipos[c] = (cal.value("chassis", "com_x_m"), 0.0, cal.value("chassis", "com_z_m"))
            m.body_iquat[c] = (1.0, 0.0, 0.0, 0.0)  # inertia given about the car's own axes
            m.body_inertia[c] = [cal.value("chassis", f"i{a}{a}_kgm2") for a in "xyz"]
        if cal.has("wheels"):
            spin, cross = cal.value("wheels", "spin_inertia_kgm2"), cal.value("wheels", "cross_inertia_kgm2")
            m.body_mass[self._wheel_bodies] = cal.value("wheels", "mass_kg")
            m.body_inertia[self._wheel_bodies] = (cross, spin, cross)  # the wheel spins about its y axis
            m.body_mass[self._hinge_bodies] = cal.value("wheels", "hinge_mass_kg")
        if cal.has("drive"):
            torque = cal.value("drive", "max_torque_nm")
            for wheel, act in zip(_WHEELS, self._drive, strict=True):
                gain = cal.value("drive", "rear_gain_nms" if wheel[0] == "r" else "front_gain_nms")
                m.actuator_gainprm[act, 0] = gain  # a velocity servo: force = gain · ctrl - gain · velocity
                m.actuator_biasprm[act, 2] = -gain
                m.actuator_forcerange[act] = (-torque, torque)
        # Constants MuJoCo derives from the masses at compile time (constraint scaling, mean inertia): refresh
        # them for the new car, on scratch data (mj_setConst moves the state it is given to qpos0).
        mujoco.mj_setConst(m, mujoco.MjData(m))
        self._model_changed = changes
        self._mass = m.body_mass.copy()
        self._inertia = m.body_inertia.copy()

    def reset(self, pose: Pose) -> None:
        """Place the car at rest at ``pose`` with wheels straight."""
        mujoco.mj_resetData(self.model, self.data)
        q = self.data.qpos
        q[self._root_q : self._root_q + 3] = (pose.x, pose.y, self._height)
        q[self._root_q + 3 : self._root_q + 7] = (math.cos(pose.yaw / 2), 0.0, 0.0, math.sin(pose.yaw / 2))
        mujoco.mj_forward(self.model, self.data)
        self._pose = None
        self._target = (0.0, 0.0)
        if self._actuation is not None:
            self._actuation.reset()

    def snapshot(self) -> PhysicsSnapshot:
        """Everything the car's future depends on: the MuJoCo state, the command held and the effects' memory.
        :meth:`restore` puts it back bit for bit, so a controller may try commands ahead and leave no trace."""
        data = mujoco.MjData(self.model)
        mujoco.mj_copyData(data, self.model, self.data)
        effects = None if self._actuation is None else self._actuation.save()
        return PhysicsSnapshot(data, self._target, effects)

    def restore(self, snapshot: PhysicsSnapshot) -> None:
        """Back to a :meth:`snapshot` of this car (the snapshot stays usable for further restores)."""
        mujoco.mj_copyData(self.data, self.model, snapshot.data)
        self._target = snapshot.target
        if self._actuation is not None:
            self._actuation.load(snapshot.effects)
        self._pose = None

    def set_dynamics(self, friction_scale: float = 1.0, mass_scale: float = 1.0) -> None:
        """Scale tyre friction and all body masses (domain randomization); 1.0 restores the car as calibrated."""
        self.model.geom_friction[self._tyres, 0] = self._tyre_friction * friction_scale
        self.model.body_mass[:] = self._mass * mass_scale
        self.model.body_inertia[:] = self._inertia * mass_scale

    def command(self, steering_deg: float, speed_mps: float) -> None:
        """Command the car until the next step: both front hinges to the steering angle, all wheels to the speed
        (through the calibration's effects, if one is set)."""
        self._target = (steering_deg, speed_mps)
        self._set_servos(steering_deg, speed_mps)

    def _set_servos(self, steering_deg: float, speed_mps: float) -> None:
        self.data.ctrl[self._steer] = math.radians(steering_deg)
        self.data.ctrl[self._drive] = speed_mps / WHEEL_RADIUS_M

    def control_vectors(self, steering_deg: np.ndarray, speed_mps: np.ndarray) -> np.ndarray:
        """(..., nu) MuJoCo ctrl arrays for servo targets given as arrays of the same shape."""
        ctrl = np.zeros((*np.shape(steering_deg), self.model.nu))
        ctrl[..., self._steer] = np.radians(steering_deg)[..., None]
        ctrl[..., self._drive] = (np.asarray(speed_mps) / WHEEL_RADIUS_M)[..., None]
        return ctrl

    def step(self, substeps: int = PHYSICS_SUBSTEPS) -> None:
        """Advance the physics by one control period."""
        if self._actuation is None:
            mujoco.mj_step(self.model, self.data, nstep=substeps)
        else:
            # The effects change the servo targets within the control period: one MuJoCo step per substep.
            for steer, speed in zip(*self._actuation.step(*self._target, substeps), strict=True):
                self._set_servos(steer, speed)
                mujoco.mj_step(self.model, self.data)
        # mj_step leaves positions derived from qpos (wheels, camera) one substep stale: refresh them.
        mujoco.mj_kinematics(self.model, self.data)
        self._pose = None

    @property
    def time(self) -> float:
        """Simulated time since reset, s."""
        return float(self.data.time)

    @property
    def pose(self) -> Pose:
        """Planar pose of base_link."""
        if self._pose is None:
            self._pose = self._read_pose()
        return self._pose

    def _read_pose(self) -> Pose:
        q = self.data.qpos
        x, y = q[self._root_q], q[self._root_q + 1]
        yaw = float(yaw_of_quaternion(*q[self._root_q + 3 : self._root_q + 7]))
        return Pose(float(x), float(y), yaw)

    @property
    def speed(self) -> float:
        """Forward speed of base_link along the car's heading, m/s."""
        v = self.data.qvel[self._root_v : self._root_v + 2]
        yaw = self.pose.yaw
        return float(v[0] * math.cos(yaw) + v[1] * math.sin(yaw))

    @property
    def yaw_rate(self) -> float:
        """Yaw rate, rad/s."""
        return float(self.data.qvel[self._root_v + 5])

    @property
    def steering_deg(self) -> float:
        """Measured mean front hinge angle, degrees."""
        return math.degrees(float(np.mean(self.data.qpos[self._steer_q])))

    @property
    def upright(self) -> bool:
        """False if the car has tipped over (body z axis more than 60° from vertical)."""
        return bool(self.data.xmat[self._car_body, 8] > 0.5)

    def wheel_positions(self) -> np.ndarray:
        """(4, 2) ground positions of the wheel centres (fl, fr, rl, rr), metres."""
        return self.data.geom_xpos[self._tyres, :2].copy()
