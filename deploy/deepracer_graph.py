"""racer's network as DeepRacer's TensorFlow graph, and back: the weights of one in the other's names and layouts.

DeepRacer trains with rl_coach's clipped PPO in TensorFlow (aws-deepracer-community/deepracer-simapp at 01f5f015,
``bundle/rl_coach/rl_coach/architectures/tensorflow_components/``). What a DeepRacer model file holds, and so what
this module builds with ``tf.compat.v1`` (graph mode, reference variables, no Keras: the names are written out):

* Scopes: ``main_level/agent/main/online/network_<i>`` (``general_network.py: GeneralTensorFlowNetwork.get_model``,
  ``variable_scope('network_{}')``). Clipped PPO sets ``use_separate_networks_per_head``, so there are two networks:
  ``network_0`` ends in the value head ``ppo_v_head_0/output`` (``heads/ppo_v_head.py``, a dense layer of 1 unit)
  and ``network_1`` in the policy head ``ppo_head_0`` (``heads/ppo_head.py``). racer's value and policy heads share
  one trunk: export writes that trunk into both networks; import takes the trunk and policy head from
  ``network_1`` and the value head from ``network_0`` when ``network_0``'s trunk is the same (a racer export), else
  keeps racer's fresh value head (``deploy/importer.py``).
* Inputs: one placeholder per sensor, made in ``network_0`` and shared by ``network_1`` (``get_model``: ``if
  network_idx == 0: input_embedder()`` else ``input_embedder(self.inputs[input_name])``), named
  ``network_0/<SENSOR>/<SENSOR>`` (``embedders/embedder.py: InputEmbedder.__call__``: ``variable_scope(name)``,
  ``placeholder(name=name)``), float32 (batch, 120, 160, 1) for FRONT_FACING_CAMERA, (batch, 120, 160, 2) for
  STEREO_CAMERAS (``markov/sensors/utils.py: get_observation_space`` and the RGB-to-Y and stacking filters), (batch,
  64) for LIDAR and (batch, 8) for SECTOR_LIDAR. The car feeds these names (aws-deepracer-model-optimizer-pkg
  ``constants.py: NETWORK_INPUT_FORMAT_MAPPING``). Camera pixels are divided by 255 inside the graph
  (``embedder_parameters.py``: ``input_rescaling {'image': 255.0, 'vector': 1.0}``; ``InputEmbedder._build_module``:
  ``self.input / self.input_rescaling``).
* Embedders: the layers of ``markov/architecture/embedder_factory.py: create_scheme`` (the convs, then the dense
  layers), each followed by a ``BatchnormActivationDropout`` entry (``InputEmbedder.__init__`` inserts one after
  every layer), named ``<Class>_<index>`` (``_build_module``), so convs are ``Conv2d_0``, ``Conv2d_2``, ``Conv2d_4``
  and activations ``BatchnormActivationDropout_1_activation`` (ReLU, ``layers.py: batchnorm_activation_dropout``),
  then the camera's dense layers (``deep``, ``deep_deep``: ``Dense_8``, ...) as Keras ``Dense`` on the 4-D NHWC
  tensor (the last axis: every pixel's channels), then a Flatten of the NHWC tensor. Convs are Keras ``Conv2D``
  (``layers.py: Conv2d``, channels last, valid padding): kernel (kh, kw, in, out), bias. Dense layers are Keras
  ``Dense``: kernel (in, out), bias.
* Merger and middleware: embeddings in the sorted order of the sensor names, ``tf.concat(..., name="merger")``, then
  ``middleware_fc_embedder`` (``middlewares/fc_middleware.py``) with ``Dense_0`` (and ``Dense_2``), ReLU.
* Head input: ``(1 - r) * stop_gradient(x) + r * x`` with ``r`` the variable ``gradients_from_head_0-0_rescalers``
  (1.0: ``get_model``).
* Policy: discrete, ``ppo_head_0/policy_fc`` then ``tf.nn.softmax(name="policy")``; continuous, ``ppo_head_0/
  policy_mean`` then ``tf.identity(name="policy")``, the mean in units where each action's range is [-1, 1]
  (``markov/multi_agent_coach/action_space_configs.py: ClippedPPOActionSpaceConfig``, low -1, high 1, scaled in the
  environment by ``spaces.py: ScalableBoxActionSpace._scale_value``), and the variable ``policy_log_std`` (1, n),
  clipped to [-20, 3] before ``exp``. racer's Gaussian mean is ``mid + half * policy_head(h)`` and its std ``half *
  exp(log_std)``: the same head and log-std in the simapp's units.
* The frozen ``model.pb`` is ``tf.compat.v1.graph_util.convert_variables_to_constants`` of the session for the one
  output ``main_level/agent/main/online/network_1/ppo_head_0/policy`` (``markov/boto/s3/files/checkpoint_files/
  tensorflow_model.py: write_frozen_graph``; ``markov/boto/s3/constants.py: FROZEN_HEAD_OUTPUT_GRAPH_FORMAT_MAPPING``),
  so it holds the shared input placeholders and ``network_1`` only.
* Checkpoints hold the trainable variables of both networks (``savers.py: GlobalVariableSaver``:
  ``trainable_variables()`` without the target network), written by ``tf.compat.v1.train.Saver``.

Layouts: a torch conv weight is (out, in, kh, kw) and TensorFlow's kernel (kh, kw, in, out); racer flattens the last
conv's output in (C, H, W) order and TensorFlow's Flatten of NHWC in (H, W, C) order, so the rows of the first dense
layer after the flatten are permuted (``_flat_rows_to_tf``). racer's BatchNorm2d (off in DeepRacer's networks) is
folded into the conv before it; Dropout is the identity when acting.

Not exportable (``export_problem`` says why in one line): frame stacks (the simapp's camera input is one frame).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from common.errors import UserError
from common.policy import LIDAR_EMBEDDER, TOPOLOGIES, ActorCritic, PixelDense

SCOPE = "main_level/agent/main/online"
"""The agent's online network scope (rl_coach ``main_level/<agent>/main/online``, agent name ``agent``)."""
POLICY_NODE = f"{SCOPE}/network_1/ppo_head_0/policy"
"""The frozen graph's output (simapp ``FROZEN_HEAD_OUTPUT_GRAPH_FORMAT_MAPPING['clipped_ppo']``)."""
FRAME_SHAPE = (120, 160)
"""(height, width) of the camera input (simapp ``TRAINING_IMAGE_SIZE`` = (160, 120), width first)."""
RESCALER = "gradients_from_head_0-0_rescalers"
"""The head-gradient rescaler variable of each network (``general_network.py: get_model``)."""
EXTRA = "pip install 'racer[deepracer]'"
"""How to get TensorFlow and OpenVINO for the DeepRacer formats."""


