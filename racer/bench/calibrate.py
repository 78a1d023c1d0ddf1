"""``racer bench calibrate``: how long ``racer calibrate`` takes for one log, and its parts.

Each log given is calibrated ``repeats`` times in this process (``sim.calibration.fit.calibrate``, the command's
own code) with the replay on ``threads`` threads, and the median time is reported with the parts the calibration
clocks itself (``report["seconds"]``: cutting windows, choosing effects, scoring the held-out episodes, the base
car's score). With ``--threads 1`` the process is pinned to one core. Without logs, a synthetic log is written
first: 45 episodes of 100 rows of DeepRacer-like actions (7 angles × 2 speeds, held 1–4 rows) driven by racer's
own car with a 0.3 s steering lag, 3 mm / 0.2° of measurement noise: the size of one training log.
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.table import Table

from common.car_calibration import CarCalibration
from common.errors import OptionError
from racer.bench import Report
from racer.bench.env import pin_to_one_core
from sim.calibration import read_logs
from sim.calibration.fit import MAX_FIT_WINDOWS, calibrate
from sim.physics import CarPhysics, Pose
from sim.texture import TextureFrame
from sim.world import CONTROL_HZ, build_model

SYNTHETIC_EPISODES = 45
"""Episodes of the synthetic log (a DeepRacer training log's size)."""
SYNTHETIC_ROWS = 100
"""Rows per synthetic episode (6.7 s at 15 Hz)."""
SYNTHETIC_LAG_S = 0.3
"""The steering lag of the car that drives the synthetic log, s."""


def synthetic_log(path: Path, seed: int = 0) -> Path:
    """Write the benchmark's default log (see the module docstring) as a plain CSV; returns ``path``."""
    rng = np.random.default_rng(seed)
    physics = CarPhysics(build_model(TextureFrame(x0=-50.0, y1=50.0, ppm=1.0, width=100, height=100)))
    physics.set_calibration(CarCalibration.from_values({"steering_lag": {"tau_s": SYNTHETIC_LAG_S}}))
    lines = ["# reference_point_m: 0.14", "episode,time_s,steer_cmd_deg,speed_cmd_mps,x_m,y_m,heading_deg"]
    for ep in range(SYNTHETIC_EPISODES):
        physics.reset(Pose(0.0, 0.0, float(rng.uniform(-math.pi, math.pi))))
        steer, speed = _actions(rng, SYNTHETIC_ROWS)
        for k in range(SYNTHETIC_ROWS):
            pose = physics.pose
            x, y = np.asarray(pose.ahead(0.14)) + rng.normal(0, 0.003, 2)
            heading = math.degrees(math.remainder(pose.yaw + math.radians(rng.normal(0, 0.2)), 2 * math.pi))
            lines.append(f"{ep},{k / CONTROL_HZ:.6f},{steer[k]},{speed[k]},{x:.5f},{y:.5f},{heading:.4f}")
            physics.command(steer[k], speed[k])
            physics.step()
    path.write_text("\n".join(lines) + "\n")
    return path


def _actions(rng: np.random.Generator, rows: int) -> tuple[list[float], list[float]]:
    steer: list[float] = []
    speed: list[float] = []
    while len(steer) < rows:
        hold = int(rng.integers(1, 5))
        steer += [float(rng.choice([-30, -20, -10, 0, 10, 20, 30]))] * hold
        speed += [float(rng.choice([1.0, 2.0]))] * hold
    return steer[:rows], speed[:rows]


def command(logs: list[Path], *, repeats: int, threads: int, max_windows: int | None) -> Report:
    """Calibrate each log ``repeats`` times; the median seconds per log and its parts."""
    if repeats < 1 or threads < 1:
        raise OptionError(f"--repeats {repeats}, --threads {threads}: each must be at least 1")
    core = pin_to_one_core() if threads == 1 else None
    with tempfile.TemporaryDirectory() as tmp:
        paths = logs or [synthetic_log(Path(tmp) / "synthetic.csv")]
        rows = [_time_log(p, repeats, threads, max_windows) for p in paths]
    if not logs:
        rows[0]["log"] = f"synthetic: racer's car, steering lag {SYNTHETIC_LAG_S} s"
    table = Table("log", "episodes", "windows", "seconds (median)", "parts", "effects")
    for r in rows:
        parts = ", ".join(f"{k} {v:.1f}" for k, v in r["parts"].items())
        table.add_row(r["log"], str(r["episodes"]), str(r["windows_fit"]), f"{r['seconds']:.1f}", parts, r["found"])
    result = {"threads": threads, "pinned_core": core, "repeats": repeats, "logs": rows}
    return Report(result, [table])


def _time_log(path: Path, repeats: int, threads: int, max_windows: int | None) -> dict:
    trajectories = read_logs([path])
    times, reports = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = calibrate(
            trajectories, max_windows=max_windows or MAX_FIT_WINDOWS, progress=lambda _: None, threads=threads
        )
        times.append(time.perf_counter() - t0)
        reports.append(result.report)
    median = statistics.median(times)
    report = reports[times.index(min(times, key=lambda t: abs(t - median)))]
    found = [e["name"] for e in report["effects"]]
    return {
        "log": str(path),
        "episodes": len(trajectories),
        "windows_fit": report["windows_fit"],
        "seconds": round(median, 2),
        "seconds_each": [round(t, 2) for t in times],
        "parts": report["seconds"],
        "found": ", ".join(found) or "none",
        "effects": report["effects"],
        "base": report["base"],
    }
