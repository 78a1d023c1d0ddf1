"""Is what a calibration leaves over noise or structure, and where does it concentrate?

:func:`residual_structure` reads the residuals of replayed windows (``sim.calibration.replay.residuals``:
simulated minus measured) and points at the conditions under which the model is still wrong in one
direction: the user's pointer to an effect the library lacks.

The per-window error
--------------------
Each row's position error is turned into the car's frame along the measured path *at that row* (its measured
heading): ``along_track_m`` (+ = the model is ahead of the car) and ``cross_track_m`` (+ = the model is left of
the car's path). The row's own heading rather than the one at the window start, because in a 1 s window of a
30° turn a DeepRacer turns by well over 90°, and the start frame would mix along- and cross-track errors.
``heading_deg`` (+ = the model points further left, counter-clockwise) and ``speed_mps`` (+ = the model is
faster) are taken as they are. A window's error in a channel is the mean over its H rows: it uses all rows
(measurement noise averages down), and keeps half the end value of an error that grows over the window.

Bins
----
Windows are put in bins by condition, from the commands (the things a user can relate to an effect):

- turn: ``turning left`` / ``turning right`` (mean steering command above 5° / below -5°),
  ``going straight``, and ``turning (either way)``;
- speed: ``slow`` / ``medium speed`` / ``fast``, the thirds of the mean speed command over the windows
  given (speeds differ between cars too much for fixed bands);
- acceleration: ``accelerating`` / ``slowing`` / ``steady``: the mean speed command above / below the window's
  first measured speed (``Windows.measured()``) by more than 0.2 m/s (as ``sim.calibration.fit.conditions``);
- steering change: ``steering swings left`` / ``right`` / ``(either way)`` / ``steering held``: the window's
  mean steering command minus the command of the row before it, beyond ±10° (where a lag or a rate limit
  shows);
- the crosses speed × turn, acceleration × turn and speed × steering change, and all windows together.

Bins "either way" fold the sign: heading and cross-track errors are multiplied by the turn's (or the swing's)
direction, +1 left and -1 right, so that a symmetric effect (a steering gain: the model turns more than the car
both ways) adds up over left and right instead of cancelling, and its sign reads as "toward the turn".

Tests
-----
Windows of one episode are not independent (they share the car's state, battery, surface, and overlap when
the stride is shorter than a window), so every test treats episodes as the independent units (clusters):

- per bin and channel, the mean error with a CR2 cluster-robust standard error (Bell & McCaffrey) and a t
  reference whose degrees of freedom are the Satterthwaite approximation under two working models (windows of
  an episode independent; or all equal), the smaller of the two. With Bonferroni's small per-test levels the
  tail of the reference matters: a bin whose windows come mostly from one or two episodes has about one or two
  degrees of freedom, not G - 1, and a plain t(G - 1) reference would flag noise there. Bins with fewer than
  :data:`MIN_EPISODES` episodes are not tested.
- per channel, a regression of the window error on the condition features (steering, |steering|, speed,
  steering × centred speed, speed change asked for, steering change; and a constant) with CR1 cluster-robust
  covariance, and the Wald test that all coefficients are zero, scaled as Hotelling's T² and referred to
  F(k, G_eff - k), where G_eff is one more than the degrees of freedom of the all-windows mean (conservative
  for episodes of uneven length). The bins localise; this test catches a dependence spread thinly over all
  windows, and its per-feature t values are in ``tests``.

``structured`` is true when any of these tests is significant after Bonferroni's correction over all of them
(about 136: 33 bins × 4 channels and 4 regressions). ``z_max`` is the family's threshold as a two-sided normal
quantile: the default 2.576 aims at a false-alarm rate of at most 1 % when the residual is noise. The tests are
positively correlated (nested bins), so Bonferroni is conservative: on synthetic noise (white; random walks
within windows with episode offsets, spread that grows with speed and steering, heavy tails; overlapping
windows; 8 to 40 episodes of uneven length; 600 data sets of each of five kinds) at most 0.5 % were flagged (0
to 3 of 600 per kind), and at most 4.2 % at a nominal 10 % (``z_max`` 1.645). The per-bin t tests alone are
conservative in the far tail (simulated: 0.0 to 0.9 of the nominal rate at p = 1e-4). A sign-flip (wild cluster)
bootstrap of the largest t would spend the 1 % more fully, but it cannot reach 1 % at all with fewer than 8
episodes, and costs hundreds of passes.

A whiteness check (a Ljung–Box-type Q of the first-row residuals over the windows of an episode in time order,
lags 1 to 5 windows) is reported in ``tests`` but does not decide ``structured``: autocorrelation across windows
says there is a slowly varying state the model lacks, but not which; at its 1 % level (per channel, Bonferroni
over the four) it rejected 0.8 to 1.7 % of white-noise data sets, and nearly all of those with per-episode
offsets (real autocorrelation, which the bins count as noise between episodes).
"""

