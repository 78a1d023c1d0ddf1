"""Tests of the actor-critic networks and their serialization (common.policy)."""

from __future__ import annotations

import functools
from unittest import mock

import numpy as np
import pytest
import torch
from pydantic import ValidationError
from torch import nn

from common.action_space import ActionSpace as DeepRacerActionSpace
from common.action_space import ContinuousSpace, Range, default_action_space
from common.policy import (
    HIDDEN,
    ActorCritic,
    PolicyConfig,
    action_space_spec,
    build_policy,
    censored_mean,
    conv_output_shape,
    network_from_metadata,
)

DISCRETE = {"kind": "discrete", "n": 10}
CONTINUOUS = {"kind": "continuous", "low": [-30.0, 0.5], "high": [30.0, 4.0]}
SMALL = (36, 36, 1)  # the smallest frames the shallow trunk takes: fast tests of everything but shapes


def random_frames(batch: int, shape: tuple[int, int, int], seed: int = 0) -> np.ndarray:
    """``batch`` uint8 frames of ``shape``, uniformly random (seeded)."""
    return np.random.default_rng(seed).integers(0, 256, (batch, *shape), dtype=np.uint8)


@functools.cache
def _full_size(network: str, kind: str, stack: int) -> ActorCritic:
    """A model on DeepRacer's 120×160 frames, built once, for shape tests.

    The orthogonal init of the 11264×512 dense layer is a QR costing most of a second, and shapes do not
    depend on it, so it is skipped here (the layers keep torch's default init); test_orthogonal_init_gains
    checks the init on small frames.
    """
    torch.manual_seed(0)
    spec = DISCRETE if kind == "discrete" else CONTINUOUS
    with mock.patch.object(nn.init, "orthogonal_", lambda tensor, gain=1.0: tensor):
        return build_policy((120, 160, stack), spec, PolicyConfig(network=network, stack_size=stack))


# Each network with each action kind, and each with 1 and 2 stacked frames (pairwise, to keep the test fast).
FULL_SIZE = [
    ("shallow", "discrete", 1),
    ("shallow", "continuous", 2),
    ("deep", "discrete", 2),
    ("deep", "continuous", 1),
    ("deep_deep", "discrete", 1),
    ("deep_deep", "continuous", 2),
]


@pytest.mark.parametrize(("network", "kind", "stack"), FULL_SIZE)
def test_output_shapes(network: str, kind: str, stack: int) -> None:
    model = _full_size(network, kind, stack)
    obs = torch.from_numpy(random_frames(3, (120, 160, stack)))
    params, value = model(obs)
    width = 10 if kind == "discrete" else 2
    assert params.shape == (3, width) and value.shape == (3,)
    logp, entropy, value = model.evaluate(obs, model.act(obs)[0])
    assert logp.shape == entropy.shape == value.shape == (3,)


def test_shallow_trunk_is_deepracers() -> None:
    model = _full_size("shallow", "discrete", 1)
    convs = [m for m in model.trunk if isinstance(m, nn.Conv2d)]
    got = [(c.in_channels, c.out_channels, c.kernel_size, c.stride) for c in convs]
    assert got == [(1, 32, (8, 8), (4, 4)), (32, 64, (4, 4), (2, 2)), (64, 64, (3, 3), (1, 1))]
    # 120×160 → (120-8)//4+1 × (160-8)//4+1 = 29×39 → 13×18 → 11×16
    assert model.conv_out_shape == (64, 11, 16)
    (dense,) = [m for m in model.trunk if isinstance(m, nn.Linear)]
    assert (dense.in_features, dense.out_features) == (64 * 11 * 16, HIDDEN) == (11264, 512)


def test_the_deep_networks_are_the_simapps() -> None:
    """simapp markov/sensors/utils.py get_front_camera_embedders and agents/utils.py get_network_settings: the
    DEEP_CONVOLUTIONAL_NETWORK's 4 convs and dense 64 before the middleware's 512; the _DEEP one's 4 convs, dense
    512 → 512, then VGG_MIDDLEWARE's 256 → 128, which the heads read."""
    model = _full_size("deep", "discrete", 2)
    convs = [m for m in model.trunk if isinstance(m, nn.Conv2d)]
    got = [(c.in_channels, c.out_channels, c.kernel_size[0], c.stride[0]) for c in convs]
    assert got == [(2, 32, 5, 2), (32, 32, 3, 1), (32, 64, 3, 2), (64, 64, 3, 1)]
    assert model.conv_out_shape == (64, 25, 35)
    dense = [(m.in_features, m.out_features) for m in model.trunk if isinstance(m, nn.Linear)]
    # The camera's dense 64 acts on each pixel (rl_coach's Dense on the 4-D conv output), flattened after it.
    assert dense == [(64, 64), (25 * 35 * 64, 512)] and model.hidden == 512
    deeper = _full_size("deep_deep", "discrete", 1)
    convs = [m for m in deeper.trunk if isinstance(m, nn.Conv2d)]
    got = [(c.in_channels, c.out_channels, c.kernel_size[0], c.stride[0]) for c in convs]
    assert got == [(1, 32, 8, 4), (32, 32, 4, 2), (32, 64, 4, 2), (64, 64, 3, 1)]
    dense = [(m.in_features, m.out_features) for m in deeper.trunk if isinstance(m, nn.Linear)]
    assert dense == [(64, 512), (512, 512), (3 * 6 * 512, 256), (256, 128)]
    assert deeper.policy_head.in_features == deeper.value_head.in_features == deeper.hidden == 128


