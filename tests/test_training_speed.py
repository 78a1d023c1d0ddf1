"""The trainer's speed settings (fused Adam, bf16 trunk) keep PPO's arithmetic; ``auto`` precision times both and
keeps the faster; racer bench update runs."""

from __future__ import annotations

import pytest
import torch

from common.policy import build_policy
from racer.bench.update import bench_update
from trainer.ppo import PPOBatch, StepArgs, minibatch_step
from trainer.precision import bf16_is_fast, fastest, precision_candidates, time_precisions
from trainer.process import make_optimizer

DISCRETE = {"kind": "discrete", "n": 10}


def _batch(n: int = 32, seed: int = 0) -> PPOBatch:
    g = torch.Generator().manual_seed(seed)
    return PPOBatch(
        obs=torch.randint(0, 256, (n, 120, 160, 1), dtype=torch.uint8, generator=g),
        actions=torch.randint(0, 10, (n,), generator=g),
        old_logp=torch.full((n,), -2.3),
        advantages=torch.randn(n, generator=g),
        returns=torch.randn(n, generator=g) + 3.0,
        old_values=torch.zeros(n),
    )


def _twin_models(seed: int = 0):
    torch.manual_seed(seed)
    a = build_policy((120, 160, 1), DISCRETE)
    b = build_policy((120, 160, 1), DISCRETE)
    b.load_state_dict(a.state_dict())
    return a, b


def _step(model, opt, mb):
    return minibatch_step(
        model, opt, mb, clip_eps=0.2, beta_entropy=0.01, value_coef=0.5, loss_type="huber", max_grad_norm=0.5
    )


def test_fused_adam_makes_the_same_update_as_the_loop() -> None:
    loop_model, fused_model = _twin_models()
    loop_opt = torch.optim.Adam(loop_model.parameters(), lr=3e-4, weight_decay=1e-4)
    fused_opt = make_optimizer(fused_model, 3e-4, 1e-4)
    assert fused_opt.defaults["fused"] is True
    mb = _batch()
    for _ in range(3):
        loop_stats, fused_stats = _step(loop_model, loop_opt, mb), _step(fused_model, fused_opt, mb)
        assert fused_stats["value_loss"] == pytest.approx(loop_stats["value_loss"], rel=1e-5)
    moved = False
    for (name, p_loop), p_fused in zip(loop_model.named_parameters(), fused_model.parameters(), strict=True):
        torch.testing.assert_close(p_fused, p_loop, rtol=1e-5, atol=1e-6, msg=name)
    for p_loop, p0 in zip(loop_model.parameters(), _twin_models()[0].parameters(), strict=True):
        moved |= not torch.equal(p_loop, p0)
    assert moved, "three Adam steps should have changed the weights"


def test_bf16_trunk_gives_float32_outputs_close_to_fp32() -> None:
    fp32, bf16 = _twin_models(1)
    bf16.set_trunk_precision("bf16")
    obs = _batch(8).obs
    with torch.no_grad():
        (logits32, v32), (logits16, v16) = fp32(obs), bf16(obs)
    assert logits16.dtype == torch.float32 and v16.dtype == torch.float32
    assert not torch.equal(logits16, logits32), "autocast should change the arithmetic"
    # bf16 keeps 8 mantissa bits: the features are within ~1 %, the (small, 0.01-gain) logits within 1e-3.
    torch.testing.assert_close(bf16.features(obs), fp32.features(obs), rtol=0.05, atol=0.02)
    torch.testing.assert_close(logits16, logits32, rtol=0, atol=2e-3)
    torch.testing.assert_close(v16, v32, rtol=0, atol=0.05)
    bf16.set_trunk_precision("fp32")
    with torch.no_grad():
        assert torch.equal(bf16(obs)[0], logits32)


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_bf16_update_learns_like_fp32() -> None:
    # The value head fits returns around 3 on a fixed batch. Single trajectories are noisy (lr 1e-3 on noise
    # images), so both precisions must clear the same bar: the best of the last 10 of 40 steps ≤ 15 % of the first.
    mb = _batch(64, seed=2)
    for precision in ("fp32", "bf16"):
        torch.manual_seed(3)
        model = build_policy((120, 160, 1), DISCRETE)
        model.set_trunk_precision(precision)
        model.train()
        opt = make_optimizer(model, 1e-3, 0.0)
        losses = [_step(model, opt, mb)["value_loss"] for _ in range(40)]
        assert min(losses[-10:]) < 0.15 * losses[0], f"{precision}: value loss {losses[0]:.3f} → {losses[-10:]}"


def test_precision_names() -> None:
    # auto: both where bf16 is native (then timed), fp32 alone where bf16 would be emulated (always slower).
    assert precision_candidates("auto") == (("fp32", "bf16") if bf16_is_fast() else ("fp32",))
    assert precision_candidates("fp32") == ("fp32",) and precision_candidates("bf16") == ("bf16",)
    with pytest.raises(ValueError, match="'fp16'"):
        precision_candidates("fp16")
    with pytest.raises(ValueError, match="'half'"):
        build_policy((120, 160, 1), DISCRETE).set_trunk_precision("half")  # type: ignore[arg-type]


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_bench_update_times_every_setting() -> None:
    result = bench_update(threads=1, batch=8, steps=2, repeats=2)
    assert set(result["ms_per_step"]) == {"fp32", "fp32-fused", "bf16", "bf16-fused"}
    assert all(ms > 0 for ms in result["ms_per_step"].values())
    assert all(len(v) == 2 for v in result["ms_per_step_runs"].values())
    assert result["speedup_vs_fp32_loop"]["fp32"] == pytest.approx(1.0)
    fused = {p: result["ms_per_step"][f"{p}-fused"] for p in precision_candidates("auto")}
    assert result["auto"] == fastest(fused)


def test_fastest_precision_is_the_one_with_fewest_ms_and_fp32_on_a_tie() -> None:
    assert fastest({"fp32": 64.6, "bf16": 87.0}) == "fp32"  # this project's Intel Xeon with AVX512-BF16, no AMX
    assert fastest({"fp32": 66.3, "bf16": 40.3}) == "bf16"  # its AMD EPYC
    assert fastest({"bf16": 50.0, "fp32": 50.0}) == "fp32"
    assert fastest({"bf16": 50.0}) == "bf16"
    with pytest.raises(ValueError, match="no precision"):
        fastest({})


def test_timing_the_precisions_leaves_the_model_and_the_random_state_alone() -> None:
    model, _ = _twin_models()
    model.eval()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    torch.manual_seed(7)
    expected_draw = torch.rand(3)
    torch.manual_seed(7)
    args = StepArgs(clip_eps=0.2, beta_entropy=0.01, value_coef=0.5, loss_type="huber", max_grad_norm=0.5)
    ms = time_precisions(model, _batch(8), ("fp32", "bf16"), args)
    assert set(ms) == {"fp32", "bf16"} and all(v > 0 for v in ms.values())
    assert torch.equal(torch.rand(3), expected_draw)
    assert not model.training and model.trunk_dtype is None
    for key, value in model.state_dict().items():
        assert torch.equal(value, before[key]), key
