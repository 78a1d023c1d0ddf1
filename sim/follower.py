"""A classical controller that drives a racing line in the real env: it checks that a computed lap-time limit can
be driven (``racer limit``'s driven lap).

The steering is a small model-predictive controller, because a geometric follower cannot drive a car whose
steering lags: DeepRacer's Gazebo car turns its wheels with a time constant of half a second, and racer's first
follower (pure pursuit with a speed-dependent look-ahead) drove it off reInvent2019_track in its first bends.
Every control period:

1. **Plan** on a kinematic model: the rear axle moves on the curvature that the car's measured trials hold at
   this speed and steering angle (``CarLimits.curvature_by_steering``, understeer included), the wheels follow
   the command with the measured steering time constant, the speeds are the profile's. Every pair of steering
   commands (one for the first third of the horizon, one after it, 13 angles each) is scored by the summed squared
   distance of the car's centre to the line, plus its heading's squared difference from the line's (a lagging car
   that reaches the line pointing across it leaves it again), plus a steep cost for leaving the line's corridor
   (the line may run within a few centimetres of the off-track boundary, so a deviation outwards costs far more
   than one inwards); the horizon is twice the steering time constant plus half a second.
2. **Check** on the simulator itself: the best plan and its neighbours (±2° on either piece; ±3° for a car whose
   steering lags, :data:`LAGGING_CHECK_OFFSETS_DEG`), the previous period's choice one period on, and the wheels
   held where they are, are driven on the env's own physics from a snapshot, with the speed commands the
   controller would give, and scored the same way; the snapshot is restored after each. The kinematic model
   misses what the car does between steady states (sliding, load transfer); the simulator does not.
3. The best checked plan's first command is sent.

The speed command reads the profile (its squared speeds, linear in distance where it accelerates or brakes) one
control period ahead of the car's own distance along the line (:data:`SPEED_LEAD_S`: the command acts over the next
period) and asks for the speed that takes the car's speed servo, a first-order lag of its measured time constant
(``CarLimits.speed_tau_s``), from its speed to that one in that period (:func:`lead_speed`), divided by the car's
speed-per-command ratio (its wheels slip slightly) and clipped to its commands.

How close it drives each car to its limit on DeepRacer's loops: docs/racing.md ("Current figures"). Its lap at
the limit is chaotic: the CPUs' last-digit differences in the line make different laps. Driven at its limit a car
may still leave the track in one bend and not on a second try a little slower there: ``drive_line`` slows the
stretch before the place where a try left the track, or left the line's corridor, and tries again
(:data:`PACE_STEP`), so the rest of the lap keeps the profile's speeds, and reports the fastest lap; a retry replays
the earlier try's commands up to where its slower stretch is first read (:meth:`TryRecord.same_steps`)."""

from __future__ import annotations

import bisect
import json
import math
import tempfile
from dataclasses import KW_ONLY, dataclass, field
from functools import cache
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from common.car_calibration import CarCalibration
from common.config import EnvConfig
from sim.car_limits import CarLimits
from sim.physics import MAX_STEERING_DEG, SPEED_RANGE_MPS, WHEELBASE_M, CarPhysics
from sim.raceline import RacingLine
from sim.world import CONTROL_HZ

