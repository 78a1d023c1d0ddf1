"""Tests for DeepRacer's obstacles and bot cars as the simapp computes them (sim.obstacles, sim.placement,
sim.bots, sim.object_params, sim.race_rules) and for common.race.

Expected values are worked out by hand or by transcribing the simapp's own formula here (aws-deepracer-community/
deepracer-simapp, ``bundle/markov/…``; each test names the file and function), with shapely on the raw waypoints,
independently of racer's own lane geometry (sim.lanes).
"""

from __future__ import annotations

import bisect
import math

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.interpolate import spalde, splprep
from shapely.geometry import LinearRing, Point, Polygon

from common.defaults import DEFAULT_TRACK, STRAIGHT_TRACK
from common.race import (
    HeadToBotConfig,
    ObjectAvoidanceConfig,
    ObstacleLane,
    ObstaclePosition,
    PenaltyConfig,
    RaceConfig,
    RaceType,
    parse_object_positions,
    race_config_from_drfc,
)
from sim.bots import CONTROL_DT_S, BotCars, RaceSetupError, object_progress, pause_steps
from sim.object_params import OBJECT_PARAM_KEYS, in_camera_view, object_params
from sim.obstacles import (
    BOT_CAR,
    BOT_CAR_OBSTACLE,
    CAR_CRASH_LENGTH_M,
    CAR_CRASH_WIDTH_M,
    FOOTPRINTS,
    WorldObject,
    as_boxes,
)
from sim.physics import FRONT_POINT_M, Pose
from sim.placement import Obstacles, obstacle_gap_m, place_obstacles
from sim.race_rules import car_at_fault, collided_object, is_crashed, reset_pose, start_pose
from sim.reward import PARAM_KEYS
from sim.track import Track, load_track
from tests.shared_data import needs_deepracer_tracks


@pytest.fixture(scope="module")
def loop() -> Track:
    """racer's default track: a counter-clockwise loop 0.76 m wide (lanes 0.19 m either side of the centre)."""
    return load_track(DEFAULT_TRACK)


@pytest.fixture(scope="module")
def cw_loop() -> Track:
    """A loop whose file runs clockwise (racer_loop mirrored)."""
    return load_track("racer_loop_cw")


@pytest.fixture(scope="module")
def wide() -> Track:
    """Another counter-clockwise loop, of other bends, 1.07 m wide."""
    return load_track("racer_wide")


def directed(track: Track, reverse: bool) -> np.ndarray:
    """The waypoint rows in the direction of travel (simapp ``TrackData``: ``waypoints[::-1]`` when reversed)."""
    return track.waypoints[::-1] if reverse else track.waypoints


def ring(points: np.ndarray) -> LinearRing:
    return LinearRing(points)


def pose_at(track: Track, frac: float, reverse: bool = False, lateral: float = 0.0) -> Pose:
    """base_link on the centre line (shifted ``lateral`` m to the left) at ``frac`` of the lap, facing along it."""
    t = track.reversed() if reverse else track
    p, heading = t.point_at(frac * t.length)
    return Pose(p[0] - lateral * math.sin(heading), p[1] + lateral * math.cos(heading), heading)


def box_at(track: Track, frac: float, lane: float, reverse: bool = False, kind: str = "box_obstacle") -> WorldObject:
    """An object at ``frac`` of the lap, ``lane`` m left of the centre line (inner lane ≈ +0.19 on a CCW loop)."""
    p = pose_at(track, frac, reverse, lateral=lane)
    return WorldObject.of(kind, p.x, p.y, p.yaw)


# ---------------------------------------------------------------------------------------------------------------
# The simapp's get_object_reward_params, transcribed (markov/track_geom/track_data.py: TrackData.get_object_reward_
# params; find_prev_next from track_geom/utils.py) for the params that do not need the camera.


def find_prev_next(a, x):
    next_index = bisect.bisect_right(a, x)
    prev_index = next_index - 1
    if prev_index == -1:
        prev_index = len(a) - 1
    if next_index == len(a):
        next_index = 0
    return prev_index, next_index


def simapp_params(track: Track, car: Pose, objects: list[WorldObject], reverse: bool) -> dict:
    wp = directed(track, reverse)
    center_line = ring(wp[:, 0:2])
    inner_poly = Polygon(ring(track.waypoints[:, 0:2]), [ring(track.waypoints[:, 2:4])])
    is_ccw = ring(track.waypoints[:, 0:2]).is_ccw ^ reverse
    locations = [[o.x, o.y] for o in objects]
    pdists = [center_line.project(Point(p)) for p in locations]
    model_point = Point(car.x + FRONT_POINT_M * math.cos(car.yaw), car.y + FRONT_POINT_M * math.sin(car.yaw))
    model_pdist = center_line.project(model_point)
    order = np.argsort(pdists)
    prev_i, next_i = find_prev_next([pdists[i] for i in order], model_pdist)
    return {
        "closest_objects": [order[prev_i], order[next_i]],
        "objects_location": locations,
        "objects_left_of_center": [inner_poly.contains(Point(p)) ^ (not is_ccw) for p in locations],
        "objects_distance_from_center": [center_line.distance(Point(p)) for p in locations],
        "objects_distance": pdists,
    }


def assert_matches_simapp(track, car, objects, reverse):
    got = object_params(track, car, objects, reverse)
    want = simapp_params(track, car, objects, reverse)
    assert got["closest_objects"] == want["closest_objects"]
    assert got["objects_location"] == want["objects_location"]
    assert got["objects_left_of_center"] == want["objects_left_of_center"]
    np.testing.assert_allclose(got["objects_distance"], want["objects_distance"], atol=1e-9)
    np.testing.assert_allclose(got["objects_distance_from_center"], want["objects_distance_from_center"], atol=1e-9)
    return got


# ---------------------------------------------------------------------------------------------------------------
# Time trial


