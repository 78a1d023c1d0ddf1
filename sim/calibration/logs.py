"""Measured car logs, read into one normalized form: a :class:`Trajectory` per episode.

:func:`read_log` reads one file and tells the three formats apart by their content; :func:`read_logs` reads
files and folders. Anything unusable raises :class:`LogError`, one line naming the file (and the line or
episode) and what is wrong.

Formats
-------
1. **DeepRacer sim-trace CSV** (``training-simtrace/<N>-iteration.csv``, ``evaluation-simtrace/...``): the
   header ``episode,steps,X,Y,yaw,steer,throttle,action,reward,done,all_wheels_on_track,progress,
   closest_waypoint,track_len,tstamp,episode_status,pause_duration``; 2026 logs add
   ``obstacle_crash_counter,wall_clock``. Read: ``episode`` (splits the episodes), ``tstamp`` (simulation
   time, s), ``steer`` (degrees, + = left) and ``throttle`` (m/s), the COMMANDED action, ``X``, ``Y`` (m, a
   point 0.14 m ahead of base_link, hence ``reference_point_m = 0.14``) and ``yaw`` (degrees). The other
   columns need not be there. ``action`` is ignored: an action index, or ``[steer speed]`` for continuous
   action spaces, which repeats ``steer`` and ``throttle``.
2. **RoboMaker log** (``*-robomaker.log``): any text in which the sim-trace rows appear as
   ``SIM_TRACE_LOG:<the same 17 or 19 values, comma-separated>``, without a header; all other lines are
   ignored. Line numbers in errors are lines of the log file.
3. **Plain CSV** for logs from a real car: one header row holding (in any order, more columns allowed)::

       time_s,steer_cmd_deg,speed_cmd_mps,x_m,y_m,heading_deg[,episode]

   - ``time_s``: time of the sample, s, strictly increasing within an episode (any origin).
   - ``steer_cmd_deg``: commanded steering angle, degrees, + = left (as DeepRacer's ``steer``).
   - ``speed_cmd_mps``: commanded speed, m/s.
   - ``x_m``, ``y_m``: measured position, metres, in a fixed right-handed frame (+y is 90° left of +x).
   - ``heading_deg``: measured heading, degrees in [-180, 180], counter-clockwise from +x.
   - ``episode`` (optional): integer; rows of one episode are consecutive. Without it the file is episode 0.

   The measured point is the car's base_link (the rear-axle midpoint on DeepRacer) unless a comment line
   ``# reference_point_m: 0.14`` gives its distance ahead of base_link along the heading (m);
   ``# track: <name>`` names the track. Other lines starting with ``#`` and blank lines are ignored.

The normalized form
-------------------
Row k of an episode is sample k of its :class:`Trajectory`. As in DeepRacer, the action of row k is the one
chosen at sample k, so it causes the motion from sample k to sample k+1 (the simulator is paused between
steps); the last row's action never shows in the positions.

The first row of a DeepRacer episode (``episode_status`` ``prepare``) is kept as sample 0: it is the car
standing at its start pose together with the first action the policy chose there, so it is the initial state
of the first interval. One exception: a first sample more than :data:`MAX_STEP_M` from the second is a stale
pose (ROS2 simapp sometimes logs the previous episode's end pose before moving the car to its start) and
is dropped, with a logged warning. An episode that jumps more than :data:`MAX_STEP_M` later on (a reset,
a glitch of the measurement) is skipped with a warning, and so is, silently, an episode shorter than
:data:`MIN_ROWS` rows; a file with no usable episode left raises :class:`LogError`.

Checked, each a :class:`LogError`: missing or empty file, unknown header, missing columns (named),
a row with the wrong number of fields, non-numeric or non-finite values (line given), a non-integer
episode, an episode that starts again after other episodes, time not strictly increasing within an
episode (duplicates and steps back told apart), headings outside [-180, 180] degrees.
"""

from __future__ import annotations

import csv
import logging
import re
from collections.abc import Iterable
from dataclasses import KW_ONLY, dataclass, field
from pathlib import Path

import numpy as np

from common.errors import UserError
from common.simtrace import COLUMNS

log = logging.getLogger(__name__)

MIN_ROWS = 16
"""Fewest rows of a usable episode: about 1 s at DeepRacer's 15 Hz; shorter ones are skipped."""
MAX_STEP_M = 0.5
"""Largest plausible move between two samples, m: 4 m/s (DeepRacer's speed limit) × 0.12 s (its slowest step)."""
DEEPRACER_REFERENCE_POINT_M = 0.14
"""How far ahead of base_link DeepRacer's logged X, Y lie, m."""

