"""The wire protocol between rollout workers and the trainer.

A segment is a fixed number of consecutive env steps of one worker, sent as one Redis stream entry: a JSON
``header`` field, one field of raw bytes per small numpy array (C order, little-endian) and one field of the camera
frames, compressed. Nothing is pickled. ``decode_segment`` validates everything it reads and raises ProtocolError
with a short reason, which the trainer counts and logs before dropping the entry.

Arrays of a segment of T steps (obs shape (H, W, C), uint8), as ``Segment.arrays`` holds them on both sides:

==============  ========  =================  =====================================================
name            dtype     shape              meaning
==============  ========  =================  =====================================================
obs             uint8     (T, H, W, C)       o_t, the observation the action was chosen from
next_obs        uint8     (1, H, W, C)       o_T, the observation after the last step
actions         int64     (T,)               discrete action index (continuous: float32 (T, 2))
rewards         float32   (T,)               r_t from the user's reward function
terminated      uint8     (T,)               1 if the episode ended at step t (off track, lap...)
truncated       uint8     (T,)               1 if the episode hit its time limit at step t
logp            float32   (T,)               log π(a_t | o_t) under the behaviour policy
values          float32   (T,)               V(o_t) under the behaviour policy
next_values     float32   (T,)               V(o_{t+1}): the final observation's value for a
                                             truncated step and the last step, else V(o_{t+1})
episode_id      int64     (T,)               worker-local episode number of each step
lidar           float32   (T, N)             the LiDAR part of o_t (only with a LiDAR sensor)
next_lidar      float32   (1, N)             the LiDAR part of o_T (only with a LiDAR sensor)
teacher         float32   (T, P)             the teacher's action distribution at o_t (only in a
                                             distilling run: ``trainer.distill.label_width``)
==============  ========  =================  =====================================================

A teacher run (``EnvConfig.observation`` ``state``) sends float32 state vectors instead of camera frames: ``obs``
(T, D) and ``next_obs`` (1, D) are fields ``a:obs`` and ``a:next_obs`` of raw bytes like the rest, and the segment
has no ``a:frames``, ``a:frame_index`` or header ``frames``.

On the wire (schema 2) every array but ``obs`` and ``next_obs`` is a field ``a:<name>`` of raw bytes. The T + 1
camera observations travel as their distinct channel planes: a stacked observation's C channels are C planes of
(H, W), and with frame stacking o_{t+1} shares all but one frame with o_t (an episode's first observation repeats
its first frame), so each camera frame is sent once per segment, however many observations hold it:

==============  ========  =================  =====================================================
field           dtype     shape              meaning
==============  ========  =================  =====================================================
a:frames        uint8     (K, H, W)          the K distinct planes, in order of first appearance,
                                             as one zstd frame (level 1, with its content size
                                             and checksum); header ``frames``: codec, shape
a:frame_index   uint16    (T + 1, C)         plane of channel c of observation t (row T: o_T);
                                             uint32 only where K > 65536
==============  ========  =================  =====================================================

The decoder rebuilds ``obs`` and ``next_obs`` bit for bit (``planes[frame_index]``, channels last). It never
inflates more than the header's shapes allow: K ≤ (T + 1)·C, T ≤ ``MAX_SEGMENT_STEPS``, H and W the trainer's own;
the zstd frame must state exactly K·H·W bytes as its content size and decompress to exactly that, with no bytes
after it.

The camera part C is 1 (front camera) or 2 (stereo: left, right) channels per stacked frame; ``lidar`` and
``next_lidar`` are present exactly when the run's sensors include a LiDAR (``common.sensors``: N = 64 for
``LIDAR``, values in [0.15, 1]; N = 8 for ``SECTOR_LIDAR``, values in [0, 1]).
"""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import KW_ONLY, dataclass, field
from typing import ClassVar, Literal, Self

import cv2
import numpy as np
import zstandard
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from common.defaults import MAX_SEGMENT_STEPS
from common.errors import error_location
from common.sensors import LidarSpec