PERIOD_S = 1.0 / CONTROL_HZ
SPEED_LEAD_S = PERIOD_S
"""How far ahead (in time at the current speed) the speed command reads the profile, s: one control period, over
which the command acts. One lead for every car, not one fitted per car: a longer lead brings a car whose speed
servo follows quickly to each braking speed early, and into the bends under the profile."""
PLAN_ANGLES = np.linspace(-MAX_STEERING_DEG, MAX_STEERING_DEG, 13)
"""Steering commands the kinematic plan combines, degrees."""
HORIZON_LAG_FACTOR, HORIZON_EXTRA_S = 2.0, 0.5
"""Planning horizon = factor × the steering time constant + extra, s."""
CHECK_OFFSETS_DEG = (-2.0, 0.0, 2.0)
"""Offsets added to each piece of the best plan for the simulator check, degrees."""
LAGGING_CHECK_OFFSETS_DEG = (-3.0, 0.0, 3.0)
"""The offsets for a car whose steering lags more than :data:`LAGGING_TAU_S`. Its kinematic plan is further off
(its wheels reach a command late, and it slides at its limit), and the wider check keeps it on the line; a car
whose wheels follow at once drives worse with it, so it gets :data:`CHECK_OFFSETS_DEG`."""
LAGGING_TAU_S = 0.25
"""Steering time constant above which a car gets :data:`LAGGING_CHECK_OFFSETS_DEG`, s (the default car's is
0.04 s, the ROS2 Gazebo car's 0.16 s, the ROS1 Gazebo car's 0.50 s)."""
CHECK_STEPS = 12
"""Control periods (0.8 s) each checked plan is driven on the simulator."""
DENSE_PER_POINT = 5
"""The line is resampled this many times finer (every 2 cm) for distances."""
HEADING_WEIGHT = 0.6
"""Cost of a squared radian of heading off the line's, in squared metres off the line. Without it the plans only
chase the line's position, which a car whose steering lags half a second reaches too late: it arrives on the line
pointing across it."""
CORRIDOR_WEIGHT = 100.0
"""Cost of a squared metre outside the corridor, relative to a squared metre off the line."""
KD_TREE_MIN_POINTS = 64
"""Above this many points, :meth:`LineFollower._cost` finds their nearest line points with a k-d tree."""
NEAR_WINDOW = np.arange(-5, 40)
"""Line points searched for the nearest one, about the last nearest."""


