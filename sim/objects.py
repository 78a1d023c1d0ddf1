"""DeepRacer's obstacles and bot cars, in pure Python, as DeepRacer's simulation application computes them.

The reference is aws-deepracer-community/deepracer-simapp, ``bundle/markov/…``; each function names the simapp file
and function it follows. ``docs/object-avoidance.md`` has the notes (defaults, edge cases, simapp bugs kept).

- Model: the footprints of the objects (:data:`FOOTPRINTS`) and :class:`WorldObject`, :func:`as_boxes`.
- Placement and motion: :func:`place_obstacles` / :class:`Obstacles` (static), :class:`BotCars` (moving along their
  lanes, lane changes on cubic splines, as the simapp's ``BotCarsCtrl``).
- Task: :func:`object_params` (the reward function's object params), :func:`empty_object_params` (a time trial's),
  :func:`is_crashed` / :func:`collided_object` (the crash rule), :func:`in_camera_view` (the camera test),
  :func:`car_at_fault` (whether a crash with a bot counts for the car), :func:`reset_pose` and :func:`start_pose`
  (where the car is put back or starts near objects).

Geometry: "the centre line" is the track's centre line in the direction of travel (``reverse`` = the reversed
track, as the simapp's ``TrackData.center_line``); "inner/outer lane" is the line halfway between the centre line
and the inner/outer border (simapp ``track_data.py: TrackData.__init__``). The simapp's shapely lines are kept
(lanes, borders, the inner half-road polygon); projections onto the centre line use racer's :class:`Track`.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import shapely
from scipy.interpolate import spalde, splprep
from shapely.geometry import LinearRing, LineString, Point, Polygon

from common.errors import UserError
from common.race import HeadToBotConfig, ObjectAvoidanceConfig, ObstacleLane, RaceConfig
from sim.physics import FRONT_POINT_M, Pose
from sim.track import Track
from sim.world import CONTROL_HZ

CONTROL_DT_S = 1.0 / CONTROL_HZ
"""One control step, seconds: how far the bot cars' clock moves per :meth:`BotCars.step`."""

BOX_KINDS = ("box_obstacle", "deepracer_box_obstacle", "amazon_box_obstacle")
"""simapp ``markov/agent_ctrl/constants.py: OBSTACLE_TYPE_LIST``."""
BOT_CAR_OBSTACLE = "bot_car_obstacle"
"""A parked bot car used as a static obstacle (simapp IS_OBSTACLE_BOT_CAR: named ``obstacle_<i>`` there)."""
BOT_CAR = "bot_car"
"""A moving bot car (simapp ``BotCarsCtrl``: named ``bot_car_<i>``)."""


def pause_steps(seconds: float, dt: float = CONTROL_DT_S) -> int:
    """Control steps a pause of ``seconds`` lasts in the simapp: its pauses (the bots' ``BotCarsCtrl.pause_duration``,
    the car's ``RolloutCtrl._pause_duration``) count down by the sim time each step and end at the first
    ``judge_action`` that finds them <= 0, which is one step after a 0 s pause. ``seconds / dt`` is rounded off
    first: 2.0 / (1/15) is 30.000000000000004 in floating point, and the simapp's count ends on the 30th step."""
    return max(1, math.ceil(round(seconds / dt, 6)))


CLOSEST_OBJ_GAP_M = 1.0
"""simapp ``agent_ctrl/constants.py: CLOSEST_OBJ_GAP``: an object this close along the centre line to a start or
reset point moves the car to the other lane."""
_SPLINE_DEGREE = 3  # simapp track_geom/constants.py: SPLINE_DEGREE
_DIST_THRESHOLD_M = 0.02  # simapp track_geom/constants.py: DIST_THRESHOLD


class RaceSetupError(UserError, ValueError):
    """A race the simapp's code cannot run sensibly (the message says why)."""


@dataclass(frozen=True)
class Footprint:
    """The size of one kind of object.

    ``length``/``width``/``height`` are the model's real size (what a camera or LiDAR sees);
    ``crash_length``/``crash_width`` the rectangle the simapp's crash rule and camera test use
    (``track_geom/constants.py: ObstacleDimensions``, read by ``track_data.py: get_object_bounding_rect`` as
    (width along y, length along x) -- the enum's comment says the opposite, the code wins); ``z`` the height of the
    pose the simapp keeps for the object (``agent_ctrl/constants.py: OBSTACLE_Z``, ``BOT_CAR_Z``), which its camera
    test uses."""

    length: float
    width: float
    height: float
    crash_length: float
    crash_width: float
    z: float
    source: str


_BOX_CRASH = (0.5, 0.4)  # ObstacleDimensions.BOX_OBSTACLE_DIMENSION = (0.4, 0.5): width 0.3 + 0.1, length 0.4 + 0.1
_BOT_CAR_CRASH = (0.32352, 0.1961)  # ObstacleDimensions.BOT_CAR_DIMENSION = (0.1961, 0.32352)
_BOT_CAR_HEIGHT_M = 0.2108
"""Top of the bot car: ``bundle/meshes/deepracer/car_body_link_v3.STL`` reaches z = 0.19504 m and
``bundle/models/bot_car/model.sdf`` places it at z + 0.01577 m (the visual's pose)."""

FOOTPRINTS: dict[str, Footprint] = {
    "box_obstacle": Footprint(
        0.4, 0.3, 0.25, *_BOX_CRASH, 0.1, "bundle/models/box_obstacle/model.sdf: <box><size>0.4 0.3 0.25"
    ),
    "deepracer_box_obstacle": Footprint(
        0.36,
        0.265,
        0.24,
        *_BOX_CRASH,
        0.1,
        "bundle/models/deepracer_box_obstacle/model.sdf: a 1 m cube mesh scaled 0.36 0.265 0.24",
    ),
    "amazon_box_obstacle": Footprint(
        0.4,
        0.3,
        0.25,
        *_BOX_CRASH,
        0.1,
        "bundle/models/amazon_box_obstacle/model.sdf: a 1 m cube mesh scaled 0.4 0.3 0.25",
    ),
    BOT_CAR_OBSTACLE: Footprint(
        *_BOT_CAR_CRASH, _BOT_CAR_HEIGHT_M, *_BOT_CAR_CRASH, 0.0, "ObstacleDimensions.BOT_CAR_DIMENSION + bot_car mesh"
    ),
    BOT_CAR: Footprint(
        *_BOT_CAR_CRASH, _BOT_CAR_HEIGHT_M, *_BOT_CAR_CRASH, 0.0, "ObstacleDimensions.BOT_CAR_DIMENSION + bot_car mesh"
    ),
}
"""Every kind of object. The bot car's length and width are the simapp's BOT_CAR_DIMENSION, which matches its mesh
(body 0.324 m long; 0.197 m wide over the wheels)."""