SCHEMA_VERSION = 2
MAX_HEADER_BYTES = 1 << 16
FRAME_CODEC = "zstd"
"""The compression of ``a:frames``: zstd level 1 (``docs/speed.md``, "Wire", has the codecs measured against it)."""
ZSTD_LEVEL = 1
_KEY_STRIDE = 8
"""The encoder looks a plane up by every 8th pixel of every 8th row (300 bytes of a 120×160 plane), then compares
the whole plane: equal planes always have equal keys, and hashing 300 bytes is cheaper than hashing 19,200."""
_CAMERA_ARRAYS = ("obs", "next_obs")

_ARRAY_DTYPES: dict[str, tuple[str, ...]] = {
    "frame_index": ("uint16", "uint32"),
    "actions": ("int64", "float32"),
    "rewards": ("float32",),
    "terminated": ("uint8",),
    "truncated": ("uint8",),
    "logp": ("float32",),
    "values": ("float32",),
    "next_values": ("float32",),
    "episode_id": ("int64",),
}
_LIDAR_DTYPES: dict[str, tuple[str, ...]] = {"lidar": ("float32",), "next_lidar": ("float32",)}
"""The arrays of a run with a LiDAR sensor, in addition to ``_ARRAY_DTYPES``."""
_STATE_DTYPES: dict[str, tuple[str, ...]] = {"obs": ("float32",), "next_obs": ("float32",)}
"""The observations of a teacher run (state vectors, sent raw), in place of the camera frames and their index."""
_TEACHER_DTYPES: dict[str, tuple[str, ...]] = {"teacher": ("float32",)}
"""The teacher's action distribution at each step of a distilling run, in addition to the rest."""


class ProtocolError(ValueError):
    """A message that does not follow the protocol; ``reason`` is a short tag for drop counters."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


@dataclass(frozen=True)
class EpisodeSummary:
    """An episode that ended inside a segment, as the worker saw it."""

    episode_id: int
    steps: int
    progress: float
    """Percent of a lap, 0..100."""
    reward: float
    """Sum of rewards."""
    status: str
    """DeepRacer episode_status at the end (off_track, lap_complete, ...)."""
    _: KW_ONLY
    track: str = ""
    lap_time_s: float | None = None
    """Simulated seconds for a completed lap, else None."""


@dataclass
class Segment:
    """T consecutive steps of one worker's env (see the module docstring for the arrays)."""

    run_id: str
    worker_id: str
    policy_version: int
    env_seed: int
    _: KW_ONLY
    arrays: dict[str, np.ndarray]
    episodes: list[EpisodeSummary] = field(default_factory=list)
    created: float = field(default_factory=time.time)

    @property
    def steps(self) -> int:
        """Number of env steps in the segment."""
        return int(self.arrays["rewards"].shape[0])


def encode_segment(seg: Segment) -> dict[str, bytes]:
    """Stream-entry fields for a segment: ``header`` JSON, raw bytes per small array, the camera frames compressed
    (each distinct plane once; see the module docstring); a teacher run's float32 state vectors go raw."""
    state = seg.arrays["obs"].dtype == np.float32
    arrays = dict(seg.arrays) if state else {n: a for n, a in seg.arrays.items() if n not in _CAMERA_ARRAYS}
    if not state:
        planes, arrays["frame_index"] = frame_table(seg.arrays["obs"], seg.arrays["next_obs"])
    specs = {}
    fields: dict[str, bytes] = {}
    for name, arr in arrays.items():
        a = np.ascontiguousarray(arr)
        if a.dtype == np.bool_:
            a = a.astype(np.uint8)
        specs[name] = {"dtype": str(a.dtype), "shape": list(a.shape)}
        fields[f"a:{name}"] = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
    header = {
        "schema": SCHEMA_VERSION,
        "kind": "segment",
        "run_id": seg.run_id,
        "worker_id": seg.worker_id,
        "policy_version": seg.policy_version,
        "env_seed": seg.env_seed,
        "steps": seg.steps,
        "episode_ids": sorted({int(v) for v in seg.arrays["episode_id"]}),
        "episodes": [e.__dict__ for e in seg.episodes],
        "created": seg.created,
        "arrays": specs,
    }
    if not state:
        fields["a:frames"] = _deflate(planes)
        header["frames"] = {"codec": FRAME_CODEC, "shape": [len(planes), *planes[0].shape]}
    fields["header"] = json.dumps(header, separators=(",", ":")).encode()
    return fields


