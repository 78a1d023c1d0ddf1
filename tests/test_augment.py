"""Tests of the camera-frame augmentations (sim.augment)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from common.config import AugmentationConfig
from sim.augment import augment_frame, needs_color

H, W = 120, 160
ALL_ON = AugmentationConfig(color_prob=1, translate_prob=1, shadow_prob=1, sharpen_prob=1, salt_pepper_prob=1)


def colorful_rgb(seed: int = 0) -> np.ndarray:
    """A saturated frame: vertical bands of red, green, blue, yellow, cyan and magenta plus noise."""
    palette = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 0], [0, 255, 255], [255, 0, 255]], np.uint8)
    bands = palette[(np.arange(W) * len(palette)) // W]
    frame = np.broadcast_to(bands, (H, W, 3)).astype(np.int16)
    frame += np.random.default_rng(seed).integers(-20, 21, size=frame.shape, dtype=np.int16)
    return np.clip(frame, 0, 255).astype(np.uint8)


def gradient_gray() -> np.ndarray:
    """A gray frame with mid-range values, so darkening and brightening are both visible."""
    rows = np.linspace(60, 200, H)[:, None]
    cols = np.linspace(0, 30, W)[None, :]
    return (rows + cols).astype(np.uint8)


def stripe_frame(col: int) -> np.ndarray:
    """A dark gray frame with one bright, 2-column vertical stripe starting at ``col``."""
    frame = np.full((H, W), 40, np.uint8)
    frame[:, col : col + 2] = 230
    return frame


def stripe_col(frame: np.ndarray) -> int:
    """Leftmost column whose every pixel is bright."""
    cols = np.flatnonzero((frame > 200).all(axis=0))
    assert cols.size > 0, "stripe lost"
    return int(cols[0])


def test_needs_color() -> None:
    assert not needs_color(AugmentationConfig(translate_prob=1, shadow_prob=1, salt_pepper_prob=1))
    assert needs_color(AugmentationConfig(color_prob=0.1))


def test_all_off_rgb_is_cv2_gray() -> None:
    frame = colorful_rgb()
    out = augment_frame(frame, AugmentationConfig(), np.random.default_rng(0))
    assert out.dtype == np.uint8
    assert out.shape == (H, W)
    np.testing.assert_array_equal(out, cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))


def test_all_off_gray_is_identity_copy() -> None:
    frame = gradient_gray()
    out = augment_frame(frame, AugmentationConfig(), np.random.default_rng(0))
    assert out.dtype == np.uint8
    assert out.shape == (H, W)
    np.testing.assert_array_equal(out, frame)
    assert not np.shares_memory(out, frame)


def test_all_off_draws_no_randomness() -> None:
    rng = np.random.default_rng(7)
    augment_frame(colorful_rgb(), AugmentationConfig(), rng)
    assert rng.random() == np.random.default_rng(7).random()


@pytest.mark.parametrize("frame", [colorful_rgb(), gradient_gray()], ids=["rgb", "gray"])
def test_output_shape_dtype_all_on(frame: np.ndarray) -> None:
    out = augment_frame(frame, ALL_ON, np.random.default_rng(0))
    assert out.dtype == np.uint8
    assert out.shape == (H, W)


def test_rejects_bad_frame() -> None:
    with pytest.raises(ValueError):
        augment_frame(np.zeros((H, W, 3), np.float32), AugmentationConfig(), np.random.default_rng(0))
    with pytest.raises(ValueError):
        augment_frame(np.zeros((H, W, 4), np.uint8), AugmentationConfig(), np.random.default_rng(0))


@pytest.mark.parametrize("max_px", [1, 10, 25])
def test_translation_shifts_stripe(max_px: int) -> None:
    cfg = AugmentationConfig(translate_prob=1, translate_max_px=max_px)
    frame = stripe_frame(80)
    shifts = set()
    for seed in range(50):
        out = augment_frame(frame, cfg, np.random.default_rng(seed))
        shift = stripe_col(out) - 80
        assert 0 < abs(shift) <= max_px
        # Every column is either the shifted stripe or the replicated dark border: no other values.
        assert set(np.unique(out)) <= {40, 230}
        shifts.add(shift)
    assert any(s < 0 for s in shifts) and any(s > 0 for s in shifts)


def test_translation_replicates_border_column() -> None:
    cfg = AugmentationConfig(translate_prob=1, translate_max_px=10)
    frame = gradient_gray()
    for seed in range(20):
        out = augment_frame(frame, cfg, np.random.default_rng(seed))
        # Find the shift that maps the frame onto the output, then check the exposed edge.
        matches = [
            dx
            for dx in range(-10, 11)
            if dx and np.array_equal(out[:, max(dx, 0) : W + min(dx, 0)], frame[:, max(-dx, 0) : W - max(dx, 0)])
        ]
        assert len(matches) == 1
        dx = matches[0]
        edge = out[:, :dx] if dx > 0 else out[:, dx:]
        border = frame[:, :1] if dx > 0 else frame[:, -1:]
        np.testing.assert_array_equal(edge, np.broadcast_to(border, edge.shape))


def test_shadow_darkens_never_brightens() -> None:
    cfg = AugmentationConfig(shadow_prob=1, shadow_darkness=0.8)
    frame = gradient_gray()
    darkened = 0
    for seed in range(30):
        out = augment_frame(frame, cfg, np.random.default_rng(seed))
        assert (out <= frame).all()
        darkened += (out < frame).any()
    assert darkened >= 25  # only a near-zero factor or a degenerate polygon may leave it unchanged


def test_shadow_is_a_region_spanning_top_to_bottom() -> None:
    cfg = AugmentationConfig(shadow_prob=1, shadow_darkness=1.0)
    frame = np.full((H, W), 250, np.uint8)
    for seed in range(30):
        out = augment_frame(frame, cfg, np.random.default_rng(seed))
        dark = out < 250
        if dark.sum() < 100:
            continue  # thin polygon or factor near 1
        assert dark[0].any() and dark[-1].any()
        # Inside the shadow the factor is uniform, so all darkened pixels share one value.
        assert len(np.unique(out[dark])) == 1


def test_sharpening_steepens_an_edge_and_leaves_flat_areas_alone() -> None:
    frame = np.full((H, W), 80, np.uint8)
    frame[:, W // 2 :] = 160
    out = augment_frame(frame, AugmentationConfig(sharpen_prob=1, sharpen_max=2.0), np.random.default_rng(1))
    assert out[:, 10].tolist() == frame[:, 10].tolist() and out[:, -10].tolist() == frame[:, -10].tolist()
    # An unsharp mask overshoots on both sides of the edge: darker just left of it, brighter just right.
    assert out[5, W // 2 - 1] < 80 and out[5, W // 2] > 160
    off = augment_frame(frame, AugmentationConfig(sharpen_prob=1, sharpen_max=0.0), np.random.default_rng(1))
    np.testing.assert_array_equal(off, frame)


@pytest.mark.parametrize("amount", [0.02, 0.1, 0.3, 0.5])
def test_salt_pepper_fraction(amount: float) -> None:
    cfg = AugmentationConfig(salt_pepper_prob=1, salt_pepper_amount=amount)
    frame = np.full((H, W), 128, np.uint8)
    out = augment_frame(frame, cfg, np.random.default_rng(0))
    noisy = out != 128
    assert noisy.mean() == pytest.approx(amount, rel=0.1)
    assert set(np.unique(out[noisy])) == {0, 255}
    assert 0.35 < (out[noisy] == 255).mean() < 0.65


def test_color_jitter_changes_rgb_output() -> None:
    cfg = AugmentationConfig(color_prob=1)
    frame = colorful_rgb()
    base = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    changed = [not np.array_equal(augment_frame(frame, cfg, np.random.default_rng(s)), base) for s in range(10)]
    assert all(changed)


def test_hue_shift_alone_changes_colorful_frame() -> None:
    cfg = AugmentationConfig(color_prob=1, hue_max_deg=90, saturation_max=0, brightness_max=0, contrast_max=0)
    frame = colorful_rgb()
    base = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    diffs = [np.abs(augment_frame(frame, cfg, np.random.default_rng(s)).astype(int) - base).mean() for s in range(10)]
    assert sum(d > 5 for d in diffs) >= 8


def test_zero_strength_color_jitter_is_exact_gray() -> None:
    # With every strength at 0 the jitter is a no-op: the lossy 8-bit HSV round trip must be skipped.
    cfg = AugmentationConfig(color_prob=1, hue_max_deg=0, saturation_max=0, brightness_max=0, contrast_max=0)
    frame = colorful_rgb()
    out = augment_frame(frame, cfg, np.random.default_rng(0))
    np.testing.assert_array_equal(out, cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY))


def test_color_jitter_on_gray_is_brightness_contrast_only() -> None:
    frame = gradient_gray()
    only_hue = AugmentationConfig(color_prob=1, hue_max_deg=90, saturation_max=1, brightness_max=0, contrast_max=0)
    np.testing.assert_array_equal(augment_frame(frame, only_hue, np.random.default_rng(0)), frame)
    bright = AugmentationConfig(color_prob=1, brightness_max=0.5, contrast_max=0.5)
    diffs = [augment_frame(frame, bright, np.random.default_rng(s)) for s in range(5)]
    assert any(not np.array_equal(d, frame) for d in diffs)


@pytest.mark.parametrize(
    "cfg",
    [
        AugmentationConfig(color_prob=0.5),
        AugmentationConfig(translate_prob=0.5),
        AugmentationConfig(shadow_prob=0.5, shadow_darkness=1.0),
        AugmentationConfig(salt_pepper_prob=0.5),
    ],
    ids=["color", "translate", "shadow", "salt_pepper"],
)
def test_probability_half_applies_about_half(cfg: AugmentationConfig) -> None:
    frame = colorful_rgb()
    base = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    rng = np.random.default_rng(123)
    applied = sum(not np.array_equal(augment_frame(frame, cfg, rng), base) for _ in range(400))
    # Binomial(400, 0.5): sd 10; a rare no-op draw (e.g. a tiny shadow) only lowers the count a bit.
    assert 150 <= applied <= 250


@pytest.mark.parametrize("frame", [colorful_rgb(), gradient_gray()], ids=["rgb", "gray"])
def test_same_seed_same_output(frame: np.ndarray) -> None:
    a = [augment_frame(frame, ALL_ON, rng) for rng in [np.random.default_rng(5)] for _ in range(5)]
    b = [augment_frame(frame, ALL_ON, rng) for rng in [np.random.default_rng(5)] for _ in range(5)]
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("frame", [colorful_rgb(), gradient_gray()], ids=["rgb", "gray"])
def test_different_seeds_differ(frame: np.ndarray) -> None:
    a = augment_frame(frame, ALL_ON, np.random.default_rng(1))
    b = augment_frame(frame, ALL_ON, np.random.default_rng(2))
    assert not np.array_equal(a, b)


@pytest.mark.parametrize("frame", [colorful_rgb(), gradient_gray()], ids=["rgb", "gray"])
@pytest.mark.parametrize("cfg", [AugmentationConfig(), ALL_ON], ids=["off", "on"])
def test_input_not_modified(frame: np.ndarray, cfg: AugmentationConfig) -> None:
    before = frame.copy()
    for seed in range(10):
        out = augment_frame(frame, cfg, np.random.default_rng(seed))
        assert not np.shares_memory(out, frame)
    np.testing.assert_array_equal(frame, before)