def test_time_trial_gives_the_simapp_defaults(loop):
    """No objects: get_object_reward_params returns {} and the params keep RewardParam's defaults
    (markov/agent_ctrl/constants.py: RewardParam)."""
    assert object_params(loop, pose_at(loop, 0.1), [], False) == {}
    defaults = {
        "closest_objects": [0, 0],
        "objects_location": [],
        "objects_left_of_center": [],
        "object_in_camera": False,
        "objects_speed": [],
        "objects_heading": [],
        "objects_distance_from_center": [],
        "objects_distance": [],
    }
    assert set(OBJECT_PARAM_KEYS) == set(defaults) and set(OBJECT_PARAM_KEYS) < set(PARAM_KEYS)
    assert "is_crashed" in PARAM_KEYS and not is_crashed(pose_at(loop, 0.1), [])


def test_params_have_the_simapp_keys_in_its_order(loop):
    objs = [box_at(loop, 0.3, 0.19)]
    assert tuple(object_params(loop, pose_at(loop, 0.1), objs, False)) == OBJECT_PARAM_KEYS


# ---------------------------------------------------------------------------------------------------------------
# Object params


def test_object_behind_and_ahead(loop):
    """closest_objects = [behind, ahead] by centre-line distance; listing order kept; inner lane left on a CCW lap."""
    objs = [box_at(loop, 0.7, -0.19), box_at(loop, 0.3, 0.19), box_at(loop, 0.45, 0.19)]
    p = assert_matches_simapp(loop, pose_at(loop, 0.5), objs, False)
    assert p["closest_objects"] == [2, 0]
    assert all(type(i) is np.int64 for i in p["closest_objects"])  # np.argsort's indices, as in the simapp
    assert p["objects_left_of_center"] == [False, True, True]
    assert p["objects_location"][1] == [objs[1].x, objs[1].y]
    # The distances are metres along the centre line from the start line, unsorted.
    np.testing.assert_allclose(p["objects_distance"], np.array([0.7, 0.3, 0.45]) * loop.length, atol=0.02)
    np.testing.assert_allclose(p["objects_distance_from_center"], 0.19, atol=0.01)
    assert p["objects_heading"] == [0.0, 0.0, 0.0] and p["objects_speed"] == [0.0, 0.0, 0.0]


def test_closest_object_is_by_track_distance_not_euclidean(loop):
    """A car whose model point is just past an object: that object is 'behind' though it is the nearest."""
    car = pose_at(loop, 0.5)
    front_s = loop.project(car.ahead(FRONT_POINT_M)[None]).s[0]
    near = box_at(loop, (front_s - 0.05) / loop.length, 0.19)
    far = box_at(loop, 0.8, 0.19)
    p = assert_matches_simapp(loop, car, [far, near], False)
    assert p["closest_objects"] == [1, 0]


def test_object_across_the_seam(loop):
    """Car at 98 %, objects at 2 % and 50 %: the 2 % one is ahead (find_prev_next wraps), the 50 % one behind."""
    objs = [box_at(loop, 0.5, 0.19), box_at(loop, 0.02, -0.19)]
    p = assert_matches_simapp(loop, pose_at(loop, 0.98), objs, False)
    assert p["closest_objects"] == [0, 1]
    assert p["objects_distance"][1] == pytest.approx(0.02 * loop.length, abs=0.02)
    # Car at 1 %, behind the 2 % object: the 50 % one is behind it across the seam.
    p = assert_matches_simapp(loop, pose_at(loop, 0.01), objs, False)
    assert p["closest_objects"] == [0, 1]
    # One object: it is both behind and ahead.
    p = assert_matches_simapp(loop, pose_at(loop, 0.98), objs[1:], False)
    assert p["closest_objects"] == [0, 0]


def test_object_in_the_other_lane(loop, cw_loop, wide):
    """objects_left_of_center: inside the inner half road, XOR a clockwise lap (track_data.py)."""
    for track in (loop, wide):
        objs = [box_at(track, 0.4, 0.19), box_at(track, 0.6, -0.19)]
        p = assert_matches_simapp(track, pose_at(track, 0.1), objs, False)
        assert p["objects_left_of_center"] == [True, False]
    # racer_loop_cw's file runs clockwise: its inner border is on the right, so an object 0.2 m left is outside.
    assert cw_loop.clockwise
    objs = [box_at(cw_loop, 0.4, 0.2), box_at(cw_loop, 0.6, -0.2)]
    p = assert_matches_simapp(cw_loop, pose_at(cw_loop, 0.1), objs, False)
    assert p["objects_left_of_center"] == [True, False]


def test_reversed_direction(loop, cw_loop):
    """Reversed: distances run from the start line the other way, the inner lane is on the right."""
    fwd = [box_at(loop, 0.3, 0.19), box_at(loop, 0.6, -0.19)]  # inner lane at 30 %, outer at 60 %
    p = assert_matches_simapp(loop, pose_at(loop, 0.5, reverse=True), fwd, True)
    np.testing.assert_allclose(p["objects_distance"], np.array([0.7, 0.4]) * loop.length, atol=0.02)
    assert p["objects_left_of_center"] == [False, True]
    # The car at 50 % of the reversed lap (forward 50 %): the forward-60 % object (reversed 40 %) is behind it.
    assert p["closest_objects"] == [1, 0]
    for frac in (0.05, 0.55, 0.97):
        assert_matches_simapp(cw_loop, pose_at(cw_loop, frac, reverse=True), [box_at(cw_loop, 0.5, 0.2)], True)


