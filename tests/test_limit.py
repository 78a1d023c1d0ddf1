"""racer limit: the car's measured limits, the speed profile against hand-computed times, the racing line, and the
driven lap in the real env."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from shapely.geometry import MultiPoint

from common.car_calibration import CalibrationError, load_car
from common.defaults import DEFAULT_TRACK, STRAIGHT_TRACK
from sim.car_limits import CarLimits, measure_limits
from sim.follower import CORRIDOR_TRIES, PACE_STEP
from sim.geometry import curvature
from sim.physics import WHEELBASE_M
from sim.raceline import corridor, racing_line, speed_profile
from sim.track import load_track
from tests.shared_data import needs_deepracer_tracks


@pytest.fixture(scope="module")
def limits() -> CarLimits:
    return measure_limits()


def flat_limits(top: float = 3.0, accel: float = 2.0, brake: float = 4.0, kmax: float = 10.0) -> CarLimits:
    """Hand-made limits: constant acceleration and braking, one curvature limit at every speed."""
    speeds = [0.5, 1.0, 2.0, top]
    return CarLimits(
        top_speed=top,
        speed_per_command=1.0,
        speeds=speeds,
        accel=[accel] * 4,
        brake=[brake] * 4,
        max_curvature=[kmax] * 4,
        max_lateral_accel=[v * v * kmax for v in speeds],
        steering=[10.0, 20.0, 30.0],
        curvature_by_steering=[[1.0, 2.0, 3.0]] * 4,
        min_turn_radius=0.3,
        max_command_speed=top,
        steering_tau_s=0.0,
    )


def test_measured_limits_are_those_of_a_small_car_with_a_4_mps_top_speed(limits: CarLimits) -> None:
    assert 3.8 < limits.top_speed <= 4.0 and 0.95 < limits.speed_per_command <= 1.0
    assert all(a > 3.0 for a in limits.accel[:-1]) and limits.accel[-1] == 0.0  # no acceleration at top speed
    assert all(b > 3.0 for b in limits.brake[1:])
    k = np.array(limits.max_curvature)
    assert np.all(np.diff(k) <= 0) and k[-1] > 0  # a faster car holds no tighter curve
    # Full lock at a walking pace: close to the kinematic radius L / tan(30°), a little wider (tyres slip).
    assert WHEELBASE_M / math.tan(math.radians(30)) < limits.min_turn_radius < 0.5
    assert limits.max_lateral_accel == pytest.approx([v * v * c for v, c in zip(limits.speeds, k, strict=True)])


def test_speed_for_curvature_inverts_the_table(limits: CarLimits) -> None:
    for v, k in zip(limits.speeds[1:-1], limits.max_curvature[1:-1], strict=True):
        assert float(limits.speed_for_curvature(k)) >= v - 1e-6  # at its own limit the car may go that fast
    assert float(limits.speed_for_curvature(0.0)) == pytest.approx(limits.top_speed)


def test_standing_start_profile_matches_hand_computed_time() -> None:
    # A 30 m straight-ish loop (curvature 0): accelerate at 2 m/s² to 3 m/s (2.25 m, 1.5 s), cruise the rest.
    lim = flat_limits()
    ds = np.full(300, 0.1)
    v, lap = speed_profile(ds, np.zeros(300), lim, v_start=0.0)
    assert v[0] == 0.0 and v[-1] == pytest.approx(3.0)
    assert lap == pytest.approx(1.5 + (30.0 - 2.25) / 3.0, rel=2e-3)


def test_braking_before_a_curve_matches_hand_computed_speeds() -> None:
    # Curvature 10/1 m at one point limits the speed there to the table's lowest, 0.5 m/s; braking at 4 m/s² from
    # 3 m/s needs (9 - 0.25) / 8 = 1.09 m before it.
    lim = flat_limits(kmax=1.0)
    ds = np.full(300, 0.1)
    kappa = np.zeros(300)
    kappa[200] = 10.0
    v, _ = speed_profile(ds, kappa, lim, v_start=0.0)
    assert v[200] == pytest.approx(0.5)
    assert v[190] == pytest.approx(math.sqrt(0.25 + 2 * 4.0 * 1.0), rel=1e-6)  # 1 m before it
    assert v[180] == pytest.approx(3.0)  # 2 m before: still at top speed


def test_the_tyres_budget_is_an_ellipse_capped_by_the_motors() -> None:
    from sim.raceline import longitudinal_budget

    # Radii: 5 m/s² along the car, 4 m/s² across it; the motors give 3 m/s².
    assert longitudinal_budget(3.0, 2.0, 0.0, 5.0, 4.0) == 3.0  # straight: the motors' rate
    assert longitudinal_budget(3.0, 2.0, 0.8, 5.0, 4.0) == pytest.approx(3.0)  # 3.2 m/s² across: 5 x 0.6 = 3
    assert longitudinal_budget(3.0, 2.0, 0.9, 5.0, 4.0) == pytest.approx(5.0 * math.sqrt(1 - 0.9**2))  # 3.6 across
    assert longitudinal_budget(3.0, 2.0, -1.0, 5.0, 4.0) == 0.0  # at the grip limit: none left (either turn)
    assert longitudinal_budget(3.0, 3.0, 1.0, 5.0, 4.0) == 0.0  # beyond it: none, not a complex number


def test_braking_into_a_curve_at_the_grip_limit_starts_earlier() -> None:
    # A car holding 4, 2, 1 and 0.5 1/m at 0.5, 1, 2 and 3 m/s: its lateral grip is 4.5 m/s² (at 3 m/s), braking
    # 4 m/s², accelerating 2 m/s². A curve of 1/m from point 200 to 249 is taken at 2 m/s, 4 m/s² across the car:
    # the tyres leave 4.5 x sqrt(1 - (4 / 4.5)²) = 2.06 m/s² for braking there, so the last 0.1 m before the curve
    # is braked at that, the rest at 4 m/s². Out of the curve the motors' 2 m/s² is below the tyres' 2.06.
    speeds = [0.5, 1.0, 2.0, 3.0]
    kmax = [4.0, 2.0, 1.0, 0.5]
    lim = replace(
        flat_limits(),
        speeds=speeds,
        max_curvature=kmax,
        max_lateral_accel=[v * v * k for v, k in zip(speeds, kmax, strict=True)],
    )
    ds = np.full(400, 0.1)
    kappa = np.zeros(400)
    kappa[200:250] = 1.0
    v, _ = speed_profile(ds, kappa, lim, v_start=0.0)
    tyres = 4.5 * math.sqrt(1 - (4.0 / 4.5) ** 2)
    assert v[200] == pytest.approx(2.0)
    assert v[199] == pytest.approx(math.sqrt(4.0 + 2 * tyres * 0.1), rel=1e-9)
    assert v[195] == pytest.approx(math.sqrt(v[199] ** 2 + 2 * 4.0 * 0.4), rel=1e-9)
    assert v[250] == pytest.approx(math.sqrt(4.0 + 2 * 2.0 * 0.1), rel=1e-9)


def test_the_optimisers_smooth_lap_time_matches_the_exact_profile() -> None:
    """The line search minimises a smooth closed-form lap time; on the braking case above it must agree with the
    exact passes (hand-checked there) within 1 %, or the optimiser would chase a different lap than the one
    reported."""
    import torch

    from sim.raceline import _soft_lap_time

    lim = flat_limits(kmax=1.0)
    ds = np.full(300, 0.1)
    kappa = np.zeros(300)
    kappa[200] = 10.0
    _, exact = speed_profile(ds, kappa, lim, v_start=0.0)
    v_curve = torch.tensor(lim.speed_for_curvature(kappa))
    soft = float(_soft_lap_time(v_curve, torch.tensor(ds), 2.0, 4.0))
    assert soft == pytest.approx(exact, rel=0.01)


def test_a_car_that_holds_one_curvature_at_every_speed_still_gets_a_line() -> None:
    """Ties in the table are merged for the optimiser's speed(curvature); a table that is all one tie must still
    give a usable function: the top speed up to that curvature, falling beyond it."""
    import torch

    from sim.raceline import _curve_speed_table, _interp_speed

    kt, vt, dt = (torch.tensor(a) for a in _curve_speed_table(flat_limits(kmax=2.0)))
    v = _interp_speed(torch.tensor([0.5, 2.0, 4.0], dtype=torch.float64), kt, vt, dt)
    assert v[0] == pytest.approx(3.0) and v[1] == pytest.approx(3.0, rel=1e-4)
    assert v[2] == pytest.approx(3.0 * (2.0 / 4.0) ** 2, rel=1e-4)


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_the_gazebo_cars_line_uses_the_track() -> None:
    """The Gazebo car's curvature table is flat over several speeds; a piecewise-linear speed(curvature) then had
    vertical steps on which the line search stopped after 30 iterations, 7 cm from the centre line, and the
    controller's driven lap beat that 'limit' by 9 %. The line must use the corridor and be clearly faster than
    the centre line, and no point may be tighter than the car can turn at any speed."""
    lim = measure_limits(load_car("deepracer-gazebo"))
    track = load_track(DEFAULT_TRACK)
    line = racing_line(track, lim)
    cor = corridor(track)
    ds = np.linalg.norm(np.roll(cor.center, -1, axis=0) - cor.center, axis=1)
    _, centre_lap = speed_profile(ds, curvature(cor.center), lim)
    assert np.max(np.abs(line.offsets)) > 0.3
    # racer_loop's bends are gentler than reinvent_base's, where this asked for 0.9. On racer_loop the line takes 7 %
    # off the centre line's lap, a line kept within 7 cm of the centre (the bug) 2.7 % (measured with racing_line on
    # a corridor narrowed to 7 cm; on reinvent_base 10.3 %, just under the old bound): 0.95 lies between.
    assert line.lap_time < 0.95 * centre_lap
    assert np.max(np.abs(line.curvature)) <= max(lim.max_curvature) * 1.02


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_the_racing_line_stays_in_the_corridor_and_beats_the_centre_line(limits: CarLimits) -> None:
    track = load_track(DEFAULT_TRACK)
    line = racing_line(track, limits)
    cor = corridor(track)
    assert line.offsets[0] == 0.0  # starts where the env puts the car
    assert np.all(line.offsets >= cor.low - 1e-9) and np.all(line.offsets <= cor.high + 1e-9)
    ds = np.linalg.norm(np.roll(cor.center, -1, axis=0) - cor.center, axis=1)
    _, centre_lap = speed_profile(ds, curvature(cor.center), limits)
    assert line.lap_time < 0.95 * centre_lap
    assert line.flying_lap_time < line.lap_time  # no standing start
    assert line.length < track.length  # it cuts the corners


@pytest.mark.slow(reason="starts real racer processes")
@pytest.mark.parametrize(
    "track",
    [
        DEFAULT_TRACK,
        # A DeepRacer track by name, read from the track folder (RACER_TRACKS_DIR: the shared routes here, what
        # `racer tracks pull` fills on a user's machine).
        pytest.param("reInvent2019_track", marks=needs_deepracer_tracks),
    ],
)
def test_racer_limit_drives_its_limit_within_5_percent(tmp_path: Path, track: str) -> None:
    out, png, cache = tmp_path / "limit.json", tmp_path / "limit.png", tmp_path / "cache"
    done = subprocess.run(
        [sys.executable, "-m", "racer", "limit", track, "--json", str(out), "--png", str(png)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "RACER_CACHE_DIR": str(cache)},
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(out.read_text())
    for key in ("lap_time_s", "driven_lap_time_s", "line_length_m", "car_limits", "flying_lap_time_s", "driven_pace"):
        assert key in report
    # Every lap finished (tries only where a lap left the line's corridor, to be faster): the reported one was slowed
    # by those retries at most.
    assert report["driven_status"] == "lap_complete" and report["driven_pace"] >= PACE_STEP**CORRIDOR_TRIES - 1e-9
    assert 1 <= report["driven_tries"] <= 1 + CORRIDOR_TRIES
    # Within 5 % either way: the quasi-steady profile misses what the car does between steady states, and the
    # controller's lap, which cuts the line a little where the corridor allows, may come in just under it.
    assert 0.95 <= report["driven_lap_time_s"] / report["lap_time_s"] <= 1.05
    assert report["best_known_lap_s"] == min(report["lap_time_s"], report["driven_lap_time_s"])
    # Shorter than the centre line (racer_loop 17.60 m, reInvent2019_track 23.12 m), and no shorter than the convex
    # hull of the inner border, which any lap round the inside of the track encloses.
    route = load_track(track)
    inner_hull = MultiPoint(route.waypoints[:, 2:4]).convex_hull.length
    assert inner_hull < report["line_length_m"] < route.length
    assert {"speeds", "accel", "brake", "max_curvature", "top_speed"} <= set(report["car_limits"])
    # Its speed (under 30 s a track on one core) is measured with `racer limit` itself (docs/racing.md), not timed
    # here, where a shared machine makes seconds noise: the report only has to say what each part took.
    assert set(report["seconds"]) == {"measure_car", "optimise_line", "drive", "total"}
    # Measured, not taken from the cache, and kept there for the next run (one JSON file, the limits themselves).
    assert report["car_limits_cached"] is False
    assert [json.loads(f.read_text()) for f in cache.glob("car-limits/*.json")] == [report["car_limits"]]
    assert png.stat().st_size > 10_000
    assert "limit" in done.stdout and "driven in the env by a predictive line follower" in done.stdout


@pytest.mark.slow(reason="starts real racer processes")
@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        ([STRAIGHT_TRACK], "not a loop"),
        ([DEFAULT_TRACK, "--car", "no-such-car"], "car 'no-such-car' is neither a preset"),
        (["nowhere"], "unknown track 'nowhere'"),
    ],
)
def test_racer_limit_refuses_bad_input_in_one_line(args: list[str], fragment: str) -> None:
    done = subprocess.run([sys.executable, "-m", "racer", "limit", *args], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0], done.stderr


def test_car_presets_and_files(tmp_path: Path) -> None:
    assert load_car("default").is_identity
    path = tmp_path / "car.json"
    path.write_text(json.dumps({"effects": [{"name": "tyre_friction", "params": {"mu": 0.5}}]}))
    assert load_car(str(path)).value("tyre_friction", "mu") == 0.5
    with pytest.raises(CalibrationError, match="neither a preset"):
        load_car("fast-car")


def test_train_takes_a_car_by_preset_name_and_refuses_an_unknown_one(tmp_path: Path) -> None:
    from racer.runconfig import build_run

    run, _ = build_run("r", car_calibration="default")
    assert run.env.car.is_identity
    done = subprocess.run(
        [sys.executable, "-m", "racer", "train", "--time-limit", "60s", "--car", "warp-car"],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert done.returncode == 2 and "car 'warp-car' is neither a preset" in done.stderr
    assert not (tmp_path / "runs").exists()  # nothing written


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_the_steering_time_constant_is_measured_from_the_car() -> None:
    # The default car's servos follow within a control period or so; the Gazebo preset's lag is 0.50 s in its
    # file (fitted on DeepRacer's logs), and the hinge servo behind it adds little.
    assert measure_limits().steering_tau_s < 0.08
    gazebo = measure_limits(load_car("deepracer-gazebo"))
    assert 0.45 < gazebo.steering_tau_s < 0.56
    # The speed servo: the default car's follows within a control period, the Gazebo preset's lags (measured 0.06
    # and 0.17 s, 2026-11-28; its file's speed lag behind the wheel-velocity PID).
    assert measure_limits().speed_tau_s < 0.09
    assert 0.12 < gazebo.speed_tau_s < 0.25
    # An action space slower than the step (DeepRacer's default, 1 m/s) still measures a lag, on a smaller step.
    slow = measure_limits(load_car("deepracer-gazebo"), max_command_speed=1.0)
    assert 0.08 < slow.speed_tau_s < 0.3
    assert 0.3 < gazebo.min_turn_radius < 1.0  # the lagging car still has a finite full-lock radius


@pytest.mark.slow(reason="drives the car round a track at its limit")
@needs_deepracer_tracks  # the figures below were measured on reInvent2019_track (docs/racing.md)
def test_the_follower_drives_the_gazebo_cars_lagging_steering_round_its_limit() -> None:
    """Pure pursuit left the track with this car at any look-ahead; the predictive follower must finish the lap
    close to the limit. Measured: 1.039 at the first try, on an AMD EPYC. The lap is chaotic at the limit (the limit
    itself differs by 0.1 % between CPUs), and an earlier follower gave 1.03 after 5 tries on one machine, 1.075
    after 7 on another and no lap in 10 on a third; the bounds leave room for that spread, not for a lap that fails.
    """
    from sim.follower import drive_line

    car = load_car("deepracer-gazebo")
    lim = measure_limits(car)
    line = racing_line(load_track("reInvent2019_track"), lim)
    lap = drive_line("reInvent2019_track", line, lim, car)
    assert lap.status == "lap_complete" and lap.pace >= 0.85 and lap.tries <= 4 + CORRIDOR_TRIES
    assert 0.95 < lap.lap_time / line.lap_time < 1.08


@pytest.mark.slow(reason="drives the car round a track at its limit")
@pytest.mark.parametrize(
    ("track", "pace"),
    [
        # The two loops of the measurement in docs/racing.md.
        pytest.param("Oval_track", 0.98, marks=needs_deepracer_tracks),
        pytest.param("Oval_track", 0.94, marks=needs_deepracer_tracks),
        pytest.param("reInvent2019_track", 0.96, marks=needs_deepracer_tracks),
        # racer's default loop, so that this runs without DeepRacer's files (measured once, on a shared machine:
        # laps 1.053 and 1.064 times the limit's at paces 0.98 and 0.94, against bounds of 1.10 and 1.14).
        (DEFAULT_TRACK, 0.96),
    ],
)
def test_the_follower_keeps_the_gazebo_car_on_track_at_and_below_its_limit(track: str, pace: float) -> None:
    """No retries: one lap at a uniform fraction of the profile. The earlier follower finished 1 of 10 such laps on
    Oval_track and reInvent2019_track (paces 1.0 to 0.92; on Oval_track it left at 26-28 % at every pace, unwinding
    the lagging wheels in the bend); with the heading cost, the previous choice among the checked plans and braking
    at the lowest command, all ten (docs/racing.md)."""
    from sim.follower import LineFollower, _drive, follower_env

    car = load_car("deepracer-gazebo")
    lim = measure_limits(car)
    line = racing_line(load_track(track), lim)
    env = follower_env(track, lim, car)
    try:
        lap, _ = _drive(env, LineFollower(line, lim, pace))
    finally:
        env.close()
    assert lap.status == "lap_complete", f"left {track} at {lap.progress:.1f} %"
    assert lap.lap_time / line.lap_time < 1.0 / pace + 0.08


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_the_follower_slows_only_the_stretch_before_where_a_try_left(limits: CarLimits) -> None:
    """A try that leaves the track slows the 4 m before that place (and 0.5 m after), not the lap."""
    from sim.follower import SLOW_AFTER_M, SLOW_BEFORE_M, _stretch_before

    line = racing_line(load_track(DEFAULT_TRACK), limits)
    where = line.points[100]
    mask = _stretch_before(line, where)
    assert mask[100] and mask[99] and not mask[int(100 - (SLOW_BEFORE_M + 1.0) / line.ds.mean())]
    assert float(line.ds[mask].sum()) == pytest.approx(SLOW_BEFORE_M + SLOW_AFTER_M, abs=0.25)


def test_the_speed_command_leads_a_lagging_servo_to_the_profile() -> None:
    """The command that takes a first-order servo from the car's speed to the profile's in the lead time, by hand:
    1 - exp(-0.12 / 0.173) = 0.50025, so a 0.5 m/s step asks for 1.0 m/s more; without a lag, the target itself."""
    from sim.follower import lead_speed

    assert lead_speed(2.0, 2.5, 0.173, 0.12) == pytest.approx(2.0 + 0.5 / 0.50025, abs=1e-4)
    assert lead_speed(3.0, 2.0, 0.173, 0.12) == pytest.approx(3.0 - 1.0 / 0.50025, abs=1e-4)
    assert lead_speed(2.0, 2.5, 0.0, 0.12) == 2.5
    assert lead_speed(2.0, 2.0, 0.173, 0.12) == 2.0  # on the profile: hold it


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_the_follower_commands_the_lead_speed_within_the_cars_range(limits: CarLimits) -> None:
    from sim.follower import SPEED_LEAD_S, LineFollower, lead_speed
    from sim.physics import SPEED_RANGE_MPS

    line = racing_line(load_track(DEFAULT_TRACK), limits)
    follower = LineFollower(line, limits)
    standing = line.speed
    cruise = int(np.argmax(standing[:-1]))
    speed = float(standing[cruise]) - 0.2
    along = follower._s[cruise] + 0.02
    ahead = along + speed * SPEED_LEAD_S
    target = float(np.sqrt(np.interp(ahead % follower._s[-1], follower._s, standing**2)))
    expected = lead_speed(speed, target, limits.speed_tau_s, SPEED_LEAD_S) / limits.speed_per_command
    assert follower._speed_command(along, speed, standing) == pytest.approx(min(expected, limits.max_command_speed))
    # A lagging servo's command is clipped into the car's range: far above the profile, the lowest command; far
    # below it, the highest.
    lagging = LineFollower(line, replace(limits, speed_tau_s=0.173))
    assert lagging._speed_command(follower._s[cruise], float(standing[cruise]) + 5.0, standing) == SPEED_RANGE_MPS[0]
    assert lagging._speed_command(follower._s[cruise], 0.0, standing * 0 + 3.9) == limits.max_command_speed


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_the_follower_reads_the_profiles_squared_speed_from_a_standing_start(limits: CarLimits) -> None:
    """Between two points of constant acceleration v² is linear in distance: a third of the way from rest to
    v1 the profile's speed is v1 / sqrt(3), not v1 / 3 (which left the default car waiting at the start)."""
    from sim.follower import LineFollower

    line = racing_line(load_track(DEFAULT_TRACK), limits)
    follower = LineFollower(line, limits)
    v1, s1 = float(line.speed[1]), float(line.ds[0])
    assert line.speed[0] == 0.0 and v1 > 0.5
    assert float(follower._paced(s1 / 3, line.speed)) == pytest.approx(v1 / np.sqrt(3.0), rel=1e-9)


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_the_follower_measures_the_cars_distance_along_the_line_not_the_nearest_points(limits: CarLimits) -> None:
    """A point 3 cm ahead of line point 50 along the line's direction (and 10 cm to its side) is 3 cm further on;
    beyond half the spacing to the next point the distance is that of the halfway point (it is nearer the next)."""
    from sim.follower import LineFollower

    line = racing_line(load_track(DEFAULT_TRACK), limits)
    follower = LineFollower(line, limits)
    p, tangent = line.points[50], line.points[51] - line.points[49]
    tangent = tangent / np.linalg.norm(tangent)
    normal = np.array([-tangent[1], tangent[0]])
    assert follower._along(p + 0.03 * tangent + 0.1 * normal, 50) == pytest.approx(follower._s[50] + 0.03)
    half = 0.5 * max(line.ds[50], line.ds[49])
    assert follower._along(p + 0.5 * tangent, 50) == pytest.approx(follower._s[50] + half)
    assert follower._along(p - 0.5 * tangent, 50) == pytest.approx(follower._s[50] - half)


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_a_lap_outside_the_lines_corridor_is_found_where_it_first_leaves(limits: CarLimits) -> None:
    from sim.follower import _outside_corridor

    line = racing_line(load_track(DEFAULT_TRACK), limits)
    cor = line.corridor
    inside = cor.center + (0.5 * (cor.low + cor.high))[:, None] * cor.normal
    assert _outside_corridor(line, inside) is None
    path = inside.copy()
    path[70] = cor.center[70] + (cor.high[70] + 0.02) * cor.normal[70]
    path[90] = cor.center[90] + (cor.low[90] - 0.02) * cor.normal[90]
    assert np.array_equal(_outside_corridor(line, path), path[70])


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_a_lap_that_leaves_the_corridor_is_driven_again_and_the_fastest_is_kept(limits: CarLimits) -> None:
    """On a corridor 2 cm wide about the line no car stays inside: the lap is tried CORRIDOR_TRIES more times, each
    slower before where the last left it, and the lap reported is the fastest, at least as fast as the first."""
    from sim.follower import LineFollower, _drive, drive_line, follower_env

    line = racing_line(load_track(DEFAULT_TRACK), limits)
    cor = line.corridor
    line = replace(line, corridor=replace(cor, low=line.offsets - 0.01, high=line.offsets + 0.01))
    env = follower_env(DEFAULT_TRACK, limits)
    try:
        first, _ = _drive(env, LineFollower(line, limits))
    finally:
        env.close()
    lap = drive_line(DEFAULT_TRACK, line, limits)
    assert lap.tries >= 1 + CORRIDOR_TRIES and lap.status == "lap_complete"
    # At full pace the first try completes on an AMD EPYC (AVX-512) and leaves the track on an Intel Xeon (AVX2):
    # MuJoCo's floats differ. Where it completes, the lap kept is at least as fast; where it does not, drive_line
    # slows that stretch first and the corridor tries follow, as the count above shows.
    if first.status == "lap_complete":
        assert lap.lap_time <= first.lap_time


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_the_followers_k_d_tree_finds_the_same_costs_as_all_pairs(limits: CarLimits) -> None:
    """A plan's thousands of points are matched to the line with a k-d tree; the cost must be the all-pairs one."""
    from sim.follower import KD_TREE_MIN_POINTS, LineFollower

    line = racing_line(load_track(DEFAULT_TRACK), limits)
    follower = LineFollower(line, limits)
    rng = np.random.default_rng(0)
    near = 40
    points = line.points[near : near + 30].repeat(20, axis=0) + rng.normal(0, 0.15, (600, 2))
    yaw = rng.uniform(-math.pi, math.pi, len(points))
    assert len(points) > KD_TREE_MIN_POINTS
    tree = follower._cost(points, near, 200, yaw)
    pairs = np.concatenate([follower._cost(points[i : i + 50], near, 200, yaw[i : i + 50]) for i in range(0, 600, 50)])
    np.testing.assert_allclose(tree, pairs, rtol=1e-12, atol=1e-15)


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_the_followers_check_stops_losing_trials_early_and_still_picks_the_cheapest(limits: CarLimits) -> None:
    """The simulator check stops driving a trial once its summed cost passes the best so far; its choice must be
    the one a full drive of every trial gives."""
    from sim.follower import LineFollower, follower_env

    line = racing_line(load_track(DEFAULT_TRACK), limits)
    follower = LineFollower(line, limits)
    env = follower_env(DEFAULT_TRACK, limits)
    try:
        env.reset(seed=0, options={"start_index": 0, "reverse": False})
        physics, profile = env.physics, line.speed
        for step in range(40):
            if step % 8 == 7:
                pose = physics.pose
                follower._near = follower._nearest(np.array([pose.x, pose.y]), follower._near)
                plan = follower._plan(physics, profile)
                trials, saved = follower._trials(physics, plan), physics.snapshot()
                costs = []
                for trial in trials:
                    costs.append(follower._drive_ahead(physics, trial, profile))
                    physics.restore(saved)
                assert follower._check(physics, plan, profile) == trials[int(np.argmin(costs))][0]
            steer, speed = follower.command(physics, 0.0)
            env.step(np.array([steer, speed], dtype=np.float32))
    finally:
        env.close()


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_a_retry_replays_the_steps_its_slower_stretch_leaves_unchanged(limits: CarLimits) -> None:
    """A retry replays the earlier try's commands up to the first one that read a slowed point of the pace, then
    plans: the lap must be the one a retry planned from the start drives, and the replay must cover part of it."""
    from sim.follower import LineFollower, _drive, _stretch_before, follower_env

    line = racing_line(load_track(DEFAULT_TRACK), limits)
    env = follower_env(DEFAULT_TRACK, limits)
    try:
        first, record = _drive(env, LineFollower(line, limits))
        pace = np.ones(len(line.points))
        pace[_stretch_before(line, line.points[3 * len(line.points) // 4])] *= PACE_STEP
        fresh, _ = _drive(env, LineFollower(line, limits, pace))
        replayed, again = _drive(env, LineFollower(line, limits, pace), record)
    finally:
        env.close()
    same = record.same_steps(again.pace)
    assert 0.3 * len(record.actions) < same < 0.8 * len(record.actions)
    np.testing.assert_array_equal(replayed.path, fresh.path)
    assert replayed.lap_time == fresh.lap_time and replayed.status == fresh.status == "lap_complete"
    # The slowed stretch changed the lap, so the checks above could fail. Its path, not its time: at the limit a
    # slower stretch may give a faster lap (measured on reinvent_base: 5.80 s against 5.87 s on an Intel Xeon,
    # slower on an AMD EPYC).
    assert not np.array_equal(fresh.path, first.path)
    assert [len(r) for r in again.reads[:same]] == [len(r) for r in record.reads[:same]]


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_measured_limits_are_kept_per_car_and_top_command_and_a_bad_file_is_measured_again(tmp_path: Path) -> None:
    """``racer limit`` measures a car once (4-8 s of every run): the same car and top command read the figures
    back; another car or top command measures; a file that is not limits is measured again and replaced; a folder
    that cannot be written only costs the measurement."""
    from sim.car_limits import cached_limits

    first, cached = cached_limits(None, 2.0, tmp_path)
    assert not cached and len(list(tmp_path.glob("*.json"))) == 1
    again, cached = cached_limits(None, 2.0, tmp_path)
    assert cached and again == first
    other, cached = cached_limits(None, 1.5, tmp_path)
    assert not cached and other.max_command_speed == 1.5 and len(list(tmp_path.glob("*.json"))) == 2
    bad = [
        '{"top_speed": "fast"}',  # a field alone
        json.dumps({**first.to_dict(), "top_speed": "fast"}),  # every field, one not a number
        json.dumps({**first.to_dict(), "accel": [[1.0], [2.0, 3.0]]}),  # a table that is not one
        json.dumps({**first.to_dict(), "brake": None}),
        "[1, 2]",
        "not json",
    ]
    for text in bad:
        for f in tmp_path.glob("*.json"):
            f.write_text(text)
        redone, cached = cached_limits(None, 2.0, tmp_path)
        assert not cached and redone == first, text
    assert cached_limits(None, 2.0, tmp_path) == (first, True)
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    assert cached_limits(None, 2.0, blocked) == (first, False)


@pytest.mark.slow(reason="drives the car round a track at its limit")
def test_a_car_whose_steering_lags_gets_the_wider_simulator_check() -> None:
    """±3° for a car whose wheels lag more than 0.25 s (the Gazebo car: within 5 % on 9 loops, not 7), ±2° for one
    whose wheels follow at once (±3° took the default car 8.4 % over its limit on Bowtie_track)."""

    from sim.follower import CHECK_OFFSETS_DEG, LAGGING_CHECK_OFFSETS_DEG, LineFollower

    quick = flat_limits()
    line = racing_line(load_track(DEFAULT_TRACK), quick)
    assert LineFollower(line, quick)._offsets == CHECK_OFFSETS_DEG == (-2.0, 0.0, 2.0)
    lagging = replace(quick, steering_tau_s=0.5)
    follower = LineFollower(line, lagging)
    assert follower._offsets == LAGGING_CHECK_OFFSETS_DEG == (-3.0, 0.0, 3.0)
    follower._last = np.zeros(12)
    trials = follower._trials(SimpleNamespace(steering_deg=1.0), np.zeros(30))
    assert len(trials) == 11 and {float(t[0]) for t in trials[:9]} == {-3.0, 0.0, 3.0} and trials[10][0] == 1.0
