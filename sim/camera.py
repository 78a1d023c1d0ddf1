"""The car's camera: 160×120 at 15 Hz, two interchangeable paths.

``GroundCamera`` is the fast path. The track is flat and the camera is rigid on the car, so every
pixel's ray hits the ground at a fixed point *in the car's frame*; a frame is then only a rotation
and translation of those points into the track frame and one bilinear lookup in the track texture
(OpenCV ``remap``), with a mip level per pixel chosen from its ground footprint so that distant
lines do not alias. ``MujocoCamera`` renders the same view with MuJoCo's OpenGL renderer (EGL when
headless); it sees everything in the scene and is the reference the fast path is tested against.

Objects (obstacles, bot cars) are boxes standing on the ground, given as a (K, 6) array ``[x, y, yaw, length,
width, height]`` in world coordinates. ``GroundCamera.render(pose, boxes=...)`` projects each box's visible faces
with the camera model and fills them over the ground image, farthest box first, each face shaded by its
orientation so that edges show; ``MujocoCamera`` sees the boxes the scene's object slots hold
(``sim.world.set_objects``). ``StereoGroundCamera`` renders DeepRacer's STEREO_CAMERAS: two gray views 6 cm apart,
stacked as (H, W, 2) with the left camera first.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace

import cv2
import mujoco
import numpy as np

from common.config import FRAME_HEIGHT, FRAME_WIDTH
from common.errors import UserError
from sim._gl import ensure_gl_backend
from sim.physics import Pose
from sim.texture import TextureFrame

CLAMP_FREE_M = 1.0
"""Ground this close to the car needs no clamping to the texture: the texture reaches 1.5 m beyond the track."""
MAX_RANGE_M = 40.0
"""Ground farther than this along a ray is drawn as sky (MuJoCo's far plane is at 60 m)."""
STEREO_BASELINE_M = 0.06
"""Distance between DeepRacer's two front cameras: ``zed_camera_joint_leftcam`` and ``_rightcam`` sit at
y = +0.03 and -0.03 m on the chassis, otherwise at the single camera's pose (xyz 0.091711, ±0.03, 0.080023,
pitch 0.2618 rad), in deepracer-simapp ``bundle/urdf/deepracer/deepracer_stereo_cam*.urdf`` and
``deepracer_single_cam*.urdf``."""
DEFAULT_BOX_RGB = (123, 97, 79)
"""Colour of a box without one given: DeepRacer's default obstacle, ``box_obstacle`` (``OBSTACLE_TYPE`` default in
deepracer-simapp ``bundle/markov/agent_ctrl/obstacles_agent_ctrl.py``), whose material in
``bundle/models/box_obstacle/model.sdf`` is (0.482, 0.38, 0.309)."""
NEAR_M = 0.01
"""Box faces are clipped to points at least this far ahead of the camera (MuJoCo's znear)."""


@dataclass(frozen=True)
class CameraSpec:
    """Camera pose on the car and its image geometry (pinhole, square pixels)."""

    width: int = FRAME_WIDTH
    height: int = FRAME_HEIGHT
    hfov_deg: float = 120.0
    """Horizontal field of view, degrees (wide, as on DeepRacer)."""
    forward_m: float = 0.09
    """Distance ahead of base_link, metres."""
    left_m: float = 0.0
    """Lateral offset, metres (+ = left)."""
    up_m: float = 0.08
    """Height above base_link, metres."""
    base_height_m: float = 0.035
    """Height of base_link (the axles) above the ground, metres."""
    pitch_deg: float = 15.0
    """Downward tilt, degrees."""
    yaw_deg: float = 0.0
    """Rotation to the left, degrees."""
    roll_deg: float = 0.0
    """Roll, degrees (+ = clockwise as seen from behind)."""

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def fovy_deg(self) -> float:
        """Vertical field of view, degrees."""
        return math.degrees(2 * math.atan((self.height / 2) / self.focal_px))

    def rotation(self) -> np.ndarray:
        """3×3 matrix whose columns are the camera's forward, left and up axes in the car frame."""
        p, y, r = (math.radians(v) for v in (self.pitch_deg, self.yaw_deg, self.roll_deg))
        rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
        ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
        rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
        return rz @ ry @ rx

    def jittered(self, rng: np.random.Generator, metres: float, degrees: float) -> CameraSpec:
        """A copy moved by up to ``metres`` on each axis and turned by up to ``degrees`` about each."""
        dm = rng.uniform(-metres, metres, 3)
        dd = rng.uniform(-degrees, degrees, 3)
        return replace(
            self,
            forward_m=self.forward_m + dm[0],
            left_m=self.left_m + dm[1],
            up_m=self.up_m + dm[2],
            pitch_deg=self.pitch_deg + dd[0],
            yaw_deg=self.yaw_deg + dd[1],
            roll_deg=self.roll_deg + dd[2],
        )

    def rays(self) -> np.ndarray:
        """(H, W, 3) unit-free ray directions of pixel centres in the car frame."""
        u = np.arange(self.width) - (self.width - 1) / 2
        v = np.arange(self.height) - (self.height - 1) / 2
        uu, vv = np.meshgrid(u, v)
        f = self.focal_px
        local = np.stack([np.ones_like(uu), -uu / f, -vv / f], axis=-1)  # forward, left, up
        return local @ self.rotation().T

    @property
    def position(self) -> np.ndarray:
        """Camera position in the car frame with the origin on the ground below base_link, metres."""
        return np.array([self.forward_m, self.left_m, self.base_height_m + self.up_m])


def stereo_specs(
    spec: CameraSpec | None = None, baseline_m: float = STEREO_BASELINE_M
) -> tuple[CameraSpec, CameraSpec]:
    """(left, right) cameras of a stereo pair: ``spec`` (the single camera's pose) moved half the baseline to
    each side, as DeepRacer's stereo cameras are (:data:`STEREO_BASELINE_M`)."""
    spec = spec or CameraSpec()
    half = baseline_m / 2
    return replace(spec, left_m=spec.left_m + half), replace(spec, left_m=spec.left_m - half)


_PAD = 2  # texels of edge colour around each mip level in the atlas, so bilinear taps stay inside


@dataclass(frozen=True)
class _Atlas:
    """All mip levels of a texture packed into one image, plus a patch of sky colour."""

    image: np.ndarray
    origins: list[tuple[int, int]]  # (u0, v0) of each level's first texel in the atlas
    sizes: list[tuple[int, int]]  # (width, height) of each level
    sky_uv: tuple[float, float]  # centre of the sky patch


def _build_atlas(texture: np.ndarray, sky: np.ndarray, levels: int) -> _Atlas:
    pyramid = [texture]
    for _ in range(levels - 1):
        pyramid.append(cv2.pyrDown(pyramid[-1]))
    h0, w0 = texture.shape[:2]
    right_w = max(p.shape[1] for p in pyramid[1:]) + 2 * _PAD
    heights = [p.shape[0] + 2 * _PAD for p in pyramid[1:]]
    atlas_h = max(h0 + 2 * _PAD, sum(heights) + 8)
    image = np.empty((atlas_h, w0 + 2 * _PAD + right_w) + texture.shape[2:], np.uint8)
    image[:] = sky
    origins, sizes = [], []
    u, v = _PAD, _PAD
    for level, img in enumerate(pyramid):
        h, w = img.shape[:2]
        padded = cv2.copyMakeBorder(img, _PAD, _PAD, _PAD, _PAD, cv2.BORDER_REPLICATE)
        image[v - _PAD : v + h + _PAD, u - _PAD : u + w + _PAD] = padded
        origins.append((u, v))
        sizes.append((w, h))
        if level == 0:
            u, v = w0 + 3 * _PAD, _PAD
        else:
            v += h + 2 * _PAD
    # The sky patch is the free corner below the small levels, filled with sky colour above.
    return _Atlas(image, origins, sizes, (float(w0 + 2 * _PAD + 2), float(atlas_h - 4)))


@dataclass(frozen=True)
class _PixelMaps:
    """Per-pixel constants: atlas coordinates are ``u = c*ax - s*ay + S*X + ou`` each frame."""

    ax: np.ndarray  # S * ppm * ground_x   (ground point in the car frame, scaled to the pixel's level)
    ay: np.ndarray  # S * ppm * ground_y
    scale: np.ndarray  # S * ppm (0 for sky pixels)
    ou: np.ndarray  # atlas offsets
    ov: np.ndarray
    umin: np.ndarray  # clamp range: stay inside the pixel's level when looking beyond the texture
    umax: np.ndarray
    vmin: np.ndarray
    vmax: np.ndarray
    first_row: int  # rows above this see only sky; the arrays above cover rows first_row.. only
    clip_rows: int  # only these first rows of the arrays can look beyond the texture and need clamping


def _pixel_levels(spec: CameraSpec, texel_m: float, levels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground points (car frame, metres), ground mask and mip level of every pixel, flattened."""
    rays = spec.rays().reshape(-1, 3)
    cam = spec.position
    down = rays[:, 2] < -1e-6
    t = np.where(down, -cam[2] / np.where(down, rays[:, 2], -1.0), np.inf)
    dist = t * np.linalg.norm(rays, axis=1)
    ground = down & (dist < MAX_RANGE_M)
    pts = np.where(ground[:, None], cam[None, :2] + np.where(ground, t, 0.0)[:, None] * rays[:, :2], 0.0)
    # Footprint of a pixel on the ground: its angular size times distance, stretched by the grazing angle.
    grazing = np.abs(rays[:, 2]) / np.linalg.norm(rays, axis=1)
    footprint = np.where(ground, dist, 0.0) / spec.focal_px / np.sqrt(np.maximum(grazing, 1e-3))
    level = np.clip(np.floor(np.log2(np.maximum(footprint / texel_m, 1.0))), 0, levels - 1).astype(int)
    return pts, ground, level


def _first_ground_row(spec: CameraSpec, frame: TextureFrame, levels: int) -> int:
    _, ground, _ = _pixel_levels(spec, 1.0 / frame.ppm, levels)
    rows = np.flatnonzero(ground.reshape(spec.height, spec.width).any(axis=1))
    return int(rows[0]) if len(rows) else spec.height - 1


def _pixel_maps(
    spec: CameraSpec, frame: TextureFrame, atlas: _Atlas, levels: int, first_row: int | None = None
) -> _PixelMaps:
    """The per-pixel constants of ``spec``; ``first_row`` (at most the first row that sees ground) makes the maps
    start there instead, so that two cameras' maps have the same rows."""
    pts, ground, level = _pixel_levels(spec, 1.0 / frame.ppm, levels)
    rows = np.flatnonzero(ground.reshape(spec.height, spec.width).any(axis=1))
    first = int(rows[0]) if len(rows) else spec.height - 1
    if first_row is not None:
        if first_row > first:
            raise ValueError(f"first_row {first_row} is below the first row that sees ground ({first})")
        first = first_row
    keep = slice(first * spec.width, None)
    pts, ground, level = pts[keep], ground[keep], level[keep]
    shape = (spec.height - first, spec.width)
    # While the car is on the track, ground closer than the texture margin is inside the texture.
    far = (~ground | (np.hypot(pts[:, 0], pts[:, 1]) > CLAMP_FREE_M)).reshape(shape).any(axis=1)
    clip_rows = int(np.flatnonzero(far)[-1]) + 1 if far.any() else 0
    s = np.where(ground, frame.ppm / (1 << level), 0.0)
    origin = np.array(atlas.origins, np.float64)[level]
    size = np.array(atlas.sizes, np.float64)[level]
    # Texel centres sit at integer atlas coordinates: level-k texel i covers [i, i+1) * 2^k texels of level 0.
    ou = np.where(ground, origin[:, 0] - 0.5, atlas.sky_uv[0])
    ov = np.where(ground, origin[:, 1] - 0.5, atlas.sky_uv[1])
    lo_u, lo_v = np.where(ground, origin[:, 0], ou), np.where(ground, origin[:, 1], ov)
    hi_u = np.where(ground, origin[:, 0] + size[:, 0] - 1, ou)
    hi_v = np.where(ground, origin[:, 1] + size[:, 1] - 1, ov)

    def f32(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a.reshape(shape), dtype=np.float32)

    return _PixelMaps(
        ax=f32(s * pts[:, 0]),
        ay=f32(s * pts[:, 1]),
        scale=f32(s),
        ou=f32(ou),
        ov=f32(ov),
        umin=f32(lo_u),
        umax=f32(hi_u),
        vmin=f32(lo_v),
        vmax=f32(hi_v),
        first_row=first,
        clip_rows=clip_rows,
    )


class GroundCamera:
    """Fast camera: samples the track texture through precomputed per-pixel ground points."""

    LEVELS = 6

    def __init__(
        self,
        frame: TextureFrame,
        texture_rgb: np.ndarray,
        spec: CameraSpec | None = None,
        sky_rgb: tuple[int, int, int] = (150, 170, 200),
    ) -> None:
        self.frame = frame
        self.spec = spec or CameraSpec()
        self.set_surface(texture_rgb, sky_rgb)

    def set_spec(self, spec: CameraSpec) -> None:
        """Move the camera on the car (recomputes the per-pixel ground points)."""
        self.spec = spec
        self._maps = _pixel_maps(spec, self.frame, self._gray, self.LEVELS)
        self._mount = _Mount.of(spec)

    def set_surface(self, texture_rgb: np.ndarray, sky_rgb: tuple[int, int, int]) -> None:
        """Use a new track texture (e.g. with randomized colours)."""
        self._texture_rgb = texture_rgb
        self._sky_rgb = np.array(sky_rgb, np.uint8)
        gray = cv2.cvtColor(texture_rgb, cv2.COLOR_RGB2GRAY)
        self._sky_gray = cv2.cvtColor(self._sky_rgb[None, None], cv2.COLOR_RGB2GRAY)[0, 0]
        self._gray = _build_atlas(gray, self._sky_gray, self.LEVELS)
        self._rgb: _Atlas | None = None  # built on the first colour frame: most runs only need gray
        self.set_spec(self.spec)

    def render(
        self,
        pose: Pose,
        color: bool = False,
        boxes: np.ndarray | None = None,
        box_colors: np.ndarray | None = None,
    ) -> np.ndarray:
        """The camera image at ``pose``: (H, W) gray uint8, or (H, W, 3) RGB with ``color``.

        ``boxes`` (K, 6) ``[x, y, yaw, length, width, height]`` are drawn over the ground, in ``box_colors``
        (K, 3) RGB 0-255 (default :data:`DEFAULT_BOX_RGB`); without boxes the image is the ground alone."""
        out = self._ground(pose, color)
        if boxes is not None and len(boxes):
            _draw_views([(out, 0.0)], self._mount, pose, _prepare_boxes(boxes, box_colors, gray=not color))
        return out

    def _ground(self, pose: Pose, color: bool) -> np.ndarray:
        m, f = self._maps, self.frame
        c, s = np.float32(math.cos(pose.yaw)), np.float32(math.sin(pose.yaw))
        tx, ty = np.float32(pose.x - f.x0), np.float32(f.y1 - pose.y)
        u = c * m.ax - s * m.ay + (m.scale * tx + m.ou)
        v = (m.scale * ty + m.ov) - (s * m.ax + c * m.ay)
        k = m.clip_rows
        np.clip(u[:k], m.umin[:k], m.umax[:k], out=u[:k])
        np.clip(v[:k], m.vmin[:k], m.vmax[:k], out=v[:k])
        if color and self._rgb is None:
            self._rgb = _build_atlas(self._texture_rgb, self._sky_rgb, self.LEVELS)
        atlas = self._rgb if color else self._gray
        sky = self._sky_rgb if color else self._sky_gray
        out = np.empty((self.spec.height, self.spec.width) + atlas.image.shape[2:], np.uint8)
        out[: m.first_row] = sky  # only sky above the horizon: skip the lookup there
        cv2.remap(atlas.image, u, v, cv2.INTER_LINEAR, dst=out[m.first_row :], borderMode=cv2.BORDER_REPLICATE)
        return out


class StereoGroundCamera:
    """DeepRacer's STEREO_CAMERAS with :class:`GroundCamera`'s per-pixel ground lookup: two gray 160×120 views,
    :func:`stereo_specs` of one :class:`CameraSpec`, stacked (H, W, 2) uint8 with the left camera in channel 0.

    deepracer-simapp ``bundle/markov/sensors/sensors_rollout.py: DualCamera.get_state`` stacks
    ``(left_img, right_img)`` on axis 2, each resized to 160×120 and converted to gray (``'L'``); the left image is
    the ``camera/zed`` topic of ``camera_link_leftcam`` (+y), the right the ``camera/zed_right`` topic of
    ``camera_link_rightcam`` (``bundle/urdf/deepracer/racecar.gazebo``). The two cameras' maps are computed once
    per pose of the rig (:meth:`set_spec`), on the same rows, so a frame costs twice a single camera's lookup."""

    LEVELS = GroundCamera.LEVELS

    def __init__(
        self,
        frame: TextureFrame,
        texture_rgb: np.ndarray,
        spec: CameraSpec | None = None,
        sky_rgb: tuple[int, int, int] = (150, 170, 200),
        baseline_m: float = STEREO_BASELINE_M,
    ) -> None:
        self.frame = frame
        self.baseline_m = baseline_m
        self.spec = spec or CameraSpec()
        self.set_surface(texture_rgb, sky_rgb)

    @property
    def specs(self) -> tuple[CameraSpec, CameraSpec]:
        """(left, right) camera specs."""
        return stereo_specs(self.spec, self.baseline_m)

    def set_spec(self, spec: CameraSpec) -> None:
        """Move the rig on the car: ``spec`` is its centre, the cameras sit half the baseline to each side."""
        self.spec = spec
        left, right = self.specs
        first = min(_first_ground_row(s, self.frame, self.LEVELS) for s in (left, right))
        a = _pixel_maps(left, self.frame, self._gray, self.LEVELS, first)
        b = _pixel_maps(right, self.frame, self._gray, self.LEVELS, first)
        self._maps = _PixelMaps(
            *(np.concatenate([getattr(a, n), getattr(b, n)]) for n in ("ax", "ay", "scale", "ou", "ov")),
            *(np.concatenate([getattr(a, n), getattr(b, n)]) for n in ("umin", "umax", "vmin", "vmax")),
            first_row=first,
            clip_rows=max(a.clip_rows, b.clip_rows),
        )
        self._rows = spec.height - first  # rows of each camera in the stacked maps
        self._mount = _Mount.of(spec)

    def set_surface(self, texture_rgb: np.ndarray, sky_rgb: tuple[int, int, int]) -> None:
        """Use a new track texture (e.g. with randomized colours)."""
        sky = np.array(sky_rgb, np.uint8)
        self._sky_gray = cv2.cvtColor(sky[None, None], cv2.COLOR_RGB2GRAY)[0, 0]
        self._gray = _build_atlas(cv2.cvtColor(texture_rgb, cv2.COLOR_RGB2GRAY), self._sky_gray, self.LEVELS)
        self._buf = np.empty((2, self.spec.height, self.spec.width), np.uint8)
        self.set_spec(self.spec)

    def render(
        self,
        pose: Pose,
        color: bool = False,
        boxes: np.ndarray | None = None,
        box_colors: np.ndarray | None = None,
    ) -> np.ndarray:
        """The two views at ``pose``: (H, W, 2) gray uint8, channel 0 the left camera. ``boxes`` and
        ``box_colors`` as in :meth:`GroundCamera.render`. DeepRacer's stereo observation is gray only."""
        if color:
            raise ValueError("STEREO_CAMERAS images are gray (DeepRacer converts both views to 'L')")
        return cv2.merge(self.render_views(pose, boxes, box_colors))

    def render_views(
        self, pose: Pose, boxes: np.ndarray | None = None, box_colors: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The (left, right) views at ``pose``, each (H, W) gray uint8: views of one buffer that the next call
        overwrites (copy or merge them to keep them). A caller that processes each view on its own (the env's
        augmentations) merges once, at the end, instead of splitting an interleaved frame."""
        m, f, n = self._maps, self.frame, self._rows
        c, s = np.float32(math.cos(pose.yaw)), np.float32(math.sin(pose.yaw))
        tx, ty = np.float32(pose.x - f.x0), np.float32(f.y1 - pose.y)
        u = c * m.ax - s * m.ay + (m.scale * tx + m.ou)
        v = (m.scale * ty + m.ov) - (s * m.ax + c * m.ay)
        k = m.clip_rows
        for lo in (0, n):  # the first rows of each camera's half can look beyond the texture
            np.clip(u[lo : lo + k], m.umin[lo : lo + k], m.umax[lo : lo + k], out=u[lo : lo + k])
            np.clip(v[lo : lo + k], m.vmin[lo : lo + k], m.vmax[lo : lo + k], out=v[lo : lo + k])
        buf, first = self._buf, m.first_row
        buf[:, :first] = self._sky_gray
        image = self._gray.image
        cv2.remap(image, u[:n], v[:n], cv2.INTER_LINEAR, dst=buf[0, first:], borderMode=cv2.BORDER_REPLICATE)
        cv2.remap(image, u[n:], v[n:], cv2.INTER_LINEAR, dst=buf[1, first:], borderMode=cv2.BORDER_REPLICATE)
        if boxes is not None and len(boxes):
            half = self.baseline_m / 2  # the cameras sit this far left and right of the rig's centre
            views = [(buf[0], half), (buf[1], -half)]
            _draw_views(views, self._mount, pose, _prepare_boxes(boxes, box_colors, gray=True))
        return buf[0], buf[1]


# --- boxes --------------------------------------------------------------------------------------------------

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
class _Mount:
    """What box drawing needs of a :class:`CameraSpec`, computed once per spec."""

    position: np.ndarray  # (3,) car frame, z above the ground
    rotation: np.ndarray  # (3, 3) columns forward, left, up in the car frame
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
    def of(cls, spec: CameraSpec) -> _Mount:
        tan_h = (spec.width / 2) / spec.focal_px
        tan_v = (spec.height / 2) / spec.focal_px
        return cls(
            spec.position,
            spec.rotation(),
            spec.focal_px,
            (spec.width - 1) / 2,
            (spec.height - 1) / 2,
            spec.width,
            spec.height,
            tan_h,
            math.hypot(1.0, tan_h),
            tan_v,
            math.hypot(1.0, tan_v),
        )

    def world(self, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """Camera centre (3,) and rotation (3×3, columns forward, left, up) in the world, car at ``pose``."""
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        car = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return np.array([pose.x, pose.y, 0.0]) + car @ self.position, car @ self.rotation


@dataclass(frozen=True)
class _Boxes:
    """Boxes as Python floats and their base colours (gray level or RGB tuple per box)."""

    rows: list[list[float]]  # [x, y, yaw, length, width, height]
    colors: list


def _prepare_boxes(boxes: np.ndarray, box_colors: np.ndarray | None, gray: bool) -> _Boxes:
    array = np.asarray(boxes, np.float64).reshape(-1, 6)
    k = len(array)
    if box_colors is None:
        rgb = [DEFAULT_BOX_RGB] * k
    else:
        rgb = np.broadcast_to(np.asarray(box_colors, np.float64).reshape(-1, 3), (k, 3)).tolist()
    colors = [sum(w * v for w, v in zip(_GRAY_WEIGHTS, col, strict=True)) for col in rgb] if gray else rgb
    return _Boxes(array.tolist(), colors)


def draw_boxes(
    image: np.ndarray,
    spec: CameraSpec,
    pose: Pose,
    boxes: np.ndarray,
    box_colors: np.ndarray | None = None,
) -> None:
    """Draw ``boxes`` ((K, 6) ``[x, y, yaw, length, width, height]``) into ``image`` ((H, W) gray or (H, W, 3)
    RGB, already holding the ground) as ``spec``'s camera on a car at ``pose`` sees them.

    Painter's algorithm: boxes far to near (horizontal distance to their centre), each box's faces that turn
    towards the camera (a box's front faces never overlap each other), clipped to :data:`NEAR_M` ahead of the
    camera, projected and filled with ``cv2.fillConvexPoly`` at 1/16 pixel precision. Boxes are vertical prisms
    on flat ground, so the ground never hides them and they hide the ground behind them. The far-to-near order
    is exact for boxes whose footprints are not long and close together. Each face is the box's colour times a
    shade: 1 on top, 0.65-0.95 on the sides by how they face a fixed light, so that edges show."""
    prepared = _prepare_boxes(boxes, box_colors, gray=image.ndim == 2)
    _draw_views([(image, 0.0)], _Mount.of(spec), pose, prepared)


def _draw_views(views: list[tuple[np.ndarray, float]], mount: _Mount, pose: Pose, b: _Boxes) -> None:
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
        if d2 > MAX_RANGE_M * MAX_RANGE_M:
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


class RenderError(UserError, RuntimeError):
    """MuJoCo's renderer could not start (no OpenGL backend)."""


def _quat_from_spec(spec: CameraSpec) -> np.ndarray:
    # MuJoCo cameras look along their -z with +x right and +y up.
    rot = spec.rotation()
    fwd, left, up = rot[:, 0], rot[:, 1], rot[:, 2]
    mat = np.stack([-left, up, -fwd], axis=1)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, mat.flatten())
    return quat


class MujocoCamera:
    """Reference camera: MuJoCo's own OpenGL render of the scene from the car's camera."""

    def __init__(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        spec: CameraSpec | None = None,
        show_car: bool = False,
    ) -> None:
        ensure_gl_backend()
        self.model, self.data = model, data
        self._cam = model.camera("front").id
        self.set_spec(spec or CameraSpec())
        try:
            self._renderer = mujoco.Renderer(model, self.spec.height, self.spec.width)
        except Exception as exc:
            raise RenderError(
                f"MuJoCo could not open an OpenGL context (MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}): {exc}. "
                "Install Mesa's EGL (libegl1, libgl1-mesa-dri) or set MUJOCO_GL=osmesa; "
                "the default camera='ground' needs no OpenGL."
            ) from None
        self._opt = mujoco.MjvOption()
        self._opt.geomgroup[2] = int(show_car)  # the car's own body: DeepRacer's camera barely sees it
        self._opt.geomgroup[3] = 0  # collision spheres
        self._opt.sitegroup[:] = 0

    def set_spec(self, spec: CameraSpec) -> None:
        """Move the camera on the car."""
        self.spec = spec
        base = np.array([0.0, 0.0, spec.base_height_m])
        self.model.cam_pos[self._cam] = spec.position - base
        self.model.cam_quat[self._cam] = _quat_from_spec(spec)
        self.model.cam_fovy[self._cam] = spec.fovy_deg

    def set_surface(self, texture_rgb: np.ndarray, sky_rgb: tuple[int, int, int]) -> None:
        """Replace the ground texture (same size) and re-upload it to the GPU (colour randomization)."""
        tex = self.model.texture("track").id
        h, w = int(self.model.tex_height[tex]), int(self.model.tex_width[tex])
        if texture_rgb.shape[:2] != (h, w):
            raise ValueError(f"texture is {texture_rgb.shape[:2]}, the model's is {(h, w)}")
        adr = int(self.model.tex_adr[tex])
        # Rows are stored as in the PNG the model was built from, which was written from this same layout.
        self.model.tex_data[adr : adr + h * w * 3] = texture_rgb.reshape(-1)
        sky = self.model.texture("sky").id
        sky_adr, sky_n = int(self.model.tex_adr[sky]), int(self.model.tex_height[sky] * self.model.tex_width[sky])
        self.model.tex_data[sky_adr : sky_adr + sky_n * 3] = np.tile(np.asarray(sky_rgb, np.uint8), sky_n)
        for t in (tex, sky):
            mujoco.mjr_uploadTexture(self.model, self._renderer._mjr_context, t)

    def render(
        self,
        pose: Pose | None = None,
        color: bool = False,
        boxes: np.ndarray | None = None,
        box_colors: np.ndarray | None = None,
    ) -> np.ndarray:
        """The camera image for the current physics state (``pose`` is ignored: the data holds it). ``boxes`` and
        ``box_colors`` are ignored too: the scene's object slots are drawn (``sim.world.set_objects``)."""
        mujoco.mj_camlight(self.model, self.data)  # camera pose from the current kinematics
        self._renderer.update_scene(self.data, camera=self._cam, scene_option=self._opt)
        rgb = self._renderer.render()
        return rgb if color else cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)

    def close(self) -> None:
        """Release the OpenGL context."""
        self._renderer.close()