SIMTRACE_COLUMNS = COLUMNS
"""The 17 columns of a DeepRacer sim-trace, in order; 2026 logs append :data:`SIMTRACE_2026_EXTRA`."""
SIMTRACE_2026_EXTRA = ["obstacle_crash_counter", "wall_clock"]
PLAIN_COLUMNS = ["time_s", "steer_cmd_deg", "speed_cmd_mps", "x_m", "y_m", "heading_deg"]
"""The required columns of the plain CSV format (``episode`` is optional)."""

SIMTRACE_PREFIX = "SIM_TRACE_LOG:"

# Normalized quantity -> the column holding it, per format; "episode" is the same name in both.
_SIMTRACE_MAP = {"t": "tstamp", "steer": "steer", "speed": "throttle", "x": "X", "y": "Y", "heading": "yaw"}
_PLAIN_MAP = dict(zip(("t", "steer", "speed", "x", "y", "heading"), PLAIN_COLUMNS, strict=True))
_ARRAY_FIELDS = ("t", "steer_cmd_deg", "speed_cmd_mps", "x", "y", "heading_deg")
_META_LINE = re.compile(r"#\s*(\w+)\s*:\s*(.*?)\s*$")


class LogError(UserError, ValueError):
    """A log that cannot be used; the one-line message names the file (and line or episode) and what is wrong."""


@dataclass(eq=False)
class Trajectory:
    """One episode of a measured log, in SI units and degrees; all arrays float64, one entry per sample.

    ``steer_cmd_deg[k]`` and ``speed_cmd_mps[k]`` are the action commanded at sample k, which drives the car
    from sample k to k+1. ``x``, ``y`` are the position of the point ``reference_point_m`` ahead of base_link
    along the heading. ``speed_measured_mps`` is computed, not read: the speed of that point from its
    positions (second-order finite differences over the irregular ``t``, one-sided at the ends). It is noisy:
    DeepRacer's ``tstamp`` jitters by ±20 ms around its 1/15 s steps independently of the distance covered.
    The arrays are read-only.
    """

    source: str
    """The file the episode was read from."""
    episode: int
    """The episode number in that file (0 where the file has none)."""
    t: np.ndarray
    """Sample times, s, strictly increasing."""
    _: KW_ONLY
    steer_cmd_deg: np.ndarray
    """Commanded steering angle, degrees, + = left."""
    speed_cmd_mps: np.ndarray
    """Commanded speed, m/s."""
    x: np.ndarray
    """Measured x of the reference point, m."""
    y: np.ndarray
    """Measured y of the reference point, m."""
    heading_deg: np.ndarray
    """Measured heading, degrees in [-180, 180], counter-clockwise from +x."""
    reference_point_m: float = 0.0
    """Distance of the measured point ahead of base_link, m (0.14 for DeepRacer logs)."""
    track: str | None = None
    """The track driven, when known (a track name racer knows: ``sim.track.known_track_names``)."""
    speed_measured_mps: np.ndarray = field(init=False)
    """Speed of the reference point estimated from x, y and t, m/s (>= 0)."""

    def __post_init__(self) -> None:
        arrays = [np.array(getattr(self, name), dtype=np.float64) for name in _ARRAY_FIELDS]
        n = len(arrays[0])
        if n < 2 or any(a.shape != (n,) for a in arrays):
            raise ValueError(f"Trajectory {self.source!r}: arrays must be 1-D, of one length >= 2")
        if not np.all(np.diff(arrays[0]) > 0):
            raise ValueError(f"Trajectory {self.source!r}: t must be strictly increasing")
        for name, a in zip(_ARRAY_FIELDS, arrays, strict=True):
            a.setflags(write=False)
            setattr(self, name, a)
        self.speed_measured_mps = _speed_from_positions(self.t, self.x, self.y)
        self.speed_measured_mps.setflags(write=False)

    def __len__(self) -> int:
        return len(self.t)

    def __repr__(self) -> str:
        return (
            f"Trajectory(source={self.source!r}, episode={self.episode}, samples={len(self)}, "
            f"t=[{self.t[0]:.3f} .. {self.t[-1]:.3f}], reference_point_m={self.reference_point_m}, "
            f"track={self.track!r})"
        )