class DeepRacerModelError(UserError, ValueError):
    """A model that cannot go to DeepRacer's format, or a DeepRacer model racer cannot read."""


class MissingExtraError(UserError, ImportError):
    """TensorFlow is not installed: the DeepRacer formats need the ``deepracer`` extra."""


def tensorflow(what: str) -> Any:
    """The ``tensorflow`` module, or MissingExtraError naming ``what`` needed it and the extra that installs it."""
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")  # TensorFlow's start-up banner is not racer's output
    try:
        import tensorflow as tf
    except ImportError:
        raise MissingExtraError(f"{what} needs TensorFlow, which is not installed: {EXTRA}") from None
    tf.get_logger().setLevel("ERROR")  # tf.compat.v1's deprecation notices
    return tf


def input_node(sensor: str) -> str:
    """The placeholder of ``sensor`` (model optimizer ``NETWORK_INPUT_FORMAT_MAPPING`` with ``main``)."""
    return f"{SCOPE}/network_0/{sensor}/{sensor}"


@dataclass(frozen=True)
class Layout:
    """The simapp network of one (sensors, ``neural_network``, action space): what the graph is built from."""

    camera: str
    camera_channels: int
    convs: tuple[tuple[int, int, int], ...]
    """(filters, kernel, stride) of each conv."""
    camera_dense: tuple[int, ...]
    """Units of the camera's dense layers after the convs, each on every pixel."""
    lidar: str | None
    lidar_size: int
    lidar_dense: tuple[int, ...]
    middleware: tuple[int, ...]
    discrete: bool
    n_out: int
    """Actions (discrete) or action dimensions (continuous)."""

    @property
    def sensors(self) -> list[str]:
        """Input names in the merger's order (sorted, ``general_network.py``)."""
        return sorted([self.camera, self.lidar] if self.lidar else [self.camera])

    def conv_out(self) -> tuple[int, int, int]:
        """(height, width, channels) of the last conv's output (valid padding)."""
        h, w = FRAME_SHAPE
        for _, k, s in self.convs:
            h, w = (h - k) // s + 1, (w - k) // s + 1
        return h, w, self.convs[-1][0]

    def embed_out(self) -> tuple[int, int, int]:
        """(height, width, channels) of the camera embedder's output before its Flatten."""
        h, w, c = self.conv_out()
        return h, w, self.camera_dense[-1] if self.camera_dense else c


