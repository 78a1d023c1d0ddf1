"""Replay measured commands on the simulator's own MuJoCo car over short windows and measure the residual.

A window starts at sample k of a measured :class:`~sim.calibration.logs.Trajectory`: the car is put at the
measured pose with the measured velocity and yaw rate (central differences of the positions around k), its
steering hinges at the angle the actuation had reached, and is then driven open loop by the logged commands
of samples k … k+H-1 through the calibration's effects (``sim.actuation``). The simulated reference point and
heading at samples k+1 … k+H are compared with the measured ones.

Time: each row is replayed for a whole number of physics substeps (1/120 s). How many is a property of the
log (:func:`detect_timing`, the rule under which the rows' speeds are smoothest): in the ROS1 DeepRacer logs
``tstamp`` jitters by ±20 ms while the distance the car covers per row does not follow it (correlation -0.02
over 4,000 steady rows), so every row is replayed for the median step (1/15 s); in some ROS2 simapp logs the
distance of row k follows ``t[k] - t[k-1]`` (the positions trail the time stamps by a row); a real car's log
with honest time stamps follows its own steps ``t[k+1] - t[k]``.

The residual of a window, per sample i = 1 … H: ``dx``, ``dy`` (m) of the reference point, ``dheading`` (deg,
wrapped) and ``dspeed`` (m/s): the speed of the reference point over :data:`SPEED_ROWS` rows ending at
sample i (path length / duration; H - SPEED_ROWS + 1 values per window), simulated minus measured. Why over
several rows: in DeepRacer's logs each pose is read at a moment that wanders by ~3.3 ms (ROS1; ~8 ms ROS2) from
its row's, a noise along the path that the logged time stamps do not carry; over one row (1/15 s) it is
0.08–0.09 m/s of the speed at DeepRacer's speeds, most of what a one-row speed error measures, and no car
can explain it. Over three rows it is a third of that, while a speed lag of 0.1 s still shows. Many windows run
at once through ``mujoco.rollout`` (C, one thread per core).
"""

from __future__ import annotations

import math
import os
from dataclasses import KW_ONLY, dataclass, replace

import mujoco
import numpy as np
from mujoco import rollout

from common.car_calibration import CarCalibration
from common.errors import OptionError
from sim.actuation import ActuationParams, actuate_sequence
from sim.calibration.logs import LogError, Trajectory
from sim.physics import TRACK_WIDTH_M, WHEEL_RADIUS_M, CarPhysics, Pose, yaw_of_quaternion
from sim.texture import TextureFrame
from sim.world import CONTROL_HZ, PHYSICS_SUBSTEPS, build_model

WINDOW_S = 1.0
"""Length of a replay window, s."""
SPEED_ROWS = 3
"""Rows over which a speed is measured (see the module docstring)."""
SUBSTEP_S = 1.0 / (CONTROL_HZ * PHYSICS_SUBSTEPS)
"""The simulator's physics step, s: rows are replayed for whole numbers of it."""


TIMINGS = ("nominal", "logged", "logged_previous")
"""How long each row is replayed for: the median step of the logs; the row's own logged step t[k+1] - t[k];
or the step logged one row earlier, t[k] - t[k-1] (ROS2 simapp logs, whose positions trail their times)."""


