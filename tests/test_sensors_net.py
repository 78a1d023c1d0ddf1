"""Sensors beyond the front camera: the sensor lists DeepRacer allows, the observation they give, and the networks
DeepRacer pairs with them (common.sensors, common.policy).

The reference is DeepRacer's simulation application, aws-deepracer-community/deepracer-simapp, ``bundle/markov/``:

* allowed lists: ``boto/s3/files/model_metadata.py`` ``parse_model_metadata`` (exactly one camera, at most one
  LiDAR) and ``agents/utils.py`` ``construct_sensor`` (names of ``architecture/constants.py`` ``Input`` only);
* shapes: ``sensors/utils.py`` ``get_observation_space`` (stereo (120, 160, 2); LIDAR 64 values in [0.15, 1];
  SECTOR_LIDAR 8 values in [0, 1]), ``environments/constants.py`` (``TRAINING_LIDAR_SIZE`` 64,
  ``NUMBER_OF_LIDAR_SECTORS`` 8, ``SECTOR_LIDAR_CLIPPING_DIST`` 0.5);
* LiDAR filters: ``sagemaker_graph_manager.py`` (``ObservationClippingFilter(0.15, 1.0)`` for LIDAR,
  ``ObservationSectorDiscretizeFilter(8, 1, 0.5)`` for SECTOR_LIDAR,
  ``filters/observation/observation_sector_discretize_filter.py``);
* layers: ``sensors/utils.py`` ``get_stereo_camera_embedders`` (shallow: conv 32 8/4, 64 4/2, 64 3/1; deep: conv
  32 3/1, 64 3/2, 64 3/1, 128 3/2, 128 3/1), ``get_lidar_embedders`` (dense 256, 256), ``architecture/
  custom_architectures.py`` ``DEFAULT_MIDDLEWARE`` (dense 512); rl_coach ``general_network.py`` concatenates the
  embedders in sorted name order.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import torch
from torch import nn

from common.action_space import NEURAL_NETWORKS, ActionSpaceError, default_action_space, load_action_space
from common.config import PolicyConfig, RunConfig, network_from_metadata
from common.framestack import FrameStack
from common.hyperparams import Hyperparameters
from common.policy import LIDAR_EMBEDDER, ActorCritic, action_space_spec, build_policy
from common.sensors import (
    FRONT_FACING_CAMERA,
    LIDAR,
    SECTOR_LIDAR,
    STEREO_CAMERAS,
    SUPPORTED_COMBINATIONS,
    lidar_from_ranges,
    observation_spec,
    sensor_problem,
)
from common.weights import checkpoint_from_bytes, checkpoint_to_bytes, load_policy
from model_store import LocalStore, RunStore

DISCRETE = {"kind": "discrete", "n": 10}
CONTINUOUS = {"kind": "continuous", "low": [-30.0, 0.5], "high": [30.0, 4.0]}
SMALL = (52, 52)  # small frames the shallow and deep networks take (deep_deep needs 76): fast tests


def _camera(batch: int, shape: tuple[int, ...], seed: int = 0) -> torch.Tensor:
    return torch.from_numpy(np.random.default_rng(seed).integers(0, 256, (batch, *shape), dtype=np.uint8))


def _lidar(batch: int, sensor: str, seed: int = 0) -> torch.Tensor:
    rng = np.random.default_rng(seed)
    if sensor == LIDAR:
        return torch.from_numpy(rng.uniform(0.15, 1.0, (batch, 64)).astype(np.float32))
    return torch.from_numpy(rng.integers(0, 2, (batch, 8)).astype(np.float32))


def _model(sensors, spec=DISCRETE, network="shallow", stack=1, frame=SMALL, **cfg) -> ActorCritic:
    obs = observation_spec(sensors, stack)
    return build_policy(obs.camera_shape(frame), spec, PolicyConfig(network=network, stack_size=stack, **cfg), sensors)


# --- the sensor lists ---------------------------------------------------------------------------------------------


def test_the_six_lists_racer_builds_and_their_observation() -> None:
    assert SUPPORTED_COMBINATIONS == (
        (FRONT_FACING_CAMERA,),
        (FRONT_FACING_CAMERA, LIDAR),
        (FRONT_FACING_CAMERA, SECTOR_LIDAR),
        (STEREO_CAMERAS,),
        (STEREO_CAMERAS, LIDAR),
        (STEREO_CAMERAS, SECTOR_LIDAR),
    )
    expected = {  # (channels per frame, LiDAR size, LiDAR low, LiDAR high): simapp sensors/utils.py
        (FRONT_FACING_CAMERA,): (1, 0, None, None),
        (FRONT_FACING_CAMERA, LIDAR): (1, 64, 0.15, 1.0),
        (FRONT_FACING_CAMERA, SECTOR_LIDAR): (1, 8, 0.0, 1.0),
        (STEREO_CAMERAS,): (2, 0, None, None),
        (STEREO_CAMERAS, LIDAR): (2, 64, 0.15, 1.0),
        (STEREO_CAMERAS, SECTOR_LIDAR): (2, 8, 0.0, 1.0),
    }
    for sensors, (channels, size, low, high) in expected.items():
        for order in (sensors, sensors[::-1]):  # the simapp reads the list in any order
            spec = observation_spec(list(order), stack_size=3)
            assert spec.sensors == sensors and spec.frame_channels == channels
            assert spec.camera_channels == 3 * channels and spec.lidar_size == size
            assert spec.camera_shape((120, 160)) == (120, 160, 3 * channels)
            if size:
                assert (spec.lidar.low, spec.lidar.high) == (low, high)
            else:
                assert spec.lidar is None


@pytest.mark.parametrize(
    ("sensors", "reason"),
    [
        ([], "exactly one camera, this list has 0"),
        ([LIDAR], "exactly one camera, this list has 0"),
        ([SECTOR_LIDAR], "exactly one camera, this list has 0"),
        ([FRONT_FACING_CAMERA, STEREO_CAMERAS], "exactly one camera, this list has 2"),
        ([FRONT_FACING_CAMERA, FRONT_FACING_CAMERA], "exactly one camera, this list has 2"),
        ([STEREO_CAMERAS, LIDAR, SECTOR_LIDAR], "at most one LiDAR, this list has 2"),
        ([STEREO_CAMERAS, LIDAR, LIDAR], "at most one LiDAR, this list has 2"),
        (["LEFT_CAMERA"], "racer does not build LEFT_CAMERA"),  # the simapp has it; the console never offers it
        ([FRONT_FACING_CAMERA, "DISCRETIZED_SECTOR_LIDAR"], "racer does not build DISCRETIZED_SECTOR_LIDAR"),
        ([FRONT_FACING_CAMERA, "RADAR"], '"RADAR" is not a DeepRacer sensor'),
    ],
)
def test_lists_racer_does_not_build_are_refused_with_the_reason(sensors: list[str], reason: str) -> None:
    assert reason in sensor_problem(sensors)
    with pytest.raises(ValueError, match=reason):
        observation_spec(sensors)


@pytest.mark.parametrize("sensors", [list(c) for c in SUPPORTED_COMBINATIONS] + [[LIDAR, STEREO_CAMERAS]])
def test_model_metadata_with_each_allowed_list_loads(tmp_path: Path, sensors: list[str]) -> None:
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": [{"steering_angle": 0, "speed": 1}], "sensor": sensors}))
    assert load_action_space(path).sensor == sensors


def test_model_metadata_with_another_list_is_refused_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": [{"steering_angle": 0, "speed": 1}], "sensor": [LIDAR]}))
    with pytest.raises(ActionSpaceError) as info:
        load_action_space(path)
    message = str(info.value)
    assert 'sensor = ["LIDAR"] is not supported (DeepRacer needs exactly one camera' in message
    assert "model_metadata.json" in message and "\n" not in message
    assert '["STEREO_CAMERAS", "SECTOR_LIDAR"]' in message  # the lists it could use instead


def test_the_version_1_camera_name_is_the_front_camera_in_a_list_too(tmp_path: Path) -> None:
    # simapp sensors_rollout.py: Observation reads the front camera's topic; parse_model_metadata counts it a camera.
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": [{"steering_angle": 0, "speed": 1}], "sensor": ["observation", LIDAR]}))
    assert load_action_space(path).sensor == [FRONT_FACING_CAMERA, LIDAR]


# --- the LiDAR observation as the simapp's filters make it ---------------------------------------------------------


def _simapp_sector_filter(ranges: np.ndarray) -> np.ndarray:
    """The steps of the simapp's ObservationSectorDiscretizeFilter(num_sectors=8, num_values_per_sector=1,
    clipping_dist=0.5).filter, written out as a reference."""
    clip = 0.5
    obs = np.where(np.isinf(ranges), clip, ranges)
    obs = np.min(obs.reshape(-1, obs.shape[0] // 8), axis=1)
    np.minimum(obs, clip, out=obs)
    with np.errstate(invalid="ignore"):
        obs = np.floor(obs / clip).astype(int)
    obs = np.clip(obs, 0, 1)
    one_hot = np.zeros((obs.size, 2))
    one_hot[np.arange(obs.size), obs] = 1
    return np.delete(one_hot, -1, axis=1).reshape(-1).astype(float)


def test_sector_lidar_by_hand_and_against_the_simapp_filter() -> None:
    ranges = np.full(64, 2.0)
    ranges[0:8] = [3, 3, 0.3, 3, 3, 3, 3, 3]  # sector 0: something at 0.3 m → 1
    ranges[8:16] = np.inf  # sector 1: no return → 0
    ranges[16:24] = 0.5  # sector 2: exactly the clipping distance → 0 (floor(0.5 / 0.5) = 1: "nothing")
    ranges[24] = 0.49  # sector 3: just inside → 1
    ranges[32] = np.nan  # sector 4: the filter's integer cast of NaN reads as the nearest bin → 1
    expected = np.array([1, 0, 0, 1, 1, 0, 0, 0], np.float32)
    got = lidar_from_ranges(SECTOR_LIDAR, ranges)
    assert got.dtype == np.float32 and got.shape == (8,)
    np.testing.assert_array_equal(got, expected)
    rng = np.random.default_rng(0)
    for _ in range(200):
        scan = rng.uniform(0.15, 1.2, 64)
        scan[rng.random(64) < 0.2] = np.inf
        np.testing.assert_array_equal(lidar_from_ranges(SECTOR_LIDAR, scan), _simapp_sector_filter(scan))


def test_lidar_is_clipped_to_the_simapp_range() -> None:
    ranges = np.linspace(0.0, 2.0, 64)
    ranges[5] = np.inf
    got = lidar_from_ranges(LIDAR, ranges)
    assert got.dtype == np.float32 and got.shape == (64,)
    np.testing.assert_array_equal(got, np.clip(ranges, 0.15, 1.0).astype(np.float32))
    assert got[0] == np.float32(0.15) and got[5] == 1.0 and got[-1] == 1.0
    with pytest.raises(ValueError, match="64 ranges"):
        lidar_from_ranges(LIDAR, np.ones(63))
    with pytest.raises(ValueError, match="not a LiDAR"):
        lidar_from_ranges(STEREO_CAMERAS, np.ones(64))


def test_stereo_frames_stack_whole_frames_oldest_first() -> None:
    stack = FrameStack(2)
    frames = [np.full((4, 5, 2), 0, np.uint8), np.full((4, 5, 2), 0, np.uint8)]
    frames[0][..., 1], frames[1][..., 0], frames[1][..., 1] = 1, 2, 3  # left₀ = 0, right₀ = 1, left₁ = 2, right₁ = 3
    stack.reset(frames[0])
    obs = stack.push(frames[1])
    assert obs.shape == (4, 5, 4) and list(obs[0, 0]) == [0, 1, 2, 3]
    with pytest.raises(ValueError, match="after frames of"):
        stack.push(np.zeros((4, 5, 1), np.uint8))
    with pytest.raises(ValueError, match="channels"):
        FrameStack(2).reset(np.zeros((4, 5), np.uint8))


# --- the networks ------------------------------------------------------------------------------------------------


def _count(module: nn.Module | None) -> int:
    return sum(p.numel() for p in module.parameters()) if module is not None else 0


def _conv(c_in: int, c_out: int, k: int) -> int:
    return c_in * c_out * k * k + c_out


def _dense(n_in: int, n_out: int) -> int:
    return n_in * n_out + n_out


# The simapp's layers on 120×160 frames, one frame (stack 1), counted by hand (weights + biases).
SHALLOW_CONVS = {  # conv 32 8/4, 64 4/2, 64 3/1 → 64 × 11 × 16 = 11264 features
    1: _conv(1, 32, 8) + _conv(32, 64, 4) + _conv(64, 64, 3),  # 2080 + 32832 + 36928 = 71840
    2: _conv(2, 32, 8) + _conv(32, 64, 4) + _conv(64, 64, 3),  # 4128 + 32832 + 36928 = 73888
}
STEREO_DEEP_CONVS = (  # conv 32 3/1, 64 3/2, 64 3/1, 128 3/2, 128 3/1 → 118×158, 58×78, 56×76, 27×37, 25×35
    _conv(2, 32, 3) + _conv(32, 64, 3) + _conv(64, 64, 3) + _conv(64, 128, 3) + _conv(128, 128, 3)
)  # 608 + 18496 + 36928 + 73856 + 147584 = 277472 → 128 × 25 × 35 = 112000 features
FRONT_DEEP_CONVS = (  # DEEP_CONVOLUTIONAL_NETWORK: conv 32 5/2, 32 3/1, 64 3/2, 64 3/1 → 58×78, 56×76, 27×37, 25×35
    _conv(1, 32, 5) + _conv(32, 32, 3) + _conv(32, 64, 3) + _conv(64, 64, 3)
)  # 832 + 9248 + 18496 + 36928 = 65504 → 64 × 25 × 35 → dense 64 on each pixel → 25 × 35 × 64 = 56000 features
FRONT_DEEP_DEEP_CONVS = (  # …_DEEP: conv 32 8/4, 32 4/2, 64 4/2, 64 3/1 → 29×39, 13×18, 5×8, 3×6
    _conv(1, 32, 8) + _conv(32, 32, 4) + _conv(32, 64, 4) + _conv(64, 64, 3)
)  # 2080 + 16416 + 32832 + 36928 = 88256 → 64 × 3 × 6 → dense 512 → 512 on each pixel → 3 × 6 × 512 = 9216
VGG = (256, 128)
FEATURES = {  # (camera, racer network) → (conv parameters, flattened features, camera dense widths, middleware widths)
    (FRONT_FACING_CAMERA, "shallow"): (SHALLOW_CONVS[1], 64 * 11 * 16, (), (512,)),
    (FRONT_FACING_CAMERA, "deep"): (FRONT_DEEP_CONVS, 64 * 25 * 35, (64,), (512,)),
    (FRONT_FACING_CAMERA, "deep_deep"): (FRONT_DEEP_DEEP_CONVS, 64 * 3 * 6, (512, 512), VGG),
    (STEREO_CAMERAS, "shallow"): (SHALLOW_CONVS[2], 64 * 11 * 16, (), (512,)),
    (STEREO_CAMERAS, "deep"): (STEREO_DEEP_CONVS, 128 * 25 * 35, (), (512,)),
    (STEREO_CAMERAS, "deep_deep"): (STEREO_DEEP_CONVS, 128 * 25 * 35, (), VGG),
}


def _chain(n_in: int, widths: tuple[int, ...]) -> tuple[int, int]:
    """(parameters, output width) of dense layers of ``widths`` after ``n_in`` inputs."""
    total = 0
    for width in widths:
        total, n_in = total + _dense(n_in, width), width
    return total, n_in


LIDAR_EMBEDDERS = {LIDAR: _dense(64, 256) + _dense(256, 256), SECTOR_LIDAR: _dense(8, 256) + _dense(256, 256)}
# 16640 + 65792 = 82432, and 2304 + 65792 = 68096


@pytest.mark.parametrize("neural_network", NEURAL_NETWORKS)
@pytest.mark.parametrize("sensors", SUPPORTED_COMBINATIONS, ids="+".join)
def test_every_allowed_list_builds_with_every_deepracer_network(sensors, neural_network) -> None:
    """On DeepRacer's 120×160 frames: the layer sizes of the simapp, counted by hand, and the output shapes."""
    network = network_from_metadata(neural_network)
    camera, lidar = sensors[0], (sensors[1] if len(sensors) > 1 else None)
    with mock.patch.object(nn.init, "orthogonal_", lambda tensor, gain=1.0: tensor):  # shapes do not need the QR
        model = _model(sensors, network=network, frame=(120, 160))
    convs, features, camera_dense, middleware = FEATURES[camera, network]
    if camera_dense:  # rl_coach's Dense on the 4-D conv output: each pixel's channels in, flattened after
        channels, height, width = model.conv_out_shape
        dense, last = _chain(channels, camera_dense)
        camera_width = height * width * last
    else:
        dense, camera_width = _chain(features, camera_dense)
    merged = camera_width + (LIDAR_EMBEDDER[-1] if lidar else 0)  # the concatenation
    top, hidden = _chain(merged, middleware)
    heads = _dense(hidden, 1) + _dense(hidden, 10)  # value, 10 logits
    assert math.prod(model.conv_out_shape) == features and model.hidden == hidden
    if lidar is None:
        assert model.lidar_size == 0 and model.lidar_embedder is None
        assert _count(model.trunk) == convs + dense + top
    else:
        assert model.lidar_size == {LIDAR: 64, SECTOR_LIDAR: 8}[lidar] and model.trunk is None
        assert _count(model.camera_embedder) == convs + dense
        assert _count(model.lidar_embedder) == LIDAR_EMBEDDERS[lidar]
        assert _count(model.middleware) == top
    assert _count(model) == convs + dense + (LIDAR_EMBEDDERS[lidar] if lidar else 0) + top + heads
    obs = _camera(2, model.obs_shape)
    params, value = model(obs, _lidar(2, lidar) if lidar else None)
    assert params.shape == (2, 10) and value.shape == (2,)


