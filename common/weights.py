"""A network's weights as bytes, and back: checkpoints, the acting copies workers load, and stored policies.

Checkpoints are serialized with ``torch.save`` and read back with ``torch.load(weights_only=True)``, which
refuses any pickled object other than tensors and plain containers; so is a checkpoint's acting copy (float16
weights, :func:`acting_to_bytes`), what rollout workers load. ``load_policy`` is the one way to get a stored
checkpoint's network for acting (the evaluator, ``racer eval``, ``racer export``).
"""

from __future__ import annotations

import copy
import io
import pickle
from typing import TYPE_CHECKING, Any

import torch
from torch import nn

from common.config import FRAME_HEIGHT, FRAME_WIDTH
from common.errors import UserError
from common.policy import PolicyNetwork, action_space_spec, build_state_policy, policy_for_run
from common.privileged import STATE_SIZE

if TYPE_CHECKING:
    from common.action_space import ActionSpace
    from common.config import RunConfig
    from model_store.runs import RunStore


class CheckpointError(UserError, ValueError):
    """Bytes that are not a safe, well-formed state dict or checkpoint."""


def state_dict_to_bytes(sd: dict[str, Any]) -> bytes:
    """A state dict as ``torch.save`` bytes, every tensor on the CPU (one trained on a GPU loads anywhere)."""
    buf = io.BytesIO()
    torch.save(on_cpu(sd), buf)
    return buf.getvalue()


def on_cpu(value: Any) -> Any:
    """``value`` with every tensor in it (in nested dicts and lists) on the CPU. CPU tensors stay the same objects
    and a dict keeps its type and attributes (a module's state dict carries ``_metadata``), so CPU state dicts
    save to the very bytes they did before."""
    if isinstance(value, torch.Tensor):
        return value.cpu()
    if isinstance(value, dict):
        out = copy.copy(value)
        for key, item in value.items():
            out[key] = on_cpu(item)
        return out
    if isinstance(value, list):
        return [on_cpu(item) for item in value]
    return value


def state_dict_from_bytes(data: bytes) -> dict[str, Any]:
    """A state dict from ``state_dict_to_bytes`` bytes, on the CPU; never unpickles arbitrary objects."""
    sd = _safe_load(data)
    if not isinstance(sd, dict):
        raise CheckpointError(f"expected a state dict, got {type(sd).__name__}")
    return sd


def checkpoint_to_bytes(model_sd: dict[str, Any], optimizer_sd: dict[str, Any] | None = None) -> bytes:
    """A model state dict and an optional optimizer state dict as one ``torch.save`` blob."""
    return state_dict_to_bytes({"model": model_sd, "optimizer": optimizer_sd})


def checkpoint_from_bytes(data: bytes) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """(model state dict, optimizer state dict or None) from ``checkpoint_to_bytes`` bytes; loads weights only."""
    ckpt = _safe_load(data)
    if not isinstance(ckpt, dict) or not isinstance(ckpt.get("model"), dict):
        raise CheckpointError("not a checkpoint: expected a dict with a 'model' state dict")
    optimizer = ckpt.get("optimizer")
    if optimizer is not None and not isinstance(optimizer, dict):
        raise CheckpointError(f"checkpoint 'optimizer' is a {type(optimizer).__name__}, not a state dict")
    return ckpt["model"], optimizer


ACTING_DTYPE = torch.float16
"""The dtype of a policy's acting copy's weight matrices and kernels (:func:`acting_to_bytes`)."""
_ACTING_MAX = torch.finfo(ACTING_DTYPE).max


def acting_to_bytes(model_sd: dict[str, torch.Tensor]) -> bytes:
    """The acting copy of a network's state dict, what a rollout worker downloads per policy version: every weight
    matrix and conv kernel (a floating tensor of 2 or more dimensions: all but 683 of the default network's 5.85 M
    weights) in float16, the rest (biases, BatchNorm statistics, the log-std, counters) as it is; no optimizer
    state. Half the checkpoint's bytes. A tensor float16 cannot hold (a value beyond ±65504) stays float32.
    ``torch.save`` bytes of ``{"acting": state_dict}``, read back by :func:`acting_from_bytes`."""
    out = {}
    for name, tensor in model_sd.items():
        t = tensor.detach().to("cpu")
        if t.is_floating_point() and t.dim() >= 2 and (t.numel() == 0 or t.abs().max() <= _ACTING_MAX):
            t = t.to(ACTING_DTYPE)
        out[name] = t
    return state_dict_to_bytes({"acting": out})