CAR_CRASH_LENGTH_M, CAR_CRASH_WIDTH_M = _BOT_CAR_CRASH
"""The racing car's crash rectangle, centred on its base_link: the simapp registers the agent with
BOT_CAR_DIMENSION too (``rollout_agent_ctrl.py: RolloutCtrl.__init__``)."""


@dataclass(frozen=True)
class WorldObject:
    """An obstacle or bot car: pose (metres, radians CCW from +x) and size (metres) in world coordinates."""

    x: float
    y: float
    yaw: float
    length: float
    width: float
    height: float
    speed: float
    """m/s along the centre line; 0 for static obstacles."""
    kind: str
    """A key of :data:`FOOTPRINTS`."""

    @classmethod
    def of(cls, kind: str, x: float, y: float, yaw: float, speed: float = 0.0) -> WorldObject:
        """An object of a known kind, sized from :data:`FOOTPRINTS`."""
        fp = FOOTPRINTS[kind]
        return cls(float(x), float(y), float(yaw), fp.length, fp.width, fp.height, float(speed), kind)

    @property
    def footprint(self) -> Footprint:
        return FOOTPRINTS[self.kind]

    @property
    def is_obstacle(self) -> bool:
        """A static obstacle (the simapp's ``obstacle_<i>``), as opposed to a moving bot car."""
        return self.kind != BOT_CAR


def as_boxes(objects: Sequence[WorldObject]) -> np.ndarray:
    """(K, 6) float64 ``[x, y, yaw, length, width, height]`` of the objects in world coordinates (for the
    renderer and the LiDAR; height is the object's real height, standing on the ground)."""
    rows = [(o.x, o.y, o.yaw, o.length, o.width, o.height) for o in objects]
    return np.array(rows, dtype=np.float64).reshape(len(rows), 6)


# ---------------------------------------------------------------------------------------------------------------
# Geometry shared by placement, motion and params


def _find_prev_next(a: Sequence[float], x: float) -> tuple[int, int]:
    """simapp ``track_geom/utils.py: find_prev_next``: indices around ``x`` in sorted ``a``, wrapping."""
    next_index = bisect.bisect_right(a, x)
    prev_index = next_index - 1
    if prev_index == -1:
        prev_index = len(a) - 1
    if next_index == len(a):
        next_index = 0
    return prev_index, next_index


class _Line:
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
        prev_index, next_index = _find_prev_next(self.ndists, distance / self.length)
        nxt = self.coords[next_index]
        base = (x, y) if forward else self.coords[prev_index]
        return x, y, math.atan2(nxt[1] - base[1], nxt[0] - base[0])


@dataclass(frozen=True, eq=False)
class _Geometry:
    """The simapp's ``TrackData`` lines for one track and direction."""

    track: Track
    """The track in the direction of travel (racer's projection onto the centre line)."""
    center: _Line
    inner_border: _Line
    outer_border: _Line
    inner_lane: _Line
    outer_lane: _Line
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
def _geometry(track: Track, reverse: bool) -> _Geometry:
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
    return _Geometry(
        track=directed,
        center=_Line(wp[:, 0:2], closed),
        inner_border=_Line(wp[:, 2:4], closed),
        outer_border=_Line(wp[:, 4:6], closed),
        inner_lane=_Line((wp[:, 2:4] + wp[:, 0:2]) / 2, closed),
        outer_lane=_Line((wp[:, 4:6] + wp[:, 0:2]) / 2, closed),
        inner_poly=inner_poly,
        is_ccw=is_ccw,
    )


# ---------------------------------------------------------------------------------------------------------------
# Placement


def _spread(
    length: float, count: int, gap: float, randomize: bool, rng: np.random.Generator
) -> tuple[np.ndarray, list[bool]]:
    """Distances along the centre line and lanes (True = outer) for generated positions.

    simapp ``obstacles_agent_ctrl.py: ObstaclesCtrl._compute_obstacle_poses`` and ``bot_cars_agent_ctrl.py:
    BotCarsCtrl._compute_bot_car_initial_states`` (the same code): evenly spaced from ``gap`` to ``length - 1``;
    randomized, each (in a random order) is drawn uniformly between its neighbours' positions ± ``gap`` (the first no
    lower than ``gap``, the last no higher than ``length - 1``; one whose interval is empty stays), then each gets a
    random lane; not randomized, the lanes alternate inner, outer, … from the first."""
    start, end = gap, length - 1.0
    dists = np.linspace(start, end, count)
    if not randomize:
        return dists, [i % 2 == 1 for i in range(count)]
    for i in rng.permutation(count):
        lo = start if i == 0 else dists[i - 1] + gap
        hi = end if i == count - 1 else dists[i + 1] - gap
        if lo < hi:
            dists[i] = rng.uniform(lo, hi)
    return dists, [bool(rng.integers(2)) for _ in range(count)]


def _lane_pose(geom: _Geometry, outer: bool, center_dist: float) -> tuple[float, float, float]:
    """The lane point facing the centre-line point at ``center_dist``, with the lane's direction (CENTRAL_DIFFERENCE):
    simapp ``ObstaclesCtrl._compute_obstacle_poses``: ``lane.interpolate_pose(lane.project(center.interpolate(d)))``."""
    lane = geom.outer_lane if outer else geom.inner_lane
    cx, cy = geom.center.point(center_dist)
    return lane.pose(lane.project(cx, cy), forward=False)


