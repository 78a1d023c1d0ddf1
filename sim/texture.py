"""The track surface as DeepRacer tracks look: dark road, white borders, dashed centre line.

The surface is drawn once into an image (a "texture") in the track's own metric frame; both
camera paths sample it: the fast ground-projection camera directly, MuJoCo's renderer as the
material of the ground plane. Colours and noise can be randomized per episode.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sim.track import Track

BORDER_LINE_M = 0.05
"""Width of the white border lines, metres (about 2 inches, as on DeepRacer tracks)."""
CENTER_LINE_M = 0.03
"""Width of the dashed centre line, metres."""
DASH_M = 0.15
"""Length of a centre-line dash and of the gap after it, metres."""
MARGIN_M = 1.5
"""Background drawn around the track, metres; beyond it the camera sees the background colour."""
MAX_TEXTURE_PX = 8192
"""Largest texture side, pixels (GPU texture limits); big tracks get a coarser resolution."""
MAX_TEXTURE_AREA_PX = 6_000_000
"""Largest texture area, pixels: bounds memory and per-episode recolouring time on big tracks."""
_SHIFT = 4  # cv2 sub-pixel bits: draw at 1/16-pixel precision so thin lines stay straight


@dataclass(frozen=True)
class Palette:
    """Surface colours, RGB uint8 triples."""

    road: tuple[int, int, int] = (48, 48, 52)
    border: tuple[int, int, int] = (235, 235, 235)
    center: tuple[int, int, int] = (235, 200, 40)
    background: tuple[int, int, int] = (62, 110, 66)
    sky: tuple[int, int, int] = (150, 170, 200)


DEEPRACER_PALETTE = Palette()


def random_palette(rng: np.random.Generator, strength: float) -> Palette:
    """A palette moved from DeepRacer's colours towards a random one by ``strength`` (0..1)."""
    base = DEEPRACER_PALETTE

    def mix(colour: tuple[int, int, int], lo: int, hi: int) -> tuple[int, int, int]:
        target = rng.integers(lo, hi + 1, size=3)
        out = (1 - strength) * np.asarray(colour) + strength * target
        return tuple(int(v) for v in np.clip(out, 0, 255))

    return Palette(
        road=mix(base.road, 10, 110),
        border=mix(base.border, 170, 255),
        center=mix(base.center, 140, 255),
        background=mix(base.background, 0, 255),
        sky=mix(base.sky, 60, 255),
    )