def export_problem(model: ActorCritic) -> str | None:
    """Why ``model`` cannot be written as the simapp's graph (one line), or None."""
    spec = model.spec
    if model.obs_shape[:2] != FRAME_SHAPE:
        return f"its frames are {model.obs_shape[0]}x{model.obs_shape[1]}; DeepRacer's camera input is 120x160"
    if spec.stack_size != 1:
        return (
            f"it stacks {spec.stack_size} frames (stack_size); DeepRacer's networks take one camera frame "
            "(simapp ObservationStackingFilter(1))"
        )
    return None


def layout_of(model: ActorCritic) -> Layout:
    """The simapp layout of a racer network; DeepRacerModelError if it has none (``export_problem``)."""
    problem = export_problem(model)
    if problem:
        raise DeepRacerModelError(f"cannot export to DeepRacer: {problem}")
    spec = model.spec
    topology = TOPOLOGIES[spec.camera, model.cfg.network]
    return Layout(
        camera=spec.camera,
        camera_channels=spec.frame_channels,
        convs=topology.convs,
        camera_dense=topology.camera_dense,
        lidar=spec.lidar.name if spec.lidar else None,
        lidar_size=spec.lidar_size,
        lidar_dense=LIDAR_EMBEDDER if spec.lidar else (),
        middleware=topology.middleware,
        discrete=model.action_kind == "discrete",
        n_out=model.action_dim,
    )


# --- racer's modules, in order --------------------------------------------------------------------------------------


@dataclass
class _Parts:
    """racer's layers grouped as the simapp's: convs (with any BatchNorm after each), dense layers per part."""

    convs: list[tuple[nn.Conv2d, nn.BatchNorm2d | None]]
    camera_dense: list[PixelDense]
    lidar: list[nn.Linear]
    middleware: list[nn.Linear]


def _parts(model: ActorCritic) -> _Parts:
    """racer's conv, LiDAR and middleware layers (``common.policy.ActorCritic``: ``trunk``, or ``camera_embedder``,
    ``lidar_embedder`` and ``middleware``)."""
    camera = model.trunk if model.trunk is not None else model.camera_embedder
    convs: list[tuple[nn.Conv2d, nn.BatchNorm2d | None]] = []
    linears: list[nn.Linear] = []
    pixel: list[PixelDense] = []
    for module in camera:
        if isinstance(module, PixelDense):
            pixel.append(module)
        elif isinstance(module, nn.Conv2d):
            convs.append((module, None))
        elif isinstance(module, nn.BatchNorm2d):
            convs[-1] = (convs[-1][0], module)
        elif isinstance(module, nn.Linear):
            linears.append(module)
    if model.trunk is not None:
        return _Parts(convs, pixel, [], linears)
    lidar = [m for m in model.lidar_embedder if isinstance(m, nn.Linear)]
    return _Parts(convs, pixel, lidar, [m for m in model.middleware if isinstance(m, nn.Linear)])


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().double().numpy()


def _folded(conv: nn.Conv2d, bn: nn.BatchNorm2d | None) -> tuple[np.ndarray, np.ndarray]:
    """(kernel HWIO, bias) of a conv with its eval-mode BatchNorm folded in."""
    w, b = _np(conv.weight), _np(conv.bias)
    if bn is not None:
        scale = _np(bn.weight) / np.sqrt(_np(bn.running_var) + bn.eps)
        w = w * scale[:, None, None, None]
        b = (b - _np(bn.running_mean)) * scale + _np(bn.bias)
    return w.transpose(2, 3, 1, 0), b


