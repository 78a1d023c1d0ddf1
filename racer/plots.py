"""Pictures of a run for people: training curves and evaluation trajectories on the track, as PNGs.

Everything is read through ``model_store.runs.RunStore`` (a local directory or S3 alike):

- ``read_metrics``: ``runs/{run_id}/metrics.jsonl``, one JSON object per training iteration (written by the trainer);
- ``read_evaluation(s)``: ``runs/{run_id}/evaluations/{version:09d}.json``, one per evaluated checkpoint (written by
  the evaluator), with its trials' trajectories as ``[[x, y, speed_mps], ...]``.

Figures are drawn on matplotlib's Agg canvas directly (``Figure`` + ``FigureCanvasAgg``), never through pyplot:
no display is needed, and importing this module does not switch the backend of a process that has its own.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Literal

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from common.errors import UserError
from model_store.runs import METRICS_FILE, RunStore
from model_store.store import StoreKeyError
from sim.texture import TextureFrame, draw_surface
from sim.track import load_track

log = logging.getLogger(__name__)

DPI = 100
"""Resolution of every PNG, dots per inch: a PNG is ``figsize × DPI`` pixels."""
TRAINING_FIGSIZE = (10.0, 7.0)
"""Size of training.png, inches (1000×700 px)."""
TRAJECTORY_FIGSIZE = (10.0, 8.0)
"""Size of trajectories.png, inches (1000×800 px)."""
BACKGROUND_PPM = 50.0
"""Resolution of the track drawn under the trajectories, pixels per metre (2 cm pixels are plenty at this size)."""
SPEED_CMAP = "cool"
"""Colormap of the trajectories: cyan→magenta stands out on the green, grey, white and yellow of the track."""


Version = int | Literal["best", "latest"] | str | None


# -- reading -----------------------------------------------------------------------------------------------------------


def _training_rows(run_id: str, runs: RunStore) -> list[dict[str, Any]]:
    """``RunStore.read_metrics``, as a ValueError naming the run if it has no (or an empty) metrics.jsonl."""
    try:
        rows = runs.read_metrics(run_id)
    except StoreKeyError as exc:
        raise UserError(f"cannot plot training of run {run_id!r}: {exc}") from None
    if not rows:
        raise UserError(f"cannot plot training of run {run_id!r}: its {METRICS_FILE} has no rows")
    return rows


def _pick_evaluation(run_id: str, runs: RunStore, version: Version) -> int:
    """The evaluated version to draw: newest (None), a number, or the checkpoint a pointer names."""
    available = runs.evaluation_versions(run_id)
    if not available:
        raise UserError(f"run {run_id!r} has no evaluations in {runs.store.uri}")
    if version is None:
        return available[-1]
    if isinstance(version, str) and not version.isdecimal():
        wanted = _pointer_version(run_id, runs, version, available)
    else:
        wanted = runs.resolve(run_id, version)
    if wanted not in available:
        raise UserError(f"run {run_id!r} has no evaluation of checkpoint {wanted} (evaluated: {_short(available)})")
    return wanted


def _pointer_version(run_id: str, runs: RunStore, name: str, available: list[int]) -> int:
    """The version the ``best``/``latest`` pointer names; without a pointer, the best-scored or newest evaluation."""
    try:
        return runs.resolve(run_id, name)
    except StoreKeyError:
        pass
    if name == "latest":
        return available[-1]
    scored = [(float(e.get("score") or 0.0), e["version"]) for e in runs.read_evaluations(run_id)]
    return max(scored)[1] if scored else available[-1]


def _short(versions: list[int]) -> str:
    return ", ".join(map(str, versions)) if len(versions) <= 8 else f"{versions[0]}..{versions[-1]} ({len(versions)})"


# -- training ----------------------------------------------------------------------------------------------------------


def _column(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    """A metrics column as floats, NaN where a row lacks it (older runs, other writers)."""
    values = [row.get(key) for row in rows]
    return np.array([v if isinstance(v, int | float) and not isinstance(v, bool) else np.nan for v in values], float)


def _smooth(y: np.ndarray) -> np.ndarray | None:
    """A centred moving average over ~1/15 of the run, or None when the run is too short to need one."""
    window = len(y) // 15
    if window < 3 or np.isnan(y).any():
        return None
    kernel = np.ones(window) / window
    padded = np.pad(y, (window // 2, window - 1 - window // 2), mode="edge")
    return np.convolve(padded, kernel, mode="valid")


def _eval_iterations(rows: list[dict[str, Any]], evaluations: list[dict[str, Any]]) -> np.ndarray:
    """The iteration each evaluated checkpoint was written at (policy_version == iteration in metrics)."""
    by_version = {row.get("policy_version"): row.get("iteration") for row in rows}
    return np.array([by_version.get(e["version"], e["version"]) for e in evaluations], float)


def _extrapolate(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """``np.interp`` continued linearly past both ends: the axis margins lie outside the data, and a clamped
    mapping would put several tick labels on one spot there."""
    x = np.asarray(x, float)
    left = fp[0] + (x - xp[0]) * (fp[1] - fp[0]) / (xp[1] - xp[0])
    right = fp[-1] + (x - xp[-1]) * (fp[-1] - fp[-2]) / (xp[-1] - xp[-2])
    return np.where(x < xp[0], left, np.where(x > xp[-1], right, np.interp(x, xp, fp)))


def _env_steps_axis(ax: Any, iterations: np.ndarray, env_steps: np.ndarray) -> None:
    """A secondary x axis on top reading env steps, when env steps grow strictly with the iteration."""
    ok = ~np.isnan(env_steps)
    it, steps = iterations[ok], env_steps[ok]
    if len(it) < 2 or np.any(np.diff(it) <= 0) or np.any(np.diff(steps) <= 0):
        return
    top = ax.secondary_xaxis(
        "top", functions=(lambda x: _extrapolate(x, it, steps), lambda s: _extrapolate(s, steps, it))
    )
    top.set_xlabel("env steps")


def _curve(ax: Any, it: np.ndarray, y: np.ndarray, colour: str, label: str) -> None:
    """Per-iteration values as dots on a thin line, with a moving average on top when the run is long and noisy."""
    smooth = _smooth(y)
    ax.plot(it, y, color=colour, lw=1, alpha=1 if smooth is None else 0.4, marker=".", ms=4, label=label)
    if smooth is not None:
        ax.plot(it, smooth, color=colour, lw=2, label=f"{label}, moving average")


def _draw_reward(ax: Any, it: np.ndarray, rows: list[dict[str, Any]]) -> None:
    _curve(ax, it, _column(rows, "mean_reward"), "tab:blue", "mean reward")
    ax.set_ylabel("mean episode reward")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=9)


def _draw_progress(ax: Any, it: np.ndarray, rows: list[dict[str, Any]], evaluations: list[dict[str, Any]]) -> None:
    progress = _column(rows, "mean_progress")
    laps = 100 * _column(rows, "laps_completed") / np.maximum(_column(rows, "episodes"), 1)
    _curve(ax, it, progress, "tab:green", "mean progress (training)")
    if np.isfinite(laps).any():  # older or other writers may not record laps
        smooth_laps = _smooth(laps)  # a lap count per iteration is too jumpy to read raw over a long run
        laps_label = "laps completed (training, % of episodes)" + ("" if smooth_laps is None else ", moving average")
        ax.plot(it, laps if smooth_laps is None else smooth_laps, color="tab:olive", lw=1.2, ls="--", label=laps_label)
    if evaluations:
        ev_it = _eval_iterations(rows, evaluations)
        completion = [100 * float(e.get("completion_rate") or 0.0) for e in evaluations]
        ev_progress = [float(e.get("mean_progress") or 0.0) for e in evaluations]
        ax.scatter(ev_it, ev_progress, s=50, facecolors="none", edgecolors="tab:red", label="eval mean progress")
        ax.scatter(ev_it, completion, s=60, marker="D", color="tab:red", zorder=3, label="eval completion rate")
    ax.set_ylim(-3, 103)
    ax.set_xlabel("iteration (= policy version)")
    ax.set_ylabel("%")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8, ncols=2)


def plot_training(run_id: str, runs: RunStore, out_png: str | Path) -> Path:
    """PNG of a run's training: mean reward (top) and mean progress / laps with evaluations (bottom) per iteration.

    Evaluation completion rates (%) are red diamonds at the iteration of each evaluated checkpoint; env steps read
    on a secondary axis at the top. ValueError naming the run if it has no (or an empty) metrics.jsonl.
    """
    rows = _training_rows(run_id, runs)
    evaluations = runs.read_evaluations(run_id)
    it = _column(rows, "iteration")
    it = np.where(np.isnan(it), np.arange(1, len(rows) + 1), it)  # rows without an iteration: count them
    fig = Figure(figsize=TRAINING_FIGSIZE, dpi=DPI, layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True)
    _draw_reward(top, it, rows)
    _env_steps_axis(top, it, _column(rows, "env_steps"))
    _draw_progress(bottom, it, rows, evaluations)
    steps = _column(rows, "env_steps")
    last = f"{int(steps[-1]):,} env steps" if not np.isnan(steps[-1]) else f"{len(rows)} iterations"
    fig.suptitle(f"run {run_id}: training ({len(rows)} iterations, {last}, {len(evaluations)} evaluations)")
    return save_figure(fig, out_png)


def save_figure(fig: Figure, out_png: str | Path) -> Path:
    """Write ``fig`` as a PNG at ``out_png`` (creating its folder) with the Agg canvas; return the path."""
    path = Path(out_png)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(fig).print_png(str(path))
    return path


# -- trajectories ------------------------------------------------------------------------------------------------------


def draw_track(ax: Any, track_name: str) -> None:
    """The track as the simulator draws it, placed in metres so trajectories plot in track coordinates."""
    track = load_track(track_name)
    frame = TextureFrame.for_track(track, ppm=BACKGROUND_PPM)
    surface = draw_surface(track, frame)
    width_m, height_m = frame.size_m
    extent = (frame.x0, frame.x0 + width_m, frame.y1 - height_m, frame.y1)
    ax.imshow(surface, extent=extent, origin="upper", interpolation="bilinear")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])


def _trajectory(trial: dict[str, Any]) -> np.ndarray:
    """A trial's trajectory as (K, 3) floats (x, y, speed); (0, 3) if absent or malformed."""
    points = np.asarray(trial.get("trajectory") or [], dtype=float)
    return points if points.ndim == 2 and points.shape[1] >= 3 else np.zeros((0, 3))


