"""The fastest line round a track for a car with measured limits, and its quasi-steady speed profile.

The line is the centre line moved sideways by an offset at each of N points 0.1 m apart, inside the corridor where
the car is still on the track by DeepRacer's rule: off track only when all four wheels are off, so the car's centre
may pass a border by half its wheel track less a safety margin. The offsets minimise the line's standing-start lap
time: ``v_curve(kappa)``, the highest speed at which the car holds the line's curvature (a smooth monotone cubic
through ``CarLimits.max_curvature``), then forward and backward passes at the car's equivalent constant
acceleration and braking, in closed form with a smooth minimum (``_soft_lap_time``). They are a periodic spline
through knots 0.4 m apart, with steep penalties for leaving the corridor and for curvature tighter than the car
turns; torch gives the gradient and scipy's L-BFGS-B does the search. The first point's offset is 0: a lap starts
where the env starts the car, on the centre line at waypoint 0.

The speed profile then applies the acceleration and braking limits with a forward and a backward pass (in a curve,
what the tyres have left beside turning: ``longitudinal_budget``). The lap time is a standing start from rest, as
racer's evaluator times a lap; the flying lap (periodic profile) is reported beside it. The optimiser's own profile
uses constant rates without that budget (its closed form needs them), so it shapes the line on a slightly faster
car than the one the reported profile is computed for.
"""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize

from sim.car_limits import CarLimits
from sim.geometry import curvature as closed_curvature
from sim.physics import TRACK_WIDTH_M
from sim.track import Track, TrackError

SPACING_M = 0.1
"""Distance between the line's points along the centre line, m."""
DEFAULT_MARGIN_M = 0.05
"""How far inside DeepRacer's off-track boundary (border + half the wheel track) the car's centre stays, m."""
KNOT_SPACING_M = 0.4
"""Distance between the knots of the offsets' spline, m: the shortest wiggle the line may have."""
CORRIDOR_PENALTY = 1e4
"""Cost per squared metre of leaving the corridor, s/m² (steep: the optimum stays inside)."""
CURVATURE_PENALTY = 1e2
"""Cost per point of a squared 1/m of curvature beyond the tightest the car holds at any speed, s·m². Steep, because
the exact profile slows to the table's lowest speed there: measured, without it the Gazebo car's line kept a short
stretch too tight for the car on reinvent_base, its profile crawled through it at 0.25 m/s, and the driven lap,
which simply took that bend a little wider, beat the "limit" by 5 %."""


@dataclass(frozen=True)
class Corridor:
    """The centre line resampled every ``SPACING_M`` and the offsets the line may take at each point."""

    s: np.ndarray
    """(N,) arc length along the centre line, m (the loop closes after the last point)."""
    center: np.ndarray
    """(N, 2) centre-line points, m."""
    normal: np.ndarray
    """(N, 2) unit normals pointing left of the direction of travel."""
    low: np.ndarray
    """(N,) most negative (rightward) offset allowed, m."""
    high: np.ndarray
    """(N,) most positive (leftward) offset allowed, m."""


@dataclass(frozen=True)
class RacingLine:
    """A line, its speed profile and its times (all SI)."""

    points: np.ndarray
    """(N, 2) positions, m; the lap closes back to the first."""
    offsets: np.ndarray
    """(N,) offsets from the centre line, m (+ = left)."""
    _: KW_ONLY
    ds: np.ndarray
    """(N,) length from point i to point i + 1 (the last one back to the first), m."""
    curvature: np.ndarray
    """(N,) signed curvature at each point, 1/m (+ = turning left)."""
    speed: np.ndarray
    """(N + 1,) standing-start speed profile at each point and at the finish (= the first point), m/s."""
    flying_speed: np.ndarray
    """(N,) speed profile of a flying lap, m/s."""
    lap_time: float
    """Standing-start lap time, s."""
    flying_lap_time: float
    """Flying lap time, s."""
    corridor: Corridor
    """Where the line may go (its offsets are measured from ``corridor.center`` along ``corridor.normal``)."""

    @property
    def length(self) -> float:
        """Length of the line, m."""
        return float(self.ds.sum())


