"""Benchmarks of the distributed loop: transport cost, throughput with N workers, policy propagation, memory."""

from __future__ import annotations

import io
import statistics
import tempfile
import threading
import time

import redis
from rich.console import Console
from rich.table import Table

from common.bus import Bus
from common.defaults import DEFAULT_TRACK
from common.protocol import encode_segment
from model_store import LocalStore, RunStore
from racer.bench import Report, figures_table
from racer.embedded_redis import EmbeddedRedis
from racer.launcher import run_train
from racer.options import RunOptions
from racer.runconfig import build_run
from rollout_worker.worker import RolloutWorker, WorkerOptions
from trainer.process import Trainer, TrainerOptions


def bench_transport(track: str = DEFAULT_TRACK, segment_steps: int = 32, segments: int = 30) -> dict:
    """Time to simulate a segment (env + policy) against the time to move it through Redis (encode, XADD,
    XREAD, decode), in one process on one core, with a real Redis on a unix socket."""
    with EmbeddedRedis() as server, tempfile.TemporaryDirectory() as store:
        run, files = build_run("bench-transport", track=track)
        run = run.model_copy(update={"segment_steps": segment_steps, "stream_maxlen": 4 * segments})
        trainer = Trainer(run, TrainerOptions(server.url, store, run_files=files))
        trainer.start()
        worker = RolloutWorker(WorkerOptions(run.run_id, server.url, store))
        worker.start()
        sim, push, pull = [], [], []
        for _ in range(segments):
            t0 = time.perf_counter()
            [seg] = worker.collect()
            t1 = time.perf_counter()
            worker.push([seg])
            t2 = time.perf_counter()
            kept = trainer.read(block_ms=1000)
            t3 = time.perf_counter()
            assert kept == 1, "the segment should reach the trainer"
            sim.append(t1 - t0)
            push.append(t2 - t1)
            pull.append(t3 - t2)
        worker.close()
        trainer.close()
    transport = [a + b for a, b in zip(push, pull, strict=True)]
    return {
        "segment_steps": segment_steps,
        "segment_bytes": sum(len(k) + len(v) for k, v in encode_segment(seg).items()),  # one stream entry
        "simulate_ms": statistics.median(sim) * 1e3,
        "push_ms": statistics.median(push) * 1e3,
        "pull_ms": statistics.median(pull) * 1e3,
        "transport_fraction": statistics.median(transport) / statistics.median(sim),
    }


class _Monitor(threading.Thread):
    """Polls Redis during a run: policy versions, when each worker started acting with them, memory."""

    def __init__(self, url: str, run_id: str) -> None:
        super().__init__(daemon=True)
        self.bus = Bus(redis.Redis.from_url(url), run_id)
        self.published: dict[int, float] = {}
        self.loaded: dict[int, dict[str, float]] = {}
        self.worker_rss: dict[str, float] = {}
        self.trainer_rss = 0.0
        self.redis_peak = 0
        self.halt = threading.Event()

    def run(self) -> None:
        while not self.halt.wait(0.1):
            try:
                self._poll()
            except redis.RedisError:
                continue

    def _poll(self) -> None:
        pv = self.bus.policy()
        if pv is not None:
            self.published.setdefault(pv.version, pv.created)
        for hb in self.bus.heartbeats()[0]:
            self.loaded.setdefault(hb.policy_version, {})[hb.worker_id] = hb.policy_loaded_at
            self.worker_rss[hb.worker_id] = hb.max_rss_mb
        status = self.bus.trainer_status() or {}
        self.trainer_rss = max(self.trainer_rss, status.get("max_rss_mb", 0.0))
        self.redis_peak = max(self.redis_peak, self.bus.memory()["peak"])

    def propagation_s(self, workers: int) -> list[float]:
        """For each version seen by every worker: last worker's switch time minus the publish time."""
        out = []
        for version, created in self.published.items():
            seen = self.loaded.get(version, {})
            if version > 0 and len(seen) >= workers:
                out.append(max(seen.values()) - created)
        return out


def bench_loop(workers: int, duration_s: float, track: str = DEFAULT_TRACK, hyperparams: str | None = None) -> dict:
    """Run ``racer train`` with N workers for a while; experience consumed by the trainer, propagation, memory."""
    with EmbeddedRedis() as server, tempfile.TemporaryDirectory() as store:
        run_id = f"bench-{workers}w"
        run, files = build_run(run_id, track=track, hyperparams=hyperparams)
        monitor = _Monitor(server.url, run_id)
        monitor.start()
        t0 = time.monotonic()
        status = run_train(
            run,
            RunOptions(workers=workers, redis_url=server.url, store=store, time_limit_s=duration_s),
            files,
            Console(file=io.StringIO()),
        )
        wall = time.monotonic() - t0
        monitor.halt.set()
        monitor.join()
        rows = RunStore(LocalStore(store)).read_metrics(run_id, missing_ok=True)
    prop = monitor.propagation_s(workers)
    return {
        "workers": workers,
        "duration_s": wall,
        "env_steps_consumed": status.get("env_steps", 0),
        "consumed_steps_per_s": status.get("env_steps", 0) / wall,
        "iterations": len(rows),
        "train_s_total": sum(r["train_s"] for r in rows),
        "propagation_s_median": statistics.median(prop) if prop else None,
        "propagation_s_max": max(prop) if prop else None,
        "propagation_samples": len(prop),
        "trainer_peak_rss_mb": monitor.trainer_rss,
        "worker_peak_rss_mb": sorted(monitor.worker_rss.values()),
        "redis_peak_memory_mb": monitor.redis_peak / 2**20,
    }


def transport_command(track: str, segments: int, segment_steps: int) -> Report:
    """``racer bench transport``: on one core, the Redis transport cost of a segment against simulating it."""
    from racer.bench.env import pin_to_one_core

    pin_to_one_core()
    figures = bench_transport(track, segment_steps, segments)
    return Report(figures, [figures_table(figures, "{:.4g}")])


def command(counts: list[int], seconds: float, track: str, hyperparams: str | None) -> Report:
    """``racer bench loop``: a run of ``seconds`` for each worker count in ``counts``."""
    results = [bench_loop(n, seconds, track, hyperparams) for n in counts]
    table = Table(
        "workers", "steps/s consumed", "iterations", "propagation s (median/max)", "trainer MB", "worker MB", "redis MB"
    )
    for r in results:
        median, worst = r["propagation_s_median"], r["propagation_s_max"]
        table.add_row(
            str(r["workers"]),
            f"{r['consumed_steps_per_s']:.0f}",
            str(r["iterations"]),
            "-" if median is None else f"{median:.2f}/{worst:.2f}",
            f"{r['trainer_peak_rss_mb']:.0f}",
            ", ".join(f"{m:.0f}" for m in r["worker_peak_rss_mb"]),
            f"{r['redis_peak_memory_mb']:.0f}",
        )
    return Report(results, [table])
