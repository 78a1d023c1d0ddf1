"""Boxes over a camera frame: objects (obstacles, bot cars) standing on the ground, given as a (K, 6) array
``[x, y, yaw, length, width, height]`` in world coordinates, projected with the camera model and filled over the
ground image, farthest box first, each visible face shaded by its orientation so that edges show
(``sim.camera.GroundCamera.render(pose, boxes=...)``).
"""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from sim.physics import Pose

if TYPE_CHECKING:
    from sim.camera import CameraSpec


DEFAULT_BOX_RGB = (123, 97, 79)
"""Colour of a box without one given: DeepRacer's default obstacle, ``box_obstacle`` (``OBSTACLE_TYPE`` default in
deepracer-simapp ``bundle/markov/agent_ctrl/obstacles_agent_ctrl.py``), whose material in
``bundle/models/box_obstacle/model.sdf`` is (0.482, 0.38, 0.309)."""
NEAR_M = 0.01
"""Box faces are clipped to points at least this far ahead of the camera (MuJoCo's znear)."""
_LIGHT = (math.cos(math.radians(30)), math.sin(math.radians(30)))
"""Horizontal direction the side faces are lit from (world frame): a face turned towards it is brighter."""
_TOP_SHADE = 1.0
_SIDE_SHADE = (0.8, 0.15)  # a side face's shade is a + b * cos(angle between its normal and the light)
# Box corners: bottom (z = 0) 0-3 and top 4-7, at (+l, +w), (-l, +w), (-l, -w), (+l, -w) in the box frame.
# Faces: top, +x, +y, -x, -y (the bottom is on the ground, never seen), corner indices in order around each.
_FACE_CORNERS = ((4, 5, 6, 7), (0, 3, 7, 4), (1, 0, 4, 5), (2, 1, 5, 6), (3, 2, 6, 7))
_GRAY_WEIGHTS = (0.299, 0.587, 0.114)  # OpenCV's RGB2GRAY
_SUBPIXEL_BITS = 4
_FAR_PX = 1e5  # projected coordinates are clamped to this (the polygon is clipped to the image anyway)


