"""Pictures for people: the track from above with cars, obstacles and bot cars on it, and a camera view beside it."""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from sim.obstacles import BOT_CAR, BOT_CAR_OBSTACLE, WorldObject
from sim.physics import Pose
from sim.texture import TextureFrame
from sim.track import Track

CAR_LENGTH_M = 0.28
CAR_WIDTH_M = 0.2

CAR_COLOR = (220, 30, 30)
"""RGB of the car being driven."""
BOX_COLOR = (255, 140, 0)
"""RGB of a box obstacle (any of DeepRacer's box models): orange, apart from the road, its lines and the car."""
BOT_COLOR = (40, 110, 255)
"""RGB of a bot car, moving or parked as an obstacle: blue."""
_NOSE_COLOR = (255, 255, 255)


def object_color(obj: WorldObject) -> tuple[int, int, int]:
    """The colour an object is drawn in from above: :data:`BOT_COLOR` for bot cars (moving or parked), else
    :data:`BOX_COLOR`."""
    return BOT_COLOR if obj.kind in (BOT_CAR, BOT_CAR_OBSTACLE) else BOX_COLOR


def _pixels(frame: TextureFrame, scale: float, world: np.ndarray) -> np.ndarray:
    return np.round(frame.to_pixels(np.asarray(world, np.float64).reshape(-1, 2)) * scale).astype(np.int32)


def _rectangle(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    """(4, 2) world corners of a ``length`` × ``width`` rectangle centred on (x, y), its length along ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    half = ((length / 2, width / 2), (-length / 2, width / 2), (-length / 2, -width / 2), (length / 2, -width / 2))
    return np.array([(x + c * a - s * b, y + s * a + c * b) for a, b in half])


def _draw_vehicle(
    img: np.ndarray,
    frame: TextureFrame,
    scale: float,
    *,
    x: float,
    y: float,
    yaw: float,
    length: float,
    width: float,
    color: tuple[int, int, int],
    nose: bool,
) -> None:
    """A filled rotated rectangle and, for something that drives, a white line from its centre to its nose."""
    cv2.fillPoly(img, [_pixels(frame, scale, _rectangle(x, y, yaw, length, width))], color, cv2.LINE_AA)
    if nose:
        ends = _pixels(frame, scale, [(x, y), (x + length * math.cos(yaw), y + length * math.sin(yaw))])
        cv2.line(img, tuple(int(v) for v in ends[0]), tuple(int(v) for v in ends[1]), _NOSE_COLOR, 2, cv2.LINE_AA)


def draw_objects(img: np.ndarray, frame: TextureFrame, objects: Sequence[WorldObject], scale: float = 1.0) -> None:
    """Draw ``objects`` into ``img`` (RGB, ``frame``'s pixels × ``scale``) in place: each its footprint (real length
    × width, rotated by its yaw), boxes in :data:`BOX_COLOR`, bot cars in :data:`BOT_COLOR` with a nose line."""
    for o in objects:
        is_car = o.kind in (BOT_CAR, BOT_CAR_OBSTACLE)
        _draw_vehicle(
            img,
            frame,
            scale,
            x=o.x,
            y=o.y,
            yaw=o.yaw,
            length=o.length,
            width=o.width,
            color=object_color(o),
            nose=is_car,
        )


def top_down(
    track: Track,
    texture: np.ndarray,
    frame: TextureFrame,
    poses: list[Pose],
    width: int = 800,
    objects: Sequence[WorldObject] | None = None,
) -> np.ndarray:
    """RGB image of the track texture scaled to ``width`` pixels, with ``objects`` (obstacles and bot cars, see
    :func:`draw_objects`) and each pose drawn as a red car on top."""
    scale = width / texture.shape[1]
    img = cv2.resize(texture, (width, int(round(texture.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    if objects:
        draw_objects(img, frame, objects, scale)
    for pose in poses:
        _draw_vehicle(
            img,
            frame,
            scale,
            x=pose.x,
            y=pose.y,
            yaw=pose.yaw,
            length=CAR_LENGTH_M,
            width=CAR_WIDTH_M,
            color=CAR_COLOR,
            nose=False,
        )
        nose = _pixels(frame, scale, pose.ahead(CAR_LENGTH_M)[None])[0]
        centre = _pixels(frame, scale, [(pose.x, pose.y)])[0]
        cv2.line(img, tuple(int(v) for v in centre), tuple(int(v) for v in nose), _NOSE_COLOR, 2, cv2.LINE_AA)
    return img


def side_by_side(left_rgb: np.ndarray, camera_gray: np.ndarray, label: str = "") -> np.ndarray:
    """Top-down view with the camera image (scaled up to the same height) on its right."""
    h = left_rgb.shape[0]
    scale = h / camera_gray.shape[0]
    cam = cv2.resize(camera_gray, (int(round(camera_gray.shape[1] * scale)), h), interpolation=cv2.INTER_NEAREST)
    out = np.concatenate([left_rgb, cv2.cvtColor(cam, cv2.COLOR_GRAY2RGB)], axis=1)
    if label:
        cv2.putText(out, label, (10, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2, cv2.LINE_AA)
    return out