@pytest.mark.parametrize(
    "name",
    [
        DEFAULT_TRACK,
        "racer_loop_cw",
        # DeepRacer's own files, which the simapp's formulas were written for: reinvent_base, and Spain_track, which
        # runs clockwise with unevenly spaced waypoints (0.11-0.32 m apart).
        pytest.param("reinvent_base", marks=needs_deepracer_tracks),
        pytest.param("Spain_track", marks=needs_deepracer_tracks),
    ],
)
def test_matches_the_simapp_at_random_poses(name):
    rng, track = np.random.default_rng(7), load_track(name)
    for reverse in (False, True):
        for _ in range(10):
            objs = [
                box_at(track, f, lane, reverse)
                for f, lane in zip(rng.random(4), rng.uniform(-0.3, 0.3, 4), strict=True)
            ]
            car = pose_at(track, rng.random(), reverse, rng.uniform(-0.2, 0.2))
            assert_matches_simapp(track, car, objs, reverse)


def test_bot_car_heading_is_radians_and_every_object_gets_the_bot_speed(loop):
    """track_data.py: with bot cars (NUMBER_OF_BOT_CARS > 0) every object reports its yaw from
    quaternion_to_euler (radians, though the docs say degrees) and BOT_CAR_SPEED."""
    bot = WorldObject.of(BOT_CAR, 1.0, 0.5, 2.5, speed=0.3)
    box = WorldObject.of("box_obstacle", 3.0, 0.8, -1.0)
    p = object_params(loop, pose_at(loop, 0.5), [box, bot], False)
    assert p["objects_heading"] == [-1.0, 2.5]
    assert p["objects_speed"] == [0.3, 0.3]
    parked = WorldObject.of(BOT_CAR_OBSTACLE, 1.0, 0.5, 2.5)  # IS_OBSTACLE_BOT_CAR: no bot cars running
    p = object_params(loop, pose_at(loop, 0.5), [parked], False)
    assert p["objects_heading"] == [0.0] and p["objects_speed"] == [0.0]


def test_object_in_camera_tests_the_object_before_the_one_ahead(loop):
    """track_data.py: get_objects_in_camera_frustums numbers ALL registered objects, the car itself first (index 0),
    while closest_objects numbers the others from 0; object_in_camera compares the two, so it is True when object
    closest_objects[1] - 1 is in view."""
    car = pose_at(loop, 0.02)  # the start straight
    ahead_1m = box_at(loop, 0.02 + 1.0 / loop.length, 0.0)
    ahead_2m = box_at(loop, 0.02 + 2.0 / loop.length, 0.0)
    behind = box_at(loop, 0.02 - 1.0 / loop.length, 0.0)
    # The object ahead is object 0: the simapp tests index 0, the car itself, which it never sees.
    assert object_params(loop, car, [ahead_1m, behind], False)["object_in_camera"] is False
    # The object ahead is object 1; object 0 (behind the car) is not in view.
    p = object_params(loop, car, [behind, ahead_1m], False)
    assert p["closest_objects"][1] == 1 and p["object_in_camera"] is False
    # The object ahead is object 1; object 0, 2 m ahead, is in view.
    p = object_params(loop, car, [ahead_2m, ahead_1m], False)
    assert p["closest_objects"][1] == 1 and p["object_in_camera"] is True


def test_camera_frustum_by_hand():
    """cameras/frustum.py (v3 camera 0.145 m ahead, 0.130 m up, pitched 0.2618 rad down, near plane 0.2 m, 65° wide):
    a box 1 m ahead is in view, one behind or 1 m to the side at 1 m ahead is not."""
    car = Pose(0.0, 0.0, 0.0)

    def seen(x: float, y: float) -> bool:
        return in_camera_view(car, WorldObject.of("box_obstacle", x, y, 0.0))

    assert seen(1.0, 0.0)
    assert not seen(-1.0, 0.0)
    assert not seen(1.0, 1.2)  # the view is ±0.7 m wide 1.1 m from the camera; the box's edge is at 1.0 m
    assert not seen(0.15, 0.0)  # under the camera, before the near plane
    assert seen(3.0, 1.2)  # further out the view is wider
    assert in_camera_view(Pose(1.0, 2.0, math.pi / 2), WorldObject.of(BOT_CAR, 1.0, 3.0, 0.0))


# ---------------------------------------------------------------------------------------------------------------
# Crash rule (track_data.py: get_collided_object_name, get_object_bounding_rect)


HALF_CAR_L, HALF_CAR_W = CAR_CRASH_LENGTH_M / 2, CAR_CRASH_WIDTH_M / 2
BOX = WorldObject.of("box_obstacle", 0.0, 0.0, 0.0)  # crash rectangle 0.5 (x) × 0.4 (y)


def test_crash_rectangles_are_the_simapp_dimensions():
    """ObstacleDimensions: BOX (0.4, 0.5) and BOT_CAR (0.1961, 0.32352) read as (width along y, length along x)."""
    assert (FOOTPRINTS["box_obstacle"].crash_length, FOOTPRINTS["box_obstacle"].crash_width) == (0.5, 0.4)
    assert (CAR_CRASH_LENGTH_M, CAR_CRASH_WIDTH_M) == (0.32352, 0.1961)
    assert (FOOTPRINTS["box_obstacle"].length, FOOTPRINTS["box_obstacle"].width) == (0.4, 0.3)  # model.sdf
    assert FOOTPRINTS["box_obstacle"].height == 0.25


@pytest.mark.parametrize("gap, crashed", [(-1e-6, True), (1e-6, False), (-0.1, True)])
def test_crash_head_on_into_a_box(gap, crashed):
    """The car's front corners reach x = -0.25 + -gap: inside the box's rectangle (x > -0.25) is a crash."""
    car = Pose(-0.25 - HALF_CAR_L - gap, 0.0, 0.0)
    assert is_crashed(car, [BOX]) is crashed


@pytest.mark.parametrize("gap, crashed", [(-1e-6, True), (1e-6, False)])
def test_crash_side_by_side(gap, crashed):
    """Beside the box: the car's left corners at y = -0.2 - gap."""
    car = Pose(0.0, -0.2 - HALF_CAR_W - gap, 0.0)
    assert is_crashed(car, [BOX]) is crashed