@dataclass(frozen=True)
class Windows:
    """Replay windows cut from measured trajectories; arrays have one row per window."""

    trajectories: list[Trajectory]
    traj: np.ndarray
    """(W,) index into ``trajectories``."""
    start: np.ndarray
    """(W,) sample index k where each window starts."""
    _: KW_ONLY
    horizon: int
    """Samples replayed per window, H."""
    row_substeps: list[np.ndarray]
    """Per trajectory: physics substeps each of its rows is replayed for (one entry per sample)."""
    timing: str = "nominal"
    """Which rule of :data:`TIMINGS` set ``row_substeps``."""

    def __len__(self) -> int:
        return len(self.start)

    def subset(self, mask_or_index: np.ndarray) -> Windows:
        """The windows selected by a boolean mask or an index array."""
        return replace(self, traj=self.traj[mask_or_index], start=self.start[mask_or_index])

    def episode_keys(self) -> np.ndarray:
        """(W,) an integer per distinct (file, episode) of each window: the unit of independence."""
        return self.traj.copy()

    def commands(self) -> tuple[np.ndarray, np.ndarray]:
        """(W, H) commanded steering (deg) and speed (m/s) over each window."""
        steps = self.start[:, None] + np.arange(self.horizon)
        steer = np.stack([self.trajectories[t].steer_cmd_deg[s] for t, s in zip(self.traj, steps, strict=True)])
        speed = np.stack([self.trajectories[t].speed_cmd_mps[s] for t, s in zip(self.traj, steps, strict=True)])
        return steer, speed

    def durations(self) -> np.ndarray:
        """(W, H) replayed duration of each row of each window, s."""
        steps = self.start[:, None] + np.arange(self.horizon)
        return np.stack([self.row_substeps[t][s] for t, s in zip(self.traj, steps, strict=True)]) * SUBSTEP_S

    def measured(self) -> dict[str, np.ndarray]:
        """(W, H+1) measured reference point x, y (m), heading (rad) and (W, H - SPEED_ROWS + 1) speeds (m/s)."""
        steps = self.start[:, None] + np.arange(self.horizon + 1)
        trajs = [self.trajectories[t] for t in self.traj]
        x = np.stack([tr.x[s] for tr, s in zip(trajs, steps, strict=True)])
        y = np.stack([tr.y[s] for tr, s in zip(trajs, steps, strict=True)])
        h = np.stack([np.radians(tr.heading_deg[s]) for tr, s in zip(trajs, steps, strict=True)])
        return {"x": x, "y": y, "heading": h, "speed": path_speed(x, y, self.durations())}


def detect_timing(trajectories: list[Trajectory]) -> str:
    """The rule of :data:`TIMINGS` under which the rows' speeds (distance / duration) are smoothest.

    If the distance covered per row follows a logged time step, dividing by that step removes the jitter;
    if the time stamps jitter on their own, dividing by them adds it. Smoothness: the RMS of each row's speed
    minus the mean of its neighbours'. A property of the log, decided without the car model.
    """
    roughness = {}
    for rule in TIMINGS:
        hp = []
        for tr in trajectories:
            if len(tr) < 4:
                continue
            d, dt = np.hypot(np.diff(tr.x), np.diff(tr.y)), np.diff(tr.t)
            med = np.median(dt)
            dur = {"nominal": np.full_like(dt, med), "logged": dt, "logged_previous": np.r_[med, dt[:-1]]}[rule]
            v = d / dur
            hp.append(v[1:-1] - (v[:-2] + v[2:]) / 2)
        roughness[rule] = float(np.mean(np.square(np.concatenate(hp)))) if hp else 0.0
    return min(TIMINGS, key=lambda r: roughness[r])  # ties go to "nominal", first in TIMINGS


def row_substeps(tr: Trajectory, timing: str, median_substeps: int) -> np.ndarray:
    """Physics substeps for each row of a trajectory under a timing rule (at least 1 each)."""
    dt = np.diff(tr.t)
    if timing == "nominal":
        return np.full(len(tr), median_substeps)
    steps = np.r_[dt, np.median(dt)] if timing == "logged" else np.r_[np.median(dt), dt]
    return np.maximum(1, np.round(steps / SUBSTEP_S)).astype(int)


def make_windows(
    trajectories: list[Trajectory], stride: int | None = None, window_s: float = WINDOW_S, timing: str = "auto"
) -> Windows:
    """Windows of about ``window_s`` starting every ``stride`` samples (default: one window length) from sample 1.

    ``timing`` is one of :data:`TIMINGS`, or "auto" (:func:`detect_timing`). Windows need the samples around
    their start for the initial speed, so they start at sample 1 and end at least one sample before the last.
    """
    if not trajectories:
        raise LogError("no trajectories to make replay windows from")
    if timing == "auto":
        timing = detect_timing(trajectories)
    if timing not in TIMINGS:
        raise OptionError(f"timing {timing!r} is not one of {', '.join(TIMINGS)} or auto")
    median = max(1, round(float(np.median(np.concatenate([np.diff(t.t) for t in trajectories]))) / SUBSTEP_S))
    horizon = max(SPEED_ROWS, round(window_s / (median * SUBSTEP_S)))
    stride = stride or horizon
    traj, start = [], []
    for i, tr in enumerate(trajectories):
        ks = np.arange(1, len(tr) - horizon, stride)
        traj.extend([i] * len(ks))
        start.extend(ks)
    if not start:
        raise LogError(
            f"no replay window: every episode is shorter than {horizon + 2} rows ({window_s:g} s and a row either side)"
        )
    subs = [row_substeps(tr, timing, median) for tr in trajectories]
    return Windows(
        trajectories, np.array(traj, int), np.array(start, int), horizon=horizon, row_substeps=subs, timing=timing
    )