from __future__ import annotations

import functools
import math
from dataclasses import KW_ONLY, dataclass

import numpy as np
from scipy import stats
from scipy.special import ndtri_exp, stdtr

from sim.calibration.replay import Windows

Z_MAX = 2.576
"""Default family threshold: a two-sided normal quantile; 2.576 aims at <= 1 % false alarms under noise."""
MIN_EPISODES = 5
"""Fewest episodes (clusters) a bin needs to be tested."""
MAX_WHERE = 6
"""Most entries in ``where``."""
MAX_WHERE_PER_CHANNEL = 3
"""Most entries of one channel in ``where``, so that a second effect is not crowded out by one effect's bins."""
TURN_DEG = 5.0
"""A window whose mean steering command is beyond this is a turn, degrees."""
SWING_DEG = 10.0
"""A window whose mean steering command differs from the command before it by more than this swings, degrees."""
ACCEL_MPS = 0.2
"""A window whose mean speed command differs from its first measured speed by more than this accelerates, m/s."""
WHITENESS_LAGS = 5
"""Lags of the whiteness check (in windows of an episode)."""

CHANNELS = ("heading_deg", "cross_track_m", "along_track_m", "speed_mps")
_LATERAL = ("heading_deg", "cross_track_m")  # the channels whose sign depends on the turn's direction


@dataclass(frozen=True)
class _Part:
    """One condition of a bin: its split, label, definition, phrase key, windows and fold direction."""

    split: str
    key: str
    label: str
    definition: str
    mask: np.ndarray
    _: KW_ONLY
    direction: np.ndarray | None = None
    """+1 / -1 per window for a folded ("either way") condition."""


@dataclass(frozen=True)
class _Bin:
    split: str
    parts: tuple[_Part, ...]
    mask: np.ndarray
    direction: np.ndarray | None


# ------------------------------------------------------------------------------------------------ public


