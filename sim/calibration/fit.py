"""Find the effects the car model lacks, fit them, and score the result on data the fit did not see.

The procedure (:func:`calibrate`):

1. Split the episodes (sorted by file and episode number; episode i): ``i % 4 in (0, 1)`` fit the parameters,
   ``i % 4 == 2`` choose the effects, ``i % 4 == 3`` report the error. The split interleaves episodes, so
   each part spans the whole log, and no episode is in two parts.
2. Replay 1 s windows (``sim.calibration.replay``) and measure the residual of the uncalibrated car.
3. Forward selection: each round, add each candidate effect in turn to those already chosen, fit its
   parameters on the fit windows (``scipy.optimize``, derivative-free: see :func:`fit_effects`), and score
   the result on the selection windows. The best candidate is kept if it cuts the held-out cost by more than
   :data:`PENALTY_PER_PARAM` of what is left per parameter it adds and its value is significant (more than
   :data:`MIN_Z` standard errors from the value that does nothing); otherwise selection stops. After each
   addition, all chosen effects are refitted together, and one that the joint refit leaves within
   :data:`MIN_Z` joint standard errors of doing nothing is dropped and not tried again.
4. Backward check: a chosen effect that no longer pays its penalty once the others were refitted is dropped.
5. Report the chosen effects with standard errors (cluster-robust by episode: windows of one episode are not
   independent) and the error before and after on the report windows, broken down by condition.

The cost: each channel's mean squared residual (position, heading, speed) divided by the uncalibrated car's on
the fit windows, summed, so the uncalibrated car scores 3 on the fit windows and each channel weighs the same.

A base car (``calibrate(base=...)``, e.g. a design read from DeepRacer's simapp, ``sim/cars/design/``) is the
start instead of the car as modelled: its model properties (masses, inertias, drives) stay; its other effects
are refitted first and with every candidate, then effects are chosen on top as above. "Before" in the report
is still the car as modelled, so that every score compares with the default car.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from common.car_calibration import CANDIDATE_EFFECTS, EFFECTS, CarCalibration, CarEffect, ParamSpec
from sim.calibration.logs import LogError, Trajectory
from sim.calibration.replay import Replayer, Windows, detect_timing, make_windows, residuals
from sim.calibration.response import command_response, simulate_open_loop

log = logging.getLogger(__name__)

PENALTY_PER_PARAM = 0.03
"""An effect must cut the held-out cost by more than this fraction of it per parameter it adds."""
MIN_Z = 2.0
"""An effect is chosen only if a parameter is more than this many standard errors from its identity value."""
MAX_FIT_WINDOWS = 400
"""Windows used to fit parameters (and as many to choose effects): evenly spread over the episodes."""
MAX_NFEV = 30
"""Cost evaluations allowed per fitted parameter."""


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
    meas: dict[str, np.ndarray] = field(init=False)

    def __post_init__(self) -> None:
        self.meas = self.windows.measured()

    def residual(self, cal: CarCalibration) -> dict[str, np.ndarray]:
        """Raw residuals (W, H) of the calibration on these windows."""
        return residuals(self.replayer.replay(self.windows, cal), self.meas)

    def vector(self, res: dict[str, np.ndarray]) -> np.ndarray:
        """Normalized residual vector: its squared norm is the cost."""
        n = res["dx"].size
        sp, sh, sv = (np.sqrt(self.scales[k] * n) for k in ("pos", "heading", "speed"))
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
        per_window = np.repeat(self.windows.episode_keys(), self.windows.horizon)
        return np.tile(per_window, 4)


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
    objective: Objective, effects: list[str], start: CarCalibration | None = None, free: list[str] | None = None
) -> Fit:
    """Fit the parameters of the ``free`` effects (default: all of ``effects``, jointly) on the objective's
    windows; every other effect of ``start`` keeps its value (the base car's effects among them).

    Derivative-free on purpose: the replayed car's contacts make the cost rough at the scale of small
    parameter changes (a 0.5 ms change of a delay moves single speed residuals by 3 % of the cost), and
    delays act like phase shifts, which Gauss-Newton steps handle badly. One parameter: bounded Brent search;
    several: Powell's method within the bounds. Standard errors then come from a finite-difference Jacobian
    with steps of a third of each parameter's typical size.
    """
    start = start or CarCalibration()
    free = effects if free is None else free
    fixed = start.model_copy(update={"effects": [e for e in start.effects if e.name not in free]})
    keys = _param_keys(free)
    specs = [EFFECTS[e].params[p] for e, p in keys]
    started = {e.name for e in start.effects}
    x0 = np.array([start.value(e, p) if e in started else s.start for (e, p), s in zip(keys, specs, strict=True)])
    lo, hi = np.array([s.low for s in specs]), np.array([s.high for s in specs])
    scale = np.array([s.scale for s in specs])
    evals = 0

    def calibration(x: np.ndarray, err: np.ndarray | None = None) -> CarCalibration:
        return _to_calibration(keys, np.clip(x, lo, hi), err, fixed)

    def vector(x: np.ndarray) -> np.ndarray:
        nonlocal evals
        evals += 1
        return objective.vector(objective.residual(calibration(x)))

    def cost(z: np.ndarray) -> float:  # z: parameters in units of their typical size
        return float(np.sum(np.square(vector(np.atleast_1d(z) * scale))))

    if len(keys) == 1:
        sol = minimize_scalar(
            cost,
            bounds=(lo[0] / scale[0], hi[0] / scale[0]),
            method="bounded",
            options={"xatol": 0.02, "maxiter": MAX_NFEV},
        )
        x = np.array([sol.x]) * scale
    else:
        sol = minimize(
            cost,
            x0 / scale,
            method="Powell",
            bounds=list(zip(lo / scale, hi / scale, strict=True)),
            options={"xtol": 0.02, "ftol": 1e-3, "maxfev": MAX_NFEV * len(keys)},
        )
        x = sol.x * scale
    r = vector(x)
    err = _standard_errors(vector, x, r, specs, objective.clusters())
    return Fit(calibration(x, err), float(np.sum(r**2)), evals)


def _standard_errors(
    vector: Callable, x: np.ndarray, r: np.ndarray, specs: list[ParamSpec], clusters: np.ndarray
) -> np.ndarray:
    """Cluster-robust standard errors at ``x``, from a forward-difference Jacobian with steps of a third of
    each parameter's typical size (smaller steps would see the contact solver's roughness, not the trend)."""
    lo, hi = np.array([s.low for s in specs]), np.array([s.high for s in specs])
    jac = _jacobian(vector, x, r, 0.3 * np.array([s.scale for s in specs]), lo, hi)
    return _cluster_stderr(jac, r, clusters)


def _jacobian(f: Callable, x: np.ndarray, fx: np.ndarray, step: np.ndarray, lo: np.ndarray, hi: np.ndarray):
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


@dataclass
class Round:
    """One round of forward selection: each candidate's held-out cost, and the one kept (if any)."""

    candidates: list[dict]
    chosen: str | None
    cost_before: float
    dropped: list[str] = field(default_factory=list)
    """Chosen effects (this round's or earlier) the joint refit left insignificant, dropped after the round."""


