"""DeepRacer sim-traces: one CSV row per step, ``SIM_TRACE_LOG:`` log lines, and where the CSVs go in a run.

The community's ``deepracer-utils`` (``deepracer.logs``) reads a run folder with
``DeepRacerLog("<store>/runs/<run_id>").load()`` exactly as it reads a DeepRacer-for-Cloud (DRfC) model folder,
and with ``S3FileHandler(bucket, prefix + "runs/<run_id>")`` when the store is a bucket.

Layout (DRfC's multi-worker model folder, ``LogFolderType.DRFC_MODEL_MULTIPLE_WORKERS``; the keys are spelled by
``model_store/runs.py: simtrace_key``, which owns the run's layout in the store)::

    runs/{run_id}/{k}/training-simtrace/{N}-iteration.csv                 worker k, policy version N
    runs/{run_id}/evaluation-{YYYYMMDDHHMMSS}/evaluation-simtrace/0-iteration.csv   one evaluation

Why this one: deepracer-utils knows five local layouts. The two console ones (``sim-trace/training/...`` beside
RoboMaker logs) need the console's ``.log`` files and tarball structure; DRfC's single-worker one
(``training-simtrace/`` at the top) has one file per iteration, which several racer workers writing independently
would overwrite. DRfC's multi-worker layout gives each worker its own folder, lives at the top of the model folder
(so the run folder itself is the "model folder"), and is detected from a folder named ``0``. Its limits, which are
deepracer-utils' and not ours: worker folders are one character (its path regex is ``/(.)/training-simtrace/``), so
only worker indexes 0-9 load and a folder ``10`` or above makes its whole load fail (``racer train`` numbers its
workers 0..N-1; give compose workers ``RACER_WORKER_INDEX`` 0-9, not the random default), worker 0 must have written
a file for the folder to be recognised, and only ``0-iteration.csv`` is read in an evaluation folder. It reads
``model/model_metadata.json`` and ``ip/hyperparameters.json`` for metadata; the trainer writes copies of the run's
files there (``trainer/checkpoints.py: Checkpoints.write_run_files``), so ``load()`` finds them.

Rows follow DeepRacer's convention (as in its public sim-traces, sim/cars/SOURCES.md): row k is the pose the car was in
when it chose action k, the reward computed at that pose, and the action chosen there, so the motion from row k to
row k+1 is caused by the action of row k. The first row of an episode is ``prepare`` (car at rest, steps 1, reward
0); racer's env step t is DeepRacer's step t+1. No action is chosen at the final pose of an episode, so its row
repeats the last action.

Iterations: DeepRacer's N-iteration.csv holds the episodes played with policy N. racer's workers switch policy
between segments, in the middle of an episode, so an episode belongs to the iteration (policy version) the
worker was acting with when it ENDED: splitting it across two files would give deepracer-utils an episode without
its ``prepare`` row. ``episode`` counts on across iterations per worker, as DeepRacer's does. deepracer-utils'
``unique_episode`` assumes every iteration has as many episodes per worker as iteration 0 (true in DeepRacer, not
always in racer), so with several workers group by ``["worker", "episode"]``, which is unique. A worker with K envs
(``--envs-per-worker``) writes the one file per iteration a one-env worker writes, not a folder per env (the 0-9
limit above would soon be passed, and DeepRacer's worker is the process): env j numbers its n-th episode n·K + j,
so episodes stay unique within the worker and are the usual 0, 1, 2, … with one env; :func:`merged_csv` writes each
episode's rows whole, episodes in the order of their numbers. ``tstamp`` is the
simulation time since the episode's reset (DeepRacer's clock runs on across episodes; its tools use only differences
within an episode).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

LOG = logging.getLogger("racer.simtrace")

COLUMNS: list[str] = [
    "episode",
    "steps",
    "X",
    "Y",
    "yaw",
    "steer",
    "throttle",
    "action",
    "reward",
    "done",
    "all_wheels_on_track",
    "progress",
    "closest_waypoint",
    "track_len",
    "tstamp",
    "episode_status",
    "pause_duration",
]
"""DeepRacer's sim-trace header (the simapp's StepMetrics, without the 2026 obstacle_crash_counter/wall_clock)."""
OBSTACLE_COLUMN = "obstacle_crash_counter"
"""The column the simapp adds for races with objects (``markov/metrics/constants.py: StepMetrics``): crashes into an
object so far in the episode. Written only by runs with obstacles or bot cars; deepracer-utils reads it (and drops
it) when present."""


def _f(value: float) -> str:
    # DeepRacer writes str() of Python floats: full precision, "2.0" rather than "2".
    return repr(float(value))


def _action_text(action: int | Sequence[float]) -> str:
    """An index for discrete action spaces, ``[steer speed]`` (DeepRacer 2026's continuous format) otherwise."""
    if np.ndim(action) == 0:
        return str(int(action))  # type: ignore[arg-type]
    steer, speed = (float(v) for v in action)  # type: ignore[union-attr]
    return f"[{steer!r} {speed!r}]"


def simtrace_row(
    *,
    episode: int,
    steps: int,
    x: float,
    y: float,
    yaw_deg: float,
    steer_deg: float,
    throttle: float,
    action: int | tuple[float, float],
    reward: float,
    done: bool,
    all_wheels_on_track: bool,
    progress: float,
    closest_waypoint: int,
    track_len: float,
    tstamp: float,
    episode_status: str,
    pause_duration: float = 0.0,
) -> list[str]:
    """One sim-trace row as DeepRacer writes it: ``steps`` as a float (``1.0``), booleans ``True``/``False``,
    floats at full precision, ``tstamp`` (simulation time, s) to the millisecond like the simapp's clock."""
    return [
        str(int(episode)),
        _f(int(steps)),
        _f(x),
        _f(y),
        _f(yaw_deg),
        _f(steer_deg),
        _f(throttle),
        _action_text(action),
        _f(reward),
        str(bool(done)),
        str(bool(all_wheels_on_track)),
        _f(progress),
        str(int(closest_waypoint)),
        _f(track_len),
        _f(round(float(tstamp), 3)),
        str(episode_status),
        _f(pause_duration),
    ]


def _closest_waypoint(params: dict[str, Any]) -> int:
    """The nearer of ``closest_waypoints`` (DeepRacer's sim-trace logs the nearest waypoint, not the previous one)."""
    prev, nxt = (int(i) for i in params["closest_waypoints"])
    waypoints = params.get("waypoints")
    if not waypoints:
        return prev
    x, y = params["x"], params["y"]
    d_prev = math.hypot(waypoints[prev][0] - x, waypoints[prev][1] - y)
    d_next = math.hypot(waypoints[nxt][0] - x, waypoints[nxt][1] - y)
    return nxt if d_next < d_prev else prev


def row_from_step(
    info: dict[str, Any],
    *,
    episode: int,
    action: int | tuple[float, float],
    reward: float,
    done: bool,
    command: tuple[float, float] | None = None,
) -> list[str]:
    """A row from the env's ``info`` (of a step, or of a reset for the ``prepare`` row).

    The pose, progress, waypoint and time come from ``info["params"]``; ``steer``/``throttle`` are ``command``
    (steering deg, speed m/s), by default ``info["command"]``. ``steps`` is ``params["steps"]``, the env's step count
    + 1: DeepRacer counts the ``prepare`` row as step 1.
    """
    p = info["params"]
    steer, speed = command if command is not None else info["command"]
    return simtrace_row(
        episode=episode,
        steps=int(p["steps"]),
        x=p["x"],
        y=p["y"],
        yaw_deg=p["heading"],
        steer_deg=steer,
        throttle=speed,
        action=action,
        reward=reward,
        done=done,
        all_wheels_on_track=p["all_wheels_on_track"],
        progress=p["progress"],
        closest_waypoint=_closest_waypoint(p),
        track_len=p["track_length"],
        tstamp=p["sim_time"],
        episode_status=info["episode_status"],
        pause_duration=float(info.get("pause_duration", 0.0)),
    ) + ([str(int(info[OBSTACLE_COLUMN]))] if OBSTACLE_COLUMN in info else [])


class SimTraceWriter:
    """Rows of one iteration: the body of DeepRacer's ``N-iteration.csv``."""

    def __init__(self) -> None:
        self.rows: list[list[str]] = []

    def __len__(self) -> int:
        return len(self.rows)

    def add(self, row: list[str]) -> None:
        """Append a row (from :func:`simtrace_row` or :func:`row_from_step`)."""
        self.rows.append(row)

    def csv_text(self) -> str:
        """Header and rows, comma-separated, one per line (no quoting: no DeepRacer value holds a comma). Rows of a
        race with objects carry :data:`OBSTACLE_COLUMN` too (one env writes one kind of row)."""
        header = COLUMNS + [OBSTACLE_COLUMN] if self.rows and len(self.rows[0]) > len(COLUMNS) else COLUMNS
        return "".join(",".join(r) + "\n" for r in [header, *self.rows])

    def clear(self) -> None:
        """Forget the rows (after they were uploaded)."""
        self.rows.clear()

    @staticmethod
    def log_line(row: list[str]) -> str:
        """The row as the simapp logs it: ``SIM_TRACE_LOG:`` and its printf precisions (4 decimals for the pose,
        2 for the command, the action and time as written in the CSV)."""
        (ep, steps, x, y, yaw, steer, speed, action, reward, done, on, prog, wp, length, t, status, pause) = row[:17]
        crashes = "".join(f",{int(c)}" for c in row[17:])
        return (
            f"SIM_TRACE_LOG:{int(ep)},{int(float(steps))},{float(x):.4f},{float(y):.4f},{float(yaw):.4f},"
            f"{float(steer):.2f},{float(speed):.2f},{action},{float(reward):.4f},{done},{on},{float(prog):.4f},"
            f"{int(wp)},{float(length):.2f},{t},{status},{float(pause):.2f}{crashes}"
        )


@dataclass
class _Pose:
    """A pose waiting for the action chosen at it."""

    info: dict[str, Any]
    reward: float
    done: bool


class SimTraceRecorder:
    """Turns env resets and steps into rows in DeepRacer's order (each pose with the action chosen at it).

    ``reset`` after every ``env.reset``, ``step`` after every ``env.step``; ``take`` returns the CSV text of the
    finished episodes (and clears them) when an iteration ends. Each row is also logged as a ``SIM_TRACE_LOG:`` line
    on the ``racer.simtrace`` logger at INFO, as the simapp logs it to its RoboMaker log.
    """

    def __init__(self) -> None:
        self.writer = SimTraceWriter()
        """Finished episodes not yet taken."""
        self.open: list[list[str]] = []
        """Rows of the episode in progress."""
        self.episode = 0
        """Number of the episode being recorded."""
        self._pose: _Pose | None = None
        self._last: tuple[int | tuple[float, float], tuple[float, float]] | None = None

    def reset(self, info: dict[str, Any], episode: int) -> None:
        """An episode starts: its ``prepare`` row waits for the first action."""
        self._close_episode()  # an episode cut short by a reset keeps its rows
        self.episode = episode
        self._pose = _Pose(info, 0.0, False)

    def step(self, action: Any, info: dict[str, Any], reward: float, done: bool) -> None:
        """``action`` was applied from the waiting pose, leading to ``info``'s pose; ``done`` ends the episode."""
        command = (float(info["command"][0]), float(info["command"][1]))
        # A continuous action is logged as the clipped command, as the car (and DeepRacer's log) got it.
        recorded = int(action) if np.ndim(action) == 0 else command
        self._last = (recorded, command)
        self._emit(recorded, command)
        self._pose = _Pose(info, float(reward), bool(done))
        if done:
            self._emit(recorded, command)  # the final pose: no action is chosen there, repeat the last one
            self._close_episode()

    def take(self, include_open: bool = False) -> str | None:
        """CSV text of the finished episodes (plus, with ``include_open``, the one in progress), then forget them;
        None when there are no rows. The episode in progress otherwise stays for the next iteration."""
        return merged_csv([self], include_open)

    def take_rows(self, include_open: bool = False) -> list[list[str]]:
        """The rows :meth:`take` would write, then forget them."""
        if include_open:
            if self._last is not None:
                self._emit(*self._last)
            self._close_episode()
        rows = list(self.writer.rows)
        self.writer.clear()
        return rows

    def extend(self, other: SimTraceRecorder) -> None:
        """Append ``other``'s finished episodes to this recording (trials driven side by side, kept in order)."""
        self.writer.rows.extend(other.writer.rows)
        other.writer.clear()

    def _emit(self, action: int | tuple[float, float], command: tuple[float, float]) -> None:
        pose = self._pose
        if pose is None:
            return
        row = row_from_step(
            pose.info, episode=self.episode, action=action, reward=pose.reward, done=pose.done, command=command
        )
        self.open.append(row)
        self._pose = None
        if LOG.isEnabledFor(logging.INFO):
            LOG.info("%s", SimTraceWriter.log_line(row))

    def _close_episode(self) -> None:
        self.writer.rows.extend(self.open)
        self.open = []
        self._pose = None
        self._last = None


def merged_csv(recorders: Sequence[SimTraceRecorder], include_open: bool = False) -> str | None:
    """One CSV of the rows :meth:`SimTraceRecorder.take` would give for each recorder (several envs of one worker
    writing one file), episodes in the order of their numbers, each episode's rows whole and in order; None when
    there are no rows. The recorders must number their episodes apart (a rollout worker's env j of K numbers its
    n-th episode n·K + j)."""
    writer = SimTraceWriter()
    for recorder in recorders:
        writer.rows.extend(recorder.take_rows(include_open))
    if not writer.rows:
        return None
    if len(recorders) > 1:
        writer.rows.sort(key=lambda row: int(row[0]))  # stable: each episode's rows keep their order
    return writer.csv_text()
