"""An independent car and log generator for the tests of ``racer calibrate``: a ground truth sharing no code.

Nothing here imports racer (``sim``, ``common``, ``racer``, ...): only numpy and the standard library. A test
writes a log with :func:`write_log` from a car with known :class:`Effects` and checks that calibration finds them.

The car
-------
A dynamic bicycle with DeepRacer's dimensions (the ``CAR_*`` constants): wheelbase 0.164 m, centre of mass
0.08 m ahead of the rear axle, 1.5 kg, yaw inertia 0.0068 kg m²; the logged point is 0.14 m ahead of the rear
axle midpoint (``# reference_point_m: 0.14``, as in DeepRacer's sim-traces). States: position of the centre of
mass, yaw, body-frame velocities ``vx`` (forward) and ``vy`` (left), yaw rate ``r``, the front wheels' actual
angle and the wheels' actual rim speed ``w``.

Tyres: each axle's lateral force is ``-mu Fz tanh(C s / (mu Fz))`` of its lateral slip ``s`` (velocity across
the wheel over velocity along it), with ``C = 20 Fz`` per unit slip, so at low lateral acceleration the car
follows the kinematic bicycle (rear-axle radius ``L / tan(delta)``) and saturates at ``mu Fz``; mu is 1.0 at
the rear and 0.8 at the front, so the car understeers (plows) at the limit instead of spinning. Drive (4WD,
as DeepRacer): a force ``F tanh(C (w - vx) / (vx F))`` of the slip between rim speed and car speed, ``F`` the
motor's :data:`MOTOR_MAX_FORCE_N`, split between the axles in proportion to their grip, along each wheel;
each axle's two forces are then scaled into its friction circle. Slips divide by ``max(|u|,
SLIP_SPEED_FLOOR_MPS)``: at walking pace a tyre acts as a stiff damper towards rolling without slip, which
keeps the stiff equations stable from rest. No load transfer, no rolling resistance or air drag.

Integrated with semi-implicit Euler (velocities from the forces, then positions from the new velocities) at
:data:`SIM_HZ` or a little faster: the step is ``1 / (rate_hz · ceil(SIM_HZ / rate_hz))``, a whole number of
steps per row. Episodes are simulated side by side (numpy arrays over episodes).

The car's own actuators (always there): the steering servo follows its target as a first-order lag of
:data:`SERVO_TAU_S` within a mechanical range of ±:data:`MAX_WHEEL_DEG`; the motor brings the rim speed to
its target as a first-order lag of :data:`MOTOR_TAU_S`, within ±:data:`MOTOR_ACCEL_MPS2`.

Injected effects
----------------
Between command and actuators, in this order (see :class:`Effects` for each parameter):

- steering: ``clip(gain · cmd, ±max_deg) + offset_deg``, asymmetry, dead time, lag, understeer ``/ (1 + k v²)``
  and speed fade (v the car's current forward speed), the mechanical range, then the servo (with its rate
  limit) and backlash between servo and wheels;
- speed: ``gain · cmd``, battery sag, dead time, lag, cornering drag, then the motor.

The first nine and the rate limit are the effects racer's calibration library declares (:data:`DECLARED`); the
other five (:data:`OUT_OF_LIBRARY`) are ones real cars have that it does not model. Before t = 0 the car stands
still with a zero command applied for ever, so each filter and queue starts at the value a zero command settles
to.

Logs
----
Row k of an episode holds the sample at the start of row k and the command chosen there, which acts from
sample k to sample k + 1 (DeepRacer's convention): sample 0 is the car at rest, the last row's command never
shows. :func:`drive` adds measurement noise (:data:`NOISE_POS_M`, :data:`NOISE_HEADING_DEG`, times ``noise``).
"""

from __future__ import annotations

import csv
import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# ------------------------------------------------------------------------------------------------ the car

CAR_WHEELBASE_M = 0.164
CAR_COM_AHEAD_OF_REAR_M = 0.08
CAR_REFERENCE_POINT_M = 0.14
"""Where the logged point is: ahead of the rear axle midpoint, along the heading, m."""
CAR_MASS_KG = 1.5
CAR_YAW_INERTIA_KGM2 = 0.0068
CAR_MU_REAR = 1.0
CAR_MU_FRONT = 0.8
"""Tyre-road friction coefficients. The front grips less, so the car understeers at the limit (as most cars do);
with equal grip this one spins under power in tight turns above 2 m/s."""
GRAVITY_MPS2 = 9.81
TYRE_STIFFNESS_PER_LOAD = 20.0
"""Cornering (per rad of slip) and longitudinal (per unit slip ratio) stiffness, in units of the axle's load."""
SLIP_SPEED_FLOOR_MPS = 0.5
"""Slips divide by at least this speed (see the module)."""

