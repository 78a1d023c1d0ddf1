"""The racing task: start positions, DeepRacer's reward ``params``, episode status and termination.

Kept apart from the physics: it sees the car only through its pose, wheel positions and time.
Positions follow the DeepRacer simapp: ``x, y`` (and everything measured from them) are at the
point 0.14 m ahead of base_link; progress is the distance driven along the centre line since the
start, in percent of a lap, starting from base_link's position at the start waypoint.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sim.physics import FRONT_POINT_M, Pose
from sim.track import Track

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
        self._waypoints = {False: _waypoint_list(track), True: _waypoint_list(self._reversed_track)}
        self.state: EpisodeState | None = None

    def start_pose(self, index: int, reverse: bool) -> Pose:
        """base_link at waypoint ``index`` (of the track in the direction of travel), facing along it."""
        track = self._reversed_track if reverse else self.track
        n_seg = len(track.center) - 1
        i = index % n_seg
        a, b = track.center[i], track.center[i + 1]
        return Pose(float(a[0]), float(a[1]), math.atan2(b[1] - a[1], b[0] - a[0]))

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
        self.state = EpisodeState(track, reverse, start_s, s, _wrap(s - start_s, track), int(proj.segment[0]))

    def observe(
        self,
        pose: Pose,
        wheels: np.ndarray,
        upright: bool,
        sim_time: float,
        command: tuple[float, float],
        count_step: bool = True,
    ) -> StepResult:
        """Params and status after a step (or at the start with ``count_step=False``)."""
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
        params = self._params(st, pose, front, proj, on, progress, sim_time, command)
        status = self._status(st, on, upright, progress) if count_step else Status.PREPARE
        return StepResult(params, status, status in TERMINAL)

    def _progress(self, st: EpisodeState, s: float) -> float:
        track = st.track
        if track.closed:
            return 100.0 * st.travelled / track.length
        if s >= track.length - OPEN_TRACK_END_M:
            return 100.0
        return 100.0 * st.travelled / max(track.length - st.start_s, 1e-6)

    def _status(self, st: EpisodeState, on: np.ndarray, upright: bool, progress: float) -> str:
        if progress >= 100.0:
            return Status.LAP_COMPLETE
        if not on.any():
            return Status.OFF_TRACK
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
        on: np.ndarray,
        progress: float,
        sim_time: float,
        command: tuple[float, float],
    ) -> dict:
        track = st.track
        seg = int(proj.segment[0])
        n = len(track.center)
        nxt = seg + 1 if not (track.closed and seg + 1 == n - 1) else 0
        lateral = float(proj.lateral[0])
        heading = math.degrees(math.atan2(math.sin(pose.yaw), math.cos(pose.yaw)))
        if heading <= -180.0:  # DeepRacer's range is (-180, 180]
            heading += 360.0
        return {
            "all_wheels_on_track": bool(on.all()),
            "x": float(front[0]),
            "y": float(front[1]),
            "heading": heading,
            "distance_from_center": abs(lateral),
            "projection_distance": float(proj.s[0]),
            "progress": float(min(max(progress, 0.0), 100.0)),
            "steps": st.steps,
            "speed": float(command[1]),
            "steering_angle": float(command[0]),
            "track_width": float(track.width_at(proj)[0]),
            "track_length": track.length,
            "waypoints": self._waypoints[st.reversed],
            "closest_waypoints": [seg, nxt],
            "is_left_of_center": lateral > 0,
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


def _wrap(ds: float, track: Track) -> float:
    """Shortest signed arc-length difference (handles crossing the start line of a loop)."""
    if not track.closed:
        return ds
    half = track.length / 2
    return (ds + half) % track.length - half


def _waypoint_list(track: Track) -> list[tuple[float, float]]:
    return [(float(x), float(y)) for x, y in track.center]
