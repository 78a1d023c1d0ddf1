"""The wire protocol: segments survive a real Redis stream byte for byte; anything malformed is refused."""

import json

import numpy as np
import pytest
import redis

from common.defaults import DEFAULT_TRACK, MAX_SEGMENT_STEPS
from common.framestack import FrameStack
from common.keys import Keys, check_run_id
from common.protocol import (
    SCHEMA_VERSION,
    EpisodeSummary,
    Heartbeat,
    PolicyVersion,
    ProtocolError,
    Segment,
    decode_segment,
    encode_segment,
)
from common.sensors import LIDARS

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
    ep = EpisodeSummary(7, 12, 33.5, 4.2, "off_track", track=DEFAULT_TRACK, lap_time_s=None)
    return Segment(run_id, "w-0", 3, 1000, arrays=arrays, episodes=[ep])


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


def _flipped(data: bytes) -> bytes:
    """``data`` with one bit of its middle byte flipped."""
    middle = len(data) // 2
    return data[:middle] + bytes([data[middle] ^ 0x10]) + data[middle + 1 :]


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
        (lambda f, h: h.update(steps=MAX_SEGMENT_STEPS + 1), "bad_header"),
        (lambda f, h: h["arrays"]["frame_index"].update(dtype="float64"), "bad_dtype"),
        (lambda f, h: h["arrays"]["frame_index"].update(dtype="object"), "bad_dtype"),
        (lambda f, h: f.update({"a:frame_index": f["a:frame_index"][:-1]}), "bad_length"),
        (lambda f, h: h["arrays"]["rewards"].update(shape=[2, 2]), "bad_shape"),
        (lambda f, h: h["arrays"]["frame_index"].update(shape=[4, 1]), "bad_length"),
        (lambda f, h: f.pop("a:frames"), "missing_array"),
        (lambda f, h: h.pop("frames"), "missing_array"),
        (lambda f, h: h["frames"].update(codec="lz4"), "bad_frames"),
        (lambda f, h: h["frames"].update(shape=[4, 60, 80]), "bad_shape"),
        (lambda f, h: h["frames"].update(shape=[-4, 120, 160]), "bad_shape"),
        (lambda f, h: h["frames"].update(shape=[0, 120, 160]), "bad_shape"),
        (lambda f, h: h["frames"].update(shape=[5, 120, 160, 1]), "bad_shape"),
        (lambda f, h: h["frames"].update(shape=[6, 120, 160]), "bad_shape"),  # 5 observations of 1 channel: 5 planes
        (lambda f, h: h["frames"].update(shape=[4, 120, 160]), "bad_frames"),  # the index names plane 4
        (lambda f, h: f.update({"a:frame_index": np.full(5, 9, np.uint16).tobytes()}), "bad_frames"),
        (lambda f, h: f.update({"a:frames": f["a:frames"][:-1]}), "corrupt"),  # truncated
        (lambda f, h: f.update({"a:frames": f["a:frames"] + b"\0"}), "corrupt"),  # bytes after the frame
        (lambda f, h: f.update({"a:frames": b"not zstd"}), "corrupt"),
        (lambda f, h: f.update({"a:frames": b""}), "corrupt"),
        (lambda f, h: f.update({"a:frames": _flipped(f["a:frames"])}), "corrupt"),  # the checksum catches it
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
        worker_id="w", pid=12, host="host", policy_version=3, env_steps=100, segments=4, time=2.0, track=DEFAULT_TRACK
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


# --- the LiDAR arrays (common.sensors: LIDAR 64 values in [0.15, 1], SECTOR_LIDAR 8 in [0, 1]) ---------------------

STEREO = (120, 160, 2)


def lidar_segment(spec, steps=4, seed=0) -> Segment:
    """A stereo segment with a LiDAR: the camera arrays have 2 channels, plus ``lidar`` and ``next_lidar``."""
    rng = np.random.default_rng(seed)
    seg = make_segment(steps=steps, seed=seed)
    seg.arrays["obs"] = rng.integers(0, 256, (steps, *STEREO), dtype=np.uint8)
    seg.arrays["next_obs"] = rng.integers(0, 256, (1, *STEREO), dtype=np.uint8)
    for name, rows in (("lidar", steps), ("next_lidar", 1)):
        if spec.name == "LIDAR":
            values = rng.uniform(spec.low, spec.high, (rows, spec.size))
        else:
            values = rng.integers(0, 2, (rows, spec.size))
        seg.arrays[name] = values.astype(np.float32)
    return seg


