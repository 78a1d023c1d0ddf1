"""DeepRacer's LIDAR, SECTOR_LIDAR and DISCRETIZED_SECTOR_LIDAR sensors, cast with MuJoCo rays.

What DeepRacer's simulation does (aws-deepracer-community/deepracer-simapp, files under ``bundle/``):

- The scan. ``urdf/deepracer/racecar.gazebo`` puts a Gazebo ``gpu_lidar`` (``ray`` before the ROS 2 port) on the
  ``laser`` link at 10 Hz with 64 samples from -2.61799 to 2.61799 rad, range 0.15-12 m (range resolution 0.01),
  Gaussian noise mean 0, stddev 0.01 (the values ``src/deepracer_simulation_environment/launch/racecar.launch.py``
  passes, the same as ``markov/sensors/constants.py``: ``LIDAR_360_DEGREE_*``). The ``laser`` link is mounted by
  ``hokuyo_joint`` at xyz (0.02913, 0, 0.16145) rpy (0, 0, 3.1416) on ``chassis``, itself 0.023249 above
  ``base_link`` (``urdf/deepracer/deepracer_*_lidar.urdf``). The sensor is turned half a turn: sample 0 looks 30°
  left of straight ahead and the samples sweep anticlockwise through left, behind and right to 30° right of
  ahead; the 60° blind cone is straight ahead (where the cameras look).
- The ranges (Gazebo Harmonic: gz-rendering 8 ``ogre2/src/Ogre2GpuRays.cc`` and
  ``ogre2/.../gpu_rays_1st_pass_fs.glsl``, gz-sensors 8 ``src/GpuLidarSensor.cc`` and ``src/Lidar.cc``): the sensor
  renders a cube map whose near clip is min range / sqrt(3) along each face's axis, and its shader reads a hit
  beyond the max range as +inf and one nearer than the min range as -inf (``SetClamp(false)``: REP 117's "too
  close"); geometry inside the near clip is not drawn at all. ``Lidar::ApplyNoise`` adds the noise to every range
  and clamps the finite ones to [min, max]; ±inf stay infinite through ``PublishLidarScan`` and the ROS bridge. No
  step applies ``<range><resolution>`` (gz-sensors only returns it from ``Lidar::RangeResolution``): ranges are not
  quantized to 0.01 m.
- LIDAR observation: ``markov/sagemaker_graph_manager.py`` adds ``ObservationClippingFilter(0.15, 1.0)``
  (``rl_coach/filters/observation/observation_clipping_filter.py``: ``np.clip``) to the 64 ranges
  (``markov/sensors/sensors_rollout.py: Lidar._scan_cb`` keeps ``LaserScan.ranges`` as they are), so a miss
  reads 1.0 and an object nearer than 0.15 m reads 0.15; observation space (64,) in [0.15, 1.0]
  (``markov/sensors/utils.py``, ``TRAINING_LIDAR_SIZE`` in ``markov/environments/constants.py``).
- SECTOR_LIDAR: the same scan through ``ObservationSectorDiscretizeFilter(num_sectors=8, num_values_per_sector=1,
  clipping_dist=0.5)`` (``NUMBER_OF_LIDAR_SECTORS``, ``SECTOR_LIDAR_CLIPPING_DIST`` in
  ``markov/environments/constants.py``; ``markov/filters/observation/observation_sector_discretize_filter.py``):
  infinite ranges (either sign) become 0.5 first, then the minimum of each run of 8 consecutive samples, 1.0 where
  it is below 0.5 m, else 0.0; shape (8,). An object nearer than 0.15 m is therefore not seen by SECTOR_LIDAR.
- DISCRETIZED_SECTOR_LIDAR: the same filter with the model metadata's sectors, values per sector and clipping
  distance (``markov/boto/s3/files/model_metadata.py``).

Here the scan is a batch of horizontal MuJoCo rays (``mj_multiRay``) from the sensor at its height above the
ground, from the car's planar pose (as :class:`sim.camera.GroundCamera`): the ground plane is never hit, and only
the object slots (geom group :data:`sim.world.OBJECT_GEOM_GROUP`, see :func:`sim.world.set_objects`) are tested,
so the car never sees itself. The scene holds only the track and those objects: nothing else stands at lidar
height (DeepRacer's worlds may have walls or buildings there). Boxes lower than the sensor
(:attr:`LidarSpec.height_m`, 0.185 m) are not seen, as in DeepRacer. A sensor inside a box (the car overlapping
it: a crash) reads the box's far side where Gazebo would see through it, and a hit inside the cube map's near clip
reads +inf without looking behind it (only an object overlapping the car's body is that near: the car's sides are
0.098 m from the sensor, the clip at most 0.087 m along a face's axis). :func:`analytic_ranges` is the same scan
computed in closed form (ray against oriented box), the reference the tests hold the MuJoCo cast to.

The env calls, each step after the physics (and after :func:`sim.world.set_objects` when objects moved)::

    ranges = lidar.scan(physics.pose, np_random)  # one Lidar for either sensor
    obs = lidar_from_ranges(obs_spec.lidar.name, ranges)
    # LIDAR: (64,) float32 in [0.15, 1.0]; SECTOR_LIDAR: (8,) float32 of 0.0 / 1.0

DeepRacer's lidar publishes at 10 Hz and its agent takes the latest scan without waiting
(``markov/sensors/sensors_rollout.py: Lidar.get_state``: a non-blocking get from a buffer that is not cleared on
get, blocking only when it is empty, as after ``reset``), so at 15 Hz one step in three repeats the previous scan:
the env scans only when :func:`scan_due` says a new one has arrived, and repeats the last one otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from common.defaults import DEFAULT_TRACK
from common.sensors import LIDAR, LIDAR_MAX_RANGE_M, LIDAR_MIN_RANGE_M, LIDAR_SAMPLES, lidar_from_ranges
from sim.physics import Pose
from sim.world import CONTROL_HZ, OBJECT_GEOM_GROUP

LIDAR_MIN_ANGLE = -2.61799
"""Radians, in the laser frame (``LIDAR_360_DEGREE_MIN_ANGLE``)."""
LIDAR_MAX_ANGLE = 2.61799
"""Radians, in the laser frame (``LIDAR_360_DEGREE_MAX_ANGLE``)."""
LIDAR_MIN_RANGE = LIDAR_MIN_RANGE_M
LIDAR_MAX_RANGE = LIDAR_MAX_RANGE_M
LIDAR_NOISE_STDDEV = 0.01
"""Metres, Gaussian, mean 0 (``LIDAR_360_DEGREE_NOISE_STDDEV``, ``_MEAN``)."""
LIDAR_HZ = 10.0
"""Scan rate (``update_rate`` in urdf/deepracer/racecar.gazebo); the camera's is 15 Hz."""


