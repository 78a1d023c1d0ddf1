"""The car file (``car.json``): the car's physical properties and the effects between command and wheels.

``racer calibrate`` writes it; ``racer train/eval/bench --car-calibration F`` (and ``--car NAME|FILE``) load
it and every env of the run applies it. The file::

    {"version": 1,
     "about": "where the values came from (optional, informative)",
     "effects": [{"name": "steering_lag", "params": {"tau_s": 0.55}, "stderr": {"tau_s": 0.02}}, ...]}

Each effect is named from :data:`EFFECTS`; an effect that is absent acts as the identity (the car as
modelled in ``sim/assets/car.xml``). Two kinds (:attr:`EffectSpec.acts_on`): ``command`` effects sit between
the command and the servos (``sim/actuation.py`` holds the maths); ``model`` effects are properties of the
MuJoCo car itself (tyre friction, masses, inertias, the wheel drives) that ``sim/physics.py`` writes into the
model. ``stderr`` is informative (the fit's standard error) and optional. The file is validated in full: an
unknown effect or parameter, a missing parameter, a value outside its physical range or a repeated effect is
refused with one line naming it.

Presets (:data:`CAR_PRESETS`, ``--car NAME``) are car files shipped in ``sim/cars/``; ``default`` is the car
as modelled, with no effects.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping
from dataclasses import KW_ONLY, dataclass
from functools import cache
from importlib.resources.abc import Traversable
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from common.errors import UserError, error_location


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect: its identity value and physical bounds (by position), then by name a start for
    fitting, a scale and its meaning."""

    identity: float
    """The value at which the effect does nothing."""
    low: float
    high: float
    _: KW_ONLY
    start: float
    """Where a fit starts from (near identity, but where the error still depends on it)."""
    scale: float
    """A typical size of the parameter, for the optimizer's scaling and finite differences."""
    doc: str


@dataclass(frozen=True)
class EffectSpec:
    """A named effect: what it does and its parameters."""

    doc: str
    params: dict[str, ParamSpec]
    acts_on: str = "command"
    """``command``: between the command and the servos (``sim.actuation``); ``model``: a property of the MuJoCo
    car that ``sim.physics`` writes into the model."""
    candidate: bool = True
    """Whether ``racer calibrate`` tries it unless told which effects to try. The car's masses, inertias and
    drives are not: they come from the car's design (e.g. the DeepRacer simapp's URDF), not from trajectories,
    which hardly tell a mass from a drive gain."""