def test_conv_output_shape_checks_frame_size() -> None:
    assert conv_output_shape((36, 36, 1), "shallow") == (64, 1, 1)
    with pytest.raises(ValueError, match="too small"):
        conv_output_shape((30, 160, 1), "shallow")


def test_act_numpy_discrete_consistent_with_evaluate() -> None:
    torch.manual_seed(1)
    model = build_policy(SMALL, DISCRETE)
    obs = random_frames(5, SMALL)
    actions, logp, values = model.act_numpy(obs)
    assert actions.dtype == np.int64 and actions.shape == (5,) and ((actions >= 0) & (actions < 10)).all()
    assert logp.dtype == values.dtype == np.float32 and logp.shape == values.shape == (5,)
    with torch.no_grad():
        logp2, _, values2 = model.evaluate(torch.from_numpy(obs), torch.from_numpy(actions))
    np.testing.assert_allclose(logp, logp2.numpy(), atol=1e-5)
    np.testing.assert_allclose(values, values2.numpy(), atol=1e-5)


def test_act_numpy_continuous_consistent_with_evaluate() -> None:
    torch.manual_seed(2)
    model = build_policy(SMALL, CONTINUOUS)
    obs = random_frames(5, SMALL)
    actions, logp, _ = model.act_numpy(obs)
    assert actions.dtype == np.float32 and actions.shape == (5, 2) and np.isfinite(actions).all()
    with torch.no_grad():
        logp2, entropy, _ = model.evaluate(torch.from_numpy(obs), torch.from_numpy(actions))
    np.testing.assert_allclose(logp, logp2.numpy(), atol=1e-4)
    assert torch.isfinite(entropy).all()


def test_continuous_starts_mid_range_with_half_range_std() -> None:
    model = build_policy(SMALL, CONTINUOUS)
    dist = model.distribution(torch.from_numpy(random_frames(4, SMALL)))
    # The 0.01-gain head starts near 0, i.e. near the middle of [-30, 30] and [0.5, 4].
    np.testing.assert_allclose(dist.mean.detach().numpy(), [[0.0, 2.25]] * 4, atol=0.2)
    np.testing.assert_allclose(dist.stddev.detach().numpy(), [[30.0, 1.75]] * 4, rtol=1e-6)


def test_deterministic_act_picks_argmax() -> None:
    model = build_policy(SMALL, DISCRETE)
    obs = random_frames(4, SMALL)
    with torch.no_grad():
        model.policy_head.bias[7] = 5.0  # make action 7 the most likely by far
    actions, logp, _ = model.act_numpy(obs, deterministic=True)
    assert (actions == 7).all()
    logits, _ = model(torch.from_numpy(obs))
    np.testing.assert_array_equal(actions, logits.argmax(-1).numpy())
    np.testing.assert_allclose(logp, torch.log_softmax(logits, -1)[:, 7].detach().numpy(), atol=1e-6)


def test_deterministic_continuous_act_is_the_mean() -> None:
    model = build_policy(SMALL, CONTINUOUS)
    obs = random_frames(2, SMALL)
    actions, _, _ = model.act_numpy(obs, deterministic=True)
    mean, _ = model(torch.from_numpy(obs))
    np.testing.assert_allclose(actions, mean.detach().numpy(), atol=1e-6)


def test_censored_mean_matches_hand_computed_values() -> None:
    # Mean at the lower bound 0 of [0, 10], std 1: a = 0, b = 10, so E = 10 (1 - Φ(10)) + 0 + 1 × (φ(0) - φ(10))
    # = φ(0) = 1/sqrt(2π) = 0.398942 (the half-normal's mean), to 1e-6.
    got = censored_mean(torch.tensor([0.0]), torch.tensor([1.0]), torch.tensor([0.0]), torch.tensor([10.0]))
    assert got.item() == pytest.approx(0.3989423, abs=1e-6)
    # Symmetric range about the mean: E = mean exactly, whatever the std.
    sym = censored_mean(torch.tensor([2.0]), torch.tensor([5.0]), torch.tensor([-1.0]), torch.tensor([5.0]))
    assert sym.item() == pytest.approx(2.0, abs=1e-6)
    # A narrow Gaussian well inside the range: its mean. Far below the range: the lower bound.
    inside = censored_mean(torch.tensor([1.2]), torch.tensor([0.01]), torch.tensor([0.5]), torch.tensor([4.0]))
    below = censored_mean(torch.tensor([-20.0]), torch.tensor([1.0]), torch.tensor([0.5]), torch.tensor([4.0]))
    assert inside.item() == pytest.approx(1.2, abs=1e-6) and below.item() == pytest.approx(0.5, abs=1e-6)