def scan_due(step: int, control_hz: float = CONTROL_HZ) -> bool:
    """Whether a new scan has arrived by control step ``step`` of an episode (0: the reset, whose first get waits
    for one). Scans come every 1 / LIDAR_HZ s from the reset; steps come every 1 / control_hz s, so at 15 Hz steps
    1, 4, 7… see no new scan and repeat the last."""
    if step <= 0:
        return True
    return (step * LIDAR_HZ) // control_hz > ((step - 1) * LIDAR_HZ) // control_hz


_CHASSIS_ABOVE_BASE_M = 0.023249  # base_link_joint, urdf/deepracer/deepracer_*_lidar.urdf
_LASER_ON_CHASSIS = (0.02913, 0.0, 0.16145)  # hokuyo_joint xyz, ditto; rpy (0, 0, 3.1416)


@dataclass(frozen=True)
class LidarSpec:
    """The scan's geometry and noise; defaults are DeepRacer's (module docstring).

    The mount is relative to this repository's base_link (midway between the axles) on the ground: DeepRacer's
    ``base_link`` is at ground level (its bot car, ``models/bot_car/model.sdf``, has the rear axle 0.039 m up) and
    0.3 mm behind the axles' midpoint, which is neglected."""

    samples: int = LIDAR_SAMPLES
    min_angle: float = LIDAR_MIN_ANGLE
    max_angle: float = LIDAR_MAX_ANGLE
    min_range: float = LIDAR_MIN_RANGE
    max_range: float = LIDAR_MAX_RANGE
    noise_stddev: float = LIDAR_NOISE_STDDEV
    forward_m: float = _LASER_ON_CHASSIS[0]
    """Sensor ahead of base_link, metres."""
    left_m: float = _LASER_ON_CHASSIS[1]
    height_m: float = _CHASSIS_ABOVE_BASE_M + _LASER_ON_CHASSIS[2]
    """Sensor above the ground, metres (0.1847)."""
    yaw: float = 3.1416
    """Sensor frame's rotation on the car, radians (hokuyo_joint's rpy: it looks backwards)."""

    def angles(self) -> np.ndarray:
        """(samples,) ray directions in the car frame, radians anticlockwise from ahead, in scan order."""
        return self.yaw + np.linspace(self.min_angle, self.max_angle, self.samples)

    def face_cos(self) -> np.ndarray:
        """(samples,) cosine between each ray and the axis of the cube-map face that draws it (faces along the
        sensor frame's axes, every 90°): a hit's depth on that face is its range times this."""
        laser = np.linspace(self.min_angle, self.max_angle, self.samples)
        return np.cos((laser + math.pi / 4) % (math.pi / 2) - math.pi / 4)


