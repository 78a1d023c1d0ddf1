"""The racing task: start positions, DeepRacer's reward ``params``, episode status and termination.

Kept apart from the physics: it sees the car only through its pose, wheel positions and time.
Positions follow the DeepRacer simapp: ``x, y`` (and everything measured from them) are at the
point 0.14 m ahead of base_link; progress is the distance driven along the centre line since the
start, in percent of a lap, starting from base_link's position at the start waypoint.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import KW_ONLY, dataclass, field

import numpy as np

from sim.object_params import object_params
from sim.obstacles import WorldObject
from sim.physics import FRONT_POINT_M, Pose
from sim.track import Segment, Track, nearest_segment, polyline_segments

REVERSED_WINDOW_STEPS = 15
"""Window (steps, 1 s at 15 Hz) over which going backwards or standing still ends an episode."""
REVERSED_DISTANCE_M = 0.1
"""Going this far backwards along the track within the window ends the episode as "reversed"."""
IMMOBILIZED_DISTANCE_M = 0.03
"""Moving less than this within the window ends the episode as "immobilized"."""
OPEN_TRACK_END_M = 0.02
"""On an open track the lap is complete when the car's front is this close to the end."""


class Status:
    """DeepRacer's episode_status values."""

    PREPARE = "prepare"
    IN_PROGRESS = "in_progress"
    OFF_TRACK = "off_track"
    CRASHED = "crashed"
    IMMOBILIZED = "immobilized"
    REVERSED = "reversed"
    LAP_COMPLETE = "lap_complete"
    TIME_UP = "time_up"


TERMINAL = {Status.OFF_TRACK, Status.CRASHED, Status.IMMOBILIZED, Status.REVERSED, Status.LAP_COMPLETE}


@dataclass
class EpisodeState:
    """What the task remembers within an episode."""

    track: Track
    """The track in this episode's direction of travel."""
    reversed: bool
    start_s: float
    """Arc length of the start waypoint (base_link's start), metres."""
    _: KW_ONLY
    last_s: float
    travelled: float
    """Distance of the front point along the centre line from the start position, metres."""
    segment: int = 0
    """Centre-line segment closest to the front point at the last step (search hint)."""
    steps: int = 0
    history: deque = field(default_factory=lambda: deque(maxlen=REVERSED_WINDOW_STEPS + 1))


@dataclass(frozen=True)
class StepResult:
    """The task's view of one step."""

    params: dict
    status: str
    terminated: bool


