"""``racer export``: a run's checkpoint as an ONNX model a car can run without PyTorch.

The ONNX graph takes what the camera pipeline produces, uint8 frames ``obs`` of shape (batch, 120, 160,
stack_size), and returns ``action_probs`` (discrete: the policy's probabilities over the action space) or
``action_mean`` (continuous: the Gaussian's mean, in steering degrees and m/s), plus ``value``. The scaling to
[0, 1] happens inside the graph, as in training, so the car feeds raw pixels. ``model_metadata.json`` (the
action space, in DeepRacer's format) is written beside the model; the model's own metadata properties say which
run and version it came from and how to build its input.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import torch

from common.action_space import ActionSpace
from common.policy import ActorCritic, load_policy
from deploy.model_file import OBS_HEIGHT, OBS_WIDTH, stamp
from model_store import RunStore


class _Exported(torch.nn.Module):
    """The policy as the car needs it: probabilities (or the mean action) and the value, no sampling."""

    def __init__(self, model: ActorCritic) -> None:
        super().__init__()
        self.model = model

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        params, value = self.model(obs)
        if self.model.action_kind == "discrete":
            params = torch.softmax(params, dim=-1)
        return params, value


def export_onnx(runs: RunStore, run_id: str, checkpoint: str | int, out: str | Path) -> dict:
    """Write ``out`` (ONNX) and ``model_metadata.json`` beside it; return what was written."""
    out = Path(out)
    run = runs.read_config(run_id)
    metadata = runs.read_file(run_id, "model_metadata.json")
    actions = ActionSpace.model_validate_json(metadata)
    model, meta = load_policy(runs, run, actions, checkpoint)
    discrete = model.action_kind == "discrete"
    outputs = ["action_probs" if discrete else "action_mean", "value"]
    example = torch.zeros((1, OBS_HEIGHT, OBS_WIDTH, run.hyperparams.stack_size), dtype=torch.uint8)
    out.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        # The TorchScript exporter: it needs no extra packages (the torch.export one needs onnxscript) and handles
        # this plain CNN exactly; the parity test checks its output against torch.
        warnings.simplefilter("ignore")
        torch.onnx.export(
            _Exported(model),
            (example,),
            str(out),
            input_names=["obs"],
            output_names=outputs,
            dynamic_axes={"obs": {0: "batch"}, outputs[0]: {0: "batch"}, "value": {0: "batch"}},
            opset_version=17,
            dynamo=False,
        )
    info = {
        "run_id": run_id,
        "version": int(meta["version"]),
        "env_steps": meta.get("env_steps"),
        "stack_size": run.hyperparams.stack_size,
        "obs_shape": [OBS_HEIGHT, OBS_WIDTH, run.hyperparams.stack_size],
        "action_kind": model.action_kind,
        "preprocess": "grayscale (OpenCV BGR2GRAY), resize to 160x120 (INTER_AREA), uint8, oldest frame first",
    }
    stamp(out, info)
    (out.parent / "model_metadata.json").write_bytes(metadata)
    return {**info, "model": str(out), "model_metadata": str(out.parent / "model_metadata.json")}
