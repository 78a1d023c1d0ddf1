"""The sensors of a DeepRacer model_metadata.json ``sensor`` list, and the observation they give the policy.

The one owner of sensor names and observation shapes: the action space file's check, the network, the wire
protocol, the export and the env all ask ``observation_spec`` (or ``sensor_problem``). No torch here: the on-car
runtime imports it.

What DeepRacer's simulation application (aws-deepracer-community/deepracer-simapp, ``bundle/markov/``) does, and
racer with it:

* Sensor names: ``architecture/constants.py`` ``Input`` (``FRONT_FACING_CAMERA``, ``STEREO_CAMERAS``, ``LIDAR``,
  ``SECTOR_LIDAR``; also ``LEFT_CAMERA``, ``DISCRETIZED_SECTOR_LIDAR`` and the version-1 ``observation``).
* Allowed lists: ``boto/s3/files/model_metadata.py`` ``parse_model_metadata`` refuses a list without exactly one
  camera (``observation``, ``FRONT_FACING_CAMERA``, ``LEFT_CAMERA``, ``STEREO_CAMERAS``) or with more than one
  LiDAR (``LIDAR``, ``SECTOR_LIDAR``, ``DISCRETIZED_SECTOR_LIDAR``); ``agents/utils.py`` ``construct_sensor`` refuses
  a name outside ``Input``. The order of the list does not matter there. racer builds the front and stereo cameras,
  each alone or with ``LIDAR`` or ``SECTOR_LIDAR``: six lists (``SUPPORTED_COMBINATIONS``).
* Camera: 160×120 frames (``environments/constants.py`` ``TRAINING_IMAGE_SIZE``). The front camera goes to gray
  (``sagemaker_graph_manager.py``: ``ObservationRGBToYFilter``); the stereo pair is two gray images stacked as
  channels, left then right (``sensors/sensors_rollout.py`` ``DualCamera.get_state``: ``np.stack((left_img,
  right_img), axis=2)``; ``sensors/utils.py`` ``get_observation_space``: shape (120, 160, 2)). The simapp
  stacks no frames (``ObservationStackingFilter(1)`` for a camera, no stacking filter for the stereo pair; it reads
  ``stack_size`` and never uses it); racer's ``stack_size`` stacks whole camera frames on the channel axis, so
  a stereo observation has 2 × stack_size channels, left and right of the oldest frame first.
* ``LIDAR``: 64 ranges (``environments/constants.py`` ``TRAINING_LIDAR_SIZE``; ``sensors/constants.py``
  ``LIDAR_360_DEGREE_SAMPLE``), clipped to [0.15, 1.0] m (``sagemaker_graph_manager.py``:
  ``ObservationClippingFilter(0.15, 1.0)``; ``sensors/utils.py``: ``VectorObservationSpace(shape=
  TRAINING_LIDAR_SIZE, low=0.15, high=1.0)``).
* ``SECTOR_LIDAR``: the 64 ranges in 8 sectors (``environments/constants.py`` ``NUMBER_OF_LIDAR_SECTORS``), each
  1.0 if its nearest return is closer than 0.5 m (``SECTOR_LIDAR_CLIPPING_DIST``), else 0.0
  (``filters/observation/observation_sector_discretize_filter.py`` with ``num_values_per_sector=1``).
* Neither LiDAR is frame-stacked (the simapp adds no stacking filter for them): the observation's LiDAR part is
  the latest vector, float32 (N,).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

FRONT_FACING_CAMERA = "FRONT_FACING_CAMERA"
STEREO_CAMERAS = "STEREO_CAMERAS"
LIDAR = "LIDAR"
SECTOR_LIDAR = "SECTOR_LIDAR"

# Names the simapp knows (markov/architecture/constants.py, Input) that racer does not build.
LEFT_CAMERA = "LEFT_CAMERA"
DISCRETIZED_SECTOR_LIDAR = "DISCRETIZED_SECTOR_LIDAR"
LEGACY_CAMERA = "observation"
"""The camera's name in the simapp's version-1 files (``Input.OBSERVATION``)."""

SIMAPP_CAMERAS: tuple[str, ...] = (LEGACY_CAMERA, FRONT_FACING_CAMERA, LEFT_CAMERA, STEREO_CAMERAS)
"""The camera sensors of ``parse_model_metadata``'s check: a list has exactly one."""
SIMAPP_LIDARS: tuple[str, ...] = (LIDAR, SECTOR_LIDAR, DISCRETIZED_SECTOR_LIDAR)
"""The LiDAR sensors of ``parse_model_metadata``'s check: a list has at most one."""

CAMERA_CHANNELS: dict[str, int] = {FRONT_FACING_CAMERA: 1, STEREO_CAMERAS: 2}
"""Gray channels per camera frame of the cameras racer builds: one image, or the left and right images."""