def _draw_paths(ax: Any, paths: list[np.ndarray], norm: Normalize) -> LineCollection:
    """All trajectories as one LineCollection, each segment coloured by the speed at its start."""
    segments = [np.stack([p[:-1, :2], p[1:, :2]], axis=1) for p in paths if len(p) >= 2]
    speeds = [p[:-1, 2] for p in paths if len(p) >= 2]
    lines = LineCollection(
        np.concatenate(segments) if segments else np.zeros((0, 2, 2)),
        cmap=SPEED_CMAP,
        norm=norm,
        linewidths=3.0,
        capstyle="round",
        zorder=2,
    )
    lines.set_array(np.concatenate(speeds) if speeds else np.zeros(0))
    ax.add_collection(lines)
    return lines


_MARKERS = {  # scatter style of each kind of point; the keys of the ends are _end_kind's answers
    "start": dict(marker="o", s=30, color="white", edgecolors="black", label="start"),
    "lap_complete": dict(marker="*", s=220, color="lime", edgecolors="black", label="lap completed"),
    "off_track": dict(marker="X", s=110, color="red", edgecolors="white", label="off track"),
    "other": dict(marker="^", s=90, color="orange", edgecolors="black", label="other end (immobilized, time up, ...)"),
}


def _draw_ends(ax: Any, trials: list[dict[str, Any]], paths: list[np.ndarray]) -> None:
    """Mark where each trial started and ended: completed laps, off-track ends and any other end."""
    points = {kind: [] for kind in _MARKERS}
    for trial, path in zip(trials, paths, strict=True):
        if len(path):
            points["start"].append(path[0, :2])
            points[_end_kind(trial)].append(path[-1, :2])
    for kind, xy in points.items():
        if xy:
            xy = np.array(xy)
            ax.scatter(xy[:, 0], xy[:, 1], zorder=4 if kind != "start" else 3, linewidths=0.8, **_MARKERS[kind])