def obstacle_gap_m(cfg: ObjectAvoidanceConfig, track_length: float, placements: int = 1) -> float:
    """The minimum distance the simapp uses between generated obstacles, metres.

    ``ObstaclesCtrl._compute_obstacle_poses`` converts MIN_DISTANCE_BETWEEN_OBSTACLES from percent of the lap to
    metres each time it runs, on the value it converted last time; it runs once when the worker starts and once at
    each episode's reset, so the ``placements``-th placement (1 = the start-up one, 2 = the first episode's, n + 1 =
    the n-th episode's) uses percent·(L/100)^placements. :class:`Obstacles` keeps that count."""
    gap = cfg.min_distance_between_obstacles
    for _ in range(placements):
        gap = gap / 100.0 * track_length
    return gap


def place_obstacles(
    track: Track,
    cfg: ObjectAvoidanceConfig,
    rng: np.random.Generator,
    reverse: bool,
    gap_m: float | None = None,
) -> list[WorldObject]:
    """The static obstacles of an episode: simapp ``obstacles_agent_ctrl.py: ObstaclesCtrl._compute_obstacle_poses``.

    Fixed positions (``cfg.object_positions``): ``progress`` × the centre line's length along the centre line of the
    direction of travel (so on a reversed lap the same numbers are measured from the start line the other way), in
    the given lane. Otherwise :func:`_spread` with ``gap_m`` (default: the percent converted once, see
    :func:`obstacle_gap_m`). Each obstacle sits on its lane at the point nearest the centre-line point, facing along
    the lane in the direction of travel. ``track`` is the track as loaded (forward)."""
    geom = _geometry(track, reverse)
    if cfg.object_positions:
        dists = [p.progress * geom.center.length for p in cfg.object_positions]
        outer = [p.lane == ObstacleLane.OUTER for p in cfg.object_positions]
    else:
        gap = obstacle_gap_m(cfg, geom.center.length) if gap_m is None else gap_m
        dists, outer = _spread(geom.center.length, cfg.count, gap, cfg.randomize_obstacle_locations, rng)
    kind = BOT_CAR_OBSTACLE if cfg.is_obstacle_bot_car else cfg.obstacle_type
    return [WorldObject.of(kind, *_lane_pose(geom, o, float(d))) for d, o in zip(dists, outer, strict=True)]


class Obstacles:
    """The simapp's ``ObstaclesCtrl`` over a worker's life: new obstacle poses at each :meth:`reset`, with the
    minimum distance converted once more each time, exactly as the simapp does (see :func:`obstacle_gap_m`: with
    the default 2 % on reinvent_base the first episode uses 0.063 m and the gap keeps shrinking towards 0)."""

    def __init__(self, track: Track, cfg: ObjectAvoidanceConfig) -> None:
        self.track = track
        self.cfg = cfg
        self.placements = 1  # ObstaclesCtrl.__init__ computes poses once
        self.objects: list[WorldObject] = []

    def reset(self, rng: np.random.Generator, reverse: bool) -> list[WorldObject]:
        """``ObstaclesCtrl.reset_agent``: the obstacles of the next episode."""
        self.placements += 1
        gap = obstacle_gap_m(self.cfg, self.track.length, self.placements)
        self.objects = place_obstacles(self.track, self.cfg, rng, reverse, gap_m=gap)
        return self.objects


# ---------------------------------------------------------------------------------------------------------------
# Bot cars


def _eval_spline(tck, dist: float, length: float) -> tuple[float, float, float, float]:
    """simapp ``track_geom/spline/abstract_spline.py: AbstractSpline.eval_spline``: (x, y, dx, dy) at centre-line
    distance ``dist``, shifted by one lap into the spline's range, then clamped to it."""
    min_dist = tck[0][_SPLINE_DEGREE]
    max_dist = tck[0][-_SPLINE_DEGREE - 1]
    if dist < min_dist:
        dist += length
    if dist > max_dist:
        dist -= length
    derivs = spalde(max(min_dist, min(dist, max_dist)), tck)
    return float(derivs[0][0]), float(derivs[1][0]), float(derivs[0][1]), float(derivs[1][1])


class _LaneSpline:
    """simapp ``track_geom/spline/track_spline.py: TrackSpline``: a cubic spline through a lane's vertices,
    parametrized by their projections onto the centre line (so a bot's speed is along the centre line)."""

    def __init__(self, geom: _Geometry, lane: _Line) -> None:
        length = geom.length
        lane_dists = [float(s) for s in geom.center_s(lane.coords)]
        # Projections of the first vertices can land at the end of the lap, those of the last at its start.
        for i in range(len(lane_dists)):
            if lane_dists[i] < 0.5 * length:
                break
            lane_dists[i] -= length
        for i in range(len(lane_dists) - 1, 0, -1):
            if lane_dists[i] > 0.5 * length:
                break
            lane_dists[i] += length
        u, ui = np.unique(lane_dists, return_index=True)
        x = lane.coords.T[:, ui]
        if u[0] > 0.0:
            x[:, 0] = lane.point(lane.project(*geom.center.coords[0]))
            u[0] = 0.0
        if u[-1] < length:
            x[:, -1] = lane.point(lane.project(*geom.center.coords[-1]))
            u[-1] = length
        closed = geom.track.closed
        if closed:
            x[:, -1] = x[:, 0]
        self.line = lane
        self.dists = lane_dists
        self.tck = splprep(x, u=u, k=_SPLINE_DEGREE, s=0, per=1 if closed else 0)[0]
        self.length = length

    def eval(self, dist: float) -> tuple[float, float, float, float]:
        return _eval_spline(self.tck, dist, self.length)


