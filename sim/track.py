"""DeepRacer tracks: loading, validation and the geometry the task needs.

A track file is a DeepRacer ``.npy`` waypoint array of shape (N, 6):
``center_x, center_y, inner_x, inner_y, outer_x, outer_y`` in metres, where "inner" is the
border inside the loop. A loop repeats its first row exactly as its last; an open track
(Straight_track) does not.

A route is read as DeepRacer's simapp reads it (``bundle/markov/track_geom/track_data.py``,
``TrackData.__init__`` and ``_sanitize_waypoints``, at :data:`sim.routes.SIMAPP_COMMIT`): a bad shape or a
non-finite value is an error naming the row and column; it is a loop when its first and last rows are equal in
every column; zero-length centre-line steps (1e-9 m or shorter) are dropped, a loop's closing row kept. The result is
``Track.waypoints``, which is also the reward function's ``waypoints``.

A track is named by a path to an ``.npy`` file, one of racer's own tracks (:mod:`sim.track_gen`, generated, always
there), or a DeepRacer track name found in the track folder (:func:`sim.routes.tracks_dir`, filled by
``racer tracks pull``).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from common.errors import UserError, did_you_mean
from sim.routes import cached_route_names, deepracer_route_names, pull_command, route_checksums, tracks_dir
from sim.track_gen import DEFAULT_TRACK, is_racer_track, racer_track_array, racer_track_names

__all__ = ["DEFAULT_TRACK", "Track", "TrackError", "known_track_names", "load_track", "track_source"]

MIN_WAYPOINTS = 5
SANITIZE_EPS_M = 1e-9
"""The simapp's ``_sanitize_waypoints`` eps: a centre-line step this short or shorter is dropped."""
_NEAR_CLOSED_M = 0.01
log = logging.getLogger("racer.track")


class TrackError(UserError, ValueError):
    """A track file that cannot be used; the message names the file and what is wrong."""


def known_track_names() -> list[str]:
    """Every track name racer can resolve: its own, the cached DeepRacer tracks and the ones that can be pulled."""
    return sorted(set(racer_track_names()) | set(cached_route_names()) | set(deepracer_route_names()))


def track_source(track: str | Path) -> Path | str:
    """Where a track name leads: a racer track's name (a str), or the path of its ``.npy`` file.

    Raises TrackError for a missing file, a DeepRacer track not yet pulled (giving the pull command) or an
    unknown name (with the closest known names)."""
    text = str(track)
    if isinstance(track, str) and is_racer_track(text):
        return text
    path = Path(track)
    if path.suffix == ".npy" or path.exists():
        if not path.is_file():
            raise TrackError(f"track file {text!r} does not exist")
        return path
    cached = tracks_dir() / f"{text}.npy"
    if cached.is_file():
        return cached
    if text in route_checksums():
        raise TrackError(
            f"DeepRacer track {text!r} is not in the track folder {str(tracks_dir())!r}: get it with "
            f"`{pull_command(text)}` (or set RACER_TRACKS_DIR to a folder of DeepRacer .npy routes)"
        )
    guess = did_you_mean(text, known_track_names())
    raise TrackError(
        f"unknown track {text!r}: {guess + ' Or give' if guess else 'give'} a .npy path, one of racer's tracks "
        f"({', '.join(racer_track_names())}) or a DeepRacer track name (`racer tracks ls` lists them)"
    )


def load_track(track: str | Path) -> Track:
    """Load and validate a track: racer's by name, a DeepRacer track by name from the track folder, or a path."""
    source = track_source(track)
    if isinstance(source, str):
        return Track.from_array(racer_track_array(source), name=source, source=f"racer:{source}")
    try:
        raw = np.load(source, allow_pickle=False)
    except Exception as exc:  # numpy raises several types for unreadable files
        raise TrackError(f"track file {str(source)!r} is not a readable .npy array: {exc}") from None
    return Track.from_array(raw, name=source.stem, source=str(source))


