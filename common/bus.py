"""One run's Redis bus: every command racer sends to Redis, on the keys of :mod:`common.keys`, with the typed
messages of :mod:`common.protocol`. The roles, the launcher and the benches talk to Redis only through a
:class:`Bus`; nothing read from Redis is unpickled (segments are raw arrays, messages strict JSON).

Errors of the connection (``redis.RedisError``) pass through: the roles ride them out with ``common.retry``.
"""

from __future__ import annotations

import json
from typing import Any, NamedTuple, TypeVar

import redis

from common.keys import Keys
from common.protocol import (
    CarPose,
    EvaluationSummary,
    Heartbeat,
    PolicyVersion,
    ProtocolError,
    TrainerBeat,
    TrainerEnd,
)
from common.redis_util import connect_checked

M = TypeVar("M", CarPose, Heartbeat)
"""A JSON message kept one per key (``Bus._messages``)."""

EVALUATIONS_KEPT = 1000
"""Evaluation summaries kept in Redis (a run lasts hours; the store keeps every evaluation)."""
TRAINER_STATUS_TTL_S = 30
"""The trainer's status key expires this long after its last refresh (it refreshes every second)."""
TRAINER_BEAT_EVERY_S = 2.0
"""How often the trainer's heartbeat thread refreshes its key."""
TRAINER_BEAT_TTL_S = 15
"""The trainer's heartbeat expires this long after its last refresh: a trainer silent for 15 s is gone (its thread
beats whatever the main loop does, so a slow PPO update does not count)."""
TRAINER_END_TTL_S = 7 * 24 * 3600
"""How long a stopped trainer's end record stays (a shared Redis outlives runs; ``racer status`` reads it)."""
TRAINING_MARK_TTL_S = 600
"""The "PPO update running" mark expires on its own if the trainer dies mid-update."""
WATCH_TTL_S = 3
"""A ``racer view`` page's marks (``watchers``, ``camera_watch``) expire this long after the view's last refresh
(every second while a page polls), so workers stop publishing within ~4 s of the last page closing."""
POSE_TTL_S = 3
"""A watched worker's pose and frame keys expire this long after its last publish (a stopped worker's car leaves
the page)."""


class StreamCounts(NamedTuple):
    """The segment stream as XINFO STREAM sees it."""

    length: int
    """Entries in the stream now."""
    added: int
    """Entries ever added: XINFO STREAM's ``entries-added`` on Redis 7+, racer's own counter of pushed segments on
    6.2 (which does not count them)."""


