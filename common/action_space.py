"""DeepRacer action spaces, read from and written to DeepRacer's ``model_metadata.json``.

Discrete: a list of ``{"steering_angle": deg, "speed": m/s}``. Continuous: ranges
``{"steering_angle": {"low", "high"}, "speed": {"low", "high"}}``. Commands are clipped like
the DeepRacer simapp: steering to ±30°, speed to [0.1, 4] m/s.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from common.errors import UserError, validation_error_line
from common.jsonfile import read_json_object
from common.sensors import FRONT_FACING_CAMERA, LEGACY_CAMERA, SUPPORTED_COMBINATIONS, sensor_problem

MAX_STEERING_DEG = 30.0
MIN_SPEED_MPS = 0.1
MAX_SPEED_MPS = 4.0


class ActionSpaceError(UserError, ValueError):
    """A model_metadata.json that cannot be used; the message names the file and the problem."""


class DiscreteAction(BaseModel):
    """One action of a discrete space."""

    model_config = ConfigDict(extra="ignore")
    steering_angle: float
    """Steering angle, degrees, + = left."""
    speed: float
    """Speed, m/s."""
    index: int | None = None
    """Position in the list (DeepRacer writes it; informative only)."""


class Range(BaseModel):
    """A closed interval."""

    low: float
    high: float

    @model_validator(mode="after")
    def _ordered(self) -> Range:
        if not self.low <= self.high:
            raise ValueError(f"low {self.low} is above high {self.high}")
        return self


class ContinuousSpace(BaseModel):
    """Ranges of a continuous space."""

    steering_angle: Range
    """Steering range, degrees."""
    speed: Range
    """Speed range, m/s."""


class ActionSpace(BaseModel):
    """A DeepRacer action space with the rest of model_metadata.json kept as given."""

    model_config = ConfigDict(extra="allow")
    action_space_type: Literal["discrete", "continuous"] = "discrete"
    action_space: list[DiscreteAction] | ContinuousSpace = Field(default_factory=list)
    sensor: list[str] = Field(default_factory=lambda: [FRONT_FACING_CAMERA])
    neural_network: str = "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
    training_algorithm: str = "clipped_ppo"
    version: str = "5"
    """The simapp version the file was written for; the simapp reads it with ``float()``."""

    @field_validator("version")
    @classmethod
    def _numeric_version(cls, value: str) -> str:
        try:
            float(value)
        except ValueError:
            raise ValueError(f"version {value!r} is not a number (DeepRacer reads it with float())") from None
        return value

    @model_validator(mode="after")
    def _consistent(self) -> ActionSpace:
        discrete = isinstance(self.action_space, list)
        if discrete != (self.action_space_type == "discrete"):
            raise ValueError(f"action_space_type {self.action_space_type!r} does not match the action_space given")
        if discrete and not self.action_space:
            raise ValueError("the discrete action_space is empty")
        values = (
            [v for a in self.action_space for v in (a.steering_angle, a.speed)]
            if discrete
            else [
                self.action_space.steering_angle.low,
                self.action_space.steering_angle.high,
                self.action_space.speed.low,
                self.action_space.speed.high,
            ]
        )
        if not all(math.isfinite(v) for v in values):
            raise ValueError("an action value is not a finite number")
        return self

    @property
    def discrete(self) -> bool:
        """True for a list of actions."""
        return self.action_space_type == "discrete"

    @property
    def n(self) -> int:
        """Number of discrete actions (0 for a continuous space)."""
        return len(self.action_space) if self.discrete else 0

    def values(self, action: int | tuple[float, float] | list[float]) -> tuple[float, float]:
        """(steering_deg, speed_mps) of an action index or a continuous pair, before the car's limits.

        This is what DeepRacer's reward function is told (simapp ``set_reward_and_metrics``: ``float(json_actions
        [...])``): a listed 4.89 m/s or 12 m/s stays as listed. A continuous pair is clipped to the space's ranges.
        """
        if self.discrete:
            i = int(action)  # type: ignore[arg-type]
            if not 0 <= i < self.n:
                raise IndexError(f"action {i} is outside 0..{self.n - 1}")
            a = self.action_space[i]
            return float(a.steering_angle), float(a.speed)
        steer, speed = (float(v) for v in action)  # type: ignore[union-attr]
        rng = self.action_space
        steer = min(max(steer, rng.steering_angle.low), rng.steering_angle.high)
        speed = min(max(speed, rng.speed.low), rng.speed.high)
        return steer, speed

    def command(self, action: int | tuple[float, float] | list[float]) -> tuple[float, float]:
        """The (steering_deg, speed_mps) command the car gets for an action: its values within the car's limits."""
        return clip_command(*self.values(action))

    def to_json(self) -> str:
        """model_metadata.json text, as DeepRacer writes it."""
        return self.model_dump_json(indent=4)


def clip_command(steering_deg: float, speed_mps: float) -> tuple[float, float]:
    """Clip a command to the simulated car's physical limits (steering ±30°, speed 0.1–4 m/s).

    The simapp clamps only the minimum speed and lets the car model cap the rest; the reward function is told the
    action's own values either way (``ActionSpace.values``)."""
    if not (math.isfinite(steering_deg) and math.isfinite(speed_mps)):
        raise ValueError(f"command ({steering_deg}, {speed_mps}) is not finite")
    steer = min(max(float(steering_deg), -MAX_STEERING_DEG), MAX_STEERING_DEG)
    speed = min(max(float(speed_mps), MIN_SPEED_MPS), MAX_SPEED_MPS)
    return steer, speed


