"""The privileged teacher's state vector (common/privileged.py): hand-built tracks of known shape, and a real env."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.privileged import LOOKAHEAD_M, STATE_SIZE, state_vector

N_AHEAD = len(LOOKAHEAD_M)
AHEAD = slice(6, 6 + 2 * N_AHEAD)
OBJECTS = slice(6 + 2 * N_AHEAD, STATE_SIZE)


def _params(waypoints, closest, x, y, heading, *, left=True, dist=0.0, width=1.0, **extra):
    """A DeepRacer params dict with the keys the state vector reads (the rest as a time trial has them)."""
    return {
        "x": x,
        "y": y,
        "heading": heading,
        "speed": 2.0,
        "steering_angle": -15.0,
        "distance_from_center": dist,
        "is_left_of_center": left,
        "track_width": width,
        "waypoints": waypoints,
        "closest_waypoints": closest,
        "objects_location": [],
        **extra,
    }


def _ahead(vec: np.ndarray) -> np.ndarray:
    """(len(LOOKAHEAD_M), 2): the scaled (forward, left) of each point ahead."""
    return vec[AHEAD].reshape(N_AHEAD, 2)


# --- (a) a straight open track along +x, a waypoint every 0.1 m from x = 0 to 10 m ---

STRAIGHT = [(0.1 * i, 0.0) for i in range(101)]


def test_straight_track_centred_and_aligned_reads_unit_forward_points_and_scaled_speed_steering():
    vec = state_vector(_params(STRAIGHT, [30, 31], 3.05, 0.0, 0.0))
    np.testing.assert_allclose(_ahead(vec), np.tile([1.0, 0.0], (N_AHEAD, 1)), atol=1e-6)
    assert vec[0] == pytest.approx(0.5) and vec[1] == pytest.approx(-0.5)  # 2 m/s / 4, -15° / 30
    assert vec[2] == pytest.approx(0.0, abs=1e-6) and vec[3] == pytest.approx(1.0)
    assert vec[4] == pytest.approx(0.0) and vec[5] == pytest.approx(0.5)


def test_straight_track_car_left_of_centre_gives_positive_offset_and_points_to_its_right():
    vec = state_vector(_params(STRAIGHT, [30, 31], 3.05, 0.2, 0.0, left=True, dist=0.2, width=1.0))
    assert vec[4] == pytest.approx(0.4)  # 0.2 m / (1.0 m / 2)
    np.testing.assert_allclose(_ahead(vec)[:, 1], [-0.2 / d for d in LOOKAHEAD_M], rtol=1e-5)
    np.testing.assert_allclose(_ahead(vec)[:, 0], 1.0, atol=1e-6)
    right = state_vector(_params(STRAIGHT, [30, 31], 3.05, -0.2, 0.0, left=False, dist=0.2, width=1.0))
    assert right[4] == pytest.approx(-0.4)
    assert (_ahead(right)[:, 1] > 0).all()


@pytest.mark.parametrize("heading, sin", [(90.0, 1.0), (-90.0, -1.0)])
def test_straight_track_90_degree_heading_error_has_the_sign_of_the_turn(heading, sin):
    vec = state_vector(_params(STRAIGHT, [30, 31], 3.05, 0.0, heading))
    assert vec[2] == pytest.approx(sin) and vec[3] == pytest.approx(0.0, abs=1e-6)
    # Pointing left (+90°), the road ahead lies to the car's right, and vice versa.
    np.testing.assert_allclose(_ahead(vec), np.tile([0.0, -sin], (N_AHEAD, 1)), atol=1e-6)


def test_open_track_points_ahead_clamp_at_its_end():
    vec = state_vector(_params(STRAIGHT, [98, 99], 9.8, 0.0, 0.0))
    # The end is 0.2 m ahead: every point ahead is the last row, so forward = 0.2 / L.
    np.testing.assert_allclose(_ahead(vec)[:, 0], [0.2 / d for d in LOOKAHEAD_M], rtol=1e-5)
    past = state_vector(_params(STRAIGHT, [100, 0], 10.05, 0.0, 0.0))  # DeepRacer's [n-1, 0] past the end
    np.testing.assert_allclose(_ahead(past)[:, 0], [-0.05 / d for d in LOOKAHEAD_M], rtol=1e-4)
    assert np.isfinite(past).all()


def test_a_repeated_waypoint_row_changes_nothing():
    doubled = [*STRAIGHT[:31], STRAIGHT[30], *STRAIGHT[31:]]  # row 30 twice: a zero-length segment 30 -> 31
    plain = state_vector(_params(STRAIGHT, [30, 31], 3.0, 0.0, 10.0))
    vec = state_vector(_params(doubled, [30, 31], 3.0, 0.0, 10.0))
    np.testing.assert_allclose(vec, plain, atol=1e-6)


# --- (b) a circular loop of radius R, a waypoint every ~0.05 m, closed (last row = first row) ---

R = 2.0
N_SEG = round(2 * math.pi * R / 0.05)


def _circle(ccw: bool) -> list[tuple[float, float]]:
    sign = 1.0 if ccw else -1.0
    rows = [
        (R * math.cos(sign * 2 * math.pi * k / N_SEG), R * math.sin(sign * 2 * math.pi * k / N_SEG))
        for k in range(N_SEG)
    ]
    return [*rows, rows[0]]


def _on_circle(waypoints, k: int, ccw: bool):
    """Params of a centred car on waypoint ``k``, heading along the circle's tangent in the direction of travel."""
    x, y = waypoints[k]
    heading = math.degrees(math.atan2(y, x)) + (90.0 if ccw else -90.0)
    heading = (heading + 180.0) % 360.0 - 180.0
    nxt = 0 if k == len(waypoints) - 1 else k + 1
    return _params(waypoints, [k, nxt], x, y, heading)


