"""PPO as small pure torch functions, and one linear ``update()`` that does no I/O.

The functions follow CleanRL's PPO (clipped surrogate, per-minibatch advantage normalization, global
gradient-norm clipping) with SB3's typed batch. Each is tested against hand-computed values in
``tests/test_ppo.py``.

racer's stability knobs live here too, all off by default (DeepRacer has none of them): target-KL early stopping
of the epochs (``update(target_kl=...)``) and the learning-rate / entropy schedules (``scheduled``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Literal, TypedDict

import torch
import torch.nn.functional as F
from torch import nn

ValueLossKind = Literal["huber", "mse"]
ScheduleKind = Literal["constant", "linear"]


class StepArgs(TypedDict):
    """:func:`minibatch_step`'s loss settings, to pass as ``**args`` (the trainer's probes and benchmarks)."""

    clip_eps: float
    beta_entropy: float
    value_coef: float
    loss_type: ValueLossKind
    max_grad_norm: float


@torch.no_grad()
def compute_gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    terminated: torch.Tensor,
    truncated: torch.Tensor,
    next_values: torch.Tensor,
    *,
    gamma: float,
    lam: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalized advantage estimates and returns of ONE segment of T consecutive steps, in time order.

    All inputs are 1-D tensors of length T (``terminated`` / ``truncated`` may be bool or 0/1):

    * ``rewards[t]`` = r_t, ``values[t]`` = V(o_t) as seen at rollout time;
    * ``next_values[t]`` = V(o_{t+1}) as seen at rollout time. For the segment's last step it is the bootstrap
      value of the final next observation; for a truncated step (time limit) it is V of the episode's final
      observation, so truncation bootstraps; for a terminated step it is ignored (no future after the end).

    The recursion, backwards from t = T-1 with gae_T = 0::

        delta_t = r_t + gamma * next_values[t] * (1 - terminated_t) - values_t
        gae_t   = delta_t + gamma * lam * (1 - done_t) * gae_{t+1},   done_t = terminated_t or truncated_t

    so the advantage never flows across an episode boundary, and the segment's end bootstraps only through
    ``next_values[T-1]``. Returns (advantages, returns) with returns = advantages + values.
    """
    if rewards.dim() != 1:
        raise ValueError(f"rewards has shape {tuple(rewards.shape)}, expected one segment (T,)")
    n = rewards.shape[0]
    others = {"values": values, "terminated": terminated, "truncated": truncated, "next_values": next_values}
    for name, x in others.items():
        if x.shape != (n,):
            raise ValueError(f"{name} has shape {tuple(x.shape)}, expected ({n},) like rewards")
    rewards = rewards.float()
    # where(), not a multiply by (1 - terminated): a value written as NaN for a terminal step stays ignored.
    future = torch.where(terminated.bool(), 0.0, gamma * next_values.float())
    not_done = 1.0 - (terminated.bool() | truncated.bool()).float()
    deltas = rewards + future - values.float()
    advantages = torch.zeros_like(rewards)
    gae = torch.zeros((), dtype=rewards.dtype)
    for t in reversed(range(n)):
        gae = deltas[t] + gamma * lam * not_done[t] * gae
        advantages[t] = gae
    return advantages, advantages + values.float()


