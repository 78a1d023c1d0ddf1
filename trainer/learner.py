"""The learning step: the run's network, its optimizer and one PPO update over a batch of segments.

The network's input and output come from the run's own files (its ``model_metadata.json``: sensors, action space)
and its hyperparameters (frame stack), never from an env: the trainer builds no simulator.
"""

from __future__ import annotations

import logging

import torch

from common.action_space import ActionSpace
from common.config import PretrainedError, RunConfig
from common.deadline import Deadline
from common.policy import PolicyNetwork, Precision, label_width, policy_for_run
from common.protocol import Segment
from common.sensors import ObsSpec, observation_spec
from common.weights import checkpoint_from_bytes, load_weights, misfit, state_dict_from_bytes
from trainer.distill import distill
from trainer.ppo import PPOBatch, StepArgs, compute_gae, cooldown_factor, scheduled, update
from trainer.precision import fastest, grad_scaler, precision_candidates, time_precisions

log = logging.getLogger("racer.trainer")


class Learner:
    """The network and Adam on ``device``, the update's precision, and the PPO step with its schedules."""

    def __init__(self, run: RunConfig, actions: ActionSpace, device: torch.device, precision: str) -> None:
        self.run, self.hp, self.device = run, run.hyperparams, device
        self.obs_spec: ObsSpec = observation_spec(actions.sensor, self.hp.stack_size)
        """The sensors' observation: the camera channels segments carry, and their LiDAR (if any)."""
        self.n_actions = actions.n if actions.discrete else None
        torch.manual_seed(run.seed)
        # Initialized on the CPU, then moved: the same initial weights on every device.
        self.model: PolicyNetwork = policy_for_run(run, actions).to(device)
        self.obs_shape = self.model.obs_shape
        """One observation as segments carry it: stacked camera frames (H, W, C), or a teacher's state (D,)."""
        self.lidar = self.obs_spec.lidar if run.env.observation == "sensors" else None
        """The LiDAR segments carry: the sensors' (None for a teacher's state vectors)."""
        self.label_width = (
            label_width(self.model.action_kind, self.model.action_dim) if run.distill is not None else None
        )
        """The width of the teacher's label rows segments carry in a distilling run; None otherwise."""
        self.precision_choices = precision_candidates(precision, device)
        """Precisions still in the running: more than one until the first update times them (``auto`` on a CPU)."""
        self.precision: Precision = self.precision_choices[0]
        self.precision_ms: dict[str, float] = {}
        """Milliseconds per minibatch step of each precision timed (empty where only one could run)."""
        self.model.set_trunk_precision(self.precision)
        self.scaler = grad_scaler(self.precision, device)
        """The loss scaler of an fp16 trunk on a GPU; None otherwise."""
        self.optimizer = make_optimizer(self.model, self.hp.lr, run.policy.l2)
        self.generator = torch.Generator().manual_seed(run.seed)

    def load_state(self, payload: bytes, optimizer: bytes | None, label: str) -> None:
        """Weights from a checkpoint's bytes, and the optimizer state saved beside them (or, from a trainer before
        racer kept it apart, inside them); without either the optimizer starts afresh. Weights made for another
        network are one CheckpointError naming ``label`` (the run and the version)."""
        model_sd, optim_sd = checkpoint_from_bytes(payload)
        load_weights(self.model, model_sd, label)
        if optimizer is not None:
            optim_sd = state_dict_from_bytes(optimizer)
        if optim_sd is None:
            self.optimizer = make_optimizer(self.model, self.hp.lr, self.run.policy.l2)
        else:
            self.optimizer.load_state_dict(optim_sd)
            for group in self.optimizer.param_groups:  # a checkpoint from an older trainer says fused=None
                group["fused"] = self.optimizer.defaults["fused"]

    def load_pretrained(self, payload: bytes, ref: str) -> None:
        """Take another run's weights (``ref``, ``run.pretrained``); a shape mismatch is one clear error."""
        model_sd, _ = checkpoint_from_bytes(payload)
        detail = misfit(self.model, model_sd)
        if detail:
            raise PretrainedError(f"pretrained {ref}: the network's shapes differ from this run's ({detail})")
        self.model.load_state_dict(model_sd)

    def learning_rate(self, iteration: int, lr_scale: float, deadline: Deadline | None) -> float:
        """The learning rate of the next policy update: the schedule's value (``lr`` itself when constant, as in
        DeepRacer), times the cool-down's factor in the last ``lr_cooldown`` of the time limit (counted back from
        the run's deadline, the one ``racer train`` stops every process at), times the rollbacks' ``lr_scale``."""
        hp = self.hp
        base = scheduled(hp.lr_schedule, hp.lr, hp.lr_final_fraction, iteration, hp.schedule_updates)
        if hp.lr_cooldown is not None and deadline is not None:
            base *= cooldown_factor(deadline.left(), deadline.limit_s, hp.lr_cooldown, hp.lr_final_fraction)
        return base * lr_scale

    def entropy_coef(self, iteration: int) -> float:
        """The entropy coefficient of the next policy update: ``beta_entropy`` itself when constant (DeepRacer)."""
        hp = self.hp
        return scheduled(
            hp.entropy_schedule, hp.beta_entropy, hp.entropy_final_fraction, iteration, hp.schedule_updates
        )

    def set_lr(self, lr: float) -> None:
        """The optimizer's learning rate from now on."""
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    def update(self, batch: PPOBatch, lr: float, beta_entropy: float) -> dict[str, float]:
        """One PPO update (``trainer.ppo.update``) over ``batch`` at ``lr``; returns its losses and figures."""
        hp = self.hp
        self.set_lr(lr)
        self._choose_precision(batch, beta_entropy)
        self.model.train()
        result = update(
            self.model,
            self.optimizer,
            batch,
            epochs=hp.num_epochs,
            minibatch_size=hp.batch_size,
            clip_eps=hp.clip_epsilon,
            beta_entropy=beta_entropy,
            value_coef=hp.value_loss_coef,
            loss_type=hp.value_loss_kind,
            max_grad_norm=hp.max_grad_norm,
            generator=self.generator,
            target_kl=hp.target_kl,
            scaler=self.scaler,
        )
        result["beta_entropy"] = beta_entropy
        self.model.eval()
        return result

    def learn(self, batch: PPOBatch, lr: float, *, version: int, iteration: int) -> dict[str, float]:
        """The update from policy ``version``: a distilling run's distillation while it distills
        (``DistillConfig.distilling``), else PPO's with the entropy coefficient of ``iteration``."""
        distill = self.run.distill
        if distill is not None and distill.distilling(version):
            return self.distill(batch, lr)
        return self.update(batch, lr, self.entropy_coef(iteration))

    def distill(self, batch: PPOBatch, lr: float) -> dict[str, float]:
        """One distillation update (``trainer.distill.distill``: KL(teacher ‖ student) and the value loss) over
        ``batch``, whose rows carry the teacher's labels, at ``lr``; returns its losses and figures."""
        hp = self.hp
        self.set_lr(lr)
        self._choose_precision(batch, hp.beta_entropy)
        self.model.train()
        result = distill(
            self.model,
            self.optimizer,
            batch,
            epochs=hp.num_epochs,
            minibatch_size=hp.batch_size,
            value_coef=hp.value_loss_coef,
            loss_type=hp.value_loss_kind,
            max_grad_norm=hp.max_grad_norm,
            generator=self.generator,
            scaler=self.scaler,
        )
        self.model.eval()
        return result

    def _choose_precision(self, batch: PPOBatch, beta_entropy: float) -> None:
        """``auto`` on a CPU with native bf16: before the first update, time both precisions on a copy of the
        network and the batch's first minibatch, and train in the faster from then on."""
        if len(self.precision_choices) < 2:
            return
        hp = self.hp
        minibatch = batch.select(torch.arange(min(len(batch), hp.batch_size), device=batch.obs.device))
        step_args = StepArgs(
            clip_eps=hp.clip_epsilon,
            beta_entropy=beta_entropy,
            value_coef=hp.value_loss_coef,
            loss_type=hp.value_loss_kind,
            max_grad_norm=hp.max_grad_norm,
        )
        self.precision_ms = time_precisions(self.model, minibatch, self.precision_choices, step_args, hp.lr)
        self.precision = fastest(self.precision_ms)
        self.precision_choices = (self.precision,)
        self.model.set_trunk_precision(self.precision)
        timings = ", ".join(f"{p} {ms:.1f} ms" for p, ms in self.precision_ms.items())
        log.info("PPO updates in %s: the faster per minibatch step on this machine (%s)", self.precision, timings)