def test_crash_needs_a_car_corner_inside_the_object():
    """Only the car's corners are tested: a box turned 45° poking its corner 2 cm into the car's side, with no car
    corner inside the box, is no crash, though the rectangles overlap."""
    depth = (0.25 + 0.2) * math.sqrt(0.5)  # how far the turned box reaches below its centre
    box = WorldObject.of("box_obstacle", 0.0, HALF_CAR_W + depth - 0.02, math.pi / 4)
    car = Pose(0.0, 0.0, 0.0)
    car_poly = Polygon(
        [(HALF_CAR_L, HALF_CAR_W), (HALF_CAR_L, -HALF_CAR_W), (-HALF_CAR_L, -HALF_CAR_W), (-HALF_CAR_L, HALF_CAR_W)]
    )
    c, s = math.cos(box.yaw), math.sin(box.yaw)
    box_poly = Polygon(
        [
            (box.x + c * a - s * b, box.y + s * a + c * b)
            for a, b in ((0.25, 0.2), (0.25, -0.2), (-0.25, -0.2), (-0.25, 0.2))
        ]
    )
    assert car_poly.intersects(box_poly)
    assert not is_crashed(car, [box])


def test_crash_names_the_first_object_touched_and_bot_cars_count():
    bot = WorldObject.of(BOT_CAR, 1.0, 0.0, math.pi, speed=0.2)
    car = Pose(1.0 - 2 * HALF_CAR_L + 0.01, 0.0, 0.0)  # nose into the bot's nose
    assert collided_object(car, [BOX, bot]) == 1
    assert collided_object(Pose(5.0, 5.0, 0.0), [BOX, bot]) is None


def test_car_at_fault_compares_normalized_progress():
    """rollout_agent_ctrl.py _check_for_episode_termination: the car crashed if behind the bot, progress
    normalized by get_normalized_progress = (progress + start_ndist·100) % 100; no seam handling."""
    assert car_at_fault(30.0, 0.0, 31.0)
    assert not car_at_fault(32.0, 0.0, 31.0)
    assert car_at_fault(30.0, 0.5, 81.0)  # started at 50 %: it is at 80 %
    assert not car_at_fault(99.0, 0.0, 1.0)  # the bot just past the start line counts as behind


# ---------------------------------------------------------------------------------------------------------------
# Placement (obstacles_agent_ctrl.py: ObstaclesCtrl._compute_obstacle_poses)


def simapp_lane_pose(track: Track, reverse: bool, center_dist: float, outer: bool):
    """lane.interpolate_pose(lane.project(center_line.interpolate(d))) with CENTRAL_DIFFERENCE (track_data.py)."""
    wp = directed(track, reverse)
    center = ring(wp[:, 0:2])
    border = wp[:, 4:6] if outer else wp[:, 2:4]
    lane = ring((border + wp[:, 0:2]) / 2)
    d = lane.project(center.interpolate(center_dist))
    p = lane.interpolate(d)
    coords = list(lane.coords)
    ndists = [lane.project(Point(c), normalized=True) for c in coords[:-1]] + [1.0]
    prev_i, next_i = find_prev_next(ndists, d / lane.length)
    yaw = math.atan2(coords[next_i][1] - coords[prev_i][1], coords[next_i][0] - coords[prev_i][0])
    return p.x, p.y, yaw


@pytest.mark.parametrize("reverse", [False, True])
def test_fixed_positions(loop, reverse):
    cfg = ObjectAvoidanceConfig(object_positions=parse_object_positions("0.23,-1;0.46,1;0.7,-1"))
    objs = place_obstacles(loop, cfg, np.random.default_rng(0), reverse)
    assert [o.kind for o in objs] == ["box_obstacle"] * 3
    for o, (frac, outer) in zip(objs, [(0.23, True), (0.46, False), (0.7, True)], strict=True):
        x, y, yaw = simapp_lane_pose(loop, reverse, frac * loop.length, outer)
        assert (o.x, o.y, o.yaw) == pytest.approx((x, y, yaw), abs=1e-9)
    p = object_params(loop, pose_at(loop, 0.0, reverse), objs, reverse)
    assert p["objects_left_of_center"] == [reverse, not reverse, reverse]  # outer lane = right on a CCW lap
    np.testing.assert_allclose(p["objects_distance"], np.array([0.23, 0.46, 0.7]) * loop.length, atol=0.03)


def test_fixed_positions_override_count_and_randomization(wide):
    positions = [ObstaclePosition(progress=0.5, lane="outer")]
    cfg = ObjectAvoidanceConfig(number_of_obstacles=6, randomize_obstacle_locations=True, object_positions=positions)
    assert cfg.count == 1
    a = place_obstacles(wide, cfg, np.random.default_rng(1), False)
    b = place_obstacles(wide, cfg, np.random.default_rng(2), False)
    assert a == b and len(a) == 1


def test_evenly_spaced_defaults(loop):
    """Not randomized: np.linspace(gap, L - 1, n), lanes alternating inner, outer; gap = 2 % of L."""
    cfg = ObjectAvoidanceConfig()
    gap = 0.02 * loop.length
    assert obstacle_gap_m(cfg, loop.length) == pytest.approx(gap)
    objs = place_obstacles(loop, cfg, np.random.default_rng(0), False)
    expect = np.linspace(gap, loop.length - 1.0, 6)
    for o, d, outer in zip(objs, expect, [False, True] * 3, strict=True):
        assert (o.x, o.y, o.yaw) == pytest.approx(simapp_lane_pose(loop, False, d, outer), abs=1e-9)
    p = object_params(loop, pose_at(loop, 0.5), objs, False)
    assert p["objects_left_of_center"] == [True, False] * 3