# markov/sensors/constants.py (the values of racecar.launch): the simulated LiDAR.
LIDAR_SAMPLES = 64
"""Ranges per scan (``LIDAR_360_DEGREE_SAMPLE``, = ``TRAINING_LIDAR_SIZE``)."""
LIDAR_MIN_RANGE_M = 0.15
"""The scanner's shortest range, m (``LIDAR_360_DEGREE_MIN_RANGE``)."""
LIDAR_MAX_RANGE_M = 12.0
"""The scanner's longest range, m (``LIDAR_360_DEGREE_MAX_RANGE``)."""
LIDAR_CLIP_M = (0.15, 1.0)
"""``LIDAR`` observation: ranges clipped to this interval, m (``ObservationClippingFilter(0.15, 1.0)``)."""
LIDAR_SECTORS = 8
"""``SECTOR_LIDAR`` observation: sectors (``NUMBER_OF_LIDAR_SECTORS``)."""
SECTOR_CLIPPING_DIST_M = 0.5
"""``SECTOR_LIDAR``: a sector reads 1 when its nearest return is closer than this, m
(``SECTOR_LIDAR_CLIPPING_DIST``)."""


@dataclass(frozen=True)
class LidarSpec:
    """The LiDAR part of an observation: float32 (size,), every value in [low, high]."""

    name: str
    size: int
    low: float
    high: float


LIDARS: dict[str, LidarSpec] = {
    LIDAR: LidarSpec(LIDAR, LIDAR_SAMPLES, *LIDAR_CLIP_M),
    SECTOR_LIDAR: LidarSpec(SECTOR_LIDAR, LIDAR_SECTORS, 0.0, 1.0),
}
"""The LiDARs racer builds (bounds: ``sensors/utils.py`` ``get_observation_space``)."""

SUPPORTED_COMBINATIONS: tuple[tuple[str, ...], ...] = tuple(
    (camera, *extra) for camera in CAMERA_CHANNELS for extra in ((), *((name,) for name in LIDARS))
)
"""The sensor lists racer builds, in canonical order (camera first); a file may list them in any order."""


@dataclass(frozen=True)
class ObsSpec:
    """What a policy sees for a sensor list: a uint8 camera array (H, W, camera_channels) and, with a LiDAR, a
    float32 vector (lidar_size,)."""

    camera: str
    """FRONT_FACING_CAMERA or STEREO_CAMERAS."""
    stack_size: int
    """Camera frames stacked on the channel axis (the LiDAR is not stacked)."""
    lidar: LidarSpec | None = None

    @property
    def frame_channels(self) -> int:
        """Channels of one camera frame: 1, or 2 for the stereo pair (left, right)."""
        return CAMERA_CHANNELS[self.camera]

    @property
    def camera_channels(self) -> int:
        """Channels of the stacked camera observation: frame_channels × stack_size."""
        return self.frame_channels * self.stack_size

    @property
    def lidar_size(self) -> int:
        """Values of the LiDAR vector, 0 without a LiDAR."""
        return self.lidar.size if self.lidar else 0

    @property
    def sensors(self) -> tuple[str, ...]:
        """The sensor list, canonical order (camera, then the LiDAR if any)."""
        return (self.camera, self.lidar.name) if self.lidar else (self.camera,)

    def camera_shape(self, frame: tuple[int, int]) -> tuple[int, int, int]:
        """(H, W, camera_channels) of the stacked camera observation for frames of ``frame`` = (height, width)."""
        return (int(frame[0]), int(frame[1]), self.camera_channels)

    def frame_shape(self, frame: tuple[int, int]) -> tuple[int, int, int]:
        """(H, W, frame_channels) of one camera frame (what the env renders per step)."""
        return (int(frame[0]), int(frame[1]), self.frame_channels)


def sensor_problem(sensors: Sequence[str]) -> str | None:
    """Why racer cannot drive with this model_metadata ``sensor`` list (a short reason), or None if it can."""
    if isinstance(sensors, str) or not all(isinstance(s, str) for s in sensors):
        return "the sensor list must be a list of names"
    unknown = [s for s in sensors if s not in SIMAPP_CAMERAS + SIMAPP_LIDARS]
    if unknown:
        return f"{json.dumps(unknown[0])} is not a DeepRacer sensor"
    cameras = [s for s in sensors if s in SIMAPP_CAMERAS]
    lidars = [s for s in sensors if s in SIMAPP_LIDARS]
    if len(cameras) != 1:
        return f"DeepRacer needs exactly one camera, this list has {len(cameras)}"
    if len(lidars) > 1:
        return f"DeepRacer takes at most one LiDAR, this list has {len(lidars)}"
    for name in (*cameras, *lidars):
        if name not in CAMERA_CHANNELS and name not in LIDARS:
            return f"racer does not build {name}"
    return None


