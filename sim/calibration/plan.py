"""What to drive so that ``racer calibrate`` can identify each effect, and whether given logs did.

:data:`MANOEUVRES` is the system-identification plan, in the spirit of the F1TENTH community's checklists:
each manoeuvre excites some effects and holds the others still, so that the fit can tell them apart.
:func:`plan_text` prints it for a user (``racer calibrate --plan``).

:func:`identifiability` measures, from the logged commands and the measured speeds, whether the logs hold
the excitation each candidate effect needs (sustained turns at several speeds, steering steps, ...), and names
the manoeuvre to drive where they do not. :func:`pairs_confounded` lists the effect pairs the logs cannot tell
apart (e.g. steering gain and understeer from circles at one speed only), for the report's ``ambiguous_with``.

The measures work on "holds": runs of consecutive rows with one command (within :data:`STEER_TOL_DEG` and
:data:`SPEED_TOL_MPS`). Row k's command drives the car from sample k to k+1, so a hold of rows
``start .. stop-1`` shows in the samples ``start .. stop`` (the last row's command never shows).
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass

import numpy as np

from common.car_calibration import CANDIDATE_EFFECTS
from sim.calibration.logs import PLAIN_COLUMNS, Trajectory
from sim.calibration.values import DEFAULT_STEPS
from sim.physics import WHEELBASE_M

# ------------------------------------------------------------------------------------------------ thresholds

STEER_TOL_DEG = 0.5
"""Steering commands this close count as one command: continuous-action policies jitter by less than this,
which changes the turn radius by a few per cent at most."""
SPEED_TOL_MPS = 0.05
"""Speed commands this close count as one command (a few per cent of a typical 1-2 m/s)."""
MIN_MOVING_MPS = 0.3
"""A hold counts only when the car moves at least this fast: slower, the heading hardly changes over a hold and
the per-row speed from positions is mostly noise."""
HOLD_S = 0.7
"""A steady hold lasts at least this long: a ~0.1 s dead time plus three time constants of a ~0.15 s lag, so
the second half of the hold (where its speed is measured) is settled."""
MIN_CONDITION_ROWS = 30
"""Rows each condition needs (a speed level of circles or straight runs, a side, full lock, high grip): 2 s at
15 Hz, so averaging cuts the ±30 % per-row speed noise of DeepRacer's ±20 ms time-stamp jitter to ~5 %."""
MIN_TURN_DEG = 5.0
"""Steering of at least this counts as turning: curvature ≥ tan(5°)/0.164 m ≈ 0.5 /m, a yaw rate well above
the heading noise at the speeds of the plan."""
STRAIGHT_MAX_DEG = 2.0
"""Steering of at most this counts as straight running: at 2 m/s it asks for < 1 m/s² of lateral
acceleration, so neither tyre slip nor understeer changes the speed or the path noticeably."""
SPEED_SEPARATION_MPS = 0.5
"""Two speed levels this far apart tell a gain from a speed-dependent effect: understeer's v² changes by at
least a quarter across 0.5 m/s at any DeepRacer speed (≤ 4 m/s), and more than doubles from 1 to 1.5 m/s."""
LEVEL_WIDTH_MPS = 0.25
"""Holds whose settled speeds lie within this of a level's slowest hold form one speed level: half the plan's
0.5 m/s spacing, and well above the few per cent by which the settled speed of one command varies."""
MIRROR_TOL_DEG = 2.0
"""A left and a right turn whose |commands| differ by at most this mirror each other: their turn rates then
differ by the offset's share far more than by the gain's (a few per cent of the angle)."""
SATURATION_PROBE_DEG = 20.0
"""Commands at least this large probe the steering limit: DeepRacer cars' effective lock is typically
20-30° although 30° is commanded."""
MIN_STEER_STEP_DEG = 10.0
"""A steering step changes the command by at least this: at 1 m/s the yaw rate then changes by ≥ 1 rad/s,
so its onset (dead time) and rise (lag) stand out of the noise."""
LARGE_STEER_STEP_DEG = 30.0
"""A steering step this large shows a servo's slew rate: at a hobby servo's 0.15 s/60° it takes 75 ms, over a
15 Hz row, and a slew's rise time grows with the step where a lag's does not: steps of both sizes (this and
under it) tell the two apart."""
LARGE_SPEED_STEP_MPS = 1.5
"""A speed step this large shows a drive's acceleration limit the way a large steering step shows a slew rate:
at 5 m/s² it takes 0.3 s, and a lag's rise time does not grow with the step."""
MIN_SPEED_STEP_MPS = 0.5
"""A speed step changes the command by at least this: a third of a typical 1.5 m/s, comparable with the
per-row speed noise (±30 %), which :data:`MIN_STEPS` steps average out."""
STEP_HOLD_S = 0.5
"""After a step the new command is held this long: a 0.1 s dead time plus over two time constants of a
0.15 s lag, so the whole response is seen before the next change."""
MIN_STEPS = 10
"""Clean steps needed to tell a dead time from a lag: each is seen at a random phase of the ±20 ms time-stamp
jitter, and about ten average it below the ~0.03 s these effects differ by."""
MAX_ROW_PERIOD_S = 0.1
"""Rows further apart than this (slower than 10 Hz) hide a typical 0.05-0.1 s dead time inside one row,
where it looks the same as a lag: delay and lag are then confounded whatever the steps."""
HIGH_LATERAL_MPS2 = 3.0
"""Commanded lateral acceleration (v²·tan|δ|/L) from which tyre grip shows: ~0.3 g, where a DeepRacer-size
car starts to slide on smooth floors (μ down to the effect's 0.2 bound slides earlier). Below it the car
follows its kinematic path whatever the friction, which is then not seen."""


