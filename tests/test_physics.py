"""The car model: DeepRacer's dimensions, its servos, and that it drives like a car."""

import math

import mujoco
import numpy as np
import pytest

from common.defaults import DEFAULT_TRACK
from sim.env import RacerEnv
from sim.physics import WHEEL_RADIUS_M, CarPhysics, Pose
from sim.texture import TextureFrame
from sim.track import load_track
from sim.world import CONTROL_HZ, PHYSICS_SUBSTEPS, build_model


@pytest.fixture(scope="module")
def physics() -> CarPhysics:
    track = load_track(DEFAULT_TRACK)
    return CarPhysics(build_model(TextureFrame.for_track(track)))


def drive(ph: CarPhysics, pose: Pose, steer: float, speed: float, steps: int) -> None:
    ph.reset(pose)
    ph.command(steer, speed)
    for _ in range(steps):
        ph.step()


def test_dimensions_match_deepracer(physics):
    m = physics.model
    pos = {n: m.body(n).pos for n in ("fl_steer", "fr_steer", "rl_wheel", "rr_wheel")}
    assert pos["fl_steer"][0] - pos["rl_wheel"][0] == pytest.approx(0.164)  # wheelbase
    assert pos["fl_steer"][1] - pos["fr_steer"][1] == pytest.approx(0.16)  # track width
    assert m.geom("fl_tyre").size[0] == pytest.approx(0.035)
    assert 1.5 <= m.body_subtreemass[m.body("car").id] <= 5.0
    assert m.opt.timestep * PHYSICS_SUBSTEPS == pytest.approx(1 / CONTROL_HZ)


def test_actuators_velocity_per_wheel_position_per_hinge(physics):
    m = physics.model
    names = {m.actuator(i).name for i in range(m.nu)}
    assert names == {"fl_drive", "fr_drive", "rl_drive", "rr_drive", "fl_steer", "fr_steer"}
    assert m.actuator("fl_drive").trntype == 0 and m.actuator("fl_steer").trntype == 0
    # The servo limits the angle to DeepRacer's ±30°; the mechanical stop sits beyond it, never reached.
    assert np.degrees(m.actuator_ctrlrange[m.actuator("fl_steer").id]).tolist() == pytest.approx([-30, 30], abs=1e-3)
    assert np.degrees(m.jnt_range[m.joint("fl_steer").id]).tolist() == pytest.approx([-34, 34])


def test_full_lock_stays_off_the_mechanical_stop(physics):
    drive(physics, Pose(0, 0, 0), 30.0, 2.0, 30)
    assert 29.0 < physics.steering_deg < 31.0
    active = physics.data.efc_type[: physics.data.nefc]
    assert int(mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT) not in active.tolist()


def test_reset_puts_car_at_rest_at_pose(physics):
    physics.reset(Pose(1.0, 2.0, 0.7))
    p = physics.pose
    assert (p.x, p.y, p.yaw) == pytest.approx((1.0, 2.0, 0.7))
    assert physics.speed == 0.0
    assert physics.upright


@pytest.mark.parametrize("yaw", [0.0, 0.5, 1.2, -2.5])
def test_drives_straight_at_commanded_speed_in_any_heading(physics, yaw):
    drive(physics, Pose(1.0, 2.0, yaw), 0.0, 1.0, 15)  # 1 s
    p = physics.pose
    lateral = -(p.x - 1.0) * math.sin(yaw) + (p.y - 2.0) * math.cos(yaw)
    assert physics.speed == pytest.approx(1.0, rel=0.03)
    assert abs(lateral) < 0.002 and abs(p.yaw - yaw) < 0.002


def test_wheel_speed_command_is_speed_over_radius(physics):
    physics.reset(Pose(0, 0, 0))
    physics.command(10.0, 2.0)
    assert physics.data.ctrl[physics.model.actuator("rl_drive").id] == pytest.approx(2.0 / WHEEL_RADIUS_M)
    assert physics.data.ctrl[physics.model.actuator("fr_steer").id] == pytest.approx(math.radians(10.0))


def test_steering_reaches_command_and_turns_left_for_positive_angle(physics):
    drive(physics, Pose(0, 0, 0), 15.0, 0.5, 8)
    assert physics.steering_deg == pytest.approx(15.0, abs=0.5)
    assert physics.yaw_rate > 0 and physics.pose.yaw > 0
    drive(physics, Pose(0, 0, 0), -15.0, 0.5, 8)
    assert physics.yaw_rate < 0


def test_turn_rate_close_to_kinematic_at_low_speed(physics):
    # An ideal car before calibration: at 0.5 m/s and 10° the yaw rate is within 20 % of v/L·tan(δ).
    drive(physics, Pose(0, 0, 0), 10.0, 0.5, 30)
    kinematic = physics.speed / 0.164 * math.tan(math.radians(10.0))
    assert physics.yaw_rate == pytest.approx(kinematic, rel=0.2)


def test_dynamics_randomization_scales_and_restores(physics):
    m = physics.model
    mass0, fric0 = m.body_mass.copy(), m.geom_friction[m.geom("fl_tyre").id, 0]
    physics.set_dynamics(friction_scale=0.5, mass_scale=1.5)
    assert m.geom_friction[m.geom("fl_tyre").id, 0] == pytest.approx(0.5 * fric0)
    assert m.body_mass == pytest.approx(1.5 * mass0)
    physics.set_dynamics()
    assert m.body_mass == pytest.approx(mass0)


def test_wheel_positions_are_the_four_corners(physics):
    physics.reset(Pose(0, 0, 0))
    w = physics.wheel_positions()
    assert w == pytest.approx(np.array([[0.082, 0.08], [0.082, -0.08], [-0.082, 0.08], [-0.082, -0.08]]), abs=1e-6)


def test_env_render_rgb_array_shows_the_track():
    env = RacerEnv(track=DEFAULT_TRACK, render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.shape[1] == 800
    assert (img == (220, 30, 30)).all(axis=2).sum() > 20  # the car is drawn


def test_snapshot_restores_the_car_bit_for_bit_with_its_effects_memory():
    """A controller may try commands ahead on the car itself (racer limit's line follower): after ``restore`` the
    same commands give the same states, the lagged steering included."""
    from common.car_calibration import load_car
    from sim.car_limits import _plain_physics

    car = _plain_physics(load_car("deepracer-gazebo"))  # a 0.5 s steering lag and a speed lag: state to keep
    car.reset(Pose(0.0, 0.0, 0.0))
    for _ in range(10):
        car.command(20.0, 2.0)
        car.step()
    saved = car.snapshot()

    def drive() -> np.ndarray:
        for _ in range(8):
            car.command(-25.0, 3.0)
            car.step()
        return car.data.qpos.copy()

    first = drive()
    car.restore(saved)
    assert car.steering_deg > 5.0  # back where the wheels were turning left, not where the trial left them
    assert np.array_equal(drive(), first)
    car.restore(saved)
    car.command(20.0, 2.0)  # the snapshot's own continuation differs from the trial's
    car.step()
    assert not np.array_equal(car.data.qpos, first)
