"""What ``racer view`` costs a rollout worker: its step time with nobody watching and with one page watching.

A real worker (``rollout_worker/worker.py``: env, policy, the ``WatchPublisher``) acts with a real run's v0 policy
against an embedded Redis; ``racer view`` runs as its own process, and "one page watching" is a third process that
does what the page does (polls ``/api/live`` five times a second and holds the chosen worker's MJPEG camera stream
open), so the worker publishes poses and 15 frames/s. Three conditions are timed in interleaved blocks of
``seconds`` each, ``repeats`` times: the worker without a publisher at all, with its publisher and nobody watching,
and with one page watching. Each block times ``RolloutWorker.collect`` (the step loop the publisher is called from):
wall clock and the process's CPU time per step, which on a shared machine move with everything else running, and
the publisher's own cost, measured directly: the wall time inside its ``step`` calls (all it does runs there), as a
share of the block's. Figures are medians over the blocks.
"""

from __future__ import annotations

import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

from common.defaults import DEFAULT_TRACK
from racer.bench import Report
from racer.embedded_redis import EmbeddedRedis
from racer.runconfig import build_run
from rollout_worker.worker import RolloutWorker, WorkerOptions
from trainer.peak import cpu_model
from trainer.process import Trainer, TrainerOptions

RUN_ID = "bench-view"
WORKER_ID = "bench-worker-0"
CONDITIONS = ("no publisher", "nobody watching", "one page watching")
SETTLE_S = 20.0
"""Longest wait for the worker to notice a page opening or closing (the marks expire in ~4 s)."""

_PAGE = """
import http.client, sys, threading, time, urllib.request
port, worker = int(sys.argv[1]), sys.argv[2]
def live():
    while True:
        urllib.request.urlopen(f"http://127.0.0.1:{port}/api/live", timeout=10).read()
        time.sleep(0.2)
threading.Thread(target=live, daemon=True).start()
conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
conn.request("GET", f"/api/camera?worker={worker}")
response = conn.getresponse()
while response.read1(65536):
    pass
"""
"""The page's traffic without a browser: the live poll and the camera stream."""


class _NoPublisher:
    """Stands in for ``WatchPublisher`` in the "no publisher" blocks."""

    watched = camera = False
    frames = 0
    spent = 0.0

    def step(self, observation: Any, info: dict) -> None:
        """Nothing."""


class _Timed:
    """A ``WatchPublisher`` whose ``step`` calls are timed by the wall clock. (Not by the thread's CPU clock: reading
    it is a system call, and on a loaded machine the process was often descheduled right there, which made calls of
    a few microseconds look milliseconds long.)"""

    def __init__(self, publisher: Any) -> None:
        self.publisher, self.spent = publisher, 0.0

    @property
    def frames(self) -> int:
        """Frames the publisher has sent."""
        return self.publisher.frames

    def step(self, observation: Any, info: dict) -> None:
        """The publisher's step, timed."""
        t0 = time.perf_counter()
        self.publisher.step(observation, info)
        self.spent += time.perf_counter() - t0