def frame_table(*cameras: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """The distinct channel planes of stacked observations ``cameras`` (each (N_i, H, W, C) uint8, taken one after
    the other: N observations in all), in order of first appearance, each a contiguous (H, W) array (a view of
    ``cameras`` where C is 1), and the index (N, C) with observation i's channel c == ``planes[index[i, c]]``: a
    frame shared by several stacked observations (or repeated within one) is kept once. Equality is exact (the
    whole plane is compared), so :func:`frames_from_table` gives the observations back bit for bit."""
    h, w, c = cameras[0].shape[1:]
    # Channels first, so that each plane is one run of bytes to compare and compress (a copy only where C > 1).
    planes = [p for cam in cameras for p in np.ascontiguousarray(cam.transpose(0, 3, 1, 2)).reshape(-1, h, w)]
    index = np.empty(len(planes), np.int64)
    kept: list[np.ndarray] = []
    by_key: dict[bytes, list[int]] = {}
    for m, plane in enumerate(planes):
        same = by_key.setdefault(plane[::_KEY_STRIDE, ::_KEY_STRIDE].tobytes(), [])
        k = next((k for k in same if np.array_equal(kept[k], plane)), None)
        if k is None:
            k = len(kept)
            same.append(k)
            kept.append(plane)
        index[m] = k
    dtype = np.uint16 if len(kept) <= 1 << 16 else np.uint32
    return kept, index.reshape(-1, c).astype(dtype)


def _deflate(planes: list[np.ndarray]) -> bytes:
    """One zstd frame of the planes one after the other, streamed (never copied into one buffer first), stating
    its content size."""
    stream = _ZSTD.compressor.compressobj(size=sum(p.nbytes for p in planes))
    return b"".join([*(stream.compress(p) for p in planes), stream.flush()])


def frames_from_table(planes: np.ndarray, index: np.ndarray) -> np.ndarray:
    """The stacked observations (N, H, W, C) of :func:`frame_table`'s planes (K, H, W) and index (N, C)."""
    n, c = index.shape
    if c == 1:
        if len(planes) == n and np.array_equal(index[:, 0], np.arange(n)):
            return planes[..., None]  # one frame per observation, in order (one frame, no stacking): no copy
        return planes[index[:, 0]][..., None]
    out = np.empty((n, *planes.shape[1:], c), np.uint8)
    for i in range(n):  # OpenCV interleaves channels many times faster than numpy's transposing copy
        out[i] = cv2.merge([planes[k] for k in index[i]])
    return out


class _Zstd(threading.local):
    """One zstd compressor and decompressor per thread (their contexts are not thread-safe, and are reused)."""

    def __init__(self) -> None:
        self.compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_checksum=True, write_content_size=True)
        self.decompressor = zstandard.ZstdDecompressor()


_ZSTD = _Zstd()