def _flat_rows_to_tf(rows: np.ndarray, chw: tuple[int, int, int]) -> np.ndarray:
    """Rows of a (C·H·W, out) kernel in torch's (C, H, W) flatten order → TensorFlow's (H, W, C) order."""
    c, h, w = chw
    return rows.reshape(c, h, w, -1).transpose(1, 2, 0, 3).reshape(c * h * w, -1)


def _flat_rows_to_torch(rows: np.ndarray, chw: tuple[int, int, int]) -> np.ndarray:
    """The inverse of ``_flat_rows_to_tf``."""
    c, h, w = chw
    return rows.reshape(h, w, c, -1).transpose(2, 0, 1, 3).reshape(c * h * w, -1)


def _middleware_in(layout: Layout) -> list[tuple[str, int]]:
    """The merger's blocks, in order: (sensor, width) (the camera's width is its flat conv output)."""
    h, w, c = layout.embed_out()
    widths = {layout.camera: h * w * c}
    if layout.lidar:
        widths[layout.lidar] = layout.lidar_dense[-1]
    return [(name, widths[name]) for name in layout.sensors]


def _first_middleware_kernel(weight: np.ndarray, layout: Layout, to_tf: bool) -> np.ndarray:
    """The middleware's first kernel (in, out) with the camera block's rows permuted between the flatten orders."""
    h, w, c = layout.embed_out()
    out, start = weight.copy(), 0
    for name, width in _middleware_in(layout):
        if name == layout.camera:
            rows = weight[start : start + width]
            out[start : start + width] = (
                _flat_rows_to_tf(rows, (c, h, w)) if to_tf else _flat_rows_to_torch(rows, (c, h, w))
            )
        start += width
    return out


# --- names ----------------------------------------------------------------------------------------------------------


def conv_names(layout: Layout) -> list[str]:
    """Scope of each camera conv inside the camera's embedder: ``Conv2d_0``, ``Conv2d_2``, ..."""
    return [f"Conv2d_{2 * i}" for i in range(len(layout.convs))]


def camera_dense_names(layout: Layout) -> list[str]:
    """Scope of each camera dense layer, numbered on after the convs and their activations: ``Dense_8``, ..."""
    first = 2 * len(layout.convs)
    return [f"Dense_{first + 2 * i}" for i in range(len(layout.camera_dense))]


def dense_names(n: int) -> list[str]:
    """Scope of each of ``n`` dense layers of a LiDAR embedder or the middleware: ``Dense_0``, ``Dense_2``, ..."""
    return [f"Dense_{2 * i}" for i in range(n)]


def policy_dense(discrete: bool) -> str:
    """The policy head's dense layer: ``policy_fc`` (softmax) or ``policy_mean`` (``heads/ppo_head.py``)."""
    return "policy_fc" if discrete else "policy_mean"


# --- racer → simapp -------------------------------------------------------------------------------------------------


def simapp_weights(model: ActorCritic) -> dict[str, np.ndarray]:
    """Every trainable variable of the simapp's graph for ``model`` (full names without ``:0``), in TensorFlow's
    layouts: racer's trunk in both networks, the value head in ``network_0``, the policy head in ``network_1``."""
    layout = layout_of(model)
    parts = _parts(model)
    trunk: dict[str, np.ndarray] = {}
    for name, (conv, bn) in zip(conv_names(layout), parts.convs, strict=True):
        trunk[f"{layout.camera}/{name}/kernel"], trunk[f"{layout.camera}/{name}/bias"] = _folded(conv, bn)
    for name, linear in zip(camera_dense_names(layout), parts.camera_dense, strict=True):
        trunk[f"{layout.camera}/{name}/kernel"] = _np(linear.weight).T
        trunk[f"{layout.camera}/{name}/bias"] = _np(linear.bias)
    if layout.lidar:
        for name, linear in zip(dense_names(len(parts.lidar)), parts.lidar, strict=True):
            trunk[f"{layout.lidar}/{name}/kernel"] = _np(linear.weight).T
            trunk[f"{layout.lidar}/{name}/bias"] = _np(linear.bias)
    for i, (name, linear) in enumerate(zip(dense_names(len(parts.middleware)), parts.middleware, strict=True)):
        kernel = _np(linear.weight).T
        trunk[f"middleware_fc_embedder/{name}/kernel"] = (
            _first_middleware_kernel(kernel, layout, to_tf=True) if i == 0 else kernel
        )
        trunk[f"middleware_fc_embedder/{name}/bias"] = _np(linear.bias)
    trunk[RESCALER] = np.array(1.0)
    out = {f"{SCOPE}/network_{i}/{k}": v for i in (0, 1) for k, v in trunk.items()}
    out[f"{SCOPE}/network_0/ppo_v_head_0/output/kernel"] = _np(model.value_head.weight).T
    out[f"{SCOPE}/network_0/ppo_v_head_0/output/bias"] = _np(model.value_head.bias)
    head = f"{SCOPE}/network_1/ppo_head_0"
    out[f"{head}/{policy_dense(layout.discrete)}/kernel"] = _np(model.policy_head.weight).T
    out[f"{head}/{policy_dense(layout.discrete)}/bias"] = _np(model.policy_head.bias)
    if not layout.discrete:
        out[f"{head}/policy_log_std"] = _np(model.log_std)[None, :]
    return {k: np.asarray(v, dtype=np.float32) for k, v in out.items()}