def test_hand_counted_totals() -> None:
    """The sums above, as numbers (stack 1, 10 actions): what the parametrized test asserts, spelled out."""
    assert SHALLOW_CONVS == {1: 71840, 2: 73888} and STEREO_DEEP_CONVS == 277472
    assert FRONT_DEEP_CONVS == 65504 and FRONT_DEEP_DEEP_CONVS == 88256
    assert _chain(56000, (64,)) == (3584064, 64) and _chain(1152, (512, 512)) == (590336 + 262656, 512)
    assert _chain(512 + 256, VGG) == (196864 + 32896, 128)
    assert LIDAR_EMBEDDERS == {LIDAR: 82432, SECTOR_LIDAR: 68096}
    assert _dense(11264, 512) == 5767680 and _dense(11264 + 256, 512) == 5898752
    assert _dense(112000, 512) == 57344512 and _dense(112000 + 256, 512) == 57475584


@pytest.mark.parametrize("sensors", [s for s in SUPPORTED_COMBINATIONS if len(s) == 2], ids="+".join)
@pytest.mark.parametrize("network", ["shallow", "deep"])
def test_a_lidar_only_change_changes_the_output(sensors, network) -> None:
    torch.manual_seed(0)
    model = _model(sensors, network=network, spec=CONTINUOUS)
    obs = _camera(1, model.obs_shape).expand(2, *model.obs_shape)  # the same frames twice
    lidar = _lidar(2, sensors[1], seed=1)
    if sensors[1] == SECTOR_LIDAR:
        lidar = torch.tensor([[0.0] * 8, [1.0] * 8])
    params, value = model(obs, lidar)
    assert not torch.allclose(params[0], params[1]) and value[0] != value[1]
    # and the gradient reaches the LiDAR embedder's first layer
    logp, _, value = model.evaluate(obs, params.detach(), lidar)
    (value.sum() + logp.sum()).backward()
    assert model.lidar_embedder[0].weight.grad.abs().sum() > 0


