"""OpenGL backend choice for MuJoCo; imported by ``sim`` before anything imports mujoco."""

import os


def ensure_gl_backend() -> str:
    """Use MuJoCo's EGL backend (headless, Mesa) when no display is present and the user chose none.

    MuJoCo reads ``MUJOCO_GL`` when it is first imported, so this must run before ``import mujoco``.
    """
    if "MUJOCO_GL" not in os.environ and not os.environ.get("DISPLAY"):
        os.environ["MUJOCO_GL"] = "egl"
    return os.environ.get("MUJOCO_GL", "glfw")
