"""The live half of ``racer view``: one thread that reads the run's Redis for every page at once.

While a page is open (it polls ``/api/live`` a few times a second) the feed refreshes the ``watchers`` mark each
second, so workers publish their poses; while a page shows a worker's camera it also refreshes that worker's
``camera_watch`` mark and reads its frame ``FRAME_HZ`` times a second. Pages read what the feed last read, so
several browsers cost Redis (and the workers) no more than one. With no page open it sends nothing, the marks
expire (``common.bus.WATCH_TTL_S``) and the workers stop publishing.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import redis

from common.bus import Bus
from common.redis_util import redact
from rollout_worker.watch import FRAME_HZ

log = logging.getLogger("racer.view")

PAGE_IDLE_S = 3.0
"""A page (or a camera stream) not heard from for this long has closed."""
POSE_POLL_S = 0.2
"""How often the feed reads the poses while a page is open."""
MARK_EVERY_S = 1.0
"""How often the feed refreshes the watch marks (they expire after ``common.bus.WATCH_TTL_S``)."""
STATUS_EVERY_S = 1.0
"""How often the feed reads the trainer's status and the workers' heartbeats."""
MAX_CAMERAS = 16
"""Cameras shown at once, all pages together (each costs its worker 15 JPEGs a second)."""


class LiveFeed:
    """Poses, frames and the trainer's status of one run, read from Redis only while a page wants them."""

    def __init__(self, bus: Bus, url: str) -> None:
        """Starts the feed's thread (a daemon: it never holds a process up)."""
        self.bus, self.url = bus, redact(url)
        self._lock = threading.Lock()
        self._page_seen = -float("inf")
        self._cameras: dict[str, float] = {}
        """Worker id → when a page last wanted its camera."""
        self._frames: dict[str, tuple[int, bytes]] = {}
        self._poses: dict[str, dict[str, Any]] = {}
        self._alive: set[str] = set()
        """Workers with a heartbeat (it outlives the pose key while a worker waits out a PPO update). A car's id is
        its worker's id, or ``<worker id>/<env>`` for one of a worker's several envs."""
        self._snapshot: dict[str, Any] = {"poses": [], "trainer": None, "workers": [], "error": None, "time": 0.0}
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._thread = threading.Thread(target=self._run, name="racer-view-live", daemon=True)
        self._thread.start()

    # -- what the pages call ---------------------------------------------------------------------------------------
    def touch(self) -> dict[str, Any]:
        """A page polled: keep the feed reading, and return what it read last."""
        with self._lock:
            idle = time.monotonic() - self._page_seen > PAGE_IDLE_S
            self._page_seen = time.monotonic()
            snapshot = dict(self._snapshot)
        if idle:
            self._wake.set()
        return snapshot

    def want_camera(self, worker_id: str) -> bool:
        """A page shows ``worker_id``'s camera (a stream calls this for every frame it waits for); False when
        ``MAX_CAMERAS`` others are shown already."""
        with self._lock:
            new = worker_id not in self._cameras
            if new and len(self._cameras) >= MAX_CAMERAS:
                return False
            self._cameras[worker_id] = time.monotonic()
        if new:
            self._wake.set()
        return True

    def frame(self, worker_id: str) -> tuple[int, bytes] | None:
        """(sequence number, JPEG) of the latest frame read of ``worker_id``, None before the first."""
        with self._lock:
            return self._frames.get(worker_id)

    @property
    def closed(self) -> bool:
        """The feed has been stopped."""
        return self._stop.is_set()

    def close(self) -> None:
        """Stop the thread (the marks then expire on their own)."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout=5)

    # -- the thread --------------------------------------------------------------------------------------------------
    def _wanted(self, now: float) -> tuple[bool, list[str]]:
        """(a page is open, the workers whose cameras are shown), forgetting cameras no page wants any more."""
        with self._lock:
            self._cameras = {w: t for w, t in self._cameras.items() if now - t <= PAGE_IDLE_S}
            for gone in set(self._frames) - set(self._cameras):
                del self._frames[gone]
            return now - self._page_seen <= PAGE_IDLE_S or bool(self._cameras), sorted(self._cameras)

    def _run(self) -> None:
        next_mark = next_pose = next_status = 0.0
        cameras_marked: list[str] = []
        while not self._stop.is_set():
            now = time.monotonic()
            open_, cameras = self._wanted(now)
            if not open_:
                self._wake.wait(0.5)
                self._wake.clear()
                next_mark = next_pose = next_status = 0.0
                continue
            try:
                if now >= next_mark or cameras != cameras_marked:
                    self.bus.watch(cameras)
                    next_mark, cameras_marked = now + MARK_EVERY_S, cameras
                if now >= next_pose:
                    self._read_poses()
                    next_pose = now + POSE_POLL_S
                if now >= next_status:
                    self._read_status()
                    next_status = now + STATUS_EVERY_S
                for worker_id in cameras:
                    self._read_frame(worker_id)
                self._set(error=None)
            except redis.RedisError as exc:
                self._set(error=f"Redis at {self.url} unreachable ({type(exc).__name__})")
                self._stop.wait(1.0)
                continue
            self._wake.wait(1.0 / FRAME_HZ if cameras else POSE_POLL_S)
            self._wake.clear()

    def _set(self, **values: Any) -> None:
        with self._lock:
            self._snapshot = {**self._snapshot, **values, "time": time.time()}

    def _read_poses(self) -> None:
        poses = {p.worker_id: p.model_dump() for p in self.bus.poses()[0]}
        for worker_id, last in self._poses.items():
            if worker_id not in poses and worker_id.split("/")[0] in self._alive:
                poses[worker_id] = last  # its worker waits for a PPO update: the car stays where it stopped
        self._poses = poses
        self._set(poses=sorted(poses.values(), key=lambda p: (p["index"], p["worker_id"])))

    def _read_status(self) -> None:
        beats, _ = self.bus.heartbeats()
        self._alive = {b.worker_id for b in beats}
        workers = [
            {"worker_id": b.worker_id, "policy_version": b.policy_version, "env_steps": b.env_steps, "track": b.track}
            for b in sorted(beats, key=lambda b: b.worker_id)
        ]
        self._set(trainer=self.bus.trainer_status(), workers=workers)

    def _read_frame(self, worker_id: str) -> None:
        data = self.bus.frame(worker_id)
        if data is None:
            return
        with self._lock:
            last = self._frames.get(worker_id)
            if last is None or last[1] != data:
                self._frames[worker_id] = ((last[0] + 1) if last else 1, data)