SERVO_TAU_S = 0.02
MAX_WHEEL_DEG = 30.0
MOTOR_TAU_S = 0.05
MOTOR_ACCEL_MPS2 = 6.0
MOTOR_MAX_FORCE_N = 9.0
"""The most the motor pushes (or brakes) the car with, N: 6 m/s² on 1.5 kg."""
SIM_HZ = 1000.0
"""Least integration rate, Hz."""

NOISE_POS_M = 0.003
NOISE_HEADING_DEG = 0.2

_A = CAR_WHEELBASE_M - CAR_COM_AHEAD_OF_REAR_M  # centre of mass to front axle
_B = CAR_COM_AHEAD_OF_REAR_M  # centre of mass to rear axle
_REF_FROM_COM = CAR_REFERENCE_POINT_M - CAR_COM_AHEAD_OF_REAR_M
_GRIP_F = CAR_MU_FRONT * CAR_MASS_KG * GRAVITY_MPS2 * _B / CAR_WHEELBASE_M  # mu · Fz, front axle, N
_GRIP_R = CAR_MU_REAR * CAR_MASS_KG * GRAVITY_MPS2 * _A / CAR_WHEELBASE_M
_STIFF_F = TYRE_STIFFNESS_PER_LOAD * _GRIP_F / CAR_MU_FRONT  # N per unit slip
_STIFF_R = TYRE_STIFFNESS_PER_LOAD * _GRIP_R / CAR_MU_REAR
_GRIP, _STIFF = _GRIP_F + _GRIP_R, _STIFF_F + _STIFF_R
_FRONT_SHARE = _GRIP_F / _GRIP

# ------------------------------------------------------------------------------------------------ effects

PARAMETERS: dict[str, tuple[str, float]] = {
    "steering_offset": ("offset_deg", 0.0),
    "steering_gain": ("gain", 1.0),
    "steering_saturation": ("max_deg", MAX_WHEEL_DEG),
    "steering_delay": ("delay_s", 0.0),
    "steering_lag": ("tau_s", 0.0),
    "speed_gain": ("gain", 1.0),
    "speed_delay": ("delay_s", 0.0),
    "speed_lag": ("tau_s", 0.0),
    "understeer": ("k_s2pm2", 0.0),
    "steering_backlash": ("band_deg", 0.0),
    "steering_rate_limit": ("max_dps", math.inf),
    "steering_asymmetry": ("right_gain", 1.0),
    "steering_speed_fade": ("k_spm", 0.0),
    "cornering_drag": ("k_s2pm", 0.0),
    "battery_sag": ("drop_per_s", 0.0),
}
"""Each effect's one parameter: its name (the declared ones' as in racer's car.json) and the value that does nothing."""
DECLARED = (*list(PARAMETERS)[:9], "steering_rate_limit")
"""The effects racer's calibration library models (the rate limit as ``steering_rate``, seconds per 60°: 60 /
``max_dps``)."""
OUT_OF_LIBRARY = tuple(name for name in PARAMETERS if name not in DECLARED)
"""Effects real cars have that racer's calibration library does not model."""


