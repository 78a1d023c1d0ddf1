"""Tests of the PPO functions (trainer.ppo) against values computed by hand."""

from __future__ import annotations

import math

import pytest
import torch

from common.policy import PolicyConfig, build_policy
from trainer.ppo import (
    PPOBatch,
    approx_kl,
    compute_gae,
    cooldown_factor,
    entropy_bonus,
    explained_variance,
    kl_exceeded,
    normalize_advantages,
    policy_loss,
    scheduled,
    update,
    value_loss,
)


def t(*values: float) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float32)


def _close(actual: torch.Tensor, expected: list[float]) -> None:
    torch.testing.assert_close(actual, torch.tensor(expected, dtype=torch.float32), rtol=0, atol=1e-6)


# --- compute_gae ---------------------------------------------------------------------------------


def test_gae_no_dones() -> None:
    # gamma = 0.5, lam = 0.5, so gamma * lam = 0.25; next_values[t] = values[t+1], next_values[2] = 2.0 bootstraps.
    # delta_2 = 3 + 0.5*2.0 - 1.5 = 2.5
    # delta_1 = 2 + 0.5*1.5 - 1.0 = 1.75
    # delta_0 = 1 + 0.5*1.0 - 0.5 = 1.0
    # gae_2 = 2.5;  gae_1 = 1.75 + 0.25*2.5 = 2.375;  gae_0 = 1.0 + 0.25*2.375 = 1.59375
    # returns = gae + values = [2.09375, 3.375, 4.0]
    zeros = t(0, 0, 0)
    adv, ret = compute_gae(t(1, 2, 3), t(0.5, 1.0, 1.5), zeros, zeros, t(1.0, 1.5, 2.0), gamma=0.5, lam=0.5)
    _close(adv, [1.59375, 2.375, 2.5])
    _close(ret, [2.09375, 3.375, 4.0])


# Four steps with an episode ending at t=1; next_values[1] = 9 is V of that episode's final observation.
REWARDS, VALUES, NEXT_VALUES, ENDS_AT_1 = t(1, 2, 3, 4), t(1, 1, 1, 1), t(1, 9, 1, 2), t(0, 1, 0, 0)


def test_gae_terminated_in_the_middle() -> None:
    # gamma = lam = 0.5; terminated at t=1: no bootstrap (the 9 is ignored) and no flow of gae_2 into gae_1.
    # delta_3 = 4 + 0.5*2 - 1 = 4        gae_3 = 4
    # delta_2 = 3 + 0.5*1 - 1 = 2.5      gae_2 = 2.5 + 0.25*4 = 3.5
    # delta_1 = 2 + 0          - 1 = 1   gae_1 = 1 + 0.25*0*3.5 = 1
    # delta_0 = 1 + 0.5*1 - 1 = 0.5      gae_0 = 0.5 + 0.25*1 = 0.75
    adv, ret = compute_gae(REWARDS, VALUES, ENDS_AT_1, t(0, 0, 0, 0), NEXT_VALUES, gamma=0.5, lam=0.5)
    _close(adv, [0.75, 1.0, 3.5, 4.0])
    _close(ret, [1.75, 2.0, 4.5, 5.0])


def test_gae_truncated_bootstraps_without_flow() -> None:
    # Same as above but truncated (time limit) at t=1: bootstrap from V(final obs) = 9, still no flow of gae_2.
    # delta_1 = 2 + 0.5*9 - 1 = 5.5      gae_1 = 5.5 + 0.25*0*3.5 = 5.5   (with flow it would be 6.375)
    # delta_0 = 0.5                      gae_0 = 0.5 + 0.25*5.5 = 1.875
    # gae_2 = 3.5 and gae_3 = 4 as before.
    adv, ret = compute_gae(REWARDS, VALUES, t(0, 0, 0, 0), ENDS_AT_1, NEXT_VALUES, gamma=0.5, lam=0.5)
    _close(adv, [1.875, 5.5, 3.5, 4.0])
    _close(ret, [2.875, 6.5, 4.5, 5.0])


