"""What happens between a command and the wheels: the calibrated effects of ``common.car_calibration``.

The MuJoCo car's own servos follow their targets within a few hundredths of a second; a real car (or
DeepRacer's Gazebo car) does not. :class:`Actuation` turns the commanded steering angle and speed, one value
per physics substep, into the servo targets, applying in this order:

- steering: ``clip(gain · cmd, ±max_deg) + offset_deg``, then a dead time ``delay_s``, then a first-order lag
  ``tau_s``, then a slew rate (60° in ``s_per_60deg`` at most), then understeer ``/ (1 + k · v²)`` with v the
  speed target below, then the hinge range ±30°;
- speed: ``gain · cmd``, then a dead time ``delay_s``, then a first-order lag ``tau_s``, then a rate limit (1 m/s
  in ``s_per_mps`` at most: the largest acceleration).

Dead time is applied to the substep-averaged signal, so a delay that is not a whole number of substeps
interpolates between them (and a fit sees an error that changes smoothly with it). The lag is the exact
discretization of ``τ dy/dt = u - y`` for an input held over each substep. Both are state carried between
calls, so feeding a sequence in pieces gives the same result as feeding it at once; :func:`actuate_sequence`
is the batch form the calibration replay uses, and the env steps :meth:`Actuation.step` per control period.
"""

from __future__ import annotations

import copy
import math
from dataclasses import KW_ONLY, dataclass

import numpy as np

from common.action_space import MAX_STEERING_DEG
from common.car_calibration import CarCalibration


@dataclass(frozen=True)
class ActuationParams:
    """The parameter values of every effect (identity values for the absent ones)."""

    steer_offset_deg: float
    steer_gain: float
    steer_max_deg: float
    steer_delay_s: float
    steer_tau_s: float
    steer_s_per_60deg: float
    speed_gain: float
    speed_delay_s: float
    speed_tau_s: float
    speed_s_per_mps: float
    understeer_k: float

    @classmethod
    def from_calibration(cls, cal: CarCalibration) -> ActuationParams:
        """Read the values of a calibration."""
        return cls(
            steer_offset_deg=cal.value("steering_offset", "offset_deg"),
            steer_gain=cal.value("steering_gain", "gain"),
            steer_max_deg=cal.value("steering_saturation", "max_deg"),
            steer_delay_s=cal.value("steering_delay", "delay_s"),
            steer_tau_s=cal.value("steering_lag", "tau_s"),
            steer_s_per_60deg=cal.value("steering_rate", "s_per_60deg"),
            speed_gain=cal.value("speed_gain", "gain"),
            speed_delay_s=cal.value("speed_delay", "delay_s"),
            speed_tau_s=cal.value("speed_lag", "tau_s"),
            speed_s_per_mps=cal.value("speed_rate", "s_per_mps"),
            understeer_k=cal.value("understeer", "k_s2pm2"),
        )


@dataclass
class ActuationState:
    """What the effects remember: recent inputs of the dead times and the outputs of the lags."""

    steer_hist: np.ndarray
    """Recent inputs of the steering dead time, oldest first, degrees."""
    speed_hist: np.ndarray
    """Recent inputs of the speed dead time, oldest first, m/s."""
    _: KW_ONLY
    steer_y: float = 0.0
    speed_y: float = 0.0
    steer_slewed: float = 0.0
    """The steering rate limiter's output (degrees)."""
    speed_slewed: float = 0.0
    """The speed rate limiter's output (m/s)."""


def _history_len(delay_s: float, substep_s: float) -> int:
    return int(math.floor(delay_s / substep_s)) + 2


def initial_state(params: ActuationParams, substep_s: float) -> ActuationState:
    """The car at rest with its wheels straight (inputs and outputs all zero)."""
    return ActuationState(
        steer_hist=np.zeros(_history_len(params.steer_delay_s, substep_s)),
        speed_hist=np.zeros(_history_len(params.speed_delay_s, substep_s)),
    )


