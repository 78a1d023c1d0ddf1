"""The simapp's track lines for placing and judging objects: centre line, borders, lanes and the inner half-road.

simapp ``markov/track_geom/track_data.py: TrackData`` (its shapely lines are kept); projections onto the centre line
use racer's :class:`Track`. "The centre line" is the track's centre line in the direction of travel (``reverse`` =
the reversed track, as the simapp's ``TrackData.center_line``); "inner/outer lane" is the line halfway between the
centre line and the inner/outer border (``TrackData.__init__``). Shared by ``sim/placement.py``, ``sim/bots.py``,
``sim/object_params.py`` and ``sim/race_rules.py``.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from shapely.geometry import LinearRing, LineString, Point, Polygon

from sim.track import Track


def find_prev_next(a: Sequence[float], x: float) -> tuple[int, int]:
    """simapp ``track_geom/utils.py: find_prev_next``: indices around ``x`` in sorted ``a``, wrapping."""
    next_index = bisect.bisect_right(a, x)
    prev_index = next_index - 1
    if prev_index == -1:
        prev_index = len(a) - 1
    if next_index == len(a):
        next_index = 0
    return prev_index, next_index


class TrackLine:
    """simapp ``track_geom/track_data.py: TrackLine``: a shapely line and its vertices' normalized distances."""

    def __init__(self, coords: np.ndarray, closed: bool) -> None:
        self.line = LinearRing(coords) if closed else LineString(coords)
        self.coords = np.asarray(self.line.coords, dtype=np.float64)
        self.length = float(self.line.length)
        self.ndists = [self.line.project(Point(p), normalized=True) for p in self.coords[:-1]] + [1.0]

    def project(self, x: float, y: float) -> float:
        return float(self.line.project(Point(x, y)))

    def point(self, distance: float) -> tuple[float, float]:
        """shapely ``interpolate``: a negative distance counts from the end, one past the end stops there."""
        p = self.line.interpolate(distance)
        return float(p.x), float(p.y)

    def pose(self, distance: float, forward: bool) -> tuple[float, float, float]:
        """simapp ``TrackLine.interpolate_pose``: (x, y, yaw); ``forward`` = FORWARD_DIFFERENCE (towards the next
        vertex) instead of CENTRAL_DIFFERENCE (previous to next vertex)."""
        x, y = self.point(distance)
        prev_index, next_index = find_prev_next(self.ndists, distance / self.length)
        nxt = self.coords[next_index]
        base = (x, y) if forward else self.coords[prev_index]
        return x, y, math.atan2(nxt[1] - base[1], nxt[0] - base[0])


@dataclass(frozen=True, eq=False)
class LaneGeometry:
    """The simapp's ``TrackData`` lines for one track and direction."""

    track: Track
    """The track in the direction of travel (racer's projection onto the centre line)."""
    center: TrackLine
    inner_border: TrackLine
    outer_border: TrackLine
    inner_lane: TrackLine
    outer_lane: TrackLine
    inner_poly: Polygon
    """Between the centre line and the inner border (direction-independent)."""
    is_ccw: bool
    """simapp ``TrackData.is_ccw``: the forward centre line's orientation (True for an open track), flipped when
    reversed."""

    @property
    def length(self) -> float:
        return self.track.length

    def center_s(self, points: np.ndarray) -> np.ndarray:
        """simapp ``center_line.project``: arc length of the nearest centre-line point, metres."""
        return self.track.project(np.asarray(points, dtype=np.float64).reshape(-1, 2)).s

    def is_inner(self, x: float, y: float) -> bool:
        """simapp ``RolloutCtrl._is_obstacle_inner``: nearer the inner border than the outer one, both measured at
        the centre-line point nearest (x, y) (``TrackData.get_nearest_points`` / ``get_nearest_dist``)."""
        cx, cy = self.center.point(self.center.project(x, y))
        ix, iy = self.inner_border.point(self.inner_border.project(cx, cy))
        ox, oy = self.outer_border.point(self.outer_border.project(cx, cy))
        return math.hypot(x - ix, y - iy) < math.hypot(x - ox, y - oy)


@lru_cache(maxsize=32)
def lane_geometry(track: Track, reverse: bool) -> LaneGeometry:
    """simapp ``track_data.py: TrackData.__init__``, for ``track`` as loaded (forward) driven forward or reversed."""
    forward = track
    directed = track.reversed() if reverse else track
    wp = directed.waypoints
    closed = directed.closed
    if closed:
        inner_poly = Polygon(forward.center, [forward.inner])
        is_ccw = (not forward.clockwise) ^ reverse
    else:
        inner_poly = Polygon(np.vstack((forward.center, np.flipud(forward.inner))))
        is_ccw = True ^ reverse
    return LaneGeometry(
        track=directed,
        center=TrackLine(wp[:, 0:2], closed),
        inner_border=TrackLine(wp[:, 2:4], closed),
        outer_border=TrackLine(wp[:, 4:6], closed),
        inner_lane=TrackLine((wp[:, 2:4] + wp[:, 0:2]) / 2, closed),
        outer_lane=TrackLine((wp[:, 4:6] + wp[:, 0:2]) / 2, closed),
        inner_poly=inner_poly,
        is_ccw=is_ccw,
    )
