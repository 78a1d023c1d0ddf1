"""Serving ``racer view``: the run's store and Redis found, the socket bound, the token made, uvicorn started.

uvicorn (with Starlette) serves the page: a well-kept ASGI server that streams (the camera's MJPEG) without a
thread per client, shuts down on request from another thread (``racer train --view`` runs it beside the launcher's
display), and is pure Python on its h11 protocol, so it installs from wheels alone.
"""

from __future__ import annotations

import ipaddress
import logging
import secrets
import socket
import threading
from dataclasses import KW_ONLY, dataclass

import redis
import uvicorn

from common.bus import Bus
from common.config import RunConfig
from common.errors import OptionError
from common.keys import check_run_id
from common.redis_util import RedisUrlError, connect, connect_checked, redact
from model_store import RunStore, open_store
from racer.redis_record import REDIS_RECORD, live_redis_record
from racer.view.app import LOOPBACK_HOSTS, create_app
from racer.view.data import RunData
from racer.view.live import LiveFeed

log = logging.getLogger("racer.view")

DEFAULT_PORT = 8090
SHUTDOWN_S = 2
"""How long a stopping server waits for open requests (camera streams end as soon as the feed stops)."""


@dataclass
class ViewOptions:
    """What ``racer view`` serves, and where (keyword-only after the store)."""

    run_id: str
    store: str = "."
    _: KW_ONLY
    s3_endpoint: str | None = None
    redis_url: str | None = None
    """The run's Redis; None: the one a running ``racer train`` of it recorded (``racer/redis_record.py``) if it
    answers, else the store alone."""
    host: str = "127.0.0.1"
    port: int = DEFAULT_PORT
    """0: a free port."""
    run: RunConfig | None = None
    """The run's config when the caller has it (``racer train --view`` starts before the trainer stores it)."""


def is_loopback(host: str) -> bool:
    """``host`` names this machine only (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def _live_bus(opts: ViewOptions) -> tuple[Bus | None, str | None, str]:
    """(the run's bus, its URL, a note for the user): an explicit ``--redis`` must answer (a user error otherwise);
    a recorded one that does not is the run having ended."""
    if opts.redis_url:
        return Bus(connect_checked(opts.redis_url), opts.run_id), opts.redis_url, f"live from {redact(opts.redis_url)}"
    record = live_redis_record(opts.store, opts.run_id)
    url = record["url"] if record is not None else None
    if url is None:
        return None, None, "no Redis given or recorded: the run as stored"
    try:
        client = connect(url)
        client.ping()
    except (redis.RedisError, RedisUrlError) as exc:
        return None, None, f"the run's Redis ({redact(url)}) does not answer ({type(exc).__name__}): the run as stored"
    return Bus(client, opts.run_id), url, f"live from {redact(url)} (runs/{opts.run_id}/{REDIS_RECORD})"


def _bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host``:``port``; OptionError naming the option on failure."""
    if not 0 <= port <= 65535:
        raise OptionError(f"--port {port}: a port is 0 (any free one) to 65535")
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host.strip("[]"), port, type=socket.SOCK_STREAM)[0]
    except socket.gaierror as exc:
        raise OptionError(f"--host {host!r}: {exc.strerror}") from None
    sock = socket.socket(family, kind, proto)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        raise OptionError(f"--host {host} --port {port}: cannot listen there ({exc.strerror})") from None
    sock.listen(128)
    sock.set_inheritable(False)
    return sock


class ViewServer:
    """One run's page, served by uvicorn in the foreground (:meth:`serve_forever`) or in a thread (``with``)."""

    def __init__(self, opts: ViewOptions) -> None:
        """Open the store (StoreKeyError naming the run if it is not there), find its Redis, bind the socket."""
        check_run_id(opts.run_id)
        self.data = RunData(RunStore(open_store(opts.store, opts.s3_endpoint)), opts.run_id, opts.run)
        bus, self.redis_url, self.note = _live_bus(opts)
        self.sock = _bind(opts.host, opts.port)
        self.loopback = is_loopback(opts.host)
        self.token = None if self.loopback else secrets.token_urlsafe(18)
        hosts = frozenset(LOOPBACK_HOSTS | {opts.host}) if self.loopback else None
        self.live = LiveFeed(bus, self.redis_url or "") if bus is not None else None
        app = create_app(self.data, self.live, self.token, hosts)
        config = uvicorn.Config(
            app,
            log_level="warning",
            log_config=None,
            access_log=False,
            lifespan="off",
            timeout_graceful_shutdown=SHUTDOWN_S,
        )
        self.server = uvicorn.Server(config)
        self.host, self.port = opts.host, int(self.sock.getsockname()[1])
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        """The page's address as the user opens it (with the token when one is required)."""
        host = self.host
        if host in ("0.0.0.0", "::", "[::]", ""):
            host = socket.gethostname()
        elif ":" in host and not host.startswith("["):
            host = f"[{host}]"
        return f"http://{host}:{self.port}/" + (f"?token={self.token}" if self.token else "")

    def serve_forever(self) -> None:
        """Serve until Ctrl-C or SIGTERM, then stop cleanly (exit code 0: uvicorn's own handlers would re-raise the
        signal once it has stopped)."""
        from racer.lifecycle import stop_event_on_signals

        stop = stop_event_on_signals()
        with self:
            while not stop.wait(0.5):
                if self._thread is None or not self._thread.is_alive():
                    raise RuntimeError("racer view's server stopped on its own")

    def __enter__(self) -> ViewServer:
        """Serve from a daemon thread until the ``with`` block ends."""
        self._thread = threading.Thread(
            target=self.server.run, kwargs={"sockets": [self.sock]}, name="racer-view", daemon=True
        )
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        """Stop serving and wait for the thread."""
        self.close()

    def close(self) -> None:
        """Stop the live feed (camera streams end) and the server; idempotent."""
        if self.live is not None:
            self.live.close()
        self.server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=SHUTDOWN_S + 3)
            self._thread = None
        self.sock.close()
