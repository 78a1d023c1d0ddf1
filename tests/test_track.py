"""Tests for sim.track: bundled tracks, .npy loading and validation, and the centre-line geometry."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from sim.track import Track, TrackError, bundled_track_names, load_track

# Reference centre-line lengths (m) of the bundled tracks, whose sources sim/tracks/LICENSE names; kept here as
# literals so that the loader is checked against fixed figures rather than against itself.
EXPECTED_LENGTH_M = {
    "reinvent_base": 17.71,
    "Oval_track": 19.55,
    "Bowtie_track": 17.43,
    "AWS_track": 69.25,
    "H_track": 100.85,
    "reInvent2019_track": 23.12,
    "reInvent2019_wide": 16.64,
    "Straight_track": 5.71,
    "Vegas_track": 22.55,
    "Tokyo_Training_track": 22.63,
    "2022_summit_speedway": 25.17,
    "Spain_track": 60.00,
}

CIRCLE_POINTS = 60
CIRCLE_R, CIRCLE_R_IN, CIRCLE_R_OUT = 2.0, 1.6, 2.4


def circle_array(n: int = CIRCLE_POINTS) -> np.ndarray:
    """A counter-clockwise ring road: centre radius 2 m, borders at 1.6 and 2.4 m; closing row repeated."""
    theta = 2 * np.pi * np.arange(n + 1) / n
    c, s = np.cos(theta), np.sin(theta)
    radii = (CIRCLE_R, CIRCLE_R, CIRCLE_R_IN, CIRCLE_R_IN, CIRCLE_R_OUT, CIRCLE_R_OUT)
    arr = np.column_stack([r * v for r, v in zip(radii, (c, s) * 3, strict=True)])
    arr[-1] = arr[0]
    return arr


def straight_array(n: int = 9) -> np.ndarray:
    """An open straight road along +x from 0 to 10 m, 1 m wide: borders at y=+0.5 and y=-0.5 (1.25 m spacing)."""
    x = np.linspace(0.0, 10.0, n)
    y = np.zeros_like(x)
    return np.column_stack([x, y, x, y + 0.5, x, y - 0.5])


def save(tmp_path: Path, arr: np.ndarray, name: str = "track.npy") -> Path:
    path = tmp_path / name
    np.save(path, arr)
    return path


@pytest.fixture
def straight() -> Track:
    return Track.from_array(straight_array(), name="straight")


@pytest.fixture
def circle() -> Track:
    return Track.from_array(circle_array(), name="circle")


# --- bundled tracks -------------------------------------------------------------------------------


def test_bundled_track_names_are_the_documented_twelve():
    assert sorted(bundled_track_names()) == sorted(EXPECTED_LENGTH_M)


@pytest.mark.parametrize("name", bundled_track_names())
def test_bundled_track_loads_with_documented_length(name):
    track = load_track(name)
    assert track.name == name
    assert track.waypoints.shape[1] == 6
    assert len(track.center) >= 5
    assert track.length == pytest.approx(EXPECTED_LENGTH_M[name], abs=0.02)
    assert track.closed == (name != "Straight_track")


def test_straight_track_is_open():
    track = load_track("Straight_track")
    assert track.closed is False
    assert track.clockwise is False
    assert track.road_polygons[1] is None


def test_spain_track_is_clockwise():
    track = load_track("Spain_track")
    assert track.closed is True
    assert track.clockwise is True
    assert track.reversed().clockwise is False


def test_reinvent_base_is_counter_clockwise():
    track = load_track("reinvent_base")
    assert track.closed is True
    assert track.clockwise is False
    assert track.reversed().clockwise is True


# --- loading a .npy path --------------------------------------------------------------------------


def test_load_synthetic_oval_from_npy_path(tmp_path):
    path = save(tmp_path, circle_array(), "ring.npy")
    track = load_track(path)
    assert track.name == "ring"
    assert track.source == str(path)
    assert track.closed is True
    assert track.clockwise is False
    # 60 chords of a radius-2 circle, each subtending 2π/60.
    expected = CIRCLE_POINTS * 2 * CIRCLE_R * math.sin(math.pi / CIRCLE_POINTS)
    assert track.length == pytest.approx(expected, rel=1e-9)
    assert expected < 2 * math.pi * CIRCLE_R
    assert track.length == pytest.approx(2 * math.pi * CIRCLE_R, abs=0.02)
    assert track.width == pytest.approx(CIRCLE_R_OUT - CIRCLE_R_IN)


def test_load_npy_path_given_as_str(tmp_path):
    path = save(tmp_path, circle_array())
    assert load_track(str(path)).length == pytest.approx(load_track(path).length)


def test_open_track_from_npy_path(tmp_path):
    track = load_track(save(tmp_path, straight_array()))
    assert track.closed is False
    assert track.length == pytest.approx(10.0)
    assert track.width == pytest.approx(1.0)


# --- bad files ------------------------------------------------------------------------------------


def assert_track_error(path: Path, *fragments: str) -> str:
    with pytest.raises(TrackError) as info:
        load_track(path)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message
    return message


def test_missing_file_is_a_track_error(tmp_path):
    assert_track_error(tmp_path / "missing.npy", "does not exist")


def test_text_file_named_npy_is_a_track_error(tmp_path):
    path = tmp_path / "x.npy"
    path.write_text("center_x,center_y\n1,2\n")
    assert_track_error(path, "not a readable .npy")


def test_wrong_shape_is_a_track_error(tmp_path):
    arr = straight_array()[:, :4]
    assert_track_error(save(tmp_path, arr), "(N, 6)", str(arr.shape))


def test_one_dimensional_array_is_a_track_error(tmp_path):
    assert_track_error(save(tmp_path, np.arange(6.0)), "(N, 6)")


def test_nan_value_is_a_track_error(tmp_path):
    arr = circle_array()
    arr[7, 3] = np.nan
    assert_track_error(save(tmp_path, arr), "row 7")


def test_too_few_points_is_a_track_error(tmp_path):
    assert_track_error(save(tmp_path, straight_array(3)), "3 distinct waypoints")


def test_self_crossing_border_loads_with_a_warning_naming_the_crossing(tmp_path, caplog):
    # DeepRacer loads such a file (the simapp never validates its shapely geometry; the 2019 reinvent_base.npy has a
    # self-crossing border), so racer loads it and says where the border crosses itself.
    arr = circle_array()
    theta = 2 * np.pi * np.arange(CIRCLE_POINTS + 1) / CIRCLE_POINTS
    # Figure-eight inner border (crosses itself at the origin), well away from the outer border.
    arr[:, 2] = 1.2 * np.sin(theta)
    arr[:, 3] = 0.8 * np.sin(2 * theta)
    arr[-1] = arr[0]
    with caplog.at_level("WARNING", logger="racer.track"):
        track = load_track(save(tmp_path, arr))
    assert track.closed
    message = " ".join(r.getMessage() for r in caplog.records)
    assert "inner border crosses itself" in message
    assert "segments 30-31 and 59-60 at (0.000, 0.000)" in message, message


def test_borders_crossing_each_other_load_with_a_warning(tmp_path, caplog):
    arr = straight_array(11)  # waypoints 1 m apart
    # From waypoint 5 on, the borders swap sides: segment 4-5 of each border crosses the other's,
    # while the width at every waypoint stays 1 m and neither border crosses itself.
    arr[5:, 3], arr[5:, 5] = -0.5, 0.5
    with caplog.at_level("WARNING", logger="racer.track"):
        load_track(save(tmp_path, arr))
    assert "inner and outer borders cross" in caplog.text


class _Unpickled:
    """Creating a directory on unpickling, to prove a file is refused without being unpickled."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.mkdir, (str(self.marker),))


