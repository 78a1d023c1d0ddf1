"""The rollout worker's acting copy of the policy network in ONNX Runtime.

A worker acts on one core. There ONNX Runtime runs DeepRacer's shallow network's forward pass 1.4-1.8 × as fast as
PyTorch for batches of 1 to 8 (docs/speed.md, "Workers"), with the same outputs to ~1e-6. Only the forward pass
(``ActorCritic.forward``: logits or the Gaussian's mean, and the value) runs in ONNX Runtime: the action is drawn
from, and its log-probability taken under, the torch network's own distribution (``ActorCritic.act_from``) with
torch's random generator, so sampling is exactly what ``ActorCritic.act`` does on those outputs.

The copy is exported from the network's current weights (``torch.onnx.export`` into memory, ~0.2 s): build a new
one for every policy version. Where it cannot be built (an exporter or runtime that refuses the network), the
worker acts with the torch network itself (:func:`acting_copy`).
"""

from __future__ import annotations

import io
import logging
import warnings
from typing import Protocol

import numpy as np
import torch

from common.policy import PolicyNetwork

log = logging.getLogger("racer.worker")


class Actor(Protocol):
    """What a worker acts with: an ``ActorCritic`` or its :class:`OnnxPolicy` copy."""

    def act_numpy(
        self, obs: np.ndarray, deterministic: bool = False, lidar: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(actions, log-probs, values) of a uint8 (B, H, W, C) batch (and its float32 (B, N) LiDAR batch)."""
        ...


class OnnxPolicy:
    """``model``'s forward pass in a one-thread ONNX Runtime session; ``act_numpy`` as ``ActorCritic.act_numpy``."""

    def __init__(self, model: PolicyNetwork) -> None:
        import onnxruntime as ort  # the worker only: the trainer and the launcher never load it

        self.model = model
        self.lidar = bool(model.lidar_size)
        self.dtype = np.float32 if model.obs_dtype == torch.float32 else np.uint8
        inputs = ["obs", "lidar"] if self.lidar else ["obs"]
        example: tuple[torch.Tensor, ...] = (torch.zeros((1, *model.obs_shape), dtype=model.obs_dtype),)
        if self.lidar:
            example += (torch.zeros((1, model.lidar_size), dtype=torch.float32),)
        buffer = io.BytesIO()
        with warnings.catch_warnings():
            # The TorchScript exporter, as racer export uses it (no extra packages); its deprecation and tracer
            # warnings are about code paths this plain network does not take. The parity test checks the outputs.
            warnings.simplefilter("ignore")
            torch.onnx.export(
                model,
                example,
                buffer,
                input_names=inputs,
                output_names=["params", "value"],
                dynamic_axes={name: {0: "batch"} for name in [*inputs, "params", "value"]},
                opset_version=17,
                dynamo=False,
            )
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1  # a worker is a single-core process, as torch.set_num_threads(1) says
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        self.session = ort.InferenceSession(buffer.getvalue(), options, providers=["CPUExecutionProvider"])

    def act_numpy(
        self, obs: np.ndarray, deterministic: bool = False, lidar: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(int64 (B,) or float32 (B, d) actions, float32 log-probs, float32 values), as ``ActorCritic.act_numpy``."""
        if obs.ndim != len(self.model.obs_shape) + 1:
            raise ValueError(f"act_numpy takes a batch (B, *{self.model.obs_shape}), got shape {obs.shape}")
        if (lidar is not None) != self.lidar:
            raise ValueError(f"this network {'needs a' if self.lidar else 'takes no'} LiDAR batch")
        feed = {"obs": np.ascontiguousarray(obs, self.dtype)}
        if lidar is not None:
            feed["lidar"] = np.ascontiguousarray(lidar, np.float32)
        params, value = self.session.run(None, feed)
        return self.model.act_numpy_from(params, value, deterministic)


def acting_copy(model: PolicyNetwork) -> Actor:
    """An :class:`OnnxPolicy` of ``model``'s current weights, or ``model`` itself where one cannot be built."""
    try:
        return OnnxPolicy(model)
    except Exception as exc:  # noqa: BLE001 - any exporter or runtime failure: torch acts, slower but the same
        log.warning("acting with PyTorch: no ONNX Runtime copy of the network (%s: %s)", type(exc).__name__, exc)
        return model