def decode_segment(
    fields: dict[bytes | str, bytes],
    run_id: str,
    obs_shape: tuple[int, ...],
    n_actions: int | None,
    lidar: LidarSpec | None = None,
    teacher_width: int | None = None,
) -> Segment:
    """Validate stream-entry fields and rebuild the Segment; raise ProtocolError on anything malformed.

    ``obs_shape`` is the stacked camera observation (H, W, C), or (D,) for a teacher run's state vectors;
    ``n_actions`` the number of discrete actions (None for a continuous space of 2 values); ``lidar`` the run's LiDAR
    (``ObsSpec.lidar``; None: the segment must have no LiDAR arrays); ``teacher_width`` the width of a distilling
    run's ``teacher`` rows (``trainer.distill.label_width``; None: the segment must have none).
    """
    f = {(k.decode() if isinstance(k, bytes) else k): v for k, v in fields.items()}
    header = _header(f)
    if header.get("run_id") != run_id:
        raise ProtocolError("other_run", f"run_id {header.get('run_id')!r}")
    steps = header.get("steps")
    if not isinstance(steps, int) or isinstance(steps, bool) or not 1 <= steps <= MAX_SEGMENT_STEPS:
        raise ProtocolError("bad_header", f"steps {steps!r}")
    state = len(obs_shape) == 1
    arrays = {name: _array(f, header, name) for name in _ARRAY_DTYPES if not (state and name == "frame_index")}
    _optional(arrays, f, header, _LIDAR_DTYPES, expected=lidar is not None, without="a run without a LiDAR")
    _optional(arrays, f, header, _TEACHER_DTYPES, expected=teacher_width is not None, without="a run without a teacher")
    if state:
        if "a:frames" in f or "frames" in header:
            raise ProtocolError("bad_header", "camera frames in a segment of state vectors")
        arrays.update({name: _array(f, header, name, _STATE_DTYPES) for name in _STATE_DTYPES})
    else:
        camera = _camera(f, header, arrays.pop("frame_index"), steps, tuple(obs_shape))
        arrays["obs"], arrays["next_obs"] = camera[:steps], camera[steps:]
    _check_shapes(arrays, steps, tuple(obs_shape), n_actions)
    if lidar is not None:
        _check_lidar(arrays, steps, lidar)
    if teacher_width is not None:
        _check_rows(arrays, "teacher", (steps, teacher_width))
    return Segment(
        run_id=run_id,
        worker_id=_str(header, "worker_id"),
        policy_version=_int(header, "policy_version"),
        env_seed=_int(header, "env_seed"),
        arrays=arrays,
        episodes=_episodes(header),
        created=_created(header),
    )


def _camera(f: dict[str, bytes], header: dict, index: np.ndarray, steps: int, obs_shape: tuple) -> np.ndarray:
    """The T + 1 stacked observations (T + 1, H, W, C) from ``a:frames`` and the frame index, checked before a byte
    is inflated: K·H·W is at most what the header's own shapes allow, and the zstd frame must say that size."""
    if len(obs_shape) != 3:
        raise ValueError(f"obs_shape {obs_shape} is not (H, W, C)")
    height, width, channels = obs_shape
    if index.shape != (steps + 1, channels):
        raise ProtocolError("bad_shape", f"frame_index: {index.shape}, expected {(steps + 1, channels)}")
    spec = header.get("frames")
    raw = f.get("a:frames")
    if not isinstance(spec, dict) or raw is None:
        raise ProtocolError("missing_array", "frames")
    if spec.get("codec") != FRAME_CODEC:
        raise ProtocolError("bad_frames", f"codec {spec.get('codec')!r}, expected {FRAME_CODEC!r}")
    shape = spec.get("shape")
    if (
        not isinstance(shape, list)
        or len(shape) != 3
        or not all(isinstance(v, int) and not isinstance(v, bool) for v in shape)
        or shape[1:] != [height, width]
        or not 1 <= shape[0] <= (steps + 1) * channels
    ):
        raise ProtocolError("bad_shape", f"frames: {shape!r} for {steps} steps of {obs_shape}")
    count = shape[0]
    if index.max() >= count:
        raise ProtocolError("bad_frames", f"frame_index names plane {int(index.max())} of {count}")
    planes = _inflate(raw, count * height * width).reshape(count, height, width)
    return frames_from_table(planes, index)


def _inflate(raw: bytes, size: int) -> np.ndarray:
    """Exactly ``size`` bytes from one zstd frame that says it holds ``size`` bytes (checksum checked), or
    ProtocolError: a frame claiming more (a decompression bomb) is refused before anything is allocated."""
    try:
        claimed = zstandard.frame_content_size(raw)
    except zstandard.ZstdError as exc:
        raise ProtocolError("corrupt", f"frames: {exc}") from None
    if claimed != size:
        raise ProtocolError("bad_length", f"frames: the zstd frame holds {claimed} bytes, the header's shapes {size}")
    try:
        out = _ZSTD.decompressor.decompress(raw, max_output_size=size, allow_extra_data=False)
    except zstandard.ZstdError as exc:
        raise ProtocolError("corrupt", f"frames: {exc}") from None
    if len(out) != size:
        raise ProtocolError("bad_length", f"frames: {len(out)} bytes, expected {size}")
    return np.frombuffer(out, np.uint8)


