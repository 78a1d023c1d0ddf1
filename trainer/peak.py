"""The machine's matrix-multiply peak and the arithmetic of one PPO minibatch step, to put the update against it.

``racer bench update`` divides the FLOP/s a minibatch step achieves by the FLOP/s of a plain square GEMM in the same
arithmetic, on the same threads, timed in the same run: the share of what this CPU's BLAS can do that the update
gets.

* The peak (:class:`Gemm`): ``C = A @ B`` with square ``A``, ``B`` of :data:`GEMM_SIZE` (compute-bound: 2·n³ FLOPs
  on 3·n² values), in fp32, and in bf16 where its kernels are native (:func:`trainer.precision.bf16_is_fast`; emulated
  bf16 is no hardware peak). It is what ``torch.mm`` reaches (MKL for fp32, oneDNN for bf16), not a figure from
  the data sheet: the clock the cores keep under load is in it, and it is what a convolution's GEMM could reach.
* The work (:func:`layer_costs`, :func:`step_flops`): the multiply-accumulates of the network's convolutions and
  dense layers, 2 FLOPs each, counted from the layers themselves on the real input shape. Forward one GEMM per
  layer; backward one for the weight gradient and one for the input gradient, except where the layer's input
  needs no gradient (the first convolution, fed by the frames): about 3× the forward in all. Biases, ReLUs,
  batch norm, the losses, gradient clipping and Adam are left out: they are memory-bound, and they are part of what
  keeps the update below the peak.
"""

from __future__ import annotations

import math
import platform
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import nn

from common.policy import ActorCritic, Precision
from trainer.precision import bf16_is_fast

GEMM_SIZE = 1024
"""Side of the square matrices: 2.1 GFLOP a product, compute-bound (on the 2-core AMD EPYC 1024 and 2048 gave the
same GFLOP/s within 5 %, 512 about 12 % less), and a few milliseconds a call so that it interleaves with the update."""


def peak_precisions() -> tuple[Precision, ...]:
    """The arithmetic whose peak means something here: fp32, and bf16 where its kernels are native."""
    return ("fp32", "bf16") if bf16_is_fast() else ("fp32",)


class Gemm:
    """A square matrix product in one precision, its operands and result allocated once, ready to be timed."""

    def __init__(self, precision: Precision, size: int = GEMM_SIZE, seed: int = 0) -> None:
        dtype = {"fp32": torch.float32, "bf16": torch.bfloat16}[precision]
        gen = torch.Generator().manual_seed(seed)
        self.precision = precision
        self.size = size
        self.a = torch.randn(size, size, generator=gen).to(dtype)
        self.b = torch.randn(size, size, generator=gen).to(dtype)
        self.c = torch.empty(size, size, dtype=dtype)

    @property
    def flops(self) -> int:
        """FLOPs of one product: n³ multiply-accumulates, 2 FLOPs each."""
        return 2 * self.size**3

    def gflops(self, calls: int) -> float:
        """GFLOP/s over ``calls`` back-to-back products (under torch's current thread count)."""
        start = time.perf_counter()
        for _ in range(calls):
            torch.mm(self.a, self.b, out=self.c)
        return self.flops * calls / (time.perf_counter() - start) / 1e9


@dataclass(frozen=True)
class LayerCost:
    """The multiply-accumulates of one convolution or dense layer for one sample, and which gradients it needs."""

    name: str
    macs: int
    """Multiply-accumulates of the forward pass, per sample."""
    weight_grad: bool
    """The backward computes the weight gradient (one more GEMM of ``macs``)."""
    input_grad: bool
    """The backward computes the input gradient (one more GEMM of ``macs``): false where the input is the data."""


def step_flops(layers: Sequence[LayerCost], batch: int) -> int:
    """FLOPs of one forward and backward pass of ``batch`` samples: 2 per multiply-accumulate, once for the forward,
    once more for each gradient a layer computes."""
    return sum(2 * layer.macs * (1 + layer.weight_grad + layer.input_grad) for layer in layers) * batch


def layer_costs(model: nn.Module, *example: torch.Tensor) -> list[LayerCost]:
    """The :class:`LayerCost` of each ``Conv2d`` and ``Linear`` of ``model``, in the order they run, from one forward
    pass on ``example`` (a batch of one). A layer's input needs a gradient exactly when autograd says so
    (``requires_grad`` of what reaches it), so a layer fed by data that needs none is counted without one. The pass
    runs in eval mode (no batch-norm statistics move, no dropout draws) and leaves the mode as it was."""
    costs: list[LayerCost] = []

    def record(name: str):
        def hook(module: nn.Module, inputs: tuple[torch.Tensor, ...], output: torch.Tensor) -> None:
            per_output = module.in_features if isinstance(module, nn.Linear) else _conv_macs_per_output(module)
            macs = output.numel() // output.shape[0] * per_output
            costs.append(LayerCost(name, macs, module.weight.requires_grad, inputs[0].requires_grad))

        return hook

    handles = [
        module.register_forward_hook(record(name))
        for name, module in model.named_modules()
        if isinstance(module, (nn.Conv2d, nn.Linear))
    ]
    was_training = model.training
    try:
        model.eval()
        with torch.enable_grad():
            model(*example)
    finally:
        model.train(was_training)
        for handle in handles:
            handle.remove()
    return costs


def _conv_macs_per_output(conv: nn.Module) -> int:
    """Multiply-accumulates per output value of a ``Conv2d``: its input channels per group × the kernel's area."""
    assert isinstance(conv, nn.Conv2d)
    return conv.in_channels // conv.groups * math.prod(conv.kernel_size)


def update_flops(model: ActorCritic, batch: int) -> int:
    """FLOPs of one PPO minibatch step's forward and backward (:func:`step_flops`) of ``model`` on ``batch`` uint8
    frames of its own shape (and LiDAR vectors where it has a LiDAR)."""
    obs = torch.zeros((1, *model.obs_shape), dtype=torch.uint8)
    lidar = torch.zeros((1, model.lidar_size)) if model.lidar_size else None
    return step_flops(layer_costs(model, obs, lidar), batch)


def cpu_model() -> str:
    """The CPU's model name (Linux's /proc/cpuinfo), else what ``platform`` says: the machine a benchmark's
    figures were measured on."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()
