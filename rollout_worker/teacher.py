"""A distilling run's teacher in a rollout worker: the privileged network (``common.policy.StatePolicy``) acting on
the car's state vectors, giving every step's label (its action distribution) and the action it would take."""

from __future__ import annotations

import numpy as np
import torch

from common.policy import PolicyNetwork


class Teacher:
    """The teacher network, its weights loaded, in eval mode; ``act`` on a batch of state vectors.

    It runs in torch (a few dense layers on a 24-value vector: microseconds), sampling with ``generator`` so a
    worker's seed makes its teacher's draws reproducible."""

    def __init__(self, model: PolicyNetwork, seed: int) -> None:
        self.model = model.eval()
        self.generator = torch.Generator().manual_seed(seed)

    @torch.no_grad()
    def act(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(float32 (B, P) labels, the teacher's sampled actions: int64 (B,) or float32 (B, d)) for float32 (B, D)
        state vectors."""
        params, _ = self.model(torch.from_numpy(np.ascontiguousarray(states, np.float32)))
        labels = self.model.labels(params)
        if self.model.action_kind == "discrete":
            probs = torch.softmax(params, dim=-1)
            actions = torch.multinomial(probs, 1, generator=self.generator)[:, 0].numpy().astype(np.int64)
        else:
            d = params.shape[-1]
            noise = torch.randn(params.shape, generator=self.generator)
            actions = (params + labels[:, d:] * noise).numpy().astype(np.float32)
        return labels.numpy().astype(np.float32), actions