def _header(f: dict[str, bytes]) -> dict:
    raw = f.get("header")
    if raw is None:
        raise ProtocolError("no_header")
    if len(raw) > MAX_HEADER_BYTES:
        raise ProtocolError("bad_header", "header too large")
    try:
        header = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError("bad_header", str(exc)) from None
    if not isinstance(header, dict) or header.get("kind") != "segment":
        raise ProtocolError("bad_header", "not a segment header")
    if header.get("schema") != SCHEMA_VERSION:
        raise ProtocolError("schema", f"schema {header.get('schema')!r}, expected {SCHEMA_VERSION}")
    return header


def _array(
    f: dict[str, bytes], header: dict, name: str, dtypes: dict[str, tuple[str, ...]] = _ARRAY_DTYPES
) -> np.ndarray:
    specs = header.get("arrays")
    if not isinstance(specs, dict):
        raise ProtocolError("bad_header", f"arrays {type(specs).__name__}")
    spec = specs.get(name)
    raw = f.get(f"a:{name}")
    if not isinstance(spec, dict) or raw is None:
        raise ProtocolError("missing_array", name)
    dtype, shape = spec.get("dtype"), spec.get("shape")
    if dtype not in dtypes[name]:
        raise ProtocolError("bad_dtype", f"{name}: {dtype!r}")
    if not isinstance(shape, list) or not all(isinstance(v, int) and v >= 0 for v in shape):
        raise ProtocolError("bad_shape", f"{name}: {shape!r}")
    dt = np.dtype(dtype).newbyteorder("<")
    if len(raw) != dt.itemsize * math.prod(shape):
        raise ProtocolError("bad_length", f"{name}: {len(raw)} bytes for {shape} {dtype}")
    return np.frombuffer(raw, dtype=dt).reshape(shape).astype(dtype, copy=False)


def _optional(
    arrays: dict[str, np.ndarray],
    f: dict[str, bytes],
    header: dict,
    dtypes: dict[str, tuple[str, ...]],
    *,
    expected: bool,
    without: str,
) -> None:
    """Read optional arrays a run has (``expected``); refuse them in a segment of a run without them (they would be
    dropped unseen, or mean another run's sensors or teacher)."""
    if expected:
        arrays.update({name: _array(f, header, name, dtypes) for name in dtypes})
        return
    specs = header.get("arrays")
    for name in dtypes:
        if f"a:{name}" in f or (isinstance(specs, dict) and name in specs):
            raise ProtocolError("bad_header", f"array {name} in a segment of {without}")


def _check_rows(a: dict[str, np.ndarray], name: str, shape: tuple[int, int]) -> None:
    """``a[name]`` is of ``shape`` and finite."""
    if a[name].shape != shape:
        raise ProtocolError("bad_shape", f"{name}: {a[name].shape}, expected {shape}")
    if not np.all(np.isfinite(a[name])):
        raise ProtocolError("non_finite", name)


def _check_lidar(a: dict[str, np.ndarray], steps: int, lidar: LidarSpec) -> None:
    """Shapes (T, N) and (1, N), finite values within the LiDAR's range."""
    for name, rows in (("lidar", steps), ("next_lidar", 1)):
        if a[name].shape != (rows, lidar.size):
            raise ProtocolError("bad_shape", f"{name}: {a[name].shape}, expected {(rows, lidar.size)}")
        if not np.all(np.isfinite(a[name])):
            raise ProtocolError("non_finite", name)
        low, high = np.float32(lidar.low), np.float32(lidar.high)
        if a[name].min() < low or a[name].max() > high:
            raise ProtocolError("bad_lidar", f"{name}: {lidar.name} values outside [{lidar.low}, {lidar.high}]")