class Replayer:
    """Replays windows on the simulator's car (one MuJoCo model, rolled out in C on all cores)."""

    def __init__(self, nthread: int | None = None) -> None:
        frame = TextureFrame(x0=-50.0, y1=50.0, ppm=1.0, width=100, height=100)  # a 100 m plane: no texture
        self.model = build_model(frame)
        self.physics = CarPhysics(self.model)
        self.nthread = nthread or max(1, min(4, os.cpu_count() or 1))
        self._datas = [mujoco.MjData(self.model) for _ in range(self.nthread)]
        self._spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        nstate = mujoco.mj_stateSize(self.model, self._spec)
        # FULLPHYSICS is [time, qpos, qvel] for this model (no activations, no mocap): qpos starts at 1.
        assert nstate == 1 + self.model.nq + self.model.nv, "unexpected MuJoCo state layout"
        self._root_q = 1 + self.model.jnt_qposadr[self.model.joint("car_root").id]
        self._steer_q = [1 + self.model.jnt_qposadr[self.model.joint(f"{w}_steer").id] for w in ("fl", "fr")]

    def replay(self, windows: Windows, calibration: CarCalibration | None = None) -> dict[str, np.ndarray]:
        """Simulated (W, H+1) reference point x, y (m), heading (rad) and (W, H - SPEED_ROWS + 1) speeds (m/s)."""
        calibration = calibration or CarCalibration()
        self.physics.set_calibration(calibration)  # the tyres' friction, on the model the rollout uses
        params = ActuationParams.from_calibration(calibration)
        steer, speed, sample_at = self._targets(windows, params)
        init = self._initial_states(windows, steer[:, 0])
        ctrl = self.physics.control_vectors(steer[:, 1:], speed[:, 1:])
        with rollout.Rollout(nthread=self.nthread) as r:
            states, _ = r.rollout(self.model, self._datas, init, ctrl)
        qpos = np.take_along_axis(states, sample_at[..., None], axis=1)[..., self._root_q : self._root_q + 7]
        yaw = yaw_of_quaternion(*np.moveaxis(qpos[..., 3:7], -1, 0))
        ref_d = np.array([windows.trajectories[t].reference_point_m for t in windows.traj])[:, None]
        x = qpos[..., 0] + ref_d * np.cos(yaw)
        y = qpos[..., 1] + ref_d * np.sin(yaw)
        meas0 = windows.measured()
        x = np.concatenate([meas0["x"][:, :1], x], axis=1)
        y = np.concatenate([meas0["y"][:, :1], y], axis=1)
        yaw = np.concatenate([meas0["heading"][:, :1], yaw], axis=1)
        return {"x": x, "y": y, "heading": yaw, "speed": path_speed(x, y, windows.durations())}

    def initial_states(self, windows: Windows, calibration: CarCalibration | None = None) -> np.ndarray:
        """(W, nstate) the MuJoCo state (``mjSTATE_FULLPHYSICS``) each window starts from."""
        params = ActuationParams.from_calibration(calibration or CarCalibration())
        return self._initial_states(windows, self._targets(windows, params)[0][:, 0])

    def _initial_states(self, windows: Windows, steer_deg: np.ndarray) -> np.ndarray:
        return np.stack([self._initial_state(windows, i, steer_deg[i]) for i in range(len(windows))])

    def _targets(self, windows: Windows, params: ActuationParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Servo targets (W, 1 + N): the one in force just before each window, then one per substep (windows
        shorter than the longest, N substeps, are padded with their last target); and (W, H) the substep
        after which each of the window's samples is taken."""
        per_traj, cum = {}, {}
        for t in np.unique(windows.traj):
            tr, subs = windows.trajectories[t], windows.row_substeps[t]
            st, sp = actuate_sequence(params, tr.steer_cmd_deg, tr.speed_cmd_mps, subs, SUBSTEP_S)
            per_traj[t] = (np.r_[0.0, st], np.r_[0.0, sp])
            cum[t] = np.r_[0, np.cumsum(subs)]
        first = np.array([cum[t][k] for t, k in zip(windows.traj, windows.start, strict=True)])
        ends = np.stack(
            [cum[t][k + 1 : k + windows.horizon + 1] for t, k in zip(windows.traj, windows.start, strict=True)]
        )
        sample_at = ends - first[:, None] - 1
        n = int(sample_at.max()) + 1
        steer, speed = np.empty((len(windows), n + 1)), np.empty((len(windows), n + 1))
        for w, (t, f) in enumerate(zip(windows.traj, first, strict=True)):
            idx = np.minimum(f + np.arange(n + 1), len(per_traj[t][0]) - 1)  # index 0 = the substep before
            steer[w], speed[w] = per_traj[t][0][idx], per_traj[t][1][idx]
        return steer, speed, sample_at

    def _initial_state(self, windows: Windows, i: int, steer_deg: float) -> np.ndarray:
        tr, k = windows.trajectories[windows.traj[i]], int(windows.start[i])
        subs = windows.row_substeps[windows.traj[i]]
        pose, velocity, yaw_rate = initial_motion(tr, k, (subs[k - 1] + subs[k]) * SUBSTEP_S)
        self.physics.reset(pose)
        data = self.physics.data
        v_root = self.model.jnt_dofadr[self.model.joint("car_root").id]
        data.qvel[v_root : v_root + 2] = velocity
        data.qvel[v_root + 5] = yaw_rate
        speed = float(velocity @ (math.cos(pose.yaw), math.sin(pose.yaw)))
        for side, sign in (("l", 1.0), ("r", -1.0)):
            wheel_speed = (speed - sign * yaw_rate * TRACK_WIDTH_M / 2) / WHEEL_RADIUS_M
            for axle in ("f", "r"):
                data.qvel[self.model.jnt_dofadr[self.model.joint(f"{axle}{side}_spin").id]] = wheel_speed
        state = np.empty(mujoco.mj_stateSize(self.model, self._spec))
        mujoco.mj_getState(self.model, data, state, self._spec)
        state[self._steer_q] = math.radians(steer_deg)
        return state


def initial_motion(tr: Trajectory, k: int, span_s: float) -> tuple[Pose, np.ndarray, float]:
    """Base_link pose, velocity (vx, vy in m/s, world frame) and yaw rate (rad/s) at sample k, from central
    differences over the rows k-1 and k (lasting ``span_s`` together). The velocity keeps its sideways part: a
    sliding car starts sliding."""
    h = math.radians(tr.heading_deg[k])
    d = tr.reference_point_m
    pose = Pose(tr.x[k] - d * math.cos(h), tr.y[k] - d * math.sin(h), h)
    dh = math.remainder(math.radians(tr.heading_deg[k + 1] - tr.heading_deg[k - 1]), 2 * math.pi)
    yaw_rate = dh / span_s
    v_ref = np.array([tr.x[k + 1] - tr.x[k - 1], tr.y[k + 1] - tr.y[k - 1]]) / span_s
    # The reference point ahead of base_link also moves sideways when the car turns: remove that part.
    velocity = v_ref - yaw_rate * d * np.array([-math.sin(h), math.cos(h)])
    return pose, velocity, yaw_rate


def path_speed(x: np.ndarray, y: np.ndarray, durations: np.ndarray, rows: int = SPEED_ROWS) -> np.ndarray:
    """(W, H - rows + 1) speed over ``rows`` consecutive rows: the path length from sample i to i + rows over
    their duration, for (W, H+1) positions and (W, H) row durations."""
    step = np.hypot(np.diff(x, axis=1), np.diff(y, axis=1))
    kernel = np.ones(rows)
    length = np.apply_along_axis(np.convolve, 1, step, kernel, mode="valid")
    return length / np.apply_along_axis(np.convolve, 1, durations, kernel, mode="valid")


def residuals(sim: dict[str, np.ndarray], meas: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """(W, H) simulated minus measured: dx, dy (m), dheading (deg, wrapped to ±180); (W, H - SPEED_ROWS + 1)
    dspeed (m/s)."""
    dh = np.degrees(np.remainder(sim["heading"][:, 1:] - meas["heading"][:, 1:] + np.pi, 2 * np.pi) - np.pi)
    return {
        "dx": sim["x"][:, 1:] - meas["x"][:, 1:],
        "dy": sim["y"][:, 1:] - meas["y"][:, 1:],
        "dheading": dh,
        "dspeed": sim["speed"] - meas["speed"],
    }