class Bus:
    """The Redis traffic of run ``run_id`` over ``client``."""

    def __init__(self, client: redis.Redis, run_id: str) -> None:
        self.redis = client
        self.keys = Keys(run_id)

    @classmethod
    def connect(cls, url: str, run_id: str) -> Bus:
        """The bus of ``run_id`` over a checked connection to ``url`` (``common.redis_util.connect_checked``). A bad
        run id fails first, naming it, before any connection is tried."""
        keys = Keys(run_id)
        return cls(connect_checked(url), keys.run_id)

    # --- the policy: trainer → workers, evaluator ----------------------------------------------
    def publish_policy(self, pv: PolicyVersion) -> None:
        """Make ``pv`` the run's newest policy (workers poll the key between segments)."""
        self.redis.set(self.keys.policy, pv.to_json())

    def policy(self) -> PolicyVersion | None:
        """The newest published policy, None before the first; ProtocolError if the key holds something else."""
        raw = self.redis.get(self.keys.policy)
        return None if raw is None else PolicyVersion.from_json(raw)

    def has_policy(self) -> bool:
        """The policy key exists (a restarted Redis without persistence comes back without it)."""
        return bool(self.redis.exists(self.keys.policy))

    # --- segments: workers → trainer ------------------------------------------------------------
    def push_segments(
        self, segments: list[dict[str, bytes]], heartbeat: Heartbeat, maxlen: int, heartbeat_ttl_s: int
    ) -> None:
        """Append encoded segments to the capped stream, in order, and refresh the worker's heartbeat, in one round
        trip (a worker with several envs pushes one segment per env)."""
        pipe = self.redis.pipeline(transaction=False)
        for fields in segments:
            pipe.xadd(self.keys.segments, fields, maxlen=maxlen, approximate=True)
        pipe.incrby(self.keys.segments_added, len(segments))  # Redis 6.2 does not count a stream's entries added
        pipe.set(self.keys.heartbeat(heartbeat.worker_id), heartbeat.to_json(), ex=heartbeat_ttl_s)
        pipe.execute()

    def read_segments(self, after: bytes | str, count: int, block_ms: int) -> list[tuple[bytes, dict]]:
        """Up to ``count`` segments after stream id ``after`` as (id, fields), waiting up to ``block_ms`` for one."""
        reply = self.redis.xread({self.keys.segments: after}, count=count, block=block_ms)
        return [entry for _, entries in reply or [] for entry in entries]

    def drop_segments_through(self, entry_id: bytes | str) -> None:
        """Free the segments up to ``entry_id`` (read into the trainer's buffer) rather than when MAXLEN would."""
        self.redis.xtrim(self.keys.segments, minid=entry_id, approximate=True)

    def segments_queued(self) -> int:
        """Segments in the stream now."""
        return int(self.redis.xlen(self.keys.segments))

    def segment_stream(self) -> StreamCounts | None:
        """The segment stream's length now and the entries ever added to it (XINFO STREAM; reading frees none, so
        the count survives the trainer's trimming), None while the stream does not exist (before the first push)."""
        try:
            info = self.redis.xinfo_stream(self.keys.segments)
        except redis.ResponseError as exc:
            if "no such key" in str(exc).lower():
                return None
            raise
        added = info.get("entries-added")  # Redis 7+; on 6.2, racer's own count of what the pushes added
        if added is None:
            added = self.redis.get(self.keys.segments_added) or 0
        return StreamCounts(length=int(info["length"]), added=int(added))

    # --- workers: slots and heartbeats -----------------------------------------------------------
    def take_worker_slot(self) -> int:
        """The next free worker index, 0, 1, … (for workers started without one, e.g. scaled compose workers)."""
        return int(self.redis.incr(self.keys.worker_slots)) - 1

    def beat(self, heartbeat: Heartbeat, ttl_s: int) -> None:
        """Refresh a worker's heartbeat key (it expires ``ttl_s`` after the last beat)."""
        self.redis.set(self.keys.heartbeat(heartbeat.worker_id), heartbeat.to_json(), ex=ttl_s)

    def heartbeats(self) -> tuple[list[Heartbeat], int]:
        """The live workers' heartbeats (SCAN, never KEYS), and how many keys held something malformed."""
        return self._messages(self.keys.heartbeat_pattern, Heartbeat)

    # --- the trainer's state ---------------------------------------------------------------------
    def set_trainer_status(self, status: dict[str, Any]) -> None:
        """The trainer's progress for displays and health checks; expires unless refreshed."""
        self.redis.set(self.keys.trainer_status, json.dumps(status), ex=TRAINER_STATUS_TTL_S)

    def trainer_status(self) -> dict[str, Any] | None:
        """The trainer's last status, None if it is not running (or wrote none for TRAINER_STATUS_TTL_S)."""
        raw = self.redis.get(self.keys.trainer_status)
        return None if raw is None else _json_object(raw)

    def beat_trainer(self, beat: TrainerBeat) -> None:
        """Refresh the trainer process's heartbeat (expires ``TRAINER_BEAT_TTL_S`` after the last)."""
        self.redis.set(self.keys.trainer_beat, beat.to_json(), ex=TRAINER_BEAT_TTL_S)

    def trainer_beat(self) -> TrainerBeat | None:
        """The trainer's heartbeat, None if it is gone (or the key holds something malformed: never trusted)."""
        raw = self.redis.get(self.keys.trainer_beat)
        try:
            return None if raw is None else TrainerBeat.from_json(raw)
        except ProtocolError:
            return None

    def end_trainer(self, end: TrainerEnd) -> None:
        """Record why the trainer stopped, and drop its heartbeat (it is not running any more)."""
        pipe = self.redis.pipeline()
        pipe.set(self.keys.trainer_end, end.to_json(), ex=TRAINER_END_TTL_S).delete(self.keys.trainer_beat)
        pipe.execute()

    def clear_trainer_end(self) -> None:
        """A trainer (re)started: a predecessor's end record no longer describes the run."""
        self.redis.delete(self.keys.trainer_end)

    def trainer_end(self) -> TrainerEnd | None:
        """Why the run's last trainer stopped, None if none has (or the key holds something malformed)."""
        raw = self.redis.get(self.keys.trainer_end)
        try:
            return None if raw is None else TrainerEnd.from_json(raw)
        except ProtocolError:
            return None

    def mark_training(self, version: int) -> None:
        """Say a PPO update from ``version`` is running (workers with max_policy_lag 0 wait for its result)."""
        self.redis.set(self.keys.training, version, ex=TRAINING_MARK_TTL_S)

    def clear_training(self) -> None:
        """The PPO update is over (or a predecessor's mark is stale)."""
        self.redis.delete(self.keys.training)

    def training(self) -> bool:
        """A PPO update is running."""
        return bool(self.redis.exists(self.keys.training))

    # --- evaluations: evaluator → trainer, launcher ----------------------------------------------
    def report_evaluation(self, summary: EvaluationSummary) -> None:
        """Append an evaluation summary to the capped list."""
        key = self.keys.evaluations
        self.redis.pipeline().rpush(key, summary.to_json()).ltrim(key, -EVALUATIONS_KEPT, -1).execute()

    def evaluations(self, last: int | None = None) -> tuple[list[EvaluationSummary], int]:
        """The evaluation summaries, oldest first (only the ``last`` N if given), and how many were malformed."""
        raws = self.redis.lrange(self.keys.evaluations, -last if last else 0, -1)
        summaries, bad = [], 0
        for raw in raws:
            try:
                summaries.append(EvaluationSummary.from_json(raw))
            except ProtocolError:
                bad += 1
        return summaries, bad

    # --- racer view: poses and frames, published only while a page watches ------------------------------
    def watch(self, cameras: list[str], ttl_s: int = WATCH_TTL_S) -> None:
        """Say a page is open (every worker publishes its pose) and which workers' cameras it shows (those publish
        frames too), for ``ttl_s``."""
        pipe = self.redis.pipeline(transaction=False)
        pipe.set(self.keys.watchers, 1, ex=ttl_s)
        for worker_id in cameras:
            pipe.set(self.keys.camera_watch(worker_id), 1, ex=ttl_s)
        pipe.execute()

    def watched(self, worker_id: str) -> tuple[bool, bool]:
        """(a page is open, a page shows ``worker_id``'s camera), in one round trip."""
        return self.watched_reply(self.redis.execute_command(*self.watched_query(worker_id)))

    def watched_query(self, worker_id: str) -> tuple:
        """The command ``watched`` sends, for a caller that reads its reply later (``rollout_worker/watch.py``)."""
        return ("MGET", self.keys.watchers, self.keys.camera_watch(worker_id))

    @staticmethod
    def watched_reply(reply: list) -> tuple[bool, bool]:
        """``watched``'s answer from the reply to ``watched_query``."""
        page, camera = reply
        return page is not None or camera is not None, camera is not None

    def publish_pose(self, pose: CarPose, frame: bytes | None, ttl_s: int = POSE_TTL_S) -> None:
        """Set a worker's latest pose, and its latest camera frame (JPEG) if given, in one round trip."""
        pipe = self.redis.pipeline(transaction=False)
        for command in self.pose_commands(pose, frame, ttl_s):
            pipe.execute_command(*command)
        pipe.execute()

    def pose_commands(self, pose: CarPose, frame: bytes | None, ttl_s: int = POSE_TTL_S) -> list[tuple]:
        """The commands ``publish_pose`` sends, for a caller that writes them without waiting for the replies."""
        commands = [("SET", self.keys.pose(pose.worker_id), pose.to_json(), "EX", ttl_s)]
        if frame is not None:
            commands.append(("SET", self.keys.frame(pose.worker_id), frame, "EX", ttl_s))
        return commands

    def poses(self) -> tuple[list[CarPose], int]:
        """The watched workers' latest poses (SCAN, then one MGET), and how many keys held something malformed."""
        return self._messages(self.keys.pose_pattern, CarPose)

    def _messages(self, pattern: str, kind: type[M]) -> tuple[list[M], int]:
        """The messages of type ``kind`` in the keys matching ``pattern`` (SCAN, never KEYS, then one MGET), and how
        many keys held something malformed."""
        keys = list(self.redis.scan_iter(match=pattern, count=100))
        found, bad = [], 0
        for raw in self.redis.mget(keys) if keys else []:
            if raw is None:
                continue  # expired between SCAN and MGET
            try:
                found.append(kind.from_json(raw))
            except ProtocolError:
                bad += 1
        return found, bad

    def frame(self, worker_id: str) -> bytes | None:
        """A watched worker's latest camera frame (JPEG bytes, never decoded here), None if it has none."""
        return self.redis.get(self.keys.frame(worker_id))

    # --- all of it, for racer status -------------------------------------------------------------------
    def snapshot(self) -> dict[str, Any]:
        """The run as Redis sees it now: trainer status, live workers, newest policy, last evaluation, queue."""
        try:
            policy = self.policy()
        except ProtocolError:
            policy = None
        evaluations, _ = self.evaluations(last=1)
        return {
            "run_id": self.keys.run_id,
            "trainer": self.trainer_status(),
            "workers": [hb.model_dump() for hb in self.heartbeats()[0]],
            "policy": policy.model_dump() if policy else None,
            "last_evaluation": evaluations[-1].model_dump() if evaluations else None,
            "segments_queued": self.segments_queued(),
            "training": self.training(),
            "trainer_beat": _dump(self.trainer_beat()),
            "trainer_end": _dump(self.trainer_end()),
            "redis_version": self.server_version(),
        }

    # --- the server --------------------------------------------------------------------------------
    def server_version(self) -> str:
        """The Redis server's version (INFO server), e.g. ``7.0.15``: racer runs on 6.2 and 7.x."""
        return str(self.redis.info("server")["redis_version"])

    def memory(self) -> dict[str, int]:
        """Redis's used and peak memory (bytes) and its key count, for the benches."""
        info = self.redis.info("memory")
        return {
            "used": int(info["used_memory"]),
            "peak": int(info["used_memory_peak"]),
            "keys": int(self.redis.dbsize()),
        }

    def cpu_seconds(self) -> float:
        """CPU time the Redis server has used since it started (system + user, INFO cpu), for the benches."""
        info = self.redis.info("cpu")
        return float(info["used_cpu_sys"]) + float(info["used_cpu_user"])


def _json_object(raw: bytes | str) -> dict[str, Any] | None:
    try:
        value = json.loads(raw)
    except ValueError:
        return None
    return value if isinstance(value, dict) else None


def _dump(message: TrainerBeat | TrainerEnd | None) -> dict[str, Any] | None:
    return None if message is None else message.model_dump()