def _check_shapes(a: dict[str, np.ndarray], steps: int, obs_shape: tuple, n_actions: int | None) -> None:
    expect = {
        "obs": (steps, *obs_shape),
        "next_obs": (1, *obs_shape),
        "actions": (steps,) if n_actions is not None else (steps, 2),
    }
    for name in ("obs", "next_obs", *(n for n in _ARRAY_DTYPES if n != "frame_index")):
        want = expect.get(name, (steps,))
        if a[name].shape != want:
            raise ProtocolError("bad_shape", f"{name}: {a[name].shape}, expected {want}")
    finite = ("rewards", "logp", "values", "next_values", *(("obs", "next_obs") if len(obs_shape) == 1 else ()))
    for name in finite:
        if not np.all(np.isfinite(a[name])):
            raise ProtocolError("non_finite", name)
    act = a["actions"]
    if n_actions is not None:
        if act.dtype != np.int64 or act.min() < 0 or act.max() >= n_actions:
            raise ProtocolError("bad_action", f"discrete actions outside 0..{n_actions - 1}")
    elif act.dtype != np.float32 or not np.all(np.isfinite(act)):
        raise ProtocolError("bad_action", "continuous actions must be finite float32")
    for name in ("terminated", "truncated"):
        if a[name].max(initial=0) > 1:
            raise ProtocolError("bad_flag", name)


def _created(h: dict) -> float:
    v = h.get("created", 0.0)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ProtocolError("bad_header", f"created {v!r}")
    return float(v)


def _str(h: dict, key: str) -> str:
    v = h.get(key)
    if not isinstance(v, str) or not v or len(v) > 128:
        raise ProtocolError("bad_header", f"{key} {v!r}")
    return v


def _int(h: dict, key: str) -> int:
    v = h.get(key)
    if not isinstance(v, int) or isinstance(v, bool) or v < 0:
        raise ProtocolError("bad_header", f"{key} {v!r}")
    return v


def _episodes(h: dict) -> list[EpisodeSummary]:
    episodes = h.get("episodes") or []
    if not isinstance(episodes, list):
        raise ProtocolError("bad_header", "episodes is not a list")
    return [_typed(EpisodeSummary, e, "bad_header") for e in episodes]


_JSON_TYPES: dict[str, tuple[type, ...]] = {
    "str": (str,),
    "int": (int,),
    "float": (int, float),
    "float | None": (int, float, type(None)),
}