@pytest.mark.parametrize("sensor", ["LIDAR", "SECTOR_LIDAR"])
def test_lidar_arrays_roundtrip(sensor, redis_url):
    spec = LIDARS[sensor]
    seg = lidar_segment(spec, steps=8)
    seg.arrays["lidar"][0, :2] = [spec.low, spec.high]  # the bounds themselves are in range
    r = redis.Redis.from_url(redis_url)
    r.xadd(Keys("run-a").segments, encode_segment(seg))
    [(_, [(_, fields)])] = r.xread({Keys("run-a").segments: "0-0"}, count=1, block=100)
    out = decode_segment(fields, "run-a", STEREO, 10, lidar=spec)
    for name, arr in seg.arrays.items():
        assert out.arrays[name].dtype == arr.dtype and np.array_equal(out.arrays[name], arr), name
    assert out.arrays["lidar"].shape == (8, spec.size) and out.arrays["next_lidar"].shape == (1, spec.size)


def corrupt_lidar(mutate, spec=LIDARS["LIDAR"]):
    fields = encode_segment(lidar_segment(spec))
    header = json.loads(fields["header"])
    mutate(fields, header)
    fields["header"] = json.dumps(header).encode()
    return fields


def _floats(values) -> bytes:
    return np.asarray(values, np.float32).tobytes()


def _reshaped(name: str, shape: list[int]):
    """A mutation giving array ``name`` another (consistent) shape, filled with valid values."""

    def mutate(f, h):
        h["arrays"][name].update(shape=shape)
        f[f"a:{name}"] = _floats(np.full(shape, 0.5))

    return mutate


@pytest.mark.parametrize(
    "mutate, reason",
    [
        (lambda f, h: (f.pop("a:lidar"), h["arrays"].pop("lidar")), "missing_array"),
        (lambda f, h: (f.pop("a:next_lidar"), h["arrays"].pop("next_lidar")), "missing_array"),
        (lambda f, h: h["arrays"]["lidar"].update(dtype="float64"), "bad_dtype"),
        (lambda f, h: h["arrays"]["lidar"].update(dtype="uint8"), "bad_dtype"),
        (lambda f, h: f.update({"a:lidar": f["a:lidar"][:-4]}), "bad_length"),
        (_reshaped("lidar", [4, 8]), "bad_shape"),
        (_reshaped("lidar", [3, 64]), "bad_shape"),
        (_reshaped("next_lidar", [64]), "bad_shape"),
        (lambda f, h: f.update({"a:lidar": _floats(np.full((4, 64), np.nan))}), "non_finite"),
        (lambda f, h: f.update({"a:next_lidar": _floats(np.full((1, 64), np.inf))}), "non_finite"),
        (lambda f, h: f.update({"a:lidar": _floats(np.full((4, 64), 0.1))}), "bad_lidar"),  # below 0.15 m
        (lambda f, h: f.update({"a:next_lidar": _floats(np.full((1, 64), 12.0))}), "bad_lidar"),  # not clipped to 1
    ],
)  # fmt: skip
def test_malformed_lidar_arrays_are_refused_with_a_reason(mutate, reason):
    with pytest.raises(ProtocolError) as exc:
        decode_segment(corrupt_lidar(mutate), "run-a", STEREO, 10, lidar=LIDARS["LIDAR"])
    assert exc.value.reason == reason


def test_lidar_arrays_must_match_the_runs_sensors():
    sector = LIDARS["SECTOR_LIDAR"]
    fields = encode_segment(lidar_segment(sector))
    with pytest.raises(ProtocolError) as exc:  # a run without a LiDAR refuses them
        decode_segment(fields, "run-a", STEREO, 10)
    assert exc.value.reason == "bad_header" and "without a LiDAR" in str(exc.value)
    with pytest.raises(ProtocolError) as exc:  # a LIDAR run refuses a SECTOR_LIDAR segment (8 values, not 64)
        decode_segment(fields, "run-a", STEREO, 10, lidar=LIDARS["LIDAR"])
    assert exc.value.reason == "bad_shape"
    bad = lidar_segment(sector)
    bad.arrays["lidar"][1, 3] = 1.5  # sector values are within [0, 1]
    with pytest.raises(ProtocolError) as exc:
        decode_segment(encode_segment(bad), "run-a", STEREO, 10, lidar=sector)
    assert exc.value.reason == "bad_lidar"
    with pytest.raises(ProtocolError) as exc:  # a LiDAR run refuses a segment without them
        decode_segment(encode_segment(make_segment()), "run-a", OBS, 10, lidar=sector)
    assert exc.value.reason == "missing_array"
    with pytest.raises(ProtocolError) as exc:  # and a stereo run a front-camera segment
        decode_segment(encode_segment(make_segment()), "run-a", STEREO, 10)
    assert exc.value.reason == "bad_shape"


def test_a_camera_only_segment_has_no_lidar_fields():
    """The LiDAR pair is the only optional part: a camera-only segment carries the camera frames and the rest."""
    fields = encode_segment(make_segment())
    names = ["frame_index", "actions", "rewards", "terminated", "truncated", "logp", "values", "next_values"]
    assert sorted(json.loads(fields["header"])["arrays"]) == sorted([*names, "episode_id"])
    assert sorted(fields) == sorted(["header", "a:frames", *(f"a:{n}" for n in [*names, "episode_id"])])
    assert json.loads(fields["header"])["schema"] == SCHEMA_VERSION == 2


