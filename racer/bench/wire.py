"""The wire budget: bytes per env step a worker sends upstream (segments) and bytes per policy version it downloads,
with the CPU cost of encoding and decoding a segment.

Segments here are collected by the rollout worker's own loop at version 0: a ``RacerEnv`` of the default run
(default track, DeepRacer's default action space and reward function) with the chosen sensors and stack size,
driven by the untrained default network, episodes reset as they end. The
figures compare schema 1 (every array raw, ``schema1_bytes``) with today's ``encode_segment``; ``codecs`` compares
compressions of the same distinct frames. Times are CPU time of this process (``time.process_time``: a shared
machine's other work does not count), per env step, medians over repeats. ``bench_wire()`` returns a JSON-ready
dict; ``python -m racer.bench.wire`` prints it.
"""

from __future__ import annotations

import json
import statistics
import tempfile
import time
import zlib
from collections.abc import Callable, Sequence

import numpy as np
import torch
from rich.table import Table

from common.config import EnvConfig, PolicyConfig, RandomizationConfig, RunConfig
from common.hyperparams import Hyperparameters
from common.policy import build_policy
from common.protocol import Segment, decode_segment, encode_segment, frame_table
from common.sensors import LidarSpec, observation_spec
from common.weights import acting_from_bytes, acting_to_bytes, checkpoint_from_bytes, checkpoint_to_bytes
from racer.bench import Report
from rollout_worker.rollouts import Rollouts
from trainer.peak import cpu_model

_IMAGE_RANDOMIZED = {"texture": 1.0, "lighting": 1.0, "track_color": 1.0}
CASES: dict[str, tuple[tuple[str, ...] | None, int, dict]] = {
    "default": (None, 1, {}),
    "stack3": (None, 3, {}),
    "stereo_lidar": (("STEREO_CAMERAS", "LIDAR"), 1, {}),
    "stereo_lidar_stack3": (("STEREO_CAMERAS", "LIDAR"), 3, {}),
    "image_randomized": (None, 1, _IMAGE_RANDOMIZED),
    "salt_pepper": (None, 1, {**_IMAGE_RANDOMIZED, "augment": {"salt_pepper_prob": 1.0}}),
}
"""Runs measured: (model_metadata sensor list, None for the default front camera; stack_size; RandomizationConfig
fields: the last two randomize the image at full strength, the frames a codec finds hardest)."""
N_ACTIONS = 10
"""DeepRacer's default action space, the one ``driven_segments`` drives with."""


def driven_segments(
    steps: int = 32,
    segments: int = 8,
    *,
    sensors: Sequence[str] | None = None,
    stack_size: int = 1,
    seed: int = 0,
    randomization: dict | None = None,
) -> list[Segment]:
    """``segments`` consecutive segments of ``steps`` env steps, collected by the rollout worker's own loop
    (``rollout_worker.rollouts.Rollouts``, one env) at version 0 of the default run with ``sensors``, ``stack_size``
    and ``randomization`` (RandomizationConfig fields), driven by the untrained network."""
    from racer.bench.env import write_sensor_space

    dr = RandomizationConfig.model_validate(randomization or {})
    with tempfile.TemporaryDirectory(prefix="racer-bench-wire-") as folder:
        space = str(write_sensor_space(folder, sensors)) if sensors else None
        env = EnvConfig(action_space=space, randomization=dr)
        run = RunConfig(
            run_id="bench-wire",
            env=env,
            hyperparams=Hyperparameters(stack_size=stack_size),
            policy=PolicyConfig(stack_size=stack_size),
            segment_steps=steps,
            seed=seed,
        )
        rollouts = Rollouts(run, env, [seed], ["bench-0"])  # builds the env while its action space file exists
    torch.manual_seed(seed)
    model = rollouts.build_policy()
    rollouts.reset()
    out = [seg for _ in range(segments) for seg in rollouts.collect(model, 0)]
    rollouts.close()
    return out


