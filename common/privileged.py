"""The privileged teacher's observation: the car's exact state relative to the track, from one step's ``params``.

Teacher–student training (learning by cheating) first trains a small MLP *teacher* on this vector, which it can read
without learning vision, then distils it into the camera *student*. The vector is built from DeepRacer's reward
``params`` alone (``sim/reward.py: PARAM_KEYS``; meanings and units in ``sim/task.py: RacingTask._params`` and
``sim/object_params.py``), so any producer of those params (racer's env, a log of a real DeepRacer run) can feed it.
Here, in ``common`` and free of torch and of the simulator, because rollout workers and the trainer both build it.

Layout of :func:`state_vector` (float32, :data:`STATE_SIZE` = 24); "car frame" is x forward, y left, at the car's
``(x, y)`` turned by its ``heading``; "ahead point L" is the centre-line point L metres further along the centre line
than the car's projection on it (wrapping over a loop's seam, clamped at an open track's end):

=====  ==============================================================  ======  =================================
index  meaning                                                         unit    scale (typical range)
=====  ==============================================================  ======  =================================
0      ``speed`` (the commanded speed)                                 m/s     / 4          ([0, 1])
1      ``steering_angle`` (positive = left)                            deg     / 30         ([-1, 1])
2      sin(heading error): ``heading`` minus the direction of the      --      none         ([-1, 1])
       centre-line segment ``closest_waypoints[0] → [1]``; positive
       when the car points left of the centre line's direction
3      cos(heading error)                                              --      none         ([-1, 1])
4      signed lateral offset: ``distance_from_center``, positive when  m       / (track_width / 2)
       ``is_left_of_center``                                                   ([-1, 1] on track)
5      half the track width: ``track_width / 2``                       m       none         (~0.3 to 0.6)
6, 7   ahead point 0.5 m: (forward, left) in the car frame             m       / 0.5        (~[-1, 1])
8, 9   ahead point 1.0 m                                               m       / 1.0
10, 11 ahead point 1.5 m                                               m       / 1.5
12, 13 ahead point 2.0 m                                               m       / 2.0
14, 15 ahead point 3.0 m                                               m       / 3.0
16, 17 ahead point 4.0 m                                               m       / 4.0
18     nearest object ahead: present (1) or not (0)                    --      none         ({0, 1})
19     its forward coordinate in the car frame                         m       / 5          ((0, 1]; absent 1)
20     its left coordinate in the car frame                            m       / 1          (~[-1, 1]; absent 0)
21-23  second-nearest object ahead: as 18-20                           as above
=====  ==============================================================  ======  =================================

"Objects ahead" are the entries of ``objects_location`` (obstacles and bot cars; empty or missing in a time trial)
with a positive forward coordinate in the car frame and within :data:`OBJECT_RANGE_M` metres of the car, nearest
first; an absent slot reads (0, 1, 0), i.e. "nothing, as far away as the teacher looks".
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

LOOKAHEAD_M: tuple[float, ...] = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
"""Distances (metres) ahead of the car's projection along the centre line at which the track's shape is sampled."""

OBJECT_SLOTS = 2
"""How many objects ahead the vector describes (the nearest ones)."""

OBJECT_RANGE_M = 5.0
"""Objects further than this (metres, straight-line from the car) are left out; also the forward coordinate's scale."""

SPEED_SCALE_MPS = 4.0
"""Divisor of ``speed`` (DeepRacer's top action speed is 4 m/s)."""

STEERING_SCALE_DEG = 30.0
"""Divisor of ``steering_angle`` (DeepRacer's steering range is ±30°)."""

STATE_SIZE: int = 6 + 2 * len(LOOKAHEAD_M) + 3 * OBJECT_SLOTS
"""Length of :func:`state_vector`'s vector (24)."""

_ABSENT_OBJECT = (0.0, 1.0, 0.0)
_MIN_HALF_WIDTH_M = 1e-3  # a degenerate track_width must not divide by zero (the vector must stay finite)