def test_the_gap_compounds_over_episodes_as_in_the_simapp(loop):
    """_compute_obstacle_poses converts the percent to metres on every call, once at start-up and once per reset:
    the first episode uses 2·L²/10⁴ m, the next 2·L³/10⁶ m."""
    cfg = ObjectAvoidanceConfig()
    length = loop.length
    obstacles = Obstacles(loop, cfg)
    first = obstacles.reset(np.random.default_rng(0), False)
    assert obstacle_gap_m(cfg, length, 2) == pytest.approx(2.0 * length**2 / 1e4)
    # To rounding: 2·L²/10⁴ and the simapp's (2 / 100 · L) / 100 · L may differ in the last bit.
    want = place_obstacles(loop, cfg, np.random.default_rng(0), False, gap_m=2.0 * length**2 / 1e4)
    np.testing.assert_allclose(as_boxes(first), as_boxes(want), rtol=0, atol=1e-12)
    obstacles.reset(np.random.default_rng(0), False)
    assert obstacles.placements == 3
    second = place_obstacles(loop, cfg, np.random.default_rng(0), False, gap_m=2.0 * length**3 / 1e6)
    np.testing.assert_allclose(as_boxes(obstacles.objects), as_boxes(second), rtol=0, atol=1e-12)


def test_random_placement_keeps_the_minimum_distance(loop, wide):
    """Randomized: consecutive obstacles at least the gap apart along the centre line, all within [gap, L - 1]."""
    for track in (loop, wide):
        cfg = ObjectAvoidanceConfig(
            number_of_obstacles=5, min_distance_between_obstacles=10.0, randomize_obstacle_locations=True
        )
        gap = 0.1 * track.length
        lanes_seen, firsts = set(), set()
        for seed in range(100):
            objs = place_obstacles(track, cfg, np.random.default_rng(seed), seed % 2 == 1)
            p = object_params(track, pose_at(track, 0.0, seed % 2 == 1), objs, seed % 2 == 1)
            d = np.array(p["objects_distance"])
            assert np.all(np.diff(d) >= gap - 0.03), (seed, d)  # placed in order; lane → centre mapping ≈ 1 cm
            assert d[0] >= gap - 0.03 and d[-1] <= track.length - 1.0 + 0.03
            lanes_seen.update(p["objects_left_of_center"])
            firsts.add(round(d[0], 3))
        assert lanes_seen == {True, False} and len(firsts) > 50


def test_bot_car_as_obstacle(loop):
    cfg = ObjectAvoidanceConfig(number_of_obstacles=2, is_obstacle_bot_car=True, obstacle_type="amazon_box_obstacle")
    objs = place_obstacles(loop, cfg, np.random.default_rng(0), False)
    assert {o.kind for o in objs} == {BOT_CAR_OBSTACLE} and all(o.speed == 0.0 for o in objs)
    assert objs[0].length == 0.32352 and objs[0].height == pytest.approx(0.2108)


def test_as_boxes(loop):
    objs = place_obstacles(loop, ObjectAvoidanceConfig(number_of_obstacles=3), np.random.default_rng(0), False)
    boxes = as_boxes(objs)
    assert boxes.shape == (3, 6) and boxes.dtype == np.float64
    assert boxes[1].tolist() == [objs[1].x, objs[1].y, objs[1].yaw, 0.4, 0.3, 0.25]
    assert as_boxes([]).shape == (0, 6)


# ---------------------------------------------------------------------------------------------------------------
# Bot cars (bot_cars_agent_ctrl.py: BotCarsCtrl)


def simapp_lane_spline(track: Track, reverse: bool, outer: bool):
    """track_geom/spline/track_spline.py: TrackSpline._build_spline, transcribed with shapely on the raw rows."""
    wp = directed(track, reverse)
    center_line = ring(wp[:, 0:2])
    border = wp[:, 4:6] if outer else wp[:, 2:4]
    lane = ring((border + wp[:, 0:2]) / 2)
    length = center_line.length
    lane_dists = [center_line.project(Point(c)) for c in lane.coords]
    for i in range(len(lane_dists)):
        if lane_dists[i] < 0.5 * length:
            break
        lane_dists[i] -= length
    for i in range(len(lane_dists) - 1, 0, -1):
        if lane_dists[i] > 0.5 * length:
            break
        lane_dists[i] += length
    u, ui = np.unique(lane_dists, return_index=True)
    x = np.array(lane.coords.xy)[:, ui]
    if u[0] > 0.0:
        p0 = lane.interpolate(lane.project(Point(center_line.coords[0])))
        u[0] = 0.0
        x[:, :1] = p0.xy
    if u[-1] < length:
        pn = lane.interpolate(lane.project(Point(center_line.coords[-1])))
        u[-1] = length
        x[:, -1:] = pn.xy
    x[:, -1] = x[:, 0]
    return splprep(x, u=u, k=3, s=0, per=1)[0], length


def simapp_eval_spline(spline, dist: float) -> tuple[float, float, float]:
    """track_geom/spline/abstract_spline.py: eval_spline, and BotCarsCtrl._compute_bot_car_poses: (x, y, yaw)."""
    tck, length = spline
    min_dist, max_dist = tck[0][3], tck[0][-4]
    if dist < min_dist:
        dist += length
    if dist > max_dist:
        dist -= length
    d = spalde(max(min_dist, min(dist, max_dist)), tck)
    return d[0][0], d[1][0], math.atan2(d[1][1], d[0][1])


