"""The ``racer view`` web app (Starlette, ASGI): the page, its JSON endpoints and the camera stream.

=============================  =============================================================================
``GET /``                      the page (``static/index.html``; its script and style under ``/static/``)
``GET /api/run``               the run: id, store, tracks, sensors; whether a live Redis is attached
``GET /api/live``              the watched workers' poses, the trainer's status (keeps the workers publishing)
``GET /api/camera?worker=ID``  that worker's camera as an MJPEG stream (multipart/x-mixed-replace), ≤ 15 frames/s
``GET /api/frame?worker=ID``   its latest frame, one JPEG (404 until the worker has sent one)
``GET /api/metrics``           metrics.jsonl, one row per iteration
``GET /api/checkpoints``       the checkpoints with their ``best``/``latest`` flags, evaluation and video
``GET /api/evaluations``       each evaluation's figures
``GET /api/evaluation/{v}``    checkpoint v's whole evaluation record (trials with their trajectories)
``GET /api/video/{v}``         checkpoint v's stored evaluation MP4 (byte ranges served), 404 if there is none
``GET /api/track?name=N``      a track of the run: centre line and borders
=============================  =============================================================================

Access (``AccessCheck``): bound to a loopback address, only requests naming a loopback host are served (a page
elsewhere cannot reach the server through DNS rebinding); bound beyond loopback, every request must carry the token
printed at start, as ``?token=`` (which sets a cookie for the page's own requests) or that cookie: 403 otherwise.
"""

from __future__ import annotations

import asyncio
import hmac
import math
import re
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from common.errors import one_line
from model_store.store import StoreError, StoreKeyError
from racer.view.data import RunData
from racer.view.live import MAX_CAMERAS, LiveFeed
from rollout_worker.watch import FRAME_HZ

STATIC = Path(__file__).parent / "static"
COOKIE = "racer_view_token"
LOOPBACK_HOSTS = frozenset({"127.0.0.1", "localhost", "::1", "[::1]"})
WORKER_ID = re.compile(r"^[^\x00-\x1f*?\[\]]{1,256}$")
"""A worker id as a query value: no control characters or SCAN wildcards (it becomes part of a Redis key)."""
NO_STORE = {"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff"}
PAGE_POLICY = (
    "default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; object-src 'none'; "
    "base-uri 'none'; frame-ancestors 'none'"
)
"""The page's Content-Security-Policy: its own script, style, images and video only (it loads nothing else)."""