def sanitize_waypoints(raw: np.ndarray, source: str) -> np.ndarray:
    """The simapp's ``TrackData._sanitize_waypoints``: the route as DeepRacer uses it, or a TrackError.

    Follows bundle/markov/track_geom/track_data.py at :data:`sim.routes.SIMAPP_COMMIT` step by step: the shape
    (2-D, at least 2 rows and 6 columns), finiteness of the first six columns (the first bad row and column named),
    a loop when the first and last rows are equal in every column, zero-length centre-line steps dropped (a loop's
    closing row always kept). Columns past the sixth are kept, as the simapp keeps them (only its loop test reads
    them)."""
    if raw.dtype.kind not in "fiu":
        raise TrackError(f"track file {source!r}: expected numbers, got dtype {raw.dtype}")
    if raw.ndim != 2 or raw.shape[0] < 2 or raw.shape[1] < 6:
        raise TrackError(f"track file {source!r}: expected shape (N, 6), got {raw.shape}")
    waypoints = raw.astype(np.float64)
    core = waypoints[:, :6]
    if not np.isfinite(core).all():
        row, col = (int(v) for v in np.argwhere(~np.isfinite(core))[0])
        raise TrackError(f"track file {source!r}: non-finite value {core[row, col]} at row {row}, column {col}")
    is_loop = bool(np.all(waypoints[0, :] == waypoints[-1, :]))
    center = waypoints[:, 0:2]
    if is_loop and len(waypoints) > 2:
        core_center = center[:-1]
        keep = np.ones(len(core_center), dtype=bool)
        keep[1:] = np.linalg.norm(np.diff(core_center, axis=0), axis=1) > SANITIZE_EPS_M
        sanitized = np.vstack((waypoints[:-1][keep], waypoints[-1:]))
    else:
        keep = np.ones(len(center), dtype=bool)
        keep[1:] = np.linalg.norm(np.diff(center, axis=0), axis=1) > SANITIZE_EPS_M
        sanitized = waypoints[keep]
    if len(sanitized) < 2:
        raise TrackError(f"track file {source!r}: the route is degenerate once zero-length steps are dropped")
    return sanitized


