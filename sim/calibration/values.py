"""The fitted calibration as a user reads it: each effect's value in its plain physical sense, with an interval.

``car.json`` holds the parameters as the simulator applies them (``sim.actuation``); the report gives, beside
them, what they mean for the car, relative to the calibrated car's own base:

- steering offset: degrees added to the *command* (the file's offset is added after the steering gain, so it
  is divided by that gain); slew rate: the seconds the wheels take to turn 60° at their fastest, as a servo's
  datasheet gives it;
- steering and speed gain: effective / commanded; dead time: s from a command step to the first response;
  lag: the first-order time constant, s; understeer k: the effective angle is divided by 1 + k·v²;
  saturation: the largest wheel angle, degrees; tyre friction: the friction coefficient.

Each value comes with its standard error (cluster-robust by episode, from the fit) and a 95 % interval. Where
the data cannot tell an effect from its nearest alternative (``sim.calibration.fit.PARTNERS``: a dead time
from a lag at 15 Hz, understeer from a gain at one speed), the entry says ``ambiguous_with`` and gives what the
data does determine: the total delay (the mean delay of the response to a step: dead time + time constant, plus
half the slew time of the logs' median steering step) or the effective steering gain at the logs' speeds.
"""

from __future__ import annotations

import math

from common.car_calibration import EFFECTS, CarCalibration, CarEffect

Z95 = 1.96
"""Half-width of a 95 % interval, in standard errors."""

MEANING = {
    "steering_offset": ("offset_deg", "deg", "degrees added to the steering command"),
    "steering_gain": ("gain", "", "effective / commanded steering angle"),
    "steering_saturation": ("max_deg", "deg", "largest effective wheel angle"),
    "steering_delay": ("delay_s", "s", "dead time from a steering command step to the first response"),
    "steering_lag": ("tau_s", "s", "first-order time constant of the steering response"),
    "steering_rate": ("s_per_60deg", "s/60°", "seconds the wheels take to turn 60° at their fastest"),
    "speed_gain": ("gain", "", "effective / commanded speed"),
    "speed_delay": ("delay_s", "s", "dead time from a speed command step to the first response"),
    "speed_lag": ("tau_s", "s", "first-order time constant of the speed response"),
    "speed_rate": ("s_per_mps", "s/(m/s)", "seconds to change speed by 1 m/s at the fastest (1 / top acceleration)"),
    "understeer": ("k_s2pm2", "s²/m²", "the effective angle is divided by 1 + k·v²"),
    "tyre_friction": ("mu", "", "tyre-ground friction coefficient (racer's car: 1.0)"),
}
"""Per effect: the parameter reported, its unit and what it means."""

_CHANNELS = {
    "steering": ("steering_delay", "steering_lag", "steering_rate", 60.0),
    "speed": ("speed_delay", "speed_lag", "speed_rate", 1.0),
}
"""Per channel: its dead time, lag and rate limit, and the unit its rate limit's time is given per."""
DEFAULT_STEPS = {"steering": 15.0, "speed": 0.5}
"""A typical command step per channel (degrees, m/s), where the logs give none."""


def describe(
    cal: CarCalibration,
    names: list[str],
    *,
    ambiguous: dict[str, list[str]] | None = None,
    mean_v2: float = 1.0,
    steps: dict[str, float] | None = None,
) -> list[dict]:
    """Report entries for the effects ``names`` of ``cal``: the file's params and stderr, and the value in its
    physical sense with its standard error and 95 % interval. ``ambiguous`` (effect → the effects the data cannot
    tell it from) adds ``ambiguous_with`` and what the data determines. ``mean_v2``: the logs' mean squared
    speed, m²/s²; ``steps``: their median command step per channel (``sim.calibration.plan.command_steps``)."""
    ambiguous = ambiguous or {}
    out = []
    for effect in [e for e in cal.effects if e.name in names]:
        entry = effect.model_dump(exclude_none=True)
        if effect.name in MEANING:
            entry.update(_value(cal, effect))
        if effect.name in ambiguous:
            entry["ambiguous_with"] = sorted(ambiguous[effect.name])
            entry["determined"] = determined(cal, effect.name, mean_v2, steps or DEFAULT_STEPS)
        out.append(entry)
    return out


def _value(cal: CarCalibration, effect: CarEffect) -> dict:
    key, unit, meaning = MEANING[effect.name]
    value, se = effect.params[key], (effect.stderr or {}).get(key)
    if effect.name == "steering_offset":  # added after the gain in the file: in command degrees, divide by it
        gain = cal.value("steering_gain", "gain")
        value, se = value / gain, (se / gain if se is not None else None)
    return {"value": round(value, 5), "unit": unit, "meaning": meaning, **_interval(value, se, effect.name, key)}


def _interval(value: float, se: float | None, name: str, key: str) -> dict:
    if se is None:
        return {}
    spec = EFFECTS[name].params[key]
    lo = max(value - Z95 * se, spec.low) if name != "steering_offset" else value - Z95 * se
    hi = min(value + Z95 * se, spec.high) if name != "steering_offset" else value + Z95 * se
    return {"value_stderr": round(se, 5), "interval_95": [round(lo, 5), round(hi, 5)]}


def determined(cal: CarCalibration, name: str, mean_v2: float, steps: dict[str, float] = DEFAULT_STEPS) -> dict:
    """What the data does determine where ``name`` and its partner cannot be told apart: the total delay of its
    channel, s (the mean delay of the response to a step: dead time + lag time constant + half the time the rate
    limit takes over the logs' median step, ``steps[channel]``); or the effective steering gain at the logs' mean
    squared speed."""
    for channel, (delay, lag, rate, unit) in _CHANNELS.items():
        if name in (delay, lag, rate):
            half_ramp = steps[channel] / unit / 2  # a ramp's mean delay, per second-per-unit of the rate limit
            total = cal.value(delay, "delay_s") + cal.value(lag, "tau_s")
            rate_key = next(iter(EFFECTS[rate].params))
            total += half_ramp * cal.value(rate, rate_key)
            se2 = (
                _se(cal, delay, "delay_s") ** 2
                + _se(cal, lag, "tau_s") ** 2
                + (half_ramp * _se(cal, rate, rate_key)) ** 2
            )
            return {
                f"{channel}_total_delay_s": round(total, 5),
                "stderr": round(math.sqrt(se2), 5),
                "at_step": steps[channel],
            }
    gain = cal.value("steering_gain", "gain") / (1 + cal.value("understeer", "k_s2pm2") * mean_v2)
    return {"steering_gain_at_logged_speeds": round(gain, 5), "mean_speed_squared_m2ps2": round(mean_v2, 4)}


def _se(cal: CarCalibration, name: str, key: str) -> float:
    effect = next((e for e in cal.effects if e.name == name), None)
    return float((effect.stderr or {}).get(key, 0.0)) if effect is not None else 0.0