class _LaneChangeSpline:
    """simapp ``track_geom/spline/lane_change_spline.py: LaneChangeSpline``: a cubic spline from a few vertices of
    the start lane before the bot, through the start lane's point where the change starts and the end lane's point
    where it ends, to a few vertices of the end lane after it."""

    def __init__(
        self,
        geom: _Geometry,
        start: _LaneSpline,
        end: _LaneSpline,
        current_dist: float,
        start_dist: float,
        end_dist: float,
    ) -> None:
        length = geom.length
        start_point = np.array(start.eval(start_dist)[:2])
        end_point = np.array(end.eval(end_dist)[:2])
        end_offset = 0.0 if start_dist < end_dist else length
        current_prev_index = bisect.bisect_left(start.dists, current_dist) - 1
        start_prev_index = bisect.bisect_left(start.dists, start_dist) - 1
        end_next_index = bisect.bisect_right(end.dists, end_dist)
        num_start = len(start.line.coords) - (1 if geom.track.closed else 0)
        num_end = len(end.line.coords) - (1 if geom.track.closed else 0)
        start_index_0 = (current_prev_index - 3) % num_start
        start_index_1 = start_prev_index
        end_index_0 = end_next_index
        end_index_1 = (end_next_index + 3) % num_end
        if start_index_0 < start_index_1:
            start_indices = list(range(start_index_0, start_index_1 + 1))
            start_offsets = [0.0] * len(start_indices)
        else:
            first, second = list(range(start_index_0, num_start)), list(range(start_index_1 + 1))
            start_indices = first + second
            start_offsets = [-length] * len(first) + [0.0] * len(second)
        if end_index_0 < end_index_1:
            end_indices = list(range(end_index_0, end_index_1 + 1))
            end_offsets = [end_offset] * len(end_indices)
        else:
            first, second = list(range(end_index_0, num_end)), list(range(end_index_1 + 1))
            end_indices = first + second
            end_offsets = [end_offset] * len(first) + [end_offset + length] * len(second)
        # Drop a lane vertex too close to the change's own start or end point.
        if np.linalg.norm(start.line.coords[start_indices[-1]] - start_point) < _DIST_THRESHOLD_M:
            start_indices.pop()
            start_offsets.pop()
        if np.linalg.norm(end.line.coords[end_indices[0]] - end_point) < _DIST_THRESHOLD_M:
            end_indices.pop(0)
            end_offsets.pop(0)
        u = np.hstack(
            (
                np.array(start.dists)[start_indices] + np.array(start_offsets),
                start_dist,
                end_dist + end_offset,
                np.array(end.dists)[end_indices] + np.array(end_offsets),
            )
        )
        x = np.hstack(
            (
                start.line.coords.T[:, start_indices],
                start_point[:, None],
                end_point[:, None],
                end.line.coords.T[:, end_indices],
            )
        )
        u, ui = np.unique(u, return_index=True)
        self.tck = splprep(x[:, ui], u=u, k=_SPLINE_DEGREE, s=0)[0]
        self.length = length

    def eval(self, dist: float) -> tuple[float, float, float, float]:
        return _eval_spline(self.tck, dist, self.length)


class BotCars:
    """The simapp's ``bot_cars_agent_ctrl.py: BotCarsCtrl`` without Gazebo: call :meth:`reset` at the start of an
    episode and :meth:`step` once per control step.

    A bot's position is a function of the time since the reset: ``(initial + elapsed · speed) mod L`` along the
    centre line (``_get_dist_from_sim_time``), where ``elapsed`` leaves out ``penalty_seconds`` per :meth:`penalize`;
    it is drawn on its lane's spline, or on a lane-change spline. With lane changes each bot waits
    U(lower, upper) seconds, then changes lane over ``lane_change_distance`` metres of centre line
    (``_compute_bot_car_lane_changes``), and again. The first poses (at time 0) are those of the reset."""

    def __init__(self, track: Track, cfg: HeadToBotConfig, dt: float = CONTROL_DT_S) -> None:
        if cfg.is_lane_change and not track.closed:
            # The bots' distance wraps from the end of an open track to its start (d mod L), and the simapp's
            # lane-change splines then take points from both ends: their positions run off to kilometres.
            raise RaceSetupError(
                f"bot cars cannot change lanes on the open track {track.name!r}: DeepRacer's lane-change splines "
                "break where the bots jump from its end back to its start; set is_lane_change false"
            )
        self.track = track
        self.cfg = cfg
        self.dt = dt
        self.time = 0.0
        """Seconds since the reset (the simapp's sim time minus its start)."""
        self.crash_count = 0
        self.objects: list[WorldObject] = []
        self._lane_change_duration = cfg.lane_change_distance / cfg.bot_car_speed
        self._pause_left = 0
        """Control steps the bots still stand still."""
        self._rng = np.random.default_rng()

    def reset(self, rng: np.random.Generator, reverse: bool) -> list[WorldObject]:
        """``BotCarsCtrl.reset_agent`` + ``_compute_bot_car_initial_states``: new start positions and lanes."""
        self._rng = rng
        self._geom = _geometry(self.track, reverse)
        inner, outer = _lane_splines(self.track, reverse)
        self.time, self.crash_count, self._pause_left = 0.0, 0, 0
        n = self.cfg.number_of_bot_cars
        dists, use_outer = _spread(
            self._geom.length, n, self.cfg.min_distance_between_bot_cars, self.cfg.randomize_bot_car_locations, rng
        )
        self._initial = [float(d) for d in dists]
        self._lanes = [outer if o else inner for o in use_outer]
        self._opposite = [inner if o else outer for o in use_outer]
        self._end_times = [0.0 if self.cfg.is_lane_change else math.inf] * n
        self._trajectories: list[_LaneSpline | _LaneChangeSpline] = list(self._lanes)
        self.objects = self._poses()
        return self.objects

    @property
    def lane_change_end_times(self) -> list[float]:
        """When each bot's current (or next) lane change ends, seconds since the reset; inf without lane changes."""
        return list(self._end_times)

    @property
    def paused(self) -> bool:
        """The bots stand still after one ran into the car (``AgentPhase.PAUSE``)."""
        return self._pause_left > 0

    def step(self) -> list[WorldObject]:
        """One control step: the clock moves by ``dt``; unless paused, lane changes and poses are updated
        (``BotCarsCtrl.send_action``); while paused the bots keep their poses (``judge_action``'s PAUSE phase)."""
        self.time += self.dt
        if self._pause_left > 0:
            self._pause_left -= 1
            return self.objects
        self._lane_changes()
        self.objects = self._poses()
        return self.objects

    def penalize(self) -> None:
        """A bot ran into the car from behind (:func:`car_at_fault` False): ``BotCarsCtrl.judge_action`` pauses all
        bots for ``penalty_seconds`` (not again while paused), shifting their lane-change times and their clock.
        They stand still for the next :func:`pause_steps` steps (30 for 2 s), then go on one step's distance
        from where they stopped."""
        if self._pause_left > 0:
            return
        self._end_times = [t + self.cfg.penalty_seconds for t in self._end_times]
        self.crash_count += 1
        self._pause_left = pause_steps(self.cfg.penalty_seconds, self.dt)

    def distance(self, index: int, time: float | None = None) -> float:
        """``_get_dist_from_sim_time``: bot ``index``'s distance along the centre line at ``time`` (default now)."""
        t = self.time if time is None else time
        elapsed = max(t - self.crash_count * self.cfg.penalty_seconds, 0.0)
        return (self._initial[index] + elapsed * self.cfg.bot_car_speed) % self._geom.length

    def _lane_changes(self) -> None:
        """``BotCarsCtrl._compute_bot_car_lane_changes``."""
        for i, end_time in enumerate(self._end_times):
            if self.time < end_time:
                continue
            if end_time > 0.0:  # the last change is over: the bot is on the other lane now
                self._lanes[i], self._opposite[i] = self._opposite[i], self._lanes[i]
            end_time = self.time + self._rng.uniform(self.cfg.lower_lane_change_time, self.cfg.upper_lane_change_time)
            end_time += self._lane_change_duration
            self._end_times[i] = end_time
            start_time = end_time - self._lane_change_duration
            self._trajectories[i] = _LaneChangeSpline(
                self._geom,
                self._lanes[i],
                self._opposite[i],
                self.distance(i),
                self.distance(i, start_time),
                self.distance(i, end_time),
            )

    def _poses(self) -> list[WorldObject]:
        """``BotCarsCtrl._compute_bot_car_poses``: spline point, yaw of the spline's tangent."""
        objects = []
        for i, spline in enumerate(self._trajectories):
            x, y, dx, dy = spline.eval(self.distance(i))
            objects.append(WorldObject.of(BOT_CAR, x, y, math.atan2(dy, dx), self.cfg.bot_car_speed))
        return objects