EFFECTS: dict[str, EffectSpec] = {
    "steering_offset": EffectSpec(
        "a constant added to the commanded steering angle (a mis-centred servo)",
        {"offset_deg": ParamSpec(0.0, -10.0, 10.0, start=0.5, scale=1.0, doc="added angle, degrees, + = left")},
    ),
    "steering_gain": EffectSpec(
        "the wheels turn by gain × the commanded angle",
        {"gain": ParamSpec(1.0, 0.05, 2.0, start=0.9, scale=0.1, doc="effective / commanded angle")},
    ),
    "steering_saturation": EffectSpec(
        "the wheels turn no further than a limit, whatever the command",
        {"max_deg": ParamSpec(30.0, 1.0, 30.0, start=20.0, scale=2.0, doc="largest effective angle, degrees")},
    ),
    "steering_delay": EffectSpec(
        "dead time between a steering command and the wheels starting to turn",
        {"delay_s": ParamSpec(0.0, 0.0, 0.5, start=0.05, scale=0.03, doc="dead time, s")},
    ),
    "steering_lag": EffectSpec(
        "the wheels follow the steering command as a first-order lag",
        {"tau_s": ParamSpec(0.0, 0.0, 2.0, start=0.15, scale=0.1, doc="time constant, s")},
    ),
    "steering_rate": EffectSpec(
        "the wheels turn no faster than a servo's slew rate, whatever the command asks",
        {
            "s_per_60deg": ParamSpec(
                0.0, 0.0, 2.0, start=0.3, scale=0.3, doc="seconds to turn the wheels 60° (a servo's datasheet)"
            )
        },
    ),
    "speed_gain": EffectSpec(
        "the wheels run at gain × the commanded speed",
        {"gain": ParamSpec(1.0, 0.2, 2.0, start=0.9, scale=0.1, doc="effective / commanded speed")},
    ),
    "speed_delay": EffectSpec(
        "dead time between a speed command and the wheels changing speed",
        {"delay_s": ParamSpec(0.0, 0.0, 0.5, start=0.05, scale=0.03, doc="dead time, s")},
    ),
    "speed_lag": EffectSpec(
        "the wheel speed target follows the command as a first-order lag",
        {"tau_s": ParamSpec(0.0, 0.0, 2.0, start=0.15, scale=0.1, doc="time constant, s")},
    ),
    "speed_rate": EffectSpec(
        "the wheel speed target changes no faster than a rate: the largest acceleration the drive gives",
        {
            "s_per_mps": ParamSpec(
                0.0, 0.0, 2.0, start=0.3, scale=0.3, doc="seconds to change speed by 1 m/s (1 / acceleration)"
            )
        },
    ),
    "understeer": EffectSpec(
        "curvature lost with speed: the effective angle is divided by 1 + k·v² (v the wheel speed target)",
        {"k_s2pm2": ParamSpec(0.0, 0.0, 10.0, start=0.1, scale=0.1, doc="k, s²/m²")},
    ),
    "tyre_friction": EffectSpec(
        "tyre-ground friction coefficient: how much lateral grip the car has before it slides",
        {"mu": ParamSpec(1.0, 0.2, 3.0, start=1.3, scale=0.2, doc="friction coefficient (the model's is 1.0)")},
        acts_on="model",
    ),
    # The identity values below are the compiled sim/assets/car.xml's (rounded); an absent effect leaves the
    # compiled model untouched, so the default car stays exactly as compiled.
    "chassis": EffectSpec(
        "the car body (chassis, camera, shell: everything rigid): its mass, centre of mass and inertia",
        {
            "mass_kg": ParamSpec(1.4, 0.2, 20.0, start=1.4, scale=0.2, doc="mass, kg"),
            "com_x_m": ParamSpec(
                -0.0061, -0.1, 0.1, start=-0.0061, scale=0.005, doc="centre of mass ahead of base_link, m"
            ),
            "com_z_m": ParamSpec(
                0.0225, -0.03, 0.1, start=0.0225, scale=0.005, doc="centre of mass above the axles, m"
            ),
            "ixx_kgm2": ParamSpec(
                0.0017, 1e-5, 1.0, start=0.0017, scale=0.0005, doc="roll inertia about the centre of mass"
            ),
            "iyy_kgm2": ParamSpec(
                0.0057, 1e-5, 1.0, start=0.0057, scale=0.0005, doc="pitch inertia about the centre of mass"
            ),
            "izz_kgm2": ParamSpec(
                0.0068, 1e-5, 1.0, start=0.0068, scale=0.0005, doc="yaw inertia about the centre of mass"
            ),
        },
        acts_on="model",
        candidate=False,
    ),
    "wheels": EffectSpec(
        "mass and inertia of each wheel, and the mass of each steering hinge",
        {
            "mass_kg": ParamSpec(0.06, 0.005, 2.0, start=0.06, scale=0.01, doc="mass of one wheel, kg"),
            "spin_inertia_kgm2": ParamSpec(2.94e-5, 1e-6, 0.01, start=2.94e-5, scale=1e-5, doc="about the axle, kg·m²"),
            "cross_inertia_kgm2": ParamSpec(
                2.94e-5, 1e-6, 0.01, start=2.94e-5, scale=1e-5, doc="about a diameter, kg·m²"
            ),
            "hinge_mass_kg": ParamSpec(0.02, 0.001, 1.0, start=0.02, scale=0.01, doc="mass of one steering hinge, kg"),
        },
        acts_on="model",
        candidate=False,
    ),
    "drive": EffectSpec(
        "the wheel drives: torque = gain × (target − actual wheel speed), within ± max torque",
        {
            "rear_gain_nms": ParamSpec(0.02, 1e-3, 10.0, start=0.02, scale=0.01, doc="rear wheels, N·m per rad/s"),
            "front_gain_nms": ParamSpec(0.02, 1e-3, 10.0, start=0.02, scale=0.01, doc="front wheels, N·m per rad/s"),
            "max_torque_nm": ParamSpec(
                0.12, 0.01, 20.0, start=0.12, scale=0.05, doc="largest torque of one wheel's drive, N·m"
            ),
        },
        acts_on="model",
        candidate=False,
    ),
}
"""The effects, by name. Order of application of the command effects (fixed, whatever the file's order):
steering offset, gain and saturation, then delay, then lag, then the slew rate, then understeer; speed gain, then
delay, then lag, then the rate.
The model effects (``tyre_friction``, ``chassis``, ``wheels``, ``drive``) are properties of the car itself."""

MODEL_EFFECTS = tuple(name for name, spec in EFFECTS.items() if spec.acts_on == "model")
"""Effects that ``sim.physics`` writes into the MuJoCo model (the others act on the commands)."""
CANDIDATE_EFFECTS = tuple(name for name, spec in EFFECTS.items() if spec.candidate)
"""Effects ``racer calibrate`` tries unless told which (``--effect``)."""


class CalibrationError(UserError, ValueError):
    """A calibration file that cannot be used; the one-line message names the file and the bad value."""