# --- simapp → racer -------------------------------------------------------------------------------------------------


def _take(arrays: Mapping[str, np.ndarray], name: str, shape: tuple[int, ...], source: str) -> np.ndarray:
    """``arrays[name]`` of ``shape``, or DeepRacerModelError naming the source, the tensor and what was found."""
    if name not in arrays:
        raise DeepRacerModelError(f"{source}: no tensor {name} (not the simapp's network for this model_metadata)")
    value = np.asarray(arrays[name], dtype=np.float64)
    if value.shape != shape:
        raise DeepRacerModelError(f"{source}: {name} has shape {value.shape}, racer's network needs {shape}")
    return value


def _scoped(arrays: Mapping[str, np.ndarray], scope: str, layer: str) -> list[str]:
    """The ``<layer>_<n>`` scopes under ``scope`` that hold a kernel, in the order of n (the simapp's numbering has
    changed between versions; the order has not)."""
    found = {
        key[len(scope) + 1 :].split("/")[0]
        for key in arrays
        if key.startswith(scope + "/") and key.endswith("/kernel") and key[len(scope) + 1 :].startswith(layer + "_")
    }
    return sorted(found, key=lambda s: int(s.rsplit("_", 1)[1]) if s.rsplit("_", 1)[1].isdigit() else -1)


def _set(param: torch.Tensor, value: np.ndarray) -> None:
    with torch.no_grad():
        param.copy_(torch.from_numpy(np.ascontiguousarray(value)).to(param.dtype))


def _trunk_from(arrays: Mapping[str, np.ndarray], net: str, model: ActorCritic, layout: Layout, source: str) -> None:
    """Load ``network_<i>``'s embedders and middleware into racer's trunk (``model``'s conv, LiDAR, middleware)."""
    parts = _parts(model)
    if any(bn is not None for _, bn in parts.convs):
        raise DeepRacerModelError(f"{source}: import builds networks without BatchNorm")
    scope = f"{SCOPE}/{net}"
    convs = _scoped(arrays, f"{scope}/{layout.camera}", "Conv2d")
    denses = _scoped(arrays, f"{scope}/{layout.camera}", "Dense")
    if len(convs) != len(parts.convs) or len(denses) != len(parts.camera_dense):
        raise DeepRacerModelError(
            f"{source}: {layout.camera} has {len(convs)} convs and {len(denses)} dense layers; racer's network has "
            f"{len(parts.convs)} convs and {len(parts.camera_dense)}"
        )
    for name, (conv, _) in zip(convs, parts.convs, strict=True):
        o, i, kh, kw = conv.weight.shape
        base = f"{scope}/{layout.camera}/{name}"
        _set(conv.weight, _take(arrays, f"{base}/kernel", (kh, kw, i, o), source).transpose(3, 2, 0, 1))
        _set(conv.bias, _take(arrays, f"{base}/bias", (o,), source))
    groups = [(f"{scope}/{layout.camera}", parts.camera_dense)] if parts.camera_dense else []
    groups += [(f"{scope}/middleware_fc_embedder", parts.middleware)]
    if layout.lidar:
        groups.append((f"{scope}/{layout.lidar}", parts.lidar))
    for group, linears in groups:
        names = _scoped(arrays, group, "Dense")
        if len(names) != len(linears):
            raise DeepRacerModelError(f"{source}: {group} has {len(names)} dense layers, racer's has {len(linears)}")
        for name, linear in zip(names, linears, strict=True):
            out_f, in_f = linear.weight.shape
            kernel = _take(arrays, f"{group}/{name}/kernel", (in_f, out_f), source)
            if group.endswith("middleware_fc_embedder") and linear is linears[0]:
                kernel = _first_middleware_kernel(kernel, layout, to_tf=False)
            _set(linear.weight, kernel.T)
            _set(linear.bias, _take(arrays, f"{group}/{name}/bias", (out_f,), source))