def _segments_cross(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Pairwise proper-crossing test between segments a (M,2) and b (K,2); returns (M, K) bool."""

    def orient(p, q, r):
        return (q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1]) - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0])

    A0, A1 = a0[:, None, :], a1[:, None, :]
    B0, B1 = b0[None, :, :], b1[None, :, :]
    d1, d2 = orient(B0, B1, A0), orient(B0, B1, A1)
    d3, d4 = orient(A0, A1, B0), orient(A0, A1, B1)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


def _self_crossings(poly: np.ndarray) -> list[tuple[int, int]]:
    """Pairs (i, j), i < j, of non-adjacent segments of a polyline that cross each other."""
    a0, a1 = poly[:-1], poly[1:]
    cross = _segments_cross(a0, a1, a0, a1)
    m = len(a0)
    idx = np.arange(m)
    near = np.abs(idx[:, None] - idx[None, :]) <= 1
    near |= (idx[:, None] == 0) & (idx[None, :] == m - 1)
    near |= (idx[:, None] == m - 1) & (idx[None, :] == 0)
    return [(int(i), int(j)) for i, j in np.argwhere(np.triu(cross & ~near))]


def _crossing_point(poly: np.ndarray, i: int, j: int) -> tuple[float, float]:
    """Where segment i and segment j of a polyline cross."""
    p, r = poly[i], poly[i + 1] - poly[i]
    q, s = poly[j], poly[j + 1] - poly[j]
    t = ((q[0] - p[0]) * s[1] - (q[1] - p[1]) * s[0]) / (r[0] * s[1] - r[1] * s[0])
    # Rounded, then + 0.0, so a message never shows "-0.000".
    return round(float(p[0] + t * r[0]), 3) + 0.0, round(float(p[1] + t * r[1]), 3) + 0.0


def _signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _validate(raw: np.ndarray, source: str) -> tuple[np.ndarray, bool]:
    """Sanitize as the simapp does, then check what racer needs on top: enough waypoints, a usable width; warn
    about crossing borders and a loop that is closed only nearly (the simapp reads that as an open line).
    Returns the six route columns and whether the route is a loop (the simapp's test, on every column)."""
    sanitized = sanitize_waypoints(raw, source)
    closed = bool(np.all(sanitized[0] == sanitized[-1]))
    arr = np.ascontiguousarray(sanitized[:, :6])
    if len(arr) < MIN_WAYPOINTS:
        raise TrackError(f"track file {source!r}: {len(arr)} distinct waypoints, need at least {MIN_WAYPOINTS}")
    gap = float(np.linalg.norm(arr[0, :2] - arr[-1, :2]))
    if not closed and gap < _NEAR_CLOSED_M:
        log.warning(
            "track file %r: the first and last rows are %.2g m apart but not equal; DeepRacer reads it as an open "
            "line with no lap, and so does racer (repeat the first row exactly as the last to make it a loop)",
            source,
            gap,
        )
    width = np.linalg.norm(arr[:, 2:4] - arr[:, 4:6], axis=1)
    if np.any(width < 0.05):
        bad = int(np.argmin(width))
        raise TrackError(f"track file {source!r}: track width {width[bad]:.3f} m at row {bad} is too narrow")
    # DeepRacer loads a track whose borders cross (the simapp builds shapely geometry and never checks it), so racer
    # loads it too, and says where the crossing is. None of the 127 routes at SIMAPP_COMMIT has such a crossing.
    for col, label in ((2, "inner"), (4, "outer")):
        border = arr[:, col : col + 2]
        pairs = _self_crossings(border)
        if pairs:
            where = ", ".join(
                f"segments {i}-{i + 1} and {j}-{j + 1} at ({x:.3f}, {y:.3f})"
                for (i, j), (x, y) in ((pair, _crossing_point(border, *pair)) for pair in pairs[:3])
            )
            more = f" and {len(pairs) - 3} more" if len(pairs) > 3 else ""
            log.warning(
                "track file %r: the %s border crosses itself (%s%s); loaded as DeepRacer loads it, but the "
                "on-track test is unreliable near the crossing",
                source,
                label,
                where,
                more,
            )
    n = int(_segments_cross(arr[:-1, 2:4], arr[1:, 2:4], arr[:-1, 4:6], arr[1:, 4:6]).sum())
    if n:
        log.warning(
            "track file %r: the inner and outer borders cross (%d crossings); loaded as DeepRacer does", source, n
        )  # noqa: E501
    return arr, closed


@dataclass(frozen=True)
class Projection:
    """Where points lie relative to the centre line (arrays, one entry per point)."""

    s: np.ndarray
    """Arc length along the centre line from waypoint 0, metres."""
    lateral: np.ndarray
    """Signed distance from the centre line, metres; positive = left of the direction of travel."""
    segment: np.ndarray
    """Index of the closest centre-line segment (between waypoints i and i+1)."""
    t: np.ndarray
    """Fraction along that segment, 0..1."""


@dataclass(frozen=True, eq=False)
class Track:
    """A validated DeepRacer track. Geometry is in metres in the track's own frame."""

    name: str
    waypoints: np.ndarray = field(repr=False)
    """(N, 6) float64, the route as DeepRacer uses it (:func:`sanitize_waypoints`): center, inner, outer; a loop's
    last row equals its first. The reward function's ``waypoints`` are its centre column."""
    closed: bool
    source: str = ""

    @classmethod
    def from_array(cls, raw: np.ndarray, name: str = "track", source: str = "<array>") -> Track:
        """Validate a DeepRacer waypoint array and build a Track from it."""
        arr, closed = _validate(np.asarray(raw), source)
        return cls(name=name, waypoints=arr, closed=closed, source=source)

    def reversed(self) -> Track:
        """The same track driven the other way round (inner stays the border inside the loop)."""
        return Track(self.name, self.waypoints[::-1].copy(), self.closed, self.source)

    @property
    def center(self) -> np.ndarray:
        """(N, 2) centre-line waypoints."""
        return self.waypoints[:, 0:2]

    @property
    def inner(self) -> np.ndarray:
        """(N, 2) border inside the loop."""
        return self.waypoints[:, 2:4]

    @property
    def outer(self) -> np.ndarray:
        """(N, 2) border outside the loop."""
        return self.waypoints[:, 4:6]

    @cached_property
    def _seg(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        start = self.center[:-1]
        vec = np.diff(self.center, axis=0)
        length = np.linalg.norm(vec, axis=1)
        return start, vec, length

    @cached_property
    def cumulative(self) -> np.ndarray:
        """(N,) arc length of each waypoint from waypoint 0, metres."""
        return np.concatenate([[0.0], np.cumsum(self._seg[2])])

    @property
    def length(self) -> float:
        """Length of the centre line, metres (a full lap for a closed track)."""
        return float(self.cumulative[-1])

    @cached_property
    def widths(self) -> np.ndarray:
        """(N,) distance between the borders at each waypoint, metres."""
        return np.linalg.norm(self.outer - self.inner, axis=1)

    @property
    def width(self) -> float:
        """Median track width, metres."""
        return float(np.median(self.widths))

    @property
    def clockwise(self) -> bool:
        """True if a closed track runs clockwise in the file's order."""
        return self.closed and _signed_area(self.center) < 0

    def project(self, points: np.ndarray, hint: int | None = None, window: int = 8) -> Projection:
        """Project (K, 2) points onto the centre line.

        With ``hint`` (a segment index near the answer, e.g. last step's) only segments within ``window``
        of it are searched, which is several times faster per step; the full search runs if that finds
        nothing closer than a track width.
        """
        pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
        n_seg = len(self._seg[2])
        if hint is None or 2 * window + 1 >= n_seg:
            return self._project(pts, np.arange(n_seg))
        idx = np.arange(hint - window, hint + window + 1)
        idx = idx % n_seg if self.closed else idx[(idx >= 0) & (idx < n_seg)]
        proj = self._project(pts, idx)
        if np.all(np.abs(proj.lateral) < self.widths.max()):
            return proj
        return self._project(pts, np.arange(n_seg))

    @cached_property
    def _segment_list(self) -> list[Segment]:
        return polyline_segments(self.center)

    def project_point(self, x: float, y: float, hint: int, window: int = 8) -> Projection:
        """``project`` for one point near segment ``hint``: the per-step fast path.

        Plain Python over the ~17 segments of the window: for one point that is several times faster
        than numpy, whose per-call overhead dominates on arrays this small.
        """
        segs = self._segment_list
        if 2 * window + 1 >= len(segs):
            return self.project(np.array([[x, y]]))
        best, best_t, best_d2, best_cross = nearest_segment(segs, x, y, hint, window=window, closed=self.closed)
        lateral = math.copysign(math.sqrt(best_d2), best_cross) if best_cross != 0 else 0.0
        if abs(lateral) >= self.widths.max():  # lost (e.g. a jump): search everything
            return self.project(np.array([[x, y]]))
        s = float(self.cumulative[best]) + best_t * self._seg[2][best]
        return Projection(s=np.array([s]), lateral=np.array([lateral]), segment=np.array([best]), t=np.array([best_t]))

    def _project(self, pts: np.ndarray, segments: np.ndarray) -> Projection:
        start, vec, length = (a[segments] for a in self._seg)
        rel = pts[:, None, :] - start[None, :, :]
        t = np.clip(np.einsum("kmi,mi->km", rel, vec) / np.maximum(length**2, 1e-300), 0.0, 1.0)
        foot = start[None] + t[..., None] * vec[None]
        dist2 = np.sum((pts[:, None, :] - foot) ** 2, axis=2)
        best = np.argmin(dist2, axis=1)
        k = np.arange(len(pts))
        tk = t[k, best]
        seg = segments[best]
        cross = vec[best, 0] * rel[k, best, 1] - vec[best, 1] * rel[k, best, 0]
        lateral = np.sign(cross) * np.sqrt(dist2[k, best])
        s = self.cumulative[seg] + tk * self._seg[2][seg]
        return Projection(s=s, lateral=lateral, segment=seg, t=tk)

    def width_at(self, proj: Projection) -> np.ndarray:
        """Track width at projected points, interpolated between waypoints."""
        w = self.widths
        return (1 - proj.t) * w[proj.segment] + proj.t * w[proj.segment + 1]

    def point_at(self, s: float) -> tuple[np.ndarray, float]:
        """Centre-line point and heading (radians) at arc length s (wrapped on closed tracks)."""
        if self.closed:
            s = s % self.length
        s = float(np.clip(s, 0.0, self.length))
        start, vec, length = self._seg
        seg = int(np.clip(np.searchsorted(self.cumulative, s, side="right") - 1, 0, len(length) - 1))
        t = (s - self.cumulative[seg]) / length[seg] if length[seg] > 0 else 0.0
        return start[seg] + t * vec[seg], float(np.arctan2(vec[seg, 1], vec[seg, 0]))

    @cached_property
    def road_polygons(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(outline, hole): the road is inside ``outline`` and outside ``hole`` (None for open tracks)."""
        if self.closed:
            return self.outer[:-1].copy(), self.inner[:-1].copy()
        return np.concatenate([self.inner, self.outer[::-1]]), None

    def on_track(self, points: np.ndarray) -> np.ndarray:
        """(K,) bool: which points lie on the road surface (border lines count as road)."""
        outline, hole = self.road_polygons
        pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
        inside = _points_in_polygon(pts, outline)
        on_line = _near_polyline(pts, outline, closed=True)
        if hole is not None:
            inside &= ~_points_in_polygon(pts, hole)
            on_line |= _near_polyline(pts, hole, closed=True)
        return inside | on_line

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min_xy, max_xy) of everything drawn for the track, metres."""
        xy = self.waypoints.reshape(-1, 2)
        return xy.min(axis=0), xy.max(axis=0)


Segment = tuple[float, float, float, float, float]
"""A polyline segment as plain floats: start x, start y, vector x, vector y, 1 / squared length (0 if empty)."""


def polyline_segments(poly: np.ndarray) -> list[Segment]:
    """The segments of an (N, 2) polyline as plain floats, for per-step searches that numpy's overhead would slow."""
    start, vec = poly[:-1], np.diff(poly, axis=0)
    length2 = np.einsum("ij,ij->i", vec, vec)
    inv = np.divide(1.0, length2, out=np.zeros_like(length2), where=length2 > 0)
    return [tuple(row) for row in np.column_stack([start, vec, inv]).tolist()]


def nearest_segment(
    segments: list[Segment], x: float, y: float, hint: int, *, window: int, closed: bool
) -> tuple[int, float, float, float]:
    """Among the segments within ``window`` of ``hint`` (all of them when the window covers the polyline), the one
    nearest (x, y): (its index, the fraction t along it of the nearest point, the squared distance, and the cross
    product of the segment with the point, positive to its left)."""
    n_seg = len(segments)
    indices = range(n_seg) if 2 * window + 1 >= n_seg else range(hint - window, hint + window + 1)
    best, best_d2, best_t, best_cross = -1, math.inf, 0.0, 0.0
    for j in indices:
        if closed:
            j %= n_seg
        elif not 0 <= j < n_seg:
            continue
        sx, sy, vx, vy, inv2 = segments[j]
        rx, ry = x - sx, y - sy
        t = min(max((rx * vx + ry * vy) * inv2, 0.0), 1.0)
        dx, dy = rx - t * vx, ry - t * vy
        d2 = dx * dx + dy * dy
        if d2 < best_d2:
            best, best_d2, best_t, best_cross = j, d2, t, vx * ry - vy * rx
    return best, best_t, best_d2, best_cross


def _near_polyline(pts: np.ndarray, poly: np.ndarray, closed: bool, tol: float = 1e-9) -> np.ndarray:
    """(K,) bool: points within ``tol`` metres of the polyline (the even-odd test is ambiguous there)."""
    a = poly
    b = np.roll(poly, -1, axis=0) if closed else poly[1:]
    a = a if closed else poly[:-1]
    ab = b - a
    rel = pts[:, None, :] - a[None]
    t = np.clip(np.einsum("kmi,mi->km", rel, ab) / np.maximum(np.sum(ab**2, axis=1), 1e-18), 0.0, 1.0)
    d2 = np.sum((rel - t[..., None] * ab[None]) ** 2, axis=2)
    return d2.min(axis=1) <= tol * tol


def _points_in_polygon(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule point-in-polygon test, vectorized over points and edges."""
    x0, y0 = poly[:, 0], poly[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    px, py = pts[:, 0:1], pts[:, 1:2]
    straddle = (y0 > py) != (y1 > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xcross = x0 + (py - y0) * (x1 - x0) / (y1 - y0)
    return np.sum(straddle & (px < xcross), axis=1) % 2 == 1