def residual_structure(res: dict[str, np.ndarray], windows: Windows, *, z_max: float = Z_MAX) -> dict:
    """Whether the residual ``res`` of ``windows`` (``replay.residuals``: (W, H) ``dx``, ``dy``, ``dheading``,
    ``dspeed``, simulated minus measured) is noise or structure, and where it concentrates.

    Returns a JSON-ready dict: ``structured`` (bool), ``where`` (at most :data:`MAX_WHERE` significant bins,
    most significant first: channel, condition, split, definition, mean error, cluster-robust t, windows,
    episodes, the family-adjusted z, and a sentence) and ``tests`` (the threshold, the regression and whiteness
    tests). ``z_max``: the family threshold (two-sided normal quantile); see the module docstring."""
    rows = window_rows(res, windows)
    err = {c: np.nanmean(v, axis=1) for c, v in rows.items()}
    clusters = windows.episode_keys()
    feats = _features(windows)
    # Episodes of uneven length count as fewer: the regression's reference uses the all-windows mean's df + 1.
    sizes = np.unique(clusters, return_counts=True)[1]
    g_eff = _satterthwaite(sizes) + 1 if len(sizes) >= MIN_EPISODES else 0.0

    bins = _bins(feats)
    found = []
    for b in bins:
        for c in CHANNELS:
            e = err[c] if b.direction is None or c not in _LATERAL else err[c] * b.direction
            ok = b.mask & np.isfinite(e)
            test = _mean_test(e[ok], clusters[ok])
            if test:
                found.append({"bin": b, "channel": c, **test})
    regressions = {c: _regression(err[c], feats, clusters, g_eff) for c in CHANNELS}
    n_tests = len(found) + sum(r.get("log_p") is not None for r in regressions.values())
    for f in found:
        f["z"] = _adjusted_z(f["log_p"], n_tests)
    for r in regressions.values():
        if r.get("log_p") is not None:
            r["z"] = _adjusted_z(r.pop("log_p"), n_tests)
            r["significant"] = bool(r["z"] > z_max)
            r["z"] = round(r["z"], 2)
    flagged = [f for f in found if f["z"] > z_max]
    structured = bool(flagged) or any(r.get("significant", False) for r in regressions.values())
    where = _where(flagged, regressions)
    return {
        "structured": structured,
        "where": where,
        "tests": {
            "z_max": float(z_max),
            "false_alarm_rate": _sig(2 * stats.norm.sf(z_max)),
            "tests": int(n_tests),
            "per_test_p": _sig(2 * stats.norm.sf(z_max) / max(n_tests, 1)),
            "windows": len(windows),
            "episodes": len(np.unique(clusters)),
            "bins_tested": len({id(f["bin"]) for f in found}),
            "bins_skipped": len(bins) - len({id(f["bin"]) for f in found}),
            "min_episodes": MIN_EPISODES,
            "window_error": "mean over the window's rows; position along / across the measured path at each row",
            "regression": regressions,
            "whiteness": {c: _whiteness(rows[c][:, 0], windows) for c in CHANNELS},
        },
    }


def window_rows(res: dict[str, np.ndarray], windows: Windows) -> dict[str, np.ndarray]:
    """(W, H) per-row errors in the car's frame along the measured path: ``heading_deg``, ``cross_track_m``
    (+ = the model left of the car), ``along_track_m`` (+ = the model ahead); and ``speed_mps`` (+ = faster) as
    ``res["dspeed"]`` has it (H columns, or fewer where speeds span several rows)."""
    dx, dy = np.asarray(res["dx"], float), np.asarray(res["dy"], float)
    shape = (len(windows), windows.horizon)
    for k in ("dx", "dy", "dheading"):
        if np.shape(res[k]) != shape:
            raise ValueError(f"residual {k!r} has shape {np.shape(res[k])}, expected {shape} (windows, horizon)")
    # Speeds may be measured over several rows (replay.SPEED_ROWS): fewer columns, one row per window still.
    speed_shape = np.shape(res["dspeed"])
    if len(speed_shape) != 2 or speed_shape[0] != len(windows) or not 1 <= speed_shape[1] <= windows.horizon:
        raise ValueError(f"residual 'dspeed' has shape {speed_shape}, expected ({len(windows)}, 1 to {shape[1]})")
    h = windows.measured()["heading"][:, 1:]  # the measured heading at each residual's row
    cos, sin = np.cos(h), np.sin(h)
    return {
        "heading_deg": np.asarray(res["dheading"], float),
        "cross_track_m": -sin * dx + cos * dy,
        "along_track_m": cos * dx + sin * dy,
        "speed_mps": np.asarray(res["dspeed"], float),
    }


# ------------------------------------------------------------------------------------------------ conditions


