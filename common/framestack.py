"""The frame stack that turns camera frames into the policy's observation."""

from __future__ import annotations

from collections import deque

import numpy as np


class FrameStack:
    """The last ``n`` camera frames as channels, as DeepRacer's ``stack_size`` does (the network's input).

    Here, in ``common`` and free of torch, because rollout workers, the evaluator and the on-car runtime must all
    build the same observation."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.frames: deque = deque(maxlen=n)

    def reset(self, frame: np.ndarray) -> np.ndarray:
        """Fill the stack with the first frame of an episode."""
        for _ in range(self.n):
            self.frames.append(frame)
        return self.get()

    def push(self, frame: np.ndarray) -> np.ndarray:
        """Add a frame and return the stacked observation."""
        self.frames.append(frame)
        return self.get()

    def get(self) -> np.ndarray:
        """(H, W, n) uint8, oldest frame first."""
        return np.concatenate(list(self.frames), axis=-1) if self.n > 1 else self.frames[-1]
