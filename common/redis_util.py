"""Connecting to Redis with timeouts and retries everywhere, and a clear error for a bad URL."""

from __future__ import annotations

import time
from urllib.parse import parse_qsl, urlencode, urlsplit, urlunsplit

import redis
from redis.backoff import ExponentialBackoff
from redis.retry import Retry

from common.errors import UserError

SOCKET_TIMEOUT_S = 10.0
"""No Redis call waits longer than this for a reply (blocking reads use shorter block times)."""


class RedisUrlError(UserError, ValueError):
    """A Redis URL that cannot be used."""


def redact(url: str) -> str:
    """The URL without its password (in the user part or a ``password=`` query), for messages and logs."""
    parts = urlsplit(url)
    if parts.password is not None:
        netloc = parts.netloc.rsplit("@", 1)[1]
        user = f"{parts.username}:***@" if parts.username else ":***@"
        parts = parts._replace(netloc=user + netloc)
    if "password=" in parts.query:
        query = [(k, "***" if k == "password" else v) for k, v in parse_qsl(parts.query, keep_blank_values=True)]
        parts = parts._replace(query=urlencode(query, safe="*/"))
    out = urlunsplit(parts)
    # urlunsplit writes unix:///path as unix:/path (empty host); keep the form the user wrote.
    return out.replace(":/", ":///", 1) if url.startswith("unix:///") and not out.startswith("unix:///") else out


def connect(url: str, retries: int = 1) -> redis.Redis:
    """A client for ``redis://``, ``rediss://`` (TLS) or ``unix://`` URLs, with timeouts and one quick retry.

    One retry cures a dropped idle connection; a longer outage must reach the caller's ``common.retry.Outage``
    soon, which backs off and says so in the log. With three, a silent 20 s cut (packets dropped, no reset) was
    spent inside redis-py's own retries and the worker logged nothing (deploy/cluster/check-hosts.sh --cut drop)."""
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


STARTUP_WAIT_S = 10.0
"""How long a role process waits for Redis to answer at start (compose may start Redis a moment later)."""


def connect_checked(url: str, wait_s: float = STARTUP_WAIT_S) -> redis.Redis:
    """``connect`` plus a PING, so that a wrong host, port, password or TLS setting fails at start with one line
    naming the URL (password hidden), instead of at the first command deep inside a run."""
    probe = connect(url, retries=0)  # one attempt per try: a TLS mismatch hangs a full socket timeout each time
    deadline = time.monotonic() + wait_s
    while True:
        try:
            probe.ping()
            probe.close()
            return connect(url)
        except redis.AuthenticationError as exc:
            raise RedisUrlError(f"Redis at {redact(url)} refused the connection: {_reason(exc)}") from None
        except redis.ResponseError as exc:  # NOAUTH and friends come back as plain errors from some servers
            raise RedisUrlError(f"Redis at {redact(url)} refused the connection: {_reason(exc)}") from None
        except (redis.ConnectionError, redis.TimeoutError, OSError) as exc:
            if time.monotonic() > deadline:
                raise RedisUrlError(f"cannot reach Redis at {redact(url)}: {_reason(exc)}") from None
            time.sleep(0.5)


def _reason(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200] or type(exc).__name__