def load_simapp_weights(model: ActorCritic, arrays: Mapping[str, np.ndarray], source: str) -> bool:
    """Fill ``model`` from the simapp's tensors (a checkpoint's variables or a frozen graph's constants): the trunk
    and policy head from ``network_1``; the value head from ``network_0`` when its trunk equals ``network_1``'s (as
    racer exports it), else racer's fresh value head stays. Returns whether the value head was loaded.
    DeepRacerModelError (naming ``source``) for a missing tensor or a shape racer's network does not have."""
    layout = layout_of(model)
    _trunk_from(arrays, "network_1", model, layout, source)
    head = f"{SCOPE}/network_1/ppo_head_0/{policy_dense(layout.discrete)}"
    n, hidden = model.policy_head.weight.shape
    _set(model.policy_head.weight, _take(arrays, f"{head}/kernel", (hidden, n), source).T)
    _set(model.policy_head.bias, _take(arrays, f"{head}/bias", (n,), source))
    if not layout.discrete:
        log_std = f"{SCOPE}/network_1/ppo_head_0/policy_log_std"
        if log_std in arrays:  # a frozen graph has no log-std (the policy output is the mean)
            _set(model.log_std, np.clip(_take(arrays, log_std, (1, n), source)[0], -20.0, 3.0))
    return _value_head_from(arrays, model, source)


def _value_head_from(arrays: Mapping[str, np.ndarray], model: ActorCritic, source: str) -> bool:
    """Load ``network_0``'s value head if ``network_0``'s trunk is ``network_1``'s; whether it was loaded."""
    n0, n1 = f"{SCOPE}/network_0/", f"{SCOPE}/network_1/"
    value = f"{n0}ppo_v_head_0/output"
    if f"{value}/kernel" not in arrays:
        return False
    trunk1 = {k[len(n1) :]: v for k, v in arrays.items() if k.startswith(n1) and "ppo_head" not in k}
    same = all(
        (n0 + k) in arrays and np.array_equal(np.asarray(arrays[n0 + k]), np.asarray(v)) for k, v in trunk1.items()
    )
    if not same:
        return False
    hidden = model.value_head.weight.shape[1]
    _set(model.value_head.weight, _take(arrays, f"{value}/kernel", (hidden, 1), source).T)
    _set(model.value_head.bias, _take(arrays, f"{value}/bias", (1,), source))
    return True


# --- the TensorFlow graph -------------------------------------------------------------------------------------------


def _input_shape(layout: Layout, sensor: str) -> list[int | None]:
    if sensor == layout.camera:
        return [None, *FRAME_SHAPE, layout.camera_channels]
    return [None, layout.lidar_size]


def _variable(tf: Any, name: str, shape: tuple[int, ...]) -> Any:
    # Reference variables, as the simapp's (tf.compat.v1.disable_resource_variables); values are loaded after.
    zeros = tf.compat.v1.zeros_initializer()
    return tf.compat.v1.get_variable(name, shape=shape, initializer=zeros, use_resource=False)


def _dense(tf: Any, x: Any, name: str, units: int, relu: bool, *, activation_name: str = "") -> Any:
    with tf.compat.v1.variable_scope(name):
        kernel = _variable(tf, "kernel", (int(x.shape[-1]), units))
        bias = _variable(tf, "bias", (units,))
        # Keras Dense on a 4-D tensor maps its last axis (a camera's dense layers: every pixel's channels).
        product = tf.linalg.matmul(x, kernel, name="MatMul") if x.shape.rank == 2 else tf.tensordot(x, kernel, 1)
        y = tf.nn.bias_add(product, bias, name="BiasAdd")
    return tf.nn.relu(y, name=activation_name or f"{name}_activation") if relu else y