def corridor(track: Track, margin: float = DEFAULT_MARGIN_M) -> Corridor:
    """The resampled centre line of a closed track and the offsets that keep a wheel on the track."""
    if not track.closed:
        raise TrackError(f"track {track.name!r} is not a loop: a lap-time limit needs a closed track")
    s_rows = track.cumulative
    length = float(s_rows[-1])
    n = max(int(round(length / SPACING_M)), 20)
    s = np.linspace(0.0, length, n, endpoint=False)
    center_spline = CubicSpline(s_rows, track.center, bc_type="periodic")
    center = center_spline(s)
    tangent = center_spline(s, 1)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    # Each border's offset along the normal at the waypoint rows, then along s: left and right of travel.
    row_normal = center_spline(s_rows, 1)
    row_normal = np.column_stack([-row_normal[:, 1], row_normal[:, 0]]) / np.linalg.norm(row_normal, axis=1)[:, None]
    inner = np.einsum("ij,ij->i", track.inner - track.center, row_normal)
    outer = np.einsum("ij,ij->i", track.outer - track.center, row_normal)
    left = np.interp(s, s_rows, np.maximum(inner, outer))
    right = np.interp(s, s_rows, -np.minimum(inner, outer))
    beyond = TRACK_WIDTH_M / 2 - margin  # the centre may pass the border until the last wheel leaves the track
    return Corridor(s=s, center=center, normal=normal, low=-(right + beyond), high=left + beyond)


def _spline_basis(s: np.ndarray, length: float, knot_spacing: float) -> np.ndarray:
    """(N, M) matrix B: offsets at the N points = B @ (offsets at M knots), a periodic cubic spline."""
    m = max(int(round(length / knot_spacing)), 8)
    knots = np.linspace(0.0, length, m + 1)
    basis = np.empty((len(s), m))
    for j in range(m):
        y = np.zeros(m + 1)
        y[j] = 1.0
        if j == 0:
            y[m] = 1.0  # periodic: the last knot is the first
        basis[:, j] = CubicSpline(knots, y, bc_type="periodic")(s)
    return basis


def optimise_line(cor: Corridor, limits: CarLimits, max_iter: int = 600) -> np.ndarray:
    """Offsets (N,) minimising the lap-time estimate inside the corridor; see the module doc.

    The offsets are a periodic cubic spline through knots ``KNOT_SPACING_M`` apart (a line a car can follow has
    no shorter wiggles, and curvature computed from it is free of point-to-point noise); leaving the corridor
    costs a steep quadratic penalty, and the final offsets are clipped into it."""
    import torch

    length = float(cor.s[-1] + (cor.s[1] - cor.s[0]))
    basis = _spline_basis(cor.s, length, KNOT_SPACING_M)
    b_t = torch.tensor(basis)
    center = torch.tensor(cor.center, dtype=torch.float64)
    normal = torch.tensor(cor.normal, dtype=torch.float64)
    low, high = torch.tensor(cor.low), torch.tensor(cor.high)
    kt, vt, dt = (torch.tensor(a) for a in _curve_speed_table(limits))
    accel, brake = _equivalent_rates(limits)

    def objective(x: np.ndarray) -> tuple[float, np.ndarray]:
        knots = torch.tensor(x, dtype=torch.float64, requires_grad=True)
        alpha = b_t @ knots
        q = center + alpha[:, None] * normal
        a = q - torch.roll(q, 1, 0)
        b = torch.roll(q, -1, 0) - q
        cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        na, nb, nab = a.norm(dim=1), b.norm(dim=1), (a + b).norm(dim=1)
        kappa = 2.0 * cross.abs() / (na * nb * nab).clamp_min(1e-12)
        v_curve = _interp_speed(kappa, kt, vt, dt)
        outside = torch.relu(alpha - high) + torch.relu(low - alpha)
        too_tight = torch.relu(kappa - kt[-1])  # the car holds no tighter curve at any speed
        cost = (
            _soft_lap_time(v_curve, nb, accel, brake)
            + CORRIDOR_PENALTY * (outside**2).sum()
            + CURVATURE_PENALTY * (too_tight**2).sum()
        )
        cost.backward()
        return float(cost.detach()), knots.grad.numpy().copy()

    bounds = [(None, None)] * basis.shape[1]
    bounds[0] = (0.0, 0.0)  # the lap starts where the env puts the car: on the centre line
    options = {"maxiter": max_iter, "ftol": 1e-12, "gtol": 1e-9}
    result = minimize(objective, np.zeros(basis.shape[1]), jac=True, method="L-BFGS-B", bounds=bounds, options=options)
    return np.clip(basis @ result.x, cor.low, cor.high)


SOFT_MIN_M2S2 = 0.02
"""Temperature of the smooth minimum in the optimiser's speed profile, m²/s² of squared speed: small enough that
the profile is the exact one's to ~1 %, large enough that its gradient is smooth for the line search."""


def _equivalent_rates(limits: CarLimits) -> tuple[float, float]:
    """The constant acceleration and braking (m/s²) that cover the same distance between rest and the top speed
    as the measured tables do: the optimiser's profile uses constants, for which its passes have a closed form."""
    v = np.linspace(0.05, limits.top_speed * 0.98, 200)
    rates = []
    for table in (limits.accel_at(v), limits.brake_at(v)):
        distance = float(np.trapezoid(v / np.maximum(table, 0.1), v))
        rates.append(float(v[-1] ** 2 / (2.0 * distance)))
    return rates[0], rates[1]


