"""Tests of teacher–student distillation (trainer.distill): the KL against values computed by hand, the label rows'
round trip, and ``distill`` on a tiny real network."""

from __future__ import annotations

import math
from collections.abc import Iterator

import pytest
import torch
from torch.distributions import Categorical, Independent, Normal

from common.policy import ActorCritic, build_policy, label_distribution, label_width
from trainer.distill import (
    distill,
    distill_step,
    greedy_agreement,
    kl_to_teacher,
)
from trainer.ppo import PPOBatch, value_loss

OBS_SHAPE = (36, 36, 1)  # the smallest square frame the shallow network's convs take (8/4 → 4/2 → 3/1 gives 1×1)
DISCRETE = {"kind": "discrete", "n": 3}
CONTINUOUS = {"kind": "continuous", "low": [-30.0, 0.5], "high": [30.0, 4.0]}
# Fixed teachers, the same distribution on every row. The continuous one's means are off the range's centre and its
# standard deviations 0.8 × the student's initial ones (half the range: 30°, 1.75 m/s), so both parts must be learned.
TARGETS = {"discrete": [2.0, 0.0, -1.0], "continuous": [10.0, 3.0, 24.0, 1.4]}


def t(*values: float) -> torch.Tensor:
    return torch.tensor(values, dtype=torch.float32)


