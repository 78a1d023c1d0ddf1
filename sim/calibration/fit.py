"""Find the effects the car model lacks, fit them, and score the result on data the fit did not see.

The procedure (:func:`calibrate`):

1. Split the episodes (sorted by file and episode number; episode i): ``i % 4 in (0, 1)`` fit the parameters,
   ``i % 4 == 2`` choose the effects, ``i % 4 == 3`` report the error. The split interleaves episodes, so
   each part spans the whole log, and no episode is in two parts.
2. Replay 1 s windows (``sim.calibration.replay``) and measure the residual of the uncalibrated car.
3. Forward selection: each round, add each candidate effect in turn to those already chosen, fit all their
   parameters jointly on the fit windows (``scipy.optimize.least_squares``), and score the result on the
   selection windows. The best candidate is kept if it cuts the held-out cost by more than
   :data:`PENALTY_PER_PARAM` of what is left per parameter it adds; otherwise selection stops.
4. Backward check: a chosen effect that no longer pays its penalty once the others were refitted is dropped.
5. Report the chosen effects with standard errors (cluster-robust by episode: windows of one episode are not
   independent) and the error before and after on the report windows, broken down by condition.

The cost: each channel's mean squared residual (position, heading, speed) divided by the uncalibrated car's on
the fit windows, summed, so the uncalibrated car scores 3 on the fit windows and each channel weighs the same.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from common.car_calibration import EFFECTS, CarCalibration
from sim.calibration.logs import Trajectory
from sim.calibration.replay import Replayer, Windows, make_windows, residuals

log = logging.getLogger(__name__)

PENALTY_PER_PARAM = 0.02
"""An effect must cut the held-out cost by more than this fraction of it per parameter it adds."""
MAX_FIT_WINDOWS = 400
"""Windows used to fit parameters (and as many to choose effects): evenly spread over the episodes."""
MAX_NFEV = 40
"""Cost evaluations allowed per fit."""


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
    keys: list[tuple[str, str]], x: np.ndarray, err: np.ndarray | None, fixed: dict[str, dict[str, float]]
) -> CarCalibration:
    values: dict[str, dict[str, float]] = {k: dict(v) for k, v in fixed.items()}
    stderr: dict[str, dict[str, float]] = {}
    for i, (e, p) in enumerate(keys):
        spec = EFFECTS[e].params[p]
        values.setdefault(e, {})[p] = float(np.clip(x[i], spec.low, spec.high))
        if err is not None:
            stderr.setdefault(e, {})[p] = float(err[i])
    return CarCalibration.from_values(values, stderr if err is not None else None)


def fit_effects(
    objective: Objective, effects: list[str], start: CarCalibration | None = None, free: list[str] | None = None
) -> Fit:
    """Least-squares fit of the parameters of the ``free`` effects (default: all of ``effects``, jointly) on the
    objective's windows; the others keep their values in ``start``."""
    start = start or CarCalibration()
    free = effects if free is None else free
    fixed = {e.name: e.params for e in start.effects if e.name in effects and e.name not in free}
    keys = _param_keys(free)
    specs = [EFFECTS[e].params[p] for e, p in keys]
    started = {e.name for e in start.effects}
    x0 = np.array([start.value(e, p) if e in started else s.start for (e, p), s in zip(keys, specs, strict=True)])
    lo, hi = np.array([s.low for s in specs]), np.array([s.high for s in specs])
    x0 = np.clip(x0, lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))

    def calibration(x: np.ndarray, err: np.ndarray | None = None) -> CarCalibration:
        return _to_calibration(keys, x, err, fixed)

    def fun(x: np.ndarray) -> np.ndarray:
        return objective.vector(objective.residual(calibration(x)))

    # Finite-difference steps of a tenth of each parameter's typical size: much smaller steps would see
    # MuJoCo's contact solver rather than the trend. Tolerances of 1e-3: the data do not support more digits.
    steps = np.array([0.1 * s.scale for s in specs]) / np.maximum(1.0, np.abs(x0))
    sol = least_squares(
        fun,
        x0,
        bounds=(lo, hi),
        x_scale=[s.scale for s in specs],
        diff_step=steps,
        max_nfev=MAX_NFEV,
        method="trf",
        ftol=1e-3,
        xtol=1e-3,
        gtol=1e-4,
    )
    err = _cluster_stderr(sol.jac, sol.fun, objective.clusters())
    return Fit(calibration(sol.x, err), float(2 * sol.cost), int(sol.nfev))


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


