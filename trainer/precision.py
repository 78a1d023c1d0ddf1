"""The arithmetic of the trainer's PPO updates: the trunk in fp32, or in bf16 under autocast.

``auto`` measures rather than guesses. A CPU with native bf16 kernels (AVX512-BF16 or AMX) is not always faster in
bf16: on some it is, on others bf16 is the slower (docs/speed.md has the timings of both kinds of machine). Where
both can run natively, the trainer times a few minibatch steps of each
on a copy of its own network and its first batch, under the threads and load it trains with, and keeps the faster.
Where bf16 would be emulated (no native kernels) it is always slower, and fp32 is used without a measurement.
Where the two are close, the choice can differ between runs on one machine, and with it the updates' rounding: a
run that must repeat bit for bit names its precision (``racer train --precision fp32``).

On a CUDA device (``--device``, ``trainer/device.py``) nothing is timed: ``auto`` is a bf16 trunk where the GPU has
native bf16 (compute capability 8 and up: :func:`bf16_is_fast`), else an fp16 trunk, whose gradients
are loss-scaled by a ``torch.amp.GradScaler`` (:func:`grad_scaler`: fp16's 5-bit exponent underflows small
gradients). Either way only the trunk runs under autocast; the weights, the heads, the losses and Adam's state stay
float32. ``fp16`` is refused on a CPU (no fast kernels there), ``bf16`` on a GPU without it. None of the CUDA path
has run on a GPU yet.
"""

from __future__ import annotations

import copy
import statistics
import time

import torch

from common.config import check_precision
from common.errors import OptionError
from common.policy import ActorCritic, Precision
from trainer.ppo import PPOBatch, StepArgs, minibatch_step

PROBE_WARMUP = 2
"""Untimed steps per precision first: oneDNN builds its kernels for a shape and dtype on the first call."""
PROBE_ROUNDS = 3
"""Timed rounds, the precisions interleaved round by round so that a load that comes and goes hits both alike."""
PROBE_STEPS = 2
"""Minibatch steps per precision per round; the median round is kept. With the warm-up, 16 steps in all: about
1.3 s on a machine where a step takes 65-100 ms, once per trainer process."""


def bf16_is_fast(device: str = "cpu") -> bool:
    """True where bf16 matrix kernels run natively (AVX512-BF16 or AMX on a CPU; a CUDA GPU of compute capability 8
    or more for ``cuda`` / ``cuda:N``), so that a bf16 trunk is faster than fp32. Elsewhere bf16 is emulated, and
    slower."""
    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            return False
        with torch.cuda.device(torch.device(device)):  # is_bf16_supported asks the current device
            return torch.cuda.is_bf16_supported(including_emulation=False)
    # torch.cpu's checks are private but stable since 2.3; without them, assume emulation (fp32 is then faster).
    native = (
        getattr(torch.cpu, "_is_avx512_bf16_supported", lambda: False)()
        or getattr(torch.cpu, "_is_amx_tile_supported", lambda: False)()
    )
    return bool(native and torch.backends.mkldnn.is_available())


def precision_candidates(precision: str, device: torch.device | None = None) -> tuple[Precision, ...]:
    """What ``precision`` may run as on ``device`` (None: the CPU).

    On the CPU: itself for ``fp32`` or ``bf16``; for ``auto``, both where bf16 kernels are native
    (:func:`bf16_is_fast`; the faster is then measured), fp32 alone where they are not. On a CUDA
    device: itself, and for ``auto`` bf16 where the GPU has it, else fp16. :class:`~common.errors.OptionError` for
    any other name, for ``fp16`` on the CPU and for ``bf16`` on a GPU without bf16."""
    check_precision(precision)
    if device is None or device.type != "cuda":
        if precision == "fp16":
            raise OptionError("--precision 'fp16' is for CUDA devices (--device cuda); on a CPU use auto, fp32 or bf16")
        if precision == "auto":
            return ("fp32", "bf16") if bf16_is_fast() else ("fp32",)
        return (precision,)  # type: ignore[return-value]
    has_bf16 = bf16_is_fast(str(device))
    if precision == "bf16" and not has_bf16:
        raise OptionError(f"--precision bf16: the GPU {device} has no native bf16; use auto or fp16")
    if precision == "auto":
        return ("bf16",) if has_bf16 else ("fp16",)
    return (precision,)  # type: ignore[return-value]


