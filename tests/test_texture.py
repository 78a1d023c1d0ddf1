"""The drawn track surface and the road raster used for the on-track test."""

import numpy as np
import pytest

from common.defaults import DEFAULT_TRACK
from sim.texture import (
    DEEPRACER_PALETTE,
    Palette,
    RoadMask,
    TextureFrame,
    colorize,
    draw_layers,
    random_palette,
)
from sim.track import load_track


@pytest.fixture(scope="module")
def loop():
    track = load_track(DEFAULT_TRACK)
    frame = TextureFrame.for_track(track)
    return track, frame, draw_layers(track, frame)


def colour_at(img, frame, xy):
    u, v = frame.to_pixels(np.asarray(xy, float)[None])[0].astype(int)
    return tuple(int(c) for c in img[v, u])


def test_frame_maps_metres_to_pixels_both_ways(loop):
    track, frame, _ = loop
    lo, hi = track.bounds
    assert frame.to_pixels(np.array([[frame.x0, frame.y1]]))[0] == pytest.approx([0, 0])
    corner = frame.to_pixels(np.array([[hi[0], lo[1]]]))[0]
    assert 0 < corner[0] < frame.width and 0 < corner[1] < frame.height
    assert frame.ppm == 200.0  # the cap: 11.1 × 7.2 m with its margins is under 8192 px and 6 Mpx at 200 px/m


def test_layers_sum_to_255_and_colours_land_where_expected(loop):
    track, frame, layers = loop
    assert np.all(layers.astype(int).sum(axis=2) >= 253)  # coverage weights of every pixel sum to ~255
    img = colorize(layers)
    # Between the centre line and a border: road.
    mid = 0.5 * (track.center[10] + track.inner[10])
    assert colour_at(img, frame, mid) == pytest.approx(DEEPRACER_PALETTE.road, abs=3)
    # On the outer border: white line. Far outside: background.
    assert colour_at(img, frame, track.outer[10]) == pytest.approx(DEEPRACER_PALETTE.border, abs=3)
    assert colour_at(img, frame, track.bounds[0] - 1.0) == pytest.approx(DEEPRACER_PALETTE.background, abs=3)


def test_centre_line_is_dashed(loop):
    track, frame, layers = loop
    s = np.linspace(0, track.length, 400, endpoint=False)
    xy = np.stack([np.interp(s, track.cumulative, track.center[:, i]) for i in (0, 1)], axis=1)
    px = frame.to_pixels(xy).astype(int)
    on_dash = layers[px[:, 1], px[:, 0], 3] > 128
    assert 0.35 < on_dash.mean() < 0.65  # dashes and gaps of equal length


def test_palette_recolours_without_redrawing(loop):
    track, frame, layers = loop
    palette = random_palette(np.random.default_rng(1), 1.0)
    assert palette != DEEPRACER_PALETTE
    img = colorize(layers, palette)
    mid = 0.5 * (track.center[10] + track.inner[10])
    assert colour_at(img, frame, mid) == pytest.approx(palette.road, abs=3)
    assert random_palette(np.random.default_rng(1), 0.0) == Palette()


def test_road_raster_agrees_with_exact_polygon_test(loop):
    track, frame, _ = loop
    mask = RoadMask(track, frame)
    rng = np.random.default_rng(0)
    lo, hi = track.bounds
    pts = rng.uniform(lo - 0.5, hi + 0.5, size=(4000, 2))
    # Away from the borders (> 1 cm) the raster must agree with the polygon test exactly.
    proj = track.project(pts)
    near_border = np.abs(np.abs(proj.lateral) - track.width_at(proj) / 2) < 0.01
    exact, raster = track.on_track(pts), mask(pts)
    assert exact.sum() > 300  # the sample hits the road often enough to mean something
    assert np.array_equal(exact[~near_border], raster[~near_border])


def test_road_raster_outside_texture_is_off_road(loop):
    track, frame, _ = loop
    mask = RoadMask(track, frame)
    assert not mask(np.array([[1e3, 1e3], [-1e3, 0.0]])).any()
