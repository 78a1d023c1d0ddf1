"""``racer bench update``: the cost of one PPO minibatch step (forward, backward, Adam) in each trainer setting.

The trainer's update is most of the time to a lap (docs/speed.md), so this is the figure its settings are
chosen by: the trunk's precision (fp32 or bf16 autocast) and Adam's per-parameter loop or its fused kernel.
All settings are timed in one process, interleaved run by run, so that a noisy machine affects them alike.
``auto`` is the precision ``racer train --precision auto`` would train in here (fused Adam, as the trainer uses):
the faster fused setting of those that run natively (``trainer.precision``).
"""

from __future__ import annotations

import statistics

import torch

from common.policy import build_policy
from trainer.ppo import PPOBatch
from trainer.precision import fastest, precision_candidates, time_steps

SETTINGS: tuple[tuple[str, bool], ...] = (("fp32", False), ("fp32", True), ("bf16", False), ("bf16", True))
"""(precision, fused Adam) pairs; the first is the trainer before this benchmark existed."""


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


def bench_update(threads: int = 2, batch: int = 64, steps: int = 10, repeats: int = 5) -> dict:
    """Milliseconds per minibatch step, the median over ``repeats`` runs of ``steps`` steps, per setting."""
    torch.set_num_threads(threads)
    cases = {f"{p}{'-fused' if f else ''}": _setup(p, f, 0) for p, f in SETTINGS}
    # Warm-up first (allocator, oneDNN primitive caches), then the settings interleaved run by run.
    runs = time_steps(cases, _minibatch(batch, 0), (0.2, 0.01, 0.5, "huber", 0.5), 3, repeats, steps)
    base = statistics.median(runs["fp32"])
    fused = {p: statistics.median(runs[f"{p}-fused"]) for p in precision_candidates("auto")}
    return {
        "auto": fastest(fused),
        "threads": threads,
        "batch": batch,
        "ms_per_step": {name: statistics.median(v) for name, v in runs.items()},
        "ms_per_step_runs": runs,
        "speedup_vs_fp32_loop": {name: base / statistics.median(v) for name, v in runs.items()},
    }
