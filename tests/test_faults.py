"""Faults injected into a running training run: real role processes, a real Redis, moto's S3 server over HTTP.

Each test kills or cuts off one part and checks what the issue asks: nothing whole is lost, the fault is
reported by name, and the run goes on.
"""

from __future__ import annotations

import json
import logging
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from functools import partial

import pytest
import redis
import torch

from common.defaults import STRAIGHT_TRACK
from common.keys import Keys
from common.protocol import ProtocolError, decode_segment, encode_segment
from common.weights import state_dict_from_bytes
from model_store import RunStore, open_store
from racer.embedded_redis import EmbeddedRedis, free_port
from tests.conftest import S3_BUCKET
from tests.faults import (
    TcpProxy,
    spawn_trainer,
    spawn_worker,
    stop,
    store_args,
    trainer_and_worker,
    wait_for,
    write_run,
)

PROTOCOL_DROPS = {
    "no_header", "bad_header", "schema", "missing_array", "bad_dtype", "bad_shape", "bad_length", "bad_frames",
    "corrupt",
}  # fmt: skip


def status(r: redis.Redis, keys: Keys) -> dict:
    raw = r.get(keys.trainer_status)
    return json.loads(raw) if raw else {}


def version(r: redis.Redis, keys: Keys) -> int:
    raw = r.get(keys.policy)
    return json.loads(raw)["version"] if raw else -1


def adam_steps(optimizer: bytes) -> float:
    """Adam's step count for the first parameter: the number of optimizer steps taken so far."""
    return float(torch.as_tensor(state_dict_from_bytes(optimizer)["state"][0]["step"]))


def newest_optimizer(runs: RunStore, run_id: str) -> bytes:
    """The optimizer state of the run's latest checkpoint, read while a trainer may be writing newer ones."""
    for _ in range(100):
        data = runs.load_optimizer(run_id, runs.pointer(run_id, "latest")["version"])
        if data is not None:
            return data
        time.sleep(0.05)  # the pointer moved and pruned the state between the two reads
    raise AssertionError("the latest checkpoint never had its optimizer state")


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_worker_killed_mid_segment_is_named_and_a_restarted_worker_rejoins(tmp_path, redis_url):
    run_id = "kill-worker"
    config = write_run(tmp_path, run_id)
    store = store_args(str(tmp_path / "store"), None)
    r, keys = redis.Redis.from_url(redis_url), Keys(run_id)
    trainer = spawn_trainer(config, redis_url, store, tmp_path / "trainer.log")
    workers = [spawn_worker(run_id, k, redis_url, store, tmp_path / f"worker-{k}.log") for k in range(2)]
    try:
        beats = wait_for(
            lambda: len(status(r, keys).get("workers", [])) == 2 and status(r, keys), 120, "2 workers", alive=(trainer,)
        )
        victim = next(w["worker_id"] for w in beats["workers"] if w["pid"] == workers[0].pid)
        wait_for(lambda: version(r, keys) >= 1, 120, "a first update", alive=(trainer,))
        workers[0].send_signal(signal.SIGKILL)  # mid-segment: a worker is always collecting one
        # Its heartbeat key expires after heartbeat_ttl_s (3 s); the trainer names it and goes on.
        wait_for(
            lambda: victim in status(r, keys).get("silent_workers", []),
            30,
            "the victim reported silent",
            alive=(trainer,),
        )
        assert f"worker {victim} is silent" in (tmp_path / "trainer.log").read_text()
        v_silent = version(r, keys)
        wait_for(lambda: version(r, keys) >= v_silent + 2, 120, "training to go on with one worker", alive=(trainer,))

        # A restarted worker (same index, new process) rejoins: its segments are accepted.
        workers[0] = spawn_worker(run_id, 0, redis_url, store, tmp_path / "worker-0b.log")
        wait_for(
            lambda: any(
                wid != victim and wid.endswith("-0") and n >= 2
                for wid, n in status(r, keys).get("segments_by_worker", {}).items()
            ),
            120,
            "the restarted worker's segments to be accepted",
            alive=(trainer,),
        )
        # The kill left no partial segment: nothing was dropped as malformed, and what is in the stream decodes.
        dropped = status(r, keys)["dropped"]
        assert not PROTOCOL_DROPS & dropped.keys(), dropped
        for _, fields in r.xrange(keys.segments):
            try:
                decode_segment(fields, run_id, (120, 160, 1), 10)
            except ProtocolError as exc:
                raise AssertionError(f"a malformed segment reached the stream: {exc}") from None
        assert trainer.poll() is None
    finally:
        stop(*workers, trainer)