def _delay(u: np.ndarray, hist: np.ndarray, delay_s: float, substep_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Dead time of ``delay_s`` on a substep signal ``u``; ``hist`` holds the inputs before it (oldest first)."""
    if delay_s <= 0:
        return u, hist
    x = np.concatenate([hist, u])
    m, f = divmod(delay_s / substep_s, 1.0)
    start = len(hist) - int(m)
    # Each substep receives the input averaged over [t - delay, t - delay + h]: a blend of two neighbours.
    out = (1 - f) * x[start : start + len(u)] + f * x[start - 1 : start - 1 + len(u)]
    return out, x[-len(hist) :]


_LOOP_MAX = 64
"""Longest input :func:`_lag` filters in a Python loop; longer ones go to scipy's lfilter."""


def _lag(u: np.ndarray, y0: float, tau_s: float, substep_s: float) -> np.ndarray:
    """First-order lag, exact for an input held over each substep: y_j = a·y_(j-1) + (1 - a)·u_j."""
    if tau_s <= 0:
        return u
    a = math.exp(-substep_s / tau_s)
    if len(u) > _LOOP_MAX:  # a whole logged trajectory (calibration's replay)
        # Imported here: scipy.signal costs ~0.7 s to import, paid by every worker, trainer and evaluator at
        # start-up though they only ever filter a control period.
        from scipy.signal import lfilter

        y, _ = lfilter([1 - a], [1, -a], u, zi=[a * y0])
        return y
    # A plain loop for the env's control period (8 substeps): 1.3 us a call against lfilter's 5.7 us (timeit), about
    # 2 % of a Gazebo car's env step. Same operations in the same order as lfilter's direct form: the same floats.
    b = 1 - a
    y = np.empty(len(u))
    prev = y0
    for j, x in enumerate(u.tolist()):
        prev = b * x + a * prev
        y[j] = prev
    return y


def _slew(u: np.ndarray, y0: float, unit: float, s_per_unit: float, substep_s: float) -> np.ndarray:
    """Rate limit: each substep the output moves toward the input by at most ``unit · substep_s / s_per_unit``
    (the effects give the time per unit: per 60° of steering, per 1 m/s of speed)."""
    if s_per_unit <= 0:
        return u
    step = unit * substep_s / s_per_unit
    # A loop: each output depends on the last through the clip. A whole trajectory (~800 substeps) takes ~0.2 ms.
    y = np.empty(len(u))
    prev = y0
    for j, x in enumerate(u.tolist()):
        prev += min(max(x - prev, -step), step)
        y[j] = prev
    return y


def actuate(
    p: ActuationParams, steer_cmd: np.ndarray, speed_cmd: np.ndarray, state: ActuationState, substep_s: float
) -> tuple[np.ndarray, np.ndarray, ActuationState]:
    """Servo targets (steering deg, speed m/s) for commands given one per substep, and the state after them."""
    s = np.clip(p.steer_gain * np.asarray(steer_cmd, float), -p.steer_max_deg, p.steer_max_deg) + p.steer_offset_deg
    s, steer_hist = _delay(s, state.steer_hist, p.steer_delay_s, substep_s)
    s = _lag(s, state.steer_y, p.steer_tau_s, substep_s)
    steer_y = float(s[-1])
    s = _slew(s, state.steer_slewed, 60.0, p.steer_s_per_60deg, substep_s)
    v = p.speed_gain * np.asarray(speed_cmd, float)
    v, speed_hist = _delay(v, state.speed_hist, p.speed_delay_s, substep_s)
    v = _lag(v, state.speed_y, p.speed_tau_s, substep_s)
    speed_y = float(v[-1])
    v = _slew(v, state.speed_slewed, 1.0, p.speed_s_per_mps, substep_s)
    new_state = ActuationState(
        steer_hist, speed_hist, steer_y=steer_y, speed_y=speed_y, steer_slewed=float(s[-1]), speed_slewed=float(v[-1])
    )
    if p.understeer_k > 0:
        s = s / (1 + p.understeer_k * v * v)
    return np.clip(s, -MAX_STEERING_DEG, MAX_STEERING_DEG), v, new_state


def actuate_sequence(
    p: ActuationParams, steer_cmd: np.ndarray, speed_cmd: np.ndarray, substeps: int | np.ndarray, substep_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Servo targets, one per substep, for a sequence of commands applied from rest, each held for ``substeps``
    (one number for all, or one per command)."""
    steer, speed, _ = actuate(
        p, np.repeat(steer_cmd, substeps), np.repeat(speed_cmd, substeps), initial_state(p, substep_s), substep_s
    )
    return steer, speed


class Actuation:
    """The calibrated effects of one car, stepped one control period at a time (the env's use)."""

    def __init__(self, calibration: CarCalibration, substep_s: float) -> None:
        self.params = ActuationParams.from_calibration(calibration)
        self.substep_s = substep_s
        self.reset()

    def reset(self) -> None:
        """Back to rest: wheels straight, speed target zero, nothing in the dead times."""
        self._state = initial_state(self.params, self.substep_s)

    def save(self) -> ActuationState:
        """A copy of the effects' memory (for :meth:`load`)."""
        return copy.deepcopy(self._state)

    def load(self, state: ActuationState) -> None:
        """Back to a saved memory (copied: the saved one stays as it was)."""
        self._state = copy.deepcopy(state)

    def step(self, steering_deg: float, speed_mps: float, substeps: int) -> tuple[np.ndarray, np.ndarray]:
        """Servo targets for each of ``substeps`` physics steps holding this command."""
        n = substeps
        steer, speed, self._state = actuate(
            self.params, np.full(n, steering_deg), np.full(n, speed_mps), self._state, self.substep_s
        )
        return steer, speed