def policy_loss(
    new_logp: torch.Tensor, old_logp: torch.Tensor, advantages: torch.Tensor, clip_eps: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """PPO's clipped surrogate: (loss, clip fraction, approx KL).

    loss = -mean(min(ratio * A, clip(ratio, 1 - eps, 1 + eps) * A)) with ratio = exp(new_logp - old_logp).
    clip fraction = share of samples with |ratio - 1| > eps; approx KL = mean((ratio - 1) - log ratio), the
    low-variance, always non-negative estimator of KL(old || new) (Schulman's k3). The two statistics carry
    no gradient.
    """
    ratio = (new_logp - old_logp).exp()
    surrogate = ratio * advantages
    clipped = ratio.clamp(1.0 - clip_eps, 1.0 + clip_eps) * advantages
    loss = -torch.min(surrogate, clipped).mean()
    with torch.no_grad():
        clip_fraction = ((ratio - 1.0).abs() > clip_eps).float().mean()
    return loss, clip_fraction, approx_kl(new_logp, old_logp)


@torch.no_grad()
def approx_kl(new_logp: torch.Tensor, old_logp: torch.Tensor) -> torch.Tensor:
    """Estimate of KL(old || new) from log-probabilities of actions sampled by the old policy.

    mean((ratio - 1) - log ratio) with ratio = exp(new_logp - old_logp): Schulman's k3 estimator, unbiased,
    never negative for any sample (x - 1 >= log x), and of lower variance than mean(old_logp - new_logp).
    Carries no gradient.
    """
    log_ratio = new_logp - old_logp
    return ((log_ratio.exp() - 1.0) - log_ratio).mean()


def value_loss(values: torch.Tensor, returns: torch.Tensor, kind: ValueLossKind = "huber") -> torch.Tensor:
    """Value-function loss: ``huber`` = smooth L1 with delta 1 (mean), ``mse`` = 0.5 * mean((V - R)^2).

    The 0.5 makes the mse gradient (V - R), as in CleanRL; huber equals it for |V - R| <= 1.
    """
    if kind == "huber":
        return F.smooth_l1_loss(values, returns, beta=1.0)
    if kind == "mse":
        return 0.5 * (values - returns).pow(2).mean()
    raise ValueError(f"value loss kind must be 'huber' or 'mse', got {kind!r}")


def entropy_bonus(entropy: torch.Tensor) -> torch.Tensor:
    """Mean policy entropy of a minibatch (subtracted from the loss, weighted by beta_entropy)."""
    return entropy.mean()


def normalize_advantages(adv: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """(adv - mean) / (std + eps), std unbiased; a single advantage normalizes to 0 (its std is undefined)."""
    if adv.numel() < 2:
        return adv - adv.mean()
    return (adv - adv.mean()) / (adv.std() + eps)


def explained_variance(values: torch.Tensor, returns: torch.Tensor) -> float:
    """1 - Var(returns - values) / Var(returns): 1 = perfect values, 0 = no better than a constant.

    NaN when the returns have no variance, as in SB3.
    """
    var_returns = returns.var(unbiased=False)
    if var_returns == 0:
        return float("nan")
    return float(1.0 - (returns - values).var(unbiased=False) / var_returns)


@dataclass
class PPOBatch:
    """One update's transitions, flattened over segments; every field has the same first dimension N."""

    obs: torch.Tensor
    """uint8 (N, H, W, C) observations o_t."""
    actions: torch.Tensor
    """int64 (N,) action indices, or float32 (N, d) continuous actions in env units."""
    old_logp: torch.Tensor
    """float32 (N,) log π_old(a_t | o_t) under the behaviour policy."""
    advantages: torch.Tensor
    """float32 (N,) GAE advantages (not normalized; ``update`` normalizes per minibatch)."""
    returns: torch.Tensor
    """float32 (N,) value targets: advantages + old_values."""
    old_values: torch.Tensor
    """float32 (N,) V(o_t) under the behaviour policy."""
    lidar: torch.Tensor | None = None
    """float32 (N, L) LiDAR part of o_t, for a network with a LiDAR; None for a camera-only network."""
    teacher: torch.Tensor | None = None
    """float32 (N, P) the teacher's action distribution at each step of a distilling run (``trainer.distill``:
    logits, or the Gaussian's means then standard deviations); None otherwise."""

    def __post_init__(self) -> None:
        n = len(self)
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None and value.shape[0] != n:
                raise ValueError(f"PPOBatch.{f.name} has {value.shape[0]} rows, obs has {n}")

    def __len__(self) -> int:
        return int(self.obs.shape[0])

    def select(self, idx: torch.Tensor) -> PPOBatch:
        """The rows ``idx`` of every field (an absent LiDAR stays absent)."""
        return PPOBatch(*(_rows(getattr(self, f.name), idx) for f in fields(self)))

    def to(self, device: torch.device) -> PPOBatch:
        """The batch on ``device``: itself for the CPU; for a GPU every field copied from pinned (page-locked) memory
        without waiting, so that the copies overlap and the minibatches are then indexed on the GPU."""
        if device.type == "cpu":
            return self
        pinned = device.type == "cuda"
        return PPOBatch(*(_moved(getattr(self, f.name), device, pinned) for f in fields(self)))


def _moved(value: torch.Tensor | None, device: torch.device, pinned: bool) -> torch.Tensor | None:
    """``value`` on ``device`` (through pinned memory, asynchronously, when ``pinned``); None stays None."""
    if value is None:
        return None
    return (value.pin_memory() if pinned else value).to(device, non_blocking=pinned)


def _rows(value: torch.Tensor | None, idx: torch.Tensor) -> torch.Tensor | None:
    """``value[idx]``, or None for an absent optional field."""
    return None if value is None else value[idx]


def update(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    batch: PPOBatch,
    *,
    epochs: int,
    minibatch_size: int,
    clip_eps: float,
    beta_entropy: float,
    value_coef: float,
    loss_type: ValueLossKind,
    max_grad_norm: float,
    generator: torch.Generator,
    target_kl: float | None = None,
    scaler: torch.amp.GradScaler | None = None,
) -> dict[str, float]:
    """PPO epochs over ``batch``; returns the means over minibatches of the losses and statistics.

    Each epoch shuffles the rows with ``generator`` (so a seed makes the update reproducible) and takes
    minibatches of ``minibatch_size`` (the last may be smaller). ``model.evaluate(obs, actions, lidar)`` must return
    (log_prob, entropy, value); ``lidar`` is the minibatch's LiDAR rows, None for a camera-only network. Keys:
    policy_loss, value_loss, entropy, approx_kl, clip_fraction, grad_norm (before clipping), explained_variance (of
    the batch's old values), epochs_run and epoch_kl (the mean approx KL of the last epoch run).

    The model and the batch are on one device (``PPOBatch.to``); ``generator`` is a CPU one, so every device sees
    the same shuffles, and each epoch's order is moved to the batch's device once. ``scaler`` (an fp16 trunk on a
    GPU: ``trainer.precision.grad_scaler``) scales the loss; the means then also have ``amp_skipped``, the share of
    steps it skipped for non-finite gradients.

    ``target_kl`` (None = off, as DeepRacer) stops the remaining epochs once an epoch's mean approx KL exceeds
    it. Each minibatch's KL is measured before its own step, so an epoch's mean covers every row of the batch
    with the policy as it moved during that epoch, at no cost (a KL measured after each epoch would take one more
    forward pass over the whole batch per epoch).
    """
    model.train()
    sums = dict.fromkeys(("policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction", "grad_norm"), 0.0)
    n_steps = epochs_run = 0
    epoch_kl = 0.0
    for _ in range(epochs):
        order = torch.randperm(len(batch), generator=generator).to(batch.obs.device)
        kls = []
        for start in range(0, len(batch), minibatch_size):
            mb = batch.select(order[start : start + minibatch_size])
            stats = minibatch_step(
                model,
                optimizer,
                mb,
                clip_eps=clip_eps,
                beta_entropy=beta_entropy,
                value_coef=value_coef,
                loss_type=loss_type,
                max_grad_norm=max_grad_norm,
                scaler=scaler,
            )
            for key, value in stats.items():
                sums[key] = sums.get(key, 0.0) + value
            kls.append(stats["approx_kl"])
            n_steps += 1
        epochs_run += 1
        epoch_kl = sum(kls) / max(len(kls), 1)
        if kl_exceeded(epoch_kl, target_kl):
            break
    means = {key: total / max(n_steps, 1) for key, total in sums.items()}
    means["explained_variance"] = explained_variance(batch.old_values, batch.returns)
    means["epochs_run"] = float(epochs_run)
    means["epoch_kl"] = epoch_kl
    return means


def kl_exceeded(kl: float, target_kl: float | None) -> bool:
    """True when early stopping is on (``target_kl`` not None) and ``kl`` is above the target."""
    return target_kl is not None and kl > target_kl


def cooldown_factor(remaining_s: float, limit_s: float, share: float, final_fraction: float) -> float:
    """The cool-down's multiplier of the learning rate with ``remaining_s`` of a ``limit_s`` time limit left: 1
    until the last ``share`` of the limit, then linearly down to ``final_fraction`` at its end (and that after
    it)::

        final_fraction + (1 - final_fraction) * clip(remaining_s / (share * limit_s), 0, 1)
    """
    if limit_s <= 0 or not 0 < share <= 1:
        raise ValueError(f"cool-down needs a positive time limit and a share in (0, 1], got {limit_s}, {share}")
    left = min(max(remaining_s / (share * limit_s), 0.0), 1.0)
    return final_fraction + (1.0 - final_fraction) * left


def scheduled(kind: ScheduleKind, initial: float, final_fraction: float, k: int, length: int) -> float:
    """A schedule's value before policy update ``k`` (0 = the first update).

    ``constant``: ``initial`` at every k (DeepRacer). ``linear``: from ``initial`` at k = 0 down (or up) to
    ``initial * final_fraction`` at k = ``length``, and that final value after it::

        initial * (1 + (final_fraction - 1) * min(k / length, 1))
    """
    if kind == "constant":
        return initial
    if kind == "linear":
        if length < 1:
            raise ValueError(f"schedule length must be at least 1 update, got {length}")
        done = min(max(k, 0) / length, 1.0)
        return initial * (1.0 + (final_fraction - 1.0) * done)
    raise ValueError(f"schedule must be 'constant' or 'linear', got {kind!r}")


def minibatch_step(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    mb: PPOBatch,
    *,
    clip_eps: float,
    beta_entropy: float,
    value_coef: float,
    loss_type: ValueLossKind,
    max_grad_norm: float,
    scaler: torch.amp.GradScaler | None = None,
) -> dict[str, float]:
    """One gradient step on one minibatch; returns its losses and statistics.

    With a ``scaler`` (fp16) the loss is scaled before ``backward`` and the gradients unscaled before clipping, so
    ``grad_norm`` and the clipping see the true gradients; a step whose gradients overflowed is skipped by the
    scaler (``amp_skipped`` 1, ``grad_norm`` counted as 0 so that the means stay finite)."""
    new_logp, entropy, values = model.evaluate(mb.obs, mb.actions, mb.lidar)
    advantages = normalize_advantages(mb.advantages)  # per minibatch, as in CleanRL
    pg_loss, clip_fraction, kl = policy_loss(new_logp, mb.old_logp, advantages, clip_eps)
    v_loss = value_loss(values, mb.returns, loss_type)
    ent = entropy_bonus(entropy)
    total = pg_loss + value_coef * v_loss - beta_entropy * ent
    grad_norm = gradient_step(model, optimizer, total, max_grad_norm=max_grad_norm, scaler=scaler)
    # .item() last: on a GPU it waits for the device, and here the whole step has been queued before it does.
    stats = {
        "policy_loss": pg_loss.item(),
        "value_loss": v_loss.item(),
        "entropy": ent.item(),
        "approx_kl": kl.item(),
        "clip_fraction": clip_fraction.item(),
        "grad_norm": grad_norm.item(),
    }
    return with_amp_skipped(stats, scaler)


def gradient_step(
    model: nn.Module,
    optimizer: torch.optim.Optimizer,
    loss: torch.Tensor,
    *,
    max_grad_norm: float,
    scaler: torch.amp.GradScaler | None = None,
) -> torch.Tensor:
    """Backward ``loss``, clip the gradients' global norm to ``max_grad_norm`` and step ``optimizer``; the norm
    before clipping. With a ``scaler`` (fp16) the loss is scaled and the gradients unscaled before clipping, so the
    clipping and the norm see the true gradients, and the scaler skips a step whose gradients overflowed."""
    optimizer.zero_grad(set_to_none=True)
    if scaler is None:
        loss.backward()
        grad_norm = nn.utils.clip_grad_norm_(model.parameters(), max_grad_norm)
        optimizer.step()
        return grad_norm
    scaler.scale(loss).backward()
    scaler.unscale_(optimizer)
    grad_norm = nn.utils.clip_grad_norm_(model.parameters(), max_grad_norm)
    scaler.step(optimizer)  # skipped when the unscaled gradients hold an inf or a NaN
    scaler.update()
    return grad_norm


def with_amp_skipped(stats: dict[str, float], scaler: torch.amp.GradScaler | None) -> dict[str, float]:
    """A step's statistics with, under a ``scaler``, ``amp_skipped`` (1 where its gradients overflowed and the scaler
    skipped it) and such a step's ``grad_norm`` counted as 0, so that the means stay finite."""
    if scaler is not None:
        skipped = not math.isfinite(stats["grad_norm"])
        stats["grad_norm"] = 0.0 if skipped else stats["grad_norm"]
        stats["amp_skipped"] = float(skipped)
    return stats