class CarEffect(BaseModel):
    """One effect of a calibration with its parameter values."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str
    """An effect name from :data:`EFFECTS`."""
    params: dict[str, float]
    """Parameter values, by the names in :data:`EFFECTS` (units in their names: _s, _deg, ...)."""
    stderr: dict[str, float] | None = None
    """Standard error of each parameter from the fit (informative; not used by the simulator)."""

    @field_validator("name")
    @classmethod
    def _known(cls, name: str) -> str:
        if name not in EFFECTS:
            raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
        return name

    @model_validator(mode="after")
    def _params_match(self) -> CarEffect:
        spec = EFFECTS[self.name].params
        if set(self.params) != set(spec):
            raise ValueError(f"effect {self.name!r} takes params {sorted(spec)}, got {sorted(self.params)}")
        for key, value in self.params.items():
            p = spec[key]
            if not (math.isfinite(value) and p.low <= value <= p.high):
                raise ValueError(f"{self.name}.{key} = {value} is outside [{p.low}, {p.high}]")
        return self


class CarCalibration(BaseModel):
    """The car's effects: its physical properties and what lies between command and wheels. No effects = the
    car as modelled (the default)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    version: int = Field(1, ge=1, le=1)
    """File format version."""
    about: str | None = None
    """Where the values came from (informative; not used by the simulator)."""
    effects: list[CarEffect] = Field(default_factory=list)
    """The effects, each at most once."""

    @model_validator(mode="after")
    def _unique(self) -> CarCalibration:
        names = [e.name for e in self.effects]
        for name in names:
            if names.count(name) > 1:
                raise ValueError(f"effect {name!r} appears more than once")
        return self

    def value(self, effect: str, param: str) -> float:
        """A parameter's value, or its identity value when the effect is absent."""
        for e in self.effects:
            if e.name == effect:
                return e.params[param]
        return EFFECTS[effect].params[param].identity

    def has(self, effect: str) -> bool:
        """True when the file names this effect (at whatever value)."""
        return any(e.name == effect for e in self.effects)

    @property
    def is_identity(self) -> bool:
        """True when no effect changes anything (the uncalibrated car)."""
        return all(v == EFFECTS[e.name].params[k].identity for e in self.effects for k, v in e.params.items())

    @property
    def acts_on_commands(self) -> bool:
        """True when an effect sits between the command and the servos (all but the model's properties)."""
        return any(e.name not in MODEL_EFFECTS for e in self.effects)

    @classmethod
    def from_values(cls, values: dict[str, dict[str, float]], stderr: dict[str, dict[str, float]] | None = None):
        """Build from ``{effect: {param: value}}`` (and optional standard errors in the same shape)."""
        stderr = stderr or {}
        return cls(effects=[CarEffect(name=n, params=p, stderr=stderr.get(n)) for n, p in values.items()])


def load_calibration(path: str | Path | Traversable) -> CarCalibration:
    """Read and validate a calibration file; any problem is a :class:`CalibrationError` naming the file."""
    path = Path(path) if isinstance(path, str) else path
    try:
        text = path.read_text()
    except OSError as exc:
        raise CalibrationError(f"car calibration {path}: cannot read it ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise CalibrationError(f"car calibration {path}: not UTF-8 text") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"car calibration {path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    try:
        return CarCalibration.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = error_location(err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        raise CalibrationError(f"car calibration {path}: {where + ': ' if where else ''}{msg}") from None


def save_calibration(calibration: CarCalibration, path: str | Path) -> None:
    """Write a calibration file (JSON, indented)."""
    Path(path).write_text(calibration.model_dump_json(indent=2, exclude_none=True) + "\n")


PRESET_FILES: dict[str, str | None] = {
    "default": None,
    "deepracer-gazebo": "deepracer-gazebo.json",
    "deepracer-gazebo-ros2": "deepracer-gazebo-ros2.json",
}
"""Preset names and their car files in ``sim/cars/`` (``default``: the car as modelled, no file)."""


@cache
def _load_preset(name: str) -> CarCalibration:
    file = PRESET_FILES[name]
    if file is None:
        return CarCalibration()
    from importlib import resources

    # Read through importlib.resources, so that an installed package finds its own copy. Looked up here, not at
    # import: finding ``sim`` imports it, and the car runtime (deploy/) imports this module but never a preset.
    return load_calibration(resources.files("sim") / "cars" / file)


class _Presets(Mapping[str, CarCalibration]):
    """Name → car, each read from its shipped file on first use."""

    def __getitem__(self, name: str) -> CarCalibration:
        if name not in PRESET_FILES:
            raise KeyError(name)
        return _load_preset(name)

    def __iter__(self) -> Iterator[str]:
        return iter(PRESET_FILES)

    def __len__(self) -> int:
        return len(PRESET_FILES)


CAR_PRESETS: Mapping[str, CarCalibration] = _Presets()
"""Cars known by name (``--car NAME``): ``default`` is the car as modelled, with no effects;
``deepracer-gazebo`` is DeepRacer's Gazebo car of the ROS1 simapp (the AWS console and DeepRacer-for-Cloud
up to 2025), ``deepracer-gazebo-ros2`` that of the ROS2 simapp 6 (gz-sim, 2026); see ``sim/cars/SOURCES.md``."""


def load_car(spec: str | Path) -> CarCalibration:
    """``--car NAME|FILE``: a preset's name, or a car.json written by ``racer calibrate``; a one-line
    CalibrationError naming the value otherwise."""
    name = str(spec)
    if name in CAR_PRESETS:
        return CAR_PRESETS[name]
    path = Path(name)
    if path.suffix == ".json" or path.exists():
        return load_calibration(path)
    raise CalibrationError(f"car {name!r} is neither a preset ({', '.join(CAR_PRESETS)}) nor a car.json file")
