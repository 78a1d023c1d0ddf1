"""DeepRacer's bot cars in motion: the simapp's ``bot_cars_agent_ctrl.py: BotCarsCtrl`` without Gazebo.

Each bot drives its lane on a cubic spline, changes lanes on lane-change splines (``track_geom/spline/*.py``) and
pauses when it runs into the car (:meth:`BotCars.penalize`, :func:`pause_steps`). ``docs/object-avoidance.md`` has
the notes.
"""

from __future__ import annotations

import bisect
import math
from functools import lru_cache

import numpy as np
from scipy.interpolate import spalde, splprep

from common.errors import UserError
from common.race import HeadToBotConfig
from sim.lanes import LaneGeometry, TrackLine, lane_geometry
from sim.obstacles import BOT_CAR, WorldObject
from sim.physics import FRONT_POINT_M, Pose
from sim.placement import spread
from sim.track import Track
from sim.world import CONTROL_HZ

CONTROL_DT_S = 1.0 / CONTROL_HZ
"""One control step, seconds: how far the bot cars' clock moves per :meth:`BotCars.step`."""
_SPLINE_DEGREE = 3  # simapp track_geom/constants.py: SPLINE_DEGREE
_DIST_THRESHOLD_M = 0.02  # simapp track_geom/constants.py: DIST_THRESHOLD


class RaceSetupError(UserError, ValueError):
    """A race the simapp's code cannot run sensibly (the message says why)."""


def pause_steps(seconds: float, dt: float = CONTROL_DT_S) -> int:
    """Control steps a pause of ``seconds`` lasts in the simapp: its pauses (the bots' ``BotCarsCtrl.pause_duration``,
    the car's ``RolloutCtrl._pause_duration``) count down by the sim time each step and end at the first
    ``judge_action`` that finds them <= 0, which is one step after a 0 s pause. ``seconds / dt`` is rounded off
    first: 2.0 / (1/15) is 30.000000000000004 in floating point, and the simapp's count ends on the 30th step."""
    return max(1, math.ceil(round(seconds / dt, 6)))


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

    def __init__(self, geom: LaneGeometry, lane: TrackLine) -> None:
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
        geom: LaneGeometry,
        start: _LaneSpline,
        end: _LaneSpline,
        *,
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
        self._geom = lane_geometry(self.track, reverse)
        inner, outer = _lane_splines(self.track, reverse)
        self.time, self.crash_count, self._pause_left = 0.0, 0, 0
        n = self.cfg.number_of_bot_cars
        dists, use_outer = spread(
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
                current_dist=self.distance(i),
                start_dist=self.distance(i, start_time),
                end_dist=self.distance(i, end_time),
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
    geom = lane_geometry(track, reverse)
    return _LaneSpline(geom, geom.inner_lane), _LaneSpline(geom, geom.outer_lane)


def object_progress(track: Track, reverse: bool, obj: WorldObject) -> float:
    """A bot's progress, percent: where its front point (0.14 m ahead of its pose) projects onto the centre line,
    as a share of the lap (simapp ``BotCarsCtrl.update_agent``; ``start_ndist`` 0)."""
    geom = lane_geometry(track, reverse)
    front = Pose(obj.x, obj.y, obj.yaw).ahead(FRONT_POINT_M)
    return float(geom.center_s(front)[0]) / geom.length * 100.0
