"""Evaluation videos: what the car's camera saw, beside the car on the track from above, as an MP4.

The camera panel shows the front camera enlarged ×3, or a stereo pair's left and right images side by side at ×1.5,
with the LiDAR observation (if any) plotted in its corner; the top-down panel shows the car and the race's obstacles
(orange) and bot cars (blue).

Encoded as H.264 (``avc1``, yuv420p, ``+faststart``), the codec every browser plays, with PyAV's FFmpeg (libx264).
Where PyAV or its libx264 is missing, OpenCV's ``VideoWriter`` writes MPEG-4 part 2 (``mp4v``) instead, which
desktop players read but browsers do not, and a warning says so once per video.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from fractions import Fraction
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common.sensors import split_observation
from sim.env import RacerEnv
from sim.obstacles import WorldObject
from sim.physics import Pose
from sim.texture import TextureFrame
from sim.track import Track
from sim.views import top_down

log = logging.getLogger(__name__)

CAMERA_ZOOM = 3
"""The 160×120 camera image is enlarged this many times (nearest neighbour, so its pixels stay visible)."""
H264, FALLBACK = "avc1", "mp4v"
"""The codec wanted (H.264, with PyAV) and the one OpenCV writes where that is missing (MPEG-4 part 2)."""
H264_CRF = 23
"""libx264's constant-quality setting (23 is its own default)."""
DEFAULT_MAX_STEPS = 3000
"""``record_episode``'s step cap: the env's default time limit (200 s at 15 Hz)."""
_TEXT = (cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)  # font, scale, thickness of the overlay


def _even(n: int) -> int:
    # Most MP4 encoders work on 2×2 chroma blocks (yuv420p): odd frame sides are refused or cropped.
    return n + (n % 2)


def _fit_height(img: np.ndarray, height: int) -> np.ndarray:
    """Shrink ``img`` (keeping its aspect) if it is taller than ``height``, then pad it with black to ``height``."""
    if img.shape[0] > height:
        width = max(1, round(img.shape[1] * height / img.shape[0]))
        img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    top = (height - img.shape[0]) // 2
    return cv2.copyMakeBorder(img, top, height - img.shape[0] - top, 0, 0, cv2.BORDER_CONSTANT, value=(0, 0, 0))


class _H264Writer:
    """RGB frames to an H.264 MP4 through PyAV."""

    def __init__(self, path: Path, fps: float, size: tuple[int, int]) -> None:
        import av

        self._av = av
        self._container = av.open(str(path), mode="w", options={"movflags": "+faststart"})
        self._stream = self._container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        self._stream.width, self._stream.height = size
        self._stream.pix_fmt = "yuv420p"  # what browsers decode (libx264 would keep 4:4:4 from RGB input)
        self._stream.options = {"crf": str(H264_CRF), "preset": "veryfast"}

    def write(self, rgb: np.ndarray) -> None:
        frame = self._av.VideoFrame.from_ndarray(rgb, format="rgb24")
        self._container.mux(self._stream.encode(frame))

    def release(self) -> None:
        self._container.mux(self._stream.encode())  # flush the encoder's delayed frames
        self._container.close()


class _OpenCVWriter:
    """RGB frames to an MPEG-4 part 2 MP4 through OpenCV (the fallback)."""

    def __init__(self, path: Path, fps: float, size: tuple[int, int]) -> None:
        self._writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*FALLBACK), fps, size)
        if not self._writer.isOpened():
            raise OSError(f"could not open an MP4 writer for {str(path)!r} (no H.264 encoder; OpenCV's mp4v failed)")

    def write(self, rgb: np.ndarray) -> None:
        self._writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))

    def release(self) -> None:
        self._writer.release()


def h264_available() -> bool:
    """Whether PyAV with FFmpeg's libx264 encoder is installed."""
    try:
        import av
    except ImportError:
        return False
    return "libx264" in av.codecs_available


