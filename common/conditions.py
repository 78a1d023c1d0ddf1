"""Held-out conditions: worlds a checkpoint never trained in (``racer eval --condition``).

The DeepRacer paper (Balaji et al., Table II) drives each trained policy in five real conditions it never saw:
the track at 0.5 m/s and at 1 m/s, in bright sunlight, with no barriers around it, and a track made of tape.
racer builds such worlds from its own parts: a condition is a :class:`Condition`, a named
:class:`common.config.WorldCondition` (what the camera sees, the speed cap, the camera's mounting and pipeline)
and optionally another car (a preset or a car.json: the "real" car).

- :data:`CONDITIONS` names racer's own (``racer eval --condition NAME``; ``racer eval --help`` lists them).
- A JSON file with the fields of :class:`Condition` is a user's own (``--condition my.json``).
- ``A+B`` combines conditions into one world (``tape+sunlight``); a field both set differently is an error.
- ``A,B`` (or the option repeated) evaluates each condition on its own.
"""

from __future__ import annotations

import json
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from common.car_calibration import load_car
from common.config import EnvConfig, WorldCondition
from common.errors import OptionError, error_location

TAPE_FLOOR = (150, 142, 132)
"""A grey concrete or lino floor, RGB: what a tape track is laid on."""


class Condition(BaseModel):
    """A named held-out condition: how the world differs, and optionally the car that drives in it."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    name: str = Field(pattern=r"^[A-Za-z0-9._+-]+$")
    """How reports name it."""
    about: str = ""
    """What it is, in a sentence."""
    car: str | None = None
    """A car preset's name or a car.json path (None: the car of the run or of ``--car``)."""
    world: WorldCondition = Field(default_factory=WorldCondition)
    """How the world differs."""


def _named(name: str, about: str, car: str | None = None, **world) -> Condition:
    return Condition(name=name, about=about, car=car, world=WorldCondition(**world))


CONDITIONS: dict[str, Condition] = {
    c.name: c
    for c in (
        _named("speed-0.5", "the speed capped at 0.5 m/s, whatever the policy asks (the paper's first column)",
               speed_cap_mps=0.5),
        _named("speed-1.0", "the speed capped at 1 m/s (the paper's second column)", speed_cap_mps=1.0),
        _named("sunlight", "a sunny window: exposure up, a glare patch and hard shadows across the track",
               sunlight=1.0),
        _named("no-barriers", "what lies around the track changes: a grey floor and a white room instead of the "
               "green field and the sky", background=(128, 124, 118), sky=(226, 226, 222)),
        _named("tape", "a tape track: white tape borders on a plain floor, no road surface and no centre line",
               road=TAPE_FLOOR, background=TAPE_FLOOR, center=TAPE_FLOOR, border=(245, 245, 245)),
        _named("camera-up", "the camera tilted 3° less downwards", camera_pitch_deg=-3.0),
        _named("camera-down", "the camera tilted 3° more downwards", camera_pitch_deg=3.0),
        _named("blur", "an out-of-focus lens: Gaussian blur of 1.2 pixels", blur_px=1.2),
        _named("noise", "a noisy sensor: Gaussian noise of 12 grey levels per pixel", sensor_noise=12.0),
        _named("latency", "one frame of camera latency (67 ms)", frame_latency=1),
        _named("gazebo-car", "DeepRacer's Gazebo car (the deepracer-gazebo preset: 0.5 s steering lag)",
               car="deepracer-gazebo"),
    )
}  # fmt: skip
"""racer's named conditions (``--condition NAME``)."""


def load_condition(spec: str) -> Condition:
    """One condition: a name from :data:`CONDITIONS`, a JSON file of :class:`Condition`, or ``A+B+…`` combining
    them into one world. OptionError (one line, naming the value) for anything else."""
    parts = [p.strip() for p in spec.split("+")]
    if len(parts) > 1:
        return combine([load_condition(p) for p in parts])
    if spec in CONDITIONS:
        return CONDITIONS[spec]
    path = Path(spec)
    if path.suffix != ".json":
        raise OptionError(f"--condition {spec!r} is neither a condition ({', '.join(CONDITIONS)}) nor a .json file")
    try:
        data = json.loads(path.read_text())
        condition = Condition.model_validate(data)
    except OSError as exc:
        raise OptionError(f"--condition {spec}: cannot read it ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise OptionError(f"--condition {spec}: not JSON ({exc.msg}, line {exc.lineno})") from None
    except ValidationError as exc:
        err = exc.errors()[0]
        where = error_location(err["loc"])
        raise OptionError(f"--condition {spec}: {where}: {err['msg']} (got {err.get('input')!r})") from None
    if condition.car is not None:
        load_car(condition.car)  # a bad car is said now, naming it, not in the middle of an evaluation
    return condition


def load_conditions(specs: list[str]) -> list[Condition]:
    """The conditions of ``--condition`` values, each possibly ``A,B`` (evaluated one after another)."""
    out = [load_condition(s.strip()) for spec in specs for s in spec.split(",") if s.strip()]
    names = [c.name for c in out]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise OptionError(f"--condition {', '.join(repeated)} is given more than once")
    return out


def combine(conditions: list[Condition]) -> Condition:
    """One world with every condition's changes (``A+B``); OptionError if two set one field differently."""
    world: dict = {}
    car: str | None = None
    defaults = WorldCondition()
    for c in conditions:
        for key, value in c.world.model_dump().items():
            if value == getattr(defaults, key):
                continue
            if key in world and world[key] != value:
                raise OptionError(f"--condition {'+'.join(x.name for x in conditions)}: both set {key} differently")
            world[key] = value
        if c.car is not None:
            if car is not None and car != c.car:
                raise OptionError(f"--condition {'+'.join(x.name for x in conditions)}: two different cars")
            car = c.car
    name = "+".join(c.name for c in conditions)
    about = "; ".join(c.about for c in conditions if c.about)
    return Condition(name=name, about=about, car=car, world=WorldCondition(**world))


def apply_condition(env: EnvConfig, condition: Condition) -> EnvConfig:
    """The env of a run driven in ``condition``: its world changes, and its car if it names one."""
    update: dict = {"condition": condition.world}
    if condition.car is not None:
        update["car"] = load_car(condition.car)
    return env.model_copy(update=update)