@dataclass(frozen=True)
class TextureFrame:
    """Maps track metres to texture pixels: ``u = (x - x0) * ppm``, ``v = (y1 - y) * ppm``."""

    x0: float
    y1: float
    ppm: float
    width: int
    height: int

    @classmethod
    def for_track(cls, track: Track, ppm: float = 200.0) -> TextureFrame:
        """Frame covering the track plus a margin, at up to ``ppm`` pixels per metre."""
        lo, hi = track.bounds
        lo, hi = lo - MARGIN_M, hi + MARGIN_M
        span = hi - lo
        ppm = min(ppm, MAX_TEXTURE_PX / float(np.max(span)), float(np.sqrt(MAX_TEXTURE_AREA_PX / np.prod(span))))
        w, h = (int(np.ceil(v)) for v in (hi - lo) * ppm)
        return cls(x0=float(lo[0]), y1=float(hi[1]), ppm=ppm, width=w, height=h)

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """(K, 2) metres → (K, 2) float pixel coordinates (u right, v down)."""
        xy = np.asarray(xy, dtype=np.float64)
        return np.stack([(xy[..., 0] - self.x0) * self.ppm, (self.y1 - xy[..., 1]) * self.ppm], axis=-1)

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the textured area, metres."""
        return self.width / self.ppm, self.height / self.ppm

    @property
    def center_m(self) -> tuple[float, float]:
        """Centre of the textured area in track coordinates, metres."""
        w, h = self.size_m
        return self.x0 + w / 2, self.y1 - h / 2


def _fixed(frame: TextureFrame, xy: np.ndarray) -> np.ndarray:
    return np.round(frame.to_pixels(xy) * (1 << _SHIFT)).astype(np.int32)


def _dashes(track: Track, dash: float) -> list[np.ndarray]:
    """Centre-line polylines of the dashes, each as (6, 2) metres."""
    starts = np.arange(0.0, track.length - dash * 0.5, 2 * dash)
    s = np.minimum(starts[:, None] + np.linspace(0.0, dash, 6)[None, :], track.length)
    x = np.interp(s, track.cumulative, track.center[:, 0])
    y = np.interp(s, track.cumulative, track.center[:, 1])
    return list(np.stack([x, y], axis=-1))


def draw_layers(track: Track, frame: TextureFrame) -> np.ndarray:
    """Draw the track once as coverage weights: (H, W, 4) uint8 of background, road, border, centre line.

    Each pixel's weights sum to 255 (anti-aliased edges are mixtures), so any palette can be applied
    later by one matrix product (``colorize``) instead of redrawing: that keeps per-episode colour
    randomization cheap.
    """
    one_hot = [(255, 0, 0, 0), (0, 255, 0, 0), (0, 0, 255, 0), (0, 0, 0, 255)]
    img = np.zeros((frame.height, frame.width, 4), np.uint8)
    img[:] = one_hot[0]
    outline, hole = track.road_polygons
    cv2.fillPoly(img, [_fixed(frame, outline)], one_hot[1], cv2.LINE_AA, _SHIFT)
    if hole is not None:
        cv2.fillPoly(img, [_fixed(frame, hole)], one_hot[0], cv2.LINE_AA, _SHIFT)
    px = lambda metres: max(1, int(round(metres * frame.ppm)))  # noqa: E731
    borders = [_fixed(frame, b) for b in (track.inner, track.outer)]
    cv2.polylines(img, borders, track.closed, one_hot[2], px(BORDER_LINE_M), cv2.LINE_AA, _SHIFT)
    dashes = [_fixed(frame, d) for d in _dashes(track, DASH_M)]
    cv2.polylines(img, dashes, False, one_hot[3], px(CENTER_LINE_M), cv2.LINE_AA, _SHIFT)
    return img


def colorize(layers: np.ndarray, palette: Palette = DEEPRACER_PALETTE) -> np.ndarray:
    """Apply a palette to coverage weights from ``draw_layers``: (H, W, 3) RGB uint8."""
    colours = np.array([palette.background, palette.road, palette.border, palette.center], np.float32)
    return cv2.transform(layers, colours.T / 255.0)


def draw_surface(track: Track, frame: TextureFrame, palette: Palette = DEEPRACER_PALETTE) -> np.ndarray:
    """Draw the track into an RGB uint8 image of ``frame``'s size."""
    return colorize(draw_layers(track, frame), palette)


def add_noise_texture(img: np.ndarray, strength: float, rng: np.random.Generator) -> np.ndarray:
    """Multiply the image by smooth random blotches (grain of ~10 cm) of relative amplitude ``strength``."""
    h, w = img.shape[:2]
    coarse = rng.uniform(1 - strength, 1 + strength, size=(max(2, h // 20), max(2, w // 20))).astype(np.float32)
    gain = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
    out = img.astype(np.float32) * (gain[..., None] if img.ndim == 3 else gain)
    return np.clip(out, 0, 255).astype(np.uint8)


class RoadMask:
    """Is a point on the road? A raster of the road polygon at the texture's resolution (5 mm by default).

    The exact polygon test (``Track.on_track``) costs ~100 µs per step for four wheels; a lookup in this
    raster costs a few µs and differs only within half a texel of the border.
    """

    def __init__(self, track: Track, frame: TextureFrame) -> None:
        self.frame = frame
        mask = np.zeros((frame.height, frame.width), np.uint8)
        outline, hole = track.road_polygons
        cv2.fillPoly(mask, [_fixed(frame, outline)], 1, cv2.LINE_8, _SHIFT)
        if hole is not None:
            cv2.fillPoly(mask, [_fixed(frame, hole)], 0, cv2.LINE_8, _SHIFT)
        self.mask = mask.astype(bool)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """(K,) bool for (K, 2) points in metres; points outside the textured area are off the road."""
        f, mask = self.frame, self.mask
        out = np.zeros(len(points), bool)
        # A plain loop: for the four wheels it is several times faster than numpy's fancy indexing.
        for i, (x, y) in enumerate(np.asarray(points).tolist()):
            u, v = int((x - f.x0) * f.ppm), int((f.y1 - y) * f.ppm)
            out[i] = 0 <= u < f.width and 0 <= v < f.height and bool(mask[v, u])
        return out
