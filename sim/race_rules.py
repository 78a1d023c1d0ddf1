"""DeepRacer's race rules with objects: the crash rule, who is at fault, where the car starts and is put back, the
evaluation pause, and :class:`RaceObjects`, which runs them for one env episode after episode.

simapp ``rollout_agent_ctrl.py: RolloutCtrl`` and ``track_data.py: get_collided_object_name``; each function names
the simapp function it follows. ``docs/object-avoidance.md`` has the notes (edge cases, simapp bugs kept).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from common.race import RaceConfig
from sim.bots import BotCars, object_progress, pause_steps
from sim.lanes import LaneGeometry, lane_geometry
from sim.obstacles import BOT_CAR, CAR_CRASH_LENGTH_M, CAR_CRASH_WIDTH_M, WorldObject, rect_corners
from sim.physics import Pose
from sim.placement import place_obstacles
from sim.track import Track

CLOSEST_OBJ_GAP_M = 1.0
"""simapp ``agent_ctrl/constants.py: CLOSEST_OBJ_GAP``: an object this close along the centre line to a start or
reset point moves the car to the other lane."""


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
    corners = rect_corners(car_pose.x, car_pose.y, car_pose.yaw, CAR_CRASH_LENGTH_M, CAR_CRASH_WIDTH_M)
    for i, obj in enumerate(objects):
        if _contains(obj, corners):
            return i
    return None


def is_crashed(car_pose: Pose, objects: Sequence[WorldObject]) -> bool:
    """The simapp's crash rule (:func:`collided_object`): True if the car touches any object."""
    return collided_object(car_pose, objects) is not None


def _closest_object(
    geom: LaneGeometry, dist: float, objects: Sequence[WorldObject], obstacles_only: bool
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


def _lane_reset_pose(geom: LaneGeometry, center_dist: float, outer: bool) -> Pose:
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
    geom = lane_geometry(track, reverse)
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
    geom = lane_geometry(track, reverse)
    center = Pose(*geom.center.pose(start_dist, forward=True))
    closest = _closest_object(geom, start_dist, objects, obstacles_only=False)
    if closest is None:
        return center
    obj = closest[1]
    outer = geom.is_inner(obj.x, obj.y)
    lane = geom.outer_lane if outer else geom.inner_lane
    return Pose(*lane.pose(lane.project(center.x, center.y), forward=True))


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
