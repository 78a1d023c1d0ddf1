"""Pictures for people: the track from above with cars on it, and a camera view beside it."""

from __future__ import annotations

import math

import cv2
import numpy as np

from sim.physics import Pose
from sim.texture import TextureFrame
from sim.track import Track

CAR_LENGTH_M = 0.28
CAR_WIDTH_M = 0.2


def top_down(track: Track, texture: np.ndarray, frame: TextureFrame, poses: list[Pose], width: int = 800) -> np.ndarray:
    """RGB image of the track texture scaled to ``width`` pixels, with each pose drawn as a red car."""
    scale = width / texture.shape[1]
    img = cv2.resize(texture, (width, int(round(texture.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    for pose in poses:
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        corners = [
            (CAR_LENGTH_M / 2, CAR_WIDTH_M / 2),
            (-CAR_LENGTH_M / 2, CAR_WIDTH_M / 2),
            (-CAR_LENGTH_M / 2, -CAR_WIDTH_M / 2),
            (CAR_LENGTH_M / 2, -CAR_WIDTH_M / 2),
        ]
        world = np.array([(pose.x + c * a - s * b, pose.y + s * a + c * b) for a, b in corners])
        px = np.round(frame.to_pixels(world) * scale).astype(np.int32)
        cv2.fillPoly(img, [px], (220, 30, 30), cv2.LINE_AA)
        nose = np.round(frame.to_pixels(pose.ahead(CAR_LENGTH_M)[None]) * scale).astype(np.int32)[0]
        centre = np.round(frame.to_pixels(np.array([[pose.x, pose.y]])) * scale).astype(np.int32)[0]
        cv2.line(img, tuple(int(v) for v in centre), tuple(int(v) for v in nose), (255, 255, 255), 2, cv2.LINE_AA)
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
