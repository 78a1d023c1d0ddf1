"""The reference camera: MuJoCo's own OpenGL render of the scene from the car's camera (EGL when headless).

It sees everything in the scene, the object slots included (``sim.world.set_objects``), and is what the fast
``sim.camera.GroundCamera`` is tested against.
"""

from __future__ import annotations

import os

import cv2
import mujoco
import numpy as np

from common.errors import UserError
from sim._gl import ensure_gl_backend
from sim.camera import CameraSpec
from sim.physics import Pose


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
