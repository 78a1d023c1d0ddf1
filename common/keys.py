"""Every Redis key and channel racer uses, in one place, all under ``racer:{run_id}:``."""

from __future__ import annotations

import re

from common.errors import OptionError

PREFIX = "racer"
RUN_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
"""What a run id may be: it is part of Redis keys and store paths, so no ':', '/' or '..'."""


def check_run_id(run_id: str) -> str:
    """Return ``run_id`` if it is a valid run id (letters, digits, ``._-``; ≤ 128), else raise OptionError naming it."""
    if not isinstance(run_id, str) or not RUN_ID.match(run_id):
        raise OptionError(f"invalid run id {run_id!r}: use 1-128 of A-Z a-z 0-9 . _ - starting with a letter or digit")
    return run_id


class Keys:
    """Key names of one run."""

    def __init__(self, run_id: str) -> None:
        self.run_id = check_run_id(run_id)
        self.base = f"{PREFIX}:{run_id}"

    @property
    def segments(self) -> str:
        """Stream of experience segments, workers → trainer (capped with MAXLEN ~)."""
        return f"{self.base}:segments"

    @property
    def policy(self) -> str:
        """String key: JSON of the newest policy version (PolicyVersion)."""
        return f"{self.base}:policy"

    def heartbeat(self, worker_id: str) -> str:
        """String key with a TTL: a worker's last heartbeat (Heartbeat JSON)."""
        return f"{self.base}:heartbeat:{worker_id}"

    @property
    def heartbeat_pattern(self) -> str:
        """SCAN pattern matching every worker's heartbeat key."""
        return f"{self.base}:heartbeat:*"

    @property
    def trainer_status(self) -> str:
        """String key with a TTL: the trainer's progress (TrainerStatus JSON), for `racer train`'s display."""
        return f"{self.base}:trainer"

    @property
    def trainer_beat(self) -> str:
        """String key with a TTL: the trainer process's heartbeat (TrainerBeat JSON), refreshed by its own thread so
        that a long PPO update never reads as a dead trainer."""
        return f"{self.base}:trainer_beat"

    @property
    def trainer_end(self) -> str:
        """String key: why and where the trainer stopped (TrainerEnd JSON), written as it exits."""
        return f"{self.base}:trainer_end"

    @property
    def segments_added(self) -> str:
        """Counter: segments ever pushed to the stream (INCRBY with each push; Redis 6.2's XINFO STREAM does not
        count the entries added, 7's does)."""
        return f"{self.base}:segments_added"

    @property
    def worker_slots(self) -> str:
        """Counter: a worker started without an index takes the next one (INCR), so compose workers get 0, 1, …"""
        return f"{self.base}:worker_slots"

    @property
    def evaluations(self) -> str:
        """List: a JSON summary per evaluated checkpoint, oldest first (capped with LTRIM)."""
        return f"{self.base}:evaluations"

    @property
    def training(self) -> str:
        """String key with a TTL, present while the trainer runs a PPO update (value: the version it trains from).
        Workers whose next segment would be too old to use wait instead of burning the CPU the update needs."""
        return f"{self.base}:training"

    # --- racer view: what the workers publish only while a page watches (docs/view.md) ----------------------
    @property
    def watchers(self) -> str:
        """String key with a short TTL, present while a ``racer view`` page is open: only then do workers publish
        their poses (they read it at most once a second, so a run nobody watches pays nothing else)."""
        return f"{self.base}:watchers"

    def camera_watch(self, worker_id: str) -> str:
        """String key with a short TTL, present while a page shows worker ``worker_id``'s camera: only then does it
        publish frames."""
        return f"{self.base}:watch_camera:{worker_id}"

    def pose(self, worker_id: str) -> str:
        """String key with a short TTL: a watched worker's latest pose (CarPose JSON)."""
        return f"{self.base}:pose:{worker_id}"

    @property
    def pose_pattern(self) -> str:
        """SCAN pattern matching every worker's pose key."""
        return f"{self.base}:pose:*"

    def frame(self, worker_id: str) -> str:
        """String key with a short TTL: a watched worker's latest camera frame, JPEG bytes."""
        return f"{self.base}:frame:{worker_id}"
