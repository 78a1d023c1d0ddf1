"""What a rollout worker shows ``racer view`` (docs/view.md): its car's pose and camera, only while a page watches.

The worker calls :meth:`WatchPublisher.step` after every env step. Nobody watching, that call reads the clock and
returns. A page open, it hands the step's pose (and, while the page shows this car's camera, a copy of the frame the
policy saw) to the publisher's thread at most ``POSE_HZ`` (``FRAME_HZ``) times a second and returns; the thread
encodes the JPEG and sends pose and frame in one round trip. So the step loop never waits for Redis: on a loaded
machine a round trip can take milliseconds (docs/view.md has the measurement that made it a thread).

The thread asks Redis once a second whether a page is open (one MGET of ``Keys.watchers`` and this car's
``Keys.camera_watch``); it starts with the first step and ends on :meth:`close`, or by itself once no step has come
for ``IDLE_EXIT_S`` (a worker dropped without ``close``). A Redis error never stops the worker: the publisher
sends nothing until the next check (the worker's own calls ride the outage out and report it).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
import redis

from common.bus import Bus
from common.protocol import CarPose
from common.sensors import split_observation

log = logging.getLogger("racer.worker.watch")

CHECK_INTERVAL_S = 1.0
"""How often the publisher asks Redis whether a page is open."""
POSE_HZ = 5.0
"""Pose updates a second while a page is open."""
FRAME_HZ = 15.0
"""Camera frames a second while a page shows this car's camera (DeepRacer's camera runs at 15 Hz)."""
JPEG_QUALITY = 80
"""Of the frames sent: a 160×120 gray frame is ~3 KB."""
IDLE_EXIT_S = 10.0
"""The thread ends when no step has come for this long (it starts again with the next one)."""
REPEAT_S = 1.0
"""While the worker does not step (it waits out a PPO update) the last pose is sent again this often, so the car
stays on the page; it leaves ``common.bus.POSE_TTL_S`` after the worker's process ends."""


def encode_frame(camera: np.ndarray) -> bytes:
    """JPEG of a camera observation (H, W, C) uint8: one gray image, or a stereo pair's images side by side."""
    image = camera[..., 0] if camera.shape[-1] == 1 else np.hstack([camera[..., c] for c in range(camera.shape[-1])])
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:  # OpenCV encodes any uint8 image; a failure is a bug worth seeing
        raise RuntimeError(f"could not encode a {image.shape} frame as JPEG")
    return data.tobytes()


class WatchPublisher:
    """Publishes one car's pose and camera to ``racer view``, rate-limited, only while a page watches."""

    def __init__(
        self, bus: Bus, worker_id: str, index: int, track: str, clock: Callable[[], float] = time.monotonic
    ) -> None:
        """``worker_id`` names the car in Redis and on the page; ``index`` (the worker's k) picks its colour;
        ``track`` is the name of the track its env drives."""
        self.bus, self.worker_id, self.index, self.track = bus, worker_id, index, track
        self._clock = clock
        self.watched = False
        """A page is open (poses are published); kept current by the thread."""
        self.camera = False
        """A page shows this car's camera (frames are published too)."""
        self.frames = 0
        """Frames sent."""
        self._next_pose = self._next_frame = 0.0
        self._last_step = 0.0
        self._pose: dict[str, Any] | None = None
        self._frame: np.ndarray | None = None
        self._sent: tuple[float, dict[str, Any]] | None = None
        """(when, pose) of the last pose sent."""
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._warned = False

    # -- the worker's side ---------------------------------------------------------------------------------------
    def step(self, observation: np.ndarray | dict, info: dict) -> None:
        """After an env step: hand what a watching page needs to the thread, if anything is due; nearly free."""
        now = self._clock()
        self._last_step = now
        if self._thread is None or not self._thread.is_alive():
            self._start()
        if not self.watched:
            return
        frame_due = self.camera and now >= self._next_frame
        if not frame_due and now < self._next_pose:
            return
        camera, lidar = split_observation(observation)
        pose = _pose_fields(info, lidar)
        with self._cond:
            self._pose = pose  # an unsent one is replaced: the newest wins
            if frame_due:
                self._frame = camera.copy()  # the env may reuse its buffer
            self._cond.notify()
        self._next_pose = now + 1.0 / POSE_HZ
        if frame_due:
            self._next_frame = now + 1.0 / FRAME_HZ

    def thread_cpu_s(self) -> float:
        """CPU seconds the publisher's thread has used (0 while it has none), read from its clock without
        interrupting it (``racer/bench_view.py`` reports it)."""
        thread = self._thread
        if thread is None or thread.ident is None or not thread.is_alive():
            return 0.0
        try:
            return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))
        except OSError:  # it ended between the two calls
            return 0.0

    def close(self) -> None:
        """Stop the thread (the keys it set expire on their own)."""
        self._closed = True
        with self._cond:
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout=5)

    # -- the thread ------------------------------------------------------------------------------------------------
    def _start(self) -> None:
        if self._closed:
            return
        self._thread = threading.Thread(target=self._run, name=f"racer-watch-{self.worker_id}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_check = 0.0
        while not self._closed and self._clock() - self._last_step < IDLE_EXIT_S:
            now = self._clock()
            if now >= next_check:
                self._check()
                next_check = now + CHECK_INTERVAL_S
            with self._cond:
                if self._pose is None and not self._closed:
                    self._cond.wait(timeout=max(0.0, next_check - self._clock()))
                pose, frame, self._pose, self._frame = self._pose, self._frame, None, None
            if pose is None and self._sent is not None and self._clock() - self._sent[0] >= REPEAT_S:
                pose = self._sent[1]  # the worker is waiting: keep its car on the page
            if pose is not None and self.watched:
                self._publish(pose, frame)
        self.watched = self.camera = False  # a new thread checks again before anything is handed over

    def _check(self) -> None:
        try:
            self.watched, self.camera = self.bus.watched(self.worker_id)
        except redis.RedisError as exc:
            self._quiet(exc)

    def _publish(self, pose: dict[str, Any], frame: np.ndarray | None) -> None:
        jpeg = encode_frame(frame) if frame is not None else None
        message = CarPose(
            worker_id=self.worker_id,
            index=self.index,
            track=self.track,
            frames=self.frames + (jpeg is not None),
            **pose,
        )
        try:
            self.bus.publish_pose(message, jpeg)
        except redis.RedisError as exc:
            self._quiet(exc)
            return
        self.frames += jpeg is not None
        self._sent = (self._clock(), pose)

    def _quiet(self, exc: redis.RedisError) -> None:
        """Publish nothing until the next check; say so once (the worker's own Redis calls report outages)."""
        self.watched = self.camera = False
        if not self._warned:
            log.warning("racer view: not publishing the car's pose (%s); trying again each second", exc)
            self._warned = True


def _pose_fields(info: dict, lidar: np.ndarray | None) -> dict[str, Any]:
    """The step's ``CarPose`` fields from the env's ``info``, as plain numbers (taken now: the env moves on)."""
    p = info["params"]
    return {
        "x": float(p["x"]),
        "y": float(p["y"]),
        "heading": float(p["heading"]),
        "speed": float(p["speed"]),
        "steering": float(p["steering_angle"]),
        "progress": float(p["progress"]),
        "steps": int(info["steps"]),
        "reversed": bool(p["is_reversed"]),
        "status": str(info["episode_status"]),
        "time": time.time(),
        "lidar": None if lidar is None else [round(float(v), 3) for v in lidar],
    }