@dataclass
class LineFollower:
    """Steering and speed commands that follow ``line`` (with its standing-start profile)."""

    line: RacingLine
    limits: CarLimits
    pace: float | np.ndarray = 1.0
    """Fraction of the profile's speeds the follower commands, one for the lap or one per line point (below 1 where
    a try at full pace left the track)."""
    _s: np.ndarray = field(init=False, repr=False)
    _dense: np.ndarray = field(init=False, repr=False)
    _centre: np.ndarray = field(init=False, repr=False)
    _normal: np.ndarray = field(init=False, repr=False)
    _low: np.ndarray = field(init=False, repr=False)
    _high: np.ndarray = field(init=False, repr=False)
    _dense_step: float = field(init=False)
    _kappa: np.ndarray = field(init=False, repr=False)
    _plans: np.ndarray = field(init=False, repr=False)
    _pace: np.ndarray = field(init=False, repr=False)
    _split: int = field(init=False)
    _near: int = field(default=0, init=False)
    _last: np.ndarray | None = field(default=None, init=False, repr=False)
    _read: np.ndarray = field(init=False, repr=False)
    _s_list: list[float] = field(init=False, repr=False)
    _points: list[list[float]] = field(init=False, repr=False)
    _tangent: list[list[float]] = field(init=False, repr=False)
    _half: list[float] = field(init=False, repr=False)
    _offsets: tuple[float, ...] = field(init=False)

    def __post_init__(self) -> None:
        pts = self.line.points
        self._s = np.concatenate([[0.0], np.cumsum(self.line.ds)])
        pace = np.broadcast_to(np.asarray(self.pace, dtype=np.float64), (len(pts),))
        self._pace = np.append(pace, pace[0])  # on self._s: the finish is the start
        self._read = np.zeros(len(self._pace), dtype=bool)
        self._s_list = self._s.tolist()
        unit = np.roll(pts, -1, axis=0) - np.roll(pts, 1, axis=0)
        unit /= np.linalg.norm(unit, axis=1, keepdims=True)
        # plain lists: _along runs some 170 times a control period, where numpy's per-call cost dominates
        self._points, self._tangent = pts.tolist(), unit.tolist()
        self._half = (0.5 * np.maximum(self.line.ds, np.roll(self.line.ds, 1))).tolist()
        lagging = self.limits.steering_tau_s > LAGGING_TAU_S
        self._offsets = LAGGING_CHECK_OFFSETS_DEG if lagging else CHECK_OFFSETS_DEG
        t = np.arange(DENSE_PER_POINT) / DENSE_PER_POINT
        step = np.roll(pts, -1, axis=0) - pts
        self._dense = (pts[:, None, :] + t[None, :, None] * step[:, None, :]).reshape(-1, 2)
        cor = self.line.corridor
        self._centre = np.repeat(cor.center, DENSE_PER_POINT, axis=0)
        self._normal = np.repeat(cor.normal, DENSE_PER_POINT, axis=0)
        self._low, self._high = np.repeat(cor.low, DENSE_PER_POINT), np.repeat(cor.high, DENSE_PER_POINT)
        self._dense_step = float(np.mean(self.line.ds)) / DENSE_PER_POINT
        tangent = np.roll(self._dense, -1, axis=0) - self._dense
        self._heading = np.arctan2(tangent[:, 1], tangent[:, 0])
        self._kappa = _curvature_grid(self.limits)
        horizon = math.ceil((HORIZON_LAG_FACTOR * self.limits.steering_tau_s + HORIZON_EXTRA_S) / PERIOD_S)
        self._split = max(horizon // 3, 1)
        first, then = np.meshgrid(PLAN_ANGLES, PLAN_ANGLES, indexing="ij")
        self._plans = np.concatenate(
            [np.repeat(first.reshape(-1, 1), self._split, 1), np.repeat(then.reshape(-1, 1), horizon - self._split, 1)],
            axis=1,
        )

    def command(self, physics: CarPhysics, lap_s: float) -> tuple[float, float]:
        """(steering_deg, speed_mps) for the car in ``physics``; ``lap_s`` is the distance driven so far this lap,
        used to read the standing-start profile (the first lap's, then the flying one's)."""
        pose = physics.pose
        self._near = self._nearest(np.array([pose.x, pose.y]), self._near)
        first_lap = lap_s < 0.5 * self._s[-1] or self._s[self._near] > 0.5 * self._s[-1]
        profile = self.line.speed if first_lap else np.append(self.line.flying_speed, self.line.flying_speed[0])
        plan = self._plan(physics, profile)
        along = self._along((pose.x, pose.y), self._near)
        return self._check(physics, plan, profile), self._speed_command(along, physics.speed, profile)

    def _paced(self, s: float | np.ndarray, profile: np.ndarray) -> np.ndarray:
        """The paced profile at distances ``s`` (in [0, lap length)), noting which line points it read."""
        last = len(self._s) - 1
        if np.ndim(s) == 0:  # the speed command's one distance, some 170 times a control period: no array work
            at = bisect.bisect_left(self._s_list, s)
            self._read[min(at, last)] = self._read[min(max(at - 1, 0), last)] = True
        else:
            at = np.searchsorted(self._s, s)
            self._read[np.minimum(at, last)] = True
            self._read[np.minimum(np.maximum(at - 1, 0), last)] = True
        # v² is interpolated, not v: the profile's speeds change at a constant rate between its points where they
        # accelerate or brake, so v² is linear in distance there; v read linearly was half the profile's speed
        # 3 cm from a standing start, and the default car lost 0.13 s of a 5.0 s limit waiting for it.
        return np.sqrt(np.interp(s, self._s, (profile * self._pace) ** 2))

    def take_reads(self) -> np.ndarray:
        """Indices of the points of the pace (on the line's points and the finish) read since the last call."""
        read = np.flatnonzero(self._read)
        self._read[:] = False
        return read

    @property
    def state(self) -> tuple[int, np.ndarray | None]:
        """What the next command depends on besides the car and the pace: the nearest line point, the last plan."""
        return self._near, self._last

    @state.setter
    def state(self, value: tuple[int, np.ndarray | None]) -> None:
        self._near, self._last = value

    def _nearest(self, point: np.ndarray, near: int) -> int:
        """Index of the line point nearest ``point``, searched a short way about ``near``."""
        window = (near + NEAR_WINDOW) % len(self.line.points)
        step = self.line.points[window] - point
        # np.linalg.norm's own sum for a real array, without its checks (a third of this method's time)
        return int(window[int(np.argmin(np.sqrt(np.add.reduce(step * step, axis=1))))])

    def _along(self, point: tuple[float, float], near: int) -> float:
        """Distance along the line of ``point``'s projection, the line point ``near`` being the nearest: the
        point's distance, not the nearest point's, which is up to half a point spacing (5 cm) behind or ahead."""
        offset = (point[0] - self._points[near][0]) * self._tangent[near][0]
        offset += (point[1] - self._points[near][1]) * self._tangent[near][1]
        return self._s_list[near] + min(max(offset, -self._half[near]), self._half[near])

    def _speed_command(self, along: float, speed: float, profile: np.ndarray) -> float:
        ahead = along + max(speed, 0.5) * SPEED_LEAD_S
        target = float(self._paced(ahead % self._s[-1], profile))
        command = lead_speed(speed, target, self.limits.speed_tau_s, SPEED_LEAD_S) / self.limits.speed_per_command
        # min/max, not np.clip: this runs some 170 times a control period, and np.clip on a float costs microseconds
        return min(max(command, SPEED_RANGE_MPS[0]), self.limits.max_command_speed)

    def _plan(self, physics: CarPhysics, profile: np.ndarray) -> np.ndarray:
        """The kinematic plan (horizon,) of steering commands with the least distance to the line."""
        pose, plans = physics.pose, self._plans
        n, horizon = plans.shape
        v_now = max(physics.speed, 0.3)
        s_ahead = self._s[self._near] + v_now * PERIOD_S * np.arange(1, horizon + 1)
        speeds = 0.5 * (v_now + np.maximum(self._paced(s_ahead % self._s[-1], profile), 0.3))
        lag = math.exp(-PERIOD_S / max(self.limits.steering_tau_s, 1e-3))
        steer = np.full(n, physics.steering_deg)
        yaw = np.full(n, pose.yaw)
        rear = np.tile(pose.ahead(-WHEELBASE_M / 2), (n, 1))
        centres, yaws = np.empty((n, horizon, 2)), np.empty((n, horizon))
        for k in range(horizon):
            steer = plans[:, k] + (steer - plans[:, k]) * lag
            turn = speeds[k] * self._curvature(speeds[k], steer) * PERIOD_S
            mid = yaw + turn / 2
            rear = rear + speeds[k] * PERIOD_S * np.column_stack([np.cos(mid), np.sin(mid)])
            yaw = yaw + turn
            centres[:, k] = rear + WHEELBASE_M / 2 * np.column_stack([np.cos(yaw), np.sin(yaw)])
            yaws[:, k] = yaw
        reach = int((s_ahead[-1] - self._s[self._near]) / self._dense_step) + 60
        cost = self._cost(centres.reshape(-1, 2), self._near, reach, yaws.reshape(-1)).reshape(n, horizon).sum(axis=1)
        return plans[int(np.argmin(cost))]

    def _cost(self, points: np.ndarray, near: int, ahead: int, yaw: np.ndarray | None = None) -> np.ndarray:
        """Each point's squared distance to the line plus the corridor's cost (plus the heading's, given the car's
        ``yaw`` at each point), the line searched from a little behind line point ``near``."""
        window = (near * DENSE_PER_POINT + _window(ahead)) % len(self._dense)
        if len(points) > KD_TREE_MIN_POINTS:
            # A plan's thousands of points against hundreds of line points: a k-d tree finds the same nearest
            # points as the all-pairs distances, whose (points, window) array was 40 % of racer limit's drive.
            j = window[cKDTree(self._dense[window]).query(points)[1]]
            nearest_d2 = ((points - self._dense[j]) ** 2).sum(axis=-1)
        else:
            d2 = ((points[:, None, :] - self._dense[window][None, :, :]) ** 2).sum(axis=-1)
            closest = np.argmin(d2, axis=1)
            j, nearest_d2 = window[closest], d2[np.arange(len(points)), closest]
        lateral = np.einsum("ij,ij->i", points - self._centre[j], self._normal[j])
        outside = np.maximum(lateral - self._high[j], 0.0) + np.maximum(self._low[j] - lateral, 0.0)
        cost = nearest_d2 + CORRIDOR_WEIGHT * outside**2
        if yaw is not None:
            cost = cost + HEADING_WEIGHT * (np.angle(np.exp(1j * (yaw - self._heading[j])))) ** 2
        return cost

    def _curvature(self, speed: float, steer_deg: np.ndarray) -> np.ndarray:
        """Signed curvature the car holds at ``speed`` with its wheels at ``steer_deg`` (the measured trials,
        interpolated bilinearly; the tightest curve held so far beyond the last held trial)."""
        speeds = self.limits.speeds
        f = float(np.interp(speed, speeds, np.arange(len(speeds))))
        i = min(int(f), len(speeds) - 2)
        frac = f - i
        row = (1 - frac) * self._kappa[i] + frac * self._kappa[i + 1]
        grid = np.linspace(0.0, MAX_STEERING_DEG, len(row))
        return np.sign(steer_deg) * np.interp(np.abs(steer_deg), grid, row)

    def _check(self, physics: CarPhysics, plan: np.ndarray, profile: np.ndarray) -> float:
        """The first steering command of the best of the plan's neighbours, the previous period's choice and the
        wheels held, driven on the simulator."""
        trials = self._trials(physics, plan)
        # The trials most likely to win are driven first (the last choice, then the plan itself), so that the
        # others can stop as soon as their summed cost passes the best one's: the cost only grows along a drive,
        # so the winner is the one a full drive of every trial finds, at about half the simulator steps.
        order = [*range(len(self._offsets) ** 2, len(trials)), len(self._offsets) ** 2 // 2]
        order += [i for i in range(len(trials)) if i not in order]
        saved = physics.snapshot()
        best, best_cost = order[0], math.inf
        for i in order:
            cost = self._drive_ahead(physics, trials[i], profile, best_cost)
            if cost < best_cost or (cost == best_cost and i < best):
                best, best_cost = i, cost
            physics.restore(saved)
        self._last = trials[best]
        return float(trials[best][0])

    def _trials(self, physics: CarPhysics, plan: np.ndarray) -> list[np.ndarray]:
        """The steering sequences :meth:`_check` drives: the plan's neighbours (the plan itself in the middle), then
        the last period's choice one period on and the wheels held, once there is a last choice."""
        steps = min(CHECK_STEPS, len(plan))
        trials = [
            np.clip(
                plan[:steps] + np.where(np.arange(steps) < self._split, first, then),
                -MAX_STEERING_DEG,
                MAX_STEERING_DEG,
            )
            for first in self._offsets
            for then in self._offsets
        ]
        if self._last is not None:
            # Where the kinematic model is wrong (the Gazebo car at its grip limit turns less than its steady-state
            # trials did) all nine neighbours may unwind the wheels in a bend; the last period's choice, one period
            # on, and the wheels held where they are, keep a plan that the simulator showed to work.
            trials.append(np.append(self._last[1:], self._last[-1]))
            trials.append(np.full(steps, physics.steering_deg))
        return trials

    def _drive_ahead(
        self, physics: CarPhysics, steering: np.ndarray, profile: np.ndarray, bound: float = math.inf
    ) -> float:
        """The plan's cost (``_cost`` summed) over a drive of these steering commands on ``physics``; ``inf`` as
        soon as the sum passes ``bound``."""
        near, cost = self._near, 0.0
        pose = physics.pose
        along = self._along((pose.x, pose.y), near)
        for steer in steering:
            if cost > bound:
                return math.inf
            physics.command(float(steer), self._speed_command(along, physics.speed, profile))
            physics.step()
            pose = physics.pose
            here = np.array([pose.x, pose.y])
            near = self._nearest(here, near)
            along = self._along((pose.x, pose.y), near)
            cost += float(self._cost(here[None, :], near, 10 * DENSE_PER_POINT, np.array([pose.yaw]))[0])
        return cost


def lead_speed(speed: float, target: float, tau_s: float, lead_s: float) -> float:
    """The speed to command (m/s, before the car's speed-per-command ratio) so that a speed servo that follows its
    command as a first-order lag of time constant ``tau_s`` goes from ``speed`` to ``target`` in ``lead_s``:
    ``speed + (target - speed) / (1 - exp(-lead_s / tau_s))`` (``target`` itself for a servo without lag).

    Why not the profile's own speed: a lagging servo asked for it falls behind the profile, and switching between
    full command and brake near the profile keeps it braking for a time constant after each switch. A large gap
    still saturates at full command or brake, the rates the profile was built on; where the profile accelerates at
    the car's full-command rate out of a bend, this asks for less than full command, so a lagging car falls a
    little behind the profile there."""
    if tau_s <= 0.0:
        return target
    return speed + (target - speed) / (1.0 - math.exp(-lead_s / tau_s))


@cache
def _window(ahead: int) -> np.ndarray:
    """Offsets of the dense line points :meth:`LineFollower._cost` searches, from a little behind to ``ahead``
    (made once per length: the check asks for the same one some 170 times a control period)."""
    window = np.arange(-5 * DENSE_PER_POINT, ahead)
    window.flags.writeable = False
    return window


def _curvature_grid(limits: CarLimits, points: int = 121) -> np.ndarray:
    """(speeds, points) curvature held at each measured speed for steering 0…30°: the measured trials made
    non-decreasing in the angle (a trial in which the car slid counts as the tightest curve held before it)."""
    grid = np.linspace(0.0, MAX_STEERING_DEG, points)
    rows = []
    for row in limits.curvature_by_steering:
        held = np.maximum.accumulate(np.concatenate([[0.0], row]))
        rows.append(np.interp(grid, np.concatenate([[0.0], limits.steering]), held))
    return np.array(rows)


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
    _: KW_ONLY
    pace: float = 1.0
    """The lowest fraction of the profile's speeds commanded anywhere on the lap (1: the profile throughout)."""
    slowed_m: float = 0.0
    """Length of line driven below the profile's speeds, m."""
    tries: int = 1
    """Laps driven in all: the first, and one more each time a try left the track or the line's corridor (this lap
    is the fastest completed one)."""


PACE_STEP = 0.96
"""After a try leaves the track, the speeds of the stretch before that place are multiplied by this and the lap is
driven again. The car of the limit is driven at its limit, where a car whose steering lags half a second
(DeepRacer's Gazebo car) may leave the track in one bend and not at a slightly lower speed there; slowing only
that bend, rather than the whole lap, keeps the driven lap a fair test of the profile everywhere else."""
SLOW_BEFORE_M, SLOW_AFTER_M = 4.0, 0.5
"""The stretch slowed: this far before the place the car left the track, and this far after it, m."""
MAX_TRIES = 10
"""Laps tried before the last one's result is reported as it is."""


def drive_line(
    track: str, line: RacingLine, limits: CarLimits, car: CarCalibration | None = None, max_seconds: float = 120.0
) -> DrivenLap:
    """Drive ``line`` round ``track`` from DeepRacer's start (waypoint 0, at rest) in the real env; where a try
    leaves the track, slow the stretch before that place by :data:`PACE_STEP` and try again, up to
    :data:`MAX_TRIES` laps (the last try's lap if none completes); where a completed lap left the line's corridor,
    the same, up to :data:`CORRIDOR_TRIES` times. The fastest completed lap is reported."""
    env = follower_env(track, limits, car, max_seconds)
    try:
        pace = np.ones(len(line.points))
        tries, record, best, corrections = 0, None, None, 0
        while True:
            tries += 1
            lap, record = _drive(env, LineFollower(line, limits, pace.copy()), record)
            if lap.status == "lap_complete":
                if best is None or lap.lap_time < best[0].lap_time:
                    best = (lap, pace.copy())
                place = _outside_corridor(line, np.array(record.centres))
                if place is None or corrections == CORRIDOR_TRIES or tries == MAX_TRIES:
                    break
                corrections += 1
            elif not len(lap.path) or tries == MAX_TRIES:
                break
            else:
                place = lap.path[-1]
            pace[_stretch_before(line, place)] *= PACE_STEP
        if best is not None:
            lap, pace = best
        slowed = float(line.ds[pace < 1.0].sum())
        return DrivenLap(
            lap.status, lap.lap_time, lap.progress, lap.path, pace=float(pace.min()), slowed_m=slowed, tries=tries
        )
    finally:
        env.close()


def follower_env(track: str, limits: CarLimits, car: CarCalibration | None = None, max_seconds: float = 120.0):  # noqa: ANN201 - a RacerEnv (imported lazily)
    """A ``RacerEnv`` on ``track`` for the follower: DeepRacer's start at rest, no randomization, and a continuous
    action space up to the car's highest command (the controller needs in-between values)."""
    from sim.env import RacerEnv

    with tempfile.TemporaryDirectory(prefix="racer-limit-") as tmp:
        meta = Path(tmp) / "model_metadata.json"
        space = {
            "steering_angle": {"low": -MAX_STEERING_DEG, "high": MAX_STEERING_DEG},
            "speed": {"low": SPEED_RANGE_MPS[0], "high": limits.max_command_speed},
        }
        meta.write_text(json.dumps({"action_space": space, "action_space_type": "continuous"}))
        config = EnvConfig(
            track=track,
            action_space=str(meta),
            car=car or CarCalibration(),
            randomization={"random_start": False},
            time_limit_steps=int(max_seconds * CONTROL_HZ),
        )
        return RacerEnv(config=config)


@dataclass
class TryRecord:
    """One try's commands, with what each depended on, so that the next try can replay the part of the lap that
    its slower pace does not change instead of planning it again."""

    pace: np.ndarray
    """The try's pace on the line's points and the finish."""
    actions: list[np.ndarray] = field(default_factory=list)
    """The action sent at each step."""
    states: list[tuple[int, np.ndarray | None]] = field(default_factory=list)
    """The follower's :attr:`LineFollower.state` after each command."""
    reads: list[np.ndarray] = field(default_factory=list)
    """The pace points each command read."""
    centres: list[tuple[float, float]] = field(default_factory=list)
    """The car's centre (base_link) after each step, m."""

    def same_steps(self, pace: np.ndarray) -> int:
        """How many of this try's first steps a try at ``pace`` would command the same: those before the first one
        that read a point whose pace differs (the env, the car and the follower are deterministic from reset)."""
        changed = self.pace != pace
        for step, read in enumerate(self.reads):
            if changed[read].any():
                return step
        return len(self.reads)


def _drive(env, follower: LineFollower, replay: TryRecord | None = None) -> tuple[DrivenLap, TryRecord]:  # noqa: ANN001 - a RacerEnv (imported lazily above)
    """One lap (or until the env ends the episode) driven by ``follower``, replaying the steps of ``replay`` (an
    earlier try on the same env) that this follower's pace would command the same: at the limit the Gazebo car
    left AWS_track three times at 58 % of the lap, and each retry planned that 58 % again."""
    _, info = env.reset(seed=0, options={"start_index": 0, "reverse": False})
    record = TryRecord(follower._pace.copy())
    same = 0 if replay is None else replay.same_steps(record.pace)
    path, travelled, last = [], 0.0, None
    done = False
    while not done:
        pose = info["pose"]
        here = np.array([pose.x, pose.y])
        travelled += 0.0 if last is None else float(np.linalg.norm(here - last))
        last = here
        step = len(record.actions)
        if step < same:
            action, state, read = replay.actions[step], replay.states[step], replay.reads[step]
            follower.state = state
        else:
            steer, speed = follower.command(env.physics, travelled)
            action, state, read = np.array([steer, speed], dtype=np.float32), follower.state, follower.take_reads()
        record.actions.append(action)
        record.states.append(state)
        record.reads.append(read)
        _, _, terminated, truncated, info = env.step(action)
        record.centres.append((info["pose"].x, info["pose"].y))
        p = info["params"]
        path.append((p["x"], p["y"]))
        done = terminated or truncated
    p, status = info["params"], info["episode_status"]
    lap = float(p["sim_time"]) if status == "lap_complete" else None
    return DrivenLap(str(status), lap, float(p["progress"]), np.array(path)), record


CORRIDOR_TRIES = 3
"""Laps tried again after a completed lap whose car left the line's corridor. The limit is the time of a line
inside that corridor; a car that left it did not drive that line, most often because it came into a bend too fast
to turn on it: slowing the stretch before that place may give a faster lap, and never a slower one, since the
fastest lap is kept."""


def _outside_corridor(line: RacingLine, centres: np.ndarray) -> np.ndarray | None:
    """The first of the car's centres ((K, 2), m) outside the line's corridor, if any."""
    cor = line.corridor
    j = cKDTree(cor.center).query(centres)[1]
    lateral = np.einsum("ij,ij->i", centres - cor.center[j], cor.normal[j])
    outside = np.flatnonzero((lateral > cor.high[j]) | (lateral < cor.low[j]))
    return centres[outside[0]] if len(outside) else None


def _stretch_before(line: RacingLine, where: np.ndarray) -> np.ndarray:
    """(N,) mask of the line's points from :data:`SLOW_BEFORE_M` before the point nearest ``where`` (the place a
    try ended) to :data:`SLOW_AFTER_M` after it, round the loop."""
    s = np.concatenate([[0.0], np.cumsum(line.ds)[:-1]])
    here = s[int(np.argmin(np.linalg.norm(line.points - where, axis=1)))]
    before = (here - s) % line.length
    return (before <= SLOW_BEFORE_M) | (before >= line.length - SLOW_AFTER_M)
