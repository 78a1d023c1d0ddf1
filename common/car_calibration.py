"""The car calibration file (``car.json``): effects between the command and the wheels, with their parameters.

``racer calibrate`` writes it; ``racer train/eval/bench --car-calibration F`` load it and every env of the run
applies it (``sim/actuation.py`` holds the maths). The file::

    {"version": 1,
     "effects": [{"name": "steering_lag", "params": {"tau_s": 0.55}, "stderr": {"tau_s": 0.02}}, ...]}

Each effect is named from :data:`EFFECTS`; an effect that is absent acts as the identity. ``stderr`` is
informative (the fit's standard error) and optional. The file is validated in full: an unknown effect or
parameter, a missing parameter, a value outside its physical range or a repeated effect is refused with one
line naming it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect: its identity value, physical bounds, a start for fitting and its meaning."""

    identity: float
    """The value at which the effect does nothing."""
    low: float
    high: float
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


EFFECTS: dict[str, EffectSpec] = {
    "steering_offset": EffectSpec(
        "a constant added to the commanded steering angle (a mis-centred servo)",
        {"offset_deg": ParamSpec(0.0, -10.0, 10.0, 0.5, 1.0, "added angle, degrees, + = left")},
    ),
    "steering_gain": EffectSpec(
        "the wheels turn by gain × the commanded angle",
        {"gain": ParamSpec(1.0, 0.05, 2.0, 0.9, 0.1, "effective / commanded angle")},
    ),
    "steering_saturation": EffectSpec(
        "the wheels turn no further than a limit, whatever the command",
        {"max_deg": ParamSpec(30.0, 1.0, 30.0, 20.0, 2.0, "largest effective angle, degrees")},
    ),
    "steering_delay": EffectSpec(
        "dead time between a steering command and the wheels starting to turn",
        {"delay_s": ParamSpec(0.0, 0.0, 0.5, 0.05, 0.03, "dead time, s")},
    ),
    "steering_lag": EffectSpec(
        "the wheels follow the steering command as a first-order lag",
        {"tau_s": ParamSpec(0.0, 0.0, 2.0, 0.15, 0.1, "time constant, s")},
    ),
    "speed_gain": EffectSpec(
        "the wheels run at gain × the commanded speed",
        {"gain": ParamSpec(1.0, 0.2, 2.0, 0.9, 0.1, "effective / commanded speed")},
    ),
    "speed_delay": EffectSpec(
        "dead time between a speed command and the wheels changing speed",
        {"delay_s": ParamSpec(0.0, 0.0, 0.5, 0.05, 0.03, "dead time, s")},
    ),
    "speed_lag": EffectSpec(
        "the wheel speed target follows the command as a first-order lag",
        {"tau_s": ParamSpec(0.0, 0.0, 2.0, 0.15, 0.1, "time constant, s")},
    ),
    "understeer": EffectSpec(
        "curvature lost with speed: the effective angle is divided by 1 + k·v² (v the wheel speed target)",
        {"k_s2pm2": ParamSpec(0.0, 0.0, 10.0, 0.1, 0.1, "k, s²/m²")},
    ),
    "tyre_friction": EffectSpec(
        "tyre-ground friction coefficient: how much lateral grip the car has before it slides",
        {"mu": ParamSpec(1.0, 0.2, 3.0, 1.3, 0.2, "friction coefficient (the model's is 1.0)")},
    ),
}
"""The candidate effects, by name. Order of application (fixed, whatever the file's order): steering
offset, gain and saturation, then delay, then lag, then understeer; speed gain, then delay, then lag. All but
``tyre_friction`` act between the command and the servos; ``tyre_friction`` is a property of the tyres."""


_TYRE_EFFECTS = ("tyre_friction",)


class CalibrationError(ValueError):
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
    """Effects between the command and the wheels. No effects = the car as modelled (the default)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    version: int = Field(1, ge=1, le=1)
    """File format version."""
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

    @property
    def is_identity(self) -> bool:
        """True when no effect changes anything (the uncalibrated car)."""
        return all(v == EFFECTS[e.name].params[k].identity for e in self.effects for k, v in e.params.items())

    @property
    def acts_on_commands(self) -> bool:
        """True when an effect sits between the command and the servos (all but the tyres' properties)."""
        return any(e.name not in _TYRE_EFFECTS for e in self.effects)

    @classmethod
    def from_values(cls, values: dict[str, dict[str, float]], stderr: dict[str, dict[str, float]] | None = None):
        """Build from ``{effect: {param: value}}`` (and optional standard errors in the same shape)."""
        stderr = stderr or {}
        return cls(effects=[CarEffect(name=n, params=p, stderr=stderr.get(n)) for n, p in values.items()])


def load_calibration(path: str | Path) -> CarCalibration:
    """Read and validate a calibration file; any problem is a :class:`CalibrationError` naming the file."""
    path = Path(path)
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
        where = ".".join(str(p) for p in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        raise CalibrationError(f"car calibration {path}: {where + ': ' if where else ''}{msg}") from None


def save_calibration(calibration: CarCalibration, path: str | Path) -> None:
    """Write a calibration file (JSON, indented)."""
    Path(path).write_text(calibration.model_dump_json(indent=2, exclude_none=True) + "\n")


CAR_PRESETS: dict[str, CarCalibration] = {"default": CarCalibration()}
"""Cars known by name (``--car NAME``): ``default`` is the car as modelled, with no effects."""


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
