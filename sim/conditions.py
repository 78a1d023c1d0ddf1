"""What a held-out condition (``common.config.WorldCondition``) does to the camera's frames.

The env applies the rest itself: the colours to the track texture, the camera pitch to its camera, the speed cap
to its commands. Here: strong sunlight (exposure, a glare patch, hard shadows, drawn once per episode so that
they stay put while the car drives, as a window's light does over a lap's seconds), blur, sensor noise and
frame latency, applied to each grey view after the run's own lighting and augmentations.
"""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np

from common.config import WorldCondition

SUN_EXPOSURE = 0.6
"""Exposure gain at full sunlight: +60 %, enough to clip a light-grey border to white."""
SUN_GLARE = 120.0
"""Grey levels added at the centre of the glare patch at full sunlight."""
SUN_SHADOW = 0.35
"""Brightness inside a hard shadow at full sunlight (a third of the lit floor)."""


class FrameCondition:
    """A condition's frame effects for one env; call :meth:`begin` at each episode's start."""

    def __init__(self, world: WorldCondition, shape: tuple[int, int]) -> None:
        self.world = world
        self.shape = shape
        self._gain: np.ndarray | None = None
        self._add: np.ndarray | None = None
        self._past: deque[np.ndarray] = deque(maxlen=world.frame_latency + 1)

    @property
    def active(self) -> bool:
        """Whether it changes frames at all."""
        w = self.world
        return bool(w.sunlight or w.blur_px or w.sensor_noise or w.frame_latency)

    def begin(self, rng: np.random.Generator) -> None:
        """A new episode: a new draw of the sun's shadows and glare, and no past frames."""
        self._past.clear()
        if self.world.sunlight:
            self._gain, self._add = sunlight_maps(self.shape, self.world.sunlight, rng)

    def apply(self, frame: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The frame (H, W) or (H, W, C) uint8 as the condition's camera gives it."""
        w = self.world
        out = frame
        if self._gain is not None:
            gain = self._gain if out.ndim == 2 else self._gain[..., None]
            add = self._add if out.ndim == 2 else self._add[..., None]
            out = cv2.convertScaleAbs(out.astype(np.float32) * gain + add)
        if w.blur_px:
            out = cv2.GaussianBlur(out, (0, 0), w.blur_px)
        if w.sensor_noise:
            noise = rng.normal(0.0, w.sensor_noise, out.shape).astype(np.float32)
            out = cv2.convertScaleAbs(out.astype(np.float32) + noise)
        if w.frame_latency:
            self._past.append(out)
            out = self._past[0]  # the oldest kept: latency steps ago, or the episode's first frame early on
        return out


def sunlight_maps(shape: tuple[int, int], strength: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(gain, add) float32 maps of one sunny scene: the exposure gain with hard shadow bands cut out of it, and
    the glare (grey levels added around a point in the upper half of the frame, where the sun reflects)."""
    h, w = shape
    gain = np.full((h, w), 1.0 + SUN_EXPOSURE * strength, np.float32)
    # Hard shadows: two to three straight-edged bands across the frame (window frames, posts, a person), their
    # edges sharp: unlike the training augmentation's soft polygons.
    for _ in range(int(rng.integers(2, 4))):
        angle = rng.uniform(0, np.pi)
        width = rng.uniform(0.08, 0.2) * w
        offset = rng.uniform(-0.5, 0.5) * w
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        distance = (xx - w / 2) * np.cos(angle) + (yy - h / 2) * np.sin(angle) - offset
        gain[np.abs(distance) < width / 2] = 1.0 - (1.0 - SUN_SHADOW) * strength
    cy, cx = rng.uniform(0.05, 0.5) * h, rng.uniform(0.2, 0.8) * w
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    radius = 0.25 * w
    add = (SUN_GLARE * strength * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * radius**2))).astype(np.float32)
    return gain, add