def test_object_array_is_refused_without_unpickling(tmp_path):
    marker = tmp_path / "unpickled"
    arr = np.empty((6, 6), dtype=object)
    arr[:] = 0.0
    arr[0, 0] = _Unpickled(marker)
    path = tmp_path / "evil.npy"
    np.save(path, arr, allow_pickle=True)
    assert_track_error(path)
    assert not marker.exists()


def test_unknown_track_name_lists_bundled_names():
    with pytest.raises(TrackError) as info:
        load_track("no_such_track")
    message = str(info.value)
    assert "no_such_track" in message
    for name in bundled_track_names():
        assert name in message


def test_from_array_error_names_the_source():
    with pytest.raises(TrackError, match="my-source"):
        Track.from_array(straight_array()[:, :5], source="my-source")


# --- geometry on the straight track ---------------------------------------------------------------


def test_straight_project_left_of_travel(straight):
    proj = straight.project(np.array([[3.0, 0.2]]))
    assert proj.s[0] == pytest.approx(3.0)
    assert proj.lateral[0] == pytest.approx(0.2)  # +y is left of travel along +x
    assert proj.segment[0] == 2  # waypoints 2 (x=2.5) and 3 (x=3.75)
    assert proj.t[0] == pytest.approx(0.4)


def test_straight_project_right_of_travel(straight):
    proj = straight.project(np.array([[8.0, -0.3]]))
    assert proj.s[0] == pytest.approx(8.0)
    assert proj.lateral[0] == pytest.approx(-0.3)
    assert proj.segment[0] == 6  # x = 7.5 .. 8.75


