"""``racer calibrate``: read the logs, fit (or apply) a car calibration, write car.json, the report and a picture."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from common.car_calibration import EFFECTS, CarCalibration, load_car, save_calibration
from common.errors import OptionError
from sim.calibration import read_logs
from sim.calibration.fit import MAX_FIT_WINDOWS, Result, calibrate, score
from sim.calibration.logs import LogError
from sim.calibration.replay import TIMINGS


def run_calibrate(
    logs: list[Path],
    *,
    apply: str | Path | None = None,
    out: Path | None = None,
    png: Path | None = None,
    effects: list[str] | None = None,
    track: str | None = None,
    max_windows: int | None = None,
    say: Callable[[str], None] = print,
    timing: str = "auto",
    base: str | Path | None = None,
) -> dict:
    """Fit effects on ``logs`` (or score the car ``apply``, a preset's name or a car.json, on them) and return
    the report. ``base``: a car (preset name or car.json) whose effects the fit keeps and builds on."""
    if timing not in ("auto", *TIMINGS):
        raise OptionError(f"--timing {timing!r} is not one of auto, {', '.join(TIMINGS)}")
    for name in effects or []:
        if name not in EFFECTS:
            raise OptionError(f"--effect {name!r} is not an effect; known: {', '.join(EFFECTS)}")
    if apply is not None and (out is not None or effects or base is not None):
        raise OptionError("--apply scores an existing car: it takes no --out, --effect or base car")
    calibration = load_car(apply) if apply is not None else None
    base_car: CarCalibration | None = load_car(base) if base is not None else None
    trajectories = read_logs(logs, track=track)
    if not trajectories:
        raise LogError(f"no usable episode in {', '.join(map(str, logs))}")
    say(f"{len(trajectories)} episodes, {sum(len(t) for t in trajectories)} samples")
    if calibration is not None:
        result = score(calibration, trajectories, timing=timing)
        result.report["fit_on"] = []  # nothing was fitted here: the calibration came from elsewhere
        result.report["calibration"] = str(apply)
    else:
        result = calibrate(
            trajectories,
            effects,
            max_windows=max_windows or MAX_FIT_WINDOWS,
            progress=say,
            timing=timing,
            base=base_car,
        )
        if out is not None:
            save_calibration(result.calibration, out)
            say(f"wrote {out}")
    if png is not None:
        plot_calibration(result, png)
        say(f"wrote {png}")
    return result.report


def plot_calibration(result: Result, path: Path, episodes: int = 3) -> None:
    """Measured, uncalibrated and calibrated windows of a few episodes, and the residual over the window."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    _plot_paths(axes[0, 0], result, episodes)
    t_all = np.cumsum(np.median(result.windows.durations(), axis=0))
    res = {k: _residual(result, k) for k in ("before", "after")}
    panels = [
        (axes[0, 1], "position error (m)", lambda r: np.hypot(r["dx"], r["dy"])),
        (axes[1, 0], "heading error (deg)", lambda r: np.abs(r["dheading"])),
        (axes[1, 1], "speed error (m/s)", lambda r: np.abs(r["dspeed"])),
    ]
    for ax, label, metric in panels:
        for key, color, name in (("before", "tab:red", "uncalibrated"), ("after", "tab:blue", "calibrated")):
            m = metric(res[key])
            t = t_all[-m.shape[1] :]  # a speed is measured over the rows that end at its sample
            ax.plot(t, np.sqrt(np.mean(m**2, axis=0)), color=color, label=f"{name}: RMS")
            ax.fill_between(t, *np.percentile(m, [25, 75], axis=0), color=color, alpha=0.15, label=f"{name}: 25–75 %")
        ax.set_xlabel("time into the replay window (s)")
        ax.set_ylabel(label)
        ax.set_ylim(bottom=0)
        ax.legend(fontsize=8)
    names = ", ".join(e.name for e in result.calibration.effects) or "no effects"
    fig.suptitle(f"Calibration ({names}) on {len(result.windows)} held-out 1 s windows")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _residual(result: Result, key: str) -> dict[str, np.ndarray]:
    from sim.calibration.replay import residuals

    return residuals(result.replays[key], result.replays["measured"])


def _plot_paths(ax, result: Result, episodes: int) -> None:
    w, reps = result.windows, result.replays
    chosen = np.unique(w.traj)[:: max(1, len(np.unique(w.traj)) // episodes)][:episodes]
    for t in chosen:
        tr = w.trajectories[t]
        ax.plot(tr.x, tr.y, color="0.75", lw=3, zorder=1)
    labelled = set()
    for i in np.flatnonzero(np.isin(w.traj, chosen)):
        for key, color, name in (
            ("measured", "k", "measured"),
            ("before", "tab:red", "uncalibrated"),
            ("after", "tab:blue", "calibrated"),
        ):
            ax.plot(
                reps[key]["x"][i],
                reps[key]["y"][i],
                color=color,
                lw=1.2,
                zorder=2,
                label=None if name in labelled else f"{name} (1 s windows)",
            )
            labelled.add(name)
        ax.plot(reps["measured"]["x"][i, 0], reps["measured"]["y"][i, 0], "k.", ms=4, zorder=3)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{len(chosen)} episodes: each window starts at the measured state (dots)")
    ax.legend(fontsize=8, loc="best")