def _features(windows: Windows) -> dict[str, np.ndarray]:
    """Per window: mean steering and speed commands, speed change asked for, steering swing."""
    steer, speed = windows.commands()
    v0 = windows.measured()["speed"][:, 0]
    before = np.array(
        [windows.trajectories[t].steer_cmd_deg[max(k - 1, 0)] for t, k in zip(windows.traj, windows.start, strict=True)]
    )
    return {
        "steer": steer.mean(axis=1),
        "abs_steer": np.abs(steer).mean(axis=1),
        "speed": speed.mean(axis=1),
        "dv": speed.mean(axis=1) - v0,
        "swing": steer.mean(axis=1) - before,
    }


def _bins(f: dict[str, np.ndarray]) -> list[_Bin]:
    """The bins tested: each condition alone, the chosen crosses, and all windows."""
    turn, speed, accel, swing = _turn_parts(f), _speed_parts(f), _accel_parts(f), _swing_parts(f)
    everything = np.ones(len(f["steer"]), bool)
    bins = [_Bin("all", (), everything, None)]
    bins += [_Bin(p.split, (p,), p.mask, p.direction) for p in [*turn, *speed, *accel, *swing]]
    ends = [p for p in speed if p.key != "medium"]  # the crosses use the extreme thirds only: fewer tests
    bins += _cross("speed × turn", ends, turn)
    bins += _cross("acceleration × turn", [p for p in accel if p.key != "steady"], turn)
    bins += _cross("speed × steering change", ends, [p for p in swing if p.key == "either"])
    return bins


def _cross(split: str, first: list[_Part], second: list[_Part]) -> list[_Bin]:
    return [_Bin(split, (a, b), a.mask & b.mask, b.direction) for a in first for b in second]


def _signed_parts(
    split: str, value: np.ndarray, threshold: float, what: str, names: tuple[str, str, str, str]
) -> list[_Part]:
    """Left (value > threshold), right (< -threshold), neither, and either way with heading and cross-track errors
    signed toward the side: ``names`` are the labels of the four (left, right, neither, either)."""
    left, right = value > threshold, value < -threshold
    return [
        _Part(split, "left", names[0], f"{what} > {threshold:g}°", left),
        _Part(split, "right", names[1], f"{what} < -{threshold:g}°", right),
        _Part(split, names[2].split()[-1], names[2], f"|{what}| <= {threshold:g}°", ~(left | right)),
        _Part(
            split,
            "either",
            names[3],
            f"|{what}| > {threshold:g}°; heading and cross-track errors signed toward the "
            + ("turn" if split == "turn" else "swing"),
            left | right,
            direction=np.sign(value),
        ),
    ]


def _turn_parts(f: dict[str, np.ndarray]) -> list[_Part]:
    names = ("turning left", "turning right", "going straight", "turning (either way)")
    return _signed_parts("turn", f["steer"], TURN_DEG, "mean steering command", names)


def _speed_parts(f: dict[str, np.ndarray]) -> list[_Part]:
    v = f["speed"]
    if np.ptp(v) < 0.1:  # one speed: no bands to compare
        return []
    lo, hi = np.quantile(v, [1 / 3, 2 / 3])
    slow, fast = v <= lo, v >= hi
    if lo == hi:  # more than a third of the windows at one speed: keep the bands apart
        fast = v > hi
        if not fast.any():
            slow, fast = v < lo, v >= lo
    return [
        _Part("speed", "slow", "slow", f"mean speed command <= {lo:.2f} m/s (slowest third)", slow),
        _Part("speed", "medium", "medium speed", f"mean speed command {lo:.2f}–{hi:.2f} m/s", ~(slow | fast)),
        _Part("speed", "fast", "fast", f"mean speed command >= {hi:.2f} m/s (fastest third)", fast),
    ]