def _start_view(store: str, redis_url: str) -> tuple[subprocess.Popen, int]:
    """``racer view`` of the bench's run as its own process; (process, port)."""
    cmd = [sys.executable, "-m", "racer", "view", "--run-id", RUN_ID, "--store", store, "--redis", redis_url]
    proc = subprocess.Popen([*cmd, "--port", "0"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    for line in proc.stdout:
        if m := re.search(r"racer view: http://[^:]+:(\d+)/", line):
            return proc, int(m.group(1))
    raise RuntimeError(f"racer view exited with code {proc.wait()} before printing its URL")


def _settle(worker: RolloutWorker, publisher: Any, watched: bool) -> None:
    """Step the worker now and then until its publisher sees (or no longer sees) a page showing its camera."""
    deadline = time.monotonic() + SETTLE_S
    while (publisher.camera if watched else publisher.watched) != watched:
        if time.monotonic() > deadline:
            raise RuntimeError(f"the worker did not notice the page {'opening' if watched else 'closing'}")
        worker.collect()
        time.sleep(0.3)


def _block(worker: RolloutWorker, seconds: float) -> dict[str, float]:
    """Time ``collect`` for about ``seconds``: wall and CPU ms per step, and frames published a second."""
    frames0, steps = worker.rollouts.envs[0].watch.frames, 0
    wall0, cpu0 = time.perf_counter(), time.process_time()
    while time.perf_counter() - wall0 < seconds:
        worker.collect()
        steps += worker.run.segment_steps
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    return {
        "steps": steps,
        "wall_ms_per_step": 1000 * wall / steps,
        "cpu_ms_per_step": 1000 * cpu / steps,
        "frames_per_s": (worker.rollouts.envs[0].watch.frames - frames0) / wall,
        "publisher_us_per_step": 1e6 * worker.rollouts.envs[0].watch.spent / steps,
        "publisher_share": worker.rollouts.envs[0].watch.spent / wall,
    }


def bench_view(seconds: float = 3.0, repeats: int = 5, track: str = DEFAULT_TRACK) -> dict[str, Any]:
    """Worker step time in each of ``CONDITIONS``, interleaved blocks; medians, and the ratios to compare."""
    torch.set_num_threads(1)  # as racer worker runs (rollout_worker/worker.py: run_worker)
    blocks: dict[str, list[dict[str, float]]] = {c: [] for c in CONDITIONS}
    with tempfile.TemporaryDirectory(prefix="racer-bench-view-") as tmp, EmbeddedRedis() as server:
        store = str(Path(tmp) / "store")
        run, files = build_run(RUN_ID, track=track)
        trainer = Trainer(run, TrainerOptions(server.url, store, run_files=files))
        trainer.start()  # stores and publishes v0
        trainer.close()  # and is not needed again: the bench times the worker
        worker = RolloutWorker(WorkerOptions(RUN_ID, server.url, store, worker_id=WORKER_ID))
        worker.start()
        publisher = worker.rollouts.envs[0].watch
        view, port = _start_view(store, server.url)
        page: subprocess.Popen | None = None
        try:
            for _ in range(repeats):
                for condition in CONDITIONS:
                    if condition == "one page watching":
                        page = subprocess.Popen([sys.executable, "-c", _PAGE, str(port), WORKER_ID])
                    _settle(worker, publisher, watched=page is not None)
                    worker.rollouts.envs[0].watch = _NoPublisher() if condition == "no publisher" else _Timed(publisher)
                    blocks[condition].append(_block(worker, seconds))
                    worker.rollouts.envs[0].watch = publisher
                    if page is not None:
                        page.kill()
                        page.wait()
                        page = None
        finally:
            for proc in (page, view):
                if proc is not None:
                    proc.kill()
                    proc.wait()
            worker.close()
    return _summary(blocks, seconds, track)


def _summary(blocks: dict[str, list[dict[str, float]]], seconds: float, track: str) -> dict[str, Any]:
    median = {c: {k: statistics.median(b[k] for b in bs) for k in bs[0]} for c, bs in blocks.items()}
    none, idle, watched = (median[c] for c in CONDITIONS)
    return {
        "track": track,
        "seconds_per_block": seconds,
        "repeats": len(blocks[CONDITIONS[0]]),
        "machine": cpu_model(),
        "median": median,
        "watched_vs_nobody_wall": watched["wall_ms_per_step"] / idle["wall_ms_per_step"],
        "watched_vs_nobody_cpu": watched["cpu_ms_per_step"] / idle["cpu_ms_per_step"],
        "nobody_vs_no_publisher_wall": idle["wall_ms_per_step"] / none["wall_ms_per_step"],
        "nobody_vs_no_publisher_cpu": idle["cpu_ms_per_step"] / none["cpu_ms_per_step"],
        "publisher_share_watched": watched["publisher_share"],
        "publisher_share_nobody": idle["publisher_share"],
        "blocks": blocks,
    }


def report_lines(result: dict[str, Any]) -> list[str]:
    """What ``racer bench view`` prints: each condition's medians, then the two ratios."""
    lines = [f"{result['repeats']} × {result['seconds_per_block']:.0f} s blocks per condition, interleaved"]
    for condition, m in result["median"].items():
        lines.append(
            f"{condition:>18}: {m['wall_ms_per_step']:.3f} ms/step wall, {m['cpu_ms_per_step']:.3f} ms/step CPU, "
            f"{m['frames_per_s']:.1f} frames/s; publisher: in the step loop {m['publisher_us_per_step']:.1f} µs/step "
            f"({100 * m['publisher_share']:.2f} % of the wall time)"
        )
    lines.append(
        f"one page watching / nobody watching: {result['watched_vs_nobody_wall']:.3f} wall, "
        f"{result['watched_vs_nobody_cpu']:.3f} CPU"
    )
    lines.append(
        f"nobody watching / no publisher: {result['nobody_vs_no_publisher_wall']:.3f} wall, "
        f"{result['nobody_vs_no_publisher_cpu']:.3f} CPU"
    )
    return lines


def command(seconds: float, repeats: int, track: str) -> Report:
    """``racer bench view``: each condition's medians and the two ratios, a line each."""
    result = bench_view(seconds, repeats, track)
    return Report(result, list(report_lines(result)))