def _embedder(tf: Any, x: Any, layout: Layout, sensor: str) -> Any:
    """One sensor's embedder on its placeholder: rescale, the layers with their ReLUs, Flatten."""
    camera = sensor == layout.camera
    x = x / (255.0 if camera else 1.0)
    x = x - 0.0  # InputEmbedder._build_module: input_offset
    if camera:
        for i, ((filters, kernel, stride), name) in enumerate(zip(layout.convs, conv_names(layout), strict=True)):
            with tf.compat.v1.variable_scope(name):
                k = _variable(tf, "kernel", (kernel, kernel, int(x.shape[-1]), filters))
                b = _variable(tf, "bias", (filters,))
                x = tf.nn.conv2d(x, k, [1, stride, stride, 1], "VALID", name="Conv2D")
                x = tf.nn.bias_add(x, b, name="BiasAdd")
            x = tf.nn.relu(x, name=f"BatchnormActivationDropout_{2 * i + 1}_activation")
        # The camera's dense layers are numbered on after the convs: Dense_<2k>, then its activation at 2k + 1.
        first = len(layout.convs)
        for i, (units, name) in enumerate(zip(layout.camera_dense, camera_dense_names(layout), strict=True)):
            x = _dense(
                tf, x, name, units, True, activation_name=f"BatchnormActivationDropout_{2 * (first + i) + 1}_activation"
            )
    else:
        for i, (units, name) in enumerate(zip(layout.lidar_dense, dense_names(len(layout.lidar_dense)), strict=True)):
            x = _dense(tf, x, name, units, True, activation_name=f"BatchnormActivationDropout_{2 * i + 1}_activation")
    with tf.compat.v1.name_scope("flatten"):
        return tf.reshape(x, [-1, math.prod(int(d) for d in x.shape[1:])], name="Reshape")


def _network(tf: Any, index: int, layout: Layout, inputs: dict[str, Any]) -> Any:
    """``network_<index>``: embedders, merger, middleware, the head input; returns the head input."""
    embeddings = []
    for sensor in layout.sensors:
        with tf.compat.v1.variable_scope(sensor):
            if index == 0:
                inputs[sensor] = tf.compat.v1.placeholder(tf.float32, _input_shape(layout, sensor), name=sensor)
            embeddings.append(_embedder(tf, inputs[sensor], layout, sensor))
    x = embeddings[0] if len(embeddings) == 1 else tf.concat(embeddings, axis=-1, name="merger")
    with tf.compat.v1.variable_scope("middleware_fc_embedder"):
        names = dense_names(len(layout.middleware))
        for i, (units, name) in enumerate(zip(layout.middleware, names, strict=True)):
            x = _dense(tf, x, name, units, True, activation_name=f"BatchnormActivationDropout_{2 * i + 1}_activation")
    rescaler = tf.compat.v1.get_variable(RESCALER, initializer=1.0, use_resource=False)
    return (1 - rescaler) * tf.stop_gradient(x) + rescaler * x


def build_graph(layout: Layout) -> tuple[Any, dict[str, Any]]:
    """A new ``tf.Graph`` of the simapp's two networks for ``layout`` (variables zero until loaded); returns the
    graph and its input placeholders by sensor."""
    tf = tensorflow("building DeepRacer's network")
    graph = tf.Graph()
    inputs: dict[str, Any] = {}
    with graph.as_default(), tf.compat.v1.variable_scope(SCOPE):
        with tf.compat.v1.variable_scope("network_0"):
            x = _network(tf, 0, layout, inputs)
            with tf.compat.v1.variable_scope("ppo_v_head_0"):
                _dense(tf, x, "output", 1, False)
        with tf.compat.v1.variable_scope("network_1"):
            x = _network(tf, 1, layout, inputs)
            with tf.compat.v1.variable_scope("ppo_head_0"):
                logits = _dense(tf, x, policy_dense(layout.discrete), layout.n_out, False)
                if layout.discrete:
                    tf.nn.softmax(logits, name="policy")
                else:
                    tf.identity(logits, name="policy")
                    log_std = _variable(tf, "policy_log_std", (1, layout.n_out))
                    std = tf.exp(tf.clip_by_value(log_std, -20.0, 3.0))
                    tf.tile(std, [tf.shape(x)[0], 1], name="policy_std")
    return graph, inputs


