"""Find the effects the car model lacks, fit them, and score the result on data the fit did not see.

The procedure (:func:`calibrate`):

1. Split the episodes (sorted by file and episode number; episode i): ``i % 4 in (0, 1)`` fit the parameters,
   ``i % 4 == 2`` choose the effects, ``i % 4 == 3`` report the error. The split interleaves episodes, so
   each part spans the whole log, and no episode is in two parts.
2. Replay 1 s windows (``sim.calibration.replay``) and measure the residual of the uncalibrated car.
3. The base car: :data:`BASE_EFFECTS` (grip, steering geometry, speed scale; and a given car's candidate
   effects) fitted jointly, each kept only if it pays :data:`PENALTY_PER_PARAM` on the selection windows.
4. Forward selection on top of the base: each round, :func:`score_test` ranks the remaining candidates (one
   replay each), the best :data:`SCREEN_TOP` are fitted (:func:`fit_effects`) and scored on the selection
   windows. The best is kept if it cuts the held-out cost by more than :data:`PENALTY_PER_PARAM` of what is left
   per parameter it adds and its value is significant (more than :data:`MIN_Z` standard errors from the value
   that does nothing); otherwise selection stops. After each addition the base and all chosen effects are
   refitted together, and one that the joint refit leaves within :data:`MIN_Z` joint standard errors of doing
   nothing is dropped and not tried again.
5. Backward check: a chosen effect that no longer pays its penalty once the others were refitted is dropped;
   each chosen effect's partner (:data:`PARTNERS`) is fitted in its place to see whether the data can tell them
   apart.
6. Report the base and the effects apart (``sim.calibration.values``: values in their physical sense, standard
   errors cluster-robust by episode, 95 % intervals, ambiguities), the error before and after on the report
   windows, broken down by condition, what the logs can identify (``sim.calibration.plan``) and whether the
   residual on every episode is noise or structure (``sim.calibration.residual``).

The cost: each channel's mean squared residual (position, heading, speed) divided by the uncalibrated car's on
the fit windows, summed, so the uncalibrated car scores 3 on the fit windows and each channel weighs the same.

A base car (``calibrate(base=...)``, e.g. a design read from DeepRacer's simapp, ``sim/cars/design/``, or a car
fitted on a clean log) is the start instead of the car as modelled: its model properties (masses, inertias,
drives) stay; its other effects are refitted first, with :data:`BASE_EFFECTS`, then effects are chosen on top
as above. "Before" in the report
is still the car as modelled, so that every score compares with the default car.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, minimize

from common.car_calibration import CANDIDATE_EFFECTS, EFFECTS, CarCalibration, CarEffect
from sim.calibration.logs import LogError, Trajectory
from sim.calibration.plan import command_steps, identifiability, pairs_confounded
from sim.calibration.replay import (
    SPEED_ROWS,
    Replayer,
    Windows,
    detect_timing,
    make_windows,
    path_speed,
    residuals,
)
from sim.calibration.residual import residual_structure
from sim.calibration.response import command_response, simulate_open_loop
from sim.calibration.values import describe

log = logging.getLogger(__name__)

PENALTY_PER_PARAM = 0.03
"""An effect must cut the held-out cost by more than this fraction of it per parameter it adds."""
MIN_Z = 2.0
"""An effect is chosen only if a parameter is more than this many standard errors from its identity value."""
MAX_FIT_WINDOWS = 120
"""Windows used to fit parameters (and as many to choose effects): evenly spread over the episodes. 120 windows of
15 rows hold ~1,800 samples per channel: parameters to a few per cent, a replay in ~0.4 s on one core."""
MAX_ITER = 10
"""Levenberg-Marquardt iterations allowed per fit (one replay each, a fresh Jacobian one per parameter)."""
JOINT_ITER = 6
"""Iterations of a joint refit (each a fresh Jacobian: 1 + n replays), which starts near its solution (from the
screened values)."""
BASE_ITER = 12
"""Iterations of the base car's fit, which starts from racer's car, possibly far from the logged one."""
THOROUGH_NFEV = 30
"""Replays per parameter of a thorough (derivative-free) fit."""
STEP_TOL = 0.01
"""A fit stops when its step is below this, in units of the parameters' typical sizes."""
COST_TOL = 1e-3
"""A fit stops when an iteration removes less than this fraction of the cost."""


# ------------------------------------------------------------------------------------------------ errors


def error_summary(res: dict[str, np.ndarray]) -> dict[str, float]:
    """RMS position (m), heading (deg) and speed (m/s) error over all window samples, and at the window end."""
    pos = np.hypot(res["dx"], res["dy"])
    return {
        "position_m": _rms(pos),
        "heading_deg": _rms(res["dheading"]),
        "speed_mps": _rms(res["dspeed"]),
        "position_at_end_m": _rms(pos[:, -1]),
        "heading_at_end_deg": _rms(res["dheading"][:, -1]),
    }


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a)))) if a.size else float("nan")


def conditions(windows: Windows) -> dict[str, np.ndarray]:
    """Per window: its condition under three splits, for breaking the residual down by cause."""
    steer, speed = windows.commands()
    v0 = windows.measured()["speed"][:, 0]
    dv = speed.mean(axis=1) - v0
    return {
        "speed": np.where(speed.mean(axis=1) <= 1.25, "cmd <= 1.25 m/s", "cmd > 1.25 m/s"),
        "steering": np.select(
            [np.abs(steer).mean(axis=1) < 5, np.abs(steer).mean(axis=1) < 15],
            ["|cmd| < 5°", "|cmd| 5–15°"],
            "|cmd| >= 15°",
        ),
        "acceleration": np.select([dv > 0.2, dv < -0.2], ["accelerating", "slowing"], "steady"),
    }