def select_effects(
    fit_obj: Objective,
    sel_obj: Objective,
    candidates: list[str] | None = None,
    progress: Callable[[str], None] = log.info,
) -> tuple[CarCalibration, list[Round]]:
    """Forward selection of effects by held-out cost (see the module docstring); returns the calibration."""
    remaining = list(candidates or EFFECTS)
    chosen: list[str] = []
    current = CarCalibration()
    current_cost = sel_obj.cost(current)
    rounds: list[Round] = []
    while remaining:
        tried = []
        for name in remaining:
            # Screening: fit only the candidate's parameters, the chosen effects held at their values.
            fit = fit_effects(fit_obj, [*chosen, name], current, free=[name])
            tried.append(
                {
                    "name": name,
                    "select_cost": sel_obj.cost(fit.calibration),
                    "fit_cost": fit.cost,
                    "nfev": fit.nfev,
                    "calibration": fit.calibration,
                }
            )
            progress(f"  try {name:20s} held-out cost {tried[-1]['select_cost']:.3f} (now {current_cost:.3f})")
        best = min(tried, key=lambda t: t["select_cost"])
        n_params = len(EFFECTS[best["name"]].params)
        keep = best["select_cost"] < current_cost * (1 - PENALTY_PER_PARAM * n_params)
        rounds.append(Round([_public(t) for t in tried], best["name"] if keep else None, current_cost))
        if not keep:
            break
        chosen.append(best["name"])
        remaining.remove(best["name"])
        # Then all chosen effects are refitted together: a new effect changes what the others should be.
        joint = fit_effects(fit_obj, chosen, best["calibration"])
        current, current_cost = joint.calibration, sel_obj.cost(joint.calibration)
        progress(f"chose {best['name']}: held-out cost {current_cost:.3f} after a joint refit")
    current, current_cost = _prune(current, current_cost, sel_obj, progress)
    return current, rounds


def _prune(
    cal: CarCalibration, cost: float, sel_obj: Objective, progress: Callable[[str], None]
) -> tuple[CarCalibration, float]:
    """Drop chosen effects that no longer pay after the joint refits (the others may now explain what they did)."""
    for effect in list(cal.effects):
        without = CarCalibration(effects=[e for e in cal.effects if e.name != effect.name])
        cost_without = sel_obj.cost(without)
        if cost < cost_without * (1 - PENALTY_PER_PARAM * len(effect.params)):
            continue
        progress(f"dropped {effect.name}: held-out cost {cost_without:.3f} without it ({cost:.3f} with)")
        cal, cost = without, cost_without
    return cal, cost


def _public(tried: dict) -> dict:
    cal: CarCalibration = tried["calibration"]
    return {
        "name": tried["name"],
        "select_cost": round(tried["select_cost"], 5),
        "fit_cost": round(tried["fit_cost"], 5),
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


def score(calibration: CarCalibration, trajectories: list[Trajectory], replayer: Replayer | None = None) -> Result:
    """Error before (uncalibrated car) and after (with ``calibration``) on all windows of ``trajectories``."""
    replayer = replayer or Replayer()
    windows = make_windows(trajectories)
    meas = windows.measured()
    before, after = replayer.replay(windows), replayer.replay(windows, calibration)
    res_b, res_a = residuals(before, meas), residuals(after, meas)
    report = {
        "effects": [e.model_dump(exclude_none=True) for e in calibration.effects],
        "error_before": error_summary(res_b),
        "error_after": error_summary(res_a),
        "evaluated_on": sources(trajectories),
        "windows_evaluated": len(windows),
        "window_s": round(windows.horizon * windows.period_s, 4),
        "breakdown_before": breakdown(res_b, windows),
        "breakdown_after": breakdown(res_a, windows),
    }
    report["reduction"] = {
        k: _reduction(report["error_before"][k], report["error_after"][k])
        for k in ("position_m", "heading_deg", "speed_mps")
    }
    return Result(calibration, report, windows, {"measured": meas, "before": before, "after": after})


def _reduction(before: float, after: float) -> float:
    """Fraction of the error removed (1 = all of it, negative = worse)."""
    return round(1 - after / before, 4) if before > 0 else 0.0


def calibrate(
    trajectories: list[Trajectory],
    candidates: list[str] | None = None,
    max_windows: int = MAX_FIT_WINDOWS,
    progress: Callable[[str], None] = log.info,
) -> Result:
    """Choose and fit the effects on part of the episodes; score before and after on episodes it did not use."""
    parts = split_episodes(trajectories)
    if not all(parts.values()):
        raise ValueError(f"need at least 4 usable episodes to fit, choose and report apart; got {len(trajectories)}")
    replayer = Replayer()
    fit_w = spread(make_windows(parts["fit"], stride=5), max_windows)
    sel_w = spread(make_windows(parts["select"], stride=5), max_windows)
    scales = channel_scales(residuals(replayer.replay(fit_w), fit_w.measured()))
    progress(f"fit on {len(fit_w)} windows, choose on {len(sel_w)}; uncalibrated fit cost 3.000")
    cal, rounds = select_effects(
        Objective(replayer, fit_w, scales), Objective(replayer, sel_w, scales), candidates, progress
    )
    result = score(cal, parts["report"], replayer)
    result.report.update(
        {
            "fit_on": sources(parts["fit"]),
            "selected_on": sources(parts["select"]),
            "selection": [
                {"cost_before": round(r.cost_before, 5), "chosen": r.chosen, "candidates": r.candidates} for r in rounds
            ],
            "windows_fit": len(fit_w),
            "windows_selected_on": len(sel_w),
        }
    )
    return result
