"""The car's limits, measured on the simulator itself: what a lap-time limit and a racing line may ask of it.

Every figure comes from driving the MuJoCo car (with its calibration) on a plain plane at the 15 Hz control rate,
the way the env drives it:

- top speed per commanded speed, after 4 s straight (the wheels slip a little: 4 m/s commanded gives ~3.96);
- acceleration from rest at full command, and braking from top speed to the lowest command, as tables a(v);
- the largest curvature the car holds at each speed: at every steering angle (2° apart) the car is driven for 4 s
  and the mean curvature of its last 2 s counts unless it slid (rear axle slipping sideways), lost speed or
  tipped; the figure is where the car still follows a curve before it slides. Its lateral acceleration
  a = v² κ is reported beside it;
- the smallest turning radius at the steering limit, at the lowest speed;
- how fast the steering follows a command: the time the wheels take to turn 63 % of a 20° step (a first-order
  lag's time constant; DeepRacer's Gazebo car takes about half a second, the default car a few hundredths).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass, fields
from functools import cache
from pathlib import Path

import mujoco
import numpy as np

import common
from common.car_calibration import CarCalibration
from sim.physics import MAX_STEERING_DEG, SPEED_RANGE_MPS, WHEELBASE_M, CarPhysics, Pose
from sim.texture import TextureFrame
from sim.world import CONTROL_HZ, build_model

SPEED_GRID_MPS = tuple(np.round(np.arange(0.25, 4.001, 0.25), 3))
"""Speeds at which the curvature limit is measured."""
STEER_GRID_DEG = tuple(float(d) for d in range(2, int(MAX_STEERING_DEG) + 1, 2))
"""Steering angles tried at each speed, degrees."""
SETTLE_STEPS = 60
"""Control steps (4 s) a cornering trial lasts."""
JUDGED_STEPS = 30
"""Its last 30 steps (2 s) are judged."""
MIN_SPEED_KEPT = 0.85
"""A trial in which the car keeps less than this fraction of its commanded speed (scrub) does not hold the curve."""
MAX_SIDE_SLIP_DEG = 5.0
"""A trial whose rear axle slips sideways by more than this in its last second is sliding, not following the curve."""


@dataclass(frozen=True)
class CarLimits:
    """Measured limits of one car (all SI: m, s, m/s, m/s², 1/m). Tables are on ``speeds``."""

    top_speed: float
    """Speed reached at the highest command, m/s."""
    speed_per_command: float
    """Reached speed / commanded speed on a straight (wheel slip), dimensionless."""
    speeds: list[float]
    """Speed grid of the tables below, m/s."""
    accel: list[float]
    """Largest forward acceleration at each speed, m/s²."""
    brake: list[float]
    """Largest deceleration at each speed (positive), m/s²."""
    max_curvature: list[float]
    """Largest curvature the car holds at each speed (non-increasing with speed), 1/m."""
    max_lateral_accel: list[float]
    """v² × max_curvature at each speed, m/s²."""
    steering: list[float]
    """Steering grid of the trials, degrees."""
    curvature_by_steering: list[list[float]]
    """Curvature held in each (speed, steering) trial, 1/m, 0 where the car slid: how much steering a curve needs
    at a speed (the car understeers more the faster it goes)."""
    min_turn_radius: float
    """Turning radius at the steering limit at the lowest speed, m."""
    max_command_speed: float
    """The highest speed command the limits were measured for (the action space's), m/s."""
    steering_tau_s: float = 0.0
    """Time the wheels take to turn 63 % of a steering step, s (the controller's model of the steering lag)."""
    speed_tau_s: float = 0.0
    """Time the car takes to make 63 % of a small speed step on a straight, s (the controller's model of the speed
    servo's lag)."""

    def to_dict(self) -> dict:
        """JSON-ready figures (what ``racer limit --json`` stores, so others can recompute the profile)."""
        return asdict(self)

    def curvature_limit(self, v: np.ndarray | float) -> np.ndarray:
        """Largest curvature at speed ``v`` (interpolated; the lowest speed's below the grid), 1/m."""
        return np.interp(v, self.speeds, self.max_curvature)

    def speed_for_curvature(self, kappa: np.ndarray | float) -> np.ndarray:
        """Highest speed at which the car holds curvature |kappa|, m/s: the table's last speed still holding it,
        linearly towards the next; the top speed where every speed does, the lowest where none does."""
        k = np.abs(np.asarray(kappa, dtype=np.float64))
        table, speeds = np.asarray(self.max_curvature), np.asarray(self.speeds)
        # max_curvature is non-increasing: the last index i with table[i] >= k, by search on its negation.
        i = np.searchsorted(-table, -k, side="right") - 1
        j = np.clip(i + 1, 0, len(table) - 1)
        i_ok = np.clip(i, 0, len(table) - 1)
        span = np.where(table[i_ok] > table[j], table[i_ok] - table[j], 1.0)
        frac = np.clip((table[i_ok] - k) / span, 0.0, 1.0)
        v = speeds[i_ok] + (speeds[j] - speeds[i_ok]) * frac
        v = np.where(i >= len(table) - 1, self.top_speed, np.where(i < 0, speeds[0], v))
        return np.minimum(v, self.top_speed)

    def steering_for(self, v: float, kappa: float) -> float:
        """Steering (degrees, signed as ``kappa``) that holds curvature ``kappa`` at speed ``v``, from the trials at
        the nearest measured speed: interpolated up to the largest curvature held there, full lock beyond."""
        row = np.asarray(self.curvature_by_steering[int(np.argmin(np.abs(np.asarray(self.speeds) - v)))])
        held = row > 0
        if not held.any():
            return math.copysign(self.steering[-1], kappa)
        last = int(np.max(np.nonzero(held)))
        k = np.maximum.accumulate(np.concatenate([[0.0], row[: last + 1]]))
        d = np.concatenate([[0.0], self.steering[: last + 1]])
        keep = np.concatenate([[True], np.diff(k) > 0])  # np.interp needs increasing curvature
        steer = float(np.interp(abs(kappa), k[keep], d[keep], right=self.steering[-1]))
        return math.copysign(steer, kappa)

    def accel_at(self, v: np.ndarray | float) -> np.ndarray:
        """Largest forward acceleration at speed ``v``, m/s² (0 at the top speed)."""
        return np.interp(v, self.speeds, self.accel, right=0.0)

    def brake_at(self, v: np.ndarray | float) -> np.ndarray:
        """Largest deceleration at speed ``v`` (positive), m/s²."""
        return np.interp(v, self.speeds, self.brake)


def _plain_physics(car: CarCalibration) -> CarPhysics:
    """The car alone on a 60 m plane (large enough for any trial here)."""
    frame = TextureFrame(x0=-30.0, y1=30.0, ppm=1.0, width=60, height=60)
    physics = CarPhysics(build_model(frame))
    physics.set_calibration(car)
    return physics


def _rear_axle_velocity(physics: CarPhysics) -> tuple[float, float]:
    """(forward, leftward) velocity of the rear axle's midpoint, m/s: a car that follows its curve without
    sliding moves there straight ahead (base_link, between the axles, has a geometric side slip in a turn)."""
    vx, vy = physics.data.qvel[physics._root_v : physics._root_v + 2]
    yaw = physics.pose.yaw
    forward = vx * math.cos(yaw) + vy * math.sin(yaw)
    left = -vx * math.sin(yaw) + vy * math.cos(yaw) - physics.yaw_rate * WHEELBASE_M / 2
    return float(forward), float(left)


def _straight_run(physics: CarPhysics, commands: list[float]) -> np.ndarray:
    """Speeds after each control step of a straight run with these speed commands, starting from rest."""
    physics.reset(Pose(0.0, 0.0, 0.0))
    speeds = []
    for v in commands:
        physics.command(0.0, v)
        physics.step()
        speeds.append(physics.speed)
    return np.array(speeds)


def _rate_table(speeds: np.ndarray, grid: np.ndarray, sign: float) -> np.ndarray:
    """Acceleration (sign +1) or deceleration (-1) at the grid speeds from a run's speed samples at 15 Hz."""
    rate = sign * np.diff(speeds) * CONTROL_HZ
    mid = (speeds[1:] + speeds[:-1]) / 2
    keep = rate > 0.05
    if not np.any(keep):
        return np.zeros_like(grid)
    order = np.argsort(mid[keep])
    return np.interp(grid, mid[keep][order], rate[keep][order])


def _held_curvature(
    physics: CarPhysics, speed: float, steer_deg: float, keep_speed: bool = True
) -> tuple[float, float] | None:
    """(mean speed, mean curvature) the car holds over the last 2 s of a 4 s run at this command, or None if it
    slides (the rear axle slips sideways), tips over or (``keep_speed``) loses much of its speed. A car that wobbles
    about its circle (the four wheels share one speed, so they scrub in a turn) still holds the circle on average
    and counts."""
    physics.reset(Pose(0.0, 0.0, 0.0))
    rates, slips, speeds = [], [], []
    for _ in range(SETTLE_STEPS):
        physics.command(steer_deg, speed)
        physics.step()
        forward, left = _rear_axle_velocity(physics)
        rates.append(physics.yaw_rate)
        slips.append(math.degrees(math.atan2(abs(left), max(forward, 1e-6))))
        speeds.append(math.hypot(forward, left))
    judged = slice(SETTLE_STEPS - JUDGED_STEPS, SETTLE_STEPS)
    r, v = np.array(rates[judged]), np.array(speeds[judged])
    if not physics.upright or np.max(slips[judged]) > MAX_SIDE_SLIP_DEG:
        return None
    if keep_speed and v.mean() < MIN_SPEED_KEPT * speed:
        return None
    return float(v.mean()), float(abs(r.mean()) / v.mean())


def _curvature_table(physics: CarPhysics, grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The held curvature of every (commanded speed, steering angle) trial (0 where the car did not hold its
    curve), and the largest at each speed, made non-increasing with speed.

    Keyed by the command, not by the speed the car keeps in the curve (scrub slows it a little below its command
    in a long turn): measured both ways, the profile built on the command was the one the controller drove faster
    (6.53 s on reinvent_base against 6.76 s), so the table keyed by the kept speed would give a limit that can be
    beaten. The lap time computed on commanded speeds is a slight underestimate, which a limit may be."""
    held = np.zeros((len(grid), len(STEER_GRID_DEG)))
    best = np.zeros(len(grid))
    for i, speed in enumerate(grid):
        for j, steer in enumerate(STEER_GRID_DEG):
            trial = _held_curvature(physics, float(speed), steer, keep_speed=False)
            if trial is None:
                continue
            kept, kappa = trial
            if kept >= MIN_SPEED_KEPT * speed:
                held[i, j] = kappa
            # A trial that scrubs speed still holds its curve at the speed it keeps: the car can take that curve
            # at that speed (measured: the Gazebo car's table stopped at 1.57 1/m because its full-lock trials scrub
            # below 85 % of their command, yet driven laps took 2.2 1/m at 1.3 m/s in reinvent_base's hairpin).
            best[grid <= kept] = np.maximum(best[grid <= kept], kappa)
    # A faster car cannot hold a tighter curve than a slower one: keep the table monotone (conservative).
    return held, np.minimum.accumulate(np.maximum(held.max(axis=1), best))


def measure_limits(car: CarCalibration | None = None, max_command_speed: float = SPEED_RANGE_MPS[1]) -> CarLimits:
    """Measure the car's limits on the simulator (about two seconds on one core); see the module doc."""
    physics = _plain_physics(car or CarCalibration())
    top_command = min(max_command_speed, SPEED_RANGE_MPS[1])
    speeds_up = _straight_run(physics, [top_command] * int(4 * CONTROL_HZ))
    top_speed = float(speeds_up[-1])
    grid = np.array([v for v in SPEED_GRID_MPS if v < top_speed] + [top_speed])
    accel = _rate_table(np.concatenate([[0.0], speeds_up]), grid, +1.0)
    accel[-1] = 0.0
    down = _straight_run(physics, [top_command] * int(4 * CONTROL_HZ) + [SPEED_RANGE_MPS[0]] * int(2 * CONTROL_HZ))
    brake = _rate_table(down[int(4 * CONTROL_HZ) - 1 :], grid, -1.0)
    held, curvature = _curvature_table(physics, grid)
    return CarLimits(
        top_speed=top_speed,
        speed_per_command=top_speed / top_command,
        speeds=[float(v) for v in grid],
        accel=[float(a) for a in accel],
        brake=[float(b) for b in brake],
        max_curvature=[float(k) for k in curvature],
        steering=[float(d) for d in STEER_GRID_DEG],
        curvature_by_steering=[[float(k) for k in row] for row in held],
        max_lateral_accel=[float(v * v * k) for v, k in zip(grid, curvature, strict=True)],
        min_turn_radius=_min_turn_radius(physics, held),
        max_command_speed=top_command,
        steering_tau_s=_steering_time_constant(physics),
        speed_tau_s=_speed_time_constant(physics, top_command),
    )


def _min_turn_radius(physics: CarPhysics, held: np.ndarray) -> float:
    """Turning radius at full lock at a walking pace (0.3 m/s), m; where that trial fails (a car whose steering
    lag or scrub keeps it from settling), the tightest curve of the table's lowest speed."""
    trial = _held_curvature(physics, SPEED_RANGE_MPS[0] * 3, MAX_STEERING_DEG)
    kappa = trial[1] if trial else float(np.max(held[0]))
    return 1.0 / kappa if kappa > 0 else math.inf


STEP_DEG = 20.0
"""Size of the steering step whose response gives :attr:`CarLimits.steering_tau_s`, degrees."""


def _steering_time_constant(physics: CarPhysics) -> float:
    """Seconds the wheels take to reach 63 % (1 - 1/e) of a 20° step commanded at 1 m/s, interpolated between
    control periods; the angle after 2 s counts as the end of the step."""
    physics.reset(Pose(0.0, 0.0, 0.0))
    for _ in range(int(CONTROL_HZ)):  # 1 s straight at 1 m/s first
        physics.command(0.0, 1.0)
        physics.step()
    angles = [physics.steering_deg]
    for _ in range(int(2 * CONTROL_HZ)):
        physics.command(STEP_DEG, 1.0)
        physics.step()
        angles.append(physics.steering_deg)
    return _time_constant(np.array(angles) - angles[0])


def _time_constant(a: np.ndarray) -> float:
    """Seconds a step response ``a`` (one sample a control period, a[0] = 0, a[-1] its end) takes to reach 63 %
    (1 - 1/e) of its end, interpolated between control periods."""
    target = (1.0 - math.exp(-1.0)) * a[-1]
    k = int(np.argmax(a >= target))  # the first period at or past 63 %; a[0] = 0 is below it
    return float((k - 1 + (target - a[k - 1]) / (a[k] - a[k - 1])) / CONTROL_HZ)


SPEED_STEP_MPS = (2.0, 2.5)
"""The speed step whose response gives :attr:`CarLimits.speed_tau_s`, commanded m/s: small enough that neither car
meets its grip limit (the response is the servo's, not the tyres'); scaled down for an action space slower than its
top (DeepRacer's default space stops at 1 m/s: 0.8 to 1.0 m/s)."""


def _speed_time_constant(physics: CarPhysics, top_command: float) -> float:
    """Seconds the car takes to make 63 % of the speed step :data:`SPEED_STEP_MPS` on a straight, after 3 s at the
    first speed; the speed after 3 s more counts as the end of the step."""
    scale = min(1.0, top_command / SPEED_STEP_MPS[1])
    low, high = (v * scale for v in SPEED_STEP_MPS)
    settle, after = int(3 * CONTROL_HZ), int(3 * CONTROL_HZ)
    speeds = _straight_run(physics, [low] * settle + [high] * after)[settle - 1 :]
    a = speeds - speeds[0]
    return _time_constant(a) if a[-1] > 1e-6 else 0.0


CACHE_DIR_ENV = "RACER_CACHE_DIR"
"""Environment variable naming the folder where measured limits are kept (``$XDG_CACHE_HOME/racer`` or
``~/.cache/racer`` without it)."""


def limits_cache_dir() -> Path:
    """The folder of :func:`cached_limits`' files."""
    root = os.environ.get(CACHE_DIR_ENV)
    if not root:
        root = str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "racer")
    return Path(root) / "car-limits"


@cache
def _code_digest() -> str:
    """SHA-256 of what a measurement depends on besides the car: the simulator's and the common package's source,
    the car model's assets, and the MuJoCo and numpy versions. Any change to them measures again."""
    digest = hashlib.sha256(f"mujoco {mujoco.__version__} numpy {np.__version__}".encode())
    for package in (Path(__file__).parent, Path(common.__file__).parent):
        for path in sorted(package.rglob("*")):
            if path.is_file() and (path.suffix == ".py" or "assets" in path.parts):
                digest.update(path.relative_to(package.parent).as_posix().encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()


def _cache_file(car: CarCalibration, max_command_speed: float, folder: Path) -> Path:
    key = {
        "car": car.model_dump(mode="json", exclude={"about"}),  # "about" is informative; the simulator ignores it
        "max_command_speed": float(max_command_speed),
        "code": _code_digest(),
    }
    return folder / f"{hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()}.json"


def cached_limits(
    car: CarCalibration | None = None, max_command_speed: float = SPEED_RANGE_MPS[1], folder: Path | None = None
) -> tuple[CarLimits, bool]:
    """:func:`measure_limits`, or the figures it gave before for the same car, top command and code (and whether
    they were); kept as JSON in ``folder`` (:func:`limits_cache_dir` by default). Measuring takes 4-8 s of every
    ``racer limit`` run, the same for every track; a file that does not read back as limits is measured again and
    replaced, and a folder that cannot be written only costs the measurement."""
    car = car or CarCalibration()
    path = _cache_file(car, max_command_speed, folder or limits_cache_dir())
    try:
        kept = _limits_from_json(path.read_text())
    except (OSError, ValueError, TypeError):
        kept = None
    if kept is not None:
        return kept, True
    limits = measure_limits(car, max_command_speed)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(limits.to_dict()))
        tmp.replace(path)  # whole or not at all, also with two runs writing at once
    except OSError:
        pass
    return limits, False


def _limits_from_json(text: str) -> CarLimits | None:
    """The limits in a cache file's text: every field, each a number or a rectangular table of numbers (none NaN;
    an infinite turning radius is a car that never settles); None where that is not what the text holds."""
    data = json.loads(text)
    if not isinstance(data, dict) or set(data) != {f.name for f in fields(CarLimits)}:
        return None
    for value in data.values():
        if isinstance(value, str | bool) or np.isnan(np.asarray(value, dtype=np.float64)).any():
            return None
    return CarLimits(**data)
