"""Riding out an outage of Redis or the object store: retry with capped exponential backoff, say so once when
it starts and once when it ends, and give up with a one-line error after a bounded time.

Every role process (worker, trainer, evaluator) wraps its Redis and store calls in an :class:`Outage`, so a
restarted Redis or an unreachable bucket pauses a run instead of ending it, and nothing waits forever.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TypeVar

import redis

from common.defaults import DEFAULT_GIVE_UP_S
from common.errors import UserError

T = TypeVar("T")


class OutageError(UserError, RuntimeError):
    """A service stayed unreachable for longer than the process was willing to wait."""


def redis_transient(exc: BaseException) -> bool:
    """Errors that a later retry can cure: a lost or refused connection, a timeout, a full Redis.

    A wrong password is not one of them (it is a ConnectionError subclass in redis-py, but retrying cannot help).
    """
    if isinstance(exc, redis.AuthenticationError):
        return False
    return isinstance(exc, redis.ConnectionError | redis.TimeoutError | redis.exceptions.OutOfMemoryError)


class Outage:
    """Calls an operation until it succeeds, backing off while ``transient`` says the failure can pass.

    ``service`` names what is unreachable in messages (``Redis at redis://…``, ``store s3://…``); it must not hold
    credentials. ``stop`` ends the wait early with InterruptedError (SIGTERM during an outage).
    """

    def __init__(
        self,
        service: str,
        transient: Callable[[BaseException], bool],
        log: logging.Logger,
        stop: threading.Event | None = None,
        give_up_s: float = DEFAULT_GIVE_UP_S,
        first_delay_s: float = 0.25,
        max_delay_s: float = 5.0,
    ) -> None:
        self.service, self.transient, self.log = service, transient, log
        self.stop = stop or threading.Event()
        self.give_up_s, self.first_delay_s, self.max_delay_s = give_up_s, first_delay_s, max_delay_s
        self.outages = 0
        """Outages ridden out so far (each one logged once as it started and once as it ended)."""

    def call(self, what: str, fn: Callable[[], T]) -> T:
        """``fn()``, retried through transient failures; ``what`` says what was being done, for the log."""
        start: float | None = None
        delay = self.first_delay_s
        while True:
            try:
                result = fn()
            except Exception as exc:
                if not self.transient(exc):
                    raise
                start = self._failed(what, exc, start)
                if self.stop.wait(delay):
                    raise InterruptedError(f"stopped while {self.service} was unreachable") from None
                delay = min(2 * delay, self.max_delay_s)
                continue
            if start is not None:
                self._recovered(what, start)
            return result

    def _failed(self, what: str, exc: BaseException, start: float | None) -> float:
        now = time.monotonic()
        reason = " ".join(str(exc).split())[:200] or type(exc).__name__
        if start is None:
            self.log.warning(
                "%s unreachable while trying to %s (%s); retrying with backoff", self.service, what, reason
            )
            return now
        if now - start > self.give_up_s:
            raise OutageError(f"{self.service} unreachable for {now - start:.0f} s while trying to {what}: {reason}")
        return start

    def _recovered(self, what: str, start: float) -> None:
        self.outages += 1
        self.log.warning("%s reachable again after %.1f s (%s)", self.service, time.monotonic() - start, what)