@dataclass(frozen=True)
class Effects:
    """The effects injected between command and actuators: each field is an effect's parameter, None = absent.

    Build one as ``Effects(steering_delay=0.2, speed_gain=0.9)`` or ``Effects.of({"steering_delay": 0.2})``.
    Declared effects (:data:`DECLARED`):

    - ``steering_offset``: ``offset_deg``, added to the (gained, clipped) commanded angle, degrees, + = left.
    - ``steering_gain``: ``gain``, the commanded angle is multiplied by it.
    - ``steering_saturation``: ``max_deg``, ``|gain · cmd|`` is clipped to it (before the offset).
    - ``steering_delay``: ``delay_s``, dead time (a queue of integration steps, rounded to a whole step).
    - ``steering_lag``: ``tau_s``, first-order lag (backward-Euler filter per step).
    - ``speed_gain``: ``gain``, the commanded speed is multiplied by it.
    - ``speed_delay``: ``delay_s``, dead time of the speed target.
    - ``speed_lag``: ``tau_s``, first-order lag of the speed target.
    - ``understeer``: ``k_s2pm2``, the steering target is divided by ``1 + k v²``, v the car's forward speed.
    - ``steering_rate_limit``: ``max_dps``, the servo turns no faster than this, degrees per second (racer's
      ``steering_rate`` gives it as 60 / max_dps seconds per 60°).

    Out of library (:data:`OUT_OF_LIBRARY`):

    - ``steering_backlash``: ``band_deg``, play between servo and wheels: the wheels move only when the servo
      is more than ``band_deg`` from them, and then lag it by ``band_deg`` (a hysteresis of ±band_deg).
    - ``steering_asymmetry``: ``right_gain``, right (negative) steering targets are multiplied by it.
    - ``steering_speed_fade``: ``k_spm``, the steering target is divided by ``1 + k v`` (linear in v, s/m).
    - ``cornering_drag``: ``k_s2pm``, the wheel speed target is multiplied by ``1 - k |a_lat|`` (a_lat = vx · r),
      floored at 0: scrub the open-loop motor does not make up for.
    - ``battery_sag``: ``drop_per_s``, the speed gain falls by this fraction per second since the episode's
      start (floored at 0.2).
    """

    steering_offset: float | None = None
    steering_gain: float | None = None
    steering_saturation: float | None = None
    steering_delay: float | None = None
    steering_lag: float | None = None
    speed_gain: float | None = None
    speed_delay: float | None = None
    speed_lag: float | None = None
    understeer: float | None = None
    steering_backlash: float | None = None
    steering_rate_limit: float | None = None
    steering_asymmetry: float | None = None
    steering_speed_fade: float | None = None
    cornering_drag: float | None = None
    battery_sag: float | None = None

    @classmethod
    def of(cls, values: dict[str, float]) -> Effects:
        """Effects from a dict of effect name → parameter value; an unknown name raises ``ValueError``."""
        unknown = sorted(set(values) - set(PARAMETERS))
        if unknown:
            raise ValueError(f"unknown effects {unknown}; known: {sorted(PARAMETERS)}")
        return cls(**{name: float(v) for name, v in values.items()})

    def active(self) -> dict[str, float]:
        """The effects present: name → parameter value."""
        return {f.name: v for f in dataclasses.fields(self) if (v := getattr(self, f.name)) is not None}

    def as_params(self) -> dict[str, dict[str, float]]:
        """The effects present as name → {parameter name: value}, the shape of racer's calibration files."""
        return {name: {PARAMETERS[name][0]: v} for name, v in self.active().items()}

    def value(self, name: str) -> float:
        """An effect's parameter, or the value that does nothing when it is absent."""
        v = getattr(self, name)
        return PARAMETERS[name][1] if v is None else v


# ------------------------------------------------------------------------------------------------ actuators


class _DeadTime:
    """A fixed dead time of whole steps: a ring buffer of the last ``n`` inputs per episode."""

    def __init__(self, steps: int, initial: np.ndarray) -> None:
        self.buf = np.repeat(initial[None, :], max(steps, 1), axis=0)
        self.steps, self.i = steps, 0

    def push(self, u: np.ndarray) -> np.ndarray:
        """Take this step's input, give the one from ``steps`` steps ago."""
        if self.steps == 0:
            return u
        out = self.buf[self.i].copy()
        self.buf[self.i] = u
        self.i = (self.i + 1) % self.steps
        return out


class _Lag:
    """A first-order lag, backward Euler (stable for any tau, exact as tau/dt grows); tau 0 passes through."""

    def __init__(self, tau_s: float, dt: float, initial: np.ndarray) -> None:
        self.alpha = 1.0 if tau_s <= 0 else dt / (tau_s + dt)
        self.y = initial.copy()

    def step(self, u: np.ndarray) -> np.ndarray:
        if self.alpha == 1.0:
            return u
        self.y += self.alpha * (u - self.y)
        return self.y


