"""Per-frame image augmentations of the camera observation.

These are the augmentations of the DeepRacer paper's Table II (Balaji et al., "DeepRacer: Educational
Autonomous Racing Platform for Experimentation with Sim2Real Reinforcement Learning", 2019): random
colour (hue, saturation, brightness, contrast), horizontal translation, shadow, sharpening and
salt-and-pepper noise. Each is decided independently per frame with its probability from
:class:`~common.config.AugmentationConfig`.

The pipeline runs once per env step on a 120x160 frame, so every step is a few whole-array OpenCV or
numpy calls on uint8 data, with as few rng calls as possible (each costs microseconds).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from common.config import AugmentationConfig

__all__ = ["augment_frame", "is_identity", "needs_color"]


def needs_color(cfg: AugmentationConfig) -> bool:
    """Whether colour jitter may be applied, so the caller must render an RGB frame, not grayscale."""
    return cfg.color_prob > 0


def is_identity(cfg: AugmentationConfig) -> bool:
    """Whether :func:`augment_frame` can change nothing but the frame's conversion to gray (every probability 0, or
    a translation of 0 pixels): the caller may then skip it. It draws nothing from the rng either way."""
    translates = cfg.translate_prob > 0 and cfg.translate_max_px > 0
    sharpens = cfg.sharpen_prob > 0 and cfg.sharpen_max > 0
    return not (cfg.color_prob > 0 or translates or cfg.shadow_prob > 0 or sharpens or cfg.salt_pepper_prob > 0)


def augment_frame(frame: np.ndarray, cfg: AugmentationConfig, rng: np.random.Generator) -> np.ndarray:
    """Apply the configured augmentations to one camera frame.

    Args:
        frame: uint8 image, (H, W, 3) RGB or (H, W) grayscale. It is never modified.
        cfg: which augmentations to apply, with their probabilities and strengths.
        rng: source of all randomness; the same seed gives the same output.

    Returns:
        A new (H, W) uint8 grayscale frame. Order: colour jitter, grayscale conversion, horizontal
        translation, shadow, sharpening, salt-and-pepper. A step whose probability is 0 draws nothing from
        ``rng``, so with every probability 0 the result is exactly the grayscale of ``frame``.
    """
    _check_frame(frame)
    gray = _color_jitter(frame, cfg, rng) if _happens(cfg.color_prob, rng) else _to_gray(frame)
    if _happens(cfg.translate_prob, rng) and cfg.translate_max_px > 0:
        gray = _translate(gray, cfg.translate_max_px, rng)
    if _happens(cfg.shadow_prob, rng):
        _shadow(gray, cfg.shadow_darkness, rng)
    if _happens(cfg.sharpen_prob, rng) and cfg.sharpen_max > 0:
        gray = _sharpen(gray, cfg.sharpen_max * rng.random())
    if _happens(cfg.salt_pepper_prob, rng):
        _salt_pepper(gray, cfg.salt_pepper_amount, rng)
    return gray


def _check_frame(frame: np.ndarray) -> None:
    """Reject frames the pipeline cannot handle, before OpenCV fails with a less clear message."""
    if frame.dtype != np.uint8 or not (frame.ndim == 2 or (frame.ndim == 3 and frame.shape[2] == 3)):
        raise ValueError(f"expected a uint8 (H, W) or (H, W, 3) frame, got {frame.dtype} {frame.shape}")


def _happens(prob: float, rng: np.random.Generator) -> bool:
    """Draw whether a step happens; a probability of 0 draws nothing, keeping the rng stream intact."""
    return prob > 0 and rng.random() < prob


def _to_gray(frame: np.ndarray) -> np.ndarray:
    """A fresh grayscale copy of the frame (a copy, so later in-place steps leave the input alone)."""
    if frame.ndim == 2:
        return frame.copy()
    return cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)


def _color_jitter(frame: np.ndarray, cfg: AugmentationConfig, rng: np.random.Generator) -> np.ndarray:
    """Random hue, saturation, brightness and contrast change; returns the grayscale result.

    All four factors are drawn even for a grayscale frame, so that the rng stream does not depend on
    whether the caller rendered colour; hue and saturation are then simply not applicable.
    """
    hue_deg, sat, bright, contrast = rng.uniform(-1.0, 1.0, size=4) * (
        cfg.hue_max_deg,
        cfg.saturation_max,
        cfg.brightness_max,
        cfg.contrast_max,
    )
    if frame.ndim == 3:
        frame = _hue_saturation(frame, float(hue_deg), 1.0 + float(sat))
    gray = _to_gray(frame)
    return _brightness_contrast(gray, 1.0 + float(bright), 1.0 + float(contrast))


def _hue_saturation(rgb: np.ndarray, hue_deg: float, sat_scale: float) -> np.ndarray:
    """Rotate hue by ``hue_deg`` and scale saturation by ``sat_scale``, in HSV."""
    # The "full" 8-bit HSV maps 360 degrees of hue onto 0..255, so that uint8 addition wraps the hue
    # around the colour circle by itself, with no modulo pass.
    hue_step = round(hue_deg * 256.0 / 360.0) % 256
    if hue_step == 0 and round(sat_scale * 255.0) == 255:
        # The 8-bit HSV round trip alone shifts gray levels by a few units; skip it when it is a no-op.
        return rgb
    hue, sat, val = cv2.split(cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV_FULL))
    np.add(hue, np.uint8(hue_step), out=hue)
    # addWeighted saturates to 0..255, which is the clipping saturation needs.
    sat = cv2.addWeighted(sat, sat_scale, sat, 0.0, 0.0)
    return cv2.cvtColor(cv2.merge((hue, sat, val)), cv2.COLOR_HSV2RGB_FULL)


def _brightness_contrast(gray: np.ndarray, bright_scale: float, contrast_scale: float) -> np.ndarray:
    """Stretch intensities about the frame mean by the contrast factor, then scale by brightness."""
    mean = cv2.mean(gray)[0]
    # b * ((x - m) * c + m) = (b * c) * x + b * m * (1 - c), as one saturating affine map.
    gain = bright_scale * contrast_scale
    offset = bright_scale * mean * (1.0 - contrast_scale)
    return cv2.addWeighted(gray, gain, gray, 0.0, offset)


def _translate(gray: np.ndarray, max_px: int, rng: np.random.Generator) -> np.ndarray:
    """Shift the frame left or right by 1..max_px columns, replicating the border column into the gap.

    The shift is never 0, so a drawn translation always moves the image.
    """
    width = gray.shape[1]
    # One draw gives the magnitude (1..max_px, high bits) and the direction (lowest bit).
    draw = int(rng.integers(0, 2 * max_px))
    dx = (draw >> 1) + 1 if draw & 1 else -((draw >> 1) + 1)
    dx = max(-(width - 1), min(width - 1, dx))  # keep at least one source column
    out = np.empty_like(gray)
    if dx > 0:
        out[:, dx:] = gray[:, :-dx]
        out[:, :dx] = gray[:, :1]
    else:
        out[:, :dx] = gray[:, -dx:]
        out[:, dx:] = gray[:, -1:]
    return out


def _shadow(gray: np.ndarray, darkness: float, rng: np.random.Generator) -> None:
    """Darken, in place, a random quadrilateral that spans the frame from top to bottom.

    The top and bottom edges are sorted horizontal segments, so the trapezoid is always convex and
    ``cv2.fillConvexPoly`` can rasterize it.
    """
    height, width = gray.shape
    x0, x1, x2, x3 = rng.integers(0, width, size=4).tolist()
    factor = 1.0 - darkness * rng.random()
    corners = np.array(
        [[min(x0, x1), 0], [max(x0, x1), 0], [max(x2, x3), height - 1], [min(x2, x3), height - 1]],
        dtype=np.int32,
    )
    mask = np.zeros_like(gray)
    cv2.fillConvexPoly(mask, corners, 255)
    # With factor <= 1, round(x * factor) <= x for every integer x: no pixel gets brighter.
    dark = cv2.addWeighted(gray, factor, gray, 0.0, 0.0)
    cv2.copyTo(dark, mask, gray)


SHARPEN_SIGMA_PX = 1.0
"""Blur of the unsharp mask, pixels: edges a pixel or two wide (the borders and dashes at a few metres) get crisper."""


def _sharpen(gray: np.ndarray, amount: float) -> np.ndarray:
    """Unsharp mask: ``gray + amount · (gray - blur(gray))``, saturated to uint8."""
    blurred = cv2.GaussianBlur(gray, (0, 0), SHARPEN_SIGMA_PX)
    return cv2.addWeighted(gray, 1.0 + amount, blurred, -amount, 0.0)


def _salt_pepper(gray: np.ndarray, amount: float, rng: np.random.Generator) -> None:
    """Set, in place, about ``amount`` of the pixels to 0 or 255 at random.

    Positions are drawn with replacement, far cheaper than a permutation. n draws over N pixels hit
    a fraction 1 - exp(-n / N) of them on average, so n = -N ln(1 - amount) hits ``amount``.
    """
    flat = gray.reshape(-1)
    count = round(-math.log1p(-amount) * flat.size)
    if count == 0:
        return
    # One draw carries both the position (high bits) and the black/white choice (lowest bit).
    draws = rng.integers(0, 2 * flat.size, size=count)
    flat[draws >> 1] = (draws & 1).astype(np.uint8) * np.uint8(255)