@pytest.mark.parametrize("name", [DEFAULT_TRACK, "racer_wide"])
@pytest.mark.parametrize("reverse", [False, True])
def test_bots_move_speed_times_dt_along_their_lane(name, reverse):
    """_get_dist_from_sim_time: (initial + elapsed · speed) % L, from np.linspace(min distance, L - 1, n); the pose
    is the lane spline at that distance (lanes alternate inner, outer, … when not randomized)."""
    track = load_track(name)
    cfg = HeadToBotConfig(number_of_bot_cars=3, bot_car_speed=0.5)
    bots = BotCars(track, cfg)
    bots.reset(np.random.default_rng(0), reverse)
    expect0 = np.linspace(2.0, track.length - 1.0, 3)
    np.testing.assert_allclose([bots.distance(i) for i in range(3)], expect0)
    splines = [simapp_lane_spline(track, reverse, outer) for outer in (False, True, False)]
    for steps in (0, 100, 300):
        while bots.time < steps * CONTROL_DT_S - 1e-9:
            bots.step()
        assert bots.time == pytest.approx(steps * CONTROL_DT_S)
        want = (expect0 + steps * CONTROL_DT_S * 0.5) % track.length
        np.testing.assert_allclose([bots.distance(i) for i in range(3)], want, atol=1e-9)
        for obj, spline, d in zip(bots.objects, splines, want, strict=True):
            assert (obj.x, obj.y, obj.yaw) == pytest.approx(simapp_eval_spline(spline, d), abs=1e-6)
            assert obj.speed == 0.5 and obj.kind == BOT_CAR
        p = object_params(track, pose_at(track, 0.0, reverse), bots.objects, reverse)
        # Near the lane: the spline is parametrized by the lane vertices' centre-line projections.
        err = (np.array(p["objects_distance"]) - want + track.length / 2) % track.length - track.length / 2
        assert np.all(np.abs(err) < 0.2), err
        assert p["objects_left_of_center"] == ([False, True, False] if reverse else [True, False, True])


def test_bots_step_distance_per_step(wide):
    bots = BotCars(wide, HeadToBotConfig(number_of_bot_cars=1, bot_car_speed=0.3))
    bots.reset(np.random.default_rng(0), True)
    d0 = bots.distance(0)
    bots.step()
    assert bots.distance(0) - d0 == pytest.approx(0.3 / 15.0)


def test_bots_run_the_reversed_direction(loop):
    bots = BotCars(loop, HeadToBotConfig(number_of_bot_cars=2))
    bots.reset(np.random.default_rng(0), True)
    for _ in range(30):
        objs = bots.step()
    p = object_params(loop, pose_at(loop, 0.0, True), objs, True)
    want = [bots.distance(i) for i in range(2)]
    np.testing.assert_allclose(p["objects_distance"], want, atol=0.03)
    assert p["objects_left_of_center"] == [False, True]  # inner lane is on the right of a reversed CCW lap
    rev = loop.reversed()
    for o, d in zip(objs, want, strict=True):
        _, heading = rev.point_at(d)
        assert abs((o.yaw - heading + math.pi) % (2 * math.pi) - math.pi) < math.radians(30)


def test_random_bot_start_positions_keep_the_minimum_distance(loop):
    cfg = HeadToBotConfig(number_of_bot_cars=4, randomize_bot_car_locations=True, min_distance_between_bot_cars=2.5)
    bots = BotCars(loop, cfg)
    for seed in range(50):
        bots.reset(np.random.default_rng(seed), False)
        d = np.array([bots.distance(i) for i in range(4)])
        assert np.all(np.diff(d) >= 2.5 - 1e-9) and d[0] >= 2.5 and d[-1] <= loop.length - 1.0


def test_lane_changes_happen_within_the_time_range(loop):
    """_compute_bot_car_lane_changes: first change ends U(lower, upper) + distance/speed after the first step;
    the bot then drives in the other lane, and changes again."""
    cfg = HeadToBotConfig(
        number_of_bot_cars=2,
        is_lane_change=True,
        lower_lane_change_time=1.0,
        upper_lane_change_time=2.0,
        lane_change_distance=0.6,
        bot_car_speed=0.4,
    )
    duration = 0.6 / 0.4
    for seed in range(5):
        bots = BotCars(loop, cfg)
        bots.reset(np.random.default_rng(seed), False)
        start_sides = object_params(loop, pose_at(loop, 0.0), bots.objects, False)["objects_left_of_center"]
        bots.step()
        ends = list(bots.lane_change_end_times)
        for e in ends:
            assert CONTROL_DT_S + 1.0 + duration <= e <= CONTROL_DT_S + 2.0 + duration
        while bots.time < max(ends) + 0.2:
            bots.step()
        sides = object_params(loop, pose_at(loop, 0.0), bots.objects, False)["objects_left_of_center"]
        assert sides == [not s for s in start_sides]
        p = object_params(loop, pose_at(loop, 0.0), bots.objects, False)
        np.testing.assert_allclose(p["objects_distance_from_center"], 0.19, atol=0.04)
        for e, previous in zip(bots.lane_change_end_times, ends, strict=True):  # the next change: U(lower, upper) later
            assert previous + 1.0 + duration <= e <= previous + CONTROL_DT_S + 2.0 + duration


@needs_deepracer_tracks
def test_lane_spline_seam_jump():
    """TrackSpline: when a lane's first vertex projects before the start line, its distance is made negative, the
    end of the lap is patched with a point at L, and then overwritten with the first vertex (periodic spline): the
    spline spans L + 0.15 m on Oval_track's outer lane and a bot there jumps ~0.15 m at each lap's seam. Kept."""
    oval = load_track("Oval_track")
    spline = simapp_lane_spline(oval, False, outer=True)
    jump = math.dist(simapp_eval_spline(spline, oval.length - 1e-9)[:2], simapp_eval_spline(spline, 0.0)[:2])
    assert jump == pytest.approx(0.149, abs=0.002)
    bots = BotCars(oval, HeadToBotConfig(number_of_bot_cars=2, min_distance_between_bot_cars=oval.length - 1.05))
    bots.reset(np.random.default_rng(0), False)  # bot 1: outer lane, 1.0 m before the seam, at 0.2 m/s
    while bots.distance(1) > 1.0:
        before = bots.objects[1]
        after = bots.step()[1]
    assert math.dist((before.x, before.y), (after.x, after.y)) == pytest.approx(jump + 0.2 / 15, abs=0.02)