# ------------------------------------------------------------------------------------------------ the plan


@dataclass(frozen=True)
class Manoeuvre:
    """One system-identification drive: what to do and which effects it identifies."""

    name: str
    drive: str
    """What to drive: commands, durations, repetitions, for a DeepRacer-size car."""
    identifies: tuple[str, ...]
    """The effects (names in ``common.car_calibration.EFFECTS``) that this drive excites."""
    why: str
    """Why the drive identifies them, in one sentence."""


MANOEUVRES: tuple[Manoeuvre, ...] = (
    Manoeuvre(
        "steady circles at several speeds",
        "steer +15° (a circle ~1.2 m across), then +10° (~1.9 m across), each at 0.5, 1.0 and 1.5 m/s: "
        "hold each speed for 3 laps or at least 5 s after 1 s of settling",
        ("steering_gain", "understeer"),
        "the steady radius at a fixed angle gives gain × angle at low speed and how the turn widens with v² "
        "(understeer); circles at one speed give only their product",
    ),
    Manoeuvre(
        "left and right turns",
        "the circles above mirrored: −15° and −10° at 0.5, 1.0 and 1.5 m/s, 3 laps each, plus 5 s of "
        "driving at 0° at 1.0 m/s where the space allows",
        ("steering_offset",),
        "a mis-centred servo makes left and right circles of the same command differ in radius (and makes a "
        "0° command curve), and the mean of the two turn rates gives the offset",
    ),
    Manoeuvre(
        "full-lock circles",
        "steer ±30°, ±25° and ±20° (circles 0.6-0.9 m across) at 0.5 and 1.0 m/s, 3 laps each",
        ("steering_saturation",),
        "beyond the steering limit the circle stops shrinking as the command grows, and comparing 20°, 25° "
        "and 30° shows where",
    ),
    Manoeuvre(
        "steering steps",
        "at 1.0 m/s, switch the steering between +10° and +25° every 1.0 s (steps of 15°; the car stays within "
        "~2 m), 20 steps, then between −10° and −25°, 20 steps, then between −20° and +20° (steps of 40°), 20 "
        "steps; on a track, 0° ↔ ±15° and ±20° ↔ ∓20° every 1.0 s on the straights do as well",
        ("steering_delay", "steering_lag", "steering_rate"),
        "after a step the turn rate starts changing only after the dead time and then approaches its new value "
        "with the lag's time constant, so many clean steps, each held until settled, separate the two; a "
        "servo's slew limit makes large steps take longer than small ones, which a lag does not",
    ),
    Manoeuvre(
        "straight runs at several speeds",
        "steer 0° at 0.5, 1.0, 1.5 and 2.0 m/s, each held at least 3 s after 1 s of accelerating (2-7 m of "
        "straight: a track straight or a corridor), 3 runs each",
        ("speed_gain", "steering_offset"),
        "the steady speed over the commanded speed is the speed gain, several speeds show it is a gain and "
        "not a drive limit, and any curve at 0° is the steering offset",
    ),
    Manoeuvre(
        "speed steps",
        "on a straight, or steering +10° (a circle ~1.9 m across) in a small space, switch the speed between 0.5 "
        "and 1.5 m/s every 1.5 s, at least 20 steps, then between 0.5 and 2.5 m/s (on a straight of ≥ 6 m), "
        "at least 20 steps",
        ("speed_delay", "speed_lag", "speed_rate"),
        "the measured speed starts changing after the dead time and then approaches the new speed with the "
        "lag's time constant, and many steps average out the noisy per-row speed; a drive's acceleration "
        "limit makes large steps take longer than small ones, which a lag does not",
    ),
    Manoeuvre(
        "high-speed circles",
        "steer ±20° at 1.5, 2.0 and 2.5 m/s (commanded lateral acceleration v²·tan δ / 0.164 m of 5-14 m/s²), "
        "3 laps each or until the car slides wide; needs ~4 m of space or a track's wide bend",
        ("tyre_friction",),
        "near the grip limit the car slides wide of its kinematic circle by an amount the friction "
        "coefficient sets, while below it friction does not show at all",
    ),
)
"""The drives that make every candidate effect identifiable, in the order to drive them."""