def select_effects(
    fit_obj: Objective,
    sel_obj: Objective,
    candidates: list[str] | None = None,
    progress: Callable[[str], None] = log.info,
    base: CarCalibration | None = None,
) -> tuple[CarCalibration, list[Round]]:
    """Forward selection of effects by held-out cost (see the module docstring); returns the calibration.

    ``base``: the car to start from (one built from its design). Its model properties that trajectories cannot
    tell apart (masses, inertias, drives: effects that are not candidates) stay as they are; its other effects
    (e.g. the design's tyre friction and steering lag) are starting values, refitted with every effect tried
    and chosen, as effects are refitted once chosen. No candidate is an effect the base already has."""
    base = base or CarCalibration()
    refit = [e.name for e in base.effects if EFFECTS[e.name].candidate]
    remaining = [c for c in (candidates or CANDIDATE_EFFECTS) if not base.has(c)]
    chosen: list[str] = []
    current = base
    current_cost = sel_obj.cost(current)
    rounds: list[Round] = []
    if refit:
        # The design's values, refitted on the logs first: they are parameters already (no penalty to pay),
        # kept if the held-out windows agree.
        fit = fit_effects(fit_obj, refit, current)
        cost = sel_obj.cost(fit.calibration)
        progress(f"refit the base car's {', '.join(refit)}: held-out cost {cost:.3f} (base {current_cost:.3f})")
        if cost < current_cost:
            current, current_cost = fit.calibration, cost
    while remaining:
        tried = []
        for name in remaining:
            # Screening: fit only the candidate's parameters (and the base values being refitted), the chosen
            # effects held at their values.
            fit = fit_effects(fit_obj, [*refit, *chosen, name], current, free=[*refit, name])
            tried.append(
                {
                    "name": name,
                    "select_cost": sel_obj.cost(fit.calibration),
                    "fit_cost": fit.cost,
                    "nfev": fit.nfev,
                    "calibration": fit.calibration,
                    "z": _z_score(fit.calibration, name),
                }
            )
            progress(f"  try {name:20s} held-out cost {tried[-1]['select_cost']:.3f} (now {current_cost:.3f})")
        # Only an effect measurably away from doing nothing can be chosen: a parameter more than MIN_Z
        # standard errors from its identity value (else a lucky fit to noise could pass the held-out test).
        best = min(tried, key=lambda t: t["select_cost"] if t["z"] > MIN_Z else np.inf)
        n_params = len(EFFECTS[best["name"]].params)
        threshold = current_cost * (1 - PENALTY_PER_PARAM * n_params)
        keep = best["select_cost"] < threshold and best["z"] > MIN_Z
        rounds.append(Round([_public(t) for t in tried], best["name"] if keep else None, current_cost))
        if not keep:
            break
        chosen.append(best["name"])
        remaining.remove(best["name"])
        current, current_cost = best["calibration"], best["select_cost"]
        # Then all chosen effects are refitted together (a new effect changes what the others should be),
        # and the joint fit is kept only if it also does better on the held-out windows.
        joint = fit_effects(fit_obj, [*refit, *chosen], current)
        joint_cost = sel_obj.cost(joint.calibration)
        if joint_cost < current_cost:
            current, current_cost = joint.calibration, joint_cost
        progress(f"chose {best['name']}: held-out cost {current_cost:.3f}")
        before = list(chosen)
        current, current_cost = _drop_insignificant(fit_obj, sel_obj, current, chosen, progress, base)
        rounds[-1].dropped = [name for name in before if name not in chosen]
    current, current_cost = _prune(current, current_cost, sel_obj, progress, base)
    return with_stderr(fit_obj, current, base), rounds