def breakdown(res: dict[str, np.ndarray], windows: Windows) -> list[dict]:
    """The error summary per condition (speed, steering, acceleration), with the number of windows in each."""
    rows = []
    for split, labels in conditions(windows).items():
        for label in sorted(set(labels)):
            mask = labels == label
            part = {k: v[mask] for k, v in res.items()}
            rows.append({"split": split, "condition": str(label), "windows": int(mask.sum()), **error_summary(part)})
    return rows


# ------------------------------------------------------------------------------------------------ the cost


@dataclass
class Objective:
    """The normalized residual of a calibration on a set of windows."""

    replayer: Replayer
    windows: Windows
    scales: dict[str, float]
    """Mean squared residual of the uncalibrated car per channel (pos, heading, speed) on the fit windows."""
    speed_rows: int = SPEED_ROWS
    """Rows a speed is measured over: ``sim.calibration.replay.SPEED_ROWS``, or 1 for the car presets' refit, which
    reproduces the fit they were made with (speeds over one row)."""
    meas: dict[str, np.ndarray] = field(init=False)

    def __post_init__(self) -> None:
        self.meas = self._speeds(self.windows.measured())

    def _speeds(self, d: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        if self.speed_rows == SPEED_ROWS:
            return d
        return {**d, "speed": path_speed(d["x"], d["y"], self.windows.durations(), self.speed_rows)}

    def residual(self, cal: CarCalibration) -> dict[str, np.ndarray]:
        """Raw residuals (W, H) of the calibration on these windows."""
        return residuals(self._speeds(self.replayer.replay(self.windows, cal)), self.meas)

    def vector(self, res: dict[str, np.ndarray]) -> np.ndarray:
        """Normalized residual vector: its squared norm is the cost."""
        sp, sh = (np.sqrt(self.scales[k] * res["dx"].size) for k in ("pos", "heading"))
        sv = np.sqrt(self.scales["speed"] * res["dspeed"].size)
        return np.concatenate(
            [
                (res["dx"] / sp).ravel(),
                (res["dy"] / sp).ravel(),
                (res["dheading"] / sh).ravel(),
                (res["dspeed"] / sv).ravel(),
            ]
        )

    def cost(self, cal: CarCalibration) -> float:
        """Sum over channels of mean squared residual / the uncalibrated car's (3.0 for it on the fit windows)."""
        return float(np.sum(np.square(self.vector(self.residual(cal)))))

    def clusters(self) -> np.ndarray:
        """The episode of each entry of :meth:`vector`."""
        keys = self.windows.episode_keys()
        per_window = np.repeat(keys, self.windows.horizon)
        per_speed = np.repeat(keys, self.windows.horizon - self.speed_rows + 1)
        return np.concatenate([per_window, per_window, per_window, per_speed])


def channel_scales(res: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean squared residual per channel, the cost's normalizers."""
    return {
        "pos": float(np.mean(res["dx"] ** 2 + res["dy"] ** 2)),
        "heading": float(np.mean(res["dheading"] ** 2)),
        "speed": float(np.mean(res["dspeed"] ** 2)),
    }


# ------------------------------------------------------------------------------------------------ fitting


@dataclass
class Fit:
    """A fitted set of effects."""

    calibration: CarCalibration
    cost: float
    """Cost on the fit windows."""
    nfev: int


def _param_keys(effects: list[str]) -> list[tuple[str, str]]:
    return [(e, p) for e in effects for p in EFFECTS[e].params]


def _to_calibration(
    keys: list[tuple[str, str]], x: np.ndarray, err: np.ndarray | None, fixed: CarCalibration
) -> CarCalibration:
    """``fixed`` with the parameters ``keys`` set to ``x`` (and their standard errors ``err``): its other
    effects, and its ``about``, are kept as they are."""
    values: dict[str, dict[str, float]] = {}
    stderr: dict[str, dict[str, float]] = {}
    for i, (e, p) in enumerate(keys):
        spec = EFFECTS[e].params[p]
        values.setdefault(e, {})[p] = float(np.clip(x[i], spec.low, spec.high))
        if err is not None:
            stderr.setdefault(e, {})[p] = float(err[i])
    kept = [e for e in fixed.effects if e.name not in values]
    fitted = [CarEffect(name=n, params=p, stderr=stderr.get(n)) for n, p in values.items()]
    return CarCalibration(about=fixed.about, effects=kept + fitted)


def fit_effects(
    objective: Objective,
    effects: list[str],
    start: CarCalibration | None = None,
    free: list[str] | None = None,
    max_iter: int | None = None,
    thorough: bool = False,
) -> Fit:
    """Fit the parameters of the ``free`` effects (default: all of ``effects``, jointly) on the objective's
    windows; every other effect of ``start`` keeps its value (the base car's effects among them).

    Gauss-Newton with a trust region, within the bounds, on the residual vector; the Jacobian by forward
    differences with steps of a third of each parameter's typical size: the replayed car's contacts make the cost
    rough at the scale of small parameter changes (a 0.5 ms change of a delay moves single speed residuals by 3 %
    of the cost), and a third of the typical size sees the trend, not the roughness. One parameter: Levenberg-
    Marquardt with Broyden updates (:func:`_trust_region`, one replay an iteration); several:
    ``scipy.optimize.least_squares`` with a fresh Jacobian each iteration (measured on the ROS1 preset's refit:
    Broyden's Jacobian stalled at a cost 6 % above the minimum the fresh one reaches). Where racer's derivative-free
    searches needed 15–30 replays per parameter, these converge in 3–8 iterations. ``thorough``: Powell's
    derivative-free search instead, :data:`THOROUGH_NFEV` replays per parameter, for the car presets' refit (on the
    ROS1 preset's fit log it reaches a cost of 0.367 in 90 replays where the gradient fit stops at 0.385 in 24).
    The standard errors are cluster-robust by episode, from a fresh Jacobian at the solution.
    """
    start = start or CarCalibration()
    free = effects if free is None else free
    if not free:  # nothing to fit (e.g. --effect names none of the base's): the start as it is
        return Fit(start, objective.cost(start), 1)
    fixed = start.model_copy(update={"effects": [e for e in start.effects if e.name not in free]})
    keys = _param_keys(free)
    specs = [EFFECTS[e].params[p] for e, p in keys]
    started = {e.name for e in start.effects}
    x0 = np.array([start.value(e, p) if e in started else s.start for (e, p), s in zip(keys, specs, strict=True)])
    lo, hi = np.array([s.low for s in specs]), np.array([s.high for s in specs])
    scale = np.array([s.scale for s in specs])
    evals = 0
    cache: dict[bytes, np.ndarray] = {}

    def calibration(x: np.ndarray, err: np.ndarray | None = None) -> CarCalibration:
        return _to_calibration(keys, np.clip(x, lo, hi), err, fixed)

    def vector(x: np.ndarray) -> np.ndarray:
        nonlocal evals
        x = np.clip(x, lo, hi)
        key = x.tobytes()
        if key not in cache:  # least_squares asks for the residual and then the Jacobian at the same point
            evals += 1
            cache.clear()
            cache[key] = objective.vector(objective.residual(calibration(x)))
        return cache[key]

    z0 = np.clip(x0, lo, hi) / scale
    jac_z = None
    if thorough:  # derivative-free, many replays: finds the lower points of a rough valley (see above)
        z = minimize(
            lambda z: float(np.sum(np.square(vector(z * scale)))),
            z0,
            method="Powell",
            bounds=list(zip(lo / scale, hi / scale, strict=True)),
            options={"xtol": 0.02, "ftol": 1e-3, "maxfev": THOROUGH_NFEV * len(keys)},
        ).x
    elif len(keys) == 1:
        z, _ = _trust_region(lambda z: vector(z * scale), z0, lo / scale, hi / scale, max_iter or MAX_ITER)
    else:  # jointly: a fresh Jacobian every iteration (Broyden's drifts in the valleys a joint fit has)
        sol = least_squares(
            lambda z: vector(z * scale),
            z0,
            jac=lambda z: _jacobian(vector, z * scale, vector(z * scale), 0.3 * scale, lo=lo, hi=hi) * scale,
            bounds=(lo / scale, hi / scale),
            xtol=1e-3,
            ftol=1e-4,
            max_nfev=max_iter or JOINT_ITER,
        )
        z, jac_z = sol.x, sol.jac
    x = np.clip(z * scale, lo, hi)
    r = vector(x)
    # For the standard errors: least_squares's last Jacobian is the one at its solution; else a fresh one.
    jac_x = jac_z / scale if jac_z is not None else _jacobian(vector, x, r, 0.3 * scale, lo=lo, hi=hi)
    err = _cluster_stderr(jac_x, r, objective.clusters())
    return Fit(calibration(x, err), float(np.sum(r**2)), evals)


def _trust_region(
    f: Callable[[np.ndarray], np.ndarray], z: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_iter: int
) -> tuple[np.ndarray, np.ndarray]:
    """Bounded Levenberg-Marquardt on ``f`` (parameters in units of their typical size) with Broyden updates of
    a forward-difference Jacobian: one replay per iteration, where recomputing the Jacobian costs one per
    parameter. Steps are projected onto the bounds. The Jacobian is computed afresh when Broyden's has led to two
    failed steps in a row or to a step too small to take, and the fit ends only on a small step or a small gain
    with a fresh Jacobian (a stale one can stall far from the minimum). Returns the parameters and residual."""
    r = f(z)
    jac, fresh = _jacobian(f, z, r, np.full(len(z), 0.3), lo=lo, hi=hi), True
    cost, lam, fails = float(r @ r), 1e-2, 0
    for _ in range(max_iter):
        a, g = jac.T @ jac, jac.T @ r
        step = np.clip(z + np.linalg.solve(a + lam * np.diag(np.diag(a) + 1e-9), -g), lo, hi) - z
        if np.linalg.norm(step) < STEP_TOL or fails >= 2:
            if fresh:
                break
            jac, fresh, fails = _jacobian(f, z, r, np.full(len(z), 0.3), lo=lo, hi=hi), True, 0
            continue
        r_trial = f(z + step)
        jac = jac + np.outer(r_trial - r - jac @ step, step) / float(step @ step)  # Broyden's rank-one update
        c_trial = float(r_trial @ r_trial)
        if c_trial >= cost:
            lam, fails = lam * 4, fails + 1
            continue
        small = cost - c_trial < COST_TOL * cost
        z, r, cost, lam, fails = z + step, r_trial, c_trial, lam / 3, 0
        if small and fresh:
            break
        fresh = False
    return z, r


def _jacobian(f: Callable, x: np.ndarray, fx: np.ndarray, step: np.ndarray, *, lo: np.ndarray, hi: np.ndarray):
    """Forward-difference Jacobian, stepping towards the inside of the bounds."""
    cols = []
    for i in range(len(x)):
        h = step[i] if x[i] + step[i] <= hi[i] else -step[i]
        xi = x.copy()
        xi[i] = np.clip(xi[i] + h, lo[i], hi[i])
        cols.append((f(xi) - fx) / (xi[i] - x[i]))
    return np.stack(cols, axis=1)


def _cluster_stderr(jac: np.ndarray, r: np.ndarray, clusters: np.ndarray) -> np.ndarray:
    """Standard errors robust to correlation within a cluster: (JᵀJ)⁻¹ (Σ_c J_cᵀ r_c r_cᵀ J_c) (JᵀJ)⁻¹."""
    bread = np.linalg.pinv(jac.T @ jac)
    scores = np.stack([jac[clusters == c].T @ r[clusters == c] for c in np.unique(clusters)])
    return np.sqrt(np.maximum(np.diag(bread @ (scores.T @ scores) @ bread), 0.0))


# ------------------------------------------------------------------------------------------------ selection

BASE_EFFECTS = ("tyre_friction", "steering_gain", "speed_gain")
"""What makes a logged car differ from racer's in kind, fitted first as "the car": its grip, its steering
geometry (the wheel angle a command gives) and its speed scale."""
SAME_KIND: dict[str, tuple[float, float]] = {
    "steering_gain": (0.9, 1.1),
    "speed_gain": (0.9, 1.1),
    "steering_offset": (-0.5, 0.5),
    "steering_delay": (0.0, 0.05),
    "steering_lag": (0.0, 0.05),
    "steering_rate": (0.0, 0.1),
    "speed_delay": (0.0, 0.05),
    "speed_lag": (0.0, 0.05),
    "speed_rate": (0.0, 0.1),
    "steering_saturation": (25.0, 30.0),
    "understeer": (0.0, 0.05),
}
"""What a car of DeepRacer's kind has by construction, as each effect's first parameter: a steering ratio and a
speed scale within 10 %, a servo or motor that responds within 50 ms (less than a 15 Hz row) and turns 60° in
0.1 s or less (a hobby servo's datasheet speed) or accelerates at 10 m/s² or more, the mechanical
steering stop near 30°. Without a given base car (``--car``), a fitted value inside its range is reported as part
of the car (``"base"``), one outside as an undeclared effect (``"effects"``). One log cannot tell the car's own
small lag from an undeclared one of the same size: a base fitted on a clean log and given with ``--car`` can,
and then everything fitted on top of it is reported as an effect."""
SCREEN_TOP = 2
"""Candidates fitted in full each round: the most promising by :func:`score_test`."""
RUNNER_UP = 0.3
"""The second-ranked candidate is fitted too only if its screening promises this fraction of the first's."""
SCREEN_ITER = 5
"""Iterations of a candidate's own fit in a round: a screen (the joint refit of the chosen effects polishes)."""
MIN_GAIN = 0.5 * PENALTY_PER_PARAM
"""A candidate is fitted only if its screening promises to remove this fraction of the fit cost (half the penalty
it would pay on the held-out windows: the screening's one step may fall short of the fit)."""
AMBIGUOUS_MARGIN = 0.05
"""An alternative explanation whose held-out cost is within this fraction of the chosen one's is one the data
cannot tell apart from it."""
PARTNERS = {
    "steering_delay": "steering_lag",
    "steering_lag": "steering_delay",
    "speed_delay": "speed_lag",
    "speed_lag": "speed_delay",
    "steering_rate": "steering_lag",
    "speed_rate": "speed_lag",
    "understeer": "steering_gain",
}
"""Each effect's nearest alternative: a dead time and a lag look alike at 15 Hz; a gain and understeer alike at
one speed; a rate limit alike a lag when the steps are all of one size."""


@dataclass
class Round:
    """One round of forward selection: each candidate's screening gain and held-out cost, and the one kept."""

    candidates: list[dict]
    chosen: str | None
    cost_before: float
    dropped: list[str] = field(default_factory=list)
    """Chosen effects the joint refit left insignificant, dropped after the round."""


@dataclass
class Selection:
    """What :func:`select_effects` found."""

    calibration: CarCalibration
    cost: float
    """Held-out cost of :attr:`calibration` on the selection windows."""
    rounds: list[Round]
    base: list[str]
    """The effects that are the car itself: grip, steering geometry, speed scale, a given car's design."""
    alternatives: dict[str, dict]
    """Per chosen effect whose partner explains the data about as well: the partner's fit and held-out cost."""


def _with_effect(cal: CarCalibration, name: str, params: dict[str, float]) -> CarCalibration:
    kept = [e for e in cal.effects if e.name != name]
    return cal.model_copy(update={"effects": [*kept, CarEffect(name=name, params=params)]})


def score_test(objective: Objective, cal: CarCalibration, candidates: list[str]) -> tuple[float, dict[str, float]]:
    """``cal``'s cost, and the cost each candidate would remove from it, by one replay per candidate: its first
    parameter moved from doing nothing by its typical size (a saturation: set to its start), the larger of the
    cost that step removed and the Gauss-Newton step's prediction along it. A ranking of candidates, not a fit."""
    r0 = objective.vector(objective.residual(cal))
    c0 = float(np.sum(r0**2))
    out = {}
    for name in candidates:
        params = {k: s.identity for k, s in EFFECTS[name].params.items()}
        key, spec = next(iter(EFFECTS[name].params.items()))
        if spec.low < spec.identity < spec.high:
            params[key] = spec.identity + spec.scale
        else:  # identity at a bound: step inside (a lag, a delay) or to the start (a saturation at 30°)
            params[key] = spec.start if spec.identity == spec.high else spec.identity + spec.scale
        r1 = objective.vector(objective.residual(_with_effect(cal, name, params)))
        j = r1 - r0
        predicted = float(np.dot(j, r0) ** 2 / max(np.dot(j, j), 1e-12))
        out[name] = max(predicted if np.dot(j, r0) < 0 else 0.0, c0 - float(np.sum(r1**2)))
    return c0, out


def select_effects(
    fit_obj: Objective,
    sel_obj: Objective,
    candidates: list[str] | None = None,
    progress: Callable[[str], None] = log.info,
    base: CarCalibration | None = None,
) -> Selection:
    """The base car first, then forward selection of effects on top of it (see the module docstring).

    ``base``: a car to start from (e.g. one built from its design, or fitted on a clean log). Its model
    properties that trajectories cannot tell apart (masses, inertias, drives) stay as they are; its candidate
    effects are the base, refitted with :data:`BASE_EFFECTS` first."""
    base = base or CarCalibration()
    pool = list(candidates or CANDIDATE_EFFECTS)
    base_names = [e.name for e in base.effects if EFFECTS[e.name].candidate]
    base_names += [n for n in BASE_EFFECTS if n in pool and n not in base_names]
    guesses = [CarEffect(name=n, params={"gain": g}) for n, g in gain_guess(fit_obj.windows).items()]
    guessed = base.model_copy(update={"effects": [*base.effects, *[e for e in guesses if e.name in base_names]]})
    start = min((base, guessed), key=fit_obj.cost)  # the guess only where it starts nearer (a lag skews it)
    fit = fit_effects(fit_obj, base_names, start, max_iter=BASE_ITER)
    current, current_cost = _prune(fit.calibration, sel_obj, [n for n in base_names if not base.has(n)], progress)
    base_names = [n for n in base_names if current.has(n)]
    progress(f"the base car ({', '.join(base_names)}): held-out cost {current_cost:.3f}")
    remaining = [c for c in pool if c not in base_names and c not in BASE_EFFECTS]
    chosen: list[str] = []
    rounds: list[Round] = []
    while remaining:
        fit_cost, gains = score_test(fit_obj, current, remaining)
        ranked = sorted(remaining, key=lambda n: -gains[n])
        top = [n for n in ranked[:SCREEN_TOP] if gains[n] > max(MIN_GAIN * fit_cost, RUNNER_UP * gains[ranked[0]])]
        if not top:  # no candidate promises what it would have to pay: nothing left to fit
            screened = [{"name": n, "screen_gain": round(gains[n], 5)} for n in remaining]
            rounds.append(Round(screened, None, current_cost))
            break
        tried = []
        for name in top:
            f = fit_effects(fit_obj, [name], current, max_iter=SCREEN_ITER)
            cal = f.calibration
            tried.append(
                {
                    "name": name,
                    "screen_gain": gains[name],
                    "select_cost": sel_obj.cost(cal),
                    "fit_cost": f.cost,
                    "z": _z_score(cal, name),
                    "calibration": cal,
                }
            )
            progress(f"  try {name:20s} held-out cost {tried[-1]['select_cost']:.3f} (now {current_cost:.3f})")
        best = min(tried, key=lambda t: t["select_cost"] if t["z"] > MIN_Z else np.inf)
        threshold = current_cost * (1 - PENALTY_PER_PARAM * len(EFFECTS[best["name"]].params))
        keep = best["select_cost"] < threshold and best["z"] > MIN_Z
        screened = [{"name": n, "screen_gain": round(gains[n], 5)} for n in remaining if n not in top]
        rounds.append(Round([*map(_public, tried), *screened], best["name"] if keep else None, current_cost))
        if not keep:
            break
        chosen.append(best["name"])
        remaining.remove(best["name"])
        # All chosen effects and the base refitted together: a new effect changes what the others should be.
        joint = fit_effects(fit_obj, [*base_names, *chosen], best["calibration"])
        joint_cost = sel_obj.cost(joint.calibration)
        current, current_cost = (
            (joint.calibration, joint_cost)
            if joint_cost < best["select_cost"]
            else (best["calibration"], best["select_cost"])
        )
        weak = [n for n in chosen if _z_score(joint.calibration, n) <= MIN_Z]
        if weak:  # the joint refit took back what the screening gave them
            progress(f"dropped {', '.join(weak)}: within {MIN_Z:g} standard errors of doing nothing jointly")
            chosen = [n for n in chosen if n not in weak]
            current = current.model_copy(update={"effects": [e for e in current.effects if e.name not in weak]})
            current_cost = sel_obj.cost(current)
            rounds[-1].dropped = weak
        progress(f"chose {best['name']}: held-out cost {current_cost:.3f}")
    current, current_cost = _prune(current, sel_obj, chosen, progress)  # what no longer pays after the refits
    chosen = [n for n in chosen if current.has(n)]
    alternatives = _alternatives(fit_obj, sel_obj, current, current_cost, chosen)
    return Selection(current, current_cost, rounds, base_names, alternatives)


def gain_guess(windows: Windows) -> dict[str, float]:
    """Where the base car's steering and speed gains start: the logged car's command-response gain (the sum of
    its response weights, ``sim.calibration.response``) over racer's car's, driven open loop by the same
    commands, on the episodes of ``windows``. A trust-region fit started at racer's own gains can stall on the
    way to a car that steers 40 % less (it stopped at 0.81 for a true 0.6); from here it starts near. A slow
    car's response outlasts the 14 rows the weights span, so the guess is low for one (0.46 for a car with a
    0.5 s steering lag): :func:`select_effects` starts from it only where it costs less than racer's gains."""
    trajectories = [windows.trajectories[t] for t in np.unique(windows.traj)]
    measured, model = command_response(trajectories), command_response(simulate_open_loop(trajectories))
    out = {}
    for name, channel in (("steering_gain", "steering"), ("speed_gain", "speed")):
        g_meas, g_model = measured[channel]["gain"], model[channel]["gain"]
        if g_meas and g_model and g_model > 0:
            spec = EFFECTS[name].params["gain"]
            out[name] = float(np.clip(g_meas / g_model, spec.low, spec.high))
    return out


def _prune(
    cal: CarCalibration, sel_obj: Objective, names: list[str], progress: Callable[[str], None]
) -> tuple[CarCalibration, float]:
    """Leave out each of the effects ``names`` that does not pay on the held-out windows: one whose removal costs
    less than :data:`PENALTY_PER_PARAM` per parameter of the held-out cost (the car as modelled already is that
    car; a standard error alone would keep a gain of 1.004 ± 0.001 that a replay's own bias gives)."""
    cost = sel_obj.cost(cal)
    for name in names:
        without = cal.model_copy(update={"effects": [e for e in cal.effects if e.name != name]})
        cost_without = sel_obj.cost(without)
        if cost < cost_without * (1 - PENALTY_PER_PARAM * len(EFFECTS[name].params)):
            continue
        progress(f"left out {name}: held-out cost {cost_without:.3f} without it ({cost:.3f} with)")
        cal, cost = without, cost_without
    return cal, cost


def _alternatives(
    fit_obj: Objective,
    sel_obj: Objective,
    cal: CarCalibration,
    cost: float,
    chosen: list[str],
) -> dict[str, dict]:
    """For each chosen effect with a partner (:data:`PARTNERS`), the partner fitted in its place (or, a partner
    already chosen, the pair's held-out cost without either): kept where its held-out cost is within
    :data:`AMBIGUOUS_MARGIN` of the chosen calibration's, so the report can say the data cannot tell them apart."""
    out = {}
    for name in chosen:
        partner = PARTNERS.get(name)
        if partner is None or partner in chosen:
            continue
        without = cal.model_copy(update={"effects": [e for e in cal.effects if e.name != name]})
        alt = fit_effects(fit_obj, [partner], without)
        alt_cost = sel_obj.cost(alt.calibration)
        if alt_cost <= cost * (1 + AMBIGUOUS_MARGIN):
            out[name] = {"with": partner, "select_cost": alt_cost, "calibration": alt.calibration}
    return out


def _z_score(cal: CarCalibration, name: str) -> float:
    """How many standard errors the effect's parameter furthest from its identity value is from it."""
    effect = next((e for e in cal.effects if e.name == name), None)
    if effect is None:
        return 0.0
    spec = EFFECTS[name].params
    stderr = effect.stderr or {}
    return max(abs(v - spec[k].identity) / max(stderr.get(k, 0.0), 1e-12) for k, v in effect.params.items())


def _public(tried: dict) -> dict:
    cal: CarCalibration = tried["calibration"]
    return {
        "name": tried["name"],
        "screen_gain": round(tried["screen_gain"], 5),
        "select_cost": round(tried["select_cost"], 5),
        "fit_cost": round(tried["fit_cost"], 5),
        "z": round(min(tried["z"], 1e6), 2),
        "effects": [{"name": e.name, "params": e.params} for e in cal.effects],
    }


# ------------------------------------------------------------------------------------------------ the whole job


def split_episodes(trajectories: list[Trajectory]) -> dict[str, list[Trajectory]]:
    """Fit / select / report parts: episode i (sorted by file, episode) goes by i % 4 to fit, fit, select, report."""
    ordered = sorted(trajectories, key=lambda t: (t.source, t.episode))
    parts: dict[str, list[Trajectory]] = {"fit": [], "select": [], "report": []}
    for i, tr in enumerate(ordered):
        parts[("fit", "fit", "select", "report")[i % 4]].append(tr)
    return parts


def spread(windows: Windows, limit: int) -> Windows:
    """At most ``limit`` windows, evenly spread."""
    if len(windows) <= limit:
        return windows
    return windows.subset(np.linspace(0, len(windows) - 1, limit).round().astype(int))


def sources(trajectories: list[Trajectory]) -> list[dict]:
    """``[{"file", "episodes"}]``: which episodes of which files."""
    by_file: dict[str, list[int]] = {}
    for tr in trajectories:
        by_file.setdefault(tr.source, []).append(tr.episode)
    return [{"file": f, "episodes": sorted(eps)} for f, eps in sorted(by_file.items())]


@dataclass
class Result:
    """A calibration, its report (the JSON of ``racer calibrate``) and what the plots need."""

    calibration: CarCalibration
    report: dict
    windows: Windows
    """The windows the report scores."""
    replays: dict[str, dict[str, np.ndarray]]
    """Simulated windows, "before" (uncalibrated) and "after", plus "measured"."""


def score(
    calibration: CarCalibration, trajectories: list[Trajectory], replayer: Replayer | None = None, timing: str = "auto"
) -> Result:
    """Error before (uncalibrated car) and after (with ``calibration``) on all windows of ``trajectories``
    (``timing``: how long each row is replayed for, see ``sim.calibration.replay.TIMINGS``)."""
    replayer = replayer or Replayer()
    windows = make_windows(trajectories, timing=timing)
    meas = windows.measured()
    before, after = replayer.replay(windows), replayer.replay(windows, calibration)
    res_b, res_a = residuals(before, meas), residuals(after, meas)
    report = {
        "effects": describe(calibration, [e.name for e in calibration.effects]),
        "error_before": error_summary(res_b),
        "error_after": error_summary(res_a),
        "evaluated_on": sources(trajectories),
        "windows_evaluated": len(windows),
        "window_s": round(float(np.median(windows.durations().sum(axis=1))), 4),
        "row_timing": windows.timing,
        "breakdown_before": breakdown(res_b, windows),
        "breakdown_after": breakdown(res_a, windows),
        # What is left after the calibration, noise or structure, and where: the pointer to a missing effect.
        "residual": residual_structure(res_a, windows),
    }
    # The response shape (sim.calibration.response): measured, and the model driven open loop by the same
    # commands, before and after. Where they differ, an effect is missing; what none explains is noise.
    report["response"] = {
        "measured": command_response(trajectories),
        "before": command_response(simulate_open_loop(trajectories)),
        "after": command_response(simulate_open_loop(trajectories, calibration)),
    }
    report["reduction"] = {
        k: _reduction(report["error_before"][k], report["error_after"][k])
        for k in ("position_m", "heading_deg", "speed_mps")
    }
    report["path_time"] = path_time(windows, meas, {"before": before, "after": after})
    return Result(calibration, report, windows, {"measured": meas, "before": before, "after": after})


def path_time(windows: Windows, meas: dict[str, np.ndarray], sims: dict[str, dict[str, np.ndarray]]) -> dict:
    """How long each car takes over the logged paths, from windows that do not overlap (those of :func:`score`):
    each window's simulated end point, projected onto the measured path (extended straight past its end), is
    ahead of (or behind) the measured end by an arc length ``ds``, worth ``-ds / v`` seconds at the window's
    measured mean speed ``v``; the sum over the windows, added to the measured time they span, is the simulated
    car's time over the same path. Over complete laps this compares lap times. Not a closed-loop lap: each
    window restarts from the measured state, and the commands are the logged ones."""
    durations = windows.durations()
    span = float(durations.sum())
    steps = np.hypot(np.diff(meas["x"], axis=1), np.diff(meas["y"], axis=1))
    v = steps.sum(axis=1) / durations.sum(axis=1)
    moving = v > 0.1  # a window of a car at rest says nothing about its pace
    out = {"measured_s": round(span, 3), "windows": int(moving.sum())}
    for key, sim in sims.items():
        ds = np.array(
            [_arc_past_end(meas["x"][i], meas["y"][i], sim["x"][i, -1], sim["y"][i, -1]) for i in range(len(v))]
        )
        out[f"{key}_s"] = round(span - float(np.sum(ds[moving] / v[moving])), 3)
    return out


def _arc_past_end(px: np.ndarray, py: np.ndarray, qx: float, qy: float) -> float:
    """Arc length along the polyline p (its first and last segments extended) from its end to the point
    nearest q: positive past the end."""
    a = np.stack([px[:-1], py[:-1]], axis=1)
    d = np.stack([np.diff(px), np.diff(py)], axis=1)
    length = np.hypot(d[:, 0], d[:, 1])
    keep = length > 1e-9
    if not keep.any():
        return 0.0
    a, d, length = a[keep], d[keep], length[keep]
    u = ((qx - a[:, 0]) * d[:, 0] + (qy - a[:, 1]) * d[:, 1]) / length**2
    u[1:] = np.maximum(u[1:], 0.0)  # only the first segment reaches back before the path's start
    u[:-1] = np.minimum(u[:-1], 1.0)  # only the last one reaches past its end
    gap = np.hypot(a[:, 0] + u * d[:, 0] - qx, a[:, 1] + u * d[:, 1] - qy)
    j = int(np.argmin(gap))
    arc = np.concatenate([[0.0], np.cumsum(length)])
    return float(arc[j] + u[j] * length[j] - arc[-1])


def _reduction(before: float, after: float) -> float:
    """Fraction of the error removed (1 = all of it, negative = worse)."""
    return round(1 - after / before, 4) if before > 0 else 0.0


def calibrate(
    trajectories: list[Trajectory],
    candidates: list[str] | None = None,
    *,
    max_windows: int = MAX_FIT_WINDOWS,
    progress: Callable[[str], None] = log.info,
    timing: str = "auto",
    base: CarCalibration | None = None,
    threads: int | None = None,
) -> Result:
    """Choose and fit the effects on part of the episodes; score before and after on episodes it did not use.

    ``base``: the car to start from; its effects are kept as they are and others are chosen on top of it.
    "before" is always the car as modelled (no effects), so that scores compare with the default car's.
    ``threads``: the replay's threads (default: up to 4, one per core)."""
    clock = _Clock()
    if timing == "auto":
        timing = detect_timing(trajectories)  # one rule for all parts, decided on all the logs given
    parts = split_episodes(trajectories)
    if not all(parts.values()):
        raise LogError(f"need at least 4 usable episodes to fit, choose and report apart; got {len(trajectories)}")
    replayer = Replayer(nthread=threads)
    fit_w, sel_w = fit_windows(parts, max_windows, timing)
    scales = channel_scales(residuals(replayer.replay(fit_w), fit_w.measured()))
    progress(f"fit on {len(fit_w)} windows, choose on {len(sel_w)}; uncalibrated fit cost 3.000")
    fit_obj, sel_obj = Objective(replayer, fit_w, scales), Objective(replayer, sel_w, scales)
    clock.lap("windows")
    sel = select_effects(fit_obj, sel_obj, candidates, progress, base)
    clock.lap("selection")
    cal = sel.calibration
    if base is not None and base.effects:  # a given car: all it is, refitted, plus its masses and drives
        base_names = [n for n in sel.base if cal.has(n)] + [e.name for e in base.effects if e.name not in sel.base]
    else:  # racer's car: what lies within what a car of DeepRacer's kind has
        ordered = dict.fromkeys([*sel.base, *(e.name for e in cal.effects)])
        base_names = [n for n in ordered if cal.has(n) and _same_kind(cal, n)]
    effect_names = [e.name for e in cal.effects if e.name not in base_names]
    result = score(cal, parts["report"], replayer, timing)
    clock.lap("report")
    logged = {"mean_v2": float(np.mean(np.square(sel_obj.meas["speed"]))), "steps": command_steps(trajectories)}
    ambiguous = _ambiguous(sel, pairs_confounded(trajectories), effect_names)
    base_cal = cal.model_copy(update={"effects": [e for e in cal.effects if e.name in base_names]})
    base_res = residuals(replayer.replay(result.windows, base_cal), result.replays["measured"])
    result.report.update(
        {
            "base": describe(cal, base_names, **logged),
            "effects": describe(cal, effect_names, ambiguous=ambiguous, **logged),
            "error_base": error_summary(base_res),
            "identifiability": identifiability(trajectories),
            "alternatives": [
                {
                    "effect": n,
                    "with": a["with"],
                    "select_cost": round(a["select_cost"], 5),
                    "effects": describe(a["calibration"], [e.name for e in a["calibration"].effects]),
                }
                for n, a in sel.alternatives.items()
            ],
            "fit_on": sources(parts["fit"]),
            "selected_on": sources(parts["select"]),
            "selection": [
                {
                    "cost_before": round(r.cost_before, 5),
                    "chosen": r.chosen,
                    "dropped": r.dropped,
                    "candidates": r.candidates,
                }
                for r in sel.rounds
            ],
            "windows_fit": len(fit_w),
            "windows_selected_on": len(sel_w),
        }
    )
    # The residual's structure on every episode's windows: a test of what the model lacks, not of how well it
    # predicts, so it takes all the clusters there are (the report episodes alone, a quarter, leave it blind).
    every = make_windows(trajectories, timing=timing)
    result.report["residual"] = residual_structure(residuals(replayer.replay(every, cal), every.measured()), every)
    result.report["residual"]["on"] = "all episodes"
    if result.report["residual"]["structured"]:
        # Something the effects do not explain is left: each may be the library's nearest stand-in for what the car
        # really has, so no value is given as if it were the whole story.
        for entry in result.report["effects"]:
            entry["provisional"] = True
    clock.lap("base and residual")
    result.report["seconds"] = clock.laps
    return result


def _ambiguous(sel: Selection, confounded: list[list[str]], effects: list[str]) -> dict[str, list[str]]:
    """Per reported effect, the effects the data cannot tell it from: a partner that explains the held-out
    episodes about as well (``Selection.alternatives``), and pairs the logs lack the manoeuvres to separate
    (``sim.calibration.plan.pairs_confounded``: e.g. understeer and the steering gain at one speed)."""
    out: dict[str, set[str]] = {n: {alt["with"]} for n, alt in sel.alternatives.items() if n in effects}
    for name in effects:  # a dead time, a lag or a rate limit chosen with its partner: a split of one delay
        partner = PARTNERS.get(name)
        if partner in effects and name.endswith(("_delay", "_lag", "_rate")):
            out.setdefault(name, set()).add(partner)
            out.setdefault(partner, set()).add(name)
    for a, b in confounded:
        for name, other in ((a, b), (b, a)):
            if name in effects and sel.calibration.has(name):
                out.setdefault(name, set()).add(other)
    return {n: sorted(v) for n, v in out.items()}


def _same_kind(cal: CarCalibration, name: str) -> bool:
    """Whether the effect's value lies in :data:`SAME_KIND`, what a car of DeepRacer's kind has by construction
    (an effect with no range there, the tyres' grip, is always the car's)."""
    if name not in SAME_KIND:
        return name == "tyre_friction"
    lo, hi = SAME_KIND[name]
    key = next(iter(EFFECTS[name].params))
    return lo <= cal.value(name, key) <= hi


class _Clock:
    """Seconds spent in each part of a calibration, for the report and ``racer bench calibrate``."""

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps[name] = round(now - self._last, 3)
        self._last = now


def fit_windows(parts: dict[str, list[Trajectory]], max_windows: int, timing: str) -> tuple[Windows, Windows]:
    """The windows :func:`calibrate` fits on and chooses on: every 5th sample of the fit and select episodes,
    at most ``max_windows`` of each, evenly spread."""
    fit_w = spread(make_windows(parts["fit"], stride=5, timing=timing), max_windows)
    sel_w = spread(make_windows(parts["select"], stride=5, timing=timing), max_windows)
    return fit_w, sel_w


def refit(
    trajectories: list[Trajectory],
    car: CarCalibration,
    base: CarCalibration,
    max_windows: int = MAX_FIT_WINDOWS,
    timing: str = "auto",
) -> CarCalibration:
    """Fit again, jointly and from ``base``, the effects ``car`` was fitted with (those with standard errors),
    on the windows :func:`calibrate` would fit them on: a check that a car file's values follow from its logs
    and its base (the choice of effects is taken as made)."""
    if timing == "auto":
        timing = detect_timing(trajectories)
    replayer = Replayer()
    fit_w, _ = fit_windows(split_episodes(trajectories), max_windows, timing)
    # The presets were fitted with speeds over one row, before calibration scored them over three: their refit
    # reproduces that fit (their scores use the current rows like any car's).
    uncalibrated = Objective(replayer, fit_w, {}, speed_rows=1)
    objective = Objective(replayer, fit_w, channel_scales(uncalibrated.residual(CarCalibration())), speed_rows=1)
    fitted = [e.name for e in car.effects if e.stderr]
    start = base.model_copy(update={"about": car.about})
    return fit_effects(objective, fitted, start, thorough=True).calibration