def _open_writer(path: Path, fps: float, size: tuple[int, int]) -> tuple[_H264Writer | _OpenCVWriter, str]:
    """The H.264 writer if this machine has one, else OpenCV's MPEG-4 part 2 with a warning; and its fourcc."""
    if h264_available():
        return _H264Writer(path, fps, size), H264
    log.warning(
        "no H.264 encoder here (PyAV with libx264: pip install av): %s is MPEG-4 part 2, which desktop players "
        "play and browsers do not",
        path,
    )
    return _OpenCVWriter(path, fps, size), FALLBACK


class EpisodeVideo:
    """An MP4 of an episode: the camera view (enlarged ×3; a stereo pair at ×1.5 side by side) on the left, the car
    (with the race's obstacles and bot cars) on the track from above on the right.

    Both panels have the camera's height (360 px): the top-down view, ``top_width`` pixels wide, is shrunk if it is
    taller and padded with black otherwise. Each frame is stamped with its step number (frame 0 is the reset frame).
    Use as a context manager, or call :meth:`close` to finish the file. ``size`` is the frames' (width, height)
    in pixels (both even: 960×360 for reinvent_base at the defaults), ``frames`` the number written so far and
    ``fourcc`` the codec written (``avc1``: H.264; ``mp4v`` where no H.264 encoder is installed).
    """

    def __init__(
        self,
        path: str | Path,
        track: Track,
        texture: np.ndarray,
        frame: TextureFrame,
        fps: float = 15,
        top_width: int = 480,
    ) -> None:
        self.path = Path(path)
        self.track = track
        # Scale the texture to the panel once: top_down would otherwise resize the full-resolution texture (megapixels)
        # on every frame. A frame with the scaled resolution keeps metres → pixels exact for the smaller texture.
        scale = top_width / texture.shape[1]
        height = max(1, round(texture.shape[0] * scale))
        self._texture = cv2.resize(texture, (top_width, height), interpolation=cv2.INTER_AREA)
        self._frame = TextureFrame(frame.x0, frame.y1, frame.ppm * scale, top_width, height)
        self.top_width = top_width
        self.height = _even(120 * CAMERA_ZOOM)
        top_w = min(top_width, max(1, round(top_width * self.height / height)))  # after _fit_height
        self.size = (_even(160 * CAMERA_ZOOM + top_w), self.height)  # (width, height), pixels, both even
        self.frames = 0  # written so far
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._writer, self.fourcc = _open_writer(self.path, fps, self.size)

    def compose(
        self,
        camera_gray: np.ndarray,
        pose: Pose,
        text: str = "",
        objects: Sequence[WorldObject] | None = None,
        lidar: np.ndarray | None = None,
    ) -> np.ndarray:
        """One RGB frame of the video (height, width, 3) uint8: camera view | top-down view, with the overlay.

        ``camera_gray`` is one camera frame: (120, 160) or (120, 160, 1), shown enlarged ×3; or a stereo pair
        (120, 160, 2), shown as the left and right images side by side at ×1.5 (the panel keeps its size).
        ``objects`` (the env's obstacles and bot cars) are drawn on the track; ``lidar`` (the env's LiDAR
        observation: 64 clipped ranges or 8 sectors) is drawn as a small plot around the car in the camera panel's
        bottom-right corner."""
        left = _camera_panel(np.asarray(camera_gray), self.height)
        if lidar is not None:
            _draw_lidar(left, np.asarray(lidar, np.float32))
        top = top_down(self.track, self._texture, self._frame, [pose], width=self.top_width, objects=objects)
        out = np.concatenate([left, _fit_height(top, self.height)], axis=1)
        out = cv2.copyMakeBorder(out, 0, 0, 0, self.size[0] - out.shape[1], cv2.BORDER_CONSTANT, value=(0, 0, 0))
        _overlay(out, f"step {self.frames}" + (f"  {text}" if text else ""))
        return out

    def add(
        self,
        camera_gray: np.ndarray,
        pose: Pose,
        text: str = "",
        objects: Sequence[WorldObject] | None = None,
        lidar: np.ndarray | None = None,
    ) -> None:
        """Append a frame: the camera image (120, 160), (120, 160, 1) or stereo (120, 160, 2) uint8 and the car's
        pose; ``text`` is shown after the step number; ``objects`` and ``lidar`` as in :meth:`compose`."""
        if self._writer is None:
            raise RuntimeError(f"video {str(self.path)!r} is closed")
        rgb = self.compose(camera_gray, pose, text, objects, lidar)
        self._writer.write(rgb)
        self.frames += 1

    def close(self) -> None:
        """Finish the file (writes the MP4 index); safe to call twice."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def __enter__(self) -> EpisodeVideo:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _camera_panel(cam: np.ndarray, height: int) -> np.ndarray:
    """The camera panel (``height`` × 480 RGB): one image enlarged ×3, or a stereo pair side by side at ×1.5,
    centred vertically, each labelled."""
    if cam.ndim == 3 and cam.shape[2] == 1:
        cam = cam[..., 0]
    stereo = cam.ndim == 3 and cam.shape[2] == 2
    if cam.shape[:2] != (120, 160) or cam.dtype != np.uint8 or not (cam.ndim == 2 or stereo):
        raise ValueError(
            f"camera image must be (120, 160), (120, 160, 1) or a stereo pair (120, 160, 2) uint8, got {cam.shape} "
            f"{cam.dtype}"
        )
    if not stereo:
        big = cv2.resize(cam, None, fx=CAMERA_ZOOM, fy=CAMERA_ZOOM, interpolation=cv2.INTER_NEAREST)
        return _fit_height(cv2.cvtColor(big, cv2.COLOR_GRAY2RGB), height)
    zoom = CAMERA_ZOOM / 2
    views = [cv2.resize(cam[..., k], None, fx=zoom, fy=zoom, interpolation=cv2.INTER_LINEAR) for k in range(2)]
    strip = cv2.cvtColor(np.concatenate(views, axis=1), cv2.COLOR_GRAY2RGB)
    font, scale, thick = _TEXT
    for k, label in enumerate(("left", "right")):
        x = k * views[0].shape[1] + 6
        y = strip.shape[0] - 8
        cv2.putText(strip, label, (x, y), font, scale, (0, 0, 0), thick + 2, cv2.LINE_AA)
        cv2.putText(strip, label, (x, y), font, scale, (255, 255, 255), thick, cv2.LINE_AA)
    return _fit_height(strip, height)


LIDAR_INSET = 90
"""Side of the LiDAR plot in the camera panel's bottom-right corner, pixels."""
LIDAR_PLOT_RANGE_M = 1.0
"""The plot's radius in metres: the LIDAR observation's clip (0.15-1.0 m)."""


