"""A classical controller that drives a racing line in the real env: pure pursuit for steering, the line's speed
profile for speed. It checks that a computed lap-time limit can be driven (``racer limit``'s driven lap).

Pure pursuit steers the rear axle's midpoint onto the circle through a point one look-ahead distance further along
the line; the look-ahead grows with speed. The speed command is the profile's speed a little ahead (the command
acts on the next control period and the servos need a moment), divided by the car's speed-per-command ratio (its
wheels slip slightly).
"""

from __future__ import annotations

import json
import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from common.car_calibration import CarCalibration
from common.config import EnvConfig
from sim.car_limits import CarLimits
from sim.physics import MAX_STEERING_DEG, WHEELBASE_M, Pose
from sim.raceline import RacingLine

LOOKAHEAD_BASE_M = 0.2
"""Look-ahead distance at rest, m."""
LOOKAHEAD_PER_MPS = 0.15
"""Look-ahead added per m/s of speed, s."""
SPEED_LEAD_S = 0.12
"""How far ahead (in time at the current speed) the speed command reads the profile, s."""


@dataclass
class PurePursuit:
    """Steering and speed commands that follow ``line`` (with its standing-start profile)."""

    line: RacingLine
    speed_per_command: float = 1.0
    limits: CarLimits | None = None
    """The car's measured limits: with them, steering follows its measured understeer; without, geometry."""
    _s: np.ndarray = field(init=False, repr=False)
    _near: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        self._s = np.concatenate([[0.0], np.cumsum(self.line.ds)])

    def _point_at(self, s: float) -> np.ndarray:
        """The line's point at arc length ``s`` (wrapping round the loop)."""
        total = self._s[-1]
        s = s % total
        i = int(np.searchsorted(self._s, s, side="right") - 1)
        t = (s - self._s[i]) / max(self.line.ds[i], 1e-9)
        a, b = self.line.points[i], self.line.points[(i + 1) % len(self.line.points)]
        return a + t * (b - a)

    def _nearest(self, point: np.ndarray) -> int:
        """Index of the line point nearest ``point``, searched a short way ahead of the last one."""
        n = len(self.line.points)
        window = (self._near + np.arange(-5, 40)) % n
        d = np.linalg.norm(self.line.points[window] - point, axis=1)
        self._near = int(window[int(np.argmin(d))])
        return self._near

    def command(self, pose: Pose, speed: float, lap_s: float) -> tuple[float, float]:
        """(steering_deg, speed_mps) for the car at ``pose`` moving at ``speed``; ``lap_s`` is the distance driven
        so far this lap, used to read the standing-start profile (the first lap's, then the flying one's)."""
        rear = np.array([pose.x, pose.y]) - WHEELBASE_M / 2 * np.array([math.cos(pose.yaw), math.sin(pose.yaw)])
        i = self._nearest(rear)
        lookahead = LOOKAHEAD_BASE_M + LOOKAHEAD_PER_MPS * max(speed, 0.0)
        target = self._point_at(self._s[i] + lookahead + WHEELBASE_M / 2)
        dx, dy = target - rear
        alpha = math.atan2(dy, dx) - pose.yaw
        kappa = 2.0 * math.sin(alpha) / max(math.hypot(dx, dy), 1e-6)  # the pure-pursuit arc's curvature
        # The steering that holds that arc at this speed, from the car's measured trials (it understeers at speed).
        steer = (
            self.limits.steering_for(speed, kappa)
            if self.limits is not None
            else math.degrees(math.atan(WHEELBASE_M * kappa))
        )
        ahead = self._s[i] + max(speed, 0.5) * SPEED_LEAD_S
        first_lap = lap_s < 0.5 * self._s[-1] or self._s[i] > 0.5 * self._s[-1]
        profile = self.line.speed if first_lap else np.append(self.line.flying_speed, self.line.flying_speed[0])
        v = float(np.interp(ahead % self._s[-1], self._s, profile))
        steer = max(-MAX_STEERING_DEG, min(MAX_STEERING_DEG, steer))
        # The profile's speed and nothing more. Measured on 10 tracks: commanding extra by the car's shortfall (scrub
        # in a turn slows it) drove some laps faster than the computed limit (down to 0.98 of it), because the
        # profile is keyed by commanded speed; a check of a limit must not drive beyond it.
        return steer, v / self.speed_per_command


@dataclass(frozen=True)
class DrivenLap:
    """What the controller did in the env."""

    status: str
    """The env's episode status at the end: ``lap_complete``, ``off_track``, ``time_up``…"""
    lap_time: float | None
    """Simulated lap time, s (None unless the lap was completed)."""
    progress: float
    """Progress reached, %."""
    path: np.ndarray
    """(K, 2) positions of the car's front point (DeepRacer's x, y), m."""


def drive_line(
    track: str, line: RacingLine, limits: CarLimits, car: CarCalibration | None = None, max_seconds: float = 120.0
) -> DrivenLap:
    """Drive ``line`` once round ``track`` from DeepRacer's start (waypoint 0, at rest) in the real env."""
    from sim.env import RacerEnv

    with tempfile.TemporaryDirectory(prefix="racer-limit-") as tmp:
        # A continuous action space up to the car's highest command: the controller needs in-between values.
        meta = Path(tmp) / "model_metadata.json"
        space = {
            "steering_angle": {"low": -MAX_STEERING_DEG, "high": MAX_STEERING_DEG},
            "speed": {"low": 0.1, "high": limits.max_command_speed},
        }
        meta.write_text(json.dumps({"action_space": space, "action_space_type": "continuous"}))
        config = EnvConfig(
            track=track,
            action_space=str(meta),
            car=car or CarCalibration(),
            randomization={"random_start": False},
            time_limit_steps=int(max_seconds * 15),
        )
        env = RacerEnv(config=config)
        try:
            return _drive(env, PurePursuit(line, limits.speed_per_command, limits))
        finally:
            env.close()


def _drive(env, controller: PurePursuit) -> DrivenLap:  # noqa: ANN001 - a RacerEnv (imported lazily above)
    _, info = env.reset(seed=0, options={"start_index": 0, "reverse": False})
    path, travelled, last = [], 0.0, None
    done = False
    while not done:
        pose = info["pose"]
        here = np.array([pose.x, pose.y])
        travelled += 0.0 if last is None else float(np.linalg.norm(here - last))
        last = here
        steer, speed = controller.command(pose, env.physics.speed, travelled)
        _, _, terminated, truncated, info = env.step(np.array([steer, speed], dtype=np.float32))
        p = info["params"]
        path.append((p["x"], p["y"]))
        done = terminated or truncated
    p, status = info["params"], info["episode_status"]
    lap = float(p["sim_time"]) if status == "lap_complete" else None
    return DrivenLap(str(status), lap, float(p["progress"]), np.array(path))