@pytest.mark.parametrize("name", [DEFAULT_TRACK, "racer_wide"])
@pytest.mark.parametrize("reverse", [False, True])
def test_bots_drive_smoothly_through_lane_changes_and_the_seam(name, reverse):
    """Over a minute of lane changes (laps included): no jumps away from the lap's seam, and each bot crosses the
    centre line in every change."""
    track = load_track(name)
    cfg = HeadToBotConfig(
        number_of_bot_cars=3, is_lane_change=True, bot_car_speed=0.6, randomize_bot_car_locations=True
    )
    bots = BotCars(track, cfg)
    prev = bots.reset(np.random.default_rng(3), reverse)
    changes, min_offset = 0, np.full(3, np.inf)
    ends = bots.lane_change_end_times
    for _ in range(15 * 60):
        objs = bots.step()
        steps = np.hypot(*(as_boxes(objs)[:, :2] - as_boxes(prev)[:, :2]).T)
        near_seam = np.array([min(d, track.length - d) < 0.5 for d in map(bots.distance, range(3))])
        assert np.all((steps < 3 * 0.6 * CONTROL_DT_S) | near_seam), steps  # see test_lane_spline_seam_jump
        p = object_params(track, pose_at(track, 0.0, reverse), objs, reverse)
        min_offset = np.minimum(min_offset, p["objects_distance_from_center"])
        now = bots.lane_change_end_times
        for i in range(3):
            if now[i] != ends[i] and ends[i] > 0.0:  # a change just ended: it went through the middle
                assert min_offset[i] < 0.05
                changes += 1
                min_offset[i] = np.inf
        ends, prev = now, objs
    assert changes >= 3 * 5  # every 3-5 s + 1/0.6 s per change over 60 s


def test_bots_on_an_open_track():
    """_get_dist_from_sim_time wraps d mod L on an open track too: the bots jump from its end to its start. Lane
    changes across that jump break the simapp's splines, so racer refuses them there."""
    straight = load_track(STRAIGHT_TRACK)
    with pytest.raises(RaceSetupError, match="open track"):
        BotCars(straight, HeadToBotConfig(is_lane_change=True))
    cfg = HeadToBotConfig(number_of_bot_cars=1, min_distance_between_bot_cars=straight.length - 1.1, bot_car_speed=1.2)
    bots = BotCars(straight, cfg)
    bots.reset(np.random.default_rng(0), False)  # one bot: np.linspace(L - 1.1, L - 1, 1) = [L - 1.1]
    for _ in range(15):  # 1.2 m/s for 1 s: 0.1 m past the end
        bots.step()
    assert bots.distance(0) == pytest.approx(0.1, abs=1e-9)
    assert straight.project(as_boxes(bots.objects)[:, :2]).s[0] == pytest.approx(0.1, abs=0.03)


def test_no_lane_change_without_the_flag(loop):
    bots = BotCars(loop, HeadToBotConfig(number_of_bot_cars=2))
    bots.reset(np.random.default_rng(0), False)
    for _ in range(15 * 20):
        bots.step()
    p = object_params(loop, pose_at(loop, 0.0), bots.objects, False)
    assert p["objects_left_of_center"] == [True, False]


def test_bots_pause_after_running_into_the_car(wide):
    """judge_action: the bots stop for penalty_seconds (2.0 s: exactly 30 steps, as the simapp's pause_duration,
    counted down by the sim time, ends at the 30th step's judge_action) and their clock loses them
    (crash_count · penalty), so they resume one step's distance on from where they stopped."""
    bots = BotCars(wide, HeadToBotConfig(number_of_bot_cars=1))
    bots.reset(np.random.default_rng(0), False)
    for _ in range(30):
        bots.step()
    before = bots.objects
    d_before = bots.distance(0)
    bots.penalize()
    bots.penalize()  # ignored while paused
    assert bots.crash_count == 1 and bots.paused
    paused_steps = 0
    while bots.paused:
        assert bots.step() == before
        paused_steps += 1
    assert paused_steps == 30
    bots.step()
    assert bots.objects != before
    assert bots.distance(0) - d_before == pytest.approx(CONTROL_DT_S * 0.2, abs=1e-9)  # one step, not two


def test_a_pause_lasts_the_simapps_whole_steps():
    # pause_duration -= the step's sim time; the phase changes at the first judge_action with pause_duration <= 0.
    assert [pause_steps(s) for s in (0.0, 1.0, 2.0, 5.0, 2.1)] == [1, 15, 30, 75, 32]


def test_object_progress_is_the_bot_front_point(loop):
    obj = box_at(loop, 0.5, 0.0, kind=BOT_CAR)
    assert object_progress(loop, False, obj) == pytest.approx(50.0 + FRONT_POINT_M / loop.length * 100, 1e-3)


# ---------------------------------------------------------------------------------------------------------------
# Start and reset poses (rollout_agent_ctrl.py: _get_car_start_model_state, _get_car_reset_model_state)


def test_reset_behind_an_obstacle_in_the_other_lane(loop):
    obstacle = box_at(loop, 0.5, 0.19)  # inner lane
    s_obs = loop.project(np.array([[obstacle.x, obstacle.y]])).s[0]
    car = pose_at(loop, 0.5, lateral=0.19)
    pose = reset_pose(loop, False, s_obs - 0.3, car, [obstacle], behind_m=1.0)
    proj = loop.project(np.array([[pose.x, pose.y]]))
    assert proj.s[0] == pytest.approx(s_obs - 1.0, abs=0.03)
    assert proj.lateral[0] == pytest.approx(-0.19, abs=0.02)  # outer lane
    # Mercy reset: past it.
    pose = reset_pose(loop, False, s_obs, car, [obstacle], ahead_m=1.0)
    assert loop.project(np.array([[pose.x, pose.y]])).s[0] == pytest.approx(s_obs + 1.0, abs=0.03)


def test_reset_without_obstacle_goes_to_the_nearest_lane(loop):
    far_obstacle = box_at(loop, 0.9, 0.19)
    for lateral, want in ((0.3, 0.19), (-0.4, -0.19)):
        car = pose_at(loop, 0.3, lateral=lateral)
        pose = reset_pose(loop, False, 0.3 * loop.length, car, [far_obstacle])
        proj = loop.project(np.array([[pose.x, pose.y]]))
        assert proj.lateral[0] == pytest.approx(want, abs=0.02)
        assert proj.s[0] == pytest.approx(0.3 * loop.length, abs=0.03)