def test_straight_project_many_points(straight):
    proj = straight.project(np.array([[1.0, 0.1], [9.0, -0.4], [5.0, 0.0]]))
    np.testing.assert_allclose(proj.s, [1.0, 9.0, 5.0])
    np.testing.assert_allclose(proj.lateral, [0.1, -0.4, 0.0], atol=1e-12)


def test_reversed_straight_projects_the_other_way(straight):
    rev = straight.reversed()
    assert rev.closed is False
    assert rev.length == pytest.approx(10.0)
    np.testing.assert_allclose(rev.center[0], [10.0, 0.0])
    proj = rev.project(np.array([[3.0, 0.2]]))
    assert proj.s[0] == pytest.approx(7.0)
    assert proj.lateral[0] == pytest.approx(-0.2)  # +y is right of travel along -x
    assert proj.segment[0] == 5  # reversed waypoints 5 (x=3.75) and 6 (x=2.5)


def test_reversed_does_not_modify_the_original(straight):
    before = straight.waypoints.copy()
    straight.reversed()
    np.testing.assert_array_equal(straight.waypoints, before)


def test_straight_on_track(straight):
    pts = np.array([[5.0, 0.4], [5.0, -0.4], [5.0, 0.6], [5.0, -0.6], [-1.0, 0.0], [11.0, 0.0], [0.5, 0.0]])
    np.testing.assert_array_equal(straight.on_track(pts), [True, True, False, False, False, False, True])


def test_straight_border_lines_count_as_road(straight):
    pts = np.array([[5.0, 0.5], [5.0, -0.5], [0.0, 0.0], [10.0, 0.0]])
    np.testing.assert_array_equal(straight.on_track(pts), [True, True, True, True])


def test_straight_point_at(straight):
    point, heading = straight.point_at(2.5)
    np.testing.assert_allclose(point, [2.5, 0.0])
    assert heading == pytest.approx(0.0)
    point, _ = straight.point_at(7.3)
    np.testing.assert_allclose(point, [7.3, 0.0])


def test_open_track_point_at_clips_to_the_ends(straight):
    np.testing.assert_allclose(straight.point_at(-3.0)[0], [0.0, 0.0])
    np.testing.assert_allclose(straight.point_at(12.0)[0], [10.0, 0.0])


def test_reversed_straight_point_at_heads_back(straight):
    point, heading = straight.reversed().point_at(2.5)
    np.testing.assert_allclose(point, [7.5, 0.0])
    assert abs(heading) == pytest.approx(math.pi)


def test_straight_width_at_and_cumulative(straight):
    np.testing.assert_allclose(straight.cumulative, np.linspace(0, 10, 9))
    proj = straight.project(np.array([[4.0, 0.1]]))
    assert straight.width_at(proj)[0] == pytest.approx(1.0)


# --- geometry on the synthetic circle -------------------------------------------------------------


def test_circle_on_track_centre_line_and_off_road(circle):
    theta = np.linspace(0, 2 * np.pi, 37)
    ring = np.column_stack([np.cos(theta), np.sin(theta)])
    assert circle.on_track(CIRCLE_R * ring).all()
    assert not circle.on_track(1.5 * ring).any()  # inside the hole
    assert not circle.on_track(2.5 * ring).any()  # outside the outer border
    assert not circle.on_track(np.array([[0.0, 0.0]])).any()


def test_circle_projection_and_point_at_wrap(circle):
    chord = 2 * CIRCLE_R * math.sin(math.pi / CIRCLE_POINTS)
    # Waypoint 15 is at angle π/2, i.e. (0, 2); points outside the centre line are right of CCW travel.
    proj = circle.project(np.array([[0.0, 2.2]]))
    assert proj.s[0] == pytest.approx(15 * chord)
    assert proj.lateral[0] == pytest.approx(-0.2)
    assert proj.segment[0] in (14, 15)
    point, heading = circle.point_at(circle.length + 15 * chord)
    np.testing.assert_allclose(point, [0.0, 2.0], atol=1e-12)
    # The chord 15→16 heads at π + π/60 (into the third quadrant), reported within [-π, π].
    assert heading == pytest.approx(-math.pi + math.pi / CIRCLE_POINTS)


def test_circle_reversed_keeps_inner_inside(circle):
    rev = circle.reversed()
    assert rev.clockwise is True
    assert rev.length == pytest.approx(circle.length)
    assert np.all(np.linalg.norm(rev.inner, axis=1) == pytest.approx(CIRCLE_R_IN))
    proj = rev.project(np.array([[0.0, 2.2]]))
    assert proj.lateral[0] == pytest.approx(0.2)  # outside is left when driving clockwise
