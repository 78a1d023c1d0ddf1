"""An exported model file: the camera frame it takes, the ``racer`` metadata inside it and the observation it
describes (onnx only, no torch: the on-car runtime reads it)."""

from __future__ import annotations

import json
from pathlib import Path

import onnx

from common.config import FRAME_HEIGHT, FRAME_WIDTH
from common.errors import UserError
from common.sensors import FRONT_FACING_CAMERA, ObsSpec, observation_spec

OBS_HEIGHT, OBS_WIDTH = FRAME_HEIGHT, FRAME_WIDTH
"""The camera frame the policy was trained on (``common.config``)."""


class ExportError(UserError, ValueError):
    """A model file or checkpoint that cannot be used; the message names it."""


def stamp(path: Path, info: dict) -> None:
    """Put ``info`` into the ONNX file's metadata properties (key ``racer``, JSON), so the model describes itself."""
    proto = onnx.load(str(path))
    entry = proto.metadata_props.add()
    entry.key, entry.value = "racer", json.dumps(info)
    onnx.save(proto, str(path))


def model_info(path: str | Path) -> dict:
    """The ``racer`` metadata of an exported model (ExportError if it has none)."""
    try:
        proto = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # protobuf's DecodeError and friends: whatever it is, it is not a model we can run
        raise ExportError(f"{str(path)!r} is not an ONNX model ({type(exc).__name__})") from None
    for entry in proto.metadata_props:
        if entry.key == "racer":
            return json.loads(entry.value)
    raise ExportError(f"{str(path)!r} is not a model exported by racer export (no 'racer' metadata)")


def model_observation(info: dict) -> ObsSpec:
    """The observation an exported model takes, from its ``racer`` metadata: its ``sensors`` (a model exported
    before LiDAR has none: the front camera) and ``stack_size``. ExportError if they are not a list racer builds."""
    sensors = info.get("sensors", [FRONT_FACING_CAMERA])
    try:
        return observation_spec(sensors, info.get("stack_size"))
    except (TypeError, ValueError) as exc:
        raise ExportError(f"the model's racer metadata: {exc}") from None