def _soft_lap_time(v_curve, ds, accel: float, brake: float):  # noqa: ANN001, ANN202 - torch tensors
    """Standing-start lap time (s) of a line whose points allow speeds ``v_curve`` (N,) with ``ds`` (N,) between
    them, under constant acceleration and braking: the forward and backward passes in closed form (the squared
    speed at i is the least over j of v_j² + 2 a |S_i - S_j| in the pass's direction), with a smooth minimum
    (``torch.logcumsumexp``) so that the lap time is differentiable in the line's shape, unlike the real passes.

    The lap time, not ``sum(ds / v_curve)``: the line minimising that sum asks for speeds the car cannot reach
    between bends (0.27 s slower on reinvent_base with the default car once braking and acceleration apply)."""
    import torch

    tau = SOFT_MIN_M2S2
    s = torch.cat([ds.new_zeros(1), torch.cumsum(ds, 0)])  # (N + 1,): the finish is the start again
    w = torch.cat([v_curve, v_curve[:1]]) ** 2
    w = torch.cat([w.new_zeros(1), w[1:]])  # a standing start: 0 m/s at point 0
    forward = 2 * accel * s - tau * torch.logcumsumexp(-(w - 2 * accel * s) / tau, 0)
    backward_terms = (w + 2 * brake * s).flip(0)
    backward = -2 * brake * s - tau * torch.logcumsumexp(-backward_terms / tau, 0).flip(0)
    u = -tau * torch.logsumexp(torch.stack([forward, backward]) / -tau, 0)
    v = u.clamp_min(1e-6).sqrt()
    return (2 * ds / (v[:-1] + v[1:])).sum()


