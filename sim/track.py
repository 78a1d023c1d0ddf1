"""DeepRacer tracks: loading, validation and the geometry the task needs.

A track file is a DeepRacer ``.npy`` waypoint array of shape (N, 6):
``center_x, center_y, inner_x, inner_y, outer_x, outer_y`` in metres, where "inner" is the
border inside the loop. A closed loop repeats its first row as its last; an open track
(Straight_track) does not.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path

import numpy as np

from common.errors import UserError

MIN_WAYPOINTS = 5
_CLOSE_TOL_M = 1e-3
log = logging.getLogger("racer.track")


class TrackError(UserError, ValueError):
    """A track file that cannot be used; the message names the file and what is wrong."""


def bundled_track_names() -> list[str]:
    """Names of the DeepRacer tracks shipped with the package, sorted."""
    folder = resources.files("sim") / "tracks"
    return sorted(p.name[:-4] for p in folder.iterdir() if p.name.endswith(".npy"))


def resolve_track_path(track: str | Path) -> Path:
    """Map a bundled track name or a path to an ``.npy`` file to a path; raise TrackError if neither."""
    path = Path(track)
    if path.suffix == ".npy" or path.exists():
        if not path.is_file():
            raise TrackError(f"track file {str(track)!r} does not exist")
        return path
    bundled = resources.files("sim") / "tracks" / f"{track}.npy"
    if not bundled.is_file():
        names = ", ".join(bundled_track_names())
        raise TrackError(f"unknown track {str(track)!r}: give a .npy path or one of {names}")
    return Path(str(bundled))


def load_track(track: str | Path) -> Track:
    """Load and validate a bundled track by name or a DeepRacer ``.npy`` file by path."""
    path = resolve_track_path(track)
    try:
        raw = np.load(path, allow_pickle=False)
    except Exception as exc:  # numpy raises several types for unreadable files
        raise TrackError(f"track file {str(path)!r} is not a readable .npy array: {exc}") from None
    name = path.stem
    return Track.from_array(raw, name=name, source=str(path))


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


def _validate(raw: np.ndarray, source: str) -> np.ndarray:
    """Check shape, values and border geometry; return a float64 copy without repeated rows."""
    if raw.dtype.kind not in "fiu":
        raise TrackError(f"track file {source!r}: expected numbers, got dtype {raw.dtype}")
    if raw.ndim != 2 or raw.shape[1] != 6:
        raise TrackError(f"track file {source!r}: expected shape (N, 6), got {raw.shape}")
    arr = raw.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        bad = int(np.argwhere(~np.isfinite(arr))[0][0])
        raise TrackError(f"track file {source!r}: non-finite value (NaN or inf) in row {bad}")
    keep = np.ones(len(arr), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(arr[:, :2], axis=0), axis=1) > 1e-9
    arr = arr[keep]
    if len(arr) < MIN_WAYPOINTS:
        raise TrackError(f"track file {source!r}: {len(arr)} distinct waypoints, need at least {MIN_WAYPOINTS}")
    width = np.linalg.norm(arr[:, 2:4] - arr[:, 4:6], axis=1)
    if np.any(width < 0.05):
        bad = int(np.argmin(width))
        raise TrackError(f"track file {source!r}: track width {width[bad]:.3f} m at row {bad} is too narrow")
    # DeepRacer loads a track whose borders cross (the simapp builds shapely geometry and never checks it: the
    # 2019 reinvent_base.npy has a self-crossing border), so racer loads it too, and says where the crossing is.
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
    return arr


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
    """(N, 6) float64 as in the file: center, inner, outer."""
    closed: bool
    source: str = ""
    rows: np.ndarray | None = field(default=None, repr=False)
    """(M, 6) float64: the file's rows exactly, repeated rows included (the simapp keeps them, so the reward
    function's ``waypoints`` and ``closest_waypoints`` count them); None = the same as ``waypoints``."""

    @classmethod
    def from_array(cls, raw: np.ndarray, name: str = "track", source: str = "<array>") -> Track:
        """Validate a DeepRacer waypoint array and build a Track from it."""
        arr = _validate(np.asarray(raw), source)
        closed = bool(np.linalg.norm(arr[0, :2] - arr[-1, :2]) < _CLOSE_TOL_M)
        if closed:
            arr[-1] = arr[0]
        rows = np.asarray(raw, dtype=np.float64).copy()
        return cls(name=name, waypoints=arr, closed=closed, source=source, rows=rows)

    def reversed(self) -> Track:
        """The same track driven the other way round (inner stays the border inside the loop)."""
        return Track(self.name, self.waypoints[::-1].copy(), self.closed, self.source, self.file_rows[::-1].copy())

    @property
    def file_rows(self) -> np.ndarray:
        """(M, 6): the rows as the file has them (in this direction), repeated rows included."""
        return self.waypoints if self.rows is None else self.rows

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
        best, best_t, best_d2, best_cross = nearest_segment(segs, x, y, hint, window, self.closed)
        lateral = math.copysign(math.sqrt(best_d2), best_cross) if best_cross != 0 else 0.0
        if abs(lateral) >= self.widths.max():  # lost (e.g. a jump): search everything
            return self.project(np.array([[x, y]]))
        s = float(self.cumulative[best]) + best_t * self._seg[2][best]
        return Projection(s=np.array([s]), lateral=np.array([lateral]), segment=np.array([best]), t=np.array([best_t]))

    def _project(self, pts: np.ndarray, segments: np.ndarray) -> Projection:
        start, vec, length = (a[segments] for a in self._seg)
        rel = pts[:, None, :] - start[None, :, :]
        t = np.clip(np.einsum("kmi,mi->km", rel, vec) / (length**2), 0.0, 1.0)
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
        t = (s - self.cumulative[seg]) / length[seg]
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
    segments: list[Segment], x: float, y: float, hint: int, window: int, closed: bool
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