def test_gae_bool_flags_accepted() -> None:
    adv, _ = compute_gae(
        REWARDS, VALUES, torch.zeros(4, dtype=torch.bool), ENDS_AT_1.bool(), NEXT_VALUES, gamma=0.5, lam=0.5
    )
    _close(adv, [1.875, 5.5, 3.5, 4.0])


def test_gae_segment_end_bootstraps() -> None:
    # gamma = 0.9, lam = 0.8 (gamma*lam = 0.72); the segment ends mid-episode with V(o_2) = 10.
    # delta_1 = 1 + 0.9*10 - 0 = 10   gae_1 = 10
    # delta_0 = 1 + 0.9*0  - 0 = 1    gae_0 = 1 + 0.72*10 = 8.2
    zeros = t(0, 0)
    adv, _ = compute_gae(t(1, 1), zeros, zeros, zeros, t(0, 10), gamma=0.9, lam=0.8)
    _close(adv, [8.2, 10.0])
    # Had the last step terminated instead: delta_1 = 1, gae_1 = 1, gae_0 = 1 + 0.72*1 = 1.72.
    adv_term, _ = compute_gae(t(1, 1), zeros, t(0, 1), zeros, t(0, 10), gamma=0.9, lam=0.8)
    _close(adv_term, [1.72, 1.0])


@pytest.mark.parametrize(
    ("terminated", "mc_returns"),
    [
        # one episode ending at t=3: G = [1+2+3+4, 2+3+4, 3+4, 4] = [10, 9, 7, 4]
        ((0, 0, 0, 1), [10.0, 9.0, 7.0, 4.0]),
        # two episodes, ending at t=1 and t=3: G = [1+2, 2, 3+4, 4] = [3, 2, 7, 4]
        ((0, 1, 0, 1), [3.0, 2.0, 7.0, 4.0]),
    ],
)
def test_gae_gamma_lambda_one_is_monte_carlo(terminated: tuple[int, ...], mc_returns: list[float]) -> None:
    # With gamma = lam = 1 the deltas telescope: advantages = G_t - V(o_t), returns = G_t.
    values = t(0.5, -1.0, 2.0, 3.0)
    next_values = t(-1.0, 2.0, 3.0, 99.0)  # next_values[t] = values[t+1]; 99 is after a terminal step, ignored
    adv, ret = compute_gae(t(1, 2, 3, 4), values, t(*terminated), t(0, 0, 0, 0), next_values, gamma=1.0, lam=1.0)
    _close(ret, mc_returns)
    _close(adv, [g - v for g, v in zip(mc_returns, values.tolist(), strict=True)])


def test_gae_ignores_next_value_of_terminal_step_even_if_nan() -> None:
    # delta_0 = 1 + 0 - 0.5 = 0.5 whatever next_values[0] holds
    adv, _ = compute_gae(t(1), t(0.5), t(1), t(0), t(float("nan")), gamma=0.99, lam=0.95)
    _close(adv, [0.5])


def test_gae_shape_mismatch() -> None:
    with pytest.raises(ValueError, match="next_values"):
        compute_gae(t(1, 2), t(0, 0), t(0, 0), t(0, 0), t(0), gamma=0.9, lam=0.9)


# --- policy_loss -----------------------------------------------------------------------------------


def test_policy_loss_inside_clip_range() -> None:
    # ratios 1.1 and 0.9, both within [0.8, 1.2]: loss = -mean(ratio*A) = -(1.1*2 + 0.9*(-1))/2 = -0.65
    new_logp = torch.log(t(1.1, 0.9)).requires_grad_()
    loss, clip_fraction, _ = policy_loss(new_logp, t(0, 0), t(2, -1), 0.2)
    assert loss.item() == pytest.approx(-0.65, abs=1e-6)
    assert clip_fraction.item() == 0.0