class Lidar:
    """DeepRacer's LIDAR: 64 ranges clipped to [0.15, 1.0] m, cast against the object slots of ``model``."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, spec: LidarSpec | None = None) -> None:
        self.model, self.data = model, data
        self.spec = spec or LidarSpec()
        n = self.spec.samples
        self._angles = self.spec.angles()
        self._groups = np.zeros(6, np.uint8)
        self._groups[OBJECT_GEOM_GROUP] = 1
        self._car = model.body("car").id if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "car") >= 0 else -1
        self._vec = np.zeros((n, 3))
        self._dist = np.empty(n)
        self._geom = np.empty(n, np.int32)
        self._pnt = np.empty(3)

    def scan(self, pose: Pose, rng: np.random.Generator | None = None) -> np.ndarray:
        """The raw scan (DeepRacer's ``LaserScan.ranges``): (samples,) float32 metres in [min, max range], +inf
        where nothing is hit, -inf where a hit is nearer than the min range; Gaussian noise drawn from ``rng`` (none
        without one), then the finite ranges clamped (gz-sensors)."""
        s = self.spec
        c, si = math.cos(pose.yaw), math.sin(pose.yaw)
        self._pnt[:] = (pose.x + c * s.forward_m - si * s.left_m, pose.y + si * s.forward_m + c * s.left_m, s.height_m)
        world = self._angles + pose.yaw
        self._vec[:, 0] = np.cos(world)
        self._vec[:, 1] = np.sin(world)
        mujoco.mj_multiRay(
            self.model,
            self.data,
            self._pnt,
            self._vec.reshape(-1),
            self._groups,
            1,
            self._car,
            self._geom,
            self._dist,
            None,
            s.samples,
            s.max_range,
        )
        return _finish(self._dist, s, rng)

    def observe(self, pose: Pose, rng: np.random.Generator | None = None) -> np.ndarray:
        """The LIDAR observation: (64,) float32 in [0.15, 1.0] (``common/sensors.py: lidar_from_ranges``)."""
        return lidar_from_ranges(LIDAR, self.scan(pose, rng))


def _finish(dist: np.ndarray, spec: LidarSpec, rng: np.random.Generator | None) -> np.ndarray:
    """Ray distances (-1 = no hit) to a DeepRacer scan (module docstring): a miss, or a hit inside the cube map's
    near clip, is +inf; a hit nearer than the min range is -inf; then the noise (infinities stay) and the clamp of
    the finite ranges to [min, max] range (gz-sensors' order)."""
    clipped = dist * spec.face_cos() < spec.min_range / math.sqrt(3.0)
    ranges = np.where((dist < 0) | clipped | (dist > spec.max_range), np.inf, dist)
    ranges = np.where(ranges < spec.min_range, -np.inf, ranges)
    if rng is not None and spec.noise_stddev > 0:
        ranges = ranges + rng.normal(0.0, spec.noise_stddev, ranges.shape)
    finite = np.isfinite(ranges)
    ranges[finite] = np.clip(ranges[finite], spec.min_range, spec.max_range)
    return ranges.astype(np.float32)


def analytic_ranges(
    origin: np.ndarray, angles: np.ndarray, boxes: np.ndarray, height: float, max_range: float = np.inf
) -> np.ndarray:
    """Reference scan in closed form: distance from ``origin`` (x, y) along each world angle to the nearest box of
    ``boxes`` ((K, 6) ``[x, y, yaw, length, width, height]``) standing taller than ``height``, -1 for none
    within ``max_range``. A ray starting inside a box hits its far side (MuJoCo's convention)."""
    origin = np.asarray(origin, np.float64)
    d = np.stack([np.cos(angles), np.sin(angles)], axis=-1)  # (n, 2)
    best = np.full(len(d), np.inf)
    for x, y, yaw, length, width, h in np.asarray(boxes, np.float64).reshape(-1, 6):
        if h <= height:
            continue
        c, s = math.cos(yaw), math.sin(yaw)
        axes = np.array([[c, s], [-s, c]])  # rows: the box's x and y axes
        p = axes @ (origin - (x, y))  # origin in the box frame
        v = d @ axes.T  # directions in the box frame, (n, 2)
        half = np.array([length / 2, width / 2])
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - p) / v
            t2 = (half - p) / v
        lo = np.where(v == 0, np.where(np.abs(p) <= half, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=1)
        hi = np.where(v == 0, np.where(np.abs(p) <= half, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=1)
        t = np.where(lo >= 0, lo, hi)  # entering, or leaving when starting inside
        hit = (lo <= hi) & (t >= 0)
        best = np.where(hit & (t < best), t, best)
    return np.where(np.isfinite(best) & (best <= max_range), best, -1.0)


def analytic_scan(
    pose: Pose, boxes: np.ndarray, spec: LidarSpec | None = None, rng: np.random.Generator | None = None
) -> np.ndarray:
    """:meth:`Lidar.scan` computed with :func:`analytic_ranges` instead of MuJoCo (no model needed)."""
    s = spec or LidarSpec()
    c, si = math.cos(pose.yaw), math.sin(pose.yaw)
    origin = (pose.x + c * s.forward_m - si * s.left_m, pose.y + si * s.forward_m + c * s.left_m)
    dist = analytic_ranges(np.array(origin), s.angles() + pose.yaw, boxes, s.height_m, s.max_range)
    return _finish(dist, s, rng)


def _bench(calls: int = 1000, repeats: int = 5) -> None:
    """``python -m sim.lidar``: median time per call of the new sensors (pin it: ``taskset -c 1``), wall clock
    and this thread's CPU time (the latter is steadier on a shared machine)."""
    import statistics
    import time

    import cv2

    from sim.camera import GroundCamera, StereoGroundCamera
    from sim.physics import CarPhysics
    from sim.texture import DEEPRACER_PALETTE, TextureFrame, colorize, draw_layers
    from sim.track import load_track
    from sim.world import build_model, set_objects

    cv2.setNumThreads(1)
    track = load_track(DEFAULT_TRACK)
    frame = TextureFrame.for_track(track)
    texture = colorize(draw_layers(track, frame), DEEPRACER_PALETTE)
    model = build_model(frame, object_slots=6)
    physics = CarPhysics(model)
    x, y = track.center[3]
    dx, dy = track.center[4] - track.center[3]
    pose = Pose(float(x), float(y), math.atan2(dy, dx))
    physics.reset(pose)
    c, s = math.cos(pose.yaw), math.sin(pose.yaw)
    # Six DeepRacer box obstacles around the car, four of them in the camera's view.
    placed = [(1.0, 0.1, 0.3), (2.0, -0.4, 0.8), (0.6, 0.35, 0.0), (-1.0, 0.2, 0.0), (4.0, 1.5, 0.2), (-3.0, -0.5, 0.0)]
    boxes = np.array(
        [[pose.x + c * f - s * le, pose.y + s * f + c * le, pose.yaw + r, 0.4, 0.3, 0.25] for f, le, r in placed]
    )
    set_objects(model, physics.data, boxes)
    lidar, rng = Lidar(model, physics.data), np.random.default_rng(0)
    single = GroundCamera(frame, texture, sky_rgb=DEEPRACER_PALETTE.sky)
    stereo = StereoGroundCamera(frame, texture, sky_rgb=DEEPRACER_PALETTE.sky)
    cases = {
        "lidar scan + LIDAR obs, 6 boxes": lambda: lidar.observe(pose, rng),
        "stereo render, 6 boxes": lambda: stereo.render(pose, boxes=boxes),
        "stereo render, 0 boxes": lambda: stereo.render(pose),
        "single render, 0 boxes (today)": lambda: single.render(pose),
        "single render, 6 boxes": lambda: single.render(pose, boxes=boxes),
        "set_objects, 6 boxes": lambda: set_objects(model, physics.data, boxes),
    }
    wall: dict[str, list[float]] = {name: [] for name in cases}
    cpu: dict[str, list[float]] = {name: [] for name in cases}
    for fn in cases.values():
        fn()
    for _ in range(repeats):  # interleaved, so that a change in the machine's load hits every case alike
        for name, fn in cases.items():
            t0, c0 = time.perf_counter(), time.thread_time()
            for _ in range(calls):
                fn()
            wall[name].append((time.perf_counter() - t0) / calls * 1e6)
            cpu[name].append((time.thread_time() - c0) / calls * 1e6)
    for name in cases:
        print(
            f"{name:32s} {statistics.median(wall[name]):7.1f} us wall  {statistics.median(cpu[name]):7.1f} us cpu"
            f"   (median of {repeats} x {calls})"
        )


if __name__ == "__main__":
    _bench()