class _Steering:
    """Commanded steering (degrees) to the front wheels' actual angle (degrees), one integration step at a time."""

    def __init__(self, fx: Effects, dt: float, episodes: int) -> None:
        self.fx, self.dt = fx, dt
        rest = self.shape(np.zeros(episodes))
        self.delay = _DeadTime(round(fx.value("steering_delay") / dt), rest)
        self.lag = _Lag(fx.value("steering_lag"), dt, rest)
        self.k_us, self.k_fade = fx.value("understeer"), fx.value("steering_speed_fade")
        self.max_rate = fx.value("steering_rate_limit")
        self.band = fx.value("steering_backlash")
        self.servo = np.clip(rest, -MAX_WHEEL_DEG, MAX_WHEEL_DEG)
        self.wheel = self.servo.copy()

    def shape(self, cmd: np.ndarray) -> np.ndarray:
        """The static part (gain, saturation, offset, asymmetry), once per row."""
        fx = self.fx
        m = fx.value("steering_saturation")
        u = np.clip(fx.value("steering_gain") * cmd, -m, m) + fx.value("steering_offset")
        return np.where(u < 0, u * fx.value("steering_asymmetry"), u)

    def step(self, target: np.ndarray, vx: np.ndarray) -> np.ndarray:
        u = self.lag.step(self.delay.push(target))
        if self.k_us:
            u = u / (1.0 + self.k_us * vx * vx)
        if self.k_fade:
            u = u / (1.0 + self.k_fade * np.abs(vx))
        u = np.clip(u, -MAX_WHEEL_DEG, MAX_WHEEL_DEG)
        rate = (u - self.servo) / SERVO_TAU_S
        if self.max_rate < math.inf:
            rate = np.clip(rate, -self.max_rate, self.max_rate)
        self.servo = self.servo + rate * self.dt
        if self.band > 0:
            self.wheel = np.clip(self.wheel, self.servo - self.band, self.servo + self.band)
            return self.wheel
        return self.servo


class _Speed:
    """Commanded speed (m/s) to the wheels' actual rim speed (m/s), one integration step at a time."""

    def __init__(self, fx: Effects, dt: float, episodes: int) -> None:
        self.fx, self.dt = fx, dt
        rest = np.zeros(episodes)
        self.delay = _DeadTime(round(fx.value("speed_delay") / dt), rest)
        self.lag = _Lag(fx.value("speed_lag"), dt, rest)
        self.sag, self.drag = fx.value("battery_sag"), fx.value("cornering_drag")
        self.wheel = rest.copy()

    def shape(self, cmd: np.ndarray) -> np.ndarray:
        """The static part (gain), once per row."""
        return self.fx.value("speed_gain") * cmd

    def step(self, target: np.ndarray, t: float, lat_accel: np.ndarray) -> np.ndarray:
        if self.sag:
            target = target * max(0.2, 1.0 - self.sag * t)
        u = self.lag.step(self.delay.push(target))
        if self.drag:
            u = u * np.maximum(0.0, 1.0 - self.drag * np.abs(lat_accel))
        accel = np.clip((u - self.wheel) / MOTOR_TAU_S, -MOTOR_ACCEL_MPS2, MOTOR_ACCEL_MPS2)
        self.wheel = self.wheel + accel * self.dt
        return self.wheel


# ------------------------------------------------------------------------------------------------ dynamics