def finite(value: Any) -> Any:
    """``value`` with every NaN or infinity replaced by None: JSON has neither, and metrics.jsonl may (a NaN loss)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


def host_name(header: str) -> str:
    """The host of a Host header without its port: ``[::1]:8090`` → ``[::1]``, ``localhost:80`` → ``localhost``."""
    if header.startswith("["):
        return header.split("]", 1)[0] + "]"
    return header.rsplit(":", 1)[0]


def _json(content: Any, status: int = 200) -> JSONResponse:
    return JSONResponse(finite(content), status_code=status, headers=NO_STORE)


class AccessCheck:
    """ASGI middleware: the host check of a loopback bind, the token of any other (see the module docstring)."""

    def __init__(self, app: ASGIApp, token: str | None, hosts: frozenset[str] | None) -> None:
        """``token``: required on every request when set; ``hosts``: the Host names allowed (None: any)."""
        self.app, self.token, self.hosts = app, token, hosts

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Serve the request if it may be, else answer 403."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        request = Request(scope)
        if self.hosts is not None and host_name(request.headers.get("host", "")) not in self.hosts:
            await PlainTextResponse("forbidden: unknown host\n", 403)(scope, receive, send)
            return
        if self.token is None:
            await self.app(scope, receive, send)
            return
        if self._matches(request.query_params.get("token")):
            await self.app(scope, receive, self._set_cookie(send))
        elif self._matches(request.cookies.get(COOKIE)):
            await self.app(scope, receive, send)
        else:
            await PlainTextResponse("forbidden: open the URL with the token racer view printed\n", 403)(
                scope, receive, send
            )

    def _matches(self, given: str | None) -> bool:
        return given is not None and self.token is not None and hmac.compare_digest(given.encode(), self.token.encode())

    def _set_cookie(self, send: Send) -> Send:
        cookie = f"{COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict".encode()

        async def with_cookie(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []), (b"set-cookie", cookie)]}
            await send(message)

        return with_cookie


def _version(request: Request) -> int:
    return int(request.path_params["version"])


def _worker(request: Request) -> str | None:
    worker = request.query_params.get("worker", "")
    return worker if WORKER_ID.match(worker) else None


def create_app(data: RunData, live: LiveFeed | None, token: str | None, hosts: frozenset[str] | None) -> ASGIApp:
    """The app of one run: ``data`` from the store, ``live`` from Redis (None: a finished run, store only)."""

    def page(request: Request) -> Response:
        return FileResponse(STATIC / "index.html", headers={**NO_STORE, "Content-Security-Policy": PAGE_POLICY})

    def run(request: Request) -> Response:
        live_info = {"live": live is not None, "redis": live.url if live else None}
        return _json({**data.run(), **live_info})

    async def live_state(request: Request) -> Response:
        if live is None:
            return _json({"live": False, "poses": [], "trainer": None, "workers": [], "error": None})
        return _json({"live": True, **live.touch()})

    def metrics(request: Request) -> Response:
        return _json(data.metrics())

    def checkpoints(request: Request) -> Response:
        return _json(data.checkpoints())

    def evaluations(request: Request) -> Response:
        return _json(data.evaluations())

    def evaluation(request: Request) -> Response:
        try:
            return _json(data.evaluation(_version(request)))
        except StoreKeyError:
            return _json({"error": f"checkpoint {_version(request)} has no evaluation"}, 404)

    def video(request: Request) -> Response:
        payload = data.video(_version(request))
        if payload is None:
            return _json({"error": f"the store has no video of checkpoint {_version(request)}'s evaluation"}, 404)
        return _ranged(request, payload, "video/mp4")

    def track(request: Request) -> Response:
        name = request.query_params.get("name", "")
        geometry = data.track(name)
        if geometry is None:
            return _json({"error": f"track {name!r} is not one of this run's"}, 404)
        return _json(geometry)

    async def frame(request: Request) -> Response:
        worker = _worker(request)
        if live is None or worker is None:
            return _json({"error": "no live run, or no such worker"}, 404)
        if not live.want_camera(worker):
            return _json({"error": f"{MAX_CAMERAS} cameras are shown already"}, 429)
        got = live.frame(worker)
        if got is None:
            return _json({"error": f"no frame from {worker} yet (it sends them while a page shows them)"}, 404)
        return Response(got[1], media_type="image/jpeg", headers=NO_STORE)

    async def camera(request: Request) -> Response:
        worker = _worker(request)
        if live is None or worker is None:
            return _json({"error": "no live run, or no such worker"}, 404)
        if not live.want_camera(worker):
            return _json({"error": f"{MAX_CAMERAS} cameras are shown already"}, 429)
        return StreamingResponse(
            _mjpeg(request, live, worker), media_type="multipart/x-mixed-replace; boundary=frame", headers=NO_STORE
        )

    async def store_error(request: Request, exc: Exception) -> Response:
        return _json({"error": one_line(exc)}, 404 if isinstance(exc, StoreKeyError) else 503)

    routes = [
        Route("/", page),
        Route("/api/run", run),
        Route("/api/live", live_state),
        Route("/api/camera", camera),
        Route("/api/frame", frame),
        Route("/api/metrics", metrics),
        Route("/api/checkpoints", checkpoints),
        Route("/api/evaluations", evaluations),
        Route("/api/evaluation/{version:int}", evaluation),
        Route("/api/video/{version:int}", video),
        Route("/api/track", track),
        Mount("/static", StaticFiles(directory=STATIC)),
    ]
    app = Starlette(routes=routes, exception_handlers={StoreError: store_error})
    return AccessCheck(app, token, hosts)


async def _mjpeg(request: Request, live: LiveFeed, worker: str):  # noqa: ANN202 - an async generator
    """The frames of ``worker`` as multipart parts, each new frame once, until the page goes or the feed stops."""
    seen = 0
    while not live.closed and not await request.is_disconnected():
        live.want_camera(worker)
        got = live.frame(worker)
        if got is not None and got[0] != seen:
            seen, jpeg = got
            yield b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: %d\r\n\r\n%s\r\n" % (len(jpeg), jpeg)
        await asyncio.sleep(0.5 / FRAME_HZ)


_RANGE = re.compile(r"^bytes=(\d*)-(\d*)$")


def _ranged(request: Request, payload: bytes, media_type: str) -> Response:
    """``payload`` whole, or the one byte range asked for (a video element seeks with ranges): 206, or 416."""
    size = len(payload)
    headers = {"Accept-Ranges": "bytes", **NO_STORE}
    m = _RANGE.match(request.headers.get("range", "").strip())
    if not m or not (m.group(1) or m.group(2)):
        return Response(payload, media_type=media_type, headers=headers)
    if m.group(1):
        start, end = int(m.group(1)), int(m.group(2)) if m.group(2) else size - 1
    else:  # a suffix: the last N bytes
        start, end = max(size - int(m.group(2)), 0), size - 1
    end = min(end, size - 1)
    if start > end:
        return Response(status_code=416, headers={"Content-Range": f"bytes */{size}", **headers})
    headers["Content-Range"] = f"bytes {start}-{end}/{size}"
    return Response(payload[start : end + 1], status_code=206, media_type=media_type, headers=headers)