@dataclass(frozen=True)
class Mount:
    """What box drawing needs of a :class:`sim.camera.CameraSpec`, computed once per spec."""

    position: np.ndarray  # (3,) car frame, z above the ground
    rotation: np.ndarray  # (3, 3) columns forward, left, up in the car frame
    _: KW_ONLY
    max_range: float  # metres: boxes beyond are not drawn
    focal: float
    cx: float
    cy: float
    width: int
    height: int
    tan_h: float  # tangent of half the horizontal / vertical field of view, and 1 / their cosines
    sec_h: float
    tan_v: float
    sec_v: float

    @classmethod
    def of(cls, spec: CameraSpec, max_range_m: float) -> Mount:
        """The mount of ``spec``; boxes farther than ``max_range_m`` are not drawn (the ground there is sky)."""
        tan_h = (spec.width / 2) / spec.focal_px
        tan_v = (spec.height / 2) / spec.focal_px
        return cls(
            spec.position,
            spec.rotation(),
            max_range=max_range_m,
            focal=spec.focal_px,
            cx=(spec.width - 1) / 2,
            cy=(spec.height - 1) / 2,
            width=spec.width,
            height=spec.height,
            tan_h=tan_h,
            sec_h=math.hypot(1.0, tan_h),
            tan_v=tan_v,
            sec_v=math.hypot(1.0, tan_v),
        )

    def world(self, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """Camera centre (3,) and rotation (3×3, columns forward, left, up) in the world, car at ``pose``."""
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        car = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return np.array([pose.x, pose.y, 0.0]) + car @ self.position, car @ self.rotation


@dataclass(frozen=True)
class Boxes:
    """Boxes as Python floats and their base colours (gray level or RGB tuple per box)."""

    rows: list[list[float]]  # [x, y, yaw, length, width, height]
    colors: list


def prepare_boxes(boxes: np.ndarray, box_colors: np.ndarray | None, gray: bool) -> Boxes:
    array = np.asarray(boxes, np.float64).reshape(-1, 6)
    k = len(array)
    if box_colors is None:
        rgb = [DEFAULT_BOX_RGB] * k
    else:
        rgb = np.broadcast_to(np.asarray(box_colors, np.float64).reshape(-1, 3), (k, 3)).tolist()
    colors = [sum(w * v for w, v in zip(_GRAY_WEIGHTS, col, strict=True)) for col in rgb] if gray else rgb
    return Boxes(array.tolist(), colors)


def draw_views(views: list[tuple[np.ndarray, float]], mount: Mount, pose: Pose, b: Boxes) -> None:
    """Draw the boxes into each ``(image, left_m)`` view: the camera of ``mount`` moved ``left_m`` along the car's
    left axis (:func:`stereo_specs`), so that a stereo pair shares the culling and the corners.

    The geometry is plain Python arithmetic: for the few boxes of a scene it is several times faster than numpy's
    per-call overhead on arrays of eight corners."""
    centre, rot = mount.world(pose)
    (fx, lx, ux), (fy, ly, uy), (fz, lz, uz) = rot.tolist()
    ccx, ccy, ccz = centre.tolist()
    spread = max(abs(off) for _, off in views)
    # Cull with each box's bounding sphere: behind the cameras, beyond the sky, outside the frustum.
    order = []
    for k, (x, y, _yaw, length, width, height) in enumerate(b.rows):
        dx, dy, dz = x - ccx, y - ccy, height / 2 - ccz
        d2 = dx * dx + dy * dy
        if d2 > mount.max_range * mount.max_range:
            continue
        r = 0.5 * math.sqrt(length * length + width * width + height * height) + spread
        depth = dx * fx + dy * fy + dz * fz
        if depth < -r:
            continue
        left, up = dx * lx + dy * ly + dz * lz, dx * ux + dy * uy + dz * uz
        if depth * mount.tan_h - abs(left) < -r * mount.sec_h or depth * mount.tan_v - abs(up) < -r * mount.sec_v:
            continue
        order.append((-d2, k))
    if not order:
        return
    order.sort()
    a_side, b_side = _SIDE_SHADE
    focal, scale = mount.focal, float(1 << _SUBPIXEL_BITS)
    pcx_s, pcy_s = mount.cx * scale, mount.cy * scale  # fixed point; truncation errs by under 1/16 pixel
    c_yaw, s_yaw = math.cos(pose.yaw), math.sin(pose.yaw)
    r1 = mount.rotation[1].tolist()  # the car's left axis in camera coordinates (a view's offset direction)
    boxes = []
    for _, k in order:
        x, y, yaw, length, width, height = b.rows[k]
        c, s = math.cos(yaw), math.sin(yaw)
        ex, ey, hl, hw = x - ccx, y - ccy, length / 2, width / 2
        # Camera coordinates of the 8 corners (bottom 0-3 at (+l, +w), (-l, +w), (-l, -w), (+l, -w), top 4-7):
        # origin + sx * along-x + sy * along-y (+ the height for the top), for each of forward, left and up.
        cam = []
        for ax, ay, az in ((fx, fy, fz), (lx, ly, lz), (ux, uy, uz)):
            o = ax * ex + ay * ey - az * ccz
            p, q = hl * (ax * c + ay * s), hw * (ay * c - ax * s)
            bottom = (o + p + q, o - p + q, o - p - q, o + p - q)
            top = az * height
            cam.append(bottom + tuple(v + top for v in bottom))
        lit_x, lit_y = c * _LIGHT[0] + s * _LIGHT[1], c * _LIGHT[1] - s * _LIGHT[0]  # light · box axes
        boxes.append((k, x, y, c, s, hl, hw, height, cam, lit_x, lit_y))
    fs = focal * scale
    for image, off in views:
        gray = image.ndim == 2
        vx, vy = ccx - off * s_yaw, ccy + off * c_yaw  # this view's camera
        o_f, o_l, o_u = off * r1[0], off * r1[1], off * r1[2]
        for k, x, y, c, s, hl, hw, height, (cf, cl, cu), lit_x, lit_y in boxes:
            # The camera in the box's frame: a side face turns towards it when it is beyond the face's plane.
            bx, by = (vx - x) * c + (vy - y) * s, (vy - y) * c - (vx - x) * s
            faces = [(0, _TOP_SHADE)] if ccz > height else []
            if bx > hl:
                faces.append((1, a_side + b_side * lit_x))
            elif bx < -hl:
                faces.append((3, a_side - b_side * lit_x))
            if by > hw:
                faces.append((2, a_side + b_side * lit_y))
            elif by < -hw:
                faces.append((4, a_side - b_side * lit_y))
            if not faces:
                continue
            base = b.colors[k]
            if off:
                cf, cl, cu = [v - o_f for v in cf], [v - o_l for v in cl], [v - o_u for v in cu]
            if min(cf) >= NEAR_M:  # all corners ahead: project them, then fill each face's slice
                px = [
                    (int(pcx_s - lv * fs / d), int(pcy_s - uv * fs / d)) for d, lv, uv in zip(cf, cl, cu, strict=True)
                ]
                pts = np.array([px[i] for face, _ in faces for i in _FACE_CORNERS[face]], np.int32)
                for j, (_, shade) in enumerate(faces):
                    color = base * shade if gray else (base[0] * shade, base[1] * shade, base[2] * shade)
                    cv2.fillConvexPoly(image, pts[4 * j : 4 * j + 4], color, cv2.LINE_8, _SUBPIXEL_BITS)
                continue
            for face, shade in faces:  # some corners behind the camera: clip each face to the near plane
                poly = _clip_near(np.array([(cf[i], cl[i], cu[i]) for i in _FACE_CORNERS[face]]))
                if len(poly) < 3:
                    continue
                inv = focal / poly[:, 0]
                proj = np.column_stack([mount.cx - poly[:, 1] * inv, mount.cy - poly[:, 2] * inv])
                color = base * shade if gray else (base[0] * shade, base[1] * shade, base[2] * shade)
                pts = (np.clip(proj, -_FAR_PX, _FAR_PX) * scale).astype(np.int32)
                cv2.fillConvexPoly(image, pts, color, cv2.LINE_8, _SUBPIXEL_BITS)


def _clip_near(poly: np.ndarray) -> np.ndarray:
    """The part of a convex polygon ((N, 3) camera coordinates, forward first) at least NEAR_M ahead."""
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        a_in, b_in = a[0] >= NEAR_M, b[0] >= NEAR_M
        if a_in:
            out.append(a)
        if a_in != b_in:
            t = (NEAR_M - a[0]) / (b[0] - a[0])
            out.append(a + t * (b - a))
    return np.array(out).reshape(-1, 3)
