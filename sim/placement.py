"""Where DeepRacer puts the static obstacles of an episode (simapp ``obstacles_agent_ctrl.py: ObstaclesCtrl``).

:func:`place_obstacles` for one episode, :class:`Obstacles` for the simapp's shrinking gap over a worker's life;
:func:`spread` is the simapp's spacing, shared with the bot cars' start (``sim/bots.py``).
"""

from __future__ import annotations

import numpy as np

from common.race import ObjectAvoidanceConfig, ObstacleLane
from sim.lanes import LaneGeometry, lane_geometry
from sim.obstacles import BOT_CAR_OBSTACLE, WorldObject
from sim.track import Track


def spread(
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


def _lane_pose(geom: LaneGeometry, outer: bool, center_dist: float) -> tuple[float, float, float]:
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
    the given lane. Otherwise :func:`spread` with ``gap_m`` (default: the percent converted once, see
    :func:`obstacle_gap_m`). Each obstacle sits on its lane at the point nearest the centre-line point, facing along
    the lane in the direction of travel. ``track`` is the track as loaded (forward)."""
    geom = lane_geometry(track, reverse)
    if cfg.object_positions:
        dists = [p.progress * geom.center.length for p in cfg.object_positions]
        outer = [p.lane == ObstacleLane.OUTER for p in cfg.object_positions]
    else:
        gap = obstacle_gap_m(cfg, geom.center.length) if gap_m is None else gap_m
        dists, outer = spread(geom.center.length, cfg.count, gap, cfg.randomize_obstacle_locations, rng)
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