def test_censored_mean_is_the_mean_of_the_clipped_samples() -> None:
    # The speed case the Gazebo bench found (docs/racing.md): a mean below the range, a std of half the range.
    mean, std = torch.tensor([0.99, 20.0]), torch.tensor([1.18, 23.0])
    low, high = torch.tensor([1.5, -25.0]), torch.tensor([4.0, 25.0])
    gen = torch.Generator().manual_seed(0)
    samples = mean + std * torch.randn((400_000, 2), generator=gen)
    clipped = torch.minimum(torch.maximum(samples, low), high).mean(0)
    np.testing.assert_allclose(censored_mean(mean, std, low, high).numpy(), clipped.numpy(), atol=0.02)
    assert censored_mean(mean, std, low, high)[0].item() > 1.5 + 0.2  # well above the clipped mean, 1.5


def test_greedy_expected_takes_the_censored_mean() -> None:
    model = build_policy(SMALL, CONTINUOUS, PolicyConfig(greedy_action="expected"))
    obs = random_frames(3, SMALL)
    with torch.no_grad():
        model.policy_head.bias.copy_(torch.tensor([0.0, -2.0]))  # speed mean 2.25 - 2 × 1.75 = -1.25, below 0.5
    actions, _, _ = model.act_numpy(obs, deterministic=True)
    mean, _ = model(torch.from_numpy(obs))
    std = model.action_half * model.log_std.exp()
    low, high = torch.tensor([-30.0, 0.5]), torch.tensor([30.0, 4.0])
    np.testing.assert_allclose(actions, censored_mean(mean, std, low, high).detach().numpy(), atol=1e-5)
    assert (mean[:, 1] < 0.5).all() and (actions[:, 1] > 0.5).all() and (actions[:, 1] < 4.0).all()
    # DeepRacer's rule on the same weights: the mean itself, which the env would clip to 0.5.
    plain = build_policy(SMALL, CONTINUOUS)
    plain.load_state_dict(model.state_dict())
    np.testing.assert_allclose(plain.act_numpy(obs, deterministic=True)[0], mean.detach().numpy(), atol=1e-6)


def test_greedy_expected_holds_a_zero_width_range_at_its_value() -> None:
    """A range with no width (a fixed speed) keeps a unit scale for the Gaussian; its greedy action is still the
    value the env would clip every draw to. The range is not in the state dict: older checkpoints load unchanged."""
    fixed = {"kind": "continuous", "low": [-30.0, 2.0], "high": [30.0, 2.0]}
    model = build_policy(SMALL, fixed, PolicyConfig(greedy_action="expected"))
    with torch.no_grad():
        model.policy_head.bias[1] = 0.5  # the speed's Gaussian at 2.5 m/s, std 1 (the unit scale): off the range
    actions, _, _ = model.act_numpy(random_frames(3, SMALL), deterministic=True)
    np.testing.assert_allclose(actions[:, 1], 2.0, atol=1e-6)
    assert "action_low" not in model.state_dict() and "action_high" not in model.state_dict()


def test_orthogonal_init_gains() -> None:
    model = build_policy(SMALL, DISCRETE)
    # An orthogonal (out, in) matrix with out <= in and gain g has rows of norm g.
    rows = model.policy_head.weight.norm(dim=1)
    np.testing.assert_allclose(rows.detach().numpy(), 0.01, rtol=1e-4)
    np.testing.assert_allclose(model.value_head.weight.norm().item(), 1.0, rtol=1e-4)
    assert all(not m.bias.detach().any() for m in model.modules() if isinstance(m, nn.Linear | nn.Conv2d))


def test_batch_norm_and_dropout_flags() -> None:
    def kinds(cfg: PolicyConfig) -> set[type]:
        return {type(m) for m in build_policy(SMALL, DISCRETE, cfg).modules()}

    assert not kinds(PolicyConfig()) & {nn.BatchNorm2d, nn.Dropout}
    with_bn = build_policy(SMALL, DISCRETE, PolicyConfig(batch_norm=True))
    assert sum(isinstance(m, nn.BatchNorm2d) for m in with_bn.modules()) == 3  # one after each conv
    assert nn.Dropout in kinds(PolicyConfig(dropout=0.2))
    model = build_policy(SMALL, DISCRETE, PolicyConfig(batch_norm=True, dropout=0.2)).eval()
    actions, logp, values = model.act_numpy(random_frames(2, SMALL))
    assert np.isfinite(logp).all() and np.isfinite(values).all()


