"""``racer bench update``: the cost of one PPO minibatch step (forward, backward, Adam) in each trainer setting, and
how much of the machine's GEMM peak it gets.

The trainer's update is most of the time to a lap (docs/speed.md), so this is the figure its settings are
chosen by: the trunk's precision (fp32 or bf16 autocast) and Adam's per-parameter loop or its fused kernel.
All settings are timed in one process, interleaved run by run, so that a noisy machine affects them alike.
``auto`` is the precision ``racer train --precision auto`` would train in here (fused Adam, as the trainer uses):
the faster fused setting of those that run natively (``trainer.precision``).

Each run also times a square GEMM in fp32 and, where native, bf16 (``trainer.peak``), so that the peak and the
update meet the same load. ``fraction_of_peak`` is the update's FLOP/s (its convolutions' and dense layers' FLOPs,
``trainer.peak.update_flops``, over the median step) divided by the median GEMM FLOP/s of the same arithmetic.
"""

from __future__ import annotations

import statistics
import time

import torch
from rich.table import Table
from torch.profiler import ProfilerActivity, profile

from common.policy import build_policy
from racer.bench import Report
from trainer.peak import GEMM_SIZE, Gemm, peak_precisions, update_flops
from trainer.ppo import PPOBatch, StepArgs, minibatch_step
from trainer.precision import fastest, precision_candidates, time_steps

SETTINGS: tuple[tuple[str, bool], ...] = (("fp32", False), ("fp32", True), ("bf16", False), ("bf16", True))
"""(precision, fused Adam) pairs; the first is the trainer before this benchmark existed."""
STEP_ARGS = StepArgs(clip_eps=0.2, beta_entropy=0.01, value_coef=0.5, loss_type="huber", max_grad_norm=0.5)
"""``minibatch_step``'s loss settings (DeepRacer's)."""
GEMM_OPS = frozenset(
    ("aten::mkldnn_convolution", "aten::convolution_backward", "aten::mm", "aten::addmm", "aten::bmm", "aten::matmul")
)
"""The operators that do a layer's multiply-accumulates: the convolutions' and dense layers' GEMMs (their self time
in the profiler; a reorder they call is a copy, counted apart)."""
GEMM_CALLS_PER_STEP = 4
"""GEMM products timed per minibatch step of a run: each precision's GEMM then takes about as long as one setting's
run (a 1024 product is 5-11 ms on 2 cores, a step 40-75 ms), so that a load that comes and goes hits both alike."""


def _setup(precision: str, fused: bool, seed: int) -> tuple:
    torch.manual_seed(seed)
    model = build_policy((120, 160, 1), {"kind": "discrete", "n": 10})
    model.set_trunk_precision(precision)  # type: ignore[arg-type]
    model.train()
    return model, torch.optim.Adam(model.parameters(), lr=3e-4, fused=fused)


def _minibatch(batch: int, seed: int) -> PPOBatch:
    gen = torch.Generator().manual_seed(seed)
    return PPOBatch(
        obs=torch.randint(0, 256, (batch, 120, 160, 1), dtype=torch.uint8, generator=gen),
        actions=torch.randint(0, 10, (batch,), generator=gen),
        old_logp=torch.full((batch,), -2.3),
        advantages=torch.randn(batch, generator=gen),
        returns=torch.randn(batch, generator=gen),
        old_values=torch.zeros(batch),
    )