class _Line:
    """A centre line's per-track tables: rows, segment vectors, unit directions and cumulative arc length."""

    __slots__ = ("closed", "cum", "direction", "length", "points", "seg", "seg_len", "source")

    def __init__(self, waypoints: Sequence[Sequence[float]]) -> None:
        # Kept so the cache entry pins the list: while it lives, no other object can take its id() (see _line).
        self.source = waypoints
        points = np.asarray(waypoints, dtype=np.float64)[:, :2]
        if len(points) < 2:
            raise ValueError(f"waypoints need at least 2 rows, got {len(points)}")
        self.points = points
        # DeepRacer's waypoints of a loop end with a copy of the first row; an open track's do not.
        self.closed = bool(np.allclose(points[0], points[-1]))
        self.seg = np.diff(points, axis=0)
        self.seg_len = np.hypot(self.seg[:, 0], self.seg[:, 1])
        self.cum = np.concatenate([[0.0], np.cumsum(self.seg_len)])
        self.length = float(self.cum[-1])
        self.direction = _segment_directions(self.seg, self.seg_len, self.closed)


def _segment_directions(seg: np.ndarray, seg_len: np.ndarray, closed: bool) -> np.ndarray:
    """(n-1, 2) unit direction per segment; a zero-length segment (a repeated row) takes the next real segment's
    (wrapping on a loop; at an open track's end, the previous one's), so the heading error is always defined."""
    m = len(seg)
    real = np.flatnonzero(seg_len > 1e-12)
    if len(real) == 0:
        return np.tile([1.0, 0.0], (m, 1))  # all rows equal: any direction; +x keeps the vector finite
    unit = np.zeros_like(seg)
    unit[real] = seg[real] / seg_len[real, None]
    nxt = np.searchsorted(real, np.arange(m))  # index into real of the first real segment at or after k
    past_end = nxt == len(real)
    nxt[past_end] = 0 if closed else len(real) - 1
    return unit[real[nxt]]


# Per-track tables, keyed on the waypoints list's id() and length: the env passes the same list object every step
# (sim/task.py: _WaypointLine.waypoints), so building the tables (list -> array, ~tens of µs) happens once per track.
# The entry holds the list itself, so its id cannot be reused by another list while cached; an in-place edit that
# keeps the length would go unnoticed (nothing in racer edits the waypoints).
_CACHE: dict[tuple[int, int], _Line] = {}
_CACHE_MAX = 16


def _line(waypoints: Sequence[Sequence[float]]) -> _Line:
    key = (id(waypoints), len(waypoints))
    line = _CACHE.get(key)
    if line is None or line.source is not waypoints:
        if len(_CACHE) >= _CACHE_MAX:
            _CACHE.clear()  # a handful of tracks per process: dropping all is simpler than LRU and as good
        line = _CACHE[key] = _Line(waypoints)
    return line


def _projection(line: _Line, closest: Sequence[int], x: float, y: float) -> tuple[float, int]:
    """The car's arc length along the centre line (its foot on segment ``closest[0] → [1]``) and that segment."""
    n = len(line.points)
    i = int(closest[0]) % n
    if i >= n - 1:
        # [n-1, 0]: past the last row; on a loop that row is the first one again (arc length 0), on an open track
        # the car is beyond the end, so the last segment, clamped below, puts it at the end.
        i = 0 if line.closed else n - 2
    px, py = line.points[i]
    sx, sy = line.seg[i]
    sl = line.seg_len[i]
    t = 0.0 if sl <= 1e-12 else min(max(((x - px) * sx + (y - py) * sy) / (sl * sl), 0.0), 1.0)
    return float(line.cum[i] + t * sl), i