def observation_spec(sensors: Sequence[str], stack_size: int = 1) -> ObsSpec:
    """The observation of a model_metadata ``sensor`` list (any order) with ``stack_size`` camera frames;
    ValueError naming the problem for a list racer does not build (``sensor_problem``)."""
    problem = sensor_problem(sensors)
    if problem:
        raise ValueError(f"sensor = {json.dumps(list(sensors))}: {problem}")
    if isinstance(stack_size, bool) or not isinstance(stack_size, int) or stack_size < 1:
        raise ValueError(f"stack_size must be a positive integer, got {stack_size!r}")
    camera = next(s for s in sensors if s in CAMERA_CHANNELS)
    lidar = next((LIDARS[s] for s in sensors if s in LIDARS), None)
    return ObsSpec(camera, stack_size, lidar)


def lidar_from_ranges(sensor: str, ranges: np.ndarray) -> np.ndarray:
    """The LiDAR observation (float32) of one scan of ``LIDAR_SAMPLES`` ranges in metres, as the simapp's input
    filters make it (``sagemaker_graph_manager.py``):

    * ``LIDAR``: ``np.clip(ranges, 0.15, 1.0)`` (``ObservationClippingFilter``); +inf (no return) reads 1.0,
      -inf (a return nearer than the min range) 0.15. A NaN stays NaN, and ``check_lidar`` refuses it.
    * ``SECTOR_LIDAR`` (``ObservationSectorDiscretizeFilter(8, 1, 0.5)``): infinite ranges become 0.5, the minimum
      of each run of 8 consecutive ranges is floored to 0 (closer than 0.5 m) or 1, one-hot encoded with the
      "nothing" column dropped: a sector reads 1.0 when something is closer than 0.5 m, else 0.0 (a sector holding
      a NaN reads 1.0, as the filter's integer cast makes it).
    """
    r = np.asarray(ranges, dtype=np.float64)
    if r.shape != (LIDAR_SAMPLES,):
        raise ValueError(f"a LiDAR scan has {LIDAR_SAMPLES} ranges, got shape {r.shape}")
    if sensor == LIDAR:
        return np.clip(r, *LIDAR_CLIP_M).astype(np.float32)
    if sensor == SECTOR_LIDAR:
        clip = max(min(SECTOR_CLIPPING_DIST_M, LIDAR_MAX_RANGE_M), LIDAR_MIN_RANGE_M)
        r = np.where(np.isinf(r), clip, r)
        nearest = r.reshape(LIDAR_SECTORS, -1).min(axis=1)
        # floor(min(d, clip) / clip) is 0 below the clipping distance, 1 at it; NaN compares False: 0, as the
        # filter's NaN → int cast → clip to [0, 1] gives.
        level = np.where(np.minimum(nearest, clip) >= clip, 1, 0)
        return (level == 0).astype(np.float32)
    raise ValueError(f"{sensor!r} is not a LiDAR racer builds ({', '.join(LIDARS)})")


def check_lidar(spec: LidarSpec, values: np.ndarray) -> str | None:
    """Why ``values`` (any leading dimensions, then ``spec.size``) is not a valid LiDAR observation, or None."""
    if values.dtype != np.float32:
        return f"dtype {values.dtype}, expected float32"
    if values.ndim < 1 or values.shape[-1] != spec.size:
        return f"shape {values.shape}, expected (..., {spec.size})"
    if not np.all(np.isfinite(values)):
        return "non-finite values"
    if values.size and (values.min() < np.float32(spec.low) or values.max() > np.float32(spec.high)):
        return f"values outside [{spec.low}, {spec.high}]"
    return None


CAMERA_KEY = "camera"
"""The camera part's key in the env's observation of a run with a LiDAR (a gymnasium ``Dict`` space)."""
LIDAR_KEY = "lidar"
"""The LiDAR part's key in the env's observation of a run with a LiDAR: float32 (N,), ``lidar_from_ranges``'s."""


def split_observation(obs: np.ndarray | dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray | None]:
    """(camera uint8 (H, W, C), LiDAR float32 (N,) or None) of one env observation: the camera array alone for a
    camera-only sensor list, ``{CAMERA_KEY: ..., LIDAR_KEY: ...}`` with a LiDAR. Every consumer (workers, the
    evaluator, ``racer eval``) takes the observation apart here, so the env's layout is known in one place."""
    if isinstance(obs, dict):
        return obs[CAMERA_KEY], obs[LIDAR_KEY]
    return obs, None


def camera_frame_size(space: object) -> tuple[int, int]:
    """(height, width) of the camera frames of an env's observation space: a camera ``Box`` or a ``Dict`` with a
    ``CAMERA_KEY`` part (duck-typed: no gymnasium import here, the on-car runtime does not have it)."""
    parts = getattr(space, "spaces", None)
    camera = parts[CAMERA_KEY] if isinstance(parts, dict) else space
    shape = camera.shape
    return int(shape[0]), int(shape[1])
