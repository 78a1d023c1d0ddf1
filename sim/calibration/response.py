"""How a car responds to its commands, row by row: the shape that points at a missing effect.

:func:`command_response` fits, by least squares, each row's effective steering angle (the angle a kinematic
bicycle would need for the measured turn: ``atan(wheelbase · yaw rate / speed)``) on the steering commands of
that row and the rows before it, and each row's speed on the speed commands likewise. The weights are the
car's response to one row of command: a first-order lag shows weights that shrink by ``exp(-T/τ)`` per row,
a dead time shows leading weights near zero, their sum is the gain. What the fit leaves over is variation the
commands do not explain (noise, or effects that are not linear in the commands).

:func:`simulate_open_loop` drives the simulator's car with a log's commands from the log's first pose, so the
same fit on its output shows what the model does with the same commands.
"""

from __future__ import annotations

import math

import numpy as np

from common.car_calibration import CarCalibration
from sim.calibration.logs import Trajectory
from sim.physics import WHEELBASE_M, CarPhysics, Pose
from sim.texture import TextureFrame
from sim.world import CONTROL_HZ, build_model

LAGS = 14
"""Rows of command history in the fit (about 1 s)."""
MIN_SPEED_MPS = 0.5
"""Rows slower than this are left out of the steering fit (the angle from yaw rate / speed is ill-posed)."""


def command_response(trajectories: list[Trajectory], lags: int = LAGS) -> dict[str, dict]:
    """Per-row response weights, gain and unexplained RMS of steering (deg) and speed (m/s); see the module."""
    steer_x, steer_y, speed_x, speed_y = [], [], [], []
    for tr in trajectories:
        period = float(np.median(np.diff(tr.t)))
        speed = np.hypot(np.diff(tr.x), np.diff(tr.y)) / period  # row k: sample k → k+1
        yaw_rate = np.diff(np.unwrap(np.radians(tr.heading_deg))) / period
        steer_hist = _history(tr.steer_cmd_deg, lags, 0.0)
        speed_hist = _history(tr.speed_cmd_mps, lags, 0.0)
        for k in range(1, len(tr) - 1):
            speed_x.append(speed_hist[k])
            speed_y.append(speed[k])
            if speed[k] >= MIN_SPEED_MPS:
                steer_x.append(steer_hist[k])
                steer_y.append(math.degrees(math.atan(WHEELBASE_M * yaw_rate[k] / speed[k])))
    return {"steering": _fit(steer_x, steer_y, "deg"), "speed": _fit(speed_x, speed_y, "mps")}


def _history(commands: np.ndarray, lags: int, before: float) -> np.ndarray:
    """(n, lags): row k holds the commands of rows k, k-1, …, k-lags+1 (``before`` ahead of the first)."""
    padded = np.r_[np.full(lags - 1, before), commands]
    return np.stack([padded[k : k + lags][::-1] for k in range(len(commands))])


def _fit(x: list[np.ndarray], y: list[float], unit: str) -> dict:
    """Least-squares weights of ``y`` on the rows of ``x``; too few rows give no weights (and nulls in JSON)."""
    if not x or len(y) < 2 * len(x[0]):
        return {"weights": [], "gain": None, f"unexplained_{unit}": None, "rows": len(y)}
    x_arr, y_arr = np.array(x), np.array(y)
    w, *_ = np.linalg.lstsq(x_arr, y_arr, rcond=None)
    resid = y_arr - x_arr @ w
    return {
        "weights": [round(float(v), 4) for v in w],
        "gain": round(float(w.sum()), 4),
        f"unexplained_{unit}": round(float(np.sqrt(np.mean(resid**2))), 4),
        "rows": len(y),
    }


def simulate_open_loop(trajectories: list[Trajectory], calibration: CarCalibration | None = None) -> list[Trajectory]:
    """The simulator's car driven by each log's commands from its first pose, on the simulator's 15 Hz grid."""
    physics = CarPhysics(build_model(TextureFrame(x0=-50.0, y1=50.0, ppm=1.0, width=100, height=100)))
    physics.set_calibration(calibration)
    out = []
    for tr in trajectories:
        h0, d = math.radians(tr.heading_deg[0]), tr.reference_point_m
        physics.reset(Pose(tr.x[0] - d * math.cos(h0), tr.y[0] - d * math.sin(h0), h0))
        xs, ys, hs = [], [], []
        for k in range(len(tr)):
            pose = physics.pose
            ref = pose.ahead(d)
            xs.append(ref[0])
            ys.append(ref[1])
            hs.append(math.degrees(math.remainder(pose.yaw, 2 * math.pi)))
            physics.command(tr.steer_cmd_deg[k], tr.speed_cmd_mps[k])
            physics.step()
        t = np.arange(len(tr)) / CONTROL_HZ
        out.append(
            Trajectory(
                tr.source,
                tr.episode,
                t,
                steer_cmd_deg=tr.steer_cmd_deg,
                speed_cmd_mps=tr.speed_cmd_mps,
                x=xs,
                y=ys,
                heading_deg=hs,
                reference_point_m=d,
                track=tr.track,
            )
        )
    return out