def _speed_from_positions(t: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Speed of a point from its sampled positions: |d(x, y)/dt| by finite differences on an uneven grid."""
    return np.hypot(np.gradient(x, t), np.gradient(y, t))


@dataclass
class _Table:
    """The raw text rows of one file, before any conversion."""

    path: Path
    kind: str  # "simtrace" or "plain"
    _: KW_ONLY
    columns: dict[str, int]  # column name -> field index
    rows: list[list[str]]
    lines: list[int]  # 1-based line number of each row in the file
    meta: dict[str, str]  # "# key: value" comments of a plain CSV


# ----------------------------------------------------------------------------------------------- public API


def read_log(path: str | Path, track: str | None = None) -> list[Trajectory]:
    """Read one log file (sim-trace CSV, RoboMaker log or plain CSV) into a Trajectory per usable episode.

    ``track`` names the track driven; without it, a ``# track:`` comment (plain CSV) or else a known
    track name found in the file's path (e.g. ``.../gazebo-ros1-console2022-reinvent_base/...``) is used.
    """
    path = Path(path)
    table = _parse(path, _read_text(path))
    reference = DEEPRACER_REFERENCE_POINT_M if table.kind == "simtrace" else _plain_reference(table)
    track = track or table.meta.get("track") or _track_from_path(path)
    return _trajectories(table, reference, track)


def read_logs(paths: str | Path | Iterable[str | Path], track: str | None = None) -> list[Trajectory]:
    """Read log files and folders (every ``.csv`` and ``.log`` below a folder, in natural order) into Trajectories.

    Any unusable file raises :class:`LogError`; no paths at all give an empty list.
    """
    if isinstance(paths, str | Path):
        paths = [paths]
    out: list[Trajectory] = []
    for p in map(Path, paths):
        for f in _log_files(p) if p.is_dir() else [p]:
            out.extend(read_log(f, track=track))
    return out


# ----------------------------------------------------------------------------------------------- files


def _log_files(folder: Path) -> list[Path]:
    """The .csv and .log files below a folder, sorted so that 2-iteration comes before 10-iteration."""
    files = [f for f in folder.rglob("*") if f.is_file() and f.suffix.lower() in (".csv", ".log")]
    if not files:
        raise LogError(f"{folder}: folder holds no .csv or .log files")
    return sorted(files, key=lambda f: _natural_key(str(f.relative_to(folder))))


def _natural_key(text: str) -> list[str | int]:
    """Sort key that orders digit runs by value (re.split alternates text and digits, so types line up)."""
    return [int(s) if i % 2 else s for i, s in enumerate(re.split(r"(\d+)", text))]


def _read_text(path: Path) -> str:
    """The file's text; LogError if it is missing, a folder, not text, or empty."""
    if not path.exists():
        raise LogError(f"{path}: no such file")
    if path.is_dir():
        raise LogError(f"{path}: is a folder (read_logs reads folders)")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise LogError(f"{path}: not a text file (not UTF-8)") from None
    except OSError as exc:
        raise LogError(f"{path}: cannot be read: {exc.strerror}") from None
    if not text.strip():
        raise LogError(f"{path}: file is empty")
    return text


def _track_from_path(path: Path) -> str | None:
    """The longest track name racer knows (``sim.track.known_track_names``: its own, the cached DeepRacer tracks
    and those that can be pulled) that appears in the path (DeepRacer logs do not name their track)."""
    from sim.track import known_track_names

    found = [name for name in known_track_names() if name in str(path.absolute())]
    return max(found, key=len) if found else None


# ----------------------------------------------------------------------------------------------- parsing


def _parse(path: Path, text: str) -> _Table:
    """Split a file's text into a _Table, choosing the format from its content."""
    lines = text.splitlines()
    if any(SIMTRACE_PREFIX in line for line in lines):
        return _parse_robomaker(path, lines)
    return _parse_csv(path, lines)


def _parse_robomaker(path: Path, lines: list[str]) -> _Table:
    """Rows from the ``SIM_TRACE_LOG:`` lines of a RoboMaker log (the prefix may follow a timestamp)."""
    picked = [
        (n, line.split(SIMTRACE_PREFIX, 1)[1].strip()) for n, line in enumerate(lines, 1) if SIMTRACE_PREFIX in line
    ]
    numbers = [n for n, _ in picked]
    rows = [_merge_brackets(r) for r in csv.reader(text for _, text in picked)]
    widths = (len(SIMTRACE_COLUMNS), len(SIMTRACE_COLUMNS) + len(SIMTRACE_2026_EXTRA))
    for n, row in zip(numbers, rows, strict=True):
        if len(row) not in widths:
            raise LogError(
                f"{path}, line {n}: SIM_TRACE_LOG has {len(row)} fields, expected {' or '.join(map(str, widths))}"
            )
    columns = {name: i for i, name in enumerate(SIMTRACE_COLUMNS)}
    return _Table(path, "simtrace", columns=columns, rows=rows, lines=numbers, meta={})


def _parse_csv(path: Path, lines: list[str]) -> _Table:
    """Rows of a CSV with one header row; blank lines and ``#`` comments (kept as metadata) are skipped."""
    meta: dict[str, str] = {}
    kept: list[tuple[int, str]] = []
    for n, line in enumerate(lines, 1):
        if line.lstrip().startswith("#"):
            if m := _META_LINE.match(line.strip()):
                meta[m.group(1)] = m.group(2)
        elif line.strip():
            kept.append((n, line))
    if not kept:
        raise LogError(f"{path}: file is empty (comments only)")
    header, *rows = [[f.strip() for f in r] for r in csv.reader(line for _, line in kept)]
    numbers = [n for n, _ in kept[1:]]
    kind = _detect_kind(path, header)
    columns = {name: i for i, name in enumerate(header)}
    _check_columns(path, kind, columns)
    for n, row in zip(numbers, rows, strict=True):
        if len(row) != len(header):
            row[:] = _merge_brackets(row)
        if len(row) != len(header):
            raise LogError(f"{path}, line {n}: {len(row)} fields, the header has {len(header)}")
    if not rows:
        raise LogError(f"{path}: header but no data rows")
    return _Table(path, kind, columns=columns, rows=rows, lines=numbers, meta=meta)


def _detect_kind(path: Path, header: list[str]) -> str:
    """'simtrace' or 'plain', whichever format's own columns the header shares more of."""
    names = set(header) - {"episode"}
    simtrace = len(names & set(SIMTRACE_COLUMNS + SIMTRACE_2026_EXTRA))
    plain = len(names & set(PLAIN_COLUMNS))
    if simtrace == plain == 0:
        raise LogError(
            f"{path}: unknown header {','.join(header)[:80]!r}: expected a DeepRacer sim-trace "
            f"({','.join(SIMTRACE_COLUMNS[:7])},...) or the plain format ({','.join(PLAIN_COLUMNS)})"
        )
    return "simtrace" if simtrace > plain else "plain"


def _check_columns(path: Path, kind: str, columns: dict[str, int]) -> None:
    """LogError naming every column the format needs that the header lacks."""
    used = {"episode", *_SIMTRACE_MAP.values()}
    needed = [c for c in SIMTRACE_COLUMNS if c in used] if kind == "simtrace" else PLAIN_COLUMNS
    missing = [name for name in needed if name not in columns]
    if missing:
        label = "DeepRacer sim-trace" if kind == "simtrace" else "plain CSV"
        raise LogError(f"{path}: {label} lacks column(s) {', '.join(missing)}")


def _merge_brackets(fields: list[str]) -> list[str]:
    """Rejoin a list-valued field such as ``[-25.0, 1.3]`` that an unquoting writer split at its commas."""
    out: list[str] = []
    open_parts: list[str] | None = None
    for f in fields:
        if open_parts is not None:
            open_parts.append(f)
            if "]" in f:
                out.append(",".join(open_parts))
                open_parts = None
        elif f.lstrip().startswith("[") and "]" not in f:
            open_parts = [f]
        else:
            out.append(f)
    return out + (open_parts or [])


def _plain_reference(table: _Table) -> float:
    """The ``# reference_point_m:`` of a plain CSV, 0.0 (base_link) without one."""
    text = table.meta.get("reference_point_m")
    if text is None:
        return 0.0
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and abs(value) < 1.0):
        raise LogError(f"{table.path}: '# reference_point_m: {text}' is not a distance in metres (|d| < 1)")
    return value