def _circle_expected(sign: float) -> np.ndarray:
    """Hand formula: the point L along a circle of radius R, in the frame of a car on it facing along it."""
    return np.array([(R * math.sin(d / R) / d, sign * R * (1 - math.cos(d / R)) / d) for d in LOOKAHEAD_M])


@pytest.mark.parametrize("ccw, sign", [(True, 1.0), (False, -1.0)])
def test_circle_points_ahead_follow_the_hand_formula_left_for_ccw_right_for_cw(ccw, sign):
    waypoints = _circle(ccw)
    vec = state_vector(_on_circle(waypoints, 40, ccw))
    got, want = _ahead(vec), _circle_expected(sign)
    np.testing.assert_allclose(got, want, rtol=0.02, atol=1e-3)
    assert (np.sign(got[:, 1]) == sign).all()
    assert abs(vec[2]) < 0.02 and vec[3] > 0.999  # the tangent heading matches the chord within half a step


@pytest.mark.parametrize("k", [N_SEG - 3, N_SEG - 1, N_SEG])
def test_circle_lookahead_wraps_across_the_loops_closing_row(k):
    waypoints = _circle(True)
    vec = state_vector(_on_circle(waypoints, k, True))  # k = N_SEG is the closing row: closest [n-1, 0]
    np.testing.assert_allclose(_ahead(vec), _circle_expected(1.0), rtol=0.02, atol=1e-3)
    assert abs(vec[2]) < 0.02 and vec[3] > 0.999


# --- (c) objects ---


def test_objects_only_those_ahead_nearest_first():
    objects = [(2.0, 0.0), (6.0, 0.3), (4.0, -0.2), (9.5, 0.0)]  # behind, 3 m ahead, 1 m ahead, beyond 5 m
    vec = state_vector(_params(STRAIGHT, [30, 31], 3.0, 0.0, 0.0, objects_location=objects))
    np.testing.assert_allclose(vec[OBJECTS], [1.0, 0.2, -0.2, 1.0, 0.6, 0.3], atol=1e-6)


def test_objects_are_seen_in_the_cars_frame():
    # Heading +90°: forward is +y, left is -x; the object at (3, -1) is behind, (2.5, 2) is 2 m ahead and 0.5 m left.
    vec = state_vector(_params(STRAIGHT, [30, 31], 3.0, 0.0, 90.0, objects_location=[[3.0, -1.0], [2.5, 2.0]]))
    np.testing.assert_allclose(vec[OBJECTS], [1.0, 0.4, 0.5, 0.0, 1.0, 0.0], atol=1e-6)


@pytest.mark.parametrize("objects", [[], None, "missing"])
def test_no_objects_reads_absent_twice(objects):
    params = _params(STRAIGHT, [30, 31], 3.0, 0.0, 0.0)
    if objects == "missing":
        del params["objects_location"]
    else:
        params["objects_location"] = objects
    np.testing.assert_array_equal(state_vector(params)[OBJECTS], [0.0, 1.0, 0.0, 0.0, 1.0, 0.0])


# --- (d) type, size and a real env ---


def test_vector_is_float32_finite_and_state_size():
    vec = state_vector(_params(STRAIGHT, [30, 31], 3.0, 0.0, 0.0, width=0.0))  # even a zero track width
    assert STATE_SIZE == 24
    assert vec.dtype == np.float32 and vec.shape == (STATE_SIZE,)
    assert np.isfinite(vec).all()


def test_real_env_params_give_a_finite_vector_with_the_offsets_sign():
    from sim.env import RacerEnv

    env = RacerEnv()
    try:
        _, info = env.reset(seed=0)
        infos = [info]
        for _ in range(8):
            _, _, terminated, truncated, info = env.step(env.action_space.sample())
            infos.append(info)
            if terminated or truncated:
                break
        for info in infos:
            p = info["params"]
            vec = state_vector(p)
            assert vec.dtype == np.float32 and vec.shape == (STATE_SIZE,)
            assert np.isfinite(vec).all()
            assert abs(vec[4]) == pytest.approx(p["distance_from_center"] / (p["track_width"] / 2), rel=1e-5, abs=1e-6)
            assert vec[4] >= 0 if p["is_left_of_center"] else vec[4] <= 0
            assert vec[5] == pytest.approx(p["track_width"] / 2, rel=1e-6)
        # At the start the car stands on the centre line, aligned with it, and the road runs on ahead of it.
        start = state_vector(infos[0]["params"])
        assert start[3] > 0.9
        assert (_ahead(start)[:, 0] > 0).all()
    finally:
        env.close()
