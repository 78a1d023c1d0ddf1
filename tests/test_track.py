"""Tests for sim.track: racer's own tracks, DeepRacer's (read in place from ../shared), .npy loading and
sanitization as DeepRacer's simapp reads a route, and the centre-line geometry."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from common.defaults import DEFAULT_TRACK, STRAIGHT_TRACK
from sim.track import Track, TrackError, known_track_names, load_track, sanitize_waypoints
from sim.track_gen import racer_track_array, racer_track_names
from tests.shared_data import needs_deepracer_tracks

# Centre-line lengths (m) of the most used DeepRacer tracks, as DeepRacer's track list gives them; literals, so the
# loader is checked against fixed figures rather than against itself. The files are read from ../shared.
EXPECTED_LENGTH_M = {
    "reinvent_base": 17.71,
    "Oval_track": 19.55,
    "Bowtie_track": 17.43,
    "AWS_track": 69.25,
    "reInvent2019_track": 23.12,
    "reInvent2019_wide": 16.64,
    "Straight_track": 5.71,
    "Vegas_track": 22.55,
    "Tokyo_Training_track": 22.63,
    "2022_summit_speedway": 25.17,
    "Spain_track": 60.00,
}
# racer's own tracks: (length m, width m, direction), as sim/track_gen.py documents them.
RACER_TRACKS = {
    "racer_loop": (17.6, 0.76, "CCW"),
    "racer_loop_cw": (17.6, 0.76, "CW"),
    "racer_wide": (24.0, 1.07, "CCW"),
    "racer_bends": (20.0, 0.76, "CCW"),
    "racer_straight": (5.7, 0.61, "open"),
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


# --- racer's own tracks ---------------------------------------------------------------------------


def test_racer_tracks_are_the_documented_five_and_the_default_is_one():
    assert racer_track_names() == sorted(RACER_TRACKS)
    assert DEFAULT_TRACK in RACER_TRACKS and STRAIGHT_TRACK == "racer_straight"
    assert set(RACER_TRACKS) <= set(known_track_names())


@pytest.mark.parametrize("name", sorted(RACER_TRACKS))
def test_racer_track_loads_with_documented_size_and_direction(name, caplog):
    length, width, direction = RACER_TRACKS[name]
    with caplog.at_level("WARNING", logger="racer.track"):
        track = load_track(name)
    assert not caplog.records  # no border crossing, no near-closed loop
    assert track.name == name and track.source == f"racer:{name}"
    assert track.length == pytest.approx(length, abs=0.01)
    assert track.widths == pytest.approx(np.full(len(track.widths), width))
    assert ("open" if not track.closed else "CW" if track.clockwise else "CCW") == direction
    steps = np.linalg.norm(np.diff(track.center, axis=0), axis=1)
    assert steps.min() > 0.1 and steps.max() < 0.3  # DeepRacer's routes space waypoints 0.13-0.30 m apart
    assert np.array_equal(track.waypoints, racer_track_array(name))  # nothing for the sanitizer to drop
    assert track.bounds[0].min() >= 0.5 - 1e-9  # in x, y > 0 as DeepRacer's routes are


@pytest.mark.parametrize("name", ["racer_loop", "racer_loop_cw", "racer_wide"])
def test_racer_loops_bend_no_tighter_than_half_their_width(name):
    # The borders are the centre line offset by half the width: where the centre line bends tighter than that the
    # inner border would fold over itself. The loops also turn both ways (an S), as DeepRacer's tracks do.
    track = load_track(name)
    c = track.center[:-1]
    a, b = np.roll(c, 1, axis=0), np.roll(c, -1, axis=0)
    turn = np.cross(c - a, b - c) / (np.linalg.norm(c - a, axis=1) * np.linalg.norm(b - c, axis=1))
    radius = np.linalg.norm(b - a, axis=1) / 2 / np.abs(np.arcsin(np.clip(turn, -1, 1)) + 1e-12)
    assert radius.min() > track.width / 2 + 0.2
    sign = -1 if track.clockwise else 1
    assert (sign * turn < -0.01).any() and (sign * turn > 0.01).any()


def test_racer_loop_cw_is_racer_loop_mirrored():
    ccw, cw = load_track("racer_loop"), load_track("racer_loop_cw")
    assert cw.length == pytest.approx(ccw.length, rel=1e-12)
    np.testing.assert_allclose(cw.waypoints[:, 0::2], ccw.waypoints[:, 0::2], atol=1e-12)
    np.testing.assert_allclose(cw.widths, ccw.widths, atol=1e-12)


def test_racer_track_arrays_are_fresh_copies():
    arr = racer_track_array(DEFAULT_TRACK)
    arr[:] = 0.0
    assert load_track(DEFAULT_TRACK).length == pytest.approx(17.6, abs=0.01)


def test_a_deepracer_name_not_in_the_track_folder_gives_the_pull_command(tmp_path, monkeypatch):
    monkeypatch.setenv("RACER_TRACKS_DIR", str(tmp_path))
    with pytest.raises(TrackError) as info:
        load_track("2024_reinvent_champ_ccw")
    message = str(info.value)
    assert "`racer tracks pull 2024_reinvent_champ_ccw`" in message and str(tmp_path) in message
    assert "\n" not in message


def test_a_track_in_the_track_folder_loads_by_name(tmp_path, monkeypatch):
    monkeypatch.setenv("RACER_TRACKS_DIR", str(tmp_path))
    np.save(tmp_path / "my_loop.npy", circle_array())
    track = load_track("my_loop")
    assert track.name == "my_loop" and track.source == str(tmp_path / "my_loop.npy") and track.closed
    assert "my_loop" in known_track_names()


# --- DeepRacer's tracks (read in place from ../shared) ---------------------------------------------


@needs_deepracer_tracks
@pytest.mark.parametrize("name", sorted(EXPECTED_LENGTH_M))
def test_deepracer_track_loads_with_documented_length(name):
    track = load_track(name)
    assert track.name == name
    assert track.waypoints.shape[1] == 6
    assert len(track.center) >= 5
    assert track.length == pytest.approx(EXPECTED_LENGTH_M[name], abs=0.02)
    assert track.closed == (name != "Straight_track")


@needs_deepracer_tracks
def test_straight_track_is_open():
    track = load_track("Straight_track")
    assert track.closed is False
    assert track.clockwise is False
    assert track.road_polygons[1] is None


@needs_deepracer_tracks
def test_spain_track_is_clockwise():
    track = load_track("Spain_track")
    assert track.closed is True
    assert track.clockwise is True
    assert track.reversed().clockwise is False


@needs_deepracer_tracks
def test_reinvent_base_is_counter_clockwise():
    track = load_track("reinvent_base")
    assert track.closed is True
    assert track.clockwise is False
    assert track.reversed().clockwise is True


@needs_deepracer_tracks
def test_a_zero_length_step_in_a_deepracer_route_is_dropped():
    # Spain_track's file has 259 rows, one of them a repeat of the row before (simapp route error correction #254).
    raw = np.load(Path(os.environ["RACER_TRACKS_DIR"]) / "Spain_track.npy")
    assert raw.shape == (259, 6)
    track = load_track("Spain_track")
    assert track.waypoints.shape == (258, 6)
    assert np.array_equal(track.waypoints[-1], track.waypoints[0])


# --- sanitization: the simapp's _sanitize_waypoints, by hand -----------------------------------------


def test_sanitize_drops_a_zero_length_step_and_keeps_the_rest():
    arr = circle_array(8)
    with_repeat = np.insert(arr, 3, arr[2], axis=0)  # row 3 repeats row 2
    out = sanitize_waypoints(with_repeat, "t")
    assert np.array_equal(out, arr)


def test_sanitize_keeps_a_loops_closing_row_even_when_the_step_before_it_is_zero():
    # The simapp sanitizes a loop's rows before the closing one, then appends the closing row whatever it is: a
    # last core row equal to the first row is kept, so the step into the closing row is zero-length.
    arr = circle_array(8)
    arr = np.vstack([arr[:-1], arr[:1], arr[:1]])  # ..., row 7, row 0 again, closing row
    out = sanitize_waypoints(arr, "t")
    assert len(out) == 10 and np.array_equal(out[-1], out[0]) and np.array_equal(out[-2], out[0])
    track = Track.from_array(arr)  # the zero-length last step must not break the geometry
    plain = Track.from_array(circle_array(8))
    for point in ([2.0, 0.05], [1.9, -0.1], [0.1, 2.1]):
        got, want = track.project(np.array([point])), plain.project(np.array([point]))
        assert got.s[0] == pytest.approx(want.s[0]) and got.lateral[0] == pytest.approx(want.lateral[0])


def test_sanitize_drops_zero_length_steps_of_an_open_line_anywhere():
    arr = straight_array()
    arr = np.vstack([arr, arr[-1:]])  # the last row repeated: an open line's last step is dropped too
    assert np.array_equal(sanitize_waypoints(arr, "t"), straight_array())


def test_sanitize_treats_only_an_exact_repeat_as_zero_length():
    arr = straight_array()
    arr[3, 0] = arr[2, 0] + 2e-9  # longer than the simapp's 1e-9 m
    assert len(sanitize_waypoints(arr, "t")) == len(arr)
    arr[3, 0] = arr[2, 0] + 0.5e-9
    assert len(sanitize_waypoints(arr, "t")) == len(arr) - 1


def test_a_loop_closes_only_when_first_and_last_rows_are_equal_in_every_column(caplog):
    arr = circle_array()
    assert Track.from_array(arr).closed
    arr[-1, 4] += 1e-6  # outer border's last x differs: the simapp's np.all(row0 == row-1) is False
    with caplog.at_level("WARNING", logger="racer.track"):
        track = Track.from_array(arr)
    assert not track.closed and "open line" in caplog.text


def test_columns_past_the_sixth_are_read_as_the_simapp_reads_them():
    arr = np.column_stack([circle_array(), np.arange(CIRCLE_POINTS + 1.0)])  # a 7th column the simapp ignores
    track = Track.from_array(arr)
    assert track.waypoints.shape == (CIRCLE_POINTS + 1, 6)
    assert not track.closed  # ... except in its loop test, which compares whole rows (0 != 60 in column 7)


def test_non_finite_value_names_row_and_column():
    arr = circle_array()
    arr[7, 3] = np.inf
    with pytest.raises(TrackError, match=r"row 7, column 3"):
        sanitize_waypoints(arr, "t")


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
    assert_track_error(save(tmp_path, arr), "row 7, column 3")


def test_too_few_points_is_a_track_error(tmp_path):
    assert_track_error(save(tmp_path, straight_array(3)), "3 distinct waypoints")


def test_self_crossing_border_loads_with_a_warning_naming_the_crossing(tmp_path, caplog):
    # DeepRacer loads such a file (the simapp never validates its shapely geometry), so racer loads it and says where
    # the border crosses itself.
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


def test_unknown_track_name_lists_racers_tracks_and_where_to_find_deepracers():
    with pytest.raises(TrackError) as info:
        load_track("no_such_track")
    message = str(info.value)
    assert "no_such_track" in message and "racer tracks ls" in message
    for name in racer_track_names():
        assert name in message


def test_a_misspelt_track_name_suggests_the_closest_known_names(tmp_path, monkeypatch):
    monkeypatch.setenv("RACER_TRACKS_DIR", str(tmp_path))  # the known names: racer's and the pullable ones only
    for typed, meant in (("racer_lop", "racer_loop"), ("RACER_WIDE", "racer_wide"), ("reinvent_bse", "reinvent_base")):
        with pytest.raises(TrackError) as info:
            load_track(typed)
        message = str(info.value)
        assert f"unknown track {typed!r}: did you mean {meant!r}" in message and "\n" not in message, message
    with pytest.raises(TrackError) as info:
        load_track("qqqqqqqq")
    assert "did you mean" not in str(info.value)  # nothing close: no guess


@pytest.mark.slow(reason="starts real racer processes")
def test_a_misspelt_track_name_on_the_command_line_suggests_the_closest(tmp_path):
    env = {**os.environ, "RACER_TRACKS_DIR": str(tmp_path)}
    command = [sys.executable, "-m", "racer", "tracks", "show", "racer_bnds", "--png", str(tmp_path / "t.png")]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, env=env)
    assert done.returncode == 2
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1 and "unknown track 'racer_bnds': did you mean 'racer_bends'" in err, err
    assert not (tmp_path / "t.png").exists()


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