def _accel_parts(f: dict[str, np.ndarray]) -> list[_Part]:
    dv = f["dv"]
    up, down = dv > ACCEL_MPS, dv < -ACCEL_MPS
    what = "mean speed command minus the first measured speed"
    return [
        _Part("acceleration", "accelerating", "accelerating", f"{what} > {ACCEL_MPS:g} m/s", up),
        _Part("acceleration", "slowing", "slowing", f"{what} < -{ACCEL_MPS:g} m/s", down),
        _Part("acceleration", "steady", "steady", f"|{what}| <= {ACCEL_MPS:g} m/s", ~(up | down)),
    ]


def _swing_parts(f: dict[str, np.ndarray]) -> list[_Part]:
    names = ("steering swings left", "steering swings right", "steering held", "steering swings (either way)")
    what = "mean steering command minus the command before the window"
    return _signed_parts("steering change", f["swing"], SWING_DEG, what, names)


# ------------------------------------------------------------------------------------------------ statistics


def _mean_test(e: np.ndarray, clusters: np.ndarray) -> dict | None:
    """Mean of ``e`` with a CR2 cluster-robust t and Satterthwaite degrees of freedom; None if too few clusters."""
    _, inv = np.unique(clusters, return_inverse=True)
    n_c = np.bincount(inv).astype(float)
    if len(n_c) < MIN_EPISODES:
        return None
    n, mean = len(e), float(np.mean(e))
    s_c = np.bincount(inv, weights=e - mean)
    # CR2 for a mean: each cluster's sum scaled by (1 - its leverage n_c / n)^(-1/2).
    w = 1.0 / ((1.0 - n_c / n) * n**2)
    se = math.sqrt(float(np.sum(w * s_c**2)))
    df = _satterthwaite(n_c)
    # se is 0 only where every window is alike (hand-made data): no noise to compare with.
    t = mean / se if se > 0 else (0.0 if mean == 0 else math.copysign(1e6, mean))
    t = max(-1e6, min(1e6, t))
    return {"mean": mean, "t": t, "df": df, "log_p": _t_log_p(t, df), "windows": n, "episodes": len(n_c)}


def _sig(v: float, digits: int = 4) -> float:
    """A plain float with ``digits`` significant digits, for the report."""
    return float(f"{float(v):.{digits}g}")


def _t_log_p(t: float, df: float) -> float:
    """log of the two-sided p-value of t under Student's t with df degrees of freedom."""
    p = 2.0 * float(stdtr(df, -abs(t)))  # the lower tail keeps its precision far out (scipy.stats is slower)
    log_p = math.log(p) if p > 0 else math.log(2.0) + float(stats.t.logsf(abs(t), df))
    return min(log_p, 0.0)


@functools.lru_cache(maxsize=256)
def _satterthwaite_cached(sizes: tuple[float, ...]) -> float:
    n_c = np.array(sizes)
    n = n_c.sum()
    w = 1.0 / ((1.0 - n_c / n) * n**2)
    m = np.diag(n_c) - np.outer(n_c, n_c) / n  # cluster sums of the centred data, per unit of each cluster value
    dfs = []
    for cov in (m, m @ m.T):  # windows independent (m is also their covariance); one value per episode
        b = np.sqrt(w)[:, None] * cov * np.sqrt(w)[None, :]
        dfs.append(float(np.trace(b) ** 2 / np.sum(b * b)))
    return max(1.0, min(dfs))


def _satterthwaite(n_c: np.ndarray) -> float:
    """Degrees of freedom of the CR2 variance of a mean (Bell & McCaffrey), the smaller under two working
    models: windows independent, or the windows of an episode all equal (one value per episode). Depends on the
    episodes' window counts only, so the channels of a bin share it."""
    return _satterthwaite_cached(tuple(float(v) for v in n_c))


def _adjusted_z(log_p: float, n_tests: int) -> float:
    """The Bonferroni-adjusted p-value as a two-sided normal quantile (0 when not below 1)."""
    log_adj = log_p + math.log(max(n_tests, 1))
    if log_adj >= 0:
        return 0.0
    return float(min(-ndtri_exp(log_adj - math.log(2.0)), 1e6))


