"""The wire protocol: segments survive a real Redis stream byte for byte; anything malformed is refused."""

import json

import numpy as np
import pytest
import redis

from common.keys import Keys, check_run_id
from common.protocol import (
    EpisodeSummary,
    Heartbeat,
    PolicyVersion,
    ProtocolError,
    Segment,
    decode_segment,
    encode_segment,
)

OBS = (120, 160, 1)


def make_segment(run_id="run-a", steps=4, discrete=True, seed=0) -> Segment:
    rng = np.random.default_rng(seed)
    arrays = {
        "obs": rng.integers(0, 256, (steps, *OBS), dtype=np.uint8),
        "next_obs": rng.integers(0, 256, (1, *OBS), dtype=np.uint8),
        "actions": rng.integers(0, 10, steps).astype(np.int64)
        if discrete
        else rng.uniform(-1, 1, (steps, 2)).astype(np.float32),
        "rewards": rng.random(steps).astype(np.float32),
        "terminated": np.array([0] * (steps - 1) + [1], np.uint8),
        "truncated": np.zeros(steps, np.uint8),
        "logp": -rng.random(steps).astype(np.float32),
        "values": rng.random(steps).astype(np.float32),
        "next_values": rng.random(steps).astype(np.float32),
        "episode_id": np.full(steps, 7, np.int64),
    }
    ep = EpisodeSummary(7, 12, 33.5, 4.2, "off_track", "reinvent_base", None)
    return Segment(run_id, "w-0", 3, 1000, arrays, [ep])


def roundtrip(seg, **kw):
    fields = encode_segment(seg)
    return decode_segment(
        {k.encode(): v for k, v in fields.items()}, kw.get("run_id", seg.run_id), OBS, kw.get("n", 10)
    )


def test_roundtrip_keeps_every_array_and_header_field():
    seg = make_segment()
    out = roundtrip(seg)
    assert (out.run_id, out.worker_id, out.policy_version, out.env_seed) == ("run-a", "w-0", 3, 1000)
    assert out.episodes == seg.episodes
    for name, arr in seg.arrays.items():
        assert out.arrays[name].dtype == arr.dtype and np.array_equal(out.arrays[name], arr), name


def test_continuous_actions_roundtrip():
    seg = make_segment(discrete=False)
    out = decode_segment(encode_segment(seg), "run-a", OBS, None)
    assert out.arrays["actions"].shape == (4, 2)


def test_through_a_real_redis_stream(redis_url):
    r = redis.Redis.from_url(redis_url)
    keys = Keys("run-a")
    seg = make_segment(steps=32)
    r.xadd(keys.segments, encode_segment(seg), maxlen=10, approximate=True)
    [(_, [(_, fields)])] = r.xread({keys.segments: "0-0"}, count=1, block=100)
    out = decode_segment(fields, "run-a", OBS, 10)
    assert np.array_equal(out.arrays["obs"], seg.arrays["obs"])


def corrupt(mutate):
    fields = encode_segment(make_segment())
    header = json.loads(fields["header"])
    mutate(fields, header)
    fields["header"] = json.dumps(header).encode()
    return fields


@pytest.mark.parametrize(
    "mutate, reason",
    [
        (lambda f, h: h.update(run_id="other"), "other_run"),
        (lambda f, h: h.update(schema=99), "schema"),
        (lambda f, h: h.update(kind="heartbeat"), "bad_header"),
        (lambda f, h: h.update(steps=0), "bad_header"),
        (lambda f, h: h.update(policy_version=-1), "bad_header"),
        (lambda f, h: h.update(worker_id=""), "bad_header"),
        (lambda f, h: f.pop("a:rewards"), "missing_array"),
        (lambda f, h: h["arrays"]["obs"].update(dtype="float64"), "bad_dtype"),
        (lambda f, h: h["arrays"]["obs"].update(dtype="object"), "bad_dtype"),
        (lambda f, h: f.update({"a:obs": f["a:obs"][:-1]}), "bad_length"),
        (lambda f, h: h["arrays"]["rewards"].update(shape=[2, 2]), "bad_shape"),
        (lambda f, h: h["arrays"]["obs"].update(shape=[4, 60, 80, 4]), "bad_shape"),
        (lambda f, h: h["arrays"]["obs"].update(shape=[-4, 120, 160, 1]), "bad_shape"),
        (lambda f, h: f.update({"a:rewards": np.full(4, np.nan, np.float32).tobytes()}), "non_finite"),
        (lambda f, h: f.update({"a:actions": np.full(4, 10, np.int64).tobytes()}), "bad_action"),
        (lambda f, h: f.update({"a:terminated": np.full(4, 2, np.uint8).tobytes()}), "bad_flag"),
        (lambda f, h: h.update(episodes=[{"nope": 1}]), "bad_header"),
    ],
)
def test_malformed_segments_are_refused_with_a_reason(mutate, reason):
    with pytest.raises(ProtocolError) as exc:
        decode_segment(corrupt(mutate), "run-a", OBS, 10)
    assert exc.value.reason == reason


@pytest.mark.parametrize("raw", [b"", b"\xff\xfe", b"[1,2]", b'{"kind":"segment"', b"x" * 70000])
def test_garbage_headers_are_refused(raw):
    fields = encode_segment(make_segment())
    fields["header"] = raw
    with pytest.raises(ProtocolError):
        decode_segment(fields, "run-a", OBS, 10)


def test_missing_header_is_refused():
    fields = encode_segment(make_segment())
    del fields["header"]
    with pytest.raises(ProtocolError, match="no_header"):
        decode_segment(fields, "run-a", OBS, 10)


def test_policy_version_and_heartbeat_roundtrip_and_validation():
    pv = PolicyVersion(version=5, checkpoint_key="runs/a/checkpoints/000000005.pt", created=1.5)
    assert PolicyVersion.from_json(pv.to_json()) == pv
    bad_versions = {
        b"{}": "version",
        b"nonsense": "message",
        b'{"version": -1, "checkpoint_key": "k", "created": 0}': "version",
        b'{"version": true, "checkpoint_key": "k", "created": 0}': "version",  # a bool is not a version
        b'{"version": 1.5, "checkpoint_key": "k", "created": 0}': "version",
        b'{"version": 1, "checkpoint_key": "k", "created": NaN}': "created",
        b'{"version": 1, "checkpoint_key": 7, "created": 0}': "checkpoint_key",
        b'{"version": 1, "checkpoint_key": "k", "created": 0, "extra": 1}': "extra",
    }
    for bad, field_name in bad_versions.items():
        with pytest.raises(ProtocolError, match=f"bad_policy_version.*PolicyVersion.{field_name}"):
            PolicyVersion.from_json(bad)
    hb = Heartbeat(
        worker_id="w", pid=12, host="host", policy_version=3, env_steps=100, segments=4, time=2.0, track="reinvent_base"
    )
    assert Heartbeat.from_json(hb.to_json()) == hb
    for bad in (b'{"worker_id": "w"}', hb.to_json().replace('"pid":12', '"pid":"12"').encode()):
        with pytest.raises(ProtocolError, match="bad_heartbeat"):
            Heartbeat.from_json(bad)


def test_keys_live_under_one_prefix_and_run_ids_are_checked():
    k = Keys("run-1")
    names = [k.segments, k.policy, k.heartbeat("w"), k.trainer_status, k.worker_slots, k.evaluations, k.training]
    assert all(n.startswith("racer:run-1:") for n in names) and len(set(names)) == len(names)
    for bad in ("", "a b", "../x", "x" * 200, "a:b"):
        with pytest.raises(ValueError, match="run id"):
            check_run_id(bad)
