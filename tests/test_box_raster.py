"""Boxes over the ground camera's frame (sim/box_raster.py): drawn where the rays hit them, in their colour, the
nearer over the farther, clipped at the near plane; checked against a ray cast of the same boxes."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import sim  # noqa: F401  (first: picks MuJoCo's GL backend, EGL when headless, before mujoco is imported)
from sim.camera import CameraSpec, GroundCamera
from sim.env import RacerEnv
from sim.physics import Pose
from sim.texture import DEEPRACER_PALETTE
from tests.test_camera import STRAIGHTEST, TRACK, WHITE, W, abs_diff, box_ahead, iou, pinned, raycast_mask


@pytest.fixture(scope="module")
def scene() -> tuple[GroundCamera, Pose]:
    """racer_loop's ground camera, and the car on the centre line at its straightest waypoint."""
    env = RacerEnv(track=TRACK)
    env.reset(seed=0, options=pinned(STRAIGHTEST))
    return GroundCamera(env.frame, env.texture, CameraSpec(), DEEPRACER_PALETTE.sky), env.physics.pose


def test_zero_boxes_render_is_unchanged(scene: tuple[GroundCamera, Pose]) -> None:
    camera, centre_pose = scene
    for color in (False, True):
        plain = camera.render(centre_pose, color=color)
        np.testing.assert_array_equal(camera.render(centre_pose, color=color, boxes=None), plain)
        np.testing.assert_array_equal(camera.render(centre_pose, color=color, boxes=np.zeros((0, 6))), plain)
        # Boxes out of view (behind, far to the side, beyond the sky distance) draw nothing.
        hidden = np.array(
            [box_ahead(centre_pose, -1.0), box_ahead(centre_pose, 0.2, 3.0), box_ahead(centre_pose, 60.0)]
        )
        np.testing.assert_array_equal(camera.render(centre_pose, color=color, boxes=hidden), plain)


def test_box_ahead_covers_the_pixels_its_rays_hit(scene: tuple[GroundCamera, Pose]) -> None:
    camera, centre_pose = scene
    boxes = np.array([box_ahead(centre_pose, 1.0, 0.1, yaw=0.4)])
    plain = camera.render(centre_pose)
    img = camera.render(centre_pose, boxes=boxes, box_colors=WHITE)
    drawn = img != plain
    expected = raycast_mask(camera.spec, centre_pose, boxes)
    assert expected.sum() > 150  # about 0.4 m at 1 m: a sizeable patch
    assert iou(drawn, expected) > 0.9, iou(drawn, expected)
    # Only there, and brighter than the road: white shaded between 0.65 and 1.
    assert not (drawn & ~cv2.dilate(expected.astype(np.uint8), np.ones((3, 3))).astype(bool)).any()
    assert img[expected & drawn].min() >= 0.65 * 255 - 1
    # Two side faces are seen (the box is turned), in two different shades: its edge shows.
    assert np.unique(img[expected & drawn]).size >= 2


def test_colour_render_draws_boxes_in_their_colour(scene: tuple[GroundCamera, Pose]) -> None:
    camera, centre_pose = scene
    boxes = np.array([box_ahead(centre_pose, 0.8)])
    red = np.array([[220.0, 30.0, 30.0]])
    rgb = camera.render(centre_pose, color=True, boxes=boxes, box_colors=red)
    mask = raycast_mask(camera.spec, centre_pose, boxes)
    r, g, b = (rgb[mask][:, i].astype(int) for i in range(3))
    assert np.median(r) > 140 and np.median(g) < 40 and np.median(b) < 40
    gray = camera.render(centre_pose, boxes=boxes, box_colors=red)
    assert abs_diff(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), gray)[mask].max() <= 2


def test_box_hidden_behind_another_is_not_drawn_over_it(scene: tuple[GroundCamera, Pose]) -> None:
    camera, centre_pose = scene
    near = box_ahead(centre_pose, 0.8, size=(0.3, 0.6, 0.4))
    far = box_ahead(centre_pose, 1.8, size=(0.3, 0.3, 0.3))  # wholly behind the near one
    tall = box_ahead(centre_pose, 1.8, size=(0.3, 0.3, 1.2))  # behind it, but rising above it
    colors = np.array([[255.0, 255.0, 255.0], [0.0, 0.0, 0.0]])
    alone = camera.render(centre_pose, boxes=np.array([near]), box_colors=colors[:1])
    for order in ([near, far], [far, near]):
        cols = colors if order[0] is near else colors[::-1]
        np.testing.assert_array_equal(camera.render(centre_pose, boxes=np.array(order), box_colors=cols), alone)
    both = camera.render(centre_pose, boxes=np.array([tall, near]), box_colors=colors[::-1])
    near_mask = raycast_mask(camera.spec, centre_pose, np.array([near]))
    tall_mask = raycast_mask(camera.spec, centre_pose, np.array([tall])) & ~near_mask
    np.testing.assert_array_equal(both[near_mask], alone[near_mask])  # the near box is whole
    assert tall_mask.sum() > 20 and np.median(both[tall_mask]) == 0  # the far one shows above it


def test_box_straddling_the_camera_is_clipped(scene: tuple[GroundCamera, Pose]) -> None:
    """A long box beside the car, from behind the camera to ahead of it: its faces are clipped at the near plane."""
    camera, centre_pose = scene
    boxes = np.array([box_ahead(centre_pose, 0.3, 0.35, size=(1.6, 0.2, 0.3))])
    drawn = camera.render(centre_pose, boxes=boxes, box_colors=WHITE) != camera.render(centre_pose)
    expected = raycast_mask(camera.spec, centre_pose, boxes)
    assert expected[:, : W // 2].sum() > 1000  # fills much of the left of the image
    assert iou(drawn, expected) > 0.9, iou(drawn, expected)