def with_stderr(objective: Objective, cal: CarCalibration, base: CarCalibration | None = None) -> CarCalibration:
    """The calibration with the standard errors of all its fitted parameters, estimated jointly at its values
    (effects it has as the base car has them were not fitted, and get none)."""
    base = base or CarCalibration()
    fitted = [e.name for e in cal.effects if not base.has(e.name) or e.params != _params(base, e.name)]
    if not fitted:
        return cal
    keys = _param_keys(fitted)
    specs = [EFFECTS[e].params[p] for e, p in keys]
    x = np.array([cal.value(e, p) for e, p in keys])

    def vector(v: np.ndarray) -> np.ndarray:  # _to_calibration keeps each value within its bounds
        return objective.vector(objective.residual(_to_calibration(keys, v, None, cal)))

    return _to_calibration(keys, x, _standard_errors(vector, x, vector(x), specs, objective.clusters()), cal)


def _params(cal: CarCalibration, name: str) -> dict[str, float]:
    return next(e.params for e in cal.effects if e.name == name)


def _prune(
    cal: CarCalibration,
    cost: float,
    sel_obj: Objective,
    progress: Callable[[str], None],
    base: CarCalibration | None = None,
) -> tuple[CarCalibration, float]:
    """Drop chosen effects that no longer pay after the joint refits (the others may now explain what they did);
    the base car's effects stay."""
    base = base or CarCalibration()
    for effect in [e for e in cal.effects if not base.has(e.name)]:
        without = cal.model_copy(update={"effects": [e for e in cal.effects if e.name != effect.name]})
        cost_without = sel_obj.cost(without)
        if cost < cost_without * (1 - PENALTY_PER_PARAM * len(effect.params)):
            continue
        progress(f"dropped {effect.name}: held-out cost {cost_without:.3f} without it ({cost:.3f} with)")
        cal, cost = without, cost_without
    return cal, cost