def _legend(fig: Figure) -> None:
    """Every marker kind, whether drawn or not, so that the key (and the layout) is the same on every picture."""
    handles = [
        Line2D([], [], ls="", marker=m["marker"], ms=np.sqrt(m["s"]), mfc=m["color"], mec=m["edgecolors"], mew=0.8)
        for m in _MARKERS.values()
    ]
    labels = [m["label"] for m in _MARKERS.values()]
    # Below the axes: inside, any corner covers some track.
    fig.legend(handles, labels, loc="outside lower center", ncols=4, fontsize=9, frameon=False)


def _end_kind(trial: dict[str, Any]) -> str:
    status = trial.get("status")
    return status if status in ("lap_complete", "off_track") else "other"


def _trajectory_title(run_id: str, evaluation: dict[str, Any], drawn: int, skipped: int) -> str:
    best = evaluation.get("best_lap_s")
    best_text = f"best lap {best:.2f} s" if isinstance(best, int | float) else "no lap completed"
    steps = evaluation.get("env_steps")
    steps_text = f" ({steps:,} env steps)" if isinstance(steps, int) else ""
    rate = float(evaluation.get("completion_rate") or 0.0)
    other = f", {skipped} trials on other tracks not shown" if skipped else ""
    return (
        f"run {run_id}: checkpoint {evaluation['version']}{steps_text} on {evaluation.get('track', '?')}\n"
        f"{drawn} trials{other}; completion {rate:.0%}, mean progress "
        f"{float(evaluation.get('mean_progress') or 0.0):.1f} %, {best_text}"
    )


