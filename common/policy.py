"""The actor-critic networks, shared by the trainer and the rollout workers.

Observations are uint8 camera frames of shape (B, H, W, C), channels last as the env produces them, with
C = stack_size stacked grayscale frames (2 × stack_size for the stereo pair: left, right of each frame), plus,
when the run's sensors include a LiDAR, a float32 vector (B, N) (``common.sensors.observation_spec``). The network
scales the frames to [0, 1] and moves channels first itself; the LiDAR values go in as they are, as in DeepRacer.

The networks are the simapp's (aws-deepracer-community/deepracer-simapp, ``bundle/markov/``), one per model_metadata
``neural_network`` and camera. ``agents/utils.py: get_network_settings`` builds every part with
``EmbedderType.SCHEME`` (``architecture/embedder_factory.py: create_scheme``: the listed convs, then the listed dense
layers, each with ReLU; the scheme's batch-norm, dropout and tanh entries are not used) and the middleware
``VGG_MIDDLEWARE`` for DEEP_CONVOLUTIONAL_NETWORK_DEEP, else ``DEFAULT_MIDDLEWARE``
(``architecture/custom_architectures.py``). Convs are (filters, kernel/stride), valid padding:

* ``shallow`` (DEEP_CONVOLUTIONAL_NETWORK_SHALLOW), front camera and stereo pair alike (``sensors/utils.py:
  get_front_camera_embedders``, ``get_stereo_camera_embedders``): conv 32 8/4 → 64 4/2 → 64 3/1, middleware dense
  512. On 120×160 frames the last conv gives 64×11×16 = 11264 features.
* ``deep`` (DEEP_CONVOLUTIONAL_NETWORK): front camera conv 32 5/2 → 32 3/1 → 64 3/2 → 64 3/1 (64×25×35) → dense 64
  on each pixel (25×35×64 = 56000 features); stereo conv 32 3/1 → 64 3/2 → 64 3/1 → 128 3/2 → 128 3/1
  (128×25×35 = 112000); middleware dense 512.
* ``deep_deep`` (DEEP_CONVOLUTIONAL_NETWORK_DEEP): front camera conv 32 8/4 → 32 4/2 → 64 4/2 → 64 3/1 (64×3×6) →
  dense 512 → 512 on each pixel (3×6×512 = 9216 features); stereo as ``deep``; middleware dense 256 → 128
  (``VGG_MIDDLEWARE``).
* A camera embedder's dense layers act on each pixel of the last conv's output: rl_coach builds them as Keras
  ``Dense`` on the 4-D (B, H, W, C) tensor, which maps the last axis, and flattens only after its last layer
  (``embedders/embedder.py: InputEmbedder._build_module``); racer's :class:`PixelDense`.
* LIDAR / SECTOR_LIDAR (``sensors/utils.py: get_lidar_embedders``, the same for every ``neural_network``): dense
  256 → dense 256.
* The embeddings are concatenated in the sorted order of the sensor names (rl_coach
  ``architectures/tensorflow_components/general_network.py``: ``for input_name in sorted(...)``, ``tf.concat(...,
  name="merger")``), so the front camera's before the LiDAR's and the LiDAR's before the stereo pair's, then the
  middleware and the heads, which read the middleware's last layer (512 units, or 128 for ``deep_deep``).
  rl_coach's clipped PPO also gives the value and the policy separate copies of this network
  (``use_separate_networks_per_head``); racer's heads share one.

racer's options (off in DeepRacer's files): BatchNorm2d after each conv (before its ReLU) and Dropout before the
middleware. The policy head gives
logits of a Categorical (discrete) or the mean of a diagonal Gaussian (continuous) whose log-std is a learned
state-independent parameter. Continuous actions are in the env's units and are not squashed or clipped by the
distribution: the env clips them. The Gaussian's mean is mid + half * head(h) and its std half * exp(log_std),
with mid and half the centre and half-width of the action range, so one initialization suits degrees and m/s. Acting
greedily, a continuous policy takes its mean (DeepRacer) or, with the ``greedy_action`` hyperparameter
``expected``, the mean of the clipped action (:func:`censored_mean`).

A camera-only network keeps one ``trunk`` (convs, camera dense layers, middleware), so a shallow network's state
dict is the same as before LiDAR existed; a network with a LiDAR has ``camera_embedder`` (convs, camera dense
layers), ``lidar_embedder`` and ``middleware`` instead.

Checkpoint files (the network's weights as bytes, and loading them back) are ``common.weights``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch
from torch import nn
from torch.distributions import Categorical, Distribution, Independent, Normal

# The architecture's config lives in common.config (no torch), so that processes that only read configs
# (racer train's launcher) start without importing torch; re-exported here, where the network is built.
from common.config import (  # noqa: F401
    FRAME_HEIGHT,
    FRAME_WIDTH,
    NetworkName,
    PolicyConfig,
    RunConfig,
    network_from_metadata,
)
from common.privileged import STATE_SIZE
from common.sensors import FRONT_FACING_CAMERA, STEREO_CAMERAS, ObsSpec, observation_spec

Precision = Literal["fp32", "bf16", "fp16"]
ActionKind = Literal["discrete", "continuous"]

HIDDEN = 512
"""Width of ``DEFAULT_MIDDLEWARE``'s dense layer (the heads' input but for ``deep_deep``), units."""
LIDAR_EMBEDDER: tuple[int, ...] = (256, 256)
"""Widths of the LiDAR embedder's dense layers (simapp markov/sensors/utils.py ``get_lidar_embedders``), units."""