_WIDTH = 104
"""Width the plan's text is wrapped to (a terminal of 110 columns)."""
_COLUMN_DOCS = {
    "time_s": "sample time, s, strictly increasing within an episode",
    "steer_cmd_deg": "commanded steering angle, degrees, + = left",
    "speed_cmd_mps": "commanded speed, m/s",
    "x_m": "measured position, m, in a fixed right-handed frame",
    "y_m": "(+y is 90° left of +x)",
    "heading_deg": "measured heading, degrees in [-180, 180], counter-clockwise from +x",
}


def plan_text() -> str:
    """The plan for a user: what to drive, which effects each drive identifies, and what to log."""
    lines = [
        "Calibration drives: what to log so that `racer calibrate` can identify each effect of your car.",
        "",
        "Drive each manoeuvre as its own episode, starting from rest, on a flat floor about 3 m across (or a",
        "track). Commands are what you send the car; hold each one as stated, since the fit needs the car's",
        "settled response as well as its response to changes. `racer calibrate LOGS` reports which effects",
        "the logs could identify and names the manoeuvre that is missing.",
        "",
    ]
    for i, m in enumerate(MANOEUVRES, 1):
        lines.append(f"{i}. {m.name} (identifies {', '.join(m.identifies)})")
        for label, text in (("drive", m.drive), ("why", m.why)):
            lines += textwrap.wrap(f"{label}: {text}.", _WIDTH, initial_indent="   ", subsequent_indent="   ")
    width = max(map(len, PLAIN_COLUMNS))
    lines += [
        "",
        "Log one row per control step (10 Hz or faster; DeepRacer runs at 15 Hz) as plain CSV with the header",
        f"  {','.join(PLAIN_COLUMNS)}[,episode]",
        *(f"  {c:<{width}}  {_COLUMN_DOCS[c]}" for c in PLAIN_COLUMNS),
        f"  {'episode':<{width}}  optional integer; rows of one episode are consecutive",
        "Row k's commands are the ones sent at sample k (they drive the car until sample k+1). The position is",
        "the rear-axle midpoint unless a line '# reference_point_m: 0.14' gives the measured point's distance",
        "ahead of it; '# track: <name>' names the track.",
    ]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------------ the measures


@dataclass(frozen=True)
class _Hold:
    """A run of rows with one command: its steering, its settled speed (m/s) and its number of rows."""

    steer_deg: float
    speed_mps: float
    rows: int


@dataclass
class _Excitation:
    """What the logs hold, in the terms the effects need."""

    holds: list[_Hold]
    steering_steps: int
    large_steering_steps: int
    speed_steps: int
    large_speed_steps: int
    high_lateral_rows: int
    max_lateral_mps2: float
    row_period_s: float