def bench_update(
    threads: int = 2, batch: int = 64, steps: int = 10, repeats: int = 5, with_breakdown: bool = False
) -> dict:
    """Milliseconds per minibatch step, the median over ``repeats`` runs of ``steps`` steps, per setting; the GFLOP/s
    that makes, the GEMM peak per precision (median over the same runs, interleaved with them) and the fraction of
    that peak each setting gets (None for bf16 where it is emulated: no peak to measure). ``with_breakdown`` adds
    ``breakdown``: :func:`breakdown` of the ``auto`` setting, with its GEMM operators' share of the peak and the
    fraction of peak the step would get if they ran at the peak and the rest took as long as it does
    (``fraction_if_gemms_at_peak``: the most that faster GEMMs alone could give)."""
    torch.set_num_threads(threads)
    cases = {f"{p}{'-fused' if f else ''}": _setup(p, f, 0) for p, f in SETTINGS}
    minibatch = _minibatch(batch, 0)
    gemms = {p: Gemm(p) for p in peak_precisions()}
    calls = max(1, GEMM_CALLS_PER_STEP * steps)
    # Warm-up first (allocator, oneDNN primitive caches), then the settings and the GEMMs interleaved run by run.
    time_steps(cases, minibatch, STEP_ARGS, warmup=3, rounds=0, steps=steps)
    for gemm in gemms.values():
        gemm.gflops(2)
    runs: dict[str, list[float]] = {name: [] for name in cases}
    peak_runs: dict[str, list[float]] = {p: [] for p in gemms}
    for _ in range(repeats):
        for name, ms in time_steps(cases, minibatch, STEP_ARGS, warmup=0, rounds=1, steps=steps).items():
            runs[name] += ms
        for p, gemm in gemms.items():
            peak_runs[p].append(gemm.gflops(calls))
    ms_per_step = {name: statistics.median(v) for name, v in runs.items()}
    base = ms_per_step["fp32"]
    auto = fastest({p: ms_per_step[f"{p}-fused"] for p in precision_candidates("auto")})
    gflop = update_flops(cases["fp32"][0], batch) / 1e9
    peak = {p: statistics.median(peak_runs[p]) if p in peak_runs else None for p in ("fp32", "bf16")}
    gflops = {name: gflop / (ms / 1e3) for name, ms in ms_per_step.items()}
    fraction = {name: _fraction(gflops[name], peak[name.split("-")[0]]) for name in cases}
    result = {
        "auto": auto,
        "threads": threads,
        "batch": batch,
        "ms_per_step": ms_per_step,
        "ms_per_step_runs": runs,
        "speedup_vs_fp32_loop": {name: base / ms for name, ms in ms_per_step.items()},
        "update_gflop": gflop,
        "gflops": gflops,
        "gemm_size": GEMM_SIZE,
        "peak_gflops": peak,
        "peak_gflops_runs": peak_runs,
        "fraction_of_peak": fraction[f"{auto}-fused"],
        "fraction_of_peak_by_setting": fraction,
    }
    if with_breakdown:
        parts = breakdown(auto, threads, batch, steps)
        result["breakdown"] = {
            **parts,
            "gemm_fraction_of_peak": _fraction(parts["gemm_gflops"], peak[auto]),
            "fraction_if_gemms_at_peak": _ceiling(gflop, peak[auto], parts["other_ms"]),
        }
    return result


def _ceiling(gflop: float, peak: float | None, other_ms: float) -> float | None:
    """The fraction of ``peak`` a step of ``gflop`` gets if its GEMMs take ``gflop / peak`` and the rest
    ``other_ms``; None where there is no peak."""
    if peak is None:
        return None
    gemm_ms = gflop / peak * 1e3
    return gemm_ms / (gemm_ms + max(other_ms, 0.0))


def _fraction(gflops: float, peak: float | None) -> float | None:
    """``gflops`` as a share of ``peak``; None where there is no peak (bf16 emulated)."""
    return None if peak is None else gflops / peak


