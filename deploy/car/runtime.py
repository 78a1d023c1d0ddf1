"""The on-car runtime: camera frames in, motor commands out, with an exported ONNX policy.

Each frame goes through exactly the preprocessing of training (:func:`preprocess`: OpenCV's BGR→gray, then
160×120; a stereo model takes the left and right frames as two channels, :func:`preprocess_stereo`), onto a frame
stack like the rollout workers', through the ONNX model on one CPU thread, and the most likely action (DeepRacer's
car acts greedily, as its evaluations do) is mapped through the vehicle calibration to servo and ESC outputs, which
go to a :class:`CommandSink`. A model whose sensors include a LiDAR also takes, with each frame, the latest scan's
64 ranges in metres, turned into its LiDAR input as in training (``common.sensors.lidar_from_ranges``); a LiDAR
driver is a :class:`LidarSource`.

A real motor driver is a CommandSink: a class with ``write(command: MotorCommand)`` and ``close()``, that sends
``command.steering_out`` to the steering servo and ``command.throttle_out`` to the ESC (for example through a
PCA9685 PWM board or the car's servo node). :class:`CsvSink` (a file or standard output) is the default.
"""

from __future__ import annotations

import csv
import statistics
import sys
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import IO, Protocol

import cv2
import numpy as np
import onnxruntime as ort

from common.action_space import ActionSpace
from common.errors import UserError
from common.framestack import FrameStack
from common.sensors import STEREO_CAMERAS, check_lidar, lidar_from_ranges
from deploy.car.model_file import OBS_HEIGHT, OBS_WIDTH, model_info, model_observation
from deploy.car.vehicle import MotorCommand, VehicleCalibration, motor_command


class DeployError(UserError, ValueError):
    """A camera, video, model or frame the runtime cannot use; the message names it."""