class SimappSession:
    """The simapp's graph for a layout in a TensorFlow session with given weights: freeze it, save a checkpoint."""

    def __init__(self, layout: Layout, weights: Mapping[str, np.ndarray]) -> None:
        self.tf = tensorflow("DeepRacer's model formats")
        self.layout = layout
        self.graph, self.inputs = build_graph(layout)
        with self.graph.as_default():
            self.variables = self.tf.compat.v1.trainable_variables()
            self.session = self.tf.compat.v1.Session(graph=self.graph)
            self.session.run(self.tf.compat.v1.global_variables_initializer())
            names = {v.name.split(":")[0] for v in self.variables}
            if names != set(weights):
                missing, extra = sorted(names - set(weights)), sorted(set(weights) - names)
                raise DeepRacerModelError(f"weights do not fit the graph: missing {missing[:3]}, extra {extra[:3]}")
            for v in self.variables:
                v.load(np.asarray(weights[v.name.split(":")[0]], dtype=np.float32), self.session)

    def frozen(self) -> bytes:
        """The frozen ``model.pb`` (GraphDef bytes) for the policy output, as the simapp's ``write_frozen_graph``."""
        with self.graph.as_default():
            graph_def = self.tf.compat.v1.graph_util.convert_variables_to_constants(
                self.session, self.graph.as_graph_def(), [POLICY_NODE]
            )
        return graph_def.SerializeToString()

    def save_checkpoint(self, prefix: str) -> None:
        """``prefix``.index, .data-00000-of-00001 and .meta: the trainable variables (``GlobalVariableSaver``)."""
        with self.graph.as_default():
            saver = self.tf.compat.v1.train.Saver(self.variables, max_to_keep=None)
            saver.save(self.session, prefix, write_state=False)

    def close(self) -> None:
        """Release the session."""
        self.session.close()


def frozen_constants(pb: bytes, source: str) -> dict[str, np.ndarray]:
    """The constants of a frozen ``model.pb``: what were its variables, by name."""
    tf = tensorflow("reading a DeepRacer model.pb")
    graph_def = tf.compat.v1.GraphDef()
    try:
        graph_def.ParseFromString(pb)
    except Exception as exc:  # protobuf's DecodeError, whatever its module
        raise DeepRacerModelError(f"{source}: not a TensorFlow GraphDef ({type(exc).__name__})") from None
    return {
        node.name: tf.make_ndarray(node.attr["value"].tensor)
        for node in graph_def.node
        if node.op == "Const" and node.attr["value"].tensor.dtype == tf.float32.as_datatype_enum
    }


def checkpoint_variables(prefix: str, source: str) -> dict[str, np.ndarray]:
    """The float variables of a TensorFlow checkpoint (``prefix``.index + data)."""
    tf = tensorflow("reading a DeepRacer checkpoint")
    try:
        reader = tf.train.load_checkpoint(prefix)
    except Exception as exc:  # NotFoundError, DataLossError...: any unreadable checkpoint is the user's file
        raise DeepRacerModelError(f"{source}: not a readable TensorFlow checkpoint ({type(exc).__name__})") from None
    dtypes = reader.get_variable_to_dtype_map()
    return {name: reader.get_tensor(name) for name, dtype in dtypes.items() if dtype == tf.float32}


def run_frozen(pb: bytes, feeds: Mapping[str, np.ndarray]) -> np.ndarray:
    """The policy output of a frozen graph for inputs by sensor name (TensorFlow, as the simapp's evaluation)."""
    tf = tensorflow("running a DeepRacer model.pb")
    graph_def = tf.compat.v1.GraphDef()
    graph_def.ParseFromString(pb)
    graph = tf.Graph()
    with graph.as_default():
        tf.graph_util.import_graph_def(graph_def, name="")
    with tf.compat.v1.Session(graph=graph) as session:
        feed = {graph.get_tensor_by_name(input_node(k) + ":0"): v.astype(np.float32) for k, v in feeds.items()}
        return session.run(graph.get_tensor_by_name(POLICY_NODE + ":0"), feed)