def breakdown(precision: str, threads: int = 2, batch: int = 64, steps: int = 10, top: int = 8) -> dict:
    """Where a fused-Adam minibatch step in ``precision`` spends its time: the median of ``steps`` steps (wall clock),
    the self time of the GEMM operators (:data:`GEMM_OPS`) per step under the PyTorch profiler over ``steps`` more,
    the FLOP/s those reach on the step's FLOPs, and the rest of the step (``other_ms``: Adam, gradient clipping,
    casts, ReLUs, Python). ``gemm_ops`` lists the GEMM operators (name, input shapes, ms a step); ``other_ops`` the
    ``top`` others as the profiler times them, for their order only: it slows large copies (a 5.8 M-weight fp32 to
    bf16 cast took 1.6 ms alone and 3.5 ms profiled on the 2-core AMD EPYC), not the GEMMs."""
    torch.set_num_threads(threads)
    model, optimizer = _setup(precision, True, 0)
    minibatch = _minibatch(batch, 0)
    time_steps({precision: (model, optimizer)}, minibatch, STEP_ARGS, warmup=3, rounds=0, steps=steps)
    wall = []
    for _ in range(steps):
        start = time.perf_counter()
        minibatch_step(model, optimizer, minibatch, **STEP_ARGS)
        wall.append((time.perf_counter() - start) * 1e3)
    with profile(activities=[ProfilerActivity.CPU], record_shapes=True) as prof:
        for _ in range(steps):
            minibatch_step(model, optimizer, minibatch, **STEP_ARGS)
    ops = [
        {"op": e.key, "shapes": [list(s) for s in e.input_shapes if s][:3], "ms": e.self_cpu_time_total / 1e3 / steps}
        for e in prof.key_averages(group_by_input_shape=True)
    ]
    ops.sort(key=lambda o: -o["ms"])
    gemm_ops = [o for o in ops if o["op"] in GEMM_OPS]
    gemm_ms = sum(o["ms"] for o in gemm_ops)
    step_ms = statistics.median(wall)
    return {
        "precision": precision,
        "step_ms": step_ms,
        "gemm_ms": gemm_ms,
        "other_ms": step_ms - gemm_ms,
        "gemm_gflops": update_flops(model, batch) / 1e9 / (gemm_ms / 1e3),
        "gemm_ops": gemm_ops,
        "other_ops": [o for o in ops if o["op"] not in GEMM_OPS][:top],
    }


def command(threads: int, batch: int, repeats: int, breakdown: bool) -> Report:
    """``racer bench update``: the settings' table, the GEMM peak, what ``auto`` picks and, with ``breakdown``, the
    profiled operators of ``auto``'s step."""
    result = bench_update(threads, batch, repeats=repeats, with_breakdown=breakdown)
    table = Table("setting", "ms per minibatch (median)", "speed-up vs fp32 + Adam loop", "GFLOP/s", "of GEMM peak")
    for name, ms in result["ms_per_step"].items():
        fraction = result["fraction_of_peak_by_setting"][name]
        share = "- (bf16 emulated)" if fraction is None else f"{fraction:.2f}"
        table.add_row(
            name, f"{ms:.1f}", f"{result['speedup_vs_fp32_loop'][name]:.2f}×", f"{result['gflops'][name]:.0f}", share
        )
    peaks = ", ".join(f"{p} {g:.0f}" for p, g in result["peak_gflops"].items() if g is not None)
    shown: list[Table | str] = [
        table,
        f"{result['update_gflop']:.2f} GFLOP a minibatch step; GEMM peak ({result['gemm_size']}², "
        f"{threads} threads): {peaks} GFLOP/s",
        f"racer train --precision auto trains in {result['auto']} on this machine, at "
        f"{result['fraction_of_peak']:.2f} of its GEMM peak",
    ]
    if breakdown:
        parts = result["breakdown"]
        ops = Table("operator (profiled)", "input shapes", "ms a step")
        for kind in ("gemm_ops", "other_ops"):
            for op in parts[kind][:8]:
                ops.add_row(op["op"], " ".join(str(tuple(s)) for s in op["shapes"]), f"{op['ms']:.2f}")
            ops.add_section()
        shown += [
            ops,
            f"{parts['precision']} step {parts['step_ms']:.1f} ms: GEMM operators {parts['gemm_ms']:.1f} ms "
            f"at {parts['gemm_fraction_of_peak']:.2f} of the GEMM peak, the rest {parts['other_ms']:.1f} ms "
            "(the profiler slows large copies: the other operators' figures are for their order only); with every "
            f"GEMM at the peak the step would get {parts['fraction_if_gemms_at_peak']:.2f} of it",
        ]
    return Report(result, shown)
