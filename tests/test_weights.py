"""common/weights.py: checkpoints and acting copies as bytes and back (weights only: nothing else is unpickled),
and load_policy, a stored checkpoint's network for acting."""

from __future__ import annotations

import functools
import io
from pathlib import Path

import numpy as np
import pytest
import torch

from common.action_space import default_action_space
from common.policy import (
    ActorCritic,
    PolicyConfig,
    action_space_spec,
    build_policy,
)
from common.weights import (
    CheckpointError,
    acting_from_bytes,
    acting_to_bytes,
    checkpoint_from_bytes,
    checkpoint_to_bytes,
    state_dict_from_bytes,
    state_dict_to_bytes,
)
from tests.test_policy import CONTINUOUS, DISCRETE, SMALL, random_frames


class _PickleBomb:
    """Unpickling this opens (creates) a file: what a malicious checkpoint could do."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self) -> tuple:
        return (open, (self.path, "w"))


@functools.cache
def _driven_frames() -> np.ndarray:
    """200 real camera frames of the default run, driven by its untrained network (racer/bench/wire.py)."""
    from racer.bench.wire import driven_segments

    return np.concatenate([s.arrays["obs"] for s in driven_segments(steps=50, segments=4, seed=1)])


def _greedy_and_logits(model: ActorCritic, frames: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    model.eval()
    with torch.no_grad():
        logits, _ = model(torch.from_numpy(frames))
    return model.greedy(logits), logits


def _assert_same(a: object, b: object) -> None:
    """Deep equality of nested dicts/lists of tensors and plain values."""
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b)
    elif isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys()
        for key in a:
            _assert_same(a[key], b[key])
    elif isinstance(a, list | tuple):
        assert len(a) == len(b)
        for x, y in zip(a, b, strict=True):
            _assert_same(x, y)
    else:
        assert a == b


def test_state_dict_round_trip() -> None:
    model = build_policy(SMALL, CONTINUOUS, PolicyConfig(batch_norm=True))
    sd = state_dict_from_bytes(state_dict_to_bytes(model.state_dict()))
    _assert_same(model.state_dict(), sd)
    other = build_policy(SMALL, CONTINUOUS, PolicyConfig(batch_norm=True))
    other.load_state_dict(sd)
    obs = torch.from_numpy(random_frames(2, SMALL))
    model.eval()
    other.eval()
    torch.testing.assert_close(model(obs), other(obs), rtol=0, atol=0)


def test_checkpoint_round_trip_with_optimizer() -> None:
    model = build_policy(SMALL, DISCRETE)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    logp, _, value = model.evaluate(torch.from_numpy(random_frames(2, SMALL)), torch.tensor([0, 1]))
    (value.sum() - logp.sum()).backward()
    optimizer.step()  # so that the optimizer has state to save
    model_sd, optimizer_sd = checkpoint_from_bytes(checkpoint_to_bytes(model.state_dict(), optimizer.state_dict()))
    _assert_same(model.state_dict(), model_sd)
    _assert_same(optimizer.state_dict(), optimizer_sd)
    assert checkpoint_from_bytes(checkpoint_to_bytes(model.state_dict(), None))[1] is None


def test_pickle_bomb_refused(tmp_path: Path) -> None:
    target = tmp_path / "pwned"
    buf = io.BytesIO()
    torch.save({"model": {"w": torch.zeros(2)}, "optimizer": _PickleBomb(target)}, buf)
    with pytest.raises(CheckpointError, match="io.open"):
        checkpoint_from_bytes(buf.getvalue())
    with pytest.raises(CheckpointError):
        state_dict_from_bytes(buf.getvalue())
    assert not target.exists()
    # The bomb is real: an unrestricted torch.load would have created the file.
    torch.load(io.BytesIO(buf.getvalue()), weights_only=False)
    assert target.exists()


@pytest.mark.parametrize("data", [b"", b"not a checkpoint", state_dict_to_bytes({"w": torch.zeros(1)})[:40]])
def test_corrupt_bytes_refused(data: bytes) -> None:
    with pytest.raises(CheckpointError):
        checkpoint_from_bytes(data)


def test_checkpoint_structure_checked() -> None:
    with pytest.raises(CheckpointError, match="'model'"):
        checkpoint_from_bytes(state_dict_to_bytes({"w": torch.zeros(1)}))
    with pytest.raises(CheckpointError, match="state dict"):
        state_dict_from_bytes(state_dict_to_bytes([torch.zeros(1)]))  # type: ignore[arg-type]


def test_load_policy_gives_the_saved_weights_in_eval_mode(tmp_path: Path) -> None:
    """The one loader of a stored checkpoint for acting: by version, pointer or decimal string, from a RunConfig or
    the run id (its config.json), it gives exactly the weights saved (batch-norm statistics too), in eval mode."""
    from common.config import RunConfig
    from common.hyperparams import Hyperparameters
    from common.weights import load_policy
    from model_store import LocalStore, RunStore, StoreKeyError

    runs = RunStore(LocalStore(tmp_path))
    cfg = PolicyConfig(batch_norm=True, dropout=0.2, stack_size=2)
    run = RunConfig(run_id="p", hyperparams=Hyperparameters(stack_size=2), policy=cfg)
    runs.write_config(run)
    actions = default_action_space()
    saved = []
    for version in (0, 1):
        torch.manual_seed(version)
        model = build_policy((*SMALL[:2], 2), action_space_spec(actions), cfg).train()
        model(torch.from_numpy(random_frames(4, (*SMALL[:2], 2), version)))  # moves the batch-norm running statistics
        runs.save_checkpoint("p", version, checkpoint_to_bytes(model.state_dict()), {"env_steps": 10 * version})
        saved.append(model.state_dict())
    runs.set_pointer("p", "best", 0)
    for source in (run, "p"):
        for checkpoint, version in ((0, 0), ("1", 1), ("latest", 1), ("best", 0)):
            loaded, meta = load_policy(runs, source, actions, checkpoint, frame=SMALL[:2])
            assert not loaded.training and loaded.obs_shape == (*SMALL[:2], 2)
            assert meta["version"] == version and meta["env_steps"] == 10 * version
            state = loaded.state_dict()
            assert state.keys() == saved[version].keys()
            assert all(torch.equal(state[k], saved[version][k]) for k in state)
    with pytest.raises(StoreKeyError, match="checkpoint 7"):
        load_policy(runs, run, actions, 7, frame=SMALL[:2])


def test_the_acting_copy_takes_the_checkpoints_greedy_actions() -> None:
    """On 200 real frames, the float16 acting copy (back in float32) picks the same greedy action as the float32
    weights of the untrained default network (the network of every run's first iteration). A flip would need a
    top-two logit gap below the copy's logit error (~1e-5 here, logits ~3e-3 in size): a near-tie, where either
    action is the policy's choice to within float16. Fixed seeds: the same frames and weights every run."""
    torch.manual_seed(0)
    model = build_policy((120, 160, 1), DISCRETE)
    frames = _driven_frames()
    copy = build_policy((120, 160, 1), DISCRETE)
    copy.load_state_dict(acting_from_bytes(acting_to_bytes(model.state_dict())))
    greedy, logits = _greedy_and_logits(model, frames)
    copy_greedy, copy_logits = _greedy_and_logits(copy, frames)
    assert len(frames) == 200 and len(set(greedy.tolist())) > 1  # not one action for every frame
    assert torch.equal(greedy, copy_greedy)
    assert (logits - copy_logits).abs().max() < 1e-2 * logits.abs().mean()


def test_the_acting_copy_is_half_the_checkpoint_and_weights_only(tmp_path: Path) -> None:
    """Float16 matrices and kernels, everything else as it was (bit for bit), no optimizer; at most 12 MB for the
    default network; read with weights_only, so a pickle bomb is refused as in checkpoints."""
    torch.manual_seed(0)
    model = build_policy((120, 160, 1), CONTINUOUS, PolicyConfig(batch_norm=True))
    sd = model.state_dict()
    data = acting_to_bytes(sd)
    assert len(data) <= 12_000_000 and len(data) < 0.51 * len(checkpoint_to_bytes(sd))
    raw = torch.load(io.BytesIO(data), weights_only=True)["acting"]
    for name, tensor in sd.items():
        half = tensor.is_floating_point() and tensor.dim() >= 2
        assert raw[name].dtype == (torch.float16 if half else tensor.dtype), name
    back = acting_from_bytes(data)
    assert back.keys() == sd.keys() and all(t.dtype == sd[k].dtype for k, t in back.items())
    for name in ("log_std", "trunk.0.bias", "trunk.1.running_var", "trunk.1.num_batches_tracked"):
        assert torch.equal(back[name], sd[name]), name
    big = {"w": torch.full((2, 2), 1e6), "v": torch.ones(2, 2)}  # beyond float16: kept in float32
    assert acting_from_bytes(acting_to_bytes(big))["w"][0, 0] == 1e6
    with pytest.raises(CheckpointError, match="acting copy"):
        acting_from_bytes(checkpoint_to_bytes(sd))
    target = tmp_path / "pwned"
    buf = io.BytesIO()
    torch.save({"acting": {"w": _PickleBomb(target)}}, buf)
    with pytest.raises(CheckpointError):
        acting_from_bytes(buf.getvalue())
    assert not target.exists()
