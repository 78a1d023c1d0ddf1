"""The frame stack that turns camera frames into the policy's observation."""

from __future__ import annotations

from collections import deque

import numpy as np


class FrameStack:
    """The last ``n`` camera frames as channels, as DeepRacer's ``stack_size`` does (the network's input).

    A frame is uint8 (H, W, c): c = 1 for the front camera, 2 for the stereo pair (left, right); the stack is
    (H, W, c·n), whole frames oldest first (stereo: left₀, right₀, left₁, right₁, …). Only camera frames are
    stacked: a LiDAR vector is not (``common.sensors``), the caller passes the latest one beside the stack.

    Here, in ``common`` and free of torch, because rollout workers, the evaluator and the on-car runtime must all
    build the same observation."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.frames: deque = deque(maxlen=n)

    def reset(self, frame: np.ndarray) -> np.ndarray:
        """Fill the stack with the first frame of an episode."""
        self._check(frame, first=True)
        for _ in range(self.n):
            self.frames.append(frame)
        return self.get()

    def push(self, frame: np.ndarray) -> np.ndarray:
        """Add a frame and return the stacked observation."""
        self._check(frame, first=False)
        self.frames.append(frame)
        return self.get()

    def get(self) -> np.ndarray:
        """(H, W, c·n) uint8, oldest frame first."""
        return np.concatenate(list(self.frames), axis=-1) if self.n > 1 else self.frames[-1]

    def _check(self, frame: np.ndarray, first: bool) -> None:
        """A frame is (H, W, c) and, within an episode, of the first frame's shape: a stack of mixed frames would
        put a camera's channels where the network expects another's."""
        if frame.ndim == 1 and self.n == 1:
            return  # a teacher's state vector (``EnvConfig.observation`` state): one, as it is
        if frame.ndim != 3:
            raise ValueError(f"a camera frame is (H, W, channels), got shape {frame.shape}")
        if not first and self.frames and frame.shape != self.frames[-1].shape:
            raise ValueError(f"a camera frame of shape {frame.shape} after frames of {self.frames[-1].shape}")