_FEATURES = {
    "steer": ("steering (+ left)", lambda f: f["steer"]),
    "abs_steer": ("|steering|", lambda f: f["abs_steer"]),
    "speed": ("speed command", lambda f: f["speed"]),
    # Speed centred first: the raw product is nearly steering again (speed > 0), and the two would share one
    # direction, inflating both standard errors.
    "steer_x_speed": ("steering × speed", lambda f: f["steer"] * (f["speed"] - f["speed"].mean())),
    "dv": ("speed-up asked for", lambda f: f["dv"]),
    "swing": ("steering change (+ left)", lambda f: f["swing"]),
}


def _design(feats: dict[str, np.ndarray]) -> tuple[np.ndarray, list[str]]:
    """Constant and standardized features, dropping any that adds no new direction (a log at one speed)."""
    cols, names = [np.ones(len(feats["steer"]))], ["constant"]
    for name, (_, get) in _FEATURES.items():
        x = np.asarray(get(feats), float)
        sd = float(np.std(x))
        if sd < 1e-9:
            continue
        trial = np.column_stack([*cols, (x - x.mean()) / sd])
        if np.linalg.matrix_rank(trial, tol=1e-6 * math.sqrt(len(x))) == trial.shape[1]:
            cols, names = list(trial.T), [*names, name]
    return np.column_stack(cols), names


def _regression(e: np.ndarray, feats: dict[str, np.ndarray], clusters: np.ndarray, g_eff: float) -> dict:
    """Cluster-robust (CR1) regression of the window error on the features and a constant, with the Wald test
    that all coefficients are zero, scaled as Hotelling's T² and referred to F(k, G_eff - k)."""
    ok = np.isfinite(e)
    x, names = _design({k: v[ok] for k, v in feats.items()})
    e, cl = e[ok], clusters[ok]
    _, inv = np.unique(cl, return_inverse=True)
    n, k = x.shape
    g = int(inv.max()) + 1 if n else 0
    if g_eff - k < 3 or g < k + 3:
        return {"skipped": f"too few episodes ({g}) for {k} regressors"}
    beta, *_ = np.linalg.lstsq(x, e, rcond=None)
    r = e - x @ beta
    bread = np.linalg.pinv(x.T @ x)
    u = np.stack([np.bincount(inv, weights=x[:, j] * r, minlength=g) for j in range(k)], axis=1)
    vcov = bread @ (u.T @ u) @ bread * (g / (g - 1)) * ((n - 1) / (n - k))
    se = np.sqrt(np.maximum(np.diag(vcov), 0.0))
    t = np.divide(beta, se, out=np.zeros_like(beta), where=se > 0)
    wald = float(beta @ np.linalg.pinv(vcov) @ beta)
    # Hotelling's scaling: exact for normal, identically distributed episode scores; with G_eff (episodes of
    # uneven length count as fewer) it stays conservative where a few long episodes dominate.
    df2 = g_eff - k
    f_stat = wald * df2 / (k * (g_eff - 1))
    log_p = float(stats.f.logsf(f_stat, k, df2)) if np.isfinite(f_stat) else -math.inf
    return {
        "features": names,
        "coef_per_sd": [_sig(b) for b in beta],
        "t": [round(float(v), 2) for v in t],
        "wald": _sig(wald),
        "f": _sig(f_stat),
        "df": [int(k), round(float(df2), 2)],
        "windows": int(n),
        "episodes": g,
        "log_p": min(log_p, 0.0),
    }


