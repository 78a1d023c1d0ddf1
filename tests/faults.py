"""Fault injection for the tests: real role processes, and a TCP proxy that can cut or hold a service's traffic.

The proxy stands between a role process and a real server (moto's S3 server, redis-server). It forwards bytes
unchanged until the test says otherwise: ``down()`` closes every connection and refuses new ones (an unreachable
service), ``hold(pattern)`` stops forwarding a request whose bytes match (an upload caught in mid-flight).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from common.defaults import STRAIGHT_TRACK
from racer.runconfig import build_run
from rollout_worker.worker import RolloutWorker, WorkerOptions
from trainer.process import Trainer, TrainerOptions

FAST_HP = {"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2, "lr": 0.001, "discount_factor": 0.99}


class TcpProxy:
    """127.0.0.1:<port> → ``target``; see the module docstring."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.target = target
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = self._listener.getsockname()[1]
        self._down = threading.Event()
        self._hold: re.Pattern[bytes] | None = None
        self.held = threading.Event()
        """Set once a request matching the hold pattern arrived (and was not forwarded)."""
        self._conns: set[socket.socket] = set()
        self._lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    @property
    def url(self) -> str:
        """``http://127.0.0.1:<port>``."""
        return f"http://127.0.0.1:{self.port}"

    def down(self) -> None:
        """Cut every open connection and refuse new ones until ``up()``."""
        self._down.set()
        with self._lock:
            for c in self._conns:
                with contextlib.suppress(OSError):
                    c.shutdown(socket.SHUT_RDWR)
            self._conns.clear()

    def up(self) -> None:
        """Forward again (and release any held request's connection: it was cut)."""
        self._hold = None
        self._down.clear()

    def hold(self, pattern: bytes) -> None:
        """Stop forwarding any client chunk matching ``pattern`` (a regex on the raw bytes), and set ``held``."""
        self.held.clear()
        self._hold = re.compile(pattern)

    def close(self) -> None:
        """Stop listening and cut everything."""
        self.down()
        self._listener.close()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            if self._down.is_set():
                client.close()
                continue
            try:
                upstream = socket.create_connection(self.target)
            except OSError:
                client.close()
                continue
            with self._lock:
                self._conns |= {client, upstream}
            threading.Thread(target=self._pipe, args=(client, upstream, True), daemon=True).start()
            threading.Thread(target=self._pipe, args=(upstream, client, False), daemon=True).start()

    def _pipe(self, src: socket.socket, dst: socket.socket, from_client: bool) -> None:
        try:
            while chunk := src.recv(65536):
                hold = self._hold
                if from_client and hold is not None and hold.search(chunk):
                    self.held.set()
                    while not self._down.is_set():  # never forward it; the connection dies with down()
                        time.sleep(0.05)
                    return
                dst.sendall(chunk)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)
                s.close()


def write_run(tmp: Path, run_id: str, **updates) -> Path:
    """A small fast run on STRAIGHT_TRACK (config + files) for ``racer trainer --config``; returns the config."""
    (tmp / "hp.json").write_text(json.dumps(FAST_HP))
    run, files = build_run(run_id, track=STRAIGHT_TRACK, hyperparams=str(tmp / "hp.json"))
    run = run.model_copy(update={"segment_steps": 16, "heartbeat_ttl_s": 3.0, **updates})
    files_dir = tmp / "files"
    files_dir.mkdir(exist_ok=True)
    for name, data in files.items():
        (files_dir / name).write_bytes(data)
    config = files_dir / "run.json"
    config.write_text(run.model_dump_json())
    return config


def store_args(store: str, endpoint: str | None) -> list[str]:
    """``--store`` (and ``--s3-endpoint``) for a role."""
    return ["--store", store, *(["--s3-endpoint", endpoint] if endpoint else [])]


def spawn(args: list[str], log: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    """``python -m racer ARGS`` with its output appended to ``log``."""
    with log.open("ab") as out:
        return subprocess.Popen(
            [sys.executable, "-m", "racer", *args],
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
        )


def spawn_trainer(config: Path, redis_url: str, store: list[str], log: Path, resume: bool = False):
    """A ``racer trainer`` process for the run in ``config``."""
    args = ["trainer", "--config", str(config), "--files", str(config.parent), "--redis", redis_url, *store]
    return spawn(args + (["--resume"] if resume else []), log)


def spawn_worker(run_id: str, index: int, redis_url: str, store: list[str], log: Path) -> subprocess.Popen:
    """A ``racer worker`` process."""
    return spawn(["worker", "--run-id", run_id, "--index", str(index), "--redis", redis_url, *store], log)


def wait_for(predicate, timeout: float, what: str, poll: float = 0.2, alive: tuple[subprocess.Popen, ...] = ()):
    """Poll until ``predicate()`` is truthy and return it; AssertionError naming ``what`` on timeout, or at once
    if a process in ``alive`` exits."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        dead = [p.args[3] for p in alive if p.poll() is not None]
        if dead:
            raise AssertionError(f"{', '.join(dead)} exited while waiting for {what}")
        time.sleep(poll)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def stop(*procs: subprocess.Popen, grace: float = 15.0) -> None:
    """SIGTERM, then SIGKILL whoever is still alive after ``grace`` seconds."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(grace)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def rss_mb(pid: int) -> float:
    """Current resident memory of a process, MB (from /proc)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError(f"no VmRSS for pid {pid}")


def trainer_and_worker(url: str, store: str, tmp: Path, run_id: str) -> tuple[Trainer, RolloutWorker]:
    """An in-process trainer (started, v0 published) and worker (started) of a small run on racer's straight track."""
    (tmp / "hp.json").write_text(json.dumps(FAST_HP))
    run, files = build_run(run_id, track=STRAIGHT_TRACK, hyperparams=str(tmp / "hp.json"))
    run = run.model_copy(update={"segment_steps": 8})
    trainer = Trainer(run, TrainerOptions(url, store, run_files=files, tensorboard=False))
    trainer.start()
    worker = RolloutWorker(WorkerOptions(run_id, url, store, worker_index=0))
    worker.start()
    return trainer, worker