def _draw_lidar(panel: np.ndarray, lidar: np.ndarray) -> None:
    """A LiDAR observation from above, the car in the middle heading up, into ``panel``'s bottom-right corner:
    ``LIDAR`` (64 ranges) as rays to their returns (those short of 1 m in red); ``SECTOR_LIDAR`` (8 sectors) as
    wedges, red where something is closer than 0.5 m."""
    from sim.lidar import LidarSpec

    n = LIDAR_INSET
    h, w = panel.shape[:2]
    box = panel[h - n : h, w - n : w]
    box[:] = (box.astype(np.uint16) * 2 // 5).astype(np.uint8)  # darken what is behind
    cx = cy = n // 2
    radius = n // 2 - 4
    angles = LidarSpec().angles()  # car frame, anticlockwise from ahead, scan order

    def at(angle: float, r: float) -> tuple[int, int]:
        # Ahead is up, the car's left is the picture's left.
        return int(round(cx - r * radius * math.sin(angle))), int(round(cy - r * radius * math.cos(angle)))

    cv2.circle(box, (cx, cy), radius, (120, 120, 120), 1, cv2.LINE_AA)
    if lidar.shape == (len(angles),):
        for angle, value in zip(angles, lidar, strict=True):
            r = float(np.clip(value, 0.0, LIDAR_PLOT_RANGE_M)) / LIDAR_PLOT_RANGE_M
            hit = value < LIDAR_PLOT_RANGE_M - 1e-3
            cv2.line(box, (cx, cy), at(angle, r), (230, 40, 40) if hit else (90, 160, 90), 1, cv2.LINE_AA)
    elif lidar.ndim == 1 and lidar.size and len(angles) % lidar.size == 0:
        per = len(angles) // lidar.size
        step = float(angles[1] - angles[0])
        for k, value in enumerate(lidar):
            arc = np.linspace(angles[k * per] - step / 2, angles[(k + 1) * per - 1] + step / 2, 8)
            poly = np.array([(cx, cy), *(at(a, 1.0) for a in arc)], np.int32)
            if value > 0.5:
                cv2.fillPoly(box, [poly], (230, 40, 40), cv2.LINE_AA)
            cv2.polylines(box, [poly], True, (150, 150, 150), 1, cv2.LINE_AA)
    else:
        raise ValueError(f"lidar must be a LIDAR (64,) or SECTOR_LIDAR (8,) observation, got shape {lidar.shape}")
    car = np.array([(cx - 3, cy - 5), (cx + 3, cy - 5), (cx + 3, cy + 5), (cx - 3, cy + 5)], np.int32)
    cv2.fillPoly(box, [car], (255, 255, 255))


def _overlay(img: np.ndarray, text: str) -> None:
    """Text at the top left on a dark box, so that it reads on the camera's bright and dark scenes alike."""
    font, scale, thick = _TEXT
    (w, h), base = cv2.getTextSize(text, font, scale, thick)
    cv2.rectangle(img, (4, 4), (12 + w, 12 + h + base), (0, 0, 0), cv2.FILLED)
    cv2.putText(img, text, (8, 8 + h), font, scale, (255, 255, 255), thick, cv2.LINE_AA)


def record_episode(
    env: RacerEnv,
    policy_fn: Callable[[np.ndarray], Any],
    path: str | Path,
    max_steps: int = DEFAULT_MAX_STEPS,
    *,
    seed: int | None = None,
    options: dict | None = None,
    fps: float = 15,
) -> dict[str, Any]:
    """Reset ``env`` (with ``seed``/``options``), drive it with ``policy_fn(obs) -> action`` and record every frame
    (the reset frame first) to ``path``, until the episode ends or after ``max_steps`` steps.

    Returns ``{"path", "steps", "frames", "status", "progress", "reward", "fourcc"}``: ``status`` is the env's
    episode status at the end (still ``in_progress`` if ``max_steps`` cut the episode short), ``progress`` the
    percent of a lap driven, ``reward`` the sum of the rewards.
    """
    obs, info = env.reset(seed=seed, options=options)
    steps, total, done = 0, 0.0, False
    # After reset: the texture may have been recoloured by domain randomization for this episode.
    with EpisodeVideo(path, env.track, env.texture, env.frame, fps=fps) as video:
        camera, lidar = split_observation(obs)
        video.add(camera, env.physics.pose, _status_text(info), env.objects, lidar)
        while not done and steps < max_steps:
            obs, reward, terminated, truncated, info = env.step(policy_fn(obs))
            steps, total, done = steps + 1, total + float(reward), terminated or truncated
            camera, lidar = split_observation(obs)
            video.add(camera, env.physics.pose, _status_text(info), env.objects, lidar)
    return {
        "path": str(video.path),
        "steps": steps,
        "frames": video.frames,
        "status": str(info["episode_status"]),
        "progress": float(info["progress"]),
        "reward": total,
        "fourcc": video.fourcc,
    }


def _status_text(info: dict[str, Any]) -> str:
    return f"progress {float(info['progress']):5.1f} %  {info['episode_status']}"