@dataclass
class _Body:
    """The rigid body's state per episode: centre of mass (m), yaw (rad), body-frame velocities, yaw rate."""

    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    r: np.ndarray

    @classmethod
    def at_rest(cls, yaw: np.ndarray) -> _Body:
        """Standing with the rear axle midpoint at the origin."""
        z = np.zeros_like(yaw)
        return cls(_B * np.cos(yaw), _B * np.sin(yaw), yaw.copy(), z.copy(), z.copy(), z.copy())

    def step(self, delta_deg: np.ndarray, wheel: np.ndarray, dt: float) -> None:
        """One semi-implicit Euler step with the wheels at ``delta_deg`` turning at rim speed ``wheel``."""
        d = np.radians(delta_deg)
        cd, sd = np.cos(d), np.sin(d)
        vyf = self.vy + _A * self.r  # front axle's lateral velocity, body frame
        uf, wf = self.vx * cd + vyf * sd, vyf * cd - self.vx * sd  # front, wheel frame
        wr = self.vy - _B * self.r
        slip = (wheel - self.vx) / np.maximum(np.abs(self.vx), SLIP_SPEED_FLOOR_MPS)
        drive = MOTOR_MAX_FORCE_N * np.tanh(_STIFF * slip / MOTOR_MAX_FORCE_N)
        fxf, fyf = _friction_circle(_FRONT_SHARE * drive, _lateral(uf, wf, _GRIP_F, _STIFF_F), _GRIP_F)
        fxr, fyr = _friction_circle((1 - _FRONT_SHARE) * drive, _lateral(self.vx, wr, _GRIP_R, _STIFF_R), _GRIP_R)
        lat_f = fxf * sd + fyf * cd
        ax = (fxf * cd - fyf * sd + fxr) / CAR_MASS_KG + self.vy * self.r
        ay = (lat_f + fyr) / CAR_MASS_KG - self.vx * self.r
        self.r = self.r + dt * (_A * lat_f - _B * fyr) / CAR_YAW_INERTIA_KGM2
        self.vx, self.vy = self.vx + dt * ax, self.vy + dt * ay
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        self.x = self.x + dt * (self.vx * c - self.vy * s)
        self.y = self.y + dt * (self.vx * s + self.vy * c)
        self.yaw = self.yaw + dt * self.r

    def reference_point(self) -> tuple[np.ndarray, np.ndarray]:
        """The logged point (:data:`CAR_REFERENCE_POINT_M` ahead of the rear axle), m."""
        return self.x + _REF_FROM_COM * np.cos(self.yaw), self.y + _REF_FROM_COM * np.sin(self.yaw)


def _lateral(u: np.ndarray, w: np.ndarray, grip: float, stiff: float) -> np.ndarray:
    """An axle's lateral force (N, across the wheel) from its velocity: u along the wheel, w across it."""
    return -grip * np.tanh(stiff * w / np.maximum(np.abs(u), SLIP_SPEED_FLOOR_MPS) / grip)


def _friction_circle(fx: np.ndarray, fy: np.ndarray, grip: float) -> tuple[np.ndarray, np.ndarray]:
    """The forces scaled down, keeping their direction, to no more than the grip in all."""
    scale = np.minimum(1.0, grip / np.maximum(np.hypot(fx, fy), 1e-9))
    return fx * scale, fy * scale


# ------------------------------------------------------------------------------------------------ simulation


@dataclass
class Trace:
    """Noiseless samples of a simulation; arrays are (samples,) for one episode or (episodes, samples)."""

    t: np.ndarray
    """Time of each sample, s (the first is 0), shape (samples,)."""
    x: np.ndarray
    """The logged point, m."""
    y: np.ndarray
    heading_deg: np.ndarray
    """Yaw, degrees, counter-clockwise, wrapped to [-180, 180)."""
    speed: np.ndarray
    """Forward speed of the centre of mass (vx), m/s."""
    yaw_rate_dps: np.ndarray
    steer_deg: np.ndarray
    """The front wheels' actual angle, degrees, + = left."""
    wheel_speed: np.ndarray
    """The wheels' actual rim speed, m/s."""


_TRACE_FIELDS = ("x", "y", "heading_deg", "speed", "yaw_rate_dps", "steer_deg", "wheel_speed")