def default_action_space() -> ActionSpace:
    """DeepRacer's default: 5 steering angles (±30°, ±15°, 0°) × 2 speeds (0.5, 1 m/s) = 10 actions."""
    actions = [
        DiscreteAction(steering_angle=s, speed=v, index=2 * i + j)
        for i, s in enumerate((-30.0, -15.0, 0.0, 15.0, 30.0))
        for j, v in enumerate((0.5, 1.0))
    ]
    return ActionSpace(action_space_type="discrete", action_space=actions)


SUPPORTED_SENSORS: tuple[list[str], ...] = tuple(list(c) for c in SUPPORTED_COMBINATIONS)
"""The model_metadata ``sensor`` lists racer can honour, in any order (``common.sensors``): the front or stereo
camera, alone or with ``LIDAR`` or ``SECTOR_LIDAR``. The simapp also accepts ``LEFT_CAMERA`` and
``DISCRETIZED_SECTOR_LIDAR``, which racer does not build."""
SUPPORTED_ALGORITHMS: tuple[str, ...] = ("clipped_ppo",)
"""The ``training_algorithm`` values racer can honour (the simapp also has ``sac``)."""
NEURAL_NETWORKS: tuple[str, ...] = (
    "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW",
    "DEEP_CONVOLUTIONAL_NETWORK",
    "DEEP_CONVOLUTIONAL_NETWORK_DEEP",
)
"""The ``neural_network`` values DeepRacer's simapp knows (``markov/architecture``), all of which racer builds."""


def check_supported(space: ActionSpace, where: str) -> None:
    """Refuse, in one line naming ``where``, the key and the value, what racer would otherwise silently not honour."""
    checks = (
        ("sensor", space.sensor, [list(s) for s in SUPPORTED_SENSORS], sensor_problem(space.sensor)),
        (
            "training_algorithm",
            space.training_algorithm,
            list(SUPPORTED_ALGORITHMS),
            None if space.training_algorithm in SUPPORTED_ALGORITHMS else "racer trains clipped PPO",
        ),
        (
            "neural_network",
            space.neural_network,
            list(NEURAL_NETWORKS),
            None if space.neural_network in NEURAL_NETWORKS else "DeepRacer's three convolutional networks",
        ),
    )
    for key, value, supported, why in checks:
        if why is not None:
            allowed = " or ".join(json.dumps(v) for v in supported)
            raise ActionSpaceError(f"{where}: {key} = {json.dumps(value)} is not supported ({why}); use {allowed}")


def _as_the_simapp_reads_it(data: dict) -> dict:
    """The file's values as the simapp's ``parse_model_metadata`` (``markov/boto/s3/files/model_metadata.py``) takes
    them: ``training_algorithm`` and ``action_space_type`` lower-cased and stripped; a file with no ``version`` and no
    ``sensor``, or a ``version`` below 2, drives the front camera whatever its ``sensor`` says; the version-1 camera
    name ``observation`` is the front camera (``markov/sensors/sensors_rollout.py``: ``Observation`` reads the front
    camera's topic); ``version`` is ``float()``-ed (a JSON number is accepted). A file without a type gets the one
    its ``action_space`` implies."""
    data = dict(data)
    for key in ("training_algorithm", "action_space_type"):
        if isinstance(data.get(key), str):
            data[key] = data[key].lower().strip()
    version = data.get("version")
    if isinstance(version, int | float) and not isinstance(version, bool):
        data["version"] = str(version)
    try:
        legacy = float(data["version"]) < 2.0 if "version" in data else "sensor" not in data
    except (TypeError, ValueError):
        legacy = False  # the model's own check names the bad version
    if legacy:
        data["sensor"] = [FRONT_FACING_CAMERA]
    elif isinstance(data.get("sensor"), list):
        data["sensor"] = [FRONT_FACING_CAMERA if s == LEGACY_CAMERA else s for s in data["sensor"]]
    if "action_space_type" not in data:  # older DeepRacer files have no type: infer it
        data["action_space_type"] = "continuous" if isinstance(data.get("action_space"), dict) else "discrete"
    return data


def action_space_from_json(text: str | bytes) -> ActionSpace:
    """A run's stored ``model_metadata.json`` (written by racer, checked when the run was made), read as
    ``load_action_space`` reads a user's file."""
    return ActionSpace.model_validate(_as_the_simapp_reads_it(json.loads(text)))


def load_action_space(path: str | Path) -> ActionSpace:
    """Read a DeepRacer ``model_metadata.json``; raise ActionSpaceError naming the file if it is unusable or asks
    for what racer cannot honour (a sensor list racer does not build, SAC)."""
    p = Path(path)
    data = _as_the_simapp_reads_it(read_json_object(p, "action space file", ActionSpaceError))
    try:
        space = ActionSpace.model_validate(data)
    except ValidationError as exc:
        # The action_space field is a union: report the error of the member the file's type asks for.
        member = "ContinuousSpace" if data.get("action_space_type") == "continuous" else "list[DiscreteAction]"
        errors = exc.errors()
        err = next((e for e in errors if member in [str(v) for v in e["loc"]]), errors[0])
        raise ActionSpaceError(f"action space file {str(p)!r}: {validation_error_line(err)}") from None
    check_supported(space, f"action space file {str(p)!r}")
    return space