@dataclass(frozen=True)
class Topology:
    """One of the simapp's networks for one camera (module docstring)."""

    convs: tuple[tuple[int, int, int], ...]
    """(out_channels, kernel, stride) of each conv layer."""
    camera_dense: tuple[int, ...] = ()
    """The camera embedder's dense layers after the convs, units, each on every pixel (:class:`PixelDense`)."""
    middleware: tuple[int, ...] = (HIDDEN,)
    """The middleware's dense layers after the merger, units; the last is the heads' input."""


_SHALLOW = ((32, 8, 4), (64, 4, 2), (64, 3, 1))
_STEREO_DEEP = ((32, 3, 1), (64, 3, 2), (64, 3, 1), (128, 3, 2), (128, 3, 1))
_VGG_MIDDLEWARE = (256, 128)
# simapp markov/sensors/utils.py get_front_camera_embedders / get_stereo_camera_embedders, agents/utils.py
TOPOLOGIES: dict[tuple[str, NetworkName], Topology] = {
    (FRONT_FACING_CAMERA, "shallow"): Topology(_SHALLOW),
    (FRONT_FACING_CAMERA, "deep"): Topology(((32, 5, 2), (32, 3, 1), (64, 3, 2), (64, 3, 1)), (64,)),
    (FRONT_FACING_CAMERA, "deep_deep"): Topology(
        ((32, 8, 4), (32, 4, 2), (64, 4, 2), (64, 3, 1)), (512, 512), _VGG_MIDDLEWARE
    ),
    (STEREO_CAMERAS, "shallow"): Topology(_SHALLOW),
    (STEREO_CAMERAS, "deep"): Topology(_STEREO_DEEP),
    (STEREO_CAMERAS, "deep_deep"): Topology(_STEREO_DEEP, (), _VGG_MIDDLEWARE),
}
"""The network of each (camera, ``neural_network``)."""


def conv_output_shape(
    obs_shape: tuple[int, int, int], network: NetworkName, camera: str = FRONT_FACING_CAMERA
) -> tuple[int, int, int]:
    """(channels, height, width) of the last convolution's output for (H, W, C) frames (valid padding, as rl_coach's
    Keras ``Conv2D``)."""
    layers = TOPOLOGIES[camera, network].convs
    h, w = obs_shape[0], obs_shape[1]
    for _, kernel, stride in layers:
        h, w = (h - kernel) // stride + 1, (w - kernel) // stride + 1
        if h < 1 or w < 1:
            raise ValueError(f"frames of {obs_shape[0]}×{obs_shape[1]} are too small for the {network} network")
    return layers[-1][0], h, w


def _init(layer: nn.Module, gain: float) -> nn.Module:
    """Orthogonal weights and zero biases, as in CleanRL's ``layer_init``."""
    nn.init.orthogonal_(layer.weight, gain)
    nn.init.zeros_(layer.bias)
    return layer


