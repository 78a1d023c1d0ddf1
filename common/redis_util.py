"""Connecting to Redis with timeouts and retries everywhere, and a clear error for a bad URL."""

from __future__ import annotations

from urllib.parse import urlsplit, urlunsplit

import redis
from redis.backoff import ExponentialBackoff
from redis.retry import Retry

SOCKET_TIMEOUT_S = 10.0
"""No Redis call waits longer than this for a reply (blocking reads use shorter block times)."""


class RedisUrlError(ValueError):
    """A Redis URL that cannot be used."""


def redact(url: str) -> str:
    """The URL without its password, for messages and logs."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    netloc = parts.netloc.rsplit("@", 1)[1]
    user = f"{parts.username}:***@" if parts.username else ":***@"
    return urlunsplit(parts._replace(netloc=user + netloc))


def connect(url: str, retries: int = 3) -> redis.Redis:
    """A client for ``redis://``, ``rediss://`` (TLS) or ``unix://`` URLs, with timeouts and backoff retries."""
    if urlsplit(url).scheme not in ("redis", "rediss", "unix"):
        raise RedisUrlError(f"Redis URL {redact(url)!r} must start with redis://, rediss:// or unix://")
    try:
        return redis.Redis.from_url(
            url,
            socket_timeout=SOCKET_TIMEOUT_S,
            socket_connect_timeout=5.0,
            health_check_interval=30,
            retry=Retry(ExponentialBackoff(cap=2.0, base=0.1), retries),
            retry_on_error=[redis.ConnectionError, redis.TimeoutError],
        )
    except ValueError as exc:
        raise RedisUrlError(f"Redis URL {redact(url)!r} is not valid: {exc}") from None