@pytest.fixture(autouse=True)
def one_thread() -> Iterator[None]:
    """One intra-op thread: on networks this small, threads only wait for each other (several times slower on a busy
    two-core machine)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


# --- label_width, PolicyNetwork.labels, label_distribution ---------------------------------------------------------


def test_label_width() -> None:
    assert label_width("discrete", 3) == 3  # the logits
    assert label_width("continuous", 2) == 4  # the means, then the standard deviations
    with pytest.raises(ValueError, match="action_kind"):
        label_width("box", 2)
    with pytest.raises(ValueError, match="action_dim"):
        label_width("discrete", 0)


def test_discrete_labels_are_the_logits_and_round_trip() -> None:
    logits = t(1.0, -2.0, 0.5).repeat(2, 1)
    dist = label_distribution(logits, "discrete")
    assert isinstance(dist, Categorical)
    torch.testing.assert_close(dist.probs, torch.softmax(logits, -1))


def test_continuous_labels_are_means_then_stds_and_round_trip() -> None:
    mean = torch.tensor([[5.0, 1.0], [-3.0, 2.5]])
    labels = torch.tensor([[5.0, 1.0, 10.0, 0.5], [-3.0, 2.5, 10.0, 0.5]])
    dist = label_distribution(labels, "continuous")
    assert isinstance(dist, Independent) and isinstance(dist.base_dist, Normal)
    torch.testing.assert_close(dist.mean, mean)
    torch.testing.assert_close(dist.stddev, torch.tensor([[10.0, 0.5], [10.0, 0.5]]))
    assert dist.batch_shape == (2,) and dist.event_shape == (2,)
    # Per-row standard deviations are kept as they are.
    per_row = torch.tensor([[1.0, 2.0], [3.0, 4.0]])
    labels = torch.cat([mean, per_row], dim=-1)
    torch.testing.assert_close(label_distribution(labels, "continuous").stddev, per_row)


@pytest.mark.parametrize("spec", [DISCRETE, CONTINUOUS], ids=["discrete", "continuous"])
def test_a_real_policys_labels_give_back_its_distribution(spec: dict) -> None:
    torch.manual_seed(0)
    model = build_policy(OBS_SHAPE, spec)
    with torch.no_grad():
        params, _ = model(torch.randint(0, 256, (4, *OBS_SHAPE), dtype=torch.uint8))
        dist = model.action_distribution(params)
        labels = model.labels(params)
        assert labels.shape == (4, label_width(model.action_kind, model.action_dim)) and labels.dtype == torch.float32
        kl = kl_to_teacher(label_distribution(labels, model.action_kind), dist)
    torch.testing.assert_close(kl, torch.zeros(4), rtol=0, atol=1e-6)


def test_bad_labels_are_refused() -> None:
    with pytest.raises(ValueError, match="2·d"):
        label_distribution(torch.ones(2, 3), "continuous")  # odd width
    for std in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="not positive"):
            label_distribution(torch.tensor([[0.0, 1.0, 1.0, std]]), "continuous")
    with pytest.raises(ValueError, match="expected"):
        label_distribution(torch.ones(3), "discrete")  # not (B, P)
    with pytest.raises(ValueError, match="action_kind"):
        label_distribution(torch.ones(2, 2), "box")


# --- kl_to_teacher ----------------------------------------------------------------------------------------------------


def test_kl_discrete_by_hand() -> None:
    # p = [0.5, 0.5], q = [0.25, 0.75]: KL(p || q) = 0.5 ln(0.5/0.25) + 0.5 ln(0.5/0.75) = 0.5 ln(4/3) = 0.143841...
    # (the other direction, KL(q || p) = 0.25 ln(0.5) + 0.75 ln(1.5) = 0.130812..., so the order is checked too).
    teacher = label_distribution(t(0.5, 0.5).log().unsqueeze(0), "discrete")
    student = Categorical(probs=t(0.25, 0.75).unsqueeze(0))
    expected = 0.5 * math.log(0.5 / 0.25) + 0.5 * math.log(0.5 / 0.75)
    torch.testing.assert_close(kl_to_teacher(teacher, student), t(expected), rtol=0, atol=1e-6)
    assert expected == pytest.approx(0.143841, abs=1e-6)


def test_kl_gaussian_by_hand() -> None:
    # ln(σ2/σ1) + (σ1² + (μ1 − μ2)²) / (2σ2²) − ½ per dimension, teacher (μ1, σ1), student (μ2, σ2), summed:
    # dim 0: μ1 = 0, σ1 = 1; μ2 = 1, σ2 = 2:  ln 2 + (1 + 1) / 8 − ½ = 0.693147 − 0.25 = 0.443147
    # dim 1: μ1 = 1, σ1 = 2; μ2 = 1, σ2 = 1:  ln ½ + (4 + 0) / 2 − ½ = −0.693147 + 1.5 = 0.806853
    # sum = 1.25 (the logarithms cancel).
    teacher = label_distribution(torch.tensor([[0.0, 1.0, 1.0, 2.0]]), "continuous")
    student = Independent(Normal(torch.tensor([[1.0, 1.0]]), torch.tensor([[2.0, 1.0]])), 1)
    torch.testing.assert_close(kl_to_teacher(teacher, student), t(1.25), rtol=0, atol=1e-6)


def test_kl_of_identical_distributions_is_zero() -> None:
    logits = torch.tensor([[0.3, -1.0, 2.0], [0.0, 0.0, 0.0]])
    kl = kl_to_teacher(label_distribution(logits, "discrete"), Categorical(logits=logits))
    torch.testing.assert_close(kl, torch.zeros(2), rtol=0, atol=1e-7)
    labels = torch.tensor([[5.0, 1.0, 10.0, 0.5], [-3.0, 2.5, 1.0, 2.0]])
    same = Independent(Normal(labels[:, :2], labels[:, 2:]), 1)
    torch.testing.assert_close(kl_to_teacher(label_distribution(labels, "continuous"), same), torch.zeros(2))


# --- greedy_agreement -------------------------------------------------------------------------------------------------


def test_greedy_agreement_by_hand() -> None:
    # Teacher argmaxes 0 and 2, student argmaxes 0 and 0: half agree.
    teacher = torch.tensor([[2.0, 1.0, 0.0], [0.0, 1.0, 2.0]])
    student = torch.tensor([[5.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    assert greedy_agreement(teacher, student, "discrete").item() == 0.5
    # Tolerance (6, 0.35): row 0 is within it in both dimensions; row 1 is off by 0.5 in the second; row 2 by 7 in the
    # first. Only the means count, not the standard deviations.
    labels = torch.tensor([[0.0, 1.0, 9.0, 9.0], [0.0, 1.0, 9.0, 9.0], [0.0, 1.0, 9.0, 9.0]])
    means = torch.tensor([[5.0, 1.3], [0.0, 1.5], [7.0, 1.0]])
    assert greedy_agreement(labels, means, "continuous", t(6.0, 0.35)).item() == pytest.approx(1 / 3)
    with pytest.raises(ValueError, match="tolerance"):
        greedy_agreement(labels, means, "continuous")


# --- distill_step, distill --------------------------------------------------------------------------------------------


def _student_and_batch(spec: dict, n: int = 8, seed: int = 0) -> tuple[ActorCritic, PPOBatch]:
    """A fresh student and a fixed random batch of ``n`` frames whose labels all hold the kind's fixed target."""
    torch.manual_seed(seed)
    model = build_policy(OBS_SHAPE, spec)
    obs = torch.randint(0, 256, (n, *OBS_SHAPE), dtype=torch.uint8)
    labels = torch.tensor([TARGETS[spec["kind"]]]).repeat(n, 1)
    actions = torch.zeros(n, dtype=torch.long) if spec["kind"] == "discrete" else torch.zeros(n, 2)
    zeros = torch.zeros(n)
    returns = torch.linspace(-1.0, 1.0, n)
    return model, PPOBatch(obs, actions, zeros, zeros, returns, zeros, teacher=labels)


