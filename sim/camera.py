"""The car's camera: 160×120 at 15 Hz, two interchangeable paths.

``GroundCamera`` is the fast path. The track is flat and the camera is rigid on the car, so every
pixel's ray hits the ground at a fixed point *in the car's frame*; a frame is then only a rotation
and translation of those points into the track frame and one bilinear lookup in the track texture
(OpenCV ``remap``), with a mip level per pixel chosen from its ground footprint so that distant
lines do not alias. ``MujocoCamera`` renders the same view with MuJoCo's OpenGL renderer (EGL when
headless); it sees everything in the scene and is the reference the fast path is tested against.
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


def _pixel_maps(spec: CameraSpec, frame: TextureFrame, atlas: _Atlas, levels: int) -> _PixelMaps:
    pts, ground, level = _pixel_levels(spec, 1.0 / frame.ppm, levels)
    rows = np.flatnonzero(ground.reshape(spec.height, spec.width).any(axis=1))
    first = int(rows[0]) if len(rows) else spec.height - 1
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

    def set_surface(self, texture_rgb: np.ndarray, sky_rgb: tuple[int, int, int]) -> None:
        """Use a new track texture (e.g. with randomized colours)."""
        self._texture_rgb = texture_rgb
        self._sky_rgb = np.array(sky_rgb, np.uint8)
        gray = cv2.cvtColor(texture_rgb, cv2.COLOR_RGB2GRAY)
        self._sky_gray = cv2.cvtColor(self._sky_rgb[None, None], cv2.COLOR_RGB2GRAY)[0, 0]
        self._gray = _build_atlas(gray, self._sky_gray, self.LEVELS)
        self._rgb: _Atlas | None = None  # built on the first colour frame: most runs only need gray
        self.set_spec(self.spec)

    def render(self, pose: Pose, color: bool = False) -> np.ndarray:
        """The camera image at ``pose``: (H, W) gray uint8, or (H, W, 3) RGB with ``color``."""
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

    def render(self, pose: Pose | None = None, color: bool = False) -> np.ndarray:
        """The camera image for the current physics state (``pose`` is ignored: the data holds it)."""
        mujoco.mj_camlight(self.model, self.data)  # camera pose from the current kinematics
        self._renderer.update_scene(self.data, camera=self._cam, scene_option=self._opt)
        rgb = self._renderer.render()
        return rgb if color else cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)

    def close(self) -> None:
        """Release the OpenGL context."""
        self._renderer.close()