def _drop_insignificant(
    fit_obj: Objective,
    sel_obj: Objective,
    cal: CarCalibration,
    chosen: list[str],
    progress: Callable[[str], None],
    base: CarCalibration | None,
) -> tuple[CarCalibration, float]:
    """Drop the chosen effects that the joint refit left within :data:`MIN_Z` joint standard errors of doing
    nothing (``chosen`` is updated; a dropped effect is not tried again).

    Why: a candidate is screened with the chosen effects held, so part of its held-out gain can be the
    chosen effects' own refinement, which the joint refit then takes back from it (seen: a speed lag's
    joint refit moved a screened steering gain of 0.97 back to 1.001 ± 0.005, and the car kept a gain
    that does nothing, and two more effects riding the same roughness of the cost)."""
    joint = with_stderr(fit_obj, cal, base)
    weak = [name for name in chosen if _z_score(joint, name) <= MIN_Z]
    if not weak:
        return cal, sel_obj.cost(cal)
    for name in weak:
        z = _z_score(joint, name)
        progress(f"dropped {name}: {z:.1f} standard errors from doing nothing after the joint refit")
        chosen.remove(name)
    kept = cal.model_copy(update={"effects": [e for e in cal.effects if e.name not in weak]})
    return kept, sel_obj.cost(kept)


def _z_score(cal: CarCalibration, name: str) -> float:
    """How many standard errors the effect's parameter furthest from its identity value is from it."""
    effect = next(e for e in cal.effects if e.name == name)
    spec = EFFECTS[name].params
    stderr = effect.stderr or {}
    return max(abs(v - spec[k].identity) / max(stderr.get(k, 0.0), 1e-12) for k, v in effect.params.items())


def _public(tried: dict) -> dict:
    cal: CarCalibration = tried["calibration"]
    return {
        "name": tried["name"],
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
        "effects": [e.model_dump(exclude_none=True) for e in calibration.effects],
        "error_before": error_summary(res_b),
        "error_after": error_summary(res_a),
        "evaluated_on": sources(trajectories),
        "windows_evaluated": len(windows),
        "window_s": round(float(np.median(windows.durations().sum(axis=1))), 4),
        "row_timing": windows.timing,
        "breakdown_before": breakdown(res_b, windows),
        "breakdown_after": breakdown(res_a, windows),
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
    max_windows: int = MAX_FIT_WINDOWS,
    progress: Callable[[str], None] = log.info,
    timing: str = "auto",
    base: CarCalibration | None = None,
) -> Result:
    """Choose and fit the effects on part of the episodes; score before and after on episodes it did not use.

    ``base``: the car to start from; its effects are kept as they are and others are chosen on top of it.
    "before" is always the car as modelled (no effects), so that scores compare with the default car's."""
    if timing == "auto":
        timing = detect_timing(trajectories)  # one rule for all parts, decided on all the logs given
    parts = split_episodes(trajectories)
    if not all(parts.values()):
        raise LogError(f"need at least 4 usable episodes to fit, choose and report apart; got {len(trajectories)}")
    replayer = Replayer()
    fit_w, sel_w = fit_windows(parts, max_windows, timing)
    scales = channel_scales(residuals(replayer.replay(fit_w), fit_w.measured()))
    progress(f"fit on {len(fit_w)} windows, choose on {len(sel_w)}; uncalibrated fit cost 3.000")
    fit_obj, sel_obj = Objective(replayer, fit_w, scales), Objective(replayer, sel_w, scales)
    if base is not None and base.effects:
        progress(f"base car ({', '.join(e.name for e in base.effects)}): fit cost {fit_obj.cost(base):.3f}")
    cal, rounds = select_effects(fit_obj, sel_obj, candidates, progress, base)
    result = score(cal, parts["report"], replayer, timing)
    result.report.update(
        {
            "fit_on": sources(parts["fit"]),
            "selected_on": sources(parts["select"]),
            "selection": [
                {
                    "cost_before": round(r.cost_before, 5),
                    "chosen": r.chosen,
                    "dropped": r.dropped,
                    "candidates": r.candidates,
                }
                for r in rounds
            ],
            "windows_fit": len(fit_w),
            "windows_selected_on": len(sel_w),
        }
    )
    if base is not None:
        # The base car alone on the report windows: what its design explains before any effect is fitted.
        base_res = residuals(replayer.replay(result.windows, base), result.replays["measured"])
        result.report["base"] = [e.model_dump(exclude_none=True) for e in base.effects]
        result.report["error_base"] = error_summary(base_res)
    return result


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
    scales = channel_scales(residuals(replayer.replay(fit_w), fit_w.measured()))
    fitted = [e.name for e in car.effects if e.stderr]
    start = base.model_copy(update={"about": car.about})
    return fit_effects(Objective(replayer, fit_w, scales), fitted, start).calibration