def _points_ahead(line: _Line, s0: float, distances: np.ndarray) -> np.ndarray:
    """(k, 2) centre-line points at arc lengths ``s0 + distances``, wrapped on a loop, clamped on an open track."""
    s = s0 + distances
    s = np.mod(s, line.length) if line.closed and line.length > 0.0 else np.minimum(s, line.length)
    # side="right": the last row at or before s, which skips zero-length segments (their rows share one cum value).
    k = np.clip(np.searchsorted(line.cum, s, side="right") - 1, 0, len(line.seg) - 1)
    seg_len = line.seg_len[k]
    frac = np.divide(s - line.cum[k], seg_len, out=np.zeros_like(s), where=seg_len > 1e-12)
    frac = np.clip(frac, 0.0, 1.0)
    return line.points[k] + frac[:, None] * line.seg[k]


_LOOKAHEAD = np.asarray(LOOKAHEAD_M, dtype=np.float64)


def state_vector(params: Mapping[str, Any]) -> np.ndarray:
    """The privileged teacher's observation from one step's DeepRacer reward ``params``: float32 (:data:`STATE_SIZE`,).

    Reads ``speed``, ``steering_angle``, ``heading``, ``x``, ``y``, ``distance_from_center``, ``is_left_of_center``,
    ``track_width``, ``waypoints``, ``closest_waypoints`` and, if present, ``objects_location``; the layout is the
    module docstring's table. Every value is finite for well-formed params."""
    x, y = float(params["x"]), float(params["y"])
    heading = math.radians(float(params["heading"]))
    ch, sh = math.cos(heading), math.sin(heading)
    line = _line(params["waypoints"])
    s0, seg = _projection(line, params["closest_waypoints"], x, y)

    out = np.empty(STATE_SIZE, dtype=np.float64)
    out[0] = float(params["speed"]) / SPEED_SCALE_MPS
    out[1] = float(params["steering_angle"]) / STEERING_SCALE_DEG

    # Heading error as sin/cos of (heading - track direction), from the products with the track's unit direction:
    # no angle wrapping, and continuous through ±180°.
    dx, dy = line.direction[seg]
    out[2] = dx * sh - dy * ch  # sin(heading - track)
    out[3] = dx * ch + dy * sh  # cos(heading - track)

    half = float(params["track_width"]) / 2.0
    offset = float(params["distance_from_center"]) / max(half, _MIN_HALF_WIDTH_M)
    out[4] = offset if params["is_left_of_center"] else -offset
    out[5] = half

    # Track shape: centre-line points ahead in the car frame, each divided by its distance so that every pair is
    # about unit length whatever L (a straight road reads (1, 0) everywhere; a bend bends the far ones most).
    pts = _points_ahead(line, s0, _LOOKAHEAD)
    rx, ry = pts[:, 0] - x, pts[:, 1] - y
    n_ahead = len(LOOKAHEAD_M)
    out[6 : 6 + 2 * n_ahead : 2] = (ch * rx + sh * ry) / _LOOKAHEAD
    out[7 : 7 + 2 * n_ahead : 2] = (-sh * rx + ch * ry) / _LOOKAHEAD

    base = 6 + 2 * n_ahead
    out[base:] = _ABSENT_OBJECT * OBJECT_SLOTS
    locations = params.get("objects_location") or ()
    if len(locations):
        obj = np.asarray(locations, dtype=np.float64).reshape(-1, 2)
        ox, oy = obj[:, 0] - x, obj[:, 1] - y
        fwd, left = ch * ox + sh * oy, -sh * ox + ch * oy
        dist = np.hypot(ox, oy)
        ahead = np.flatnonzero((fwd > 0.0) & (dist <= OBJECT_RANGE_M))
        nearest = ahead[np.argsort(dist[ahead], kind="stable")][:OBJECT_SLOTS]
        for slot, j in enumerate(nearest):
            out[base + 3 * slot : base + 3 * slot + 3] = (1.0, fwd[j] / OBJECT_RANGE_M, left[j])
    return out.astype(np.float32)