def test_policy_loss_with_clipping() -> None:
    # old_logp = 0, so ratio = exp(new_logp) = [1.1, 1.5, 0.5, 0.9]; A = [1, 1, -1, -2]; eps = 0.2
    # t0: min(1.1*1,  1.1*1)   =  1.1
    # t1: min(1.5*1,  1.2*1)   =  1.2   (clipped)
    # t2: min(0.5*-1, 0.8*-1)  = -0.8   (clipped)
    # t3: min(0.9*-2, 0.9*-2)  = -1.8
    # loss = -(1.1 + 1.2 - 0.8 - 1.8)/4 = 0.075; clip fraction = 2/4
    new_logp = torch.log(t(1.1, 1.5, 0.5, 0.9)).requires_grad_()
    loss, clip_fraction, approx_kl = policy_loss(new_logp, t(0, 0, 0, 0), t(1, 1, -1, -2), 0.2)
    assert loss.item() == pytest.approx(0.075, abs=1e-6)
    assert clip_fraction.item() == 0.5
    # approx_kl = mean((r - 1) - ln r)
    kl = [(0.1 - math.log(1.1)), (0.5 - math.log(1.5)), (-0.5 - math.log(0.5)), (-0.1 - math.log(0.9))]
    assert approx_kl.item() == pytest.approx(sum(kl) / 4, abs=1e-6)  # ≈ 0.0756831
    # Clipped samples get no gradient; d(-r*A/4)/d logp = -r*A/4 for the others: t0 -1.1/4, t3 +1.8/4.
    loss.backward()
    _close(new_logp.grad, [-0.275, 0.0, 0.0, 0.45])
    assert not approx_kl.requires_grad and not clip_fraction.requires_grad


def test_approx_kl_zero_when_logps_equal() -> None:
    logp = t(-0.3, -1.2, -2.0)
    loss, clip_fraction, approx_kl = policy_loss(logp, logp.clone(), t(1, -1, 2), 0.2)
    assert approx_kl.item() == 0.0 and clip_fraction.item() == 0.0
    assert loss.item() == pytest.approx(-(1 - 1 + 2) / 3)  # ratio 1: loss = -mean(A)


def test_approx_kl_by_hand() -> None:
    # ratio = exp(new - old) = 0.5: (0.5 - 1) - ln 0.5 = -0.5 + 0.6931472 = 0.1931472
    # ratio = 2:                  (2 - 1)   - ln 2   =  1   - 0.6931472 = 0.3068528
    # mean = 0.25
    old = t(math.log(0.5), math.log(0.5))
    new = t(math.log(0.25), math.log(1.0))
    assert approx_kl(new, old).item() == pytest.approx(0.25, abs=1e-6)
    assert approx_kl(t(math.log(0.5)), t(0.0)).item() == pytest.approx((0.5 - 1) - math.log(0.5), abs=1e-6)
    assert approx_kl(old, old.clone()).item() == 0.0
    assert not approx_kl(new.requires_grad_(), old).requires_grad


def test_kl_exceeded_only_when_a_target_is_set() -> None:
    assert kl_exceeded(10.0, None) is False  # off: DeepRacer runs every epoch
    assert kl_exceeded(0.03, 0.02) is True
    assert kl_exceeded(0.02, 0.02) is False and kl_exceeded(0.01, 0.02) is False


# --- schedules ---------------------------------------------------------------------------------------


def test_constant_schedule_is_the_initial_value() -> None:
    assert [scheduled("constant", 3e-4, 0.1, k, 10) for k in (0, 5, 10, 1000)] == [3e-4] * 4


def test_linear_schedule_by_hand() -> None:
    # 1e-3 down to 0.1 of it over 10 updates: 1e-3 * (1 - 0.9 * k / 10), then 1e-4 for ever
    values = [scheduled("linear", 1e-3, 0.1, k, 10) for k in (0, 1, 5, 10, 11, 500)]
    assert values == pytest.approx([1e-3, 9.1e-4, 5.5e-4, 1e-4, 1e-4, 1e-4], rel=1e-12)
    # entropy 0.01 to 0 over 4 updates: 0.01, 0.0075, 0.005, 0.0025, 0
    assert [scheduled("linear", 0.01, 0.0, k, 4) for k in range(6)] == pytest.approx(
        [0.01, 0.0075, 0.005, 0.0025, 0.0, 0.0], abs=1e-15
    )
    assert scheduled("linear", 2.0, 1.0, 3, 4) == 2.0  # a final fraction of 1 is constant


def test_schedule_refuses_an_unknown_kind_or_no_length() -> None:
    with pytest.raises(ValueError, match="cosine"):
        scheduled("cosine", 1.0, 0.1, 0, 10)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="at least 1"):
        scheduled("linear", 1.0, 0.1, 0, 0)