@lru_cache(maxsize=32)
def _lane_splines(track: Track, reverse: bool) -> tuple[_LaneSpline, _LaneSpline]:
    """Inner and outer lane splines (``BotCarsCtrl.__init__``; rebuilt there when the direction changes)."""
    geom = _geometry(track, reverse)
    return _LaneSpline(geom, geom.inner_lane), _LaneSpline(geom, geom.outer_lane)


def object_progress(track: Track, reverse: bool, obj: WorldObject) -> float:
    """A bot's progress, percent: where its front point (0.14 m ahead of its pose) projects onto the centre line,
    as a share of the lap (simapp ``BotCarsCtrl.update_agent``; ``start_ndist`` 0)."""
    geom = _geometry(track, reverse)
    front = Pose(obj.x, obj.y, obj.yaw).ahead(FRONT_POINT_M)
    return float(geom.center_s(front)[0]) / geom.length * 100.0


def car_at_fault(car_progress: float, car_start_fraction: float, bot_progress: float) -> bool:
    """Whether a crash into a moving bot car counts as the car's crash.

    simapp ``rollout_agent_ctrl.py: RolloutCtrl._check_for_episode_termination`` (and ``BotCarsCtrl.judge_action``):
    both progresses are normalized to the start line (``agent_ctrl/utils.py: get_normalized_progress``:
    ``(progress + start_ndist · 100) % 100``); the car crashed if it is behind the bot. Otherwise the bot ran into
    it: the episode goes on with ``is_crashed`` False and the bots pause (:meth:`BotCars.penalize`). A crash into a
    static obstacle is always the car's. No lap seam handling: a car at 99 % touching a bot at 1 % is not at fault.

    ``car_progress`` is the car's ``progress`` param (percent since its start), ``car_start_fraction`` where it
    started (fraction of the lap from the start line), ``bot_progress`` :func:`object_progress`."""
    car = (car_progress + car_start_fraction * 100.0) % 100.0
    return car < bot_progress % 100.0


# ---------------------------------------------------------------------------------------------------------------
# Crash rule


def _rect_corners(x: float, y: float, yaw: float, length: float, width: float) -> list[tuple[float, float]]:
    """simapp ``TrackData.get_object_bounding_rect``: the 4 floor corners of a rectangle centred on a pose."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    return [(x + c * a - s * b, y + s * a + c * b) for a, b in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))]


def _contains(obj: WorldObject, points: list[tuple[float, float]]) -> bool:
    """Any point strictly inside the object's crash rectangle (shapely ``Polygon.contains``: the edge is out)."""
    fp = obj.footprint
    c, s = math.cos(obj.yaw), math.sin(obj.yaw)
    hl, hw = 0.5 * fp.crash_length, 0.5 * fp.crash_width
    for px, py in points:
        dx, dy = px - obj.x, py - obj.y
        if abs(c * dx + s * dy) < hl and abs(-s * dx + c * dy) < hw:
            return True
    return False


def collided_object(car_pose: Pose, objects: Sequence[WorldObject]) -> int | None:
    """Index of the first object the car crashed into, or None.

    simapp ``track_data.py: TrackData.get_collided_object_name`` (the crash reset rule,
    ``reset/rules/crash_reset_rule.py``): a crash is a corner of the car's rectangle (BOT_CAR_DIMENSION around its
    base_link, along its yaw) strictly inside an object's crash rectangle. Only the car's corners are tested: an
    object's corner poking into the car's side without a car corner inside the object is no crash."""
    corners = _rect_corners(car_pose.x, car_pose.y, car_pose.yaw, CAR_CRASH_LENGTH_M, CAR_CRASH_WIDTH_M)
    for i, obj in enumerate(objects):
        if _contains(obj, corners):
            return i
    return None