def preprocess(frame: np.ndarray) -> np.ndarray:
    """A camera frame (BGR or gray, any size) as the policy saw frames in training: (120, 160) gray uint8.

    The simulator's camera renders gray with the same OpenCV conversion (from RGB); a camera delivers BGR."""
    if frame.ndim == 3 and frame.shape[2] == 3:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    elif frame.ndim == 3 and frame.shape[2] == 1:
        frame = frame[..., 0]
    if frame.ndim != 2:
        raise DeployError(f"a camera frame of shape {frame.shape} is neither gray nor BGR")
    if frame.shape != (OBS_HEIGHT, OBS_WIDTH):
        frame = cv2.resize(frame, (OBS_WIDTH, OBS_HEIGHT), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(frame, dtype=np.uint8)


def preprocess_stereo(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The stereo pair as a stereo policy saw it in training: (120, 160, 2) gray uint8, left then right (DeepRacer's
    ``DualCamera``: ``np.stack((left_img, right_img), axis=2)``), each camera preprocessed like the front camera."""
    return np.stack((preprocess(left), preprocess(right)), axis=-1)


class LidarSource(Protocol):
    """The car's LiDAR: ``read()`` returns the latest scan, ``LIDAR_SAMPLES`` (64) ranges in metres in the scan's
    order (the simulated scanner's, from -150° to +150°), infinite where nothing returned."""

    def read(self) -> np.ndarray:
        """The latest scan."""


class CommandSink(Protocol):
    """Where motor commands go: a motor driver on a car, or a log."""

    def write(self, command: MotorCommand) -> None:
        """Send one frame's outputs."""

    def close(self) -> None:
        """Release the device or file."""


class CsvSink:
    """Commands as CSV rows (one per frame, with a header) to a file, or to standard output for ``-``."""

    def __init__(self, target: str | Path = "-") -> None:
        self._file: IO[str] = sys.stdout if str(target) == "-" else open(target, "w", newline="")  # noqa: SIM115
        self._writer = csv.DictWriter(self._file, [f.name for f in fields(MotorCommand)])
        self._writer.writeheader()

    def write(self, command: MotorCommand) -> None:
        """One row."""
        self._writer.writerow(asdict(command))

    def close(self) -> None:
        """Flush; close the file unless it is standard output."""
        self._file.flush()
        if self._file is not sys.stdout:
            self._file.close()


class Policy:
    """An exported model and its action space: a frame stack (and a LiDAR vector) in, the greedy action out."""

    def __init__(self, model: str | Path, model_metadata: str | Path | None = None) -> None:
        model = Path(model)
        if not model.is_file():
            raise DeployError(f"model {str(model)!r} does not exist")
        self.info = model_info(model)
        meta = Path(model_metadata) if model_metadata else model.parent / "model_metadata.json"
        if not meta.is_file():
            raise DeployError(f"no model_metadata.json beside the model (looked for {str(meta)!r})")
        self.actions = ActionSpace.model_validate_json(meta.read_text())
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1  # one core of the car's CPU; the camera and the rest take the others
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(model), options, providers=["CPUExecutionProvider"])
        self.spec = model_observation(self.info)
        """The sensors and observation the model takes (``common.sensors.ObsSpec``)."""
        self.stack_size = self.spec.stack_size
        self.obs_shape = self.spec.camera_shape((OBS_HEIGHT, OBS_WIDTH))

    def act(self, obs: np.ndarray, lidar: np.ndarray | None = None) -> tuple[int | None, float, float]:
        """(action index or None, steering degrees, speed m/s) for one (120, 160, C) uint8 observation and, for a
        model with a LiDAR, its float32 (N,) LiDAR vector (``common.sensors.lidar_from_ranges``)."""
        if obs.shape != self.obs_shape or obs.dtype != np.uint8:
            raise DeployError(f"an observation of {obs.shape} {obs.dtype}: the model takes {self.obs_shape} uint8")
        feed = {"obs": obs[None]}
        if self.spec.lidar:
            if lidar is None:
                raise DeployError(f"the model's sensors {list(self.spec.sensors)} need a LiDAR vector")
            problem = check_lidar(self.spec.lidar, lidar)
            if problem:
                raise DeployError(f"a {self.spec.lidar.name} vector of {problem}")
            feed["lidar"] = lidar[None]
        elif lidar is not None:
            raise DeployError(f"the model's sensors {list(self.spec.sensors)} have no LiDAR")
        params = self.session.run(None, feed)[0][0]
        if self.actions.discrete:
            index = int(np.argmax(params))
            return (index, *self.actions.command(index))
        return (None, *self.actions.command((float(params[0]), float(params[1]))))


@dataclass
class DriveResult:
    """What a drive did: frames, rate, and where the time went."""

    frames: int
    fps: float
    """Frames per second over the whole loop (read, preprocess, infer, map, write)."""
    infer_ms_median: float
    loop_ms_median: float


def open_source(source: str) -> cv2.VideoCapture:
    """A camera (``0``, ``1``…) or a video file / image sequence (``frames/%04d.png``) as a VideoCapture."""
    capture = cv2.VideoCapture(int(source)) if source.isdigit() else cv2.VideoCapture(source)
    if not capture.isOpened():
        raise DeployError(f"cannot open camera or video {source!r}")
    return capture


def drive(
    policy: Policy,
    source: str,
    calibration: VehicleCalibration,
    sink: CommandSink,
    max_frames: int | None = None,
    *,
    right_source: str | None = None,
    lidar: LidarSource | None = None,
) -> DriveResult:
    """Run the loop until the source ends (or ``max_frames``); every frame gets one command.

    ``source`` is the camera (the left one of a stereo model), ``right_source`` the right camera of a stereo model,
    ``lidar`` the LiDAR of a model with one; each is required exactly when the model's sensors need it."""
    cv2.setNumThreads(1)
    stereo = policy.spec.camera == STEREO_CAMERAS
    captures: list[cv2.VideoCapture] = []
    try:
        if stereo != (right_source is not None):
            raise DeployError(
                f"the model's camera is {policy.spec.camera}: "
                + ("give the right camera too" if stereo else "it takes no right camera")
            )
        if (policy.spec.lidar is not None) != (lidar is not None):
            raise DeployError(
                f"the model's sensors are {list(policy.spec.sensors)}: "
                + ("give a LiDAR" if policy.spec.lidar else "it takes no LiDAR")
            )
        captures.append(open_source(source))
        if right_source is not None:
            captures.append(open_source(right_source))
    except DeployError:
        for capture in captures:
            capture.release()
        sink.close()  # nothing will be written: release the output too
        raise
    stack = FrameStack(policy.stack_size)
    infer, loop = [], []
    frame_no, start = 0, time.perf_counter()
    try:
        while max_frames is None or frame_no < max_frames:
            t0 = time.perf_counter()
            frames = [capture.read() for capture in captures]
            if not all(ok for ok, _ in frames):
                break
            camera = preprocess_stereo(frames[0][1], frames[1][1]) if stereo else preprocess(frames[0][1])[..., None]
            obs = stack.reset(camera) if frame_no == 0 else stack.push(camera)
            vector = lidar_from_ranges(policy.spec.lidar.name, lidar.read()) if lidar is not None else None
            t1 = time.perf_counter()
            action, steering, speed = policy.act(obs, vector)
            infer.append(time.perf_counter() - t1)
            sink.write(motor_command(calibration, frame_no, action, steering, speed))
            loop.append(time.perf_counter() - t0)
            frame_no += 1
    finally:
        for capture in captures:
            capture.release()
        sink.close()
    if frame_no == 0:
        raise DeployError(f"no frame could be read from {source!r}")
    elapsed = time.perf_counter() - start
    return DriveResult(frame_no, frame_no / elapsed, 1e3 * statistics.median(infer), 1e3 * statistics.median(loop))