@pytest.mark.parametrize(
    ("sensors", "lidar_columns"),
    [
        ((FRONT_FACING_CAMERA, LIDAR), slice(-256, None)),  # "FRONT_FACING_CAMERA" < "LIDAR": the LiDAR second
        ((FRONT_FACING_CAMERA, SECTOR_LIDAR), slice(-256, None)),
        ((STEREO_CAMERAS, LIDAR), slice(0, 256)),  # "LIDAR" < "STEREO_CAMERAS": the LiDAR first
        ((STEREO_CAMERAS, SECTOR_LIDAR), slice(0, 256)),  # "SECTOR_LIDAR" < "STEREO_CAMERAS"
    ],
    ids=lambda v: "+".join(v) if isinstance(v, tuple) else "",
)
def test_embeddings_are_concatenated_in_rl_coachs_sorted_order(sensors, lidar_columns) -> None:
    obs_spec = observation_spec(sensors)
    obs = _camera(1, obs_spec.camera_shape(SMALL)).expand(2, *obs_spec.camera_shape(SMALL))
    lidar = torch.tensor([[0.0] * obs_spec.lidar_size, [1.0] * obs_spec.lidar_size])
    for blind, same in ((lidar_columns, True), (_other(lidar_columns), False)):
        torch.manual_seed(0)
        model = _model(sensors)
        with torch.no_grad():
            model.middleware[0].weight[:, blind] = 0.0  # the middleware no longer sees these columns
            params, value = model(obs, lidar)
        assert torch.allclose(params[0], params[1], rtol=1e-6, atol=1e-6) == same
        assert torch.allclose(value[0], value[1], rtol=1e-6, atol=1e-6) == same