def simulate(
    effects: Effects,
    steer_cmd: np.ndarray,
    speed_cmd: np.ndarray,
    *,
    start_heading_deg: float | np.ndarray = 0.0,
    rate_hz: float = 15.0,
    every_step: bool = False,
) -> Trace:
    """Drive the car from rest, rear axle midpoint at the origin, through the commands (degrees, m/s; one per
    row), noiselessly.

    ``steer_cmd`` and ``speed_cmd`` are (rows,) or (episodes, rows), episodes simulated side by side. Samples
    are taken at the start of each row (row k's command acts from sample k to k + 1), or at every integration
    step with ``every_step`` (sample i at time i · dt, the command of row ``i // steps_per_row``).
    """
    steer, speed = np.atleast_2d(np.asarray(steer_cmd, float)), np.atleast_2d(np.asarray(speed_cmd, float))
    if steer.shape != speed.shape:
        raise ValueError(f"steer_cmd {steer.shape} and speed_cmd {speed.shape} differ in shape")
    episodes, rows = steer.shape
    sub = math.ceil(SIM_HZ / rate_hz - 1e-9)
    dt = 1.0 / (rate_hz * sub)
    yaw0 = np.radians(np.broadcast_to(np.asarray(start_heading_deg, float), (episodes,)))
    body, steering, motor = _Body.at_rest(yaw0), _Steering(effects, dt, episodes), _Speed(effects, dt, episodes)
    delta, wheel = steering.servo.copy(), motor.wheel.copy()
    rec: list[tuple[np.ndarray, ...]] = [_sample(body, delta, wheel)]
    for k in range(rows - 1):
        s_target, v_target = steering.shape(steer[:, k]), motor.shape(speed[:, k])
        for j in range(sub):
            delta = steering.step(s_target, body.vx)
            wheel = motor.step(v_target, (k * sub + j) * dt, body.vx * body.r)
            body.step(delta, wheel, dt)
            if every_step or j == sub - 1:
                rec.append(_sample(body, delta, wheel))
    cols = [np.stack(c, axis=-1) for c in zip(*rec, strict=True)]
    if np.ndim(steer_cmd) == 1:
        cols = [c[0] for c in cols]
    t = np.arange(len(rec)) * (dt if every_step else 1.0 / rate_hz)
    return Trace(t, **dict(zip(_TRACE_FIELDS, cols, strict=True)))


def _sample(body: _Body, delta: np.ndarray, wheel: np.ndarray) -> tuple[np.ndarray, ...]:
    x, y = body.reference_point()
    heading = (np.degrees(body.yaw) + 180.0) % 360.0 - 180.0
    return x, y, heading, body.vx.copy(), np.degrees(body.r), delta.copy(), wheel.copy()