# --- the camera frames on the wire: each frame once, rebuilt bit for bit ----------------------------------------------


def stacked_segment(stack: int, frame_channels: int = 1, steps: int = 32, ends=(9, 20), lidar=None, seed=0) -> Segment:
    """A segment as a worker builds it: frames through a FrameStack, episodes ending after steps ``ends`` (the next
    episode's first observation repeats its first frame), starting mid-episode; returns it with ``distinct``, the
    number of distinct frames its observations hold."""
    rng = np.random.default_rng(seed)

    def frame():
        return rng.integers(0, 256, (120, 160, frame_channels), dtype=np.uint8)

    frames = FrameStack(stack)
    obs = [frames.reset(frame())]
    for _ in range(stack - 1):
        obs = [frames.push(frame())]  # mid-episode: o_0 holds `stack` distinct frames
    for t in range(steps):
        obs.append(frames.reset(frame()) if t in ends else frames.push(frame()))
    seg = make_segment(steps=steps, seed=seed)
    seg.arrays["obs"], seg.arrays["next_obs"] = np.stack(obs[:steps]), obs[steps][None]
    if lidar is not None:
        for name, rows in (("lidar", steps), ("next_lidar", 1)):
            seg.arrays[name] = rng.uniform(lidar.low, lidar.high, (rows, lidar.size)).astype(np.float32)
    seg.distinct = stack + steps  # o_0's frames, then one new frame per observation
    return seg


@pytest.mark.parametrize("stack", [1, 3])
@pytest.mark.parametrize("sensor", ["FRONT_FACING_CAMERA", "STEREO_CAMERAS", "STEREO_CAMERAS+LIDAR"])
def test_stacked_frames_travel_once_and_come_back_bit_exact(stack, sensor, redis_url):
    channels = 2 if sensor.startswith("STEREO") else 1
    lidar = LIDARS["LIDAR"] if sensor.endswith("LIDAR") else None
    seg = stacked_segment(stack, channels, lidar=lidar)
    fields = encode_segment(seg)
    header = json.loads(fields["header"])
    # Each camera frame once: o_{t+1} adds one frame to o_t's, and next_obs duplicates none of obs'.
    assert header["frames"]["shape"] == [seg.distinct * channels, 120, 160]
    assert header["arrays"]["frame_index"] == {"dtype": "uint16", "shape": [33, stack * channels]}
    r = redis.Redis.from_url(redis_url)
    r.xadd(Keys("run-a").segments, fields)
    [(_, [(_, wire)])] = r.xread({Keys("run-a").segments: "0-0"}, count=1, block=100)
    out = decode_segment(wire, "run-a", (120, 160, stack * channels), 10, lidar=lidar)
    assert sorted(out.arrays) == sorted(seg.arrays)
    for name, arr in seg.arrays.items():
        assert out.arrays[name].dtype == arr.dtype and np.array_equal(out.arrays[name], arr), name
        assert out.arrays[name].flags.c_contiguous, name


def test_real_camera_frames_fit_the_wire_budget():
    """A default run's segment (front camera, one frame, 32 steps) of real frames is at most 8 kB a step."""
    from racer.bench.wire import driven_segments

    [seg] = driven_segments(steps=32, segments=1)
    fields = encode_segment(seg)
    size = sum(len(k) + len(v) for k, v in fields.items())
    assert size / seg.steps <= 8000
    out = decode_segment(fields, seg.run_id, seg.arrays["obs"].shape[1:], 10)
    assert np.array_equal(out.arrays["obs"], seg.arrays["obs"])
    assert np.array_equal(out.arrays["next_obs"], seg.arrays["next_obs"])


def test_a_decompression_bomb_is_refused_before_it_inflates():
    """A few kB of zstd that would inflate to 1 GB, and frames that claim no size, are refused without allocating."""
    import tracemalloc

    import zstandard

    def with_frames(data: bytes) -> dict:
        fields = encode_segment(make_segment())
        fields["a:frames"] = data
        return fields

    bomb = zstandard.ZstdCompressor(level=19).compress(b"\0" * (1 << 30))
    unsized = zstandard.ZstdCompressor(write_content_size=False).compress(b"\0" * 5 * 120 * 160)
    assert len(bomb) < 100_000
    tracemalloc.start()
    try:
        for data in (bomb, unsized):
            with pytest.raises(ProtocolError) as exc:
                decode_segment(with_frames(data), "run-a", OBS, 10)
            assert exc.value.reason == "bad_length"
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 8 << 20
    # A header claiming more planes than its observations can hold is refused on the shape alone.
    fields = corrupt(lambda f, h: h["frames"].update(shape=[10**6, 120, 160]))
    with pytest.raises(ProtocolError) as exc:
        decode_segment(fields, "run-a", OBS, 10)
    assert exc.value.reason == "bad_shape"