def _other(columns: slice) -> slice:
    """The middleware's other 256 columns (the camera's last or first ones)."""
    return slice(0, 256) if columns.start != 0 else slice(-256, None)


def test_stereo_takes_two_channels_per_stacked_frame() -> None:
    model = _model((STEREO_CAMERAS,), stack=2)
    assert model.obs_shape == (*SMALL, 4) and model.trunk[0].in_channels == 4
    with pytest.raises(ValueError, match=r"stack_size=2 × 2 \(STEREO_CAMERAS\)"):
        build_policy((*SMALL, 2), DISCRETE, PolicyConfig(stack_size=2), [STEREO_CAMERAS])


def test_the_lidar_input_is_checked() -> None:
    camera_only, with_lidar = _model((FRONT_FACING_CAMERA,)), _model((FRONT_FACING_CAMERA, LIDAR))
    obs = _camera(2, (*SMALL, 1))
    with pytest.raises(ValueError, match="have no LiDAR"):
        camera_only(obs, _lidar(2, LIDAR))
    with pytest.raises(ValueError, match=r"need a LiDAR batch \(B, 64\)"):
        with_lidar(obs)
    with pytest.raises(TypeError, match="float32"):
        with_lidar(obs, _lidar(2, LIDAR).double())
    with pytest.raises(ValueError, match="expected \\(2, 64\\)"):
        with_lidar(obs, _lidar(2, SECTOR_LIDAR))
    with pytest.raises(ValueError, match="exactly one camera"):
        _model((LIDAR,))