class RacingTask:
    """DeepRacer's racing task on one track."""

    def __init__(self, track: Track, road: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        """``road`` tells which points are on the road (default: the exact polygon test of the track)."""
        self.track = track
        self._road = road or track.on_track
        self._reversed_track = track.reversed()
        self._lines = {False: _WaypointLine(track, False), True: _WaypointLine(self._reversed_track, True)}
        self._borders = {
            reverse: (polyline_segments(t.inner), polyline_segments(t.outer))
            for reverse, t in ((False, track), (True, self._reversed_track))
        }
        self.state: EpisodeState | None = None

    @property
    def steps(self) -> int:
        """Env steps taken in this episode (DeepRacer's ``steps`` param is one more: it counts the prepare step)."""
        return 0 if self.state is None else self.state.steps

    def start_pose(self, index: int, reverse: bool) -> Pose:
        """base_link at waypoint ``index`` (of the track in the direction of travel), facing along it."""
        track = self._reversed_track if reverse else self.track
        n_seg = len(track.center) - 1
        i = index % n_seg
        a, b = track.center[i], track.center[i + 1]
        return Pose(float(a[0]), float(a[1]), math.atan2(b[1] - a[1], b[0] - a[0]))

    def start_distance(self, index: int, reverse: bool) -> float:
        """Arc length of waypoint ``index`` along the centre line in the direction of travel, metres."""
        track = self._reversed_track if reverse else self.track
        return float(track.cumulative[index % (len(track.center) - 1)])

    @property
    def start_fraction(self) -> float:
        """Where this episode started, as a fraction of the lap from the start line in the direction of travel
        (the simapp's ``start_ndist``)."""
        st = self.state
        return 0.0 if st is None else st.start_s / st.track.length

    def start_indices(self, reverse: bool) -> int:
        """How many waypoints an episode may start from (open tracks: those in the first 70 %)."""
        track = self._reversed_track if reverse else self.track
        if track.closed:
            return len(track.center) - 1
        return max(1, int(np.searchsorted(track.cumulative, 0.7 * track.length)))

    def begin(self, index: int, reverse: bool) -> None:
        """Start an episode at waypoint ``index`` of the chosen direction."""
        track = self._reversed_track if reverse else self.track
        i = index % (len(track.center) - 1)
        start_s = float(track.cumulative[i])
        front = self.start_pose(index, reverse).ahead(FRONT_POINT_M)
        proj = track.project(front[None])
        s = float(proj.s[0])
        self.state = EpisodeState(
            track, reverse, start_s, last_s=s, travelled=_wrap(s - start_s, track), segment=int(proj.segment[0])
        )

    def relocate(self, pose: Pose) -> None:
        """The car was put back on the track (an evaluation reset): progress goes on from where its front point is
        now (back a little, behind an obstacle), and the reversed/immobilized window starts afresh."""
        st = self.state
        assert st is not None, "begin() an episode first"
        front = pose.ahead(FRONT_POINT_M)
        proj = st.track.project(front[None])
        s = float(proj.s[0])
        st.travelled += _wrap(s - st.last_s, st.track)
        st.last_s, st.segment = s, int(proj.segment[0])
        st.history.clear()

    def observe(
        self,
        pose: Pose,
        wheels: np.ndarray,
        upright: bool,
        sim_time: float,
        command: tuple[float, float],
        *,
        count_step: bool = True,
        objects: Sequence[WorldObject] = (),
        crashed: bool = False,
    ) -> StepResult:
        """Params and status after a step (or at the start with ``count_step=False``).

        ``objects`` are the obstacles and bot cars of an object-avoidance or head-to-bot race (their params are
        the simapp's, ``sim/object_params.py: object_params``); ``crashed`` is the env's verdict of the crash rule
        (``sim/race_rules.py: collided_object`` and, for a bot, ``car_at_fault``), which ends the episode."""
        st = self.state
        assert st is not None, "begin() an episode first"
        track = st.track
        front = pose.ahead(FRONT_POINT_M)
        proj = track.project_point(float(front[0]), float(front[1]), hint=st.segment)
        s = float(proj.s[0])
        st.segment = int(proj.segment[0])
        st.travelled += _wrap(s - st.last_s, track)
        st.last_s = s
        if count_step:
            st.steps += 1
        st.history.append((st.travelled, pose.x, pose.y))
        on = self._road(wheels)
        progress = self._progress(st, s)
        params = self._params(st, pose, front, proj, on=on, progress=progress, sim_time=sim_time, command=command)
        if objects:
            params.update(object_params(self.track, pose, objects, st.reversed, model_s=s))
        params["is_crashed"] = bool(crashed)
        status = self._status(st, on, upright, progress, crashed) if count_step else Status.PREPARE
        return StepResult(params, status, status in TERMINAL)

    def _progress(self, st: EpisodeState, s: float) -> float:
        track = st.track
        if track.closed:
            return 100.0 * st.travelled / track.length
        if s >= track.length - OPEN_TRACK_END_M:
            return 100.0
        return 100.0 * st.travelled / max(track.length - st.start_s, 1e-6)

    def _status(self, st: EpisodeState, on: np.ndarray, upright: bool, progress: float, crashed: bool) -> str:
        # The simapp's reset rules, in its order (markov/reset/utils.py: construct_reset_rules_manager): lap
        # complete, immobilized, off track, crashed, reversed; racer's immobilized test needs the window below.
        if progress >= 100.0:
            return Status.LAP_COMPLETE
        if not on.any():
            return Status.OFF_TRACK
        if crashed:
            return Status.CRASHED
        if not upright:
            return Status.IMMOBILIZED
        if len(st.history) > REVERSED_WINDOW_STEPS:
            t0, x0, y0 = st.history[0]
            t1, x1, y1 = st.history[-1]
            if t1 - t0 < -REVERSED_DISTANCE_M:
                return Status.REVERSED
            if math.hypot(x1 - x0, y1 - y0) < IMMOBILIZED_DISTANCE_M:
                return Status.IMMOBILIZED
        return Status.IN_PROGRESS

    def _params(
        self,
        st: EpisodeState,
        pose: Pose,
        front: np.ndarray,
        proj,
        *,
        on: np.ndarray,
        progress: float,
        sim_time: float,
        command: tuple[float, float],
    ) -> dict:
        track = st.track
        line = self._lines[st.reversed]
        lateral = float(proj.lateral[0])
        s = float(proj.s[0])
        foot = _foot(track, proj)
        inner_segments, outer_segments = self._borders[st.reversed]
        inner = _nearest_on_border(inner_segments, foot, int(proj.segment[0]), track.closed)
        outer = _nearest_on_border(outer_segments, foot, int(proj.segment[0]), track.closed)
        heading = math.degrees(math.atan2(math.sin(pose.yaw), math.cos(pose.yaw)))
        if heading <= -180.0:  # DeepRacer's range is (-180, 180]
            heading += 360.0
        x, y = float(front[0]), float(front[1])
        nearer_inner = math.hypot(x - inner[0], y - inner[1]) < math.hypot(x - outer[0], y - outer[1])
        return {
            "all_wheels_on_track": bool(on.all()),
            "x": x,
            "y": y,
            "heading": heading,
            "distance_from_center": abs(lateral),
            "projection_distance": s,
            "progress": float(min(max(progress, 0.0), 100.0)),
            # DeepRacer counts the prepare step (the car held at the start, never rewarded) as step 1.
            "steps": st.steps + 1,
            "speed": float(command[1]),
            "steering_angle": float(command[0]),
            "track_width": math.hypot(inner[0] - outer[0], inner[1] - outer[1]),
            "track_length": track.length,
            "waypoints": line.waypoints,
            "closest_waypoints": line.closest(s),
            # simapp: left of centre = nearer the inner border than the outer one, flipped on a clockwise lap.
            "is_left_of_center": nearer_inner ^ (not line.ccw),
            "is_reversed": st.reversed,
            "is_crashed": False,
            "is_offtrack": not bool(on.any()),
            "closest_objects": [0, 0],
            "objects_location": [],
            "objects_left_of_center": [],
            "object_in_camera": False,
            "objects_speed": [],
            "objects_heading": [],
            "objects_distance_from_center": [],
            "objects_distance": [],
            "sim_time": float(sim_time),
        }


class _WaypointLine:
    """The reward function's ``waypoints`` and ``closest_waypoints`` for one direction, computed as the simapp does.

    simapp (``markov/track_geom/track_data.py``, ``TrackLine`` and ``find_prev_next`` in ``track_geom/utils.py``):
    the waypoints are the sanitized route's centre-line rows (``Track.waypoints``) in the direction of travel, a
    loop's closing row included; ``closest_waypoints`` is ``[i, i + 1]`` for the row pair whose arc-length
    interval holds the car's projection, found with ``bisect_right``, so a car projecting exactly onto waypoint i gets
    ``[i, i + 1]``, on a loop's last segment ``[n - 2, n - 1]``, and ``[n - 1, 0]`` only at the very end.
    """

    def __init__(self, track: Track, reverse: bool) -> None:
        rows = track.waypoints[:, :2]
        self.waypoints = [(float(x), float(y)) for x, y in rows]
        seg = np.linalg.norm(np.diff(rows, axis=0), axis=1)
        # The same sums, in the same order, as Track.cumulative (a repeated row adds 0.0), so a projection that
        # lands on a vertex compares equal to that vertex's distance, as shapely's project() does in the simapp.
        self._dists = np.concatenate([[0.0], np.cumsum(seg)]).tolist()
        self._dists[-1] = max(self._dists[-1], track.length)
        # simapp: is_ccw is the forward centre line's orientation (True for an open track), flipped when reversed;
        # ``track`` is already in the direction of travel, so for a loop that is its own orientation.
        self.ccw = not track.clockwise if track.closed else not reverse

    def closest(self, s: float) -> list[int]:
        """``[prev, next]`` waypoint indices around arc length ``s`` (metres along this direction)."""
        n = len(self._dists)
        nxt = bisect.bisect_right(self._dists, s)
        prev = nxt - 1 if nxt > 0 else n - 1
        return [prev, 0 if nxt == n else nxt]


def _foot(track: Track, proj) -> tuple[float, float]:
    """The centre-line point a projection landed on."""
    i, t = int(proj.segment[0]), float(proj.t[0])
    a, b = track.center[i], track.center[i + 1]
    return float(a[0] + t * (b[0] - a[0])), float(a[1] + t * (b[1] - a[1]))


_BORDER_WINDOW = 6


def _nearest_on_border(
    segments: list[Segment], point: tuple[float, float], hint: int, closed: bool
) -> tuple[float, float]:
    """The point of a border polyline nearest ``point`` (shapely's ``interpolate(project(point))`` in the simapp).

    Searched within six segments either side of the centre line's segment (border row i faces centre row i on most
    routes), and over the whole border when the nearest lies at the window's edge: on routes whose borders are
    sampled apart from the centre line (Tokyo_Training_track) it lies further on, and shapely searches it all."""
    n, window = len(segments), _BORDER_WINDOW
    j, t, _, _ = nearest_segment(segments, point[0], point[1], hint, window=window, closed=closed)
    if 2 * window + 1 < n:
        lo, hi = hint - window, hint + window
        at_edge = (j - lo) % n == 0 or (hi - j) % n == 0 if closed else j in (max(lo, 0), min(hi, n - 1))
        if at_edge:
            j, t, _, _ = nearest_segment(segments, point[0], point[1], hint, window=n, closed=closed)
    sx, sy, vx, vy, _ = segments[j]
    return sx + t * vx, sy + t * vy


def _wrap(ds: float, track: Track) -> float:
    """Shortest signed arc-length difference (handles crossing the start line of a loop)."""
    if not track.closed:
        return ds
    half = track.length / 2
    return (ds + half) % track.length - half