def drive(
    effects: Effects,
    steer_cmd: np.ndarray,
    speed_cmd: np.ndarray,
    *,
    rng: np.random.Generator,
    noise: float = 1.0,
    start_heading: float | np.ndarray | None = None,
    rate_hz: float = 15.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Measured ``(t, x, y, heading_deg)`` of the car driven through the commands, one sample per row.

    As :func:`simulate` (shapes, timing), plus measurement noise: Gaussian, :data:`NOISE_POS_M` on x and y and
    :data:`NOISE_HEADING_DEG` on the heading, times ``noise``; headings wrapped to [-180, 180]. The start
    heading (degrees) is drawn uniformly from ``rng`` when None.
    """
    shape = np.shape(steer_cmd)[:-1]
    if start_heading is None:
        start_heading = rng.uniform(-180.0, 180.0, size=shape)
    tr = simulate(effects, steer_cmd, speed_cmd, start_heading_deg=start_heading, rate_hz=rate_hz)
    x = tr.x + rng.normal(0.0, NOISE_POS_M * noise, tr.x.shape)
    y = tr.y + rng.normal(0.0, NOISE_POS_M * noise, tr.y.shape)
    heading = tr.heading_deg + rng.normal(0.0, NOISE_HEADING_DEG * noise, tr.heading_deg.shape)
    return tr.t, x, y, (heading + 180.0) % 360.0 - 180.0


# ------------------------------------------------------------------------------------------------ commands

DEEPRACER_STEER_DEG = (-30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0)
DEEPRACER_SPEED_MPS = (1.0, 2.0)
PLAN_STRAIGHT_MPS = (0.6, 1.0, 1.8, 2.6)
PLAN_STRAIGHT_S = 2.0
PLAN_STEP_MPS, PLAN_STEP_DEG, PLAN_STEP_S = 1.2, 15.0, 1.0
PLAN_CIRCLE_MPS = (0.7, 1.4, 2.2)
PLAN_CIRCLE_DEG = (10.0, -10.0, 20.0, -20.0)
PLAN_CIRCLE_S = 3.0


def commands(
    rng: np.random.Generator, steps: int, kind: str = "deepracer", *, rate_hz: float = 15.0
) -> tuple[np.ndarray, np.ndarray]:
    """One episode's commands ``(steer_deg, speed_mps)``, each of ``steps`` rows (``plan``: its own length).

    - ``deepracer``: DeepRacer's discrete actions, steering in {-30, -20, ..., 30} × speed in {1, 2} m/s, each
      held 1-4 rows.
    - ``continuous``: steering uniform in [-30, 30] degrees, speed uniform in [0.5, 3.0] m/s, held 1-6 rows.
    - ``plan``: a system-identification drive, ignoring ``steps``: straight runs at
      :data:`PLAN_STRAIGHT_MPS`, a steering step 0 → ±15° → 0 → ∓15° → 0 at 1.2 m/s (the sign first is drawn),
      then steady circles at each of :data:`PLAN_CIRCLE_MPS` with each of :data:`PLAN_CIRCLE_DEG` (their order
      within a speed drawn).
    """
    if kind == "plan":
        return _plan(rng, rate_hz)
    if kind == "deepracer":
        return _held(rng, steps, 4, lambda: (rng.choice(DEEPRACER_STEER_DEG), rng.choice(DEEPRACER_SPEED_MPS)))
    if kind == "continuous":
        return _held(rng, steps, 6, lambda: (rng.uniform(-30.0, 30.0), rng.uniform(0.5, 3.0)))
    raise ValueError(f"unknown kind {kind!r}: deepracer, continuous or plan")


def _held(rng: np.random.Generator, steps: int, most: int, draw) -> tuple[np.ndarray, np.ndarray]:
    """Actions from ``draw()``, each held for 1 to ``most`` rows, until ``steps`` rows."""
    steer, speed = np.empty(steps), np.empty(steps)
    k = 0
    while k < steps:
        n = int(rng.integers(1, most + 1))
        steer[k : k + n], speed[k : k + n] = draw()
        k += n
    return steer, speed


def _plan(rng: np.random.Generator, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    sign = float(rng.choice((-1.0, 1.0)))
    segments = [(0.0, v, PLAN_STRAIGHT_S) for v in PLAN_STRAIGHT_MPS]
    segments += [(a * PLAN_STEP_DEG, PLAN_STEP_MPS, PLAN_STEP_S) for a in (0.0, sign, 0.0, -sign, 0.0)]
    for v in PLAN_CIRCLE_MPS:
        segments += [(float(a), v, PLAN_CIRCLE_S) for a in rng.permutation(PLAN_CIRCLE_DEG)]
    rows = [round(s * rate_hz) for _, _, s in segments]
    steer = np.repeat([a for a, _, _ in segments], rows)
    speed = np.repeat([v for _, v, _ in segments], rows)
    return steer, speed


# ------------------------------------------------------------------------------------------------ logs

CSV_HEADER = ("episode", "time_s", "steer_cmd_deg", "speed_cmd_mps", "x_m", "y_m", "heading_deg")
EPISODE_GAP_S = 1.0
"""Time between one episode's last sample and the next one's first: time runs on through the file."""


def write_log(
    path: str | Path,
    effects: Effects,
    *,
    episodes: int = 45,
    steps: int = 100,
    seed: int = 0,
    kind: str = "deepracer",
    noise: float = 1.0,
    rate_hz: float = 15.0,
) -> Path:
    """Write a plain CSV log (the format ``racer calibrate`` reads) of ``episodes`` episodes; return its path.

    The first line is ``# reference_point_m: 0.14``, then the header :data:`CSV_HEADER`, then one row per
    sample. Each episode starts at rest, rear axle midpoint at the origin, with a uniformly drawn heading, and
    runs ``steps`` rows of :func:`commands` of ``kind`` (``plan``: the plan's length). Time runs on across
    episodes (strictly increasing through the file). The same arguments write the same file.
    """
    rng = np.random.default_rng(seed)
    cmds = [commands(rng, steps, kind, rate_hz=rate_hz) for _ in range(episodes)]
    steer, speed = np.stack([c[0] for c in cmds]), np.stack([c[1] for c in cmds])
    t, x, y, heading = drive(effects, steer, speed, rng=rng, noise=noise, rate_hz=rate_hz)
    span = t[-1] + EPISODE_GAP_S
    path = Path(path)
    with path.open("w", newline="") as f:
        f.write(f"# reference_point_m: {CAR_REFERENCE_POINT_M}\n")
        w = csv.writer(f, lineterminator="\n")
        w.writerow(CSV_HEADER)
        for e in range(episodes):
            for k in range(len(t)):
                w.writerow(
                    (
                        e,
                        f"{e * span + t[k]:.4f}",
                        f"{steer[e, k]:.4f}",
                        f"{speed[e, k]:.4f}",
                        f"{x[e, k]:.5f}",
                        f"{y[e, k]:.5f}",
                        f"{heading[e, k]:.3f}",
                    )
                )
    return path