def _conv_trunk(in_channels: int, cfg: PolicyConfig, camera: str = FRONT_FACING_CAMERA) -> list[nn.Module]:
    """The convolutions of ``cfg.network`` for ``camera``, each with optional BatchNorm2d and a ReLU."""
    layers: list[nn.Module] = []
    for out_channels, kernel, stride in TOPOLOGIES[camera, cfg.network].convs:
        layers.append(_init(nn.Conv2d(in_channels, out_channels, kernel, stride), math.sqrt(2)))
        if cfg.batch_norm:
            layers.append(nn.BatchNorm2d(out_channels))
        layers.append(nn.ReLU())
        in_channels = out_channels
    return layers


class PixelDense(nn.Linear):
    """A dense layer on each pixel's channels of an (N, C, H, W) map, giving (N, units, H, W): rl_coach's Keras
    ``Dense`` on a camera embedder's 4-D conv output (module docstring). Its weight is a ``Linear``'s (units, C)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(x.permute(0, 2, 3, 1)).permute(0, 3, 1, 2)


def _dense(in_features: int, widths: Sequence[int], layer: type[nn.Linear] = nn.Linear) -> list[nn.Module]:
    """Dense layers (``layer``) of ``widths``, each with a ReLU."""
    layers: list[nn.Module] = []
    for width in widths:
        layers += [_init(layer(in_features, width), math.sqrt(2)), nn.ReLU()]
        in_features = width
    return layers


class PolicyNetwork(nn.Module):
    """What every racer policy network is: a trunk giving ``hidden`` features of an observation, a policy head and a
    value head. ``forward`` returns the distribution parameters (logits, or the Gaussian mean in env units) and V(o).
    For networks with dropout or batch norm, rollout workers should call ``eval()`` before acting.

    Subclasses set ``obs_shape``, ``obs_dtype``, ``lidar_size``, ``action_kind``, ``cfg``, ``hidden`` and
    ``trunk_dtype``, call ``_build_policy_head`` and write ``features``."""

    obs_shape: tuple[int, ...]
    """One observation's shape: (H, W, C) camera frames, or (D,) for a state vector."""
    obs_dtype: torch.dtype = torch.uint8
    """The observations' dtype: uint8 camera frames, or float32 state vectors."""
    lidar_size: int = 0

    def features(self, obs: torch.Tensor, lidar: torch.Tensor | None = None) -> torch.Tensor:
        """The trunk's float32 (B, hidden) features of a batch of observations."""
        raise NotImplementedError

    def _build_policy_head(
        self, n_actions: int | None, low: tuple[float, ...] | None, high: tuple[float, ...] | None
    ) -> int:
        """Create ``policy_head`` (and for continuous actions the Gaussian's scale); return the head's width."""
        if self.action_kind == "discrete":
            if n_actions is None or n_actions < 1:
                raise ValueError(f"a discrete policy needs n_actions >= 1, got {n_actions}")
            self.policy_head = _init(nn.Linear(self.hidden, n_actions), 0.01)
            return n_actions
        if self.action_kind != "continuous":
            raise ValueError(f"action_kind must be 'discrete' or 'continuous', got {self.action_kind!r}")
        if low is None or high is None or len(low) != len(high) or not low:
            raise ValueError(f"a continuous policy needs action_low and action_high of one length, got {low}, {high}")
        lo, hi = torch.tensor(low, dtype=torch.float32), torch.tensor(high, dtype=torch.float32)
        if not (torch.isfinite(lo).all() and torch.isfinite(hi).all() and (lo <= hi).all()):
            raise ValueError(f"action bounds are not finite and ordered: low {low}, high {high}")
        # The head works in units of half the range, centred on the range: with the 0.01 init the initial
        # mean is mid-range and the initial std (exp(0) = 1) half the range, whatever the units.
        half = (hi - lo) / 2  # a zero-width range (low == high) gets a unit scale: a Normal needs std > 0
        self.register_buffer("action_mid", (hi + lo) / 2)
        self.register_buffer("action_half", torch.where(half > 0, half, torch.ones_like(half)))
        # The range itself, for the greedy action's clipping (action_half is 1 where the range has no width). Not in
        # the state dict, so checkpoints from before it load as they are.
        self.register_buffer("action_low", lo, persistent=False)
        self.register_buffer("action_high", hi, persistent=False)
        self.policy_head = _init(nn.Linear(self.hidden, len(low)), 0.01)
        self.log_std = nn.Parameter(torch.zeros(len(low)))
        return len(low)

    def set_trunk_precision(self, precision: Precision) -> None:
        """Run the convolutions and the dense layer in ``bf16`` or ``fp16`` (autocast on the input's device: the
        weights stay float32) or ``fp32``.

        The heads, the distributions and the losses stay float32 either way: bf16's 8-bit mantissa is fine for
        features but would put ~0.4 % noise on the logits, hence on PPO's probability ratios. fp16's gradients need
        loss scaling (``trainer.precision.grad_scaler``); it is meant for GPUs without bf16.
        """
        dtypes = {"fp32": None, "bf16": torch.bfloat16, "fp16": torch.float16}
        if precision not in dtypes:
            raise ValueError(f"precision must be 'fp32', 'bf16' or 'fp16', got {precision!r}")
        self.trunk_dtype = dtypes[precision]

    def forward(self, obs: torch.Tensor, lidar: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(logits (B, n) or Gaussian mean (B, d) in env units, V(o) (B,)) of a uint8 (B, H, W, C) batch (and its
        float32 (B, N) LiDAR batch for a network with a LiDAR)."""
        h = self.features(obs, lidar)
        params = self.policy_head(h)
        if self.action_kind == "continuous":
            params = self.action_mid + self.action_half * params
        return params, self.value_head(h).squeeze(-1)

    def action_distribution(self, params: torch.Tensor) -> Distribution:
        """The action distribution for ``forward``'s parameters: Categorical over action indices, or Independent(Normal)
        over actions in env units with this network's standard deviation."""
        return self._dist(params)

    def labels(self, params: torch.Tensor) -> torch.Tensor:
        """``forward``'s parameters as a distilling run's label rows (``label_distribution`` reads them back): the
        logits (B, n), or the Gaussian's means then its standard deviations (B, 2d)."""
        params = params.detach().float()
        if self.action_kind == "discrete":
            return params
        return torch.cat([params, self._std().detach().expand_as(params)], dim=-1)

    def _dist(self, params: torch.Tensor) -> Distribution:
        """The action distribution for ``forward``'s parameters."""
        if self.action_kind == "discrete":
            return Categorical(logits=params)
        return Independent(Normal(params, self._std().expand_as(params)), 1)

    def _std(self) -> torch.Tensor:
        """The Gaussian's standard deviation in the env's units, one per action dimension."""
        return self.action_half * self.log_std.exp()

    def greedy(self, params: torch.Tensor) -> torch.Tensor:
        """The greedy action: the argmax of the logits; for continuous actions the Gaussian's mean, or with
        ``greedy_action`` ``expected`` the mean of the action the env executes (:func:`censored_mean`)."""
        if self.action_kind == "discrete":
            return params.argmax(-1)
        if self.cfg.greedy_action == "expected":
            return censored_mean(params, self._std(), self.action_low, self.action_high)
        return params

    def distribution(self, obs: torch.Tensor, lidar: torch.Tensor | None = None) -> Distribution:
        """π(·|o): Categorical over action indices, or Independent(Normal) over actions in env units."""
        return self._dist(self(obs, lidar)[0])

    @torch.no_grad()
    def act(
        self, obs: torch.Tensor, deterministic: bool = False, lidar: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(action, log π(action|o), V(o)) for a uint8 batch (and its LiDAR batch); deterministic = the greedy action
        (:meth:`greedy`)."""
        params, value = self(obs, lidar)
        return self.act_from(params, value, deterministic)

    @torch.no_grad()
    def act_from(
        self, params: torch.Tensor, value: torch.Tensor, deterministic: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``act`` from ``forward``'s outputs (params, value), for a forward pass run elsewhere (the rollout worker's
        ONNX Runtime copy of this network): the action drawn from this network's distribution, its log-probability."""
        dist = self._dist(params)
        action = self.greedy(params) if deterministic else dist.sample()
        return action, dist.log_prob(action), value

    def act_numpy(
        self, obs: np.ndarray, deterministic: bool = False, lidar: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``act`` on a numpy uint8 (B, H, W, C) batch (and, with a LiDAR, its float32 (B, N) batch): (int64 (B,) or
        float32 (B, d) actions, float32 log-probs, float32 values)."""
        if obs.ndim != len(self.obs_shape) + 1:
            raise ValueError(f"act_numpy takes a batch (B, *{self.obs_shape}), got shape {obs.shape}")
        device = self.value_head.weight.device
        lidar_t = None if lidar is None else torch.from_numpy(np.ascontiguousarray(lidar)).to(device)
        obs_t = torch.from_numpy(np.ascontiguousarray(obs)).to(device)
        return self._numpy_outputs(*self.act(obs_t, deterministic, lidar_t))

    def act_numpy_from(
        self, params: np.ndarray, value: np.ndarray, deterministic: bool = False
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``act_from`` on numpy float32 ``forward`` outputs, returning what ``act_numpy`` returns."""
        return self._numpy_outputs(*self.act_from(torch.from_numpy(params), torch.from_numpy(value), deterministic))

    def _numpy_outputs(
        self, action: torch.Tensor, logp: torch.Tensor, value: torch.Tensor
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``act``'s tensors as numpy: int64 (B,) or float32 (B, d) actions, float32 log-probs and values."""
        action, logp, value = action.cpu(), logp.cpu(), value.cpu()
        action_np = action.numpy().astype(np.int64 if self.action_kind == "discrete" else np.float32)
        return action_np, logp.numpy().astype(np.float32), value.numpy().astype(np.float32)

    def evaluate(
        self, obs: torch.Tensor, actions: torch.Tensor, lidar: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(log π(actions|o), entropy of π(·|o), V(o)), each (B,), with gradients, for the trainer."""
        params, value = self(obs, lidar)
        dist = self._dist(params)
        return dist.log_prob(actions), dist.entropy(), value


class ActorCritic(PolicyNetwork):
    """DeepRacer's network: a shared trunk (camera CNN, with a LiDAR: camera CNN + LiDAR embedder + middleware) with a
    policy head and a value head (``PolicyNetwork``)."""

    def __init__(
        self,
        obs_shape: tuple[int, int, int],
        action_kind: ActionKind,
        n_actions: int | None = None,
        action_low: tuple[float, ...] | None = None,
        action_high: tuple[float, ...] | None = None,
        cfg: PolicyConfig | None = None,
        sensors: Sequence[str] | None = None,
    ) -> None:
        super().__init__()
        cfg = cfg or PolicyConfig()
        self.spec: ObsSpec = observation_spec((FRONT_FACING_CAMERA,) if sensors is None else sensors, cfg.stack_size)
        """The sensors and the observation they give (camera channels, LiDAR size)."""
        self.obs_shape = tuple(int(v) for v in obs_shape)
        if len(self.obs_shape) != 3 or self.obs_shape[2] != self.spec.camera_channels:
            per_frame = "" if self.spec.frame_channels == 1 else f" × {self.spec.frame_channels} ({self.spec.camera})"
            raise ValueError(f"obs_shape {obs_shape} is not (H, W, stack_size={cfg.stack_size}{per_frame})")
        self.lidar_size = self.spec.lidar_size
        self.action_kind = action_kind
        self.cfg = cfg
        camera = self.spec.camera
        convs = _conv_trunk(self.obs_shape[2], cfg, camera)
        self.conv_out_shape = conv_output_shape(self.obs_shape, cfg.network, camera)
        dropout: list[nn.Module] = [nn.Dropout(cfg.dropout)] if cfg.dropout > 0 else []
        topology = TOPOLOGIES[camera, cfg.network]
        flat = math.prod(self.conv_out_shape)
        # The last ReLU goes after the Flatten (they commute; neither has parameters, so the state dict's indices
        # stay). The convolutions run channels-last (the frames arrive (B, H, W, C)) and Flatten copies to
        # (C, H, W) order: a ReLU on its contiguous output keeps the ReLU's backward on one layout, where before the
        # Flatten it read the channels-last output against the dense layer's (C, H, W) gradient, a strided pass of
        # 2.5 ms in a 76 ms bf16 minibatch step (one core; docs/speed.md).
        if topology.camera_dense:
            channels, height, width = self.conv_out_shape
            camera_part = [*convs, *_dense(channels, topology.camera_dense, PixelDense), nn.Flatten()]
            camera_width = topology.camera_dense[-1] * height * width
        else:
            camera_part = [*convs[:-1], nn.Flatten(), convs[-1]]
            camera_width = flat
        self.hidden = topology.middleware[-1]
        """Width of the heads' input, units."""
        if not self.lidar_size:
            # Camera only: one Sequential, whose state dict keys are those of every checkpoint before LiDAR.
            self.trunk = nn.Sequential(*camera_part, *dropout, *_dense(camera_width, topology.middleware))
            self.camera_embedder = self.lidar_embedder = self.middleware = None
        else:
            self.trunk = None
            self.camera_embedder = nn.Sequential(*camera_part)
            self.lidar_embedder = nn.Sequential(*_dense(self.lidar_size, LIDAR_EMBEDDER))
            merged = camera_width + LIDAR_EMBEDDER[-1]
            self.middleware = nn.Sequential(*dropout, *_dense(merged, topology.middleware))
            # rl_coach concatenates the embeddings in the sorted order of the input names.
            self._lidar_first = self.spec.lidar.name < camera
        self.value_head = _init(nn.Linear(self.hidden, 1), 1.0)
        self.action_dim = self._build_policy_head(n_actions, action_low, action_high)
        self.trunk_dtype: torch.dtype | None = None
        """None = float32; torch.bfloat16 or torch.float16 = the trunk under autocast (``set_trunk_precision``)."""

    def features(self, obs: torch.Tensor, lidar: torch.Tensor | None = None) -> torch.Tensor:
        """The trunk's ``hidden`` features (float32) of a uint8 (B, H, W, C) batch and, for a network with a LiDAR, its
        float32 (B, N) LiDAR vectors."""
        if obs.dtype != torch.uint8:
            raise TypeError(f"observations must be uint8 camera frames, got {obs.dtype}")
        if tuple(obs.shape[1:]) != self.obs_shape:
            raise ValueError(f"observations of shape {tuple(obs.shape)}, expected (B, *{self.obs_shape})")
        self._check_lidar(obs, lidar)
        x = obs.permute(0, 3, 1, 2).float() / 255.0
        if self.trunk_dtype is None:
            return self._embed(x, lidar)
        with torch.autocast(x.device.type, dtype=self.trunk_dtype):
            return self._embed(x, lidar).float()

    def _check_lidar(self, obs: torch.Tensor, lidar: torch.Tensor | None) -> None:
        """A LiDAR batch is given exactly when the network has a LiDAR, float32 (B, N)."""
        if not self.lidar_size:
            if lidar is not None:
                raise ValueError(f"this network's sensors {list(self.spec.sensors)} have no LiDAR, got a LiDAR batch")
            return
        if lidar is None:
            sensors = list(self.spec.sensors)
            raise ValueError(f"this network's sensors {sensors} need a LiDAR batch (B, {self.lidar_size})")
        if lidar.dtype != torch.float32:
            raise TypeError(f"LiDAR vectors must be float32, got {lidar.dtype}")
        if tuple(lidar.shape) != (obs.shape[0], self.lidar_size):
            raise ValueError(f"LiDAR batch of shape {tuple(lidar.shape)}, expected ({obs.shape[0]}, {self.lidar_size})")

    def _embed(self, x: torch.Tensor, lidar: torch.Tensor | None) -> torch.Tensor:
        """The trunk on scaled channels-first frames (and the LiDAR vectors)."""
        if self.trunk is not None:
            return self.trunk(x)
        parts = [self.camera_embedder(x), self.lidar_embedder(lidar)]
        return self.middleware(torch.cat(parts[::-1] if self._lidar_first else parts, dim=-1))


STATE_HIDDEN: tuple[int, ...] = (256, 256)
"""Widths of a privileged teacher's dense layers (``StatePolicy``), units: the LiDAR embedder's, on a vector a tenth
its size."""


class StatePolicy(PolicyNetwork):
    """A privileged teacher's network (``racer train --teacher``): dense layers on the car's state vector
    (``common.privileged.state_vector``, float32 (B, D)), then the heads of every racer network. No camera: a step
    costs a few microseconds of matrix products, so the teacher learns the race from thousands of steps a second."""

    obs_dtype = torch.float32

    def __init__(
        self,
        state_size: int,
        action_kind: ActionKind,
        n_actions: int | None = None,
        action_low: tuple[float, ...] | None = None,
        action_high: tuple[float, ...] | None = None,
        cfg: PolicyConfig | None = None,
    ) -> None:
        super().__init__()
        self.cfg = cfg or PolicyConfig()
        self.obs_shape = (int(state_size),)
        self.action_kind = action_kind
        self.trunk = nn.Sequential(*_dense(self.obs_shape[0], STATE_HIDDEN))
        self.hidden = STATE_HIDDEN[-1]
        self.value_head = _init(nn.Linear(self.hidden, 1), 1.0)
        self.action_dim = self._build_policy_head(n_actions, action_low, action_high)
        self.trunk_dtype: torch.dtype | None = None

    def features(self, obs: torch.Tensor, lidar: torch.Tensor | None = None) -> torch.Tensor:
        """The trunk's ``hidden`` features (float32) of a float32 (B, D) batch of state vectors."""
        if obs.dtype != torch.float32:
            raise TypeError(f"state vectors must be float32, got {obs.dtype}")
        if tuple(obs.shape[1:]) != self.obs_shape or lidar is not None:
            raise ValueError(
                f"a state network takes (B, {self.obs_shape[0]}) vectors and no LiDAR, got {tuple(obs.shape)}"
            )
        if self.trunk_dtype is None:
            return self.trunk(obs)
        with torch.autocast(obs.device.type, dtype=self.trunk_dtype):
            return self.trunk(obs).float()


def label_width(action_kind: str, action_dim: int) -> int:
    """P, the width of a label row (``PolicyNetwork.labels``): ``action_dim`` logits for a discrete policy,
    ``2 * action_dim`` (means then standard deviations) for a continuous one."""
    if action_dim < 1:
        raise ValueError(f"action_dim must be at least 1, got {action_dim}")
    if action_kind == "discrete":
        return action_dim
    if action_kind == "continuous":
        return 2 * action_dim
    raise ValueError(f"action_kind must be 'discrete' or 'continuous', got {action_kind!r}")


def label_distribution(labels: torch.Tensor, action_kind: str) -> Distribution:
    """The action distribution of (B, P) label rows (``PolicyNetwork.labels``): Categorical(logits=labels), or
    Independent(Normal(labels[:, :d], labels[:, d:]), 1) for P = 2·d.

    ValueError for labels that are not (B, P), an odd or empty continuous width, or a standard deviation that is not
    positive (NaN included): a corrupt label row should stop the run, not train the student on it.
    """
    if labels.dim() != 2 or labels.shape[1] < 1:
        raise ValueError(f"label rows of shape {tuple(labels.shape)}, expected (B, P) with P >= 1")
    if action_kind == "discrete":
        return Categorical(logits=labels)
    if action_kind != "continuous":
        raise ValueError(f"action_kind must be 'discrete' or 'continuous', got {action_kind!r}")
    width = labels.shape[1]
    if width % 2:
        raise ValueError(f"continuous labels are means then standard deviations (2·d wide), got width {width}")
    d = width // 2
    mean, std = labels[:, :d], labels[:, d:]
    if not bool((std > 0).all()):  # not (std <= 0): a NaN std fails too
        raise ValueError("continuous labels hold a standard deviation that is not positive")
    return Independent(Normal(mean, std), 1)


def censored_mean(mean: torch.Tensor, std: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """E[clip(X, low, high)] for X ~ Normal(mean, std), elementwise: the mean action of a Gaussian policy whose
    samples the env clips to [low, high].

    With a = (low - mean) / std, b = (high - mean) / std, Φ and φ the standard normal's CDF and density:
    low Φ(a) + high (1 - Φ(b)) + mean (Φ(b) - Φ(a)) + std (φ(a) - φ(b)). It equals ``mean`` where the range holds
    nearly all of the Gaussian, tends to ``low`` (``high``) as the mean leaves the range below (above), and stays
    inside the range. Written with ``erf`` and ``exp`` only, so that it exports to ONNX.
    """
    a, b = (low - mean) / std, (high - mean) / std
    cdf_a, cdf_b = 0.5 * (1 + torch.erf(a / math.sqrt(2))), 0.5 * (1 + torch.erf(b / math.sqrt(2)))
    pdf_a, pdf_b = torch.exp(-0.5 * a * a) / math.sqrt(2 * math.pi), torch.exp(-0.5 * b * b) / math.sqrt(2 * math.pi)
    return low * cdf_a + high * (1 - cdf_b) + mean * (cdf_b - cdf_a) + std * (pdf_a - pdf_b)


def build_policy(
    obs_shape: tuple[int, int, int],
    action_space_spec: dict[str, Any],
    cfg: PolicyConfig | None = None,
    sensors: Sequence[str] | None = None,
) -> ActorCritic:
    """An ActorCritic for ``{"kind": "discrete", "n": 10}`` or ``{"kind": "continuous", "low": [..], "high": [..]}``,
    for the model_metadata ``sensors`` (None: the front camera); ``obs_shape`` is the stacked camera observation
    (``common.sensors.ObsSpec.camera_shape``)."""
    kind = action_space_spec.get("kind")
    if kind == "discrete":
        return ActorCritic(obs_shape, "discrete", n_actions=int(action_space_spec["n"]), cfg=cfg, sensors=sensors)
    if kind == "continuous":
        low = tuple(float(v) for v in action_space_spec["low"])
        high = tuple(float(v) for v in action_space_spec["high"])
        return ActorCritic(obs_shape, "continuous", action_low=low, action_high=high, cfg=cfg, sensors=sensors)
    raise ValueError(f"action_space_spec kind must be 'discrete' or 'continuous', got {kind!r}")


def build_state_policy(
    state_size: int, action_space_spec: dict[str, Any], cfg: PolicyConfig | None = None
) -> StatePolicy:
    """A ``StatePolicy`` for ``build_policy``'s action space specs, on state vectors of ``state_size``."""
    kind = action_space_spec.get("kind")
    if kind == "discrete":
        return StatePolicy(state_size, "discrete", n_actions=int(action_space_spec["n"]), cfg=cfg)
    if kind == "continuous":
        low = tuple(float(v) for v in action_space_spec["low"])
        high = tuple(float(v) for v in action_space_spec["high"])
        return StatePolicy(state_size, "continuous", action_low=low, action_high=high, cfg=cfg)
    raise ValueError(f"action_space_spec kind must be 'discrete' or 'continuous', got {kind!r}")


def policy_for_run(run: RunConfig, actions: Any, frame: tuple[int, int] = (FRAME_HEIGHT, FRAME_WIDTH)) -> PolicyNetwork:
    """The network of a run (its ``common.action_space.ActionSpace`` ``actions``, its hyperparameters' frame stack, its
    env's ``observation``): DeepRacer's network on ``frame``-sized camera frames, or a teacher's ``StatePolicy``.
    The one place the trainer, the workers, the evaluator and the store's loader build a run's network."""
    spec = action_space_spec(actions)
    if run.env.observation == "state":
        return build_state_policy(STATE_SIZE, spec, run.policy)
    obs = observation_spec(actions.sensor, run.hyperparams.stack_size)
    return build_policy(obs.camera_shape(frame), spec, run.policy, actions.sensor)


def action_space_spec(space: Any) -> dict[str, Any]:
    """The ``build_policy`` spec of a ``common.action_space.ActionSpace`` (continuous: [steering°, speed m/s])."""
    if space.discrete:
        return {"kind": "discrete", "n": space.n}
    rng = space.action_space
    return {
        "kind": "continuous",
        "low": [rng.steering_angle.low, rng.speed.low],
        "high": [rng.steering_angle.high, rng.speed.high],
    }