def schema1_bytes(seg: Segment) -> int:
    """Bytes of ``seg`` as schema 1 encoded it (every array raw, ``obs`` and ``next_obs`` included): field names,
    header JSON and array bytes, what one stream entry carried before the frames were compressed."""
    specs = {name: {"dtype": str(a.dtype), "shape": list(a.shape)} for name, a in seg.arrays.items()}
    header = {
        "schema": 1,
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
    arrays = sum(len(f"a:{name}") + a.nbytes for name, a in seg.arrays.items())
    return len("header") + len(json.dumps(header, separators=(",", ":"))) + arrays


def wire_bytes(fields: dict[str, bytes]) -> int:
    """Bytes of one encoded stream entry: field names and values."""
    return sum(len(k) + len(v) for k, v in fields.items())


def segment_figures(segments: list[Segment], lidar: LidarSpec | None = None, repeats: int = 5) -> dict:
    """Bytes per env step before (schema 1) and now, and microseconds per env step to encode and to decode
    (``lidar``: the run's LiDAR, None without one)."""
    steps = sum(s.steps for s in segments)
    shape = segments[0].arrays["obs"].shape[1:]

    def decode(seg: Segment, fields: dict[str, bytes]) -> Segment:
        return decode_segment(fields, seg.run_id, shape, N_ACTIONS, lidar)

    encoded = [encode_segment(s) for s in segments]
    for seg, fields in zip(segments, encoded, strict=True):  # bit for bit, or the figures mean nothing
        back = decode(seg, fields)
        assert all(np.array_equal(back.arrays[k], v) for k, v in seg.arrays.items())
    enc, dec = [], []
    for _ in range(repeats):
        t0 = time.process_time()
        for s in segments:
            encode_segment(s)
        t1 = time.process_time()
        for s, f in zip(segments, encoded, strict=True):
            decode(s, f)
        t2 = time.process_time()
        enc.append((t1 - t0) / steps * 1e6)
        dec.append((t2 - t1) / steps * 1e6)
    before = sum(schema1_bytes(s) for s in segments) / steps
    after = sum(wire_bytes(f) for f in encoded) / steps
    return {
        "obs_shape": list(shape),
        "segment_steps": segments[0].steps,
        "segments": len(segments),
        "bytes_per_step_before": round(before, 1),
        "bytes_per_step": round(after, 1),
        "ratio": round(before / after, 2),
        "encode_us_per_step": round(statistics.median(enc), 1),
        "decode_us_per_step": round(statistics.median(dec), 1),
    }


def _codecs() -> dict[str, tuple[Callable[[bytes], bytes], Callable[[bytes, int], bytes]]]:
    import lz4.block
    import zstandard

    z1, z3 = zstandard.ZstdCompressor(level=1), zstandard.ZstdCompressor(level=3)
    d = zstandard.ZstdDecompressor()
    return {
        "zstd1": (z1.compress, lambda b, n: d.decompress(b, max_output_size=n)),
        "zstd3": (z3.compress, lambda b, n: d.decompress(b, max_output_size=n)),
        "lz4": (
            lambda b: lz4.block.compress(b, store_size=False),
            lambda b, n: lz4.block.decompress(b, uncompressed_size=n),
        ),
        "zlib1": (lambda b: zlib.compress(b, 1), lambda b, n: zlib.decompress(b)),
    }


def _delta(planes: np.ndarray) -> np.ndarray:
    """PNG-style temporal delta: each plane minus the one before it (mod 256), the first as it is."""
    out = planes.copy()
    out[1:] -= planes[:-1]
    return out


def _undelta(delta: np.ndarray) -> np.ndarray:
    return np.cumsum(delta, axis=0, dtype=np.uint8)


def codec_figures(segments: list[Segment], repeats: int = 5) -> dict:
    """Each codec on each segment's distinct planes (what ``a:frames`` carries), plain and after a temporal delta
    (plane minus previous plane, then the codec): frame bytes per env step, ratio to the raw planes, microseconds per
    env step to encode (delta included) and decode (undelta included). Needs ``lz4`` for its row."""
    tables = [np.stack(frame_table(s.arrays["obs"], s.arrays["next_obs"])[0]) for s in segments]
    steps = sum(s.steps for s in segments)
    raw = sum(t.nbytes for t in tables)
    out: dict[str, dict] = {"raw": {"bytes_per_step": round(raw / steps, 1)}}
    try:
        codecs = _codecs()
    except ImportError as exc:
        out["missing"] = str(exc)
        return out
    for name, (compress, decompress) in codecs.items():
        for delta in (False, True):
            sizes, enc, dec = 0, [], []
            for _ in range(repeats):
                te = td = 0.0
                sizes = 0
                for t in tables:
                    t0 = time.process_time()
                    blob = compress(_delta(t) if delta else t)
                    t1 = time.process_time()
                    flat = np.frombuffer(decompress(blob, t.nbytes), np.uint8).reshape(t.shape)
                    back = _undelta(flat) if delta else flat
                    t2 = time.process_time()
                    te += t1 - t0
                    td += t2 - t1
                    sizes += len(blob)
                    assert np.array_equal(back, t)
                enc.append(te / steps * 1e6)
                dec.append(td / steps * 1e6)
            out[f"delta+{name}" if delta else name] = {
                "bytes_per_step": round(sizes / steps, 1),
                "ratio": round(raw / sizes, 2),
                "encode_us_per_step": round(statistics.median(enc), 1),
                "decode_us_per_step": round(statistics.median(dec), 1),
            }
    return out


def policy_figures(repeats: int = 5) -> dict:
    """Bytes a worker downloads per policy version, the checkpoint's ``.pt`` (what it loaded before) against the
    acting copy, for the default run's network, and the milliseconds to turn each into weights."""
    torch.manual_seed(0)
    model = build_policy((120, 160, 1), {"kind": "discrete", "n": 10})
    full = checkpoint_to_bytes(model.state_dict())
    acting = acting_to_bytes(model.state_dict())
    load_full, load_acting = [], []
    for _ in range(repeats):
        t0 = time.process_time()
        model.load_state_dict(checkpoint_from_bytes(full)[0])
        t1 = time.process_time()
        model.load_state_dict(acting_from_bytes(acting))
        t2 = time.process_time()
        load_full.append((t1 - t0) * 1e3)
        load_acting.append((t2 - t1) * 1e3)
    return {
        "checkpoint_bytes": len(full),
        "acting_bytes": len(acting),
        "ratio": round(len(full) / len(acting), 2),
        "load_checkpoint_ms": round(statistics.median(load_full), 1),
        "load_acting_ms": round(statistics.median(load_acting), 1),
    }


def bench_wire(segments: int = 8, steps: int = 32, repeats: int = 5, seed: int = 0) -> dict:
    """The wire figures of each run in ``CASES`` (``segments`` segments of ``steps`` steps each), the codecs on the
    default run's frames, and the policy download."""
    torch.set_num_threads(1)  # a worker's setting
    runs = {}
    default: list[Segment] = []
    for name, (sensors, stack_size, randomization) in CASES.items():
        segs = driven_segments(
            steps, segments, sensors=sensors, stack_size=stack_size, seed=seed, randomization=randomization
        )
        lidar = observation_spec(sensors or ("FRONT_FACING_CAMERA",), stack_size).lidar
        runs[name] = segment_figures(segs, lidar, repeats)
        default = default or segs
    return {
        "machine": cpu_model(),
        "segments": runs,
        "codecs_default": codec_figures(default, repeats),
        "policy": policy_figures(repeats),
    }


def command(segments: int, steps: int, repeats: int) -> Report:
    """``racer bench wire``: each run's bytes and codec cost per env step, and the policy download."""
    result = bench_wire(segments, steps, repeats)
    table = Table("run", "bytes/step before", "bytes/step", "ratio", "encode µs/step", "decode µs/step")
    for name, f in result["segments"].items():
        table.add_row(
            name,
            f"{f['bytes_per_step_before']:,.0f}",
            f"{f['bytes_per_step']:,.0f}",
            f"{f['ratio']:.1f}",
            f"{f['encode_us_per_step']:.0f}",
            f"{f['decode_us_per_step']:.0f}",
        )
    policy = result["policy"]
    line = (
        f"policy version: checkpoint {policy['checkpoint_bytes']:,} bytes, acting copy {policy['acting_bytes']:,} "
        f"bytes ({policy['ratio']:.2f}x smaller); machine {result['machine']}"
    )
    return Report(result, [table, line])


if __name__ == "__main__":
    print(json.dumps(bench_wire(), indent=2))
