"""The car's camera: 160×120 at 15 Hz, the fast path and the camera model both paths share.

``GroundCamera`` is the fast path. The track is flat and the camera is rigid on the car, so every
pixel's ray hits the ground at a fixed point *in the car's frame*; a frame is then only a rotation
and translation of those points into the track frame and one bilinear lookup in the track texture
(OpenCV ``remap``), with a mip level per pixel chosen from its ground footprint so that distant
lines do not alias. ``sim.mujoco_camera.MujocoCamera`` renders the same view with MuJoCo's OpenGL renderer; it is
the reference the fast path is tested against.

Objects (obstacles, bot cars) are boxes drawn over the ground image by ``sim.box_raster``.
``StereoGroundCamera`` renders DeepRacer's STEREO_CAMERAS: two gray views 6 cm apart, stacked as (H, W, 2) with the
left camera first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from common.config import FRAME_HEIGHT, FRAME_WIDTH
from sim.box_raster import Mount, draw_views, prepare_boxes
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


def _texture_coords(
    m: _PixelMaps, f: TextureFrame, pose: Pose, starts: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's texture coordinates (u, v) with the car at ``pose``: the maps' ground points, fixed in the car's
    frame, turned and moved into the texture's. The first ``clip_rows`` rows from each of ``starts`` (where one
    camera's rows begin) can look beyond the texture and are clamped to it."""
    c, s = np.float32(math.cos(pose.yaw)), np.float32(math.sin(pose.yaw))
    tx, ty = np.float32(pose.x - f.x0), np.float32(f.y1 - pose.y)
    u = c * m.ax - s * m.ay + (m.scale * tx + m.ou)
    v = (m.scale * ty + m.ov) - (s * m.ax + c * m.ay)
    k = m.clip_rows
    for lo in starts:
        np.clip(u[lo : lo + k], m.umin[lo : lo + k], m.umax[lo : lo + k], out=u[lo : lo + k])
        np.clip(v[lo : lo + k], m.vmin[lo : lo + k], m.vmax[lo : lo + k], out=v[lo : lo + k])
    return u, v


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
        self._mount = Mount.of(spec, MAX_RANGE_M)

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
        (K, 3) RGB 0-255 (default :data:`sim.box_raster.DEFAULT_BOX_RGB`); without boxes the image is the ground
        alone."""
        out = self._ground(pose, color)
        if boxes is not None and len(boxes):
            draw_views([(out, 0.0)], self._mount, pose, prepare_boxes(boxes, box_colors, gray=not color))
        return out

    def _ground(self, pose: Pose, color: bool) -> np.ndarray:
        m = self._maps
        u, v = _texture_coords(m, self.frame, pose, starts=(0,))
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
        self._mount = Mount.of(spec, MAX_RANGE_M)

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
        m, n = self._maps, self._rows
        u, v = _texture_coords(m, self.frame, pose, starts=(0, n))  # each camera's rows: a half of the maps
        buf, first = self._buf, m.first_row
        buf[:, :first] = self._sky_gray
        image = self._gray.image
        cv2.remap(image, u[:n], v[:n], cv2.INTER_LINEAR, dst=buf[0, first:], borderMode=cv2.BORDER_REPLICATE)
        cv2.remap(image, u[n:], v[n:], cv2.INTER_LINEAR, dst=buf[1, first:], borderMode=cv2.BORDER_REPLICATE)
        if boxes is not None and len(boxes):
            half = self.baseline_m / 2  # the cameras sit this far left and right of the rig's centre
            views = [(buf[0], half), (buf[1], -half)]
            draw_views(views, self._mount, pose, prepare_boxes(boxes, box_colors, gray=True))
        return buf[0], buf[1]
