"""Teacher–student distillation as small pure torch functions, and one linear ``distill()`` that does no I/O.

A privileged teacher policy acts in the workers, and at each step they record its action distribution as one float32
"label" row (``PPOBatch.teacher``, (N, P); ``common.policy.PolicyNetwork.labels`` makes it,
``common.policy.label_distribution`` reads it back): the logits of a discrete policy (P = n), or the Gaussian's means
then its standard deviations for a continuous one (P = 2·d), in the env's units. The camera student then learns to
match it by minimizing KL(π_teacher ‖ π_student) on the states the rollouts visited (learning by cheating; DAgger when
the student drives the rollouts). The forward KL is the one whose gradient is the cross-entropy to the teacher's
distribution: the student is pushed to cover every action the teacher gives mass to, as behaviour cloning with soft
labels would.

The student's value head learns the batch's returns at the same time (``trainer.ppo.value_loss``), so that a later PPO
fine-tuning starts with a critic. ``distill`` mirrors ``trainer.ppo.update``: epochs of minibatches shuffled with a CPU
generator, global gradient-norm clipping, an optional fp16 loss scaler, and the means of the steps' statistics.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.distributions import Distribution, kl_divergence

from common.policy import label_distribution
from trainer.ppo import PPOBatch, ValueLossKind, gradient_step, value_loss, with_amp_skipped

AGREEMENT_SHARE = 0.1
"""A continuous student's mean agrees with the teacher's when every dimension is within this share of the action
range of it (:func:`greedy_agreement`)."""


def kl_to_teacher(teacher: Distribution, student: Distribution) -> torch.Tensor:
    """KL(π_teacher ‖ π_student) of each row, (B,): the expectation under the teacher of log π_teacher − log π_student.

    Exact (``torch.distributions.kl_divergence``): Σ p log(p / q) for Categoricals; for diagonal Gaussians
    Σ_dims ln(σ_s / σ_t) + (σ_t² + (μ_t − μ_s)²) / (2 σ_s²) − ½. Zero for identical distributions, never negative.
    """
    return kl_divergence(teacher, student)


@torch.no_grad()
def greedy_agreement(
    labels: torch.Tensor, student_params: torch.Tensor, action_kind: str, tolerance: torch.Tensor | None = None
) -> torch.Tensor:
    """The share of rows whose greedy action the student shares with the teacher, a float scalar tensor.

    Discrete: the argmax of the student's logits equals the argmax of the teacher's. Continuous: the student's mean is
    within ``tolerance`` (d,) of the teacher's mean in every dimension (the modes of the two Gaussians; a share rather
    than a distance, so that one number reads the same for both kinds of action).
    """
    if action_kind == "discrete":
        return (student_params.argmax(-1) == labels.argmax(-1)).float().mean()
    if tolerance is None:
        raise ValueError("a continuous agreement needs a tolerance per action dimension")
    d = student_params.shape[-1]
    gap = (student_params - labels[:, :d]).abs()
    return (gap <= tolerance).all(dim=-1).float().mean()


def _agreement_tolerance(model: nn.Module) -> torch.Tensor | None:
    """:data:`AGREEMENT_SHARE` of a continuous network's action range (2 × ``action_half``, which is 1 where the range
    has no width, so such a dimension still gets a tolerance); None for a discrete one."""
    if model.action_kind == "discrete":
        return None
    return AGREEMENT_SHARE * 2.0 * model.action_half


def distill_step(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    mb: PPOBatch,
    *,
    value_coef: float,
    loss_type: ValueLossKind,
    max_grad_norm: float,
    scaler: torch.amp.GradScaler | None = None,
) -> dict[str, float]:
    """One gradient step of the student on one minibatch with teacher labels; returns its losses and statistics.

    loss = mean KL(π_teacher ‖ π_student) + ``value_coef`` · value loss of the student's values against ``mb.returns``.
    Keys: distill_kl (the mean KL before the step), value_loss, grad_norm (before clipping) and agreement
    (:func:`greedy_agreement`, continuous tolerance :data:`AGREEMENT_SHARE` of the action range). With a ``scaler``
    (fp16) the loss is scaled and the gradients unscaled before clipping, as in ``trainer.ppo.minibatch_step``; a step
    whose gradients overflowed is skipped (``amp_skipped`` 1, ``grad_norm`` counted as 0).
    """
    if mb.teacher is None:
        raise ValueError("distillation needs a batch with teacher labels (PPOBatch.teacher)")
    params, values = model(mb.obs, mb.lidar)
    teacher = label_distribution(mb.teacher, model.action_kind)
    kl = kl_to_teacher(teacher, model.action_distribution(params)).mean()
    v_loss = value_loss(values, mb.returns, loss_type)
    total = kl + value_coef * v_loss
    grad_norm = gradient_step(model, optimizer, total, max_grad_norm=max_grad_norm, scaler=scaler)
    agreement = greedy_agreement(mb.teacher, params.detach(), model.action_kind, _agreement_tolerance(model))
    # .item() last: on a GPU it waits for the device, and here the whole step has been queued before it does.
    stats = {
        "distill_kl": kl.item(),
        "value_loss": v_loss.item(),
        "grad_norm": grad_norm.item(),
        "agreement": agreement.item(),
    }
    return with_amp_skipped(stats, scaler)


def distill(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    batch: PPOBatch,
    *,
    epochs: int,
    minibatch_size: int,
    value_coef: float,
    loss_type: ValueLossKind,
    max_grad_norm: float,
    generator: torch.Generator,
    scaler: torch.amp.GradScaler | None = None,
) -> dict[str, float]:
    """Distillation epochs over ``batch``; returns the means over minibatches of :func:`distill_step`'s statistics.

    As ``trainer.ppo.update``: each epoch shuffles the rows with ``generator`` (a CPU one, so a seed makes the run
    reproducible on every device) and takes minibatches of ``minibatch_size`` (the last may be smaller); the model and
    the batch are on one device (``PPOBatch.to``). Raises ValueError for a batch without teacher labels.
    """
    if batch.teacher is None:
        raise ValueError("distillation needs a batch with teacher labels (PPOBatch.teacher)")
    model.train()
    sums = dict.fromkeys(("distill_kl", "value_loss", "grad_norm", "agreement"), 0.0)
    n_steps = 0
    for _ in range(epochs):
        order = torch.randperm(len(batch), generator=generator).to(batch.obs.device)
        for start in range(0, len(batch), minibatch_size):
            stats = distill_step(
                model,
                optimizer,
                batch.select(order[start : start + minibatch_size]),
                value_coef=value_coef,
                loss_type=loss_type,
                max_grad_norm=max_grad_norm,
                scaler=scaler,
            )
            for key, value in stats.items():
                sums[key] = sums.get(key, 0.0) + value
            n_steps += 1
    return {key: total / max(n_steps, 1) for key, total in sums.items()}