def grad_scaler(precision: Precision, device: torch.device) -> torch.amp.GradScaler | None:
    """The loss scaler an fp16 trunk needs on a CUDA device (``trainer.ppo.minibatch_step`` takes it); None for
    every other precision and device, whose gradients are float32 or bf16 (float32's exponent range)."""
    if precision == "fp16" and device.type == "cuda":
        return torch.amp.GradScaler(device.type)
    return None


def time_precisions(
    model: ActorCritic,
    minibatch: PPOBatch,
    candidates: tuple[Precision, ...],
    step_args: StepArgs,
    lr: float = 3e-4,
) -> dict[str, float]:
    """Milliseconds per PPO minibatch step (forward, backward, fused Adam) of a copy of ``model`` in each candidate
    precision, on ``minibatch``; the median of :data:`PROBE_ROUNDS` interleaved rounds. ``step_args`` are
    :func:`trainer.ppo.minibatch_step`'s loss settings by name (clip_eps, beta_entropy, value_coef, loss_type and
    max_grad_norm). ``model`` itself (weights, precision, mode) is not touched, nor torch's random state (a network
    with dropout draws from it).
    """
    with torch.random.fork_rng(devices=[]):
        return _time_copies(model, minibatch, candidates, step_args, lr)


def _time_copies(
    model: ActorCritic,
    minibatch: PPOBatch,
    candidates: tuple[Precision, ...],
    step_args: StepArgs,
    lr: float,
) -> dict[str, float]:
    copies = {}
    for precision in candidates:
        twin = copy.deepcopy(model)
        twin.set_trunk_precision(precision)
        twin.train()
        copies[precision] = (twin, torch.optim.Adam(twin.parameters(), lr=lr, fused=True))
    rounds = time_steps(copies, minibatch, step_args, warmup=PROBE_WARMUP, rounds=PROBE_ROUNDS, steps=PROBE_STEPS)
    return {precision: statistics.median(ms) for precision, ms in rounds.items()}


def time_steps(
    cases: dict[str, tuple[torch.nn.Module, torch.optim.Optimizer]],
    minibatch: PPOBatch,
    step_args: StepArgs,
    *,
    warmup: int,
    rounds: int,
    steps: int,
) -> dict[str, list[float]]:
    """Milliseconds per PPO minibatch step of each (model, optimizer) case, one figure per round: ``warmup`` untimed
    steps of each first, then ``rounds`` rounds of ``steps`` steps, the cases interleaved round by round so that a
    load that comes and goes hits them alike. The cases' weights move: pass copies. ``racer bench update`` uses it
    too."""
    for model, optimizer in cases.values():
        for _ in range(warmup):
            minibatch_step(model, optimizer, minibatch, **step_args)
    ms: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(rounds):
        for name, (model, optimizer) in cases.items():
            start = time.perf_counter()
            for _ in range(steps):
                minibatch_step(model, optimizer, minibatch, **step_args)
            ms[name].append((time.perf_counter() - start) / steps * 1e3)
    return ms


def fastest(ms_per_step: dict[str, float]) -> Precision:
    """The precision with the fewest milliseconds per step; fp32 on a tie (it is the exact one)."""
    if not ms_per_step:
        raise ValueError("no precision was timed")
    return min(sorted(ms_per_step, key=lambda p: p != "fp32"), key=lambda p: ms_per_step[p])  # type: ignore[return-value]
