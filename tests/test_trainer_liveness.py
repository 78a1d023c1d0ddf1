"""trainer/liveness.py and ``racer status``: a trainer in the middle of a long PPO update, starting, or stopped is
said to be so (never "not running"), against a real Redis and a real trainer."""

from __future__ import annotations

import json
import re
import threading
import time
from pathlib import Path

import pytest
import redis
from typer.testing import CliRunner

from common.bus import TRAINER_BEAT_TTL_S, TRAINER_STATUS_TTL_S, Bus
from common.deadline import Deadline
from common.protocol import PolicyVersion, TrainerBeat, TrainerEnd
from racer.cli import app
from racer.commands.roles import trainer_alive
from tests.test_training_loop import fill, start
from trainer.liveness import Liveness, end_reason


@pytest.fixture
def hp_file(tmp_path: Path) -> str:
    path = tmp_path / "hyperparameters.json"
    path.write_text(json.dumps({"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2}))
    return str(path)


def status(redis_url: str, run_id: str, *extra: str):
    """``racer status`` of the run, as a pipe reads it."""
    return CliRunner().invoke(app, ["status", "--redis", redis_url, "--run-id", run_id, *extra])


def beat(phase: str, since: float, version: int = 3) -> TrainerBeat:
    return TrainerBeat(phase=phase, since=since, policy_version=version, pid=1, host="h", time=time.time())


def test_liveness_beats_on_its_own_thread_and_says_the_phase(redis_url, run_id):
    bus = Bus(redis.Redis.from_url(redis_url), run_id)
    live = Liveness(bus, every_s=0.05)
    live.start()
    try:
        first = bus.trainer_beat()
        assert first is not None and first.phase == "starting"
        live.set_phase("updating", 4)
        now = bus.trainer_beat()
        assert now is not None and (now.phase, now.policy_version) == ("updating", 4) and now.since >= first.since
        time.sleep(0.3)  # the main thread does nothing: the beats go on
        later = bus.trainer_beat()
        assert later is not None and later.time > now.time and later.since == now.since
        assert 0 < bus.redis.ttl(bus.keys.trainer_beat) <= TRAINER_BEAT_TTL_S
    finally:
        live.stop()
    stopped = bus.trainer_beat()
    time.sleep(0.2)
    assert bus.trainer_beat() == stopped  # no beat after stop()


def test_a_trainer_asked_to_stop_beats_stopping_until_its_end(redis_url, run_id):
    """Set mid-update (the update finishes first): the next beat says "stopping", and the loop's later phase
    changes do not take it back."""
    bus, stop = Bus(redis.Redis.from_url(redis_url), run_id), threading.Event()
    live = Liveness(bus, every_s=0.05, stopping=stop)
    live.start()
    try:
        live.set_phase("updating", 3)
        assert bus.trainer_beat().phase == "updating"
        stop.set()
        time.sleep(0.3)
        beat = bus.trainer_beat()
        assert (beat.phase, beat.policy_version) == ("stopping", 3) and beat.since >= time.time() - 0.5
        live.set_phase("collecting", 4)
        assert (bus.trainer_beat().phase, bus.trainer_beat().policy_version) == ("stopping", 4)
    finally:
        live.stop()
    state = {"trainer_beat": bus.trainer_beat().model_dump(), "trainer": None}
    assert not trainer_alive(state)  # racer status: a stopping trainer is not the run's live trainer


def test_the_end_reason_is_the_updates_done_then_the_deadline_then_a_stop():
    assert end_reason(10, 10, None) == "max_updates"
    passed = Deadline.after(0.01)
    time.sleep(0.05)
    assert end_reason(3, 10, passed) == "time_limit"
    assert end_reason(3, 10, Deadline.after(3600.0)) == "stopped" and end_reason(3, 10, None) == "stopped"


def test_a_malformed_beat_or_end_reads_as_none(redis_url, run_id):
    bus = Bus(redis.Redis.from_url(redis_url), run_id)
    bus.redis.set(bus.keys.trainer_beat, json.dumps({"phase": "dancing", "since": 0}))
    bus.redis.set(bus.keys.trainer_end, b"\x80\x04K\x01.")  # a pickle: never unpickled
    assert bus.trainer_beat() is None and bus.trainer_end() is None


def test_status_says_updating_without_a_fresh_status_and_exits_0(redis_url, run_id):
    """The status key expired during a long update (the main loop writes it between updates): the beat answers."""
    bus = Bus(redis.Redis.from_url(redis_url), run_id)
    bus.publish_policy(PolicyVersion(version=3, checkpoint_key="k", created=0.0))
    bus.beat_trainer(beat("updating", time.time() - 55))
    out = status(redis_url, run_id)
    assert out.exit_code == 0, out.output
    assert re.search(r"trainer: updating policy v3 \(PPO update running for (5[5-9]|6\d) s\)", out.output), out.output
    assert "(Redis " in out.output.splitlines()[0]
    bus.beat_trainer(beat("starting", time.time() - 7))
    out = status(redis_url, run_id)
    assert out.exit_code == 0 and re.search(r"trainer: starting \(for ([7-9]|1\d) s", out.output), out.output


def test_status_of_a_stopped_trainer_says_why_and_where_its_checkpoints_are(redis_url, run_id):
    bus = Bus(redis.Redis.from_url(redis_url), run_id)
    bus.publish_policy(PolicyVersion(version=9, checkpoint_key="k", created=0.0))
    bus.beat_trainer(beat("collecting", time.time()))
    bus.end_trainer(TrainerEnd(reason="time_limit", policy_version=9, env_steps=12345, time=time.time() - 30))
    assert bus.trainer_beat() is None  # the end drops the beat
    out = status(redis_url, run_id)
    assert out.exit_code == 1, out.output
    stopped = r"trainer: stopped (3\d|4\d) s ago \(its time limit was reached\) at policy v9, 12,345 env steps"
    assert re.search(stopped, out.output), out.output
    assert f"racer models ls --run-id {run_id}" in out.output
    bus.clear_trainer_end()  # a restarted trainer clears it
    assert "trainer: not running (no heartbeat in the last" in status(redis_url, run_id).output


def test_status_of_a_run_this_redis_never_saw_says_so(redis_url, run_id):
    out = status(redis_url, run_id)
    assert out.exit_code == 1 and f"this Redis holds nothing of run {run_id} (check --run-id)" in out.output


def test_status_from_the_store_tells_a_stopped_run_from_a_misspelt_one(tmp_path: Path):
    store = str(tmp_path)
    (tmp_path / "runs" / "run-2026-12-07-a").mkdir(parents=True)
    stopped = CliRunner().invoke(app, ["status", "--run-id", "run-2026-12-07-a", "--store", store])
    assert stopped.exit_code == 2 and "not running any more (finished or killed" in stopped.output, stopped.output
    assert f"racer models ls --store {store} --run-id run-2026-12-07-a" in stopped.output
    typo = CliRunner().invoke(app, ["status", "--run-id", "run-2026-12-07-b", "--store", store])
    assert typo.exit_code == 2 and "no such run" in typo.output and "did you mean run-2026-12-07-a?" in typo.output


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_a_real_trainer_beats_through_its_update_and_records_its_end(redis_url, run_id, tmp_path, hp_file):
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, hp_file)
    trainer.liveness.every_s = 0.1
    try:
        assert trainer.bus.trainer_beat().phase == "collecting"
        fill(trainer, worker)
        real_update = trainer.learner.update
        seen: list[TrainerBeat] = []

        def watched_update(*args, **kwargs):  # the real update, with the beats read while it runs
            result = real_update(*args, **kwargs)
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                seen.append(trainer.bus.trainer_beat())
                time.sleep(0.05)
            return result

        trainer.learner.update = watched_update
        trainer.train()
        assert {b.phase for b in seen} == {"updating"} and len({b.time for b in seen}) >= 3
        assert trainer.bus.trainer_beat().phase == "collecting" and trainer.version == 1
        trainer.liveness.end(end_reason(1, 10, None), trainer.version, trainer.stats.env_steps)
        end = trainer.bus.trainer_end()
        assert (end.reason, end.policy_version) == ("stopped", 1) and trainer.bus.trainer_beat() is None
    finally:
        trainer.liveness.stop()
        worker.close()


@pytest.mark.slow(reason="a PPO update made to outlast the trainer's status key (30 s)")
def test_racer_status_during_an_update_longer_than_the_status_key_says_updating(redis_url, run_id, tmp_path, hp_file):
    """The issue's case: ``racer status`` during a PPO update longer than the status key lives said "not running"
    and exited 1 (compose's health check then failed a working trainer). The update is made slow by a pause after
    the real one."""
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, hp_file)
    try:
        fill(trainer, worker)
        real_update, release = trainer.learner.update, threading.Event()

        def slow_update(*args, **kwargs):
            result = real_update(*args, **kwargs)
            release.wait(TRAINER_STATUS_TTL_S + 30)
            return result

        trainer.learner.update = slow_update
        trainer.write_status()
        update = threading.Thread(target=trainer.train)
        update.start()
        deadline = time.monotonic() + TRAINER_STATUS_TTL_S + 20
        while trainer.bus.trainer_status() is not None and time.monotonic() < deadline:
            time.sleep(1.0)
        assert trainer.bus.trainer_status() is None, "the status key should have expired during the update"
        out = status(redis_url, run_id)
        release.set()
        update.join(timeout=60)
        assert out.exit_code == 0, out.output
        assert "trainer: updating policy v0 (PPO update running for " in out.output
    finally:
        release.set()
        trainer.liveness.stop()
        worker.close()
