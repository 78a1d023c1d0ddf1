"""A car's vehicle calibration: how a (steering degrees, speed m/s) action becomes servo and ESC outputs.

Like the DeepRacer console's calibration, it holds the steering servo's centre and its full-left and full-right
outputs, the ESC's stop and full-forward outputs, a throttle curve (which ESC fraction gives which speed) and a
maximum-speed percentage. Outputs are in the driver's units (PWM microseconds by default; any linear unit works).

Optionally it carries the effects ``racer calibrate`` fitted on this car (``car``): a static steering offset and
gain, and a speed gain, are then compensated so that the car does what the policy asked. Dynamic effects (lags,
delays) cannot be undone by a static map and are left as they are: the policy was trained with them if the run
used the same calibration.
"""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from common.action_space import MAX_STEERING_DEG
from common.car_calibration import CarCalibration
from common.errors import UserError
from common.jsonfile import load_json_model


class VehicleCalibrationError(UserError, ValueError):
    """A vehicle calibration file that cannot be used; the message names the file and the field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class SteeringServo(_Strict):
    """The steering servo's outputs at the centre and at full lock each way."""

    center: float = 1500.0
    """Output that points the wheels straight ahead (after trimming), driver units."""
    left: float = 1900.0
    """Output at full left lock, ``max_angle_deg`` to the left."""
    right: float = 1100.0
    """Output at full right lock."""
    max_angle_deg: float = Field(MAX_STEERING_DEG, gt=0, le=45)
    """The wheel angle reached at ``left``/``right``, degrees."""


class Throttle(_Strict):
    """The ESC's outputs and the measured throttle → speed curve."""

    stop: float = 1500.0
    """Output at which the car stands still, driver units."""
    full: float = 1800.0
    """Output at full forward throttle."""
    curve: list[tuple[float, float]] = Field(default_factory=lambda: [(0.0, 0.0), (4.0, 1.0)])
    """(speed m/s, throttle fraction 0..1) points measured on the car, speed increasing; linear in between."""
    max_speed_pct: float = Field(100.0, gt=0, le=100)
    """Scales every throttle fraction, as the DeepRacer console's maximum-speed percentage does."""

    @model_validator(mode="after")
    def _increasing(self) -> Throttle:
        speeds = [s for s, _ in self.curve]
        fractions = [f for _, f in self.curve]
        if len(self.curve) < 2 or any(b <= a for a, b in zip(speeds, speeds[1:], strict=False)):
            raise ValueError("curve needs at least two points with increasing speeds")
        if not all(0 <= f <= 1 and math.isfinite(f) for f in fractions) or speeds[0] < 0:
            raise ValueError("curve fractions must lie in 0..1 and speeds be >= 0")
        return self


class VehicleCalibration(_Strict):
    """One car's calibration file (``vehicle.json``)."""

    steering: SteeringServo = Field(default_factory=SteeringServo)
    throttle: Throttle = Field(default_factory=Throttle)
    car: CarCalibration = Field(default_factory=CarCalibration)
    """Effects fitted by ``racer calibrate`` on this car; static ones are compensated."""


@dataclass(frozen=True)
class MotorCommand:
    """What goes to the car for one frame."""

    frame: int
    action: int | None
    """The discrete action index, or None for a continuous policy."""
    steering_deg: float
    """The policy's steering angle, degrees, positive left."""
    speed_mps: float
    """The policy's speed, m/s."""
    _: KW_ONLY
    steering_out: float
    """Servo output, driver units."""
    throttle_out: float
    """ESC output, driver units."""


def load_vehicle_calibration(path: str | Path) -> VehicleCalibration:
    """Read ``vehicle.json``; VehicleCalibrationError naming the file and the bad field."""
    return load_json_model(path, "vehicle calibration", VehicleCalibration, VehicleCalibrationError)


def steering_output(cal: VehicleCalibration, steering_deg: float) -> float:
    """Servo output for a wheel angle (positive left), after undoing a fitted static offset and gain."""
    car = cal.car
    gain = car.value("steering_gain", "gain")
    offset = car.value("steering_offset", "offset_deg")
    angle = (steering_deg - offset) / gain  # the car turns gain·command + offset: ask for what gives the target
    s = cal.steering
    fraction = float(np.clip(angle / s.max_angle_deg, -1.0, 1.0))
    return s.center + fraction * ((s.left - s.center) if fraction >= 0 else (s.center - s.right))


def throttle_output(cal: VehicleCalibration, speed_mps: float) -> float:
    """ESC output for a speed: the curve's fraction (after undoing a fitted speed gain), times max_speed_pct."""
    gain = cal.car.value("speed_gain", "gain")
    t = cal.throttle
    speeds, fractions = zip(*t.curve, strict=True)
    fraction = float(np.interp(max(speed_mps, 0.0) / gain, speeds, fractions)) * t.max_speed_pct / 100.0
    return t.stop + fraction * (t.full - t.stop)


def motor_command(
    cal: VehicleCalibration, frame: int, action: int | None, steering_deg: float, speed_mps: float
) -> MotorCommand:
    """The outputs for one frame's action."""
    return MotorCommand(
        frame,
        action,
        steering_deg,
        speed_mps,
        steering_out=steering_output(cal, steering_deg),
        throttle_out=throttle_output(cal, speed_mps),
    )