def _whiteness(first: np.ndarray, windows: Windows) -> dict:
    """Ljung–Box-type check of the first-row residuals over the windows of each episode in start order: per lag
    L, the self-normalized sum of products of centred values L windows apart (robust to uneven noise)."""
    ok = np.isfinite(first)
    a = np.where(ok, first - np.nanmean(first), np.nan)
    keys = windows.episode_keys()
    order = np.lexsort((windows.start, keys))
    a, keys = a[order], keys[order]
    lags, rho, z = [], [], []
    denom = float(np.nansum(a**2))
    for lag in range(1, WHITENESS_LAGS + 1):
        same = keys[lag:] == keys[:-lag]
        prod = (a[lag:] * a[:-lag])[same]
        prod = prod[np.isfinite(prod)]
        if len(prod) < 10 or denom == 0:
            break
        lags.append(lag)
        rho.append(round(float(prod.sum() / denom), 3))
        z.append(float(prod.sum() / math.sqrt(float(np.sum(prod**2)))) if np.any(prod) else 0.0)
    if not lags:
        return {"skipped": "fewer than 10 pairs of consecutive windows within episodes"}
    q = float(np.sum(np.square(z)))
    p = float(stats.chi2.sf(q, len(lags)))
    return {"lags": lags, "autocorrelation": rho, "q": _sig(q), "p": _sig(p), "white": bool(p > 0.01 / len(CHANNELS))}


# ------------------------------------------------------------------------------------------------ reporting


def _where(flagged: list[dict], regressions: dict[str, dict]) -> list[dict]:
    """Where the residual concentrates: every flagged channel's most significant entry first (a bin; or, where
    only the regression flags a channel, its strongest feature), then the next most significant bins, at most
    :data:`MAX_WHERE_PER_CHANNEL` per channel and :data:`MAX_WHERE` in all. By the family-adjusted z (which
    orders as |t| does among tests of equal degrees of freedom), then |t|."""
    entries = [_bin_entry(f) for f in flagged]
    have = {e["channel"] for e in entries}
    entries += [_regression_entry(c, r) for c, r in regressions.items() if r.get("significant") and c not in have]
    entries.sort(key=lambda e: (-e["z"], -abs(e["t"])))
    firsts = [next(e for e in entries if e["channel"] == c) for c in dict.fromkeys(e["channel"] for e in entries)]
    out = firsts[:MAX_WHERE]
    for e in entries:
        if len(out) >= MAX_WHERE:
            break
        if e not in out and sum(o["channel"] == e["channel"] for o in out) < MAX_WHERE_PER_CHANNEL:
            out.append(e)
    return sorted(out, key=lambda e: (-e["z"], -abs(e["t"])))


def _bin_entry(f: dict) -> dict:
    b: _Bin = f["bin"]
    return {
        "channel": f["channel"],
        "condition": ", ".join(p.label for p in b.parts) or "all windows",
        "split": b.split,
        "definition": "; ".join(p.definition for p in b.parts) or "every window",
        "mean": _sig(f["mean"]),
        "t": round(f["t"], 2),
        "z": round(f["z"], 2),
        "windows": int(f["windows"]),
        "episodes": int(f["episodes"]),
        "says": _says(f["channel"], f["mean"], b.parts),
    }


def _regression_entry(channel: str, r: dict) -> dict:
    """The regression's strongest coefficient, for a channel no single bin flags."""
    j = int(np.argmax(np.abs(r["t"])))
    name = r["features"][j]
    coef = r["coef_per_sd"][j]
    return {
        "channel": channel,
        "condition": _FEATURES[name][0] if name in _FEATURES else "all windows",
        "split": "regression",
        "definition": "change of the window error per standard deviation of the feature (all windows)",
        "mean": coef,
        "t": r["t"][j],
        "z": r["z"],
        "windows": int(r["windows"]),
        "episodes": int(r["episodes"]),
        "says": _says_trend(channel, coef, name),
    }


_TURN_NOUN = {"left": "left turns", "right": "right turns", "either": "turns"}
_SPEED_ADJ = {"slow": "slow", "medium": "medium-speed", "fast": "fast"}
_AT_SPEED = {"slow": "at low speed", "medium": "at medium speed", "fast": "at high speed"}
_ACCEL = {"accelerating": "when accelerating", "slowing": "when slowing", "steady": "at steady speed"}
_SWING = {
    "left": "when the steering swings left",
    "right": "when the steering swings right",
    "either": "when the steering swings",
    "held": "while the steering is held",
}