def acting_from_bytes(data: bytes) -> dict[str, torch.Tensor]:
    """The state dict of :func:`acting_to_bytes` bytes in float32, to load into a network that acts in float32;
    loads weights only (CheckpointError for anything else)."""
    obj = _safe_load(data)
    sd = obj.get("acting") if isinstance(obj, dict) else None
    if not isinstance(sd, dict) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise CheckpointError("not an acting copy: expected a dict with an 'acting' state dict of tensors")
    return {name: t.float() if t.is_floating_point() else t for name, t in sd.items()}


def misfit(model: nn.Module, state: dict[str, Any]) -> str | None:
    """How a state dict does not fit ``model`` (layers of other shapes, or layers only one of them has), in a few
    words; None if it fits."""
    ours = model.state_dict()
    wrong = [
        f"{k} {tuple(v.shape)} vs {tuple(ours[k].shape)}"
        for k, v in state.items()
        if k in ours and v.shape != ours[k].shape
    ]
    missing = sorted(set(ours) ^ set(state))
    if not (wrong or missing):
        return None
    return "; ".join(wrong[:2]) or f"layers differ: {', '.join(missing[:3])}"


def load_weights(model: PolicyNetwork, state: dict[str, Any], source: str) -> None:
    """Load ``state`` into ``model``; CheckpointError naming ``source`` (e.g. "run r version 3") and the network
    when the weights were made for another network (a run from before racer's networks became the simapp's, say)."""
    problem = misfit(model, state)
    if problem:
        spec = getattr(model, "spec", None)
        what = f"{model.cfg.network} network for {'+'.join(spec.sensors)}" if spec else "state network"
        raise CheckpointError(f"{source}: its weights do not fit a {what} ({problem})")
    model.load_state_dict(state)


def load_policy(
    runs: RunStore,
    run: RunConfig | str,
    actions: ActionSpace,
    checkpoint: int | str,
    *,
    frame: tuple[int, int] = (FRAME_HEIGHT, FRAME_WIDTH),
    device: torch.device | str = "cpu",
) -> tuple[PolicyNetwork, dict[str, Any]]:
    """A stored checkpoint's network, ready to act, and the checkpoint's metadata.

    ``run`` is the run's config or its id (its config.json is then read); ``actions`` the action space the network
    acts in, whose ``sensor`` list gives its inputs; ``checkpoint`` a version, ``"latest"`` or ``"best"``; ``frame``
    the (height, width) of the camera frames it takes (DeepRacer's by default; the frame stack comes from the run's
    hyperparameters; a teacher run's network takes state vectors instead, ``common.policy.policy_for_run``). The
    network is in eval mode, on ``device`` (the CPU unless asked: the weights are read onto the CPU, then moved).
    StoreKeyError if the run or checkpoint is missing; CheckpointError if the bytes are not a checkpoint.
    """
    if isinstance(run, str):
        run = runs.read_config(run)
    payload, meta = runs.load_checkpoint(run.run_id, checkpoint)
    model = policy_for_run(run, actions, frame)
    load_weights(
        model, checkpoint_from_bytes(payload)[0], f"run {run.run_id} checkpoint {meta.get('version', checkpoint)}"
    )
    model.to(device).eval()
    return model, meta


def load_teacher(runs: RunStore, run: RunConfig, actions: ActionSpace) -> PolicyNetwork:
    """A distilling run's teacher (its stored copy, ``model_store.runs.TEACHER_FILE``), ready to act on state
    vectors; StoreKeyError if the copy is missing, CheckpointError if its weights do not fit."""
    from model_store.runs import TEACHER_FILE  # the store's layout, imported where it is used (no cycle at import)

    model = build_state_policy(STATE_SIZE, action_space_spec(actions), run.policy)
    payload = runs.read_file(run.run_id, TEACHER_FILE)
    load_weights(model, checkpoint_from_bytes(payload)[0], f"run {run.run_id}'s teacher ({run.distill.teacher})")
    return model.eval()


def _safe_load(data: bytes) -> Any:
    """``torch.load`` restricted to tensors and plain containers (weights_only), mapped to the CPU."""
    try:
        return torch.load(io.BytesIO(data), weights_only=True, map_location="cpu")
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, AttributeError) as exc:
        # The weights-only unpickler reports a refused global as UnpicklingError; corrupt bytes as the others.
        raise CheckpointError(f"refused to load checkpoint bytes: {_reason(exc)}") from None


def _reason(exc: Exception) -> str:
    """One line of torch.load's long message: the refused global when there is one."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    refused = [line for line in lines if "Unsupported global" in line]
    line = (refused or lines or [type(exc).__name__])[0]
    return line.split(" Please use ")[0]  # drop torch's advice to allowlist the global
