"""``racer limit``: the minimum lap time a car can do on a track, its racing line and speed profile, and a lap
driven on that line in the real env by a classical controller to show the limit can be reached.

The parts: ``sim.car_limits`` measures the car, ``sim.raceline`` finds the line and its profile, ``sim.follower``
drives it. This module ties them together, writes the JSON and the PNG.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from common.action_space import load_action_space
from common.car_calibration import CarCalibration, load_car
from sim.car_limits import CarLimits, cached_limits, measure_limits
from sim.follower import DrivenLap, drive_line
from sim.physics import SPEED_RANGE_MPS
from sim.raceline import DEFAULT_MARGIN_M, RacingLine, racing_line
from sim.track import load_track


def max_command_speed(action_space: str | Path | None) -> float:
    """The highest speed an action space commands (the car's limit, 4 m/s, without one)."""
    if action_space is None:
        return SPEED_RANGE_MPS[1]
    space = load_action_space(action_space)
    top = max(a.speed for a in space.action_space) if space.discrete else space.action_space.speed.high
    return min(float(top), SPEED_RANGE_MPS[1])


def compute_limit(
    track: str,
    car: str = "default",
    action_space: str | Path | None = None,
    margin: float = DEFAULT_MARGIN_M,
    cache: bool = True,
) -> dict[str, Any]:
    """Measure the car (or, with ``cache``, take its limits measured before: ``sim.car_limits.cached_limits``),
    optimise the line, drive it; the report ``racer limit --json`` writes (with the arrays kept under ``_line`` and
    ``_driven`` for the picture)."""
    started = time.monotonic()
    calibration: CarCalibration = load_car(car)
    if cache:
        limits, cached = cached_limits(calibration, max_command_speed(action_space))
    else:
        limits, cached = measure_limits(calibration, max_command_speed(action_space)), False
    measured = time.monotonic()
    line = racing_line(load_track(track), limits, margin)
    optimised = time.monotonic()
    driven = drive_line(track, line, limits, calibration)
    report = _report(track, car, margin, limits=limits, line=line, driven=driven)
    report["car_limits_cached"] = cached
    report["seconds"] = {
        "measure_car": measured - started,
        "optimise_line": optimised - measured,
        "drive": time.monotonic() - optimised,
        "total": time.monotonic() - started,
    }
    report["_line"], report["_driven"] = line, driven
    return report


def _report(
    track: str, car: str, margin: float, *, limits: CarLimits, line: RacingLine, driven: DrivenLap
) -> dict[str, Any]:
    ratio = None if driven.lap_time is None else driven.lap_time / line.lap_time
    return {
        "track": track,
        "car": car,
        "lap_time_s": line.lap_time,
        "flying_lap_time_s": line.flying_lap_time,
        "driven_lap_time_s": driven.lap_time,
        "driven_status": driven.status,
        "driven_progress": driven.progress,
        "driven_pace": driven.pace,
        "driven_slowed_m": driven.slowed_m,
        "driven_tries": driven.tries,
        # The quasi-steady profile misses what a car does between steady states (a car that turns tighter while
        # braking than on a steady circle); where the driven lap beats it, that lap is the better figure.
        "best_known_lap_s": line.lap_time if driven.lap_time is None else min(line.lap_time, driven.lap_time),
        "driven_over_limit": ratio,
        "line_length_m": line.length,
        "margin_m": margin,
        "max_speed_mps": float(np.max(line.speed)),
        "mean_speed_mps": line.length / line.lap_time,
        "car_limits": limits.to_dict(),
        "line": {
            "x": [round(float(v), 4) for v in line.points[:, 0]],
            "y": [round(float(v), 4) for v in line.points[:, 1]],
            "speed_mps": [round(float(v), 4) for v in line.speed[:-1]],
        },
    }


def public(report: dict[str, Any]) -> dict[str, Any]:
    """The report without its in-memory objects (what goes to --json)."""
    return {k: v for k, v in report.items() if not k.startswith("_")}


def plot_limit(report: dict[str, Any], out_png: str | Path) -> Path:
    """The racing line over the track, coloured by the profile's speed, with the driven path beside it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.colors import Normalize

    from racer.plots import SPEED_CMAP, draw_track, save_figure

    line: RacingLine = report["_line"]
    driven: DrivenLap = report["_driven"]
    fig, ax = plt.subplots(figsize=(10, 7))
    draw_track(ax, report["track"])
    pts = np.vstack([line.points, line.points[:1]])
    segments = np.stack([pts[:-1], pts[1:]], axis=1)
    norm = Normalize(0.0, max(float(np.max(line.speed)), 0.1))
    lc = LineCollection(segments, cmap=SPEED_CMAP, norm=norm, linewidths=3.0, zorder=3)
    lc.set_array(line.speed[:-1])
    ax.add_collection(lc)
    if len(driven.path):
        ax.plot(driven.path[:, 0], driven.path[:, 1], color="white", lw=0.8, ls="--", zorder=4, label="driven")
    fig.colorbar(lc, ax=ax, label="speed profile (m/s)", shrink=0.8)
    driven_text = f"{report['driven_lap_time_s']:.2f} s" if report["driven_lap_time_s"] else report["driven_status"]
    ax.set_title(
        f"{report['track']}, car {report['car']}: limit {report['lap_time_s']:.2f} s "
        f"(flying {report['flying_lap_time_s']:.2f} s), driven {driven_text}, line {report['line_length_m']:.2f} m"
    )
    ax.set_aspect("equal")
    ax.legend(loc="upper right")
    return save_figure(fig, out_png)