@torch.no_grad()
def _mean_kl(model: ActorCritic, batch: PPOBatch) -> float:
    params, _ = model(batch.obs)
    teacher = label_distribution(batch.teacher, model.action_kind)
    return kl_to_teacher(teacher, model.action_distribution(params)).mean().item()


@torch.no_grad()
def _value_loss(model: ActorCritic, batch: PPOBatch) -> float:
    return value_loss(model(batch.obs)[1], batch.returns, "huber").item()


def _run(model: ActorCritic, batch: PPOBatch, *, seed: int, epochs: int, minibatch_size: int) -> dict[str, float]:
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    return distill(
        model,
        optimizer,
        batch,
        epochs=epochs,
        minibatch_size=minibatch_size,
        value_coef=0.5,
        loss_type="huber",
        max_grad_norm=0.5,
        generator=torch.Generator().manual_seed(seed),
    )


@pytest.mark.parametrize("spec", [DISCRETE, CONTINUOUS], ids=["discrete", "continuous"])
def test_distill_moves_the_student_to_the_teacher(spec: dict) -> None:
    model, batch = _student_and_batch(spec)
    before, value_before = _mean_kl(model, batch), _value_loss(model, batch)
    stats = _run(model, batch, seed=0, epochs=15, minibatch_size=8)  # 15 steps of Adam, lr 1e-3
    after = _mean_kl(model, batch)
    assert before > 0.2 and after < 0.5 * before, (before, after)
    # The value head learns the returns at the same time, for a later PPO fine-tuning.
    assert _value_loss(model, batch) < 0.5 * value_before
    assert set(stats) == {"distill_kl", "value_loss", "grad_norm", "agreement"}
    assert all(math.isfinite(v) for v in stats.values())
    assert stats["distill_kl"] >= 0 and stats["grad_norm"] > 0 and 0 <= stats["agreement"] <= 1


def test_distill_is_deterministic_for_a_seed() -> None:
    model_a, batch_a = _student_and_batch(DISCRETE, seed=3)
    model_b, batch_b = _student_and_batch(DISCRETE, seed=3)
    # Two minibatches of 4 per epoch: the generator's shuffles decide which rows go together.
    stats_a = _run(model_a, batch_a, seed=7, epochs=2, minibatch_size=4)
    stats_b = _run(model_b, batch_b, seed=7, epochs=2, minibatch_size=4)
    assert stats_a == pytest.approx(stats_b, rel=0, abs=0)
    for (name, pa), pb in zip(model_a.state_dict().items(), model_b.state_dict().values(), strict=True):
        assert torch.equal(pa, pb), name


def test_a_batch_without_labels_is_refused() -> None:
    model, batch = _student_and_batch(DISCRETE)
    batch.teacher = None
    with pytest.raises(ValueError, match="teacher labels"):
        _run(model, batch, seed=0, epochs=1, minibatch_size=8)
    optimizer = torch.optim.Adam(model.parameters())
    with pytest.raises(ValueError, match="teacher labels"):
        distill_step(model, optimizer, batch, value_coef=0.5, loss_type="huber", max_grad_norm=0.5)


def test_loss_scaling_steps_and_skips_a_step_whose_gradients_overflow() -> None:
    """The fp16 path on the CPU, as ``minibatch_step``'s test in tests/test_device.py: a sane scale steps, an absurd
    one overflows the fp16 gradients and the scaler skips that step."""
    for init_scale, skipped in ((2.0**16, False), (2.0**100, True)):
        model, batch = _student_and_batch(CONTINUOUS)
        model.set_trunk_precision("fp16")
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
        before = [p.detach().clone() for p in model.parameters()]
        scaler = torch.amp.GradScaler("cpu", init_scale=init_scale)
        stats = distill_step(model, optimizer, batch, value_coef=0.5, loss_type="mse", max_grad_norm=0.5, scaler=scaler)
        moved = any(not torch.equal(a, b) for a, b in zip(before, model.parameters(), strict=True))
        assert stats["amp_skipped"] == float(skipped) and moved is not skipped, stats
        assert (stats["grad_norm"] == 0.0) is skipped and math.isfinite(stats["distill_kl"])