def make_optimizer(model: torch.nn.Module, lr: float, l2: float) -> torch.optim.Adam:
    """Adam with its fused kernel: the same update as the per-parameter loop, one vectorized pass over the 6 M
    weights. The loop took a quarter of each minibatch step on the CPU (docs/speed.md)."""
    return torch.optim.Adam(model.parameters(), lr=lr, weight_decay=l2, fused=True)


def make_batch(segments: list[Segment], gamma: float, lam: float) -> PPOBatch:
    """GAE per segment (bootstrapping from the values the workers sent), then one flat batch on the CPU (with the
    segments' LiDAR vectors when they carry them: all or none do, ``decode_segment`` checks them against the run's
    sensors); ``PPOBatch.to`` moves it to the trainer's device."""
    parts = {k: [] for k in ("obs", "actions", "logp", "adv", "ret", "values", "lidar", "teacher")}
    for seg in segments:
        a = seg.arrays
        # Arrays decoded from Redis are read-only views of the message bytes: torch wants its own copy.
        t = {k: torch.tensor(a[k], dtype=torch.float32) for k in ("rewards", "values", "next_values")}
        adv, ret = compute_gae(
            t["rewards"],
            t["values"],
            torch.tensor(a["terminated"], dtype=torch.float32),
            torch.tensor(a["truncated"], dtype=torch.float32),
            t["next_values"],
            gamma=gamma,
            lam=lam,
        )
        parts["obs"].append(torch.from_numpy(a["obs"].copy()))
        for optional in ("lidar", "teacher"):
            if optional in a:
                parts[optional].append(torch.from_numpy(a[optional].copy()))
        parts["actions"].append(torch.from_numpy(a["actions"].copy()))
        parts["logp"].append(torch.from_numpy(a["logp"].copy()))
        parts["values"].append(t["values"])
        parts["adv"].append(adv)
        parts["ret"].append(ret)
    cat = {k: torch.cat(v) for k, v in parts.items() if v}
    return PPOBatch(
        obs=cat["obs"],
        actions=cat["actions"],
        old_logp=cat["logp"],
        advantages=cat["adv"],
        returns=cat["ret"],
        old_values=cat["values"],
        lidar=cat.get("lidar"),
        teacher=cat.get("teacher"),
    )