# ----------------------------------------------------------------------------------------------- values


def _column(table: _Table, name: str) -> np.ndarray:
    """One column as float64; LogError at the first non-numeric or non-finite value, naming its line."""
    i = table.columns[name]
    out = np.empty(len(table.rows))
    for k, row in enumerate(table.rows):
        try:
            out[k] = float(row[i])
        except ValueError:
            raise LogError(f"{table.path}, line {table.lines[k]}: {name} is not a number: {row[i]!r}") from None
    bad = np.flatnonzero(~np.isfinite(out))
    if bad.size:
        k = bad[0]
        raise LogError(f"{table.path}, line {table.lines[k]}: {name} is not finite: {table.rows[k][i]!r}")
    return out


def _episodes(table: _Table) -> np.ndarray:
    """The episode number of each row (0 where the file has no episode column); LogError if not integers."""
    if "episode" not in table.columns:
        return np.zeros(len(table.rows), dtype=np.int64)
    ep = _column(table, "episode")
    bad = np.flatnonzero(ep != np.round(ep))
    if bad.size:
        raise LogError(f"{table.path}, line {table.lines[bad[0]]}: episode is not an integer: {float(ep[bad[0]])!r}")
    return ep.astype(np.int64)


def _episode_blocks(table: _Table, ep: np.ndarray) -> list[tuple[int, int, int]]:
    """(episode, first row, end row) of each run of equal episode numbers; LogError if an episode recurs."""
    starts = [0, *(np.flatnonzero(np.diff(ep) != 0) + 1).tolist()]
    stops = [*starts[1:], len(ep)]
    first_line: dict[int, int] = {}
    for s in starts:
        e = int(ep[s])
        if e in first_line:  # interleaved episodes would be two cars' rows mixed up; refuse rather than guess
            raise LogError(
                f"{table.path}, line {table.lines[s]}: episode {e} starts again (it first ended before "
                f"other episodes; its first row is line {first_line[e]})"
            )
        first_line[e] = table.lines[s]
    return [(int(ep[s]), s, e) for s, e in zip(starts, stops, strict=True)]


