"""What a rollout worker shows ``racer view`` (docs/view.md): its car's pose and camera, only while a page watches.

The worker calls :meth:`WatchPublisher.step` after every env step. Once a second it asks Redis whether a page is
open (an MGET of ``Keys.watchers`` and this car's ``Keys.camera_watch``); the rest of the time, nobody watching, the
call reads the clock and returns. A page open, it sets the car's pose at most ``POSE_HZ`` times a second; while a page
shows this car's camera, also a JPEG of the frame the policy saw at most ``FRAME_HZ`` times a second, pose and frame
in one write. The commands and keys are ``common/bus.py``'s (``Bus.watched_query``, ``Bus.pose_commands``).

The publisher never waits for Redis: it writes its commands on a connection of its own and reads their replies
later, once they have arrived (``_Pipe``). On a loaded machine a round trip took milliseconds, and a thread that
waited for it instead cost the worker its wake-ups (docs/view.md has the measurements). A Redis error never stops the
worker: the publisher drops its connection and sends nothing until the next check (the worker's own calls ride the
outage out and report it).
"""

from __future__ import annotations

import collections
import logging
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
"""Of the frames sent: a 160×120 gray frame is about 1.5 KB."""
MAX_UNANSWERED = 32
"""Writes whose replies have not come back before the publisher gives up on its connection (Redis is stuck)."""


def encode_frame(camera: np.ndarray) -> bytes:
    """JPEG of a camera observation (H, W, C) uint8: one gray image, or a stereo pair's images side by side."""
    image = camera[..., 0] if camera.shape[-1] == 1 else np.hstack([camera[..., c] for c in range(camera.shape[-1])])
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:  # OpenCV encodes any uint8 image; a failure is a bug worth seeing
        raise RuntimeError(f"could not encode a {image.shape} frame as JPEG")
    return data.tobytes()


class _Pipe:
    """A Redis connection of the publisher's own: commands are written without waiting, and each write's replies are
    read once they are there (Redis answers in order), handed to that write's callback."""

    def __init__(self, client: redis.Redis) -> None:
        self.pool = client.connection_pool
        self.conn: Any = None
        self.waiting: collections.deque[tuple[int, Callable[[list], None] | None]] = collections.deque()

    def send(self, commands: list[tuple], on_replies: Callable[[list], None] | None = None) -> None:
        """Write ``commands`` (each a tuple of arguments); ``on_replies`` gets their replies when they come."""
        self.collect()
        if len(self.waiting) >= MAX_UNANSWERED:
            raise redis.ConnectionError(f"no reply to the last {MAX_UNANSWERED} writes")
        if self.conn is None:
            self.conn = self.pool.make_connection()  # not the pool's: the worker's own calls never share it
            self.conn.connect()
        self.conn.send_packed_command(self.conn.pack_commands(commands), check_health=False)
        self.waiting.append((len(commands), on_replies))

    def collect(self) -> None:
        """Read the replies that have arrived, without waiting for any."""
        while self.waiting and self.conn.can_read(timeout=0):
            count, on_replies = self.waiting.popleft()
            replies = [self.conn.read_response() for _ in range(count)]  # a write's replies come together
            if on_replies is not None:
                on_replies(replies)

    def close(self) -> None:
        """Drop the connection and every unread reply."""
        self.waiting.clear()
        if self.conn is not None:
            self.conn.disconnect()
            self.conn = None


class WatchPublisher:
    """Publishes one car's pose and camera to ``racer view``, rate-limited, only while a page watches."""

    def __init__(
        self, bus: Bus, worker_id: str, index: int, track: str, clock: Callable[[], float] = time.monotonic
    ) -> None:
        """``worker_id`` names the car in Redis and on the page; ``index`` (the worker's k) picks its colour;
        ``track`` is the name of the track its env drives."""
        self.bus, self.worker_id, self.index, self.track = bus, worker_id, index, track
        self._clock = clock
        self._pipe = _Pipe(bus.redis)
        self.watched = False
        """A page is open (poses are published)."""
        self.camera = False
        """A page shows this car's camera (frames are published too)."""
        self.frames = 0
        """Frames sent."""
        self._next_check = self._next_pose = self._next_frame = 0.0
        self._asking = False
        """The answer to "is a page open?" has not been read yet (other replies are read before the next write)."""
        self._warned = False

    def step(self, observation: np.ndarray | dict, info: dict) -> None:
        """After an env step: publish what a watching page needs, if anything is due; nearly free otherwise."""
        now = self._clock()
        try:
            if self._asking:
                self._pipe.collect()
            if now >= self._next_check:
                self._next_check = now + CHECK_INTERVAL_S
                self._asking = True
                self._pipe.send([self.bus.watched_query(self.worker_id)], self._on_watch)
            if not self.watched:
                return
            frame_due = self.camera and now >= self._next_frame
            if frame_due or now >= self._next_pose:
                self._publish(observation, info, frame_due)
                self._next_pose = now + 1.0 / POSE_HZ
                self._next_frame = now + 1.0 / FRAME_HZ if frame_due else self._next_frame
        except (redis.RedisError, OSError) as exc:
            self._quiet(exc)

    def close(self) -> None:
        """Drop the publisher's connection (the keys it set expire on their own)."""
        self._pipe.close()

    def _on_watch(self, replies: list) -> None:
        self.watched, self.camera = self.bus.watched_reply(replies[0])
        self._asking = False

    def _publish(self, observation: np.ndarray | dict, info: dict, frame_due: bool) -> None:
        camera, lidar = split_observation(observation)
        # A teacher's env returns the car's state, not a frame: its page shows the pose alone.
        jpeg = encode_frame(camera) if frame_due and camera.ndim == 3 else None
        frames = self.frames + (jpeg is not None)
        pose = CarPose(
            worker_id=self.worker_id, index=self.index, track=self.track, frames=frames, **_pose_fields(info, lidar)
        )
        self._pipe.send(self.bus.pose_commands(pose, jpeg))
        self.frames = frames

    def _quiet(self, exc: Exception) -> None:
        """Publish nothing until the next check, on a new connection; say so once (the worker's own Redis calls
        report outages)."""
        self._pipe.close()
        self.watched = self.camera = self._asking = False
        if not self._warned:
            log.warning("racer view: not publishing the car's pose (%s); trying again each second", exc)
            self._warned = True


def _pose_fields(info: dict, lidar: np.ndarray | None) -> dict[str, Any]:
    """The step's ``CarPose`` fields from the env's ``info``."""
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
