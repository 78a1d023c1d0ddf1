"""What a rollout worker shows ``racer view`` (docs/view.md): its car's pose and camera, only while a page watches.

The worker calls :meth:`WatchPublisher.step` after every env step. Nobody watching, that call reads the clock and
returns, and once a second it asks Redis whether a page is open (one MGET: ``Keys.watchers`` and this worker's
``Keys.camera_watch``). A page open, the worker sets its pose at most ``POSE_HZ`` times a second; its camera
shown, also a JPEG of the frame the policy saw at most ``FRAME_HZ`` times a second (the simapp's camera stream's
rate), pose and frame in one round trip. A Redis error here never stops the worker: it publishes nothing until the
next check (the worker's own pushes ride the outage out).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import cv2
import numpy as np
import redis

from common.bus import Bus
from common.protocol import CarPose
from common.sensors import split_observation

log = logging.getLogger("racer.worker.watch")

CHECK_INTERVAL_S = 1.0
"""How often an unwatched worker asks Redis whether a page has opened."""
POSE_HZ = 5.0
"""Pose updates a second while a page is open."""
FRAME_HZ = 15.0
"""Camera frames a second while a page shows this worker's camera (DeepRacer's camera runs at 15 Hz)."""
JPEG_QUALITY = 80
"""Of the frames sent: a 160×120 gray frame is ~3 KB."""


def encode_frame(camera: np.ndarray) -> bytes:
    """JPEG of a camera observation (H, W, C) uint8: one gray image, or a stereo pair's images side by side."""
    image = camera[..., 0] if camera.shape[-1] == 1 else np.hstack([camera[..., c] for c in range(camera.shape[-1])])
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:  # OpenCV encodes any uint8 image; a failure is a bug worth seeing
        raise RuntimeError(f"could not encode a {image.shape} frame as JPEG")
    return data.tobytes()


class WatchPublisher:
    """Publishes one car's pose and camera to a ``racer view`` page, rate-limited, only while one watches."""

    def __init__(
        self, bus: Bus, worker_id: str, index: int, track: str, clock: Callable[[], float] = time.monotonic
    ) -> None:
        """``worker_id`` names the car in Redis and on the page; ``index`` (the worker's k) picks its colour;
        ``track`` is the name of the track its env drives."""
        self.bus, self.worker_id, self.index, self.track = bus, worker_id, index, track
        self._clock = clock
        self.watched = False
        """A page is open (poses are published)."""
        self.camera = False
        """A page shows this car's camera (frames are published too)."""
        self.frames = 0
        self._next_check = 0.0
        self._next_pose = 0.0
        self._next_frame = 0.0
        self._warned = False

    def step(self, observation: np.ndarray | dict, info: dict) -> None:
        """After an env step: publish what a watching page needs, if anything is due; nearly free otherwise."""
        now = self._clock()
        if now >= self._next_check:
            self._check(now)
        if not self.watched:
            return
        frame_due = self.camera and now >= self._next_frame
        if frame_due or now >= self._next_pose:
            self._publish(observation, info, frame_due, now)

    def _check(self, now: float) -> None:
        self._next_check = now + CHECK_INTERVAL_S
        try:
            self.watched, self.camera = self.bus.watched(self.worker_id)
        except redis.RedisError as exc:
            self._quiet(exc)

    def _publish(self, observation: np.ndarray | dict, info: dict, frame_due: bool, now: float) -> None:
        camera, lidar = split_observation(observation)
        frame = encode_frame(camera) if frame_due else None
        self.frames += frame is not None
        p = info["params"]
        pose = CarPose(
            worker_id=self.worker_id,
            index=self.index,
            track=self.track,
            x=float(p["x"]),
            y=float(p["y"]),
            heading=float(p["heading"]),
            speed=float(p["speed"]),
            steering=float(p["steering_angle"]),
            progress=float(p["progress"]),
            steps=int(info["steps"]),
            reversed=bool(p["is_reversed"]),
            status=str(info["episode_status"]),
            time=time.time(),
            frames=self.frames,
            lidar=None if lidar is None else [round(float(v), 3) for v in lidar],
        )
        try:
            self.bus.publish_pose(pose, frame)
        except redis.RedisError as exc:
            self._quiet(exc)
            return
        self._next_pose = now + 1.0 / POSE_HZ
        if frame is not None:
            self._next_frame = now + 1.0 / FRAME_HZ

    def _quiet(self, exc: redis.RedisError) -> None:
        """Publish nothing until the next check; say so once (the worker's own Redis calls report outages)."""
        self.watched = self.camera = False
        if not self._warned:
            log.warning("racer view: not publishing the car's pose (%s); trying again each second", exc)
            self._warned = True