def test_cooldown_by_hand() -> None:
    # A 1000 s limit, the last 20 % (200 s) cooling to 10 %: 1 until 200 s are left, then 0.1 + 0.9 * left / 200.
    values = [cooldown_factor(left, 1000.0, 0.2, 0.1) for left in (1000.0, 500.0, 200.0, 150.0, 100.0, 0.0, -5.0)]
    assert values == pytest.approx([1.0, 1.0, 1.0, 0.775, 0.55, 0.1, 0.1])
    assert cooldown_factor(30.0, 60.0, 1.0, 0.0) == pytest.approx(0.5)  # the whole run, to zero
    with pytest.raises(ValueError, match="time limit"):
        cooldown_factor(10.0, 0.0, 0.2, 0.1)
    with pytest.raises(ValueError, match="share"):
        cooldown_factor(10.0, 100.0, 0.0, 0.1)


# --- value_loss, entropy, normalization, explained variance -----------------------------------------


def test_value_loss_huber_and_mse() -> None:
    # errors V - R = [-0.5, -2, 3]
    # huber (delta 1): 0.5*0.5^2 = 0.125, |2| - 0.5 = 1.5, |3| - 0.5 = 2.5 → mean 4.125/3 = 1.375
    # mse: 0.5 * mean(0.25, 4, 9) = 0.5 * 13.25/3 = 2.2083333
    values, returns = t(0, 0, 0), t(0.5, 2, -3)
    assert value_loss(values, returns, "huber").item() == pytest.approx(1.375)
    assert value_loss(values, returns, "mse").item() == pytest.approx(0.5 * 13.25 / 3)
    # For errors within ±1 both are 0.5*e^2: e = [0.5, -1] → 0.5*(0.25 + 1)/2 = 0.3125
    assert value_loss(t(0.5, -1), t(0, 0), "huber").item() == pytest.approx(0.3125)
    assert value_loss(t(0.5, -1), t(0, 0), "mse").item() == pytest.approx(0.3125)
    with pytest.raises(ValueError):
        value_loss(values, returns, "l1")  # type: ignore[arg-type]


def test_entropy_bonus_is_mean() -> None:
    assert entropy_bonus(t(0.5, 1.0, 1.5)).item() == pytest.approx(1.0)


def test_normalize_advantages() -> None:
    # mean 2, unbiased std sqrt(((1-2)^2 + 0 + (3-2)^2)/2) = 1
    _close(normalize_advantages(t(1, 2, 3)), [-1.0, 0.0, 1.0])
    _close(normalize_advantages(t(5)), [0.0])


def test_explained_variance() -> None:
    returns = t(1, 2, 3, 4)
    assert explained_variance(returns.clone(), returns) == pytest.approx(1.0)
    assert explained_variance(t(2.5, 2.5, 2.5, 2.5), returns) == pytest.approx(0.0)  # the mean: no better
    # values off by [1, -1, 1, -1]: Var(err) = 1, Var(R) = 1.25 → 1 - 1/1.25 = 0.2
    assert explained_variance(t(0, 3, 2, 5), returns) == pytest.approx(0.2)
    assert math.isnan(explained_variance(t(1, 2), t(3, 3)))


# --- update -----------------------------------------------------------------------------------------

OBS_SHAPE = (36, 36, 1)


def _bandit(seed: int = 0, n: int = 16) -> tuple[torch.nn.Module, PPOBatch]:
    """A 2-action bandit with one constant observation: action 0 has advantage +1, action 1 has -1."""
    torch.manual_seed(seed)
    model = build_policy(OBS_SHAPE, {"kind": "discrete", "n": 2}, PolicyConfig())
    obs = torch.full((n, *OBS_SHAPE), 128, dtype=torch.uint8)
    actions = torch.arange(n) % 2
    with torch.no_grad():
        old_logp, _, old_values = model.evaluate(obs, actions)
    advantages = torch.where(actions == 0, 1.0, -1.0)
    return model, PPOBatch(obs, actions, old_logp, advantages, advantages + old_values, old_values)


