"""``racer bench soak``: a long ``racer train`` run that samples Redis memory, keys, the stream and each role's
peak memory over time, to show that nothing grows without bound (the stream is capped and read entries are
trimmed, per-worker keys expire, the trainer keeps bounded histories)."""

from __future__ import annotations

import io
import json
import tempfile
import threading
import time

import redis
from rich.console import Console

from common.bus import Bus
from common.defaults import STRAIGHT_TRACK
from racer.bench import Report, figures_table
from racer.embedded_redis import EmbeddedRedis
from racer.launcher import run_train
from racer.options import RunOptions
from racer.runconfig import build_run

SOAK_HYPERPARAMS = {"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2}
"""Short iterations, so that a few minutes hold many PPO updates, checkpoints and prunings."""


class _Sampler(threading.Thread):
    """Every ``every_s``: Redis used memory, key count, stream length, trainer and worker peak RSS."""

    def __init__(self, url: str, run_id: str, every_s: float) -> None:
        super().__init__(daemon=True)
        self.bus, self.every_s = Bus(redis.Redis.from_url(url), run_id), every_s
        self.samples: list[dict] = []
        self.halt = threading.Event()
        self.t0 = time.monotonic()

    def run(self) -> None:
        while not self.halt.wait(self.every_s):
            try:
                self.samples.append(self._sample())
            except redis.RedisError:
                continue

    def _sample(self) -> dict:
        status = self.bus.trainer_status() or {}
        memory = self.bus.memory()
        return {
            "t_s": round(time.monotonic() - self.t0, 1),
            "redis_used_mb": memory["used"] / 2**20,
            "redis_keys": memory["keys"],
            "stream_len": self.bus.segments_queued(),
            "policy_version": status.get("policy_version"),
            "trainer_peak_rss_mb": status.get("max_rss_mb"),
            "worker_peak_rss_mb": {w["worker_id"]: w["max_rss_mb"] for w in status.get("workers", [])},
        }


def growth_in_last_third(samples: list[dict], value) -> float | None:
    """Relative growth of ``value(sample)`` from two thirds of the run to its end (peak figures only grow)."""
    points = [(s["t_s"], v) for s in samples if (v := value(s))]
    if len(points) < 3:
        return None
    end = points[-1][0]
    at = [v for t, v in points if t <= 2 * end / 3]
    return None if not at else points[-1][1] / at[-1] - 1.0


def bench_soak(
    duration_s: float, workers: int = 2, track: str = STRAIGHT_TRACK, stream_maxlen: int = 16, every_s: float = 2.0
) -> dict:
    """Run ``racer train`` for ``duration_s`` and return the samples and a summary of what grew."""
    with EmbeddedRedis() as server, tempfile.TemporaryDirectory() as store:
        hp_path = f"{store}/hp.json"
        with open(hp_path, "w") as f:
            json.dump(SOAK_HYPERPARAMS, f)
        run, files = build_run("soak", track=track, hyperparams=hp_path)
        run = run.model_copy(update={"stream_maxlen": stream_maxlen, "segment_steps": 16})
        sampler = _Sampler(server.url, run.run_id, every_s)
        sampler.start()
        opts = RunOptions(workers=workers, redis_url=server.url, store=store, time_limit_s=duration_s, evaluate=False)
        status = run_train(run, opts, files, Console(file=io.StringIO()))
        sampler.halt.set()
        sampler.join()
    s = sampler.samples
    return {
        "duration_s": duration_s,
        "workers": workers,
        "stream_maxlen": stream_maxlen,
        "iterations": status.get("iteration", 0),
        "env_steps": status.get("env_steps", 0),
        "redis_used_mb_max": max((x["redis_used_mb"] for x in s), default=None),
        "redis_used_mb_last": s[-1]["redis_used_mb"] if s else None,
        "redis_keys_max": max((x["redis_keys"] for x in s), default=None),
        "stream_len_max": max((x["stream_len"] for x in s), default=None),
        "trainer_rss_growth_last_third": growth_in_last_third(s, lambda x: x["trainer_peak_rss_mb"]),
        "worker_rss_growth_last_third": growth_in_last_third(
            s, lambda x: max(x["worker_peak_rss_mb"].values(), default=None)
        ),
        "samples": s,
    }


def command(seconds: float, workers: int, track: str, stream_maxlen: int) -> Report:
    """``racer bench soak``: a run of ``seconds``; its figures printed, its samples in the JSON too."""
    result = bench_soak(seconds, workers, track, stream_maxlen)
    summary = {k: v for k, v in result.items() if k != "samples"}
    return Report(result, [figures_table(summary, "{:.3f}")])