def test_training_start_avoids_an_object_at_the_start(loop):
    bot = box_at(loop, 0.2 + 0.5 / loop.length, -0.19, kind=BOT_CAR)  # outer lane, 0.5 m ahead
    pose = start_pose(loop, False, 0.2 * loop.length, [bot])
    assert loop.project(np.array([[pose.x, pose.y]])).lateral[0] == pytest.approx(0.19, abs=0.02)
    pose = start_pose(loop, False, 0.6 * loop.length, [bot])  # nothing within 1 m: centre line
    assert loop.project(np.array([[pose.x, pose.y]])).lateral[0] == pytest.approx(0.0, abs=1e-9)


# ---------------------------------------------------------------------------------------------------------------
# common.race


def test_race_defaults():
    race = RaceConfig()
    assert race.race_type is RaceType.TIME_TRIAL and race.obstacle_count == 0 and race.bot_car_count == 0
    oa, h2b, pen = ObjectAvoidanceConfig(), HeadToBotConfig(), PenaltyConfig()
    assert (oa.number_of_obstacles, oa.min_distance_between_obstacles, oa.randomize_obstacle_locations) == (
        6,
        2.0,
        False,
    )
    assert (oa.obstacle_type, oa.is_obstacle_bot_car, oa.object_positions) == ("box_obstacle", False, [])
    assert (h2b.number_of_bot_cars, h2b.bot_car_speed, h2b.min_distance_between_bot_cars) == (3, 0.2, 2.0)
    assert (h2b.is_lane_change, h2b.lower_lane_change_time, h2b.upper_lane_change_time) == (False, 3.0, 5.0)
    assert (h2b.lane_change_distance, h2b.penalty_seconds) == (1.0, 2.0)
    assert (pen.off_track_penalty, pen.collision_penalty, pen.reverse_penalty_s, pen.number_of_resets) == (
        2.0,
        5.0,
        2.0,
        0,
    )
    assert RaceConfig(race_type="OBJECT_AVOIDANCE").obstacle_count == 6


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda: ObstaclePosition(progress=23, lane=1), "write 0.23"),
        (lambda: ObstaclePosition(progress=0.2, lane="left"), "lane must be"),
        (lambda: ObstaclePosition(progress=0.2, lane=0), "lane"),
        (lambda: HeadToBotConfig(lower_lane_change_time=6.0), "above upper_lane_change_time"),
        (lambda: HeadToBotConfig(bot_car_speed=0.0), "greater than 0"),
        (lambda: PenaltyConfig(number_of_resets=1), "0 or at least 2"),
        (lambda: ObjectAvoidanceConfig(obstacle_type="crate"), "box_obstacle"),
        (lambda: RaceConfig(race_type="F1"), "TIME_TRIAL"),
        (lambda: ObjectAvoidanceConfig(number_of_obstacle=3), "Extra inputs"),
    ],
)
def test_validation_errors_are_clear(build, message):
    with pytest.raises(ValidationError, match=message):
        build()


def test_parse_object_positions():
    positions = parse_object_positions("0.23,-1;0.46,1")
    assert [(p.progress, p.lane) for p in positions] == [(0.23, ObstacleLane.OUTER), (0.46, ObstacleLane.INNER)]
    assert parse_object_positions("") == []
    with pytest.raises(ValueError, match="progress,lane"):
        parse_object_positions("0.23")


def test_race_from_drfc_template():
    """defaults/template-run.env values, mapped as scripts/{training,evaluation}/prepare-config.py map them."""
    env = {
        "DR_RACE_TYPE": "OBJECT_AVOIDANCE",
        "DR_OA_NUMBER_OF_OBSTACLES": "6",
        "DR_OA_MIN_DISTANCE_BETWEEN_OBSTACLES": "2.0",
        "DR_OA_RANDOMIZE_OBSTACLE_LOCATIONS": "False",
        "DR_OA_IS_OBSTACLE_BOT_CAR": "False",
        "DR_OA_OBSTACLE_TYPE": "box_obstacle",
        "DR_OA_OBJECT_POSITIONS": "",
        "DR_EVAL_OFF_TRACK_PENALTY": "5.0",
        "DR_EVAL_COLLISION_PENALTY": "7.0",  # DRfC's evaluation script never reads this one
        "DR_EVAL_MAX_RESETS": "100",
    }
    race = race_config_from_drfc(env, evaluation=True)
    assert race.race_type is RaceType.OBJECT_AVOIDANCE and race.obstacle_count == 6
    assert not race.object_avoidance.randomize_obstacle_locations
    assert (race.penalties.off_track_penalty, race.penalties.collision_penalty) == (5.0, 5.0)
    assert race.penalties.number_of_resets == 100
    training = race_config_from_drfc({**env, "DR_OA_OBJECT_POSITIONS": "0.1,1;0.5,-1"})
    assert training.obstacle_count == 2 and training.penalties.number_of_resets == 0
    h2b = race_config_from_drfc(
        {
            "DR_RACE_TYPE": "HEAD_TO_BOT",
            "DR_H2B_NUMBER_OF_BOT_CARS": "3",
            "DR_H2B_BOT_CAR_PENALTY": "5.0",
            "DR_H2B_IS_LANE_CHANGE": "True",
        }
    )
    assert (h2b.bot_car_count, h2b.head_to_bot.penalty_seconds, h2b.head_to_bot.is_lane_change) == (3, 5.0, True)
    with pytest.raises(ValueError, match="True or False"):
        race_config_from_drfc({"DR_RACE_TYPE": "HEAD_TO_BOT", "DR_H2B_IS_LANE_CHANGE": "yes"})
