"""sim.views: the race's obstacles and bot cars in the top-down picture, where they are, in their colours."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.defaults import DEFAULT_TRACK
from common.race import RaceConfig
from sim.env import RacerEnv
from sim.obstacles import BOT_CAR, BOT_CAR_OBSTACLE, WorldObject
from sim.physics import Pose
from sim.texture import TextureFrame, draw_surface
from sim.track import load_track
from sim.views import BOT_COLOR, BOX_COLOR, CAR_COLOR, object_color, top_down

WIDTH = 800


@pytest.fixture(scope="module")
def scene():
    track = load_track(DEFAULT_TRACK)
    frame = TextureFrame.for_track(track, ppm=80)
    return track, draw_surface(track, frame), frame


def pixel(frame: TextureFrame, texture: np.ndarray, x: float, y: float, width: int = WIDTH) -> tuple[int, int]:
    """(row, column) of the world point (x, y) in a top-down picture ``width`` pixels wide."""
    u, v = np.round(frame.to_pixels(np.array([[x, y]])) * width / texture.shape[1]).astype(int)[0]
    return int(v), int(u)


def patch(img: np.ndarray, rc: tuple[int, int], half: int = 2) -> np.ndarray:
    r, c = rc
    return img[r - half : r + half + 1, c - half : c + half + 1].reshape(-1, 3)


def along(obj: WorldObject, metres: float) -> tuple[float, float]:
    """The point ``metres`` ahead of the object's centre along its heading (negative: behind)."""
    return obj.x + metres * math.cos(obj.yaw), obj.y + metres * math.sin(obj.yaw)


def test_a_box_and_a_bot_are_drawn_where_they_are_in_their_colours(scene):
    track, texture, frame = scene
    (bx, by), (cx, cy) = track.center[5], track.center[40]
    box = WorldObject.of("box_obstacle", bx, by, 0.3)
    bot = WorldObject.of(BOT_CAR, cx, cy, -1.0, speed=0.5)
    plain = top_down(track, texture, frame, [], width=WIDTH)
    img = top_down(track, texture, frame, [], width=WIDTH, objects=[box, bot])
    assert img.shape == plain.shape and img.dtype == np.uint8
    at_box = pixel(frame, texture, bx, by)
    assert (patch(img, at_box) == BOX_COLOR).all()
    assert not (patch(plain, at_box) == BOX_COLOR).all(axis=1).any()
    # The bot's centre carries its white nose line: look behind it.
    at_bot = pixel(frame, texture, *along(bot, -0.08))
    assert (patch(img, at_bot, 1) == BOT_COLOR).all()
    # Nothing else changed: the objects' footprints (a box 0.4 × 0.3 m, a bot 0.32 × 0.2 m at 80 px/m) and a margin.
    ppm = frame.ppm * WIDTH / texture.shape[1]
    changed = (img != plain).any(axis=2)
    assert 0 < changed.sum() < 2 * (0.4 * 0.3 + 0.32 * 0.2 + 0.32 * 0.02) * ppm**2
    at_bot_centre = pixel(frame, texture, cx, cy)
    rows, cols = np.nonzero(changed)
    for r, c in zip(rows, cols, strict=True):  # within the box's half diagonal, or the bot's nose line (0.32 m)
        assert math.dist((r, c), at_box) < 0.25 * ppm + 2 or math.dist((r, c), at_bot_centre) < 0.32 * ppm + 3


def test_the_footprint_is_rotated_by_the_yaw(scene):
    track, texture, frame = scene
    x, y = track.center[5]
    lengthwise = WorldObject.of("box_obstacle", x, y, 0.0)  # 0.4 m along x, 0.3 m along y
    crosswise = WorldObject.of("box_obstacle", x, y, math.pi / 2)  # 0.4 m along y
    ahead = pixel(frame, texture, x + 0.18, y)  # inside the first (0.2 m half length), outside the second (0.15)
    assert (patch(top_down(track, texture, frame, [], WIDTH, [lengthwise]), ahead, 0) == BOX_COLOR).all()
    assert not (patch(top_down(track, texture, frame, [], WIDTH, [crosswise]), ahead, 0) == BOX_COLOR).any(axis=1).any()


def test_the_car_is_drawn_over_an_object_it_touches(scene):
    track, texture, frame = scene
    x, y = track.center[5]
    box = WorldObject.of("box_obstacle", x, y, 0.0)
    img = top_down(track, texture, frame, [Pose(x - 0.1, y, 0.0)], WIDTH, [box])
    assert (patch(img, pixel(frame, texture, x - 0.18, y + 0.05), 1) == CAR_COLOR).all()  # the car
    assert (patch(img, pixel(frame, texture, x + 0.15, y + 0.1), 1) == BOX_COLOR).all()  # the box beyond it


def test_parked_bot_cars_are_bot_coloured_and_boxes_of_every_model_box_coloured():
    assert object_color(WorldObject.of(BOT_CAR_OBSTACLE, 0, 0, 0)) == BOT_COLOR
    for kind in ("box_obstacle", "deepracer_box_obstacle", "amazon_box_obstacle"):
        assert object_color(WorldObject.of(kind, 0, 0, 0)) == BOX_COLOR
    assert len({BOX_COLOR, BOT_COLOR, CAR_COLOR}) == 3


def test_without_objects_the_picture_is_as_before(scene):
    track, texture, frame = scene
    pose = Pose(*track.center[3], 0.5)
    a = top_down(track, texture, frame, [pose], WIDTH)
    assert np.array_equal(a, top_down(track, texture, frame, [pose], WIDTH, objects=[]))
    assert np.array_equal(a, top_down(track, texture, frame, [pose], WIDTH, objects=None))


def test_a_render_of_an_object_avoidance_env_can_show_its_boxes():
    env = RacerEnv(
        track=DEFAULT_TRACK,
        render_mode="rgb_array",
        race=RaceConfig(race_type="OBJECT_AVOIDANCE", object_avoidance={"number_of_obstacles": 3}),
    )
    try:
        env.reset(seed=0)
        assert len(env.objects) == 3
        img = top_down(env.track, env.texture, env.frame, [env.physics.pose], objects=env.objects)
        for o in env.objects:
            assert (patch(img, pixel(env.frame, env.texture, o.x, o.y)) == BOX_COLOR).all()
    finally:
        env.close()
