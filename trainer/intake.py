"""The trainer's intake: segments read from Redis, checked, and buffered until the next update."""

from __future__ import annotations

import logging
import statistics
import time
from collections import deque
from dataclasses import dataclass, field

from common.bus import Bus
from common.protocol import EpisodeSummary, ProtocolError, Segment, decode_segment
from common.sensors import LidarSpec

log = logging.getLogger("racer.trainer")

SEEN_SEGMENTS = 4096
"""Segments remembered for dropping duplicates: minutes of segments, longer than TCP keeps retrying a lost one."""


@dataclass
class Stats:
    """What the trainer has seen, for the status line and the metrics."""

    env_steps: int = 0
    episodes: int = 0
    iteration: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    dropped_steps: int = 0
    """Env steps in the dropped segments that could be decoded (a malformed one's steps are unknown)."""
    lag: deque[int] = field(default_factory=lambda: deque(maxlen=1000))
    """Policy lag of the most recent segments (bounded: a run lasts hours)."""
    recent: list[EpisodeSummary] = field(default_factory=list)
    by_worker: dict[str, int] = field(default_factory=dict)
    """Segments accepted from each worker id."""
    started: float = field(default_factory=time.monotonic)

    def steps_per_s(self) -> float:
        """Env steps accepted per second since the trainer started."""
        elapsed = time.monotonic() - self.started
        return self.env_steps / elapsed if elapsed > 0 else 0.0

    def counts(self) -> dict[str, int]:
        """What a checkpoint's metadata records of the run so far."""
        return {"env_steps": self.env_steps, "episodes": self.episodes, "iteration": self.iteration}

    def figures(self) -> dict:
        """The counters of the trainer's status (the last 20 episodes for the means)."""
        recent = self.recent[-20:]
        return {
            "iteration": self.iteration,
            "env_steps": self.env_steps,
            "episodes": self.episodes,
            "steps_per_s": self.steps_per_s(),
            "mean_progress": statistics.fmean(e.progress for e in recent) if recent else 0.0,
            "mean_reward": statistics.fmean(e.reward for e in recent) if recent else 0.0,
            "dropped": dict(self.dropped),
            "dropped_steps": self.dropped_steps,
            "max_lag": max(list(self.lag)[-200:], default=0),
            "segments_by_worker": dict(self.by_worker),
        }

    def drop(self, reason: str, steps: int = 0) -> None:
        """Count a dropped segment (of ``steps`` env steps, where it could be read)."""
        self.dropped[reason] = self.dropped.get(reason, 0) + 1
        self.dropped_steps += steps


class SegmentIntake:
    """The buffer of accepted segments, filled by ``read`` from the run's stream; counts what it drops."""

    def __init__(
        self,
        bus: Bus,
        run_id: str,
        lidar: LidarSpec | None,
        obs_shape: tuple[int, ...],
        *,
        n_actions: int | None,
        stats: Stats,
        label_width: int | None = None,
    ) -> None:
        self.bus, self.run_id = bus, run_id
        self.obs_shape, self.n_actions, self.lidar = obs_shape, n_actions, lidar
        self.label_width = label_width
        """The width of a distilling run's teacher labels (``decode_segment``'s ``teacher_width``); None otherwise."""
        self.stats = stats
        self.buffer: list[Segment] = []
        self.last_id = "0-0"
        self._seen: deque[tuple[str, float]] = deque(maxlen=SEEN_SEGMENTS)
        """(worker id, created) of the segments read last, to drop a second copy of one (see ``accept``)."""

    def read(self, version: int, floor: int, max_lag: int, block_ms: int = 500, count: int = 64) -> int:
        """Pull new segments into the buffer (validating, dropping stale ones) given the current policy
        ``version``, the lineage's first version ``floor`` and the run's ``max_lag``; returns how many were kept."""
        entries = self.bus.read_segments(self.last_id, count, block_ms)
        kept = 0
        for entry_id, fields in entries:
            self.last_id = entry_id
            kept += self.accept(fields, version, floor, max_lag)
        if entries:
            # Entries read are in the buffer now: free them in Redis at once rather than when MAXLEN pushes them out.
            self.bus.drop_segments_through(self.last_id)
        return kept

    def accept(self, fields: dict, version: int, floor: int, max_lag: int) -> int:
        """Decode one stream entry and keep it (1) or count why it was dropped (0)."""
        try:
            seg = decode_segment(
                fields, self.run_id, self.obs_shape, self.n_actions, lidar=self.lidar, teacher_width=self.label_width
            )
        except ProtocolError as exc:
            self.stats.drop(exc.reason)
            log.warning("dropped a segment: %s", exc)
            return 0
        # A push cut off mid-way can reach Redis twice: redis-py or the worker retries it after a timeout while the
        # first copy is still in flight (TCP delivers it once the network heals). Both copies are the same bytes.
        key = (seg.worker_id, seg.created)
        if key in self._seen:
            self.stats.drop("duplicate", seg.steps)
            log.warning("dropped a duplicate segment from worker %s: a second copy of one already read", seg.worker_id)
            return 0
        self._seen.append(key)
        lag = version - seg.policy_version
        self.stats.lag.append(lag)
        if seg.policy_version < floor:  # acted by a policy a rollback abandoned
            self.stats.drop("rolled_back", seg.steps)
            return 0
        if lag > max_lag or lag < 0:
            self.stats.drop("stale" if lag > 0 else "future_version", seg.steps)
            return 0
        self.buffer.append(seg)
        self.stats.by_worker[seg.worker_id] = self.stats.by_worker.get(seg.worker_id, 0) + 1
        self.stats.env_steps += seg.steps
        self.stats.episodes += len(seg.episodes)
        self.stats.recent = (self.stats.recent + seg.episodes)[-100:]
        return 1

    def ready(self, episodes_between_training: int, batch_size: int) -> bool:
        """True once the buffer holds ``episodes_between_training`` finished episodes and ``batch_size`` steps."""
        episodes = sum(len(s.episodes) for s in self.buffer)
        steps = sum(s.steps for s in self.buffer)
        return episodes >= episodes_between_training and steps >= batch_size

    def take(self) -> list[Segment]:
        """The buffered segments, leaving the buffer empty."""
        segments = list(self.buffer)
        self.buffer.clear()  # in place: the trainer's ``buffer`` names this list
        return segments

    def discard(self, reason: str) -> None:
        """Drop every buffered segment, counted under ``reason``."""
        for _ in self.buffer:
            self.stats.drop(reason)
        self.buffer.clear()
