"""``racer bench worker``: a rollout worker's env steps per second on one core, for K envs per worker.

One process on one core (``racer.bench.env.pin_to_one_core``: one PyTorch thread, single-threaded OpenCV) and no Redis:
the worker's own collect loop (``rollout_worker.rollouts.Rollouts.collect``: the K envs' steps, one batched forward
pass with sampling per step, frame stacks, sim-trace rows, the segments) on the default track, acting with a freshly
built default policy through the worker's acting copy (ONNX Runtime, ``rollout_worker/onnx_policy.py``; ``acting``
``torch`` acts with the network itself). Each K's runs are interleaved with the others', run by run, so that a
noisy machine affects them alike; the figures are medians over the runs.

Per K: env steps per second of the worker's core, its speed-up over the first K (the median of the ratios of
runs made back to back) and where a step's time goes, in µs per env step: ``act`` (the
batched forward passes and sampling, including the value of each segment's last observation), ``env``
(``env.step``: physics, camera, task, reward function) and ``bookkeeping`` (the rest of ``collect``). Beside them:
the env's own parts (``racer.bench.env.env_parts_us``) and the forward pass alone per batch size, PyTorch against ONNX
Runtime, with how far apart their outputs are.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence

import numpy as np
import torch
from rich.table import Table

from common.defaults import DEFAULT_TRACK
from racer.bench import Report
from racer.bench.env import env_parts_us, pin_to_one_core
from racer.runconfig import build_run
from rollout_worker.onnx_policy import Actor, OnnxPolicy, acting_copy
from rollout_worker.rollouts import Rollouts, segment_worker_ids
from trainer.peak import cpu_model

ACT_CALLS = 20
"""Forward passes per timed run of ``act_ms``."""


def bench_worker(
    envs: Sequence[int] = (1, 4, 8),
    seconds: float = 5.0,
    repeats: int = 5,
    track: str = DEFAULT_TRACK,
    acting: str = "onnx",
) -> dict:
    """Env steps/s of a worker with each K of ``envs`` (runs of ``seconds``, ``repeats`` of them per K, interleaved),
    where a step's time goes, and the forward pass's cost per batch size in both runtimes."""
    if acting not in ("onnx", "torch"):
        raise ValueError(f"acting must be 'onnx' or 'torch', got {acting!r}")
    core = pin_to_one_core()
    run, _ = build_run("bench-worker", track=track)
    torch.manual_seed(0)
    groups = {k: Rollouts(run, run.env, [run.seed + j for j in range(k)], segment_worker_ids("bench", k)) for k in envs}
    model = groups[envs[0]].build_policy()
    actor: Actor = acting_copy(model) if acting == "onnx" else model
    for ro in groups.values():
        ro.reset()
        ro.collect(actor, 0)  # warm caches and allocators
        ro.take_simtrace()
    runs: dict[int, list[float]] = {k: [] for k in envs}
    split: dict[int, list[dict[str, float]]] = {k: [] for k in envs}
    for _ in range(repeats):
        for k, ro in groups.items():
            rate, parts = _timed(ro, actor, seconds)
            runs[k].append(rate)
            split[k].append(parts)
    first = groups[envs[0]]
    env_parts = env_parts_us(first.envs[0].env, 500)
    for ro in groups.values():
        ro.close()
    base = runs[envs[0]]
    per_k = {
        str(k): {
            "steps_per_s": statistics.median(runs[k]),
            "steps_per_s_runs": [round(r, 1) for r in runs[k]],
            # Run r of every K ran back to back: the median of the ratios run by run follows a load that drifts.
            "speedup_vs_first": statistics.median(r / b for r, b in zip(runs[k], base, strict=True)),
            "us_per_step": {p: statistics.median(s[p] for s in split[k]) for p in ("act", "env", "bookkeeping")},
        }
        for k in envs
    }
    return {
        "per_k": per_k,
        "acting": "onnxruntime" if isinstance(actor, OnnxPolicy) else "torch",
        "act_ms": act_ms(model, sorted(set(envs)), repeats),
        "env_parts_us": env_parts,
        "track": track,
        "segment_steps": run.segment_steps,
        "seconds": seconds,
        "repeats": repeats,
        "machine": {"cpu": cpu_model(), "core": core},
    }


def _timed(ro: Rollouts, actor: Actor, seconds: float) -> tuple[float, dict[str, float]]:
    """Collect for ``seconds``: (env steps/s, µs per env step of act, env and bookkeeping)."""
    before, steps = dict(ro.time_s), ro.env_steps
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        ro.collect(actor, 0)
    ro.take_simtrace()  # a worker uploads its rows once per policy version; here they are only dropped
    spent = {name: ro.time_s[name] - before[name] for name in ro.time_s}
    n = ro.env_steps - steps
    us = {"act": spent["act"], "env": spent["env"], "bookkeeping": spent["collect"] - spent["act"] - spent["env"]}
    return n / spent["collect"], {name: v / n * 1e6 for name, v in us.items()}


def act_ms(model: torch.nn.Module, batches: Sequence[int], repeats: int) -> dict:
    """Milliseconds per ``act_numpy`` (forward pass and sampling) of a batch, PyTorch and ONNX Runtime interleaved
    (medians of ``repeats`` runs of :data:`ACT_CALLS` calls), and the largest difference between their log-probs
    and values, with the same actions drawn from the same random state (``same_actions``)."""
    onnx = OnnxPolicy(model)
    actors: dict[str, Actor] = {"torch": model, "onnxruntime": onnx}
    rng = np.random.default_rng(0)
    out: dict = {name: {} for name in actors}
    out["max_abs_diff"], out["same_actions"] = {}, True
    for b in batches:
        obs = rng.integers(0, 256, (b, *model.obs_shape), dtype=np.uint8)
        results = {}
        for name, actor in actors.items():
            torch.manual_seed(b)
            results[name] = actor.act_numpy(obs)
        (a_t, lp_t, v_t), (a_o, lp_o, v_o) = results["torch"], results["onnxruntime"]
        out["same_actions"] &= bool(np.array_equal(a_t, a_o))
        out["max_abs_diff"][str(b)] = float(max(np.abs(lp_t - lp_o).max(), np.abs(v_t - v_o).max()))
        times: dict[str, list[float]] = {name: [] for name in actors}
        for _ in range(repeats):
            for name, actor in actors.items():
                t0 = time.perf_counter()
                for _ in range(ACT_CALLS):
                    actor.act_numpy(obs)
                times[name].append((time.perf_counter() - t0) / ACT_CALLS * 1e3)
        for name in actors:
            out[name][str(b)] = statistics.median(times[name])
    return out


def command(ks: list[int], seconds: float, repeats: int, track: str, acting: str) -> Report:
    """``racer bench worker``: check K (distinct, 1 to MAX_ENVS_PER_WORKER) and ``acting`` (onnx or torch), time the
    worker at each K and report where a step's time goes."""
    from common.config import MAX_ENVS_PER_WORKER
    from common.errors import OptionError

    bad = [k for k in ks if not 1 <= k <= MAX_ENVS_PER_WORKER]
    if bad or len(set(ks)) != len(ks):
        given = ",".join(str(k) for k in ks)
        raise OptionError(f"--envs-per-worker takes distinct integers from 1 to {MAX_ENVS_PER_WORKER} (got {given!r})")
    if acting not in ("onnx", "torch"):
        raise OptionError(f"--acting must be onnx or torch (got {acting!r})")
    result = bench_worker(ks, seconds, repeats, track, acting)
    table = Table("K", "env steps/s (median)", f"vs K={ks[0]}", "act µs/step", "env µs/step", "bookkeeping µs/step")
    for k, r in result["per_k"].items():
        us = r["us_per_step"]
        table.add_row(
            k,
            f"{r['steps_per_s']:.0f}",
            f"{r['speedup_vs_first']:.2f}×",
            f"{us['act']:.0f}",
            f"{us['env']:.0f}",
            f"{us['bookkeeping']:.0f}",
        )
    act = result["act_ms"]
    return Report(
        result,
        [
            table,
            "forward pass + sampling, ms per batch (torch / onnxruntime): "
            + ", ".join(f"B={b} {act['torch'][b]:.2f} / {act['onnxruntime'][b]:.2f}" for b in act["torch"]),
            f"acting with {result['acting']} on {result['machine']['cpu']}",
        ],
    )