def _typed(cls: type, d: object, reason: str):
    """``cls(**d)`` for a flat dataclass of str/int/float fields, checking every value's type and finiteness:
    a message from the network must not carry a string where the trainer does arithmetic."""
    if not isinstance(d, dict):
        raise ProtocolError(reason, f"{cls.__name__}: not an object")
    try:
        obj = cls(**d)
    except TypeError as exc:
        raise ProtocolError(reason, f"{cls.__name__}: {exc}") from None
    for name, f in cls.__dataclass_fields__.items():
        value = getattr(obj, name)
        ok = _JSON_TYPES[str(f.type)]
        if isinstance(value, bool) or not isinstance(value, ok):
            raise ProtocolError(reason, f"{cls.__name__}.{name} = {value!r}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ProtocolError(reason, f"{cls.__name__}.{name} = {value!r}")
    return obj


class _Message(BaseModel):
    """A JSON message in Redis, validated strictly: every field present and of its type (no bool for an int, no
    string for a number, no NaN or infinity), nothing unknown. A malformed one is a ProtocolError."""

    model_config = ConfigDict(strict=True, frozen=True, extra="forbid", allow_inf_nan=False)
    _reason: ClassVar[str] = "bad_message"

    def to_json(self) -> str:
        """JSON text for Redis."""
        return self.model_dump_json()

    @classmethod
    def from_json(cls, raw: bytes | str) -> Self:
        """Parse and validate; raise ProtocolError naming the first bad field."""
        try:
            return cls.model_validate_json(raw)
        except ValidationError as exc:
            first = exc.errors()[0]
            where = error_location(first["loc"]) or "message"
            raise ProtocolError(cls._reason, f"{cls.__name__}.{where}: {first['msg']}") from None


class PolicyVersion(_Message):
    """A published policy: its version and where its checkpoint is in the store."""

    _reason: ClassVar[str] = "bad_policy_version"
    version: int = Field(ge=0)
    checkpoint_key: str
    created: float


class Heartbeat(_Message):
    """A worker's liveness and progress, kept in a key with a TTL."""

    _reason: ClassVar[str] = "bad_heartbeat"
    worker_id: str
    pid: int
    host: str
    policy_version: int
    env_steps: int
    segments: int
    time: float
    track: str = ""
    policy_loaded_at: float = 0.0
    """Wall-clock time the worker started acting with ``policy_version``, epoch seconds."""
    max_rss_mb: float = 0.0
    """Peak resident memory of the worker process, MB."""


TrainerPhase = Literal["starting", "collecting", "updating", "stopping"]
"""What the trainer process is doing: loading or resuming the run, reading segments, running a PPO update, saving
its last checkpoint on the way out."""


class TrainerBeat(_Message):
    """The trainer process's liveness, refreshed by a thread of its own every few seconds whatever the main loop is
    doing (a PPO update on a loaded machine can take minutes), in a key with a TTL."""

    _reason: ClassVar[str] = "bad_trainer_beat"
    phase: TrainerPhase
    since: float
    """Wall-clock time the phase began, epoch seconds."""
    policy_version: int = Field(ge=0)
    pid: int
    host: str
    time: float


EndReason = Literal["time_limit", "max_updates", "stopped"]
"""Why a trainer stopped: ``time_limit``: its deadline passed; ``max_updates``: ``term_cond_max_episodes`` policy
updates done; ``stopped``: asked to stop (a signal)."""


class TrainerEnd(_Message):
    """Why and where the trainer stopped: written once as it exits, kept after its status and heartbeat expire."""

    _reason: ClassVar[str] = "bad_trainer_end"
    reason: EndReason
    policy_version: int = Field(ge=0)
    env_steps: int = Field(ge=0)
    time: float


class EvaluationSummary(_Message):
    """The evaluator's summary of one robust evaluation, appended to a capped list for ``racer train``'s display
    and the trainer's collapse guard (the whole record, trials included, is in the store)."""

    _reason: ClassVar[str] = "bad_evaluation"
    version: int = Field(ge=0)
    env_steps: int | None
    completion_rate: float = Field(ge=0.0, le=1.0)
    mean_progress: float
    best_lap_s: float | None
    mean_lap_s: float | None = None
    """Mean of the completed laps (None if none); the collapse guard's ``collapse_slowdown`` compares it."""
    off_track: int = Field(ge=0)
    score: float
    best: bool
    """The evaluation moved the run's ``best`` pointer."""


class CarPose(_Message):
    """Where a watched worker's car is now, for ``racer view`` (published only while a page watches,
    ``rollout_worker/watch.py``). Position and heading as the reward function sees them (``params``)."""

    _reason: ClassVar[str] = "bad_pose"
    worker_id: str = Field(max_length=256)
    index: int = Field(ge=0)
    """The worker's index k (the page colours cars by it)."""
    track: str = Field(max_length=256)
    x: float
    y: float
    heading: float
    """Degrees, counter-clockwise from +x (``params["heading"]``)."""
    speed: float
    steering: float
    """Degrees (``params["steering_angle"]``)."""
    progress: float
    steps: int = Field(ge=0)
    reversed: bool
    status: str = Field(max_length=64)
    time: float
    """Wall-clock time of the step, epoch seconds."""
    frames: int = Field(ge=0)
    """Camera frames published so far (0: none yet; the page shows a camera once there is one)."""
    lidar: list[float] | None = Field(default=None, max_length=1024)
    """The LiDAR observation of the step (``common/sensors.py: LIDARS``), None without a LiDAR."""