def is_crashed(car_pose: Pose, objects: Sequence[WorldObject]) -> bool:
    """The simapp's crash rule (:func:`collided_object`): True if the car touches any object."""
    return collided_object(car_pose, objects) is not None


# ---------------------------------------------------------------------------------------------------------------
# The camera test of object_in_camera (simapp markov/cameras/frustum.py: Frustum, simapp version >= 3, one camera)

_CAMERA_OFFSET = np.array([0.14529379, 0.0, 0.13032555])
_CAMERA_PITCH = 0.2618
_NEAR, _FAR = 0.2, 300.0
_HFOV = 1.13
_VIEW_RATIO = 480.0 / 640.0


def _normalize(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    return v if n == 0 else v / n


def _frustum_planes(car: Pose) -> list[tuple[np.ndarray, float]]:
    """``Frustum.update`` + ``_calculate_frustum_planes`` (``ccw``): the camera at its offset from the car pose
    (z = 0: racer's poses are planar), turned with the car's yaw and pitched down 0.2618 rad."""
    cy, sy = math.cos(car.yaw), math.sin(car.yaw)
    rot_yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    cp, sp = math.cos(_CAMERA_PITCH), math.sin(_CAMERA_PITCH)
    cam_rot = rot_yaw @ np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # euler_to_quaternion(pitch, yaw)
    cam_pos = np.array([car.x, car.y, 0.0]) + rot_yaw @ _CAMERA_OFFSET
    forward, up, right = cam_rot @ (1.0, 0.0, 0.0), cam_rot @ (0.0, 0.0, 1.0), cam_rot @ (0.0, -1.0, 0.0)
    near_c, far_c = cam_pos + forward * _NEAR, cam_pos + forward * _FAR
    near_w = 2.0 * math.tan(_HFOV * 0.5) * _NEAR
    far_w = 2.0 * math.tan(_HFOV * 0.5) * _FAR
    near_h, far_h = near_w * _VIEW_RATIO, far_w * _VIEW_RATIO

    def corner(center, w, h, v, hsign):
        return center + v * up * (h * 0.5) + hsign * right * (w * 0.5)

    ntl, ntr = corner(near_c, near_w, near_h, 1, -1), corner(near_c, near_w, near_h, 1, 1)
    nbl, nbr = corner(near_c, near_w, near_h, -1, -1), corner(near_c, near_w, near_h, -1, 1)
    ftl, ftr = corner(far_c, far_w, far_h, 1, -1), corner(far_c, far_w, far_h, 1, 1)
    fbl, fbr = corner(far_c, far_w, far_h, -1, -1), corner(far_c, far_w, far_h, -1, 1)
    planes = []
    for p0, p1, p2 in (
        (nbl, ntl, nbr),  # near
        (fbr, ftr, fbl),  # far
        (fbl, ftl, nbl),  # left
        (nbr, ntr, fbr),  # right
        (ntr, ntl, ftr),  # top
        (nbr, fbr, nbl),  # bottom
    ):
        normal = _normalize(np.cross(p1 - p0, p2 - p0))
        planes.append((normal, -float(np.dot(normal, p0))))
    return planes


def _plane_arrays(planes: list[tuple[np.ndarray, float]]) -> tuple[np.ndarray, np.ndarray]:
    return np.array([n for n, _ in planes]), np.array([d for _, d in planes])


# The frustum of a car at the origin facing +x: a car elsewhere sees a point where this one sees the point moved into
# the car's frame (a rigid motion keeps every plane test), which is several times cheaper than new planes per step.
_CAR_FRAME_NORMALS, _CAR_FRAME_OFFSETS = _plane_arrays(_frustum_planes(Pose(0.0, 0.0, 0.0)))


def _floor_points(objects: Sequence[WorldObject]) -> np.ndarray:
    """(K, 5, 3): each object's crash-rectangle corners and its position, at its pose's z
    (``TrackData.get_objects_in_camera_frustums``: ``get_object_bounding_rect`` + the position)."""
    rows = []
    for o in objects:
        fp = o.footprint
        corners = _rect_corners(o.x, o.y, o.yaw, fp.crash_length, fp.crash_width)
        rows.append([(px, py, fp.z) for px, py in (*corners, (o.x, o.y))])
    return np.array(rows, dtype=np.float64).reshape(len(rows), 5, 3)


def _in_view(car: Pose, objects: Sequence[WorldObject]) -> np.ndarray:
    """(K,) bool: ``Frustum.test_visibility`` (every plane test > 0) for any of each object's floor points."""
    points = _floor_points(objects)
    c, s = math.cos(car.yaw), math.sin(car.yaw)
    dx, dy = points[..., 0] - car.x, points[..., 1] - car.y
    local = np.stack((c * dx + s * dy, -s * dx + c * dy, points[..., 2]), axis=-1)
    inside = np.all(local @ _CAR_FRAME_NORMALS.T + _CAR_FRAME_OFFSETS > 0.0, axis=-1)
    return inside.any(axis=1)


def in_camera_view(car_pose: Pose, obj: WorldObject) -> bool:
    """Whether the simapp's camera frustum of a car at ``car_pose`` sees ``obj`` (any floor corner of its crash
    rectangle, or its position): ``TrackData.get_objects_in_camera_frustums`` for one object."""
    return bool(_in_view(car_pose, [obj])[0])


# ---------------------------------------------------------------------------------------------------------------
# Reward params

OBJECT_PARAM_KEYS: tuple[str, ...] = (
    "closest_objects",
    "objects_location",
    "objects_left_of_center",
    "objects_speed",
    "objects_heading",
    "objects_distance_from_center",
    "objects_distance",
    "object_in_camera",
)
"""The keys ``TrackData.get_object_reward_params`` returns, in its order (``is_crashed`` comes from the crash rule,
see :func:`is_crashed`). ``dict.update`` into racer's params keeps ``PARAM_KEYS``' order."""


def empty_object_params() -> dict:
    """The object params without objects (a time trial): the simapp's defaults, ``agent_ctrl/constants.py:
    RewardParam`` (``get_object_reward_params`` returns nothing then)."""
    return {
        "closest_objects": [0, 0],
        "objects_location": [],
        "objects_left_of_center": [],
        "objects_speed": [],
        "objects_heading": [],
        "objects_distance_from_center": [],
        "objects_distance": [],
        "object_in_camera": False,
    }


@lru_cache(maxsize=64)
def _object_geometry(
    geom: _Geometry, locations: tuple[tuple[float, float], ...]
) -> tuple[tuple[float, ...], tuple[float, ...], tuple[bool, ...]]:
    """Per object: centre-line projection (``center_line.project``), distance to the centre line
    (``center_line.distance``) and left of centre (``inner_poly.contains(p) ^ (not is_ccw)``). Cached: static
    obstacles ask the same every step."""
    points = np.array(locations, dtype=np.float64)
    proj = geom.track.project(points)
    inside = shapely.contains_xy(geom.inner_poly, points[:, 0], points[:, 1])
    return (
        tuple(float(d) for d in proj.s),
        tuple(float(d) for d in np.abs(proj.lateral)),
        tuple(bool(i) ^ (not geom.is_ccw) for i in inside),
    )


def object_params(
    track: Track, car_pose: Pose, objects: Sequence[WorldObject], reverse: bool, model_s: float | None = None
) -> dict:
    """The reward function's object params: simapp ``track_geom/track_data.py: TrackData.get_object_reward_params``.

    ``track`` is the track as loaded, ``reverse`` the direction of travel, ``car_pose`` the car's base_link (the
    simapp's model pose; its "model point" is 0.14 m ahead), ``objects`` in the simapp's order (obstacles, then bot
    cars); ``model_s``, if given, is the arc length of the car's model point along the centre line in the direction
    of travel (what the task's projection gives). Values, per object in that order:

    - ``objects_location``: ``[x, y]`` lists (not tuples).
    - ``objects_distance``: arc length of the nearest centre-line point, metres from the start line in the direction
      of travel (unsorted); ``objects_distance_from_center``: distance to the centre line, metres.
    - ``objects_left_of_center``: inside the half road between the centre line and the inner border, XOR the lap
      running clockwise (so on a reversed lap the inner side is the right).
    - ``objects_heading`` / ``objects_speed``: 0.0 each, unless bot cars run (the simapp's NUMBER_OF_BOT_CARS > 0):
      then EVERY object's yaw in RADIANS (the docs say degrees) and the bots' configured speed (also while they are
      paused).
    - ``closest_objects``: ``[behind, ahead]`` by centre-line distance, not by Euclidean distance: the objects whose
      ``objects_distance`` come last at or before, and first after, the car's model point, wrapping over the lap's
      seam (a car at 98 % sees an object at 2 % ahead); numpy int64 as the simapp's ``np.argsort`` gives them.
    - ``object_in_camera``: whether object ``closest_objects[1] - 1`` is in the camera's frustum: the simapp numbers
      the frustum's objects including the car itself (registered first) but the params without it, so it never
      tests the object ahead, and is False whenever the object ahead is object 0. Kept as the simapp does it.
    """
    if not objects:
        return {}
    geom = _geometry(track, reverse)
    locations = [[o.x, o.y] for o in objects]
    pdists, center_dists, left = _object_geometry(geom, tuple((o.x, o.y) for o in objects))
    # ``model_s``: the caller's projection of the same point (the task has it), which saves a whole-track search.
    model_pdist = float(geom.center_s(car_pose.ahead(FRONT_POINT_M))[0]) if model_s is None else model_s
    bot_speeds = [o.speed for o in objects if o.kind == BOT_CAR]
    if bot_speeds:
        headings = [float(o.yaw) for o in objects]
        speeds = [float(bot_speeds[0])] * len(objects)
    else:
        headings = [0.0] * len(objects)
        speeds = [0.0] * len(objects)
    order = np.argsort(pdists)
    prev_i, next_i = _find_prev_next([pdists[i] for i in order], model_pdist)
    prev_index, next_index = order[prev_i], order[next_i]
    # The frustum's list starts with the car itself (index 0: registered with BOT_CAR_DIMENSION at z 0, never in its
    # own view, tested anyway as the simapp does), then the objects (index i + 1). Only entry ``next_index`` decides
    # the param, so only it is tested (the frustum test is most of this function's time otherwise).
    entry = (
        WorldObject.of(BOT_CAR, car_pose.x, car_pose.y, car_pose.yaw) if next_index == 0 else objects[next_index - 1]
    )
    return {
        "closest_objects": [prev_index, next_index],
        "objects_location": locations,
        "objects_left_of_center": list(left),
        "objects_speed": speeds,
        "objects_heading": headings,
        "objects_distance_from_center": list(center_dists),
        "objects_distance": list(pdists),
        "object_in_camera": bool(_in_view(car_pose, [entry])[0]),
    }


# ---------------------------------------------------------------------------------------------------------------
# Start and reset poses near objects


def _closest_object(
    geom: _Geometry, dist: float, objects: Sequence[WorldObject], obstacles_only: bool
) -> tuple[float, WorldObject] | None:
    """simapp ``RolloutCtrl._get_closest_obj``: the object nearest ``dist`` along the centre line within
    ``CLOSEST_OBJ_GAP`` (gap ``abs(d - dist) % L``: no wrap over the seam), with its centre-line distance."""
    best, best_gap = None, CLOSEST_OBJ_GAP_M
    for obj in objects:
        if obstacles_only and not obj.is_obstacle:
            continue
        d = float(geom.center_s(np.array([obj.x, obj.y]))[0])
        gap = abs(d - dist) % geom.length
        if gap < best_gap:
            best, best_gap = (d, obj), gap
    return best


def _lane_reset_pose(geom: _Geometry, center_dist: float, outer: bool) -> Pose:
    """simapp ``RolloutCtrl._get_reset_poses``: the lane point facing the centre-line point at ``center_dist``,
    facing the lane's next vertex (FORWARD_DIFFERENCE)."""
    lane = geom.outer_lane if outer else geom.inner_lane
    cx, cy = geom.center.point(center_dist)
    return Pose(*lane.pose(lane.project(cx, cy), forward=True))


def reset_pose(
    track: Track,
    reverse: bool,
    spawn_dist: float,
    car_pose: Pose,
    objects: Sequence[WorldObject],
    behind_m: float = 1.0,
    ahead_m: float | None = None,
) -> Pose:
    """Where an evaluation puts the car back: simapp ``RolloutCtrl._get_car_reset_model_state``.

    ``spawn_dist`` is the simapp's ``progress · L / 100`` (the previous step's progress after off-track, reversed or
    immobilized, the current one after a crash), ``car_pose`` the pose then (previous / current). If a static
    obstacle lies within 1 m of it along the centre line, the car goes ``behind_m`` (RESET_BEHIND_DIST) before the
    obstacle -- or ``ahead_m`` past it for a mercy reset -- in the lane the obstacle is not in; otherwise to the lane
    (inner/outer) nearest ``car_pose``. Distances use shapely's rules (negative: from the end; past the end: the
    end)."""
    geom = _geometry(track, reverse)
    closest = _closest_object(geom, spawn_dist, objects, obstacles_only=True)
    if closest is not None:
        obstacle_dist, obstacle = closest
        dist = obstacle_dist + ahead_m if ahead_m is not None else obstacle_dist - behind_m
        return _lane_reset_pose(geom, dist, outer=geom.is_inner(obstacle.x, obstacle.y))
    inner = _lane_reset_pose(geom, spawn_dist, outer=False)
    outer = _lane_reset_pose(geom, spawn_dist, outer=True)
    d_inner = math.hypot(inner.x - car_pose.x, inner.y - car_pose.y)
    d_outer = math.hypot(outer.x - car_pose.x, outer.y - car_pose.y)
    return inner if d_inner < d_outer else outer


def start_pose(track: Track, reverse: bool, start_dist: float, objects: Sequence[WorldObject]) -> Pose:
    """Where a training episode starts: simapp ``RolloutCtrl._get_car_start_model_state`` (training branch).

    On the centre line at ``start_dist`` (facing its next vertex), unless an object (obstacle or bot) lies within
    1 m along the centre line: then in the lane the object is not in. The simapp does this before the obstacles
    and bots are reset, so it sees their previous episode's poses. Evaluations start on the centre line regardless."""
    geom = _geometry(track, reverse)
    center = Pose(*geom.center.pose(start_dist, forward=True))
    closest = _closest_object(geom, start_dist, objects, obstacles_only=False)
    if closest is None:
        return center
    obj = closest[1]
    outer = geom.is_inner(obj.x, obj.y)
    lane = geom.outer_lane if outer else geom.inner_lane
    return Pose(*lane.pose(lane.project(center.x, center.y), forward=True))


# ---------------------------------------------------------------------------------------------------------------
# One env's objects over its episodes


class RaceObjects:
    """The obstacles and bot cars of one env, episode after episode: what ``RacerEnv`` calls.

    Obstacles are placed with :func:`place_obstacles` at the gap converted once (``gap_m=None``), not with the
    simapp's shrinking gap (:class:`Obstacles`): the simapp converts MIN_DISTANCE_BETWEEN_OBSTACLES from percent to
    metres again at every reset, so after two episodes its minimum distance is practically 0, which is a bug no
    user asks for (docs/object-avoidance.md)."""

    def __init__(self, track: Track, race: RaceConfig) -> None:
        self.track = track
        self.race = race
        self._bots = BotCars(track, race.head_to_bot) if race.bot_car_count else None
        self.objects: list[WorldObject] = []
        self.crashed_into: WorldObject | None = None
        """The object of the car's last crash (:meth:`crashed` True) this episode."""
        self._reverse = False
        self._car_crashes = 0

    @property
    def crash_count(self) -> int:
        """Crashes into objects this episode: the car's own, and bots that ran into it (which paused them), as the
        simapp's sim-trace ``obstacle_crash_counter`` counts them."""
        return self._car_crashes + (self._bots.crash_count if self._bots else 0)

    @property
    def slots(self) -> int:
        """How many objects this race has in every episode (the world's object slots)."""
        return self.race.obstacle_count + self.race.bot_car_count

    def reset(self, rng: np.random.Generator, reverse: bool) -> list[WorldObject]:
        """New objects for an episode in this direction (the simapp's order: obstacles, then bot cars)."""
        self._reverse = reverse
        self._car_crashes = 0
        self.crashed_into = None
        obstacles = []
        if self.race.obstacle_count:
            obstacles = place_obstacles(self.track, self.race.object_avoidance, rng, reverse)
        bots = self._bots.reset(rng, reverse) if self._bots else []
        self.objects = [*obstacles, *bots]
        return self.objects

    def step(self) -> list[WorldObject]:
        """Move the bot cars one control step (static obstacles stay)."""
        if self._bots:
            obstacles = self.objects[: self.race.obstacle_count]
            self.objects = [*obstacles, *self._bots.step()]
        return self.objects

    def pause(self, seconds: float) -> list[WorldObject]:
        """The car's evaluation pause (simapp ``RolloutCtrl``'s PAUSE phase), in one go: the bots drive on through
        its :func:`pause_steps` steps, as their poses follow the sim time, and the car, held and non-collidable
        (``BlinkEffect``; the bots' ``judge_action`` skips a non-collidable car), neither crashes nor stops them."""
        if self._bots:
            for _ in range(pause_steps(seconds, self._bots.dt)):
                self.step()
        return self.objects

    def crashed(self, car_pose: Pose, car_progress: float, car_start_fraction: float) -> bool:
        """The simapp's crash verdict for the car at this step: touching an obstacle is a crash; touching a bot
        is the car's crash only if the car is behind it (:func:`car_at_fault`), otherwise the bots pause."""
        index = collided_object(car_pose, self.objects)
        if index is None:
            return False
        obj = self.objects[index]
        at_fault = obj.kind != BOT_CAR or car_at_fault(
            car_progress, car_start_fraction, object_progress(self.track, self._reverse, obj)
        )
        if at_fault:
            self._car_crashes += 1
            self.crashed_into = obj
            return True
        if self._bots:
            self._bots.penalize()
        return False