def _phrase(parts: tuple[_Part, ...]) -> str:
    """Where, in words: 'in fast left turns', 'when accelerating', 'on straights while slowing'."""
    by = {p.split: p.key for p in parts}
    turn, speed, accel, swing = (by.get(s) for s in ("turn", "speed", "acceleration", "steering change"))
    if turn:
        adj = f"{_SPEED_ADJ[speed]} " if speed else ""
        text = f"on {adj}straights" if turn == "straight" else f"in {adj}{_TURN_NOUN[turn]}"
        return text + (f" {_ACCEL[accel].replace('when', 'while')}" if accel else "")
    if swing:
        return _SWING[swing] + (f" {_AT_SPEED[speed]}" if speed else "")
    if speed:
        return _AT_SPEED[speed]
    if accel:
        return _ACCEL[accel]
    return "everywhere"


def _says(channel: str, mean: float, parts: tuple[_Part, ...]) -> str:
    """One sentence reading the sign of a bin's mean error (simulated minus measured) for the car."""
    where = _phrase(parts)
    by = {p.split: p.key for p in parts}
    turn, swing = by.get("turn"), by.get("steering change")
    # Direction of the bin: +1 left, -1 right; folded bins were already multiplied by theirs.
    direction = {"left": 1, "right": -1, "either": 1}
    up = mean > 0
    if channel in _LATERAL and turn in direction:
        toward = direction[turn] * mean > 0  # the model's heading / path further toward the turn than the car's
        if channel == "heading_deg":
            return f"the car turns {'less' if toward else 'more'} than the model {where}"
        return f"the car {'runs wide of' if toward else 'cuts inside'} the model's path {where}"
    if channel in _LATERAL and swing in direction:
        toward = direction[swing] * mean > 0
        what, model = ("the car", "the model") if channel == "heading_deg" else ("the car's path", "the model's")
        return f"{what} follows steering changes {'less' if toward else 'more'} than {model} {where}"
    text = {
        "heading_deg": f"the car heads further {'right' if up else 'left'} than the model",
        "cross_track_m": f"the car drifts {'right' if up else 'left'} of the model's path",
        "along_track_m": f"the car {'falls behind' if up else 'gets ahead of'} the model",
        "speed_mps": f"the car is {'slower' if up else 'faster'} than the model",
    }[channel]
    return f"{text} {where}"


def _says_trend(channel: str, coef: float, feature: str) -> str:
    """One sentence reading a regression coefficient: how the car differs from the model as a feature grows."""
    up = coef > 0
    if channel in _LATERAL and feature in ("steer", "steer_x_speed", "swing"):
        # Features signed + left: a positive coefficient puts the model further left the further left the
        # command, i.e. further toward the turn (or swing) either way.
        more = "less" if up else "more"
        heading = channel == "heading_deg"
        model = "the model" if heading else "the model's"
        if feature == "steer":
            what = "the car turns" if heading else "the car's path curves"
            return f"{what} {more} than {model}, the more so the harder it steers"
        if feature == "steer_x_speed":
            what = "it turns" if heading else "its path curves"
            return f"the faster the car goes, the {more} {what} compared with {model}"
        what = "the car follows" if heading else "the car's path follows"
        return f"{what} steering changes {more} than {model}"
    if feature not in _FEATURES:
        return _says(channel, coef, ())
    moves = {
        "heading_deg": ("heads further right", "heads further left"),
        "cross_track_m": ("drifts further right", "drifts further left"),
        "along_track_m": ("falls further behind", "gets further ahead"),
        "speed_mps": ("is slower", "is faster"),
    }[channel]
    return f"relative to the model, the car {moves[0] if up else moves[1]} as the {_FEATURES[feature][0]} grows"
