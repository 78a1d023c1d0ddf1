"""A run's time limit: parsed from its text once, and kept as one deadline every process reads."""

from __future__ import annotations

import re
import time

from pydantic import BaseModel, ConfigDict, Field

from common.errors import OptionError

_DURATION = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([smh]?)\s*$")


def parse_duration(text: str, name: str = "duration") -> float:
    """Seconds in ``90s``, ``5m`` or ``1.5h``, given by a user as ``name`` (a flag, an env var, a key); an
    OptionError naming it and the text otherwise.

    A bare number is refused: ``5`` given to ``--time-limit`` meant five minutes to the user who typed it and was
    five seconds to racer, a run over before it began. Seconds that are a number already (a run's options as JSON)
    are a float field, not text for this parser.
    """
    m = _DURATION.match(text)
    if not m:
        raise OptionError(f"{name} {text!r} is not valid: use a number with s, m or h (90s, 5m, 2h)")
    number, unit = m.groups()
    if not unit:
        raise OptionError(f"{name} {text.strip()}: give a unit: {number}s, {number}m or {number}h")
    return float(number) * {"s": 1, "m": 60, "h": 3600}[unit]


class Deadline(BaseModel):
    """When a run stops: an absolute wall-clock time (``time.time()``), so that the launcher and the roles it starts
    (other processes) stop at the same moment, and the limit's length, which the learning-rate cool-down counts
    back over."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    at: float
    """The moment the run stops, seconds since the epoch."""
    limit_s: float = Field(gt=0)
    """The time limit it was set from (``--time-limit``), seconds."""

    @classmethod
    def after(cls, limit_s: float) -> Deadline:
        """The deadline ``limit_s`` seconds from now."""
        return cls(at=time.time() + limit_s, limit_s=limit_s)

    def left(self) -> float:
        """Seconds until the deadline (negative once it has passed)."""
        return self.at - time.time()

    def elapsed(self) -> float:
        """Seconds since the deadline was set."""
        return self.limit_s - self.left()

    def passed(self) -> bool:
        """True once the deadline has come."""
        return time.time() >= self.at