def _runs(arrays: list[tuple[np.ndarray, float]]) -> list[tuple[int, int]]:
    """(start, stop) of each run of rows where every array stays within its tolerance of the run's first value."""
    lists = [(a.tolist(), tol) for a, tol in arrays]  # Python floats: a per-row loop over numpy is slow
    n = len(lists[0][0])
    runs, start = [], 0
    for k in range(1, n):
        if any(abs(a[k] - a[start]) > tol for a, tol in lists):
            runs.append((start, k))
            start = k
    runs.append((start, n))
    return runs


def _shown_s(tr: Trajectory, start: int, stop: int) -> float:
    """How long rows start..stop-1 drive the car in the samples (the last row's command never shows)."""
    return float(tr.t[min(stop, len(tr) - 1)] - tr.t[start])


def _settled_speed(tr: Trajectory, start: int, stop: int) -> float:
    """Median measured speed over the second half of a hold, after the response to its start has settled."""
    end = min(stop, len(tr) - 1)
    return float(np.median(tr.speed_measured_mps[(start + end) // 2 : end + 1]))


def _holds(tr: Trajectory) -> list[_Hold]:
    """The steady holds of one trajectory: one command for at least :data:`HOLD_S` with the car moving."""
    out = []
    for start, stop in _runs([(tr.steer_cmd_deg, STEER_TOL_DEG), (tr.speed_cmd_mps, SPEED_TOL_MPS)]):
        if _shown_s(tr, start, stop) >= HOLD_S:
            speed = _settled_speed(tr, start, stop)
            if speed >= MIN_MOVING_MPS:
                out.append(_Hold(float(np.mean(tr.steer_cmd_deg[start:stop])), speed, stop - start))
    return out


def _step_sizes(tr: Trajectory, command: np.ndarray, tol: float, min_step: float) -> list[float]:
    """Sizes of the clean steps of one command: a change of at least ``min_step`` held :data:`STEP_HOLD_S` with
    the car moving."""
    sizes = []
    for start, stop in _runs([(command, tol)])[1:]:  # the first run has no step into it
        size = abs(float(command[start] - command[start - 1]))
        if (
            size >= min_step
            and _shown_s(tr, start, stop) >= STEP_HOLD_S
            and _settled_speed(tr, start, stop) >= MIN_MOVING_MPS
        ):
            sizes.append(size)
    return sizes


def command_steps(trajectories: list[Trajectory]) -> dict[str, float]:
    """The logs' median change of each command between rows where it changes (``{"steering": degrees, "speed":
    m/s}``, ``sim.calibration.values.DEFAULT_STEPS`` where it never does): the step at which the report's total
    delay counts a rate limit."""
    out = dict(DEFAULT_STEPS)
    for channel, attr, tol in (("steering", "steer_cmd_deg", STEER_TOL_DEG), ("speed", "speed_cmd_mps", SPEED_TOL_MPS)):
        changes = np.concatenate([np.abs(np.diff(getattr(tr, attr))) for tr in trajectories] or [np.zeros(0)])
        changes = changes[changes > tol]
        if changes.size:
            out[channel] = round(float(np.median(changes)), 3)
    return out


def _lateral_mps2(tr: Trajectory) -> np.ndarray:
    """Commanded lateral acceleration v²·tan|δ|/L per shown row, v the smaller of commanded and measured speed
    (the car may not have reached the commanded speed, and the noisy measurement must not inflate it)."""
    v = np.minimum(tr.speed_cmd_mps, tr.speed_measured_mps)[:-1]
    return v**2 * np.tan(np.radians(np.abs(tr.steer_cmd_deg[:-1]))) / WHEELBASE_M


def _excitation(trajectories: list[Trajectory]) -> _Excitation:
    """Measure everything the effects need from the logs' commands and measured speeds."""
    holds, steer_steps, speed_steps, lateral = [], [], [], []
    for tr in trajectories:
        holds += _holds(tr)
        steer_steps += _step_sizes(tr, tr.steer_cmd_deg, STEER_TOL_DEG, MIN_STEER_STEP_DEG)
        speed_steps += _step_sizes(tr, tr.speed_cmd_mps, SPEED_TOL_MPS, MIN_SPEED_STEP_MPS)
        moving = tr.speed_measured_mps[:-1] >= MIN_MOVING_MPS
        lateral.append(_lateral_mps2(tr)[moving])
    lat = np.concatenate(lateral) if lateral else np.zeros(0)
    periods = np.concatenate([np.diff(tr.t) for tr in trajectories]) if trajectories else np.zeros(0)
    return _Excitation(
        holds=holds,
        steering_steps=len(steer_steps),
        large_steering_steps=sum(size >= LARGE_STEER_STEP_DEG for size in steer_steps),
        speed_steps=len(speed_steps),
        large_speed_steps=sum(size >= LARGE_SPEED_STEP_MPS for size in speed_steps),
        high_lateral_rows=int(np.sum(lat >= HIGH_LATERAL_MPS2)),
        max_lateral_mps2=float(lat.max()) if lat.size else 0.0,
        row_period_s=float(np.median(periods)) if periods.size else math.nan,
    )


def _levels(holds: list[_Hold]) -> list[tuple[float, int]]:
    """Speed levels of some holds with enough rows each: (row-weighted mean speed, rows), slowest first.

    Holds are grouped greedily from the slowest: a hold within :data:`LEVEL_WIDTH_MPS` of its group's
    slowest joins it; groups with fewer than :data:`MIN_CONDITION_ROWS` rows are left out."""
    groups: list[list[_Hold]] = []
    for h in sorted(holds, key=lambda h: h.speed_mps):
        if groups and h.speed_mps - groups[-1][0].speed_mps <= LEVEL_WIDTH_MPS:
            groups[-1].append(h)
        else:
            groups.append([h])
    out = []
    for g in groups:
        rows = sum(h.rows for h in g)
        if rows >= MIN_CONDITION_ROWS:
            out.append((sum(h.speed_mps * h.rows for h in g) / rows, rows))
    return out


def _spread_mps(levels: list[tuple[float, int]]) -> float:
    """Speed between the slowest and fastest level (0 with fewer than two)."""
    return levels[-1][0] - levels[0][0] if len(levels) >= 2 else 0.0


def _rows(holds: list[_Hold]) -> int:
    return sum(h.rows for h in holds)


def _turning(ex: _Excitation) -> list[_Hold]:
    return [h for h in ex.holds if abs(h.steer_deg) >= MIN_TURN_DEG]


def _straight(ex: _Excitation) -> list[_Hold]:
    return [h for h in ex.holds if abs(h.steer_deg) <= STRAIGHT_MAX_DEG]


def _below_limit_rows(ex: _Excitation) -> int:
    """Rows of steady turning short of the probed steering limit (where the gain alone acts)."""
    return _rows([h for h in _turning(ex) if abs(h.steer_deg) < SATURATION_PROBE_DEG])


def _mirrored_rows(turning: list[_Hold]) -> int:
    """Rows of steady turns with a mirror (a turn the other way within :data:`MIRROR_TOL_DEG`), the smaller of
    the two sides' totals: only mirrored pairs separate an offset from the gain."""
    left = [h for h in turning if h.steer_deg > 0]
    right = [h for h in turning if h.steer_deg < 0]

    def matched(side: list[_Hold], other: list[_Hold]) -> int:
        return _rows([h for h in side if any(abs(h.steer_deg + o.steer_deg) <= MIRROR_TOL_DEG for o in other)])

    return min(matched(left, right), matched(right, left))


# ------------------------------------------------------------------------------------------------ the verdicts

_Verdict = tuple[bool, dict, str]  # identifiable, evidence, what is missing


def _levels_evidence(prefix: str, holds: list[_Hold]) -> dict:
    levels = _levels(holds)
    return {
        f"{prefix}_rows": _rows(holds),
        "speed_levels_mps": [round(s, 2) for s, _ in levels],
        "speed_level_rows": [r for _, r in levels],
        "speed_spread_mps": round(_spread_mps(levels), 2),
    }


def _steering_offset(ex: _Excitation) -> _Verdict:
    turning = _turning(ex)
    ev = {
        "left_rows": _rows([h for h in turning if h.steer_deg > 0]),
        "right_rows": _rows([h for h in turning if h.steer_deg < 0]),
        "mirrored_rows": _mirrored_rows(turning),
        "straight_rows": _rows(_straight(ex)),
    }
    ok = max(ev["mirrored_rows"], ev["straight_rows"]) >= MIN_CONDITION_ROWS
    need = (
        f"left and right steady turns of the same command (or straight running at |steer| ≤ {STRAIGHT_MAX_DEG:g}°), "
        f"≥ {MIN_CONDITION_ROWS} rows"
    )
    return ok, ev, need


def _steering_gain(ex: _Excitation) -> _Verdict:
    rows = _rows(_turning(ex))
    need = f"steady turning (|steer| ≥ {MIN_TURN_DEG:g}° held ≥ {HOLD_S:g} s), ≥ {MIN_CONDITION_ROWS} rows"
    return rows >= MIN_CONDITION_ROWS, {"steady_turn_rows": rows}, need


def _understeer(ex: _Excitation) -> _Verdict:
    ev = _levels_evidence("steady_turn", _turning(ex))
    need = (
        f"steady turning (|steer| ≥ {MIN_TURN_DEG:g}° held ≥ {HOLD_S:g} s) at ≥ 2 speeds "
        f"≥ {SPEED_SEPARATION_MPS:g} m/s apart, ≥ {MIN_CONDITION_ROWS} rows each"
    )
    return ev["speed_spread_mps"] >= SPEED_SEPARATION_MPS, ev, need


def _steering_saturation(ex: _Excitation) -> _Verdict:
    beyond = _rows([h for h in _turning(ex) if abs(h.steer_deg) >= SATURATION_PROBE_DEG])
    ev = {"beyond_limit_rows": beyond, "below_limit_rows": _below_limit_rows(ex)}
    need = f"steady turning at |steer| ≥ {SATURATION_PROBE_DEG:g}°, ≥ {MIN_CONDITION_ROWS} rows"
    return beyond >= MIN_CONDITION_ROWS, ev, need


def _period(ex: _Excitation) -> float | None:
    """The median row period for the evidence (None without logs: JSON has no NaN)."""
    return None if math.isnan(ex.row_period_s) else round(ex.row_period_s, 4)


def _steering_steps(ex: _Excitation) -> _Verdict:
    ev = {"steering_steps": ex.steering_steps, "row_period_s": _period(ex)}
    need = f"≥ {MIN_STEPS} steering steps of ≥ {MIN_STEER_STEP_DEG:g}° each held ≥ {STEP_HOLD_S:g} s while moving"
    return ex.steering_steps >= MIN_STEPS, ev, need


def _rate_verdict(channel: str, steps: int, large: int, sizes: tuple[float, float, str]) -> _Verdict:
    """A rate limit shows as large steps taking longer than small ones: both sizes, :data:`MIN_STEPS` each."""
    small_from, large_from, unit = sizes
    ev = {f"large_{channel}_steps": large, f"small_{channel}_steps": steps - large}
    need = (
        f"≥ {MIN_STEPS} {channel} steps of ≥ {large_from:g} {unit} and ≥ {MIN_STEPS} of {small_from:g}-{large_from:g} "
        f"{unit}, each held ≥ {STEP_HOLD_S:g} s while moving"
    )
    return min(steps - large, large) >= MIN_STEPS, ev, need


def _steering_rate(ex: _Excitation) -> _Verdict:
    sizes = (MIN_STEER_STEP_DEG, LARGE_STEER_STEP_DEG, "°")
    return _rate_verdict("steering", ex.steering_steps, ex.large_steering_steps, sizes)


def _speed_rate(ex: _Excitation) -> _Verdict:
    sizes = (MIN_SPEED_STEP_MPS, LARGE_SPEED_STEP_MPS, "m/s")
    return _rate_verdict("speed", ex.speed_steps, ex.large_speed_steps, sizes)


def _speed_gain(ex: _Excitation) -> _Verdict:
    ev = _levels_evidence("straight", _straight(ex))
    need = (
        f"straight running (|steer| ≤ {STRAIGHT_MAX_DEG:g}° held ≥ {HOLD_S:g} s) at ≥ 2 speeds "
        f"≥ {SPEED_SEPARATION_MPS:g} m/s apart, ≥ {MIN_CONDITION_ROWS} rows each"
    )
    return ev["speed_spread_mps"] >= SPEED_SEPARATION_MPS, ev, need


def _speed_steps(ex: _Excitation) -> _Verdict:
    ev = {"speed_steps": ex.speed_steps, "row_period_s": _period(ex)}
    need = f"≥ {MIN_STEPS} speed steps of ≥ {MIN_SPEED_STEP_MPS:g} m/s each held ≥ {STEP_HOLD_S:g} s"
    return ex.speed_steps >= MIN_STEPS, ev, need


def _tyre_friction(ex: _Excitation) -> _Verdict:
    ev = {"high_lateral_rows": ex.high_lateral_rows, "max_lateral_mps2": round(ex.max_lateral_mps2, 2)}
    need = f"commanded lateral acceleration v²·tan|δ|/L ≥ {HIGH_LATERAL_MPS2:g} m/s², ≥ {MIN_CONDITION_ROWS} rows"
    return ex.high_lateral_rows >= MIN_CONDITION_ROWS, ev, need


_CHECKS = {
    "steering_offset": _steering_offset,
    "steering_gain": _steering_gain,
    "steering_saturation": _steering_saturation,
    "steering_delay": _steering_steps,
    "steering_lag": _steering_steps,
    "steering_rate": _steering_rate,
    "speed_gain": _speed_gain,
    "speed_delay": _speed_steps,
    "speed_lag": _speed_steps,
    "speed_rate": _speed_rate,
    "understeer": _understeer,
    "tyre_friction": _tyre_friction,
}


def _drive_for(effect: str) -> str:
    """The first manoeuvre of the plan that identifies an effect."""
    return next(m.name for m in MANOEUVRES if effect in m.identifies)


def identifiability(trajectories: list[Trajectory]) -> list[dict]:
    """For each candidate effect, whether the logs hold the excitation needed to identify it.

    Each entry: ``{"effect", "identifiable", "evidence": {counts}}``, and where not identifiable also
    ``"needs"`` (what is missing) and ``"drive"`` (the name of the manoeuvre in :data:`MANOEUVRES` to drive).
    Measured from the commands and the measured speeds only, so it holds whatever the car's effects are.
    """
    ex = _excitation(trajectories)
    out = []
    for effect in CANDIDATE_EFFECTS:
        ok, evidence, need = _CHECKS[effect](ex)
        entry = {"effect": effect, "identifiable": ok, "evidence": evidence}
        if not ok:
            entry |= {"needs": need, "drive": _drive_for(effect)}
        out.append(entry)
    return out


def pairs_confounded(trajectories: list[Trajectory]) -> list[list[str]]:
    """The effect pairs the logs cannot tell apart (each pair in ``EFFECTS`` order), for ``ambiguous_with``.

    - steering_offset, steering_gain: no mirrored turns nor straight running (one-sided turns mix the two);
    - steering_gain, steering_saturation: no steady turning short of :data:`SATURATION_PROBE_DEG` (a smaller
      turn at large commands is a low gain or a limit);
    - steering_delay, steering_lag and speed_delay, speed_lag: fewer than :data:`MIN_STEPS` clean steps, or rows
      further apart than :data:`MAX_ROW_PERIOD_S`;
    - steering_lag, steering_rate and speed_lag, speed_rate: steps of one size only (:func:`_rate_verdict`), or
      coarse rows as above;
    - steering_gain, understeer: steady turning at one speed only (only the product gain / (1 + k·v²) shows).
    """
    ex = _excitation(trajectories)
    coarse = not ex.row_period_s <= MAX_ROW_PERIOD_S  # NaN (no logs) is coarse too
    pairs = []
    if not _steering_offset(ex)[0]:
        pairs.append(["steering_offset", "steering_gain"])
    if _below_limit_rows(ex) < MIN_CONDITION_ROWS:
        pairs.append(["steering_gain", "steering_saturation"])
    if coarse or ex.steering_steps < MIN_STEPS:
        pairs.append(["steering_delay", "steering_lag"])
    if coarse or not _steering_rate(ex)[0]:
        pairs.append(["steering_lag", "steering_rate"])
    if coarse or ex.speed_steps < MIN_STEPS:
        pairs.append(["speed_delay", "speed_lag"])
    if coarse or not _speed_rate(ex)[0]:
        pairs.append(["speed_lag", "speed_rate"])
    if not _understeer(ex)[0]:
        pairs.append(["steering_gain", "understeer"])
    return pairs