def _run_update(
    model: torch.nn.Module, batch: PPOBatch, seed: int, epochs: int = 4, target_kl: float | None = None
) -> dict[str, float]:
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    return update(
        model,
        optimizer,
        batch,
        epochs=epochs,
        minibatch_size=8,
        clip_eps=0.2,
        beta_entropy=0.01,
        value_coef=0.5,
        loss_type="huber",
        max_grad_norm=0.5,
        generator=torch.Generator().manual_seed(seed),
        target_kl=target_kl,
    )


def _p_action0(model: torch.nn.Module, batch: PPOBatch) -> float:
    with torch.no_grad():
        return model.distribution(batch.obs[:1]).probs[0, 0].item()


def test_update_prefers_the_advantaged_action() -> None:
    model, batch = _bandit()
    before = _p_action0(model, batch)
    stats = _run_update(model, batch, seed=0)
    assert _p_action0(model, batch) > before + 0.05
    expected = {"policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction", "explained_variance", "grad_norm"}
    assert set(stats) == expected | {"epochs_run", "epoch_kl"}
    assert stats["epochs_run"] == 4  # no target_kl: every epoch, as DeepRacer
    assert all(math.isfinite(v) for k, v in stats.items() if k != "explained_variance")
    assert stats["approx_kl"] >= 0 and 0 <= stats["clip_fraction"] <= 1 and stats["grad_norm"] > 0


def test_update_is_deterministic_for_a_seed() -> None:
    model_a, batch_a = _bandit(seed=3)
    model_b, batch_b = _bandit(seed=3)
    stats_a = _run_update(model_a, batch_a, seed=7)
    stats_b = _run_update(model_b, batch_b, seed=7)
    assert stats_a == pytest.approx(stats_b, nan_ok=True, rel=0, abs=0)
    for (name, pa), pb in zip(model_a.state_dict().items(), model_b.state_dict().values(), strict=True):
        assert torch.equal(pa, pb), name


def test_update_continuous_runs() -> None:
    torch.manual_seed(0)
    model = build_policy(OBS_SHAPE, {"kind": "continuous", "low": [-30.0, 0.5], "high": [30.0, 4.0]})
    obs = torch.randint(0, 256, (6, *OBS_SHAPE), dtype=torch.uint8)
    actions, old_logp, old_values = model.act(obs)
    returns = torch.linspace(-1, 1, 6)
    batch = PPOBatch(obs, actions, old_logp, returns - old_values, returns, old_values)
    stats = _run_update(model, batch, seed=0)
    assert all(math.isfinite(v) for v in stats.values())


def test_ppo_batch_rows_checked() -> None:
    with pytest.raises(ValueError, match="returns"):
        PPOBatch(torch.zeros(2, 1), torch.zeros(2), torch.zeros(2), torch.zeros(2), torch.zeros(3), torch.zeros(2))


def _same_weights(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    return all(torch.equal(pa, pb) for pa, pb in zip(a.state_dict().values(), b.state_dict().values(), strict=True))


def test_target_kl_stops_the_remaining_epochs() -> None:
    # The first epoch's minibatches move the policy (KL > 0 from the second minibatch on), so a tiny target stops
    # the update after that epoch: the same weights as a one-epoch update with the same seed.
    model, batch = _bandit(seed=1)
    stats = _run_update(model, batch, seed=5, target_kl=1e-9)
    one_epoch, batch_b = _bandit(seed=1)
    reference = _run_update(one_epoch, batch_b, seed=5, epochs=1)
    assert stats["epochs_run"] == 1 and stats["epoch_kl"] > 1e-9
    assert stats["epoch_kl"] == pytest.approx(reference["approx_kl"], rel=0, abs=0)  # the one epoch's mean KL
    assert _same_weights(model, one_epoch)


def test_a_target_kl_never_reached_changes_nothing() -> None:
    model_a, batch_a = _bandit(seed=2)
    model_b, batch_b = _bandit(seed=2)
    stats_a = _run_update(model_a, batch_a, seed=9)
    stats_b = _run_update(model_b, batch_b, seed=9, target_kl=1e9)
    assert stats_b["epochs_run"] == 4
    assert stats_a == pytest.approx(stats_b, nan_ok=True, rel=0, abs=0)
    assert _same_weights(model_a, model_b)