def test_act_numpy_and_bf16_with_a_lidar() -> None:
    torch.manual_seed(3)
    model = _model((STEREO_CAMERAS, SECTOR_LIDAR), network="deep", batch_norm=True, dropout=0.2).eval()
    obs, lidar = _camera(3, model.obs_shape).numpy(), _lidar(3, SECTOR_LIDAR).numpy()
    actions, logp, values = model.act_numpy(obs, lidar=lidar)
    assert actions.shape == (3,) and np.isfinite(logp).all() and np.isfinite(values).all()
    with torch.no_grad():
        logp2, _, values2 = model.evaluate(torch.from_numpy(obs), torch.from_numpy(actions), torch.from_numpy(lidar))
    np.testing.assert_allclose(logp, logp2.numpy(), atol=1e-5)
    np.testing.assert_allclose(values, values2.numpy(), atol=1e-5)
    model.set_trunk_precision("bf16")
    params, value = model(torch.from_numpy(obs), torch.from_numpy(lidar))
    assert params.dtype == value.dtype == torch.float32 and torch.isfinite(params).all()


def test_a_stored_stereo_lidar_checkpoint_loads_for_acting(tmp_path: Path) -> None:
    """load_policy takes the sensors from the action space (model_metadata.json) and the stack from the run."""
    runs = RunStore(LocalStore(tmp_path))
    cfg = PolicyConfig(network="deep", stack_size=2)
    run = RunConfig(run_id="s", hyperparams=Hyperparameters(stack_size=2), policy=cfg)
    runs.write_config(run)
    actions = default_action_space().model_copy(update={"sensor": [LIDAR, STEREO_CAMERAS]})
    torch.manual_seed(5)
    model = _model(actions.sensor, network="deep", stack=2)
    runs.save_checkpoint("s", 0, checkpoint_to_bytes(model.state_dict()), {"env_steps": 0})
    loaded, meta = load_policy(runs, "s", actions, "latest", frame=SMALL)
    assert loaded.obs_shape == (*SMALL, 4) and loaded.lidar_size == 64 and not loaded.training
    state = checkpoint_from_bytes(checkpoint_to_bytes(model.state_dict()))[0]
    assert all(torch.equal(loaded.state_dict()[k], state[k]) for k in state)
    obs, lidar = _camera(2, loaded.obs_shape), _lidar(2, LIDAR)
    model.eval()
    torch.testing.assert_close(loaded(obs, lidar), model(obs, lidar), rtol=0, atol=0)
    # A front-camera network cannot take these weights.
    with pytest.raises(RuntimeError):
        _model((FRONT_FACING_CAMERA,), network="deep", stack=2).load_state_dict(state)
    assert action_space_spec(actions) == DISCRETE  # the sensors travel beside the spec, not in it


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_a_checkpoint_made_for_another_network_is_one_clear_error(tmp_path: Path) -> None:
    """A run whose config names a network its stored weights were not made for (a run from before racer's deep
    networks became the simapp's): load_policy names the run, the checkpoint and the network, in one line."""
    from common.weights import CheckpointError

    runs = RunStore(LocalStore(tmp_path))
    runs.write_config(RunConfig(run_id="old", policy=PolicyConfig(network="deep")))
    shallow = _model((FRONT_FACING_CAMERA,), frame=(120, 160))
    runs.save_checkpoint("old", 3, checkpoint_to_bytes(shallow.state_dict()), {"env_steps": 0})
    with pytest.raises(CheckpointError, match=r"run old checkpoint 3: its weights do not fit a deep network") as err:
        load_policy(runs, "old", default_action_space(), "latest")
    assert "\n" not in str(err.value)
