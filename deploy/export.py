"""``racer export``: a run's checkpoint as an ONNX model a car can run without PyTorch.

The ONNX graph takes what the camera pipeline produces, uint8 frames ``obs`` of shape (batch, 120, 160, C) with
C = stack_size (front camera) or 2 × stack_size (stereo: left, right of each frame), and, when the run's sensors
include a LiDAR, float32 ``lidar`` of shape (batch, N) (N = 64 for LIDAR, 8 for SECTOR_LIDAR:
``common.sensors``). It returns ``action_probs`` (discrete: the policy's probabilities over the action space) or
``action_mean`` (continuous: the action the policy takes greedily, in steering degrees and m/s: the Gaussian's mean,
or with the run's ``greedy_action`` ``expected`` the mean of the clipped action), plus ``value``. The scaling to
[0, 1] happens inside the graph, as in training, so the car feeds raw pixels. ``model_metadata.json`` (the
action space and sensors, in DeepRacer's format) is written beside the model; the model's own metadata properties
say which run and version it came from, its sensors and how to build its inputs.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import torch

from common.action_space import ActionSpace
from common.errors import UserError
from common.policy import ActorCritic, PolicyNetwork
from common.sensors import LIDAR, SECTOR_LIDAR, STEREO_CAMERAS, ObsSpec
from common.weights import load_policy
from deploy.car.model_file import OBS_HEIGHT, OBS_WIDTH, stamp
from model_store import RunStore


class _Exported(torch.nn.Module):
    """The policy as the car needs it: probabilities (or the mean action) and the value, no sampling."""

    def __init__(self, model: ActorCritic) -> None:
        super().__init__()
        self.model = model

    def forward(self, obs: torch.Tensor, lidar: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        params, value = self.model(obs, lidar)
        if self.model.action_kind == "discrete":
            return torch.softmax(params, dim=-1), value
        return self.model.greedy(params), value


def camera_network(model: PolicyNetwork, run_id: str) -> ActorCritic:
    """``model`` if it is a camera network (DeepRacer's, which a car can run); a privileged teacher's network acts on
    the car's exact state on the track, which no car has: UserError naming the run."""
    if isinstance(model, ActorCritic):
        return model
    raise UserError(
        f"run {run_id!r} is a privileged teacher (racer train --teacher): it acts on the car's state, which a car "
        "does not have; export its student run"
    )


def export_onnx(runs: RunStore, run_id: str, checkpoint: str | int, out: str | Path) -> dict:
    """Write ``out`` (ONNX) and ``model_metadata.json`` beside it; return what was written."""
    out = Path(out)
    run = runs.read_config(run_id)
    metadata = runs.read_file(run_id, "model_metadata.json")
    actions = ActionSpace.model_validate_json(metadata)
    model, meta = load_policy(runs, run, actions, checkpoint)
    model = camera_network(model, run_id)
    discrete = model.action_kind == "discrete"
    outputs = ["action_probs" if discrete else "action_mean", "value"]
    spec = model.spec
    inputs = ["obs", "lidar"] if spec.lidar else ["obs"]
    camera_shape = spec.camera_shape((OBS_HEIGHT, OBS_WIDTH))
    example: tuple[torch.Tensor, ...] = (torch.zeros((1, *camera_shape), dtype=torch.uint8),)
    if spec.lidar:
        example += (torch.full((1, spec.lidar_size), spec.lidar.high, dtype=torch.float32),)
    out.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        # The TorchScript exporter: it needs no extra packages (the torch.export one needs onnxscript) and handles
        # this plain CNN exactly; the parity test checks its output against torch.
        warnings.simplefilter("ignore")
        torch.onnx.export(
            _Exported(model),
            example,
            str(out),
            input_names=inputs,
            output_names=outputs,
            dynamic_axes={**{name: {0: "batch"} for name in inputs}, outputs[0]: {0: "batch"}, "value": {0: "batch"}},
            opset_version=17,
            dynamo=False,
        )
    info = {
        "run_id": run_id,
        "version": int(meta["version"]),
        "env_steps": meta.get("env_steps"),
        "stack_size": run.hyperparams.stack_size,
        "obs_shape": list(camera_shape),
        "action_kind": model.action_kind,
        "preprocess": _preprocess(spec),
        "sensors": list(spec.sensors),
    }
    if spec.lidar:
        info["lidar_shape"] = [spec.lidar_size]
    stamp(out, info)
    (out.parent / "model_metadata.json").write_bytes(metadata)
    return {**info, "model": str(out), "model_metadata": str(out.parent / "model_metadata.json")}


def _preprocess(spec: ObsSpec) -> str:
    """How the car builds the model's inputs, in words (the runtime does it: ``deploy/car/runtime.py``)."""
    camera = "grayscale (OpenCV BGR2GRAY), resize to 160x120 (INTER_AREA), uint8, oldest frame first"
    if spec.camera == STEREO_CAMERAS:
        camera = "left and right cameras each " + camera + ", left then right channel per frame"
    lidar = {
        LIDAR: "; lidar: the 64 ranges of a scan in metres clipped to [0.15, 1.0], float32",
        SECTOR_LIDAR: "; lidar: the 64 ranges of a scan in 8 sectors of 8, 1.0 if a sector's nearest range is "
        "below 0.5 m else 0.0, float32",
    }
    return camera + (lidar[spec.lidar.name] if spec.lidar else "")
