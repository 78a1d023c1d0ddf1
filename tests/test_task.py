"""Tests for sim.task (RacingTask: params, progress, statuses) and the gymnasium env built on it."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import sim  # noqa: F401  (registers sim:Racer-v0)
from common.defaults import DEFAULT_TRACK
from sim.env import OBS_SHAPE, RacerEnv, make_env
from sim.physics import FRONT_POINT_M, Pose
from sim.reward import PARAM_KEYS
from sim.task import REVERSED_WINDOW_STEPS, TERMINAL, RacingTask, Status
from sim.track import Track, load_track
from sim.track_gen import racer_track_names
from tests.shared_data import deepracer_track_names, needs_deepracer_tracks

N = 60  # waypoints of the synthetic circle
R = 2.0  # centre-line radius of the synthetic circle
CHORD = 2 * R * math.sin(math.pi / N)  # length of one centre-line segment of the circle
LAP = N * CHORD  # polyline length of the circle


def circle_array() -> np.ndarray:
    """Counter-clockwise ring road: centre radius 2 m, borders at 1.6 and 2.4 m, closing row repeated."""
    theta = 2 * np.pi * np.arange(N + 1) / N
    c, s = np.cos(theta), np.sin(theta)
    arr = np.column_stack([R * c, R * s, 1.6 * c, 1.6 * s, 2.4 * c, 2.4 * s])
    arr[-1] = arr[0]
    return arr


def straight_array() -> np.ndarray:
    """Open straight road along +x from 0 to 10 m, 1 m wide, 9 waypoints 1.25 m apart."""
    x = np.linspace(0.0, 10.0, 9)
    y = np.zeros_like(x)
    return np.column_stack([x, y, x, y + 0.5, x, y - 0.5])


@pytest.fixture
def straight() -> RacingTask:
    return RacingTask(Track.from_array(straight_array(), name="straight"))


@pytest.fixture
def circle() -> RacingTask:
    return RacingTask(Track.from_array(circle_array(), name="circle"))


def wheels(pose: Pose) -> np.ndarray:
    """Wheel centres (fl, fr, rl, rr) of a car at pose: axles 0.082 m either side of base_link, 0.08 m out."""
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    local = [(0.082, 0.08), (0.082, -0.08), (-0.082, 0.08), (-0.082, -0.08)]
    return np.array([(pose.x + c * a - s * b, pose.y + s * a + c * b) for a, b in local])


def observe(task: RacingTask, pose: Pose, command=(0.0, 1.0), upright: bool = True, sim_time: float = 0.0, **kw):
    return task.observe(pose, kw.pop("wheel_points", wheels(pose)), upright, sim_time, command, **kw)


def circle_pose(k: float, reverse: bool = False) -> Pose:
    """base_link at waypoint k of the circle (driven CCW, or CW with reverse), facing along the chord k→k+1."""
    step = 2 * math.pi / N
    if reverse:
        angle = -k * step
        return Pose(R * math.cos(angle), R * math.sin(angle), angle - math.pi / 2 - step / 2)
    angle = k * step
    return Pose(R * math.cos(angle), R * math.sin(angle), angle + math.pi / 2 + step / 2)


def prepare(task: RacingTask, index: int, reverse: bool = False):
    """begin() an episode and make the prepare observation at the start pose, as the env does."""
    task.begin(index, reverse)
    pose = task.start_pose(index, reverse)
    return observe(task, pose, command=(0.0, 0.0), count_step=False)


# --- params on the straight open track -----------------------------------------------------------


def test_params_at_known_pose_on_straight(straight):
    first = prepare(straight, 0)
    assert first.status == Status.PREPARE
    assert first.terminated is False
    assert first.params["steps"] == 1  # DeepRacer's prepare step is step 1
    assert first.params["progress"] == pytest.approx(100 * FRONT_POINT_M / 10.0)

    res = observe(straight, Pose(2.0, 0.1, 0.0), command=(12.5, 0.8), sim_time=0.4)
    p = res.params
    assert set(p) == set(PARAM_KEYS)
    assert len(p) == 27
    assert res.status == Status.IN_PROGRESS
    assert res.terminated is False
    assert p["x"] == pytest.approx(2.14)
    assert p["y"] == pytest.approx(0.1)
    assert p["heading"] == pytest.approx(0.0)
    assert p["distance_from_center"] == pytest.approx(0.1)
    assert p["projection_distance"] == pytest.approx(2.14)
    assert p["is_left_of_center"] is True
    assert p["closest_waypoints"] == [1, 2]  # waypoints at x = 1.25 and 2.5
    assert p["track_width"] == pytest.approx(1.0)
    assert p["track_length"] == pytest.approx(10.0)
    assert p["progress"] == pytest.approx(21.4)  # front point 2.14 m along a 10 m track, started at waypoint 0
    assert p["steps"] == 2  # the simapp's first rewarded step
    assert p["speed"] == 0.8
    assert p["steering_angle"] == 12.5
    assert p["sim_time"] == 0.4
    assert p["is_reversed"] is False
    assert p["all_wheels_on_track"] is True
    assert p["is_offtrack"] is False
    assert p["is_crashed"] is False
    assert p["waypoints"] == [(x, 0.0) for x in np.linspace(0.0, 10.0, 9)]
    assert p["closest_objects"] == [0, 0]
    assert p["object_in_camera"] is False
    for key in (
        "objects_location",
        "objects_left_of_center",
        "objects_speed",
        "objects_heading",
        "objects_distance_from_center",
        "objects_distance",
    ):
        assert p[key] == []


def test_params_right_of_center_and_steps_count(straight):
    prepare(straight, 0)
    for k in range(1, 4):
        res = observe(straight, Pose(1.0 + 0.5 * k, -0.2, 0.0))
        assert res.params["steps"] == k + 1
    assert res.params["is_left_of_center"] is False
    assert res.params["distance_from_center"] == pytest.approx(0.2)
    assert res.params["x"] == pytest.approx(2.64)
    assert res.params["closest_waypoints"] == [2, 3]


def test_open_track_progress_is_measured_from_the_start_waypoint(straight):
    first = prepare(straight, 2)  # waypoint 2 is at x = 2.5: 7.5 m remain to the end
    assert first.params["progress"] == pytest.approx(100 * 0.14 / 7.5)
    res = observe(straight, Pose(4.0, 0.0, 0.0))
    assert res.params["progress"] == pytest.approx(100 * (4.14 - 2.5) / 7.5)


def test_open_track_lap_completes_at_the_end(straight):
    prepare(straight, 0)
    res = observe(straight, Pose(9.0, 0.0, 0.0))
    assert res.status == Status.IN_PROGRESS
    res = observe(straight, Pose(9.9, 0.0, 0.0))
    assert res.status == Status.LAP_COMPLETE
    assert res.terminated is True
    assert res.params["progress"] == 100.0


# --- heading ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "yaw",
    [0.0, 0.3, math.pi / 2, -math.pi / 2, 3.0, -3.0, math.pi, 2 * math.pi + 0.2, -2 * math.pi - 0.2, 5 * math.pi / 2],
)
def test_heading_is_degrees_in_half_open_range(straight, yaw):
    prepare(straight, 0)
    heading = observe(straight, Pose(5.0, 0.0, yaw)).params["heading"]
    assert -180.0 < heading <= 180.0
    assert math.cos(math.radians(heading)) == pytest.approx(math.cos(yaw))
    assert math.sin(math.radians(heading)) == pytest.approx(math.sin(yaw), abs=1e-12)


def test_heading_facing_minus_y_is_minus_90(straight):
    prepare(straight, 0)
    assert observe(straight, Pose(5.0, 0.0, -math.pi / 2)).params["heading"] == pytest.approx(-90.0)
    assert observe(straight, Pose(5.0, 0.0, math.pi)).params["heading"] == pytest.approx(180.0)


def test_heading_facing_minus_x_with_yaw_minus_pi_is_180(straight):
    prepare(straight, 0)
    assert observe(straight, Pose(5.0, 0.0, -math.pi)).params["heading"] == 180.0


# --- progress on the circle ------------------------------------------------------------------------


def test_circle_start_progress_is_the_front_offset(circle):
    first = prepare(circle, 0)
    assert first.params["progress"] == pytest.approx(100 * FRONT_POINT_M / LAP)
    assert first.params["track_length"] == pytest.approx(LAP)


def test_circle_quarter_lap_progress(circle):
    prepare(circle, 0)
    for k in range(1, 16):
        res = observe(circle, circle_pose(k))
        assert res.status == Status.IN_PROGRESS
        assert res.params["progress"] == pytest.approx(100 * (k * CHORD + FRONT_POINT_M) / LAP)
    assert res.params["progress"] == pytest.approx(25.0 + 100 * FRONT_POINT_M / LAP)
    assert res.params["closest_waypoints"] == [15, 16]
    assert res.params["distance_from_center"] == pytest.approx(0.0, abs=1e-9)


def test_circle_progress_keeps_increasing_across_the_start_line(circle):
    prepare(circle, 50)
    last = 100 * FRONT_POINT_M / LAP
    for k in range(51, 66):  # waypoints 60..65 are 0..5 again: across the start line
        res = observe(circle, circle_pose(k))
        progress = res.params["progress"]
        assert progress > last
        assert progress == pytest.approx(100 * ((k - 50) * CHORD + FRONT_POINT_M) / LAP)
        last = progress
    assert res.params["closest_waypoints"] == [5, 6]
    assert res.status == Status.IN_PROGRESS


def test_circle_last_segment_is_the_closing_row_in_closest_waypoints(circle):
    # simapp find_prev_next: waypoints keep the loop's closing row (60 = 0), so the last segment is [59, 60].
    prepare(circle, 58)
    res = observe(circle, circle_pose(59))  # front point on the chord 59→60 (= 0)
    assert res.params["closest_waypoints"] == [59, 60]
    assert len(res.params["waypoints"]) == 61


def test_circle_full_lap_completes(circle):
    prepare(circle, 0)
    for k in range(1, N):
        res = observe(circle, circle_pose(k))
        assert res.status == Status.IN_PROGRESS, k
    assert res.params["progress"] == pytest.approx(100 * ((N - 1) * CHORD + FRONT_POINT_M) / LAP)
    assert res.params["progress"] < 100
    res = observe(circle, circle_pose(N))
    assert res.status == Status.LAP_COMPLETE
    assert res.terminated is True
    assert res.params["progress"] == 100.0


# --- statuses ---------------------------------------------------------------------------------------


def test_off_track_when_all_wheels_are_off(circle):
    prepare(circle, 0)
    pose = circle_pose(1)
    off = np.array([[3.0, 0.0], [3.0, 0.2], [3.1, 0.0], [3.1, 0.2]])
    res = observe(circle, pose, wheel_points=off)
    assert res.status == Status.OFF_TRACK
    assert res.terminated is True
    assert res.params["is_offtrack"] is True
    assert res.params["all_wheels_on_track"] is False


def test_one_wheel_on_track_is_still_in_progress(circle):
    prepare(circle, 0)
    pose = circle_pose(1)
    one_on = np.array([[3.0, 0.0], [3.0, 0.2], [3.1, 0.0], [2.3, 0.1]])
    res = observe(circle, pose, wheel_points=one_on)
    assert res.status == Status.IN_PROGRESS
    assert res.terminated is False
    assert res.params["is_offtrack"] is False
    assert res.params["all_wheels_on_track"] is False


def test_wheels_in_the_hole_are_off_track(circle):
    prepare(circle, 0)
    in_hole = np.array([[1.0, 0.0], [1.0, 0.2], [1.2, 0.0], [1.2, 0.2]])
    assert observe(circle, circle_pose(1), wheel_points=in_hole).status == Status.OFF_TRACK


def test_reversed_when_backing_up_along_the_track(straight):
    prepare(straight, 4)  # x = 5
    for k in range(1, REVERSED_WINDOW_STEPS + 1):
        res = observe(straight, Pose(5.0 - 0.02 * k, 0.0, 0.0), command=(0.0, 0.5))
        if k < REVERSED_WINDOW_STEPS:
            assert res.status == Status.IN_PROGRESS, k
    assert res.status == Status.REVERSED  # 0.3 m backwards within 15 steps
    assert res.terminated is True


def test_reversed_when_turned_round_and_driving_the_wrong_way(circle):
    prepare(circle, 20)
    statuses = []
    for k in range(1, 20):
        # Facing clockwise at waypoint 20 - k/4: a quarter chord (5 cm) further back along the track each step.
        res = observe(circle, circle_pose(-(20 - 0.25 * k), reverse=True))
        statuses.append(res.status)
        if res.terminated:
            break
    assert statuses[-1] == Status.REVERSED
    assert statuses[:-1] == [Status.IN_PROGRESS] * (len(statuses) - 1)
    assert len(statuses) == REVERSED_WINDOW_STEPS


def test_slow_backward_drift_below_threshold_is_not_reversed(straight):
    prepare(straight, 4)
    for k in range(1, 25):
        res = observe(straight, Pose(5.0 - 0.005 * k, 0.0, 0.0))  # 0.075 m per 15 steps < 0.1 m
        assert res.status == Status.IN_PROGRESS, k


def test_immobilized_when_not_moving_for_a_window(straight):
    prepare(straight, 4)
    pose = straight.start_pose(4, False)
    statuses = [observe(straight, pose).status for _ in range(REVERSED_WINDOW_STEPS + 1)]
    assert statuses[: REVERSED_WINDOW_STEPS - 1] == [Status.IN_PROGRESS] * (REVERSED_WINDOW_STEPS - 1)
    assert statuses[REVERSED_WINDOW_STEPS - 1] == Status.IMMOBILIZED  # 15 steps (1 s) after the prepare row
    assert Status.IMMOBILIZED in TERMINAL


def test_immobilized_when_not_upright(straight):
    prepare(straight, 0)
    res = observe(straight, Pose(1.0, 0.0, 0.0), upright=False)
    assert res.status == Status.IMMOBILIZED
    assert res.terminated is True


def test_moving_car_is_not_immobilized(straight):
    prepare(straight, 0)
    for k in range(1, 40):
        assert observe(straight, Pose(0.05 * k, 0.0, 0.0)).status == Status.IN_PROGRESS


# --- the reversed direction ------------------------------------------------------------------------


def test_reverse_direction_progress_increases_clockwise(circle):
    first = prepare(circle, 0, reverse=True)
    assert first.params["is_reversed"] is True
    assert first.params["progress"] == pytest.approx(100 * FRONT_POINT_M / LAP)
    assert first.params["waypoints"][0] == pytest.approx((2.0, 0.0))
    assert first.params["waypoints"][1] == pytest.approx(tuple(circle_array()[N - 1, :2]))
    last = first.params["progress"]
    for k in range(1, 16):
        res = observe(circle, circle_pose(k, reverse=True))
        assert res.params["is_reversed"] is True
        assert res.status == Status.IN_PROGRESS
        assert res.params["progress"] > last
        last = res.params["progress"]
    assert last == pytest.approx(25.0 + 100 * FRONT_POINT_M / LAP)
    assert res.params["y"] < 0  # a quarter lap clockwise from (2, 0) is near (0, -2)


def test_is_left_of_center_flips_with_direction(circle):
    point = 2.1 * np.array([math.cos(0.5), math.sin(0.5)])  # outside the centre line

    def base_for(yaw: float) -> Pose:
        return Pose(point[0] - FRONT_POINT_M * math.cos(yaw), point[1] - FRONT_POINT_M * math.sin(yaw), yaw)

    prepare(circle, 0)
    fwd = observe(circle, base_for(0.5 + math.pi / 2)).params
    prepare(circle, 0, reverse=True)
    rev = observe(circle, base_for(0.5 - math.pi / 2)).params
    assert (fwd["x"], fwd["y"]) == pytest.approx(tuple(point))
    assert (rev["x"], rev["y"]) == pytest.approx(tuple(point))
    assert fwd["is_left_of_center"] is False  # outside is right of counter-clockwise travel
    assert rev["is_left_of_center"] is True
    assert fwd["distance_from_center"] == pytest.approx(rev["distance_from_center"])
    assert fwd["distance_from_center"] == pytest.approx(0.1, abs=0.01)


# --- through the real env --------------------------------------------------------------------------


def straight_ahead_action(env: RacerEnv, speed: float = 1.0) -> int:
    return next(a for a in range(env.actions.n) if env.actions.command(a) == (0.0, speed))


@pytest.fixture(scope="module")
def base_env():
    env = gymnasium.make("sim:Racer-v0", track=DEFAULT_TRACK)
    yield env
    env.close()


@needs_deepracer_tracks
def test_env_reset_params_match_deepracer_first_row():
    # DeepRacer's own first row of a reinvent_base episode: track_length 17.709, progress 0.7905 (the front point
    # 0.14 m past the start line).
    env = gymnasium.make("sim:Racer-v0", track="reinvent_base")
    obs, info = env.reset(seed=0)
    env.close()
    assert obs.shape == OBS_SHAPE
    assert obs.dtype == np.uint8
    assert info["episode_status"] == "prepare"
    params = info["params"]
    assert set(params) == set(PARAM_KEYS)
    assert params["steps"] == 1 and info["steps"] == 0
    assert params["track_length"] == pytest.approx(17.709, abs=1e-3)
    assert params["progress"] == pytest.approx(100 * 0.14 / 17.709, abs=1e-3)
    assert params["progress"] == pytest.approx(0.7905, abs=1e-3)


def test_env_reset_on_racers_loop_starts_the_front_point_past_the_line(base_env):
    _, info = base_env.reset(seed=0, options={"start_index": 0})
    params = info["params"]
    assert params["steps"] == 1 and params["track_length"] == pytest.approx(17.6, abs=0.01)
    assert params["progress"] == pytest.approx(100 * 0.14 / params["track_length"], abs=1e-3)


def test_env_driving_straight_ends_terminated(base_env):
    env = base_env.unwrapped
    action = straight_ahead_action(env)
    assert env.actions.command(action) == (0.0, 1.0)
    base_env.reset(seed=0, options={"start_index": 0})
    for _ in range(600):
        _, reward, terminated, truncated, info = base_env.step(action)
        assert np.isfinite(reward)
        if terminated or truncated:
            break
    assert terminated is True
    assert truncated is False
    assert info["episode_status"] in (Status.OFF_TRACK, Status.LAP_COMPLETE)


def test_env_time_limit_truncates_with_time_up():
    env = make_env(DEFAULT_TRACK, time_limit_steps=5)
    env.reset(seed=0, options={"start_index": 0})
    action = straight_ahead_action(env, 0.5)
    for k in range(1, 6):
        _, _, terminated, truncated, info = env.step(action)
        assert terminated is False
        assert truncated is (k == 5)
    assert info["episode_status"] == Status.TIME_UP
    assert info["steps"] == 5 and info["params"]["steps"] == 6


def test_gymnasium_make_time_limit_truncates_with_time_up():
    # Our own limit: gymnasium.make keeps ``max_episode_steps`` for its TimeLimit wrapper.
    env = gymnasium.make("sim:Racer-v0", track=DEFAULT_TRACK, time_limit_steps=5)
    env.reset(seed=0, options={"start_index": 0})
    action = straight_ahead_action(env.unwrapped, 0.5)
    for k in range(1, 6):
        _, _, terminated, truncated, info = env.step(action)
        assert terminated is False
        assert truncated is (k == 5)
    assert info["episode_status"] == Status.TIME_UP


def run_episode(seed: int, actions: np.ndarray) -> tuple[list[np.ndarray], list[float], list]:
    env = gymnasium.make("sim:Racer-v0", track=DEFAULT_TRACK)
    obs, info = env.reset(seed=seed)
    observations, rewards, poses = [obs], [], [info["pose"]]
    for action in actions:
        obs, reward, terminated, truncated, info = env.step(int(action))
        observations.append(obs)
        rewards.append(reward)
        poses.append(info["pose"])
        if terminated or truncated:
            break
    env.close()
    return observations, rewards, poses


def test_env_same_seed_same_actions_is_deterministic():
    actions = np.random.default_rng(123).integers(10, size=50)
    obs_a, rew_a, poses_a = run_episode(7, actions)
    obs_b, rew_b, poses_b = run_episode(7, actions)
    assert len(obs_a) == len(obs_b) > 1
    for a, b in zip(obs_a, obs_b, strict=True):
        np.testing.assert_array_equal(a, b)
    assert rew_a == rew_b
    assert poses_a == poses_b


def test_env_different_seeds_start_at_different_places(base_env):
    _, info0 = base_env.reset(seed=0)
    _, info1 = base_env.reset(seed=1)
    _, info0_again = base_env.reset(seed=0)
    assert info0["pose"] == info0_again["pose"]
    assert (info0["pose"].x, info0["pose"].y) != pytest.approx((info1["pose"].x, info1["pose"].y), abs=1e-3)


def test_env_passes_gymnasium_env_checker():
    env = gymnasium.make("sim:Racer-v0", track=DEFAULT_TRACK)
    check_env(env.unwrapped)
    env.close()


def test_env_reverse_start_option(base_env):
    rev = base_env.unwrapped.track.reversed()
    _, info = base_env.reset(seed=0, options={"start_index": 10, "reverse": True})
    pose = info["pose"]
    assert (pose.x, pose.y) == pytest.approx(tuple(rev.center[10]), abs=1e-6)
    d = rev.center[11] - rev.center[10]
    assert math.cos(pose.yaw - math.atan2(d[1], d[0])) == pytest.approx(1.0, abs=1e-6)
    params = info["params"]
    assert params["is_reversed"] is True
    assert params["waypoints"][10] == pytest.approx(tuple(rev.center[10]))
    assert params["closest_waypoints"][0] in (10, 11)


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize(
    "name", racer_track_names() + [pytest.param(n, marks=needs_deepracer_tracks) for n in deepracer_track_names()]
)
def test_gymnasium_make_every_track(name):
    # racer's own tracks, and every DeepRacer route (all 127, _cw/_ccw variants and championship tracks included,
    # read in place from ../shared): each loads, passes the track checks and drives.
    env = gymnasium.make("sim:Racer-v0", track=name)
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert info["params"]["track_length"] == pytest.approx(load_track(name).length)
    for _ in range(3):
        obs, reward, _, _, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs)
        assert np.isfinite(reward)
    assert info["params"]["steps"] == 4
    env.close()


def test_gymnasium_make_with_npy_path(tmp_path: Path):
    path = tmp_path / "ring.npy"
    np.save(path, circle_array())
    env = gymnasium.make("sim:Racer-v0", track=str(path))
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert info["params"]["track_length"] == pytest.approx(LAP)
    assert info["params"]["progress"] == pytest.approx(100 * FRONT_POINT_M / LAP)
    for _ in range(3):
        obs, _, _, _, info = env.step(env.action_space.sample())
    assert info["params"]["steps"] == 4
    env.close()