def test_network_from_metadata() -> None:
    assert network_from_metadata("DEEP_CONVOLUTIONAL_NETWORK_SHALLOW") == "shallow"
    assert network_from_metadata("DEEP_CONVOLUTIONAL_NETWORK") == "deep"
    assert network_from_metadata("DEEP_CONVOLUTIONAL_NETWORK_DEEP") == "deep_deep"
    with pytest.raises(ValueError, match="unknown neural_network"):
        network_from_metadata("RESNET")


def test_action_space_spec_from_deepracer_metadata() -> None:
    assert action_space_spec(default_action_space()) == {"kind": "discrete", "n": 10}
    space = DeepRacerActionSpace(
        action_space_type="continuous",
        action_space=ContinuousSpace(steering_angle=Range(low=-30, high=30), speed=Range(low=0.5, high=4)),
    )
    assert action_space_spec(space) == CONTINUOUS


def test_bad_inputs_rejected() -> None:
    with pytest.raises(ValidationError):
        PolicyConfig(netwrok="deep")
    with pytest.raises(ValueError, match="stack_size"):
        build_policy((120, 160, 2), DISCRETE)  # stack_size defaults to 1
    with pytest.raises(ValueError, match="kind"):
        build_policy(SMALL, {"kind": "multi"})
    with pytest.raises(ValueError, match="n_actions"):
        ActorCritic(SMALL, "discrete", n_actions=0)
    with pytest.raises(ValueError, match="bounds"):
        build_policy(SMALL, {"kind": "continuous", "low": [1.0], "high": [0.0]})
    model = build_policy(SMALL, DISCRETE)
    with pytest.raises(TypeError, match="uint8"):
        model(torch.zeros(1, *SMALL))
    with pytest.raises(ValueError, match="shape"):
        model(torch.zeros(1, 40, 36, 1, dtype=torch.uint8))


def test_a_front_camera_network_keeps_the_state_dict_of_checkpoints_before_lidar() -> None:
    """Old checkpoints load: a camera-only network is one ``trunk`` Sequential (convs, Flatten, [Dropout], dense 512)
    with the same keys and shapes as before other sensors existed; the sensors default to the front camera."""
    shallow = build_policy(SMALL, CONTINUOUS)
    assert shallow.spec.sensors == ("FRONT_FACING_CAMERA",) and shallow.lidar_size == 0
    assert {k: tuple(v.shape) for k, v in shallow.state_dict().items()} == {
        "trunk.0.weight": (32, 1, 8, 8),
        "trunk.0.bias": (32,),
        "trunk.2.weight": (64, 32, 4, 4),
        "trunk.2.bias": (64,),
        "trunk.4.weight": (64, 64, 3, 3),
        "trunk.4.bias": (64,),
        "trunk.7.weight": (512, 64),  # after Flatten (5) and ReLU (6): 64 × 1 × 1 features on 36×36 frames
        "trunk.7.bias": (512,),
        "value_head.weight": (1, 512),
        "value_head.bias": (1,),
        "action_mid": (2,),
        "action_half": (2,),
        "policy_head.weight": (2, 512),
        "policy_head.bias": (2,),
        "log_std": (2,),
    }
    with_dropout = build_policy(SMALL, DISCRETE, PolicyConfig(dropout=0.2))
    assert "trunk.8.weight" in with_dropout.state_dict()  # Dropout (7) before the dense layer, as before
    assert build_policy(SMALL, DISCRETE, sensors=["FRONT_FACING_CAMERA"]).state_dict().keys() == (
        build_policy(SMALL, DISCRETE).state_dict().keys()
    )


# --- the acting copy: what rollout workers download per policy version ----------------------------------------------


def test_pixel_dense_maps_each_pixels_channels() -> None:
    """rl_coach's Keras Dense on a (B, H, W, C) conv output: the same (units, C) matrix on every pixel."""
    from common.policy import PixelDense

    torch.manual_seed(0)
    layer = PixelDense(3, 2)
    x = torch.randn(2, 3, 4, 5)
    expected = torch.einsum("nchw,oc->nohw", x, layer.weight) + layer.bias[None, :, None, None]
    y = layer(x)
    assert y.shape == (2, 2, 4, 5) and torch.allclose(y, expected, atol=1e-6)
    # One pixel's output depends on that pixel's channels only.
    x2 = x.clone()
    x2[:, :, 0, 0] += 1.0
    changed = (layer(x2) - y).abs().sum(dim=1) > 0
    assert changed[:, 0, 0].all() and changed.sum() == 2
