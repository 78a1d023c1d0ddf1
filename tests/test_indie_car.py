"""The independent car of ``tests/indie_car.py`` (the ground truth of the calibration tests) does what it says."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from tests.indie_car import (
    CAR_REFERENCE_POINT_M,
    CAR_WHEELBASE_M,
    CSV_HEADER,
    DECLARED,
    NOISE_HEADING_DEG,
    NOISE_POS_M,
    OUT_OF_LIBRARY,
    PARAMETERS,
    PLAN_CIRCLE_DEG,
    PLAN_CIRCLE_MPS,
    PLAN_STRAIGHT_MPS,
    SERVO_TAU_S,
    Effects,
    commands,
    drive,
    simulate,
    write_log,
)


def _radius(x: np.ndarray, y: np.ndarray) -> float:
    """Least-squares circle through the points (algebraic fit), its radius."""
    a = np.c_[2 * x, 2 * y, np.ones_like(x)]
    cx, cy, c = np.linalg.lstsq(a, x * x + y * y, rcond=None)[0]
    return float(math.sqrt(c + cx * cx + cy * cy))


def _steps(first: float, then: float, before: int, after: int) -> np.ndarray:
    return np.r_[np.full(before, first), np.full(after, then)]


def test_imports_nothing_from_racer():
    tree = ast.parse(Path(__file__).with_name("indie_car.py").read_text())
    names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert names <= {"__future__", "csv", "dataclasses", "math", "pathlib", "numpy"}


def test_low_speed_circle_is_the_kinematic_bicycle():
    steer = np.array([10.0, 20.0, 30.0, -20.0])
    tr = simulate(Effects(), np.repeat(steer[:, None], 60, axis=1), np.full((4, 60), 0.5))
    for i, d in enumerate(steer):
        rear = CAR_WHEELBASE_M / math.tan(math.radians(abs(d)))
        assert _radius(tr.x[i, 20:], tr.y[i, 20:]) == pytest.approx(math.hypot(rear, CAR_REFERENCE_POINT_M), rel=0.01)
        assert np.sign(tr.yaw_rate_dps[i, -1]) == np.sign(d)  # + = left = counter-clockwise


def test_the_tyres_saturate_and_the_car_plows_at_the_limit():
    tr = simulate(Effects(), np.full(60, 30.0), np.full(60, 2.5))
    kinematic = math.hypot(CAR_WHEELBASE_M / math.tan(math.radians(30)), CAR_REFERENCE_POINT_M)
    assert _radius(tr.x[30:], tr.y[30:]) > 2 * kinematic
    assert tr.speed[20:].min() > 2.3  # no spin
    lateral = tr.speed[-1] * math.radians(tr.yaw_rate_dps[-1])
    assert 6.0 < lateral < 9.81


def test_steering_dead_time_delays_the_yaw_response_by_its_rows():
    steer, speed = _steps(0.0, 20.0, 10, 10), np.full(20, 1.0)
    first = []
    for fx in (Effects(), Effects(steering_delay=0.2)):
        _, _, _, heading = drive(fx, steer, speed, rng=np.random.default_rng(0), noise=0.0, start_heading=0.0)
        first.append(int(np.argmax(np.abs(heading) > 0.3)))
    assert first[0] in (11, 12)  # row 10's command moves the car from sample 10 to 11
    assert abs(first[1] - first[0] - 0.2 * 15) <= 1


@pytest.mark.parametrize(
    ("fx", "channel", "cmd"),
    [(Effects(steering_lag=0.3), "steer_deg", 20.0), (Effects(speed_lag=0.3), "wheel_speed", 1.0)],
)
def test_first_order_lag_reaches_63_percent_at_tau(fx: Effects, channel: str, cmd: float):
    tr = simulate(fx, _steps(0.0, cmd, 1, 20), _steps(0.0, cmd, 1, 20), every_step=True)
    t63 = tr.t[np.argmax(getattr(tr, channel) >= (1 - math.exp(-1)) * cmd)] - 1 / 15  # the step is at row 1
    own = SERVO_TAU_S if channel == "steer_deg" else 0.05  # the car's own servo or motor, in series
    assert t63 == pytest.approx(0.3 + own, abs=0.01)


def test_understeer_divides_the_angle_by_one_plus_k_v_squared():
    tr = simulate(Effects(understeer=0.2), np.full(30, 20.0), np.full(30, 2.0))
    assert tr.speed[-1] == pytest.approx(2.0, abs=0.02)
    assert tr.steer_deg[-1] == pytest.approx(20.0 / (1 + 0.2 * tr.speed[-1] ** 2), rel=0.005)


def test_two_effects_at_once():
    tr = simulate(
        Effects(steering_gain=0.5, steering_delay=0.2), _steps(0.0, 20.0, 1, 20), np.zeros(21), every_step=True
    )
    start = tr.t[np.argmax(np.abs(tr.steer_deg) > 1e-6)] - 1 / 15
    assert start == pytest.approx(0.2, abs=0.002)
    assert tr.steer_deg[-1] == pytest.approx(10.0, abs=0.01)


def test_offset_gain_saturation_and_the_mechanical_range():
    fx = Effects(steering_offset=2.0, steering_gain=1.5, steering_saturation=25.0)
    cmd = np.array([[0.0] * 20, [10.0] * 20, [30.0] * 20, [-30.0] * 20])
    final = simulate(fx, cmd, np.zeros_like(cmd)).steer_deg[:, -1]
    np.testing.assert_allclose(final, [2.0, 17.0, 27.0, -23.0], atol=0.01)
    final = simulate(Effects(steering_offset=5.0), cmd, np.zeros_like(cmd)).steer_deg[:, -1]
    np.testing.assert_allclose(final, [5.0, 15.0, 30.0, -25.0], atol=0.01)  # the wheels stop at ±30°


def test_speed_gain_and_delay():
    tr = simulate(Effects(speed_gain=0.8, speed_delay=0.3), np.zeros(40), _steps(0.0, 2.0, 1, 39), every_step=True)
    start = tr.t[np.argmax(tr.wheel_speed > 1e-6)] - 1 / 15
    assert start == pytest.approx(0.3, abs=0.002)
    assert tr.speed[-1] == pytest.approx(1.6, abs=0.01)


def test_backlash_leaves_the_wheels_behind_the_servo():
    tr = simulate(Effects(steering_backlash=2.0), _steps(10.0, 0.0, 15, 15), np.zeros(30))
    assert tr.steer_deg[14] == pytest.approx(8.0, abs=0.01)
    assert tr.steer_deg[-1] == pytest.approx(2.0, abs=0.01)


def test_rate_limit_bounds_the_servo_speed():
    tr = simulate(Effects(steering_rate_limit=60.0), _steps(0.0, 30.0, 1, 15), np.zeros(16), every_step=True)
    rate = np.diff(tr.steer_deg) / np.diff(tr.t)
    assert rate.max() == pytest.approx(60.0, rel=1e-6)
    assert tr.t[np.argmax(tr.steer_deg >= 29.0)] - 1 / 15 == pytest.approx(29.0 / 60.0, abs=0.03)


def test_asymmetry_and_speed_fade():
    cmd = np.array([[20.0] * 30, [-20.0] * 30])
    final = simulate(Effects(steering_asymmetry=0.7), cmd, np.zeros_like(cmd)).steer_deg[:, -1]
    np.testing.assert_allclose(final, [20.0, -14.0], atol=0.01)
    tr = simulate(Effects(steering_speed_fade=0.2), np.full(30, 10.0), np.full(30, 2.0))
    assert tr.steer_deg[-1] == pytest.approx(10.0 / (1 + 0.2 * tr.speed[-1]), rel=0.005)


def test_cornering_drag_and_battery_sag_slow_the_car():
    tr = simulate(Effects(cornering_drag=0.05), np.full(45, 20.0), np.full(45, 1.5))
    lateral = tr.speed[-1] * math.radians(tr.yaw_rate_dps[-1])
    assert tr.wheel_speed[-1] == pytest.approx(1.5 * (1 - 0.05 * lateral), rel=0.005)
    assert tr.wheel_speed[-1] < 1.4
    tr = simulate(Effects(battery_sag=0.1), np.zeros(31), np.full(31, 2.0))
    assert tr.wheel_speed[-1] == pytest.approx(2.0 * (1 - 0.1 * 2.0), rel=0.01)


def test_every_effect_changes_the_drive_and_identity_values_do_not():
    steer, speed = np.r_[[20.0] * 6, [-20.0] * 5, [0.0] * 5], np.r_[[1.0] * 8, [2.0] * 8]
    base = simulate(Effects(), steer, speed)
    values = {
        **dict(steering_offset=1.0, steering_gain=0.8, steering_saturation=15.0, steering_delay=0.1),
        **dict(steering_lag=0.1, speed_gain=0.8, speed_delay=0.1, speed_lag=0.1, understeer=0.2),
        **dict(steering_backlash=1.0, steering_rate_limit=100.0, steering_asymmetry=0.7, steering_speed_fade=0.2),
        **dict(cornering_drag=0.05, battery_sag=0.05),
    }
    assert set(values) == set(PARAMETERS)
    for name, value in values.items():
        tr = simulate(Effects.of({name: value}), steer, speed)
        moved = np.hypot(tr.x - base.x, tr.y - base.y)
        assert moved.max() > 0.005, name
    identity = Effects.of({name: ident for name, (_, ident) in PARAMETERS.items()})
    assert np.array_equal(simulate(identity, steer, speed).x, base.x)


def test_effects_by_name():
    fx = Effects.of({"steering_delay": 0.2, "cornering_drag": 0.05})
    assert fx.active() == {"steering_delay": 0.2, "cornering_drag": 0.05}
    assert fx.as_params() == {"steering_delay": {"delay_s": 0.2}, "cornering_drag": {"k_s2pm": 0.05}}
    assert fx.value("speed_gain") == 1.0
    assert set(DECLARED) | set(OUT_OF_LIBRARY) == set(PARAMETERS) and len(OUT_OF_LIBRARY) >= 4
    with pytest.raises(ValueError, match="unknown effects"):
        Effects.of({"steering_dealy": 0.2})


def test_commands():
    rng = np.random.default_rng(3)
    steer, speed = commands(rng, 300, "deepracer")
    assert len(steer) == 300 and set(steer) <= {-30, -20, -10, 0, 10, 20, 30} and set(speed) <= {1.0, 2.0}
    runs = np.diff(np.flatnonzero(np.r_[True, (np.diff(steer) != 0) | (np.diff(speed) != 0), True]))
    assert runs.max() <= 8 and len(set(zip(steer, speed, strict=True))) > 10  # held 1-4 rows (two draws may agree)
    steer, speed = commands(rng, 300, "continuous")
    assert np.abs(steer).max() <= 30 and speed.min() >= 0.5 and speed.max() <= 3.0
    steer, speed = commands(rng, 0, "plan")
    pairs = set(zip(steer, speed, strict=True))
    assert {(d, v) for d in PLAN_CIRCLE_DEG for v in PLAN_CIRCLE_MPS} <= pairs
    assert {(0.0, v) for v in PLAN_STRAIGHT_MPS} <= pairs and {(15.0, 1.2), (-15.0, 1.2), (0.0, 1.2)} <= pairs
    assert len(steer) == 15 * (4 * 2.0 + 5 * 1.0 + 12 * 3.0)
    with pytest.raises(ValueError):
        commands(rng, 10, "random")


def test_measurement_noise():
    steer, speed = np.tile(commands(np.random.default_rng(1), 40, "continuous"), (8, 1, 1)).transpose(1, 0, 2)
    start = np.linspace(-180.0, 180.0, 8)
    _, x, y, heading = drive(Effects(), steer, speed, rng=np.random.default_rng(2), start_heading=start)
    tr = simulate(Effects(), steer, speed, start_heading_deg=start)
    assert np.std(np.r_[x - tr.x, y - tr.y]) == pytest.approx(NOISE_POS_M, rel=0.1)
    dh = (heading - tr.heading_deg + 180) % 360 - 180
    assert np.std(dh) == pytest.approx(NOISE_HEADING_DEG, rel=0.1)
    assert np.abs(heading).max() <= 180


def test_write_log(tmp_path: Path):
    path = write_log(tmp_path / "a.csv", Effects(steering_delay=0.1), episodes=3, steps=20, seed=5)
    lines = path.read_text().splitlines()
    assert lines[0] == "# reference_point_m: 0.14"
    assert lines[1] == ",".join(CSV_HEADER) == "episode,time_s,steer_cmd_deg,speed_cmd_mps,x_m,y_m,heading_deg"
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[2:]])
    assert rows.shape == (60, 7)
    assert list(rows[:, 0]) == [0] * 20 + [1] * 20 + [2] * 20
    assert np.all(np.diff(rows[:, 1]) > 0)
    assert np.abs(rows[:, 6]).max() <= 180
    first = rows[::20]  # at rest, the rear axle at the origin: the logged point 0.14 m from it along the heading
    heading = np.radians(first[:, 6])
    np.testing.assert_allclose(first[:, 4], 0.14 * np.cos(heading), atol=0.015)
    np.testing.assert_allclose(first[:, 5], 0.14 * np.sin(heading), atol=0.015)
    assert write_log(tmp_path / "b.csv", Effects(steering_delay=0.1), episodes=3, steps=20, seed=5).read_text() == (
        path.read_text()
    )
    assert write_log(tmp_path / "c.csv", Effects(), episodes=3, steps=20, seed=6).read_text() != path.read_text()