def plot_trajectories(run_id: str, runs: RunStore, out_png: str | Path, version: Version = None) -> Path:
    """PNG of one evaluation's trajectories on the track from above, coloured by speed (m/s colorbar).

    ``version``: None for the newest evaluation, a checkpoint number, or ``"best"``/``"latest"`` (the checkpoint
    the run's pointer names; without that pointer, the best-scored or newest evaluation). Completed laps end in a
    green star, off-track ends in a red cross. ValueError naming the run if there is no such evaluation.
    """
    number = _pick_evaluation(run_id, runs, version)
    evaluation = {**runs.read_evaluation(run_id, number), "version": number}
    track_name = str(evaluation.get("track") or "")
    all_trials = [t for t in evaluation.get("trials") or [] if isinstance(t, dict)]
    # An evaluation could span tracks; only the trials on the drawn track belong on this picture.
    trials = [t for t in all_trials if t.get("track", track_name) == track_name]
    paths = [_trajectory(t) for t in trials]
    fig = Figure(figsize=TRAJECTORY_FIGSIZE, dpi=DPI, layout="constrained")
    ax = fig.add_subplot()
    draw_track(ax, track_name)
    speeds = np.concatenate([p[:, 2] for p in paths]) if paths else np.zeros(0)
    speeds = speeds[np.isfinite(speeds)]
    norm = Normalize(0.0, max(float(speeds.max()) if speeds.size else 0.0, 0.5))  # 0.5: a range even for no data
    lines = _draw_paths(ax, paths, norm)
    _draw_ends(ax, trials, paths)
    fig.colorbar(lines, ax=ax, label="speed (m/s)", shrink=0.6)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    _legend(fig)
    ax.set_title(_trajectory_title(run_id, evaluation, len(trials), len(all_trials) - len(trials)))
    return save_figure(fig, out_png)


# -- both --------------------------------------------------------------------------------------------------------------


def plot_run(run_id: str, runs: RunStore, out_dir: str | Path, *, checkpoint: Version = "best") -> list[Path]:
    """Write ``training.png`` and (if the run has evaluations) ``trajectories.png`` into ``out_dir``.

    ``checkpoint`` picks the evaluation trajectories.png draws, as :func:`plot_trajectories`'s ``version``: by
    default ``"best"``, the checkpoint the evaluator chose (the run's ``best.json``, as ``racer models ls`` marks it),
    since that is the one a user exports and races, not whichever was evaluated last. Returns the paths written. A
    run without evaluations gets only training.png, with a warning logged.
    """
    out = Path(out_dir)
    written = [plot_training(run_id, runs, out / "training.png")]
    if runs.evaluation_versions(run_id):
        written.append(plot_trajectories(run_id, runs, out / "trajectories.png", version=checkpoint))
    else:
        log.warning("run %r has no evaluations yet: skipped trajectories.png", run_id)
    return written


def write_track_picture(track: str, png: str | Path, start: int = 0, camera: str = "ground") -> None:
    """PNG of the track from above with the car at waypoint ``start``, and the car's camera view beside it."""
    import cv2

    from sim.env import RacerEnv
    from sim.views import side_by_side, top_down

    env = RacerEnv(track=track, camera=camera)
    obs, _ = env.reset(seed=0, options={"start_index": start, "reverse": False})
    top = top_down(env.track, env.texture, env.frame, [env.physics.pose])
    picture = side_by_side(top, obs[..., 0], f"{env.track.name}  {env.track.length:.2f} m")
    env.close()
    if not cv2.imwrite(str(png), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {str(png)!r}")