def s3_behind_proxy(s3_server: str, run_id: str) -> tuple[TcpProxy, str, RunStore]:
    """A proxy in front of the moto server (for the trainer, whose store calls a test cuts or holds), the run's
    S3 prefix, and a RunStore that talks to moto directly (for the test's own reads)."""
    host, port = s3_server.removeprefix("http://").split(":")
    prefix = f"s3://{S3_BUCKET}/{run_id}"
    return TcpProxy((host, int(port))), prefix, RunStore(open_store(prefix, s3_server))


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_trainer_killed_mid_checkpoint_upload_resumes_with_its_state(tmp_path, redis_url, s3_server):
    run_id = "kill-trainer"
    config = write_run(tmp_path, run_id, keep_checkpoints=100)
    proxy, prefix, runs = s3_behind_proxy(s3_server, run_id)
    trainer_store = store_args(prefix, proxy.url)
    r, keys = redis.Redis.from_url(redis_url), Keys(run_id)
    log = tmp_path / "trainer.log"
    trainer = spawn_trainer(config, redis_url, trainer_store, log)
    worker = spawn_worker(run_id, 0, redis_url, store_args(prefix, s3_server), tmp_path / "worker.log")
    try:
        wait_for(lambda: version(r, keys) >= 2, 180, "two updates", alive=(trainer,))
        # 1. Killed after the .pt and before its .json: the pointer still names the previous, whole checkpoint.
        proxy.hold(rb"PUT /[^ ]*/checkpoints/\d{9}\.json ")
        assert proxy.held.wait(120), "the trainer should write another checkpoint"
        trainer.send_signal(signal.SIGKILL)
        trainer.wait()
        latest = runs.pointer(run_id, "latest")
        orphan = latest["version"] + 1
        assert runs.store.exists(f"runs/{run_id}/checkpoints/{orphan:09d}.pt"), "killed mid-upload"
        assert not runs.store.exists(f"runs/{run_id}/checkpoints/{orphan:09d}.json")
        payload, meta = runs.load_checkpoint(run_id, "latest")  # whole: size and metadata agree
        steps_before = adam_steps(runs.load_optimizer(run_id, meta["version"]))

        proxy.up()
        trainer = spawn_trainer(config, redis_url, trainer_store, log, resume=True)
        wait_for(
            lambda: (runs.pointer(run_id, "latest") or {}).get("version", 0) >= orphan + 1,
            180,
            "resumed updates",
            alive=(trainer,),
        )
        assert f"resumed run {run_id} at version {meta['version']}" in log.read_text()
        payload2, meta2 = runs.load_checkpoint(run_id, orphan)  # the half-written one was replaced, whole
        assert meta2["iteration"] == meta["iteration"] + 1
        assert meta2["env_steps"] > meta["env_steps"]
        # The orphan's own optimizer state is pruned once a newer checkpoint is written: read the newest one's.
        assert adam_steps(newest_optimizer(runs, run_id)) > steps_before, "the optimizer state was carried over"

        # 2. Killed after a checkpoint's .json and before the pointer: resume from that whole checkpoint.
        proxy.hold(rb"PUT /[^ ]*/latest\.json ")
        assert proxy.held.wait(120)
        trainer.send_signal(signal.SIGKILL)
        trainer.wait()
        pointed = runs.pointer(run_id, "latest")["version"]
        whole = runs.newest_whole(run_id)
        assert whole == pointed + 1, (pointed, whole)
        proxy.up()
        # Restarted as compose would restart it, without --resume: a trainer never starts its run over.
        trainer = spawn_trainer(config, redis_url, trainer_store, log)
        wait_for(
            lambda: (runs.pointer(run_id, "latest") or {}).get("version", 0) >= whole + 1,
            180,
            "updates",
            alive=(trainer,),
        )
        assert "already has checkpoints" in log.read_text() and "continuing it (as --resume)" in log.read_text()
        assert f"version {whole} is whole: resuming from it" in log.read_text()
        versions = [c["version"] for c in runs.list_checkpoints(run_id)]
        assert versions == list(range(versions[-1] + 1)), "every version is whole, none skipped"
    finally:
        stop(worker, trainer)
        proxy.close()


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_redis_restart_is_ridden_out_by_trainer_and_worker(tmp_path):
    run_id = "redis-restart"
    config = write_run(tmp_path, run_id)
    port = free_port()
    server = EmbeddedRedis(port=port)
    url = server.url
    store = store_args(str(tmp_path / "store"), None)
    trainer = spawn_trainer(config, url, store, tmp_path / "trainer.log")
    worker = spawn_worker(run_id, 0, url, store, tmp_path / "worker.log")
    keys = Keys(run_id)
    try:
        r = redis.Redis.from_url(url)
        wait_for(lambda: version(r, keys) >= 1, 120, "a first update", alive=(trainer,))
        before = version(r, keys)
        server.stop()  # no persistence: it comes back empty, as a crashed Redis would
        time.sleep(6)
        server = EmbeddedRedis(port=port)
        r = redis.Redis.from_url(url)
        # The trainer publishes its policy again, the worker sends again, and training goes on.
        wait_for(lambda: version(r, keys) > before, 120, "an update after the restart", alive=(trainer,))
        for role in ("trainer", "worker"):
            text = (tmp_path / f"{role}.log").read_text()
            assert "unreachable while trying to" in text, role
            assert "reachable again after" in text, role
        assert trainer.poll() is None and worker.poll() is None
    finally:
        stop(worker, trainer)
        server.stop()


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_store_outage_during_a_checkpoint_upload_loses_nothing(tmp_path, redis_url, s3_server):
    run_id = "store-outage"
    config = write_run(tmp_path, run_id, keep_checkpoints=100)
    proxy, prefix, runs = s3_behind_proxy(s3_server, run_id)
    r, keys = redis.Redis.from_url(redis_url), Keys(run_id)
    log = tmp_path / "trainer.log"
    trainer = spawn_trainer(config, redis_url, store_args(prefix, proxy.url), log)
    worker = spawn_worker(run_id, 0, redis_url, store_args(prefix, s3_server), tmp_path / "worker.log")
    try:
        wait_for(lambda: version(r, keys) >= 1, 180, "a first update", alive=(trainer,))
        proxy.hold(rb"PUT /[^ ]*/checkpoints/\d{9}\.pt ")
        assert proxy.held.wait(120)
        cut = version(r, keys) + 1  # the checkpoint being uploaded when the store went away
        proxy.down()
        time.sleep(8)
        assert "unreachable while trying to save checkpoint" in log.read_text()
        proxy.up()
        wait_for(lambda: version(r, keys) >= cut + 1, 180, "updates after the outage", alive=(trainer,))
        assert "reachable again after" in log.read_text()
        versions = [c["version"] for c in runs.list_checkpoints(run_id)]
        assert versions == list(range(versions[-1] + 1)) and cut in versions, versions
        assert trainer.poll() is None
    finally:
        stop(worker, trainer)
        proxy.close()


