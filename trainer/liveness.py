"""The trainer process's heartbeat: a thread of its own refreshes a key with a TTL every ``TRAINER_BEAT_EVERY_S``,
saying what the main loop is doing (starting, collecting, updating, stopping) and since when.

The status key the main loop writes once a second goes quiet for as long as a PPO update runs (a minute or more on
a loaded 2-core machine), so it cannot tell a busy trainer from a dead one; this beat can: it runs beside the update
(PyTorch releases the GIL in its kernels, and a Python-heavy step still yields every switch interval).
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time

import redis

from common.bus import TRAINER_BEAT_EVERY_S, Bus
from common.deadline import Deadline
from common.protocol import EndReason, TrainerBeat, TrainerEnd, TrainerPhase

log = logging.getLogger(__name__)


class Liveness:
    """Beats for the trainer on ``bus`` from :meth:`start` until :meth:`stop`; the loop sets the phase."""

    def __init__(
        self, bus: Bus, every_s: float = TRAINER_BEAT_EVERY_S, *, stopping: threading.Event | None = None
    ) -> None:
        """``stopping``: the trainer's stop event; once it is set the beats say "stopping" (a trainer asked to stop
        finishes its PPO update first, which can take a minute)."""
        self.bus, self.every_s, self.stopping = bus, every_s, stopping
        self.phase: TrainerPhase = "starting"
        self.since = time.time()
        self.policy_version = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Beat now and then every ``every_s`` seconds in a daemon thread. A trainer starting makes a predecessor's
        end record obsolete: it is cleared."""
        self.bus.clear_trainer_end()
        self._stop.clear()
        self.beat()  # before start() returns: a status read right after it sees "starting", not "not running"
        self._thread = threading.Thread(target=self._run, name="trainer-liveness", daemon=True)
        self._thread.start()

    def set_phase(self, phase: TrainerPhase, policy_version: int) -> None:
        """The main loop moved to ``phase`` at ``policy_version``; the next beat (sent now) says so. Once stopping,
        the phase stays "stopping"."""
        if phase != self.phase and self.phase != "stopping":
            self.phase, self.since = phase, time.time()
        self.policy_version = policy_version
        self.beat()

    def beat(self) -> None:
        """Refresh the key once. A Redis error is left to the main loop's outage handling: a missed beat is only
        a beat, and the next one comes in ``every_s``."""
        if self.stopping is not None and self.stopping.is_set() and self.phase != "stopping":
            self.phase, self.since = "stopping", time.time()
        beat = TrainerBeat(
            phase=self.phase,
            since=self.since,
            policy_version=self.policy_version,
            pid=os.getpid(),
            host=socket.gethostname(),
            time=time.time(),
        )
        try:
            self.bus.beat_trainer(beat)
        except redis.RedisError as exc:
            log.debug("trainer heartbeat not sent: %s", exc)

    def end(self, reason: EndReason, policy_version: int, env_steps: int) -> None:
        """Stop beating and tell Redis the trainer has stopped, and why (``racer status`` then says so rather than
        "not running")."""
        self.stop()
        end = TrainerEnd(reason=reason, policy_version=policy_version, env_steps=env_steps, time=time.time())
        self.bus.end_trainer(end)

    def stop(self) -> None:
        """Stop beating (the key then expires, unless the trainer records its end)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            self.beat()


def end_reason(iteration: int, max_updates: int, deadline: Deadline | None) -> EndReason:
    """Why a trainer's loop stopped: its number of policy updates (``term_cond_max_episodes``), its deadline, or else
    it was asked to."""
    if iteration >= max_updates:
        return "max_updates"
    if deadline is not None and deadline.passed():
        return "time_limit"
    return "stopped"