def _check_time(table: _Table, name: str, t: np.ndarray, episode: int, start: int) -> None:
    """LogError at the first sample of an episode whose time is not after the previous one."""
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        k = bad[0] + 1
        problem = "duplicate timestamp" if t[k] == t[k - 1] else "time goes backwards"
        raise LogError(
            f"{table.path}, line {table.lines[start + k]}, episode {episode}: {problem}: "
            f"{name} {float(t[k])!r} after {float(t[k - 1])!r}"
        )


def _check_heading(table: _Table, name: str, heading: np.ndarray) -> None:
    """LogError at the first heading outside [-180, 180] degrees (radians would pass, but nothing else does)."""
    bad = np.flatnonzero(np.abs(heading) > 180.0)
    if bad.size:
        k = bad[0]
        where = f"{table.path}, line {table.lines[k]}"
        raise LogError(f"{where}: {name} {float(heading[k])!r} is outside [-180, 180] degrees")


# ----------------------------------------------------------------------------------------------- episodes


def _trajectories(table: _Table, reference: float, track: str | None) -> list[Trajectory]:
    """Validate the whole table, then cut it into usable episodes; LogError if none is usable."""
    names = _SIMTRACE_MAP if table.kind == "simtrace" else _PLAIN_MAP
    values = {key: _column(table, col) for key, col in names.items()}
    _check_heading(table, names["heading"], values["heading"])
    blocks = _episode_blocks(table, _episodes(table))
    for episode, s, e in blocks:
        _check_time(table, names["t"], values["t"][s:e], episode, s)
    out, skipped = [], {"short": 0, "jump": 0}
    for episode, s, e in blocks:
        rows = _usable_rows(table, episode, values["x"][s:e], values["y"][s:e])
        if rows is None:
            skipped["jump"] += 1
        elif rows.stop - rows.start < MIN_ROWS:
            skipped["short"] += 1
            log.debug("%s: episode %d skipped: %d rows < %d", table.path, episode, rows.stop - rows.start, MIN_ROWS)
        else:
            part = {key: v[s:e][rows] for key, v in values.items()}
            out.append(_make(table, episode, part, reference, track))
    if not out:
        raise LogError(
            f"{table.path}: no usable episode: of {len(blocks)}, {skipped['short']} have fewer than {MIN_ROWS} "
            f"rows and {skipped['jump']} jump more than {MAX_STEP_M} m between samples"
        )
    return out


def _usable_rows(table: _Table, episode: int, x: np.ndarray, y: np.ndarray) -> slice | None:
    """The rows of an episode worth keeping: all, all but a stale first pose, or None if it jumps later on."""
    step = np.hypot(np.diff(x), np.diff(y))
    first = 0
    if step.size and step[0] > MAX_STEP_M:
        log.warning("%s: episode %d: first pose %.2f m from the next, dropped as stale", table.path, episode, step[0])
        first = 1
    later = np.flatnonzero(step[first:] > MAX_STEP_M)
    if later.size:
        k = first + later[0]
        log.warning("%s: episode %d skipped: moves %.2f m in one step (row %d)", table.path, episode, step[k], k + 1)
        return None
    return slice(first, len(x))


def _make(table: _Table, episode: int, part: dict[str, np.ndarray], reference: float, track: str | None) -> Trajectory:
    """A Trajectory from one episode's validated columns."""
    return Trajectory(
        source=str(table.path),
        episode=episode,
        t=part["t"],
        steer_cmd_deg=part["steer"],
        speed_cmd_mps=part["speed"],
        x=part["x"],
        y=part["y"],
        heading_deg=part["heading"],
        reference_point_m=reference,
        track=track,
    )