@pytest.mark.slow(reason="runs racer train with its real processes")
def test_a_reward_function_failing_mid_run_stops_racer_train_with_one_line(tmp_path, redis_url):
    """User code that passes the start-up check and raises later: the worker stops on it, is not restarted
    (a user error), and racer train ends at once naming the file, the error and the step."""
    (tmp_path / "reward.py").write_text(
        "def reward_function(params):\n"
        "    if params['steps'] > 20:\n"
        "        raise ValueError('boom at a late step')\n"
        "    return 1.0\n"
    )
    cmd = ["train", "--workers", "1", "--track", STRAIGHT_TRACK, "--reward-fn", "reward.py", "--no-eval"]
    cmd += ["--time-limit", "300s", "--redis", redis_url, "--run-id", "bad-reward"]
    t0 = time.monotonic()
    out = subprocess.run(
        [sys.executable, "-m", "racer", *cmd], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 2, out.stdout + out.stderr
    error = [line for line in out.stderr.splitlines() if line.startswith("error:")]
    assert len(error) == 1 and "raised ValueError: boom at a late step" in error[0] and "at step" in error[0], error
    # It names the worker's copy of the run's reward_function.py and the line in it.
    assert "reward_function.py" in error[0] and "(line 3)" in error[0] and "Traceback" not in out.stdout + out.stderr
    assert "not restarting" in out.stdout
    assert time.monotonic() - t0 < 120, "the run should end when its only worker stops, not at the time limit"


def test_a_full_redis_makes_workers_wait_until_the_trainer_frees_it(tmp_path, caplog):
    """Redis at its maxmemory (noeviction) refuses XADD; the worker retries the whole segment, and the trainer's
    reads trim what they consumed, so every segment arrives once and none is dropped."""
    server = EmbeddedRedis(port=free_port(), maxmemory="4mb")
    try:
        trainer, worker = trainer_and_worker(server.url, str(tmp_path / "store"), tmp_path, "oom")
        worker.run = worker.run.model_copy(update={"stream_maxlen": 1000})  # so that only memory limits the stream
        # More than 4 MB of stream entries: a segment of 8 steps is ~15 kB on the wire, so the 8 collected are sent
        # again and again, each copy a segment of its own (the trainer tells segments apart by worker and time).
        collected = [seg for _ in range(8) for seg in worker.collect()]  # one env: one segment per collect
        size = max(sum(len(k) + len(v) for k, v in encode_segment(s).items()) for s in collected)
        copies = -(-(6 << 20) // size)
        segments = [replace(collected[i % 8], created=collected[i % 8].created + i) for i in range(copies)]
        caplog.set_level(logging.WARNING, "racer.worker")
        pusher = threading.Thread(
            target=lambda: [worker.redis_outage.call("push a segment", partial(worker.push, [s])) for s in segments]
        )
        pusher.start()
        wait_for(lambda: "maxmemory" in caplog.text, 60, "Redis to refuse a segment for lack of memory")
        received = 0
        deadline = time.monotonic() + 60
        while received < len(segments) and time.monotonic() < deadline:
            received += trainer.read(block_ms=200)
        pusher.join(10)
        assert received == len(segments) and worker.redis_outage.outages >= 1
        assert not trainer.stats.dropped, trainer.stats.dropped
        worker.close()
    finally:
        server.stop()
