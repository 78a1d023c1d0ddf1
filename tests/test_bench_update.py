"""``racer bench update`` against the machine's GEMM peak: the FLOPs of a minibatch step counted from the layers, the
peak GEMM, and the JSON's keys."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from torch import nn

from common.config import PolicyConfig
from common.policy import build_policy
from racer.bench.update import GEMM_OPS, _ceiling
from trainer.peak import Gemm, LayerCost, layer_costs, peak_precisions, step_flops, update_flops

DISCRETE = {"kind": "discrete", "n": 10}


def test_a_tiny_network_costs_its_hand_counted_flops() -> None:
    model = nn.Sequential(nn.Conv2d(2, 3, 2, stride=2), nn.ReLU(), nn.Conv2d(3, 4, 1), nn.Flatten(), nn.Linear(24, 5))
    costs = layer_costs(model, torch.zeros(1, 2, 5, 7))
    # conv 2→3, 2×2 stride 2 on 5×7: 3 × 2 × 3 outputs × (2 channels × 2 × 2) = 144 MACs, fed by the data (no input
    # gradient); conv 3→4, 1×1: 4 × 2 × 3 outputs × 3 = 72; dense 24→5: 120.
    assert costs == [
        LayerCost("0", 144, weight_grad=True, input_grad=False),
        LayerCost("2", 72, weight_grad=True, input_grad=True),
        LayerCost("4", 120, weight_grad=True, input_grad=True),
    ]
    # 2 FLOPs a MAC: forward + weight gradient (2 × 144 × 2 = 576), + input gradient (2 × 72 × 3 = 432,
    # 2 × 120 × 3 = 720): 1728 a sample, × a batch of 3.
    assert step_flops(costs, 3) == 5184


def test_a_frozen_layer_and_an_input_that_needs_a_gradient_are_counted_as_autograd_runs_them() -> None:
    model = nn.Linear(4, 2)
    model.weight.requires_grad_(False)
    (cost,) = layer_costs(model, torch.zeros(1, 4, requires_grad=True))
    assert cost == LayerCost("", 8, weight_grad=False, input_grad=True)
    assert step_flops([cost], 10) == 10 * 2 * 8 * 2


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_deepracers_shallow_network_step_flops_by_hand() -> None:
    # Per 120×160 frame: conv 32 8/4 → 32×29×39 × 64 = 2,316,288 MACs; conv 64 4/2 → 64×13×18 × 512 = 7,667,712;
    # conv 64 3/1 → 64×11×16 × 576 = 6,488,064; dense 11264→512 = 5,767,168; heads 512×10 + 512 = 5,632.
    # Forward 22,244,864 MACs; weight gradients the same; input gradients all but the first conv's: 19,928,576.
    forward = 2_316_288 + 7_667_712 + 6_488_064 + 5_767_168 + 5_632
    per_sample = 2 * (forward + forward + forward - 2_316_288)
    model = build_policy((120, 160, 1), DISCRETE)
    assert update_flops(model, 64) == per_sample * 64 == 8_245_542_912
    model.set_trunk_precision("bf16")  # the arithmetic changes, the work does not
    assert update_flops(model, 64) == 8_245_542_912
    # Three stacked frames: only the first conv's MACs grow (×3), and it has no input gradient.
    stacked = build_policy((120, 160, 3), DISCRETE, PolicyConfig(stack_size=3))
    assert update_flops(stacked, 64) == 8_245_542_912 + 64 * 2 * 2 * 2 * 2_316_288


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_counting_leaves_the_network_as_it_was() -> None:
    model = build_policy((120, 160, 1), DISCRETE, PolicyConfig(batch_norm=True, dropout=0.5))
    model.train()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    state = torch.random.get_rng_state()
    update_flops(model, 8)
    assert model.training
    assert all(torch.equal(v, before[k]) for k, v in model.state_dict().items()), "batch-norm statistics moved"
    assert torch.equal(torch.random.get_rng_state(), state), "dropout drew"


@pytest.mark.parametrize("precision", peak_precisions())
def test_the_gemm_peak_times_a_square_product(precision: str) -> None:
    gemm = Gemm(precision, size=64)  # type: ignore[arg-type]
    assert gemm.flops == 2 * 64**3
    assert gemm.gflops(2) > 0
    torch.testing.assert_close(gemm.c.float(), gemm.a.float() @ gemm.b.float(), rtol=0.02, atol=0.5)


def test_the_ceiling_is_the_share_a_step_gets_with_its_gemms_at_the_peak() -> None:
    # 8 GFLOP at 400 GFLOP/s is 20 ms of GEMMs; with 20 ms of the rest the step gets half the peak.
    assert _ceiling(8.0, 400.0, 20.0) == pytest.approx(0.5)
    assert _ceiling(8.0, 400.0, 0.0) == 1.0 and _ceiling(8.0, None, 20.0) is None


@pytest.mark.slow(reason="starts real racer processes")
def test_bench_update_reports_its_share_of_the_gemm_peak(tmp_path: Path) -> None:
    # A subprocess: the benchmark sets torch's thread count, which must not change the test runner's.
    out = tmp_path / "update.json"
    cmd = [sys.executable, "-m", "racer", "bench", "update", "--threads", "1", "--batch", "8", "--repeats", "1"]
    cmd.append("--breakdown")
    subprocess.run([*cmd, "--json", str(out)], check=True, capture_output=True, timeout=300)
    result = json.loads(out.read_text())
    settings = {"fp32", "fp32-fused", "bf16", "bf16-fused"}
    assert set(result["ms_per_step"]) == set(result["gflops"]) == set(result["fraction_of_peak_by_setting"]) == settings
    assert result["update_gflop"] == pytest.approx(8_245_542_912 / 64 * 8 / 1e9)
    assert result["peak_gflops"]["fp32"] > 0
    assert (result["peak_gflops"]["bf16"] is not None) == ("bf16" in peak_precisions())
    assert 0 < result["fraction_of_peak"] == result["fraction_of_peak_by_setting"][f"{result['auto']}-fused"]
    fp32 = result["gflops"]["fp32-fused"] / result["peak_gflops"]["fp32"]
    assert result["fraction_of_peak_by_setting"]["fp32-fused"] == pytest.approx(fp32)
    parts = result["breakdown"]
    assert parts["precision"] == result["auto"] and parts["gemm_ms"] > 0 and parts["gemm_fraction_of_peak"] > 0
    assert parts["other_ms"] == pytest.approx(parts["step_ms"] - parts["gemm_ms"])
    assert "aten::convolution_backward" in {op["op"] for op in parts["gemm_ops"]}
    assert parts["gemm_ms"] == pytest.approx(sum(op["ms"] for op in parts["gemm_ops"]))
    assert parts["other_ops"] and not {op["op"] for op in parts["other_ops"]} & GEMM_OPS
    assert 0 < parts["fraction_if_gemms_at_peak"] <= 1.0
