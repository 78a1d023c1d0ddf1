"""common/retry.py against a real Redis that goes away and comes back."""

from __future__ import annotations

import logging
import threading
import time

import pytest
import redis

from common.redis_util import connect
from common.retry import Outage, OutageError, redis_transient
from racer.embedded_redis import EmbeddedRedis, free_port

log = logging.getLogger("test.retry")


def test_a_call_waits_through_an_outage_and_logs_its_start_and_end(caplog):
    port = free_port()
    client = connect(f"redis://127.0.0.1:{port}/0", retries=0)
    outage = Outage("Redis at test", redis_transient, log, give_up_s=30, first_delay_s=0.05, max_delay_s=0.2)
    servers = []
    threading.Timer(1.0, lambda: servers.append(EmbeddedRedis(port=port))).start()
    caplog.set_level(logging.WARNING, "test.retry")
    try:
        assert outage.call("ping", client.ping) is True
    finally:
        for s in servers:
            s.stop()
    assert outage.outages == 1
    messages = [r.getMessage() for r in caplog.records]
    assert len(messages) == 2, messages  # one line as it starts, one as it ends: no log flood while retrying
    assert messages[0].startswith("Redis at test unreachable while trying to ping")
    assert messages[1].startswith("Redis at test reachable again after")


def test_it_gives_up_after_give_up_s_with_one_line_naming_the_service():
    client = connect(f"redis://127.0.0.1:{free_port()}/0", retries=0)
    outage = Outage("Redis at nowhere", redis_transient, log, give_up_s=0.5, first_delay_s=0.05, max_delay_s=0.1)
    start = time.monotonic()
    with pytest.raises(OutageError, match=r"^Redis at nowhere unreachable for \d+ s while trying to ping: "):
        outage.call("ping", client.ping)
    assert time.monotonic() - start < 5


def test_a_stop_request_ends_the_wait():
    client = connect(f"redis://127.0.0.1:{free_port()}/0", retries=0)
    stop = threading.Event()
    threading.Timer(0.3, stop.set).start()
    with pytest.raises(InterruptedError):
        Outage("Redis", redis_transient, log, stop, give_up_s=60, first_delay_s=0.05).call("ping", client.ping)


def test_a_wrong_password_is_not_retried():
    server = EmbeddedRedis(port=free_port(), password="right")
    try:
        client = connect(f"redis://:wrong@127.0.0.1:{server.port}/0", retries=0)
        calls = []

        def ping():
            calls.append(1)
            return client.ping()

        with pytest.raises(redis.AuthenticationError):
            Outage("Redis", redis_transient, log, give_up_s=60).call("ping", ping)
        assert len(calls) == 1
    finally:
        server.stop()