def _curve_speed_table(limits: CarLimits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(curvature ascending, speed, slope dv/dkappa) knots of the optimiser's ``v_curve``: a C1 monotone cubic
    (PCHIP) through the measured table.

    The table is often flat over speed (the same largest curvature at 2.0 and 2.25 m/s, after it is made
    monotone); a piecewise-linear v(kappa) through such ties has a vertical cliff, on which scipy's line search
    fails ("ABNORMAL") within a few dozen iterations and leaves the line near the centre line: measured, the
    Gazebo car's line moved 7 cm at most in a corridor 0.8 m wide. Of tied curvatures the highest speed is kept
    (the car holds that curvature up to it), and the slope is 0 at the first knot, where the top speed's flat
    stretch begins."""
    from scipy.interpolate import PchipInterpolator

    kappa = np.asarray(limits.max_curvature, dtype=np.float64)[::-1]
    speed = np.minimum(np.asarray(limits.speeds, dtype=np.float64)[::-1], limits.top_speed)
    # Reversed, curvature ascends and speed descends: the first of each run of equal curvatures has the top speed.
    keep = np.concatenate([[True], np.diff(kappa) > 1e-9])
    kappa, speed = kappa[keep], speed[keep]
    if len(kappa) == 1:  # the same curvature at every speed: flat up to it, then the steep fall beyond the last knot
        return np.array([kappa[0], kappa[0] + 1e-6]), np.array([speed[0], speed[0]]), np.zeros(2)
    slope = PchipInterpolator(kappa, speed).derivative()(kappa)
    slope[0] = 0.0
    return kappa, speed, slope


def _interp_speed(kappa, kt, vt, dt):  # noqa: ANN001, ANN202 - torch tensors in, tensor out
    """The cubic Hermite v(kappa) on the knots (kt, vt, slopes dt); top speed below the first knot; beyond the
    last, the speed falls with the square of the excess so that the optimiser is pushed back inside the car's
    curvature limit."""
    import torch

    # numpy's searchsorted, not torch's: on this 2-core CPU build torch.searchsorted took 8 ms a call whatever the
    # size (numpy: 10 us), 6 of a Gazebo H_track limit's 59 s. The knots and curvatures are float64 on the CPU.
    found = np.searchsorted(kt.detach().numpy(), kappa.detach().numpy())
    idx = torch.from_numpy(found).clamp(1, len(kt) - 1)
    k0, k1, v0, v1, d0, d1 = kt[idx - 1], kt[idx], vt[idx - 1], vt[idx], dt[idx - 1], dt[idx]
    h = k1 - k0
    t = ((kappa - k0) / h).clamp(0.0, 1.0)
    t2, t3 = t * t, t * t * t
    inside = (2 * t3 - 3 * t2 + 1) * v0 + (t3 - 2 * t2 + t) * h * d0 + (-2 * t3 + 3 * t2) * v1 + (t3 - t2) * h * d1
    below = torch.full_like(kappa, float(vt[0]))
    beyond = vt[-1] * (kt[-1] / kappa.clamp_min(1e-9)) ** 2
    return torch.where(kappa <= kt[0], below, torch.where(kappa >= kt[-1], beyond, inside))


def speed_profile(
    ds: np.ndarray, curvature: np.ndarray, limits: CarLimits, v_start: float | None = 0.0
) -> tuple[np.ndarray, float]:
    """Quasi-steady speeds (N + 1,) along a closed line from point 0 back to it, and the lap time.

    ``v_start`` = 0: a standing start; None: a flying lap (the profile repeats, found by going round twice)."""
    v_lim = limits.speed_for_curvature(curvature)
    v_lim = np.append(v_lim, v_lim[0])
    k = np.append(np.abs(curvature), abs(curvature[0]))
    n = len(ds)
    if v_start is None:
        v = _passes(np.tile(ds, 3), np.tile(v_lim[:-1], 3), np.tile(k[:-1], 3), limits, v_lim[0])
        v = v[n : 2 * n + 1]
    else:
        v = _passes(ds, v_lim, k, limits, min(v_start, v_lim[0]))
    times = 2.0 * ds / np.maximum(v[:-1] + v[1:], 1e-9)
    return v, float(times.sum())


def _passes(ds: np.ndarray, v_lim: np.ndarray, k: np.ndarray, limits: CarLimits, v0: float) -> np.ndarray:
    """Forward (acceleration) and backward (braking) passes inside the tyres' budget (:func:`longitudinal_budget`);
    len(v_lim) = len(ds) + 1."""
    if len(v_lim) == len(ds):
        v_lim, k = np.append(v_lim, v_lim[-1]), np.append(k, k[-1])
    v = v_lim.astype(np.float64).copy()
    v[0] = v0
    grip = lateral_grip(limits)
    accel_peak, brake_peak = max(grip, max(limits.accel)), max(grip, max(limits.brake))
    for i in range(len(ds)):
        a = longitudinal_budget(float(limits.accel_at(v[i])), v[i], k[i], accel_peak, grip)
        v[i + 1] = min(v[i + 1], math.sqrt(v[i] ** 2 + 2.0 * a * ds[i]))
    for i in range(len(ds) - 1, -1, -1):
        b = longitudinal_budget(float(limits.brake_at(v[i + 1])), v[i + 1], k[i + 1], brake_peak, grip)
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * b * ds[i]))
    return v


def lateral_grip(limits: CarLimits) -> float:
    """The largest lateral acceleration the car held in any cornering trial, m/s²: the lateral radius of its tyres'
    friction ellipse."""
    return max(float(max(limits.max_lateral_accel)), 1e-6)


def longitudinal_budget(rate: float, v: float, kappa: float, peak: float, grip: float) -> float:
    """The acceleration or braking (m/s²) the car has left while it holds curvature ``kappa`` at speed ``v``: the
    straight-line ``rate`` (the motors' limit), capped by a friction ellipse whose radii are ``peak`` (the largest
    rate measured in that direction, at least ``grip``) along the car and ``grip`` (:func:`lateral_grip`) across it.

    Why: the tyres give one force, shared between turning and braking; a car whose motors brake about as hard as
    its tyres grip (the Gazebo car) cannot brake at its straight-line rate while turning at its grip limit. Radii
    from the tyres, not the motors' rate scaled down, so that a car whose motors are well inside its grip (the
    default car) keeps braking near its lateral limit."""
    lateral = v * v * abs(kappa)
    return min(rate, peak * math.sqrt(max(1.0 - (lateral / grip) ** 2, 0.0)))


def racing_line(track: Track, limits: CarLimits, margin: float = DEFAULT_MARGIN_M) -> RacingLine:
    """The optimised line round ``track`` (in its file's direction) with its speed profiles and lap times."""
    cor = corridor(track, margin)
    offsets = optimise_line(cor, limits)
    points = cor.center + offsets[:, None] * cor.normal
    ds = np.linalg.norm(np.roll(points, -1, axis=0) - points, axis=1)
    curvature = closed_curvature(points)
    speed, lap = speed_profile(ds, curvature, limits, v_start=0.0)
    flying, flying_lap = speed_profile(ds, curvature, limits, v_start=None)
    return RacingLine(
        points,
        offsets,
        ds=ds,
        curvature=curvature,
        speed=speed,
        flying_speed=flying[:-1],
        lap_time=lap,
        flying_lap_time=flying_lap,
        corridor=cor,
    )
