"""The reward function's object params: simapp ``track_geom/track_data.py: TrackData.get_object_reward_params``.

:func:`object_params` with objects (without, the task's params keep the simapp's defaults: ``sim/task.py``);
``object_in_camera`` uses the simapp's camera frustum (:func:`in_camera_view`, ``markov/cameras/frustum.py``).
``is_crashed`` comes from the crash rule (``sim/race_rules.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import lru_cache

import numpy as np
import shapely

from sim.lanes import LaneGeometry, find_prev_next, lane_geometry
from sim.obstacles import BOT_CAR, WorldObject, rect_corners
from sim.physics import FRONT_POINT_M, Pose
from sim.track import Track

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
        corners = rect_corners(o.x, o.y, o.yaw, fp.crash_length, fp.crash_width)
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


@lru_cache(maxsize=64)
def _object_geometry(
    geom: LaneGeometry, locations: tuple[tuple[float, float], ...]
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
    geom = lane_geometry(track, reverse)
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
    prev_i, next_i = find_prev_next([pdists[i] for i in order], model_pdist)
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
