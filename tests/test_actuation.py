"""The calibration file and the effects between command and servos, against hand-computed values."""

import json
import math

import numpy as np
import pytest

from common.car_calibration import EFFECTS, CalibrationError, CarCalibration, load_calibration, save_calibration
from common.config import EnvConfig
from common.defaults import DEFAULT_TRACK
from sim.actuation import Actuation, ActuationParams, actuate_sequence
from sim.env import RacerEnv
from sim.physics import CarPhysics, Pose
from sim.texture import TextureFrame
from sim.world import build_model

H = 1 / 120  # the physics substep


def params(**values: dict[str, float]) -> ActuationParams:
    return ActuationParams.from_calibration(CarCalibration.from_values(values))


# ----------------------------------------------------------------------------------------------- the file


def test_calibration_file_round_trip(tmp_path):
    cal = CarCalibration.from_values({"steering_lag": {"tau_s": 0.5}}, {"steering_lag": {"tau_s": 0.01}})
    save_calibration(cal, tmp_path / "car.json")
    again = load_calibration(tmp_path / "car.json")
    assert again == cal
    assert again.value("steering_lag", "tau_s") == 0.5
    assert again.value("speed_lag", "tau_s") == 0.0  # absent = identity


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("{", "not JSON"),
        ('{"effects": [{"name": "warp_drive", "params": {}}]}', "unknown effect 'warp_drive'"),
        ('{"effects": [{"name": "steering_lag", "params": {"tau": 0.5}}]}', "takes params ['tau_s']"),
        ('{"effects": [{"name": "steering_lag", "params": {"tau_s": -1}}]}', "steering_lag.tau_s = -1.0 is outside"),
        ('{"effects": [{"name": "steering_gain", "params": {"gain": NaN}}]}', "steering_gain.gain = nan"),
        (
            '{"effects": [{"name": "speed_lag", "params": {"tau_s": 0.1}}, '
            '{"name": "speed_lag", "params": {"tau_s": 0.2}}]}',
            "'speed_lag' appears more than once",
        ),
        ('{"effects": [], "colour": "red"}', "colour"),
    ],
)
def test_bad_calibration_file_is_one_line_naming_it(tmp_path, content, message):
    path = tmp_path / "car.json"
    path.write_text(content)
    with pytest.raises(CalibrationError) as err:
        load_calibration(path)
    text = str(err.value)
    assert message in text and str(path) in text and "\n" not in text


def test_missing_calibration_file(tmp_path):
    with pytest.raises(CalibrationError, match="cannot read"):
        load_calibration(tmp_path / "nope.json")


def test_every_effect_has_identity_within_bounds():
    for name, spec in EFFECTS.items():
        for key, p in spec.params.items():
            assert p.low <= p.identity <= p.high and p.low <= p.start <= p.high, f"{name}.{key}"
    identity = CarCalibration.from_values({n: {k: p.identity for k, p in s.params.items()} for n, s in EFFECTS.items()})
    assert identity.is_identity


# ----------------------------------------------------------------------------------------------- the maths


def test_identity_passes_commands_through():
    steer, speed = actuate_sequence(params(), np.array([10.0, -20.0]), np.array([1.0, 2.0]), 8, H)
    np.testing.assert_array_equal(steer, [10.0] * 8 + [-20.0] * 8)
    np.testing.assert_array_equal(speed, [1.0] * 8 + [2.0] * 8)


def test_static_steering_map_offset_gain_saturation():
    p = params(steering_gain={"gain": 0.5}, steering_saturation={"max_deg": 12.0}, steering_offset={"offset_deg": 1.0})
    steer, _ = actuate_sequence(p, np.array([10.0, 30.0, -30.0]), np.ones(3), 1, H)
    # clip(0.5 · cmd, ±12) + 1: 5 + 1, 12 + 1, -12 + 1
    np.testing.assert_allclose(steer, [6.0, 13.0, -11.0])


def test_whole_substep_delay_shifts_the_command():
    p = params(steering_delay={"delay_s": 3 * H}, speed_delay={"delay_s": 2 * H})
    steer, speed = actuate_sequence(p, np.array([0.0, 20.0]), np.array([1.0, 2.0]), 4, H)
    np.testing.assert_allclose(steer, [0, 0, 0, 0, 0, 0, 0, 20])  # 20 starts 3 substeps late
    np.testing.assert_allclose(speed, [0, 0, 1, 1, 1, 1, 2, 2])  # from rest: 0 for the first 2 substeps


def test_fractional_delay_blends_neighbouring_substeps():
    p = params(steering_delay={"delay_s": 1.25 * H})
    steer, _ = actuate_sequence(p, np.array([0.0, 8.0]), np.ones(2), 2, H)
    # Substep j receives the mean of the input over [(j - 1.25) h, (j - 0.25) h]. The input is 8 from 2 h on,
    # so substep 3 ([1.75 h, 2.75 h]) gets 0.75 · 8 and substep 2 ([0.75 h, 1.75 h]) nothing.
    np.testing.assert_allclose(steer, [0, 0, 0, 0.75 * 8])


def test_lag_is_the_exact_first_order_step_response():
    tau = 0.2
    _, speed = actuate_sequence(params(speed_lag={"tau_s": tau}), np.zeros(3), np.full(3, 2.0), 8, H)
    t = np.arange(1, 25) * H
    np.testing.assert_allclose(speed, 2.0 * (1 - np.exp(-t / tau)), rtol=1e-12)


def test_slew_rate_ramps_a_step_at_60_degrees_per_s_per_60deg():
    # 0.5 s/60° = 120 °/s = 1° per substep (h = 1/120): a 5° step takes 5 substeps, then holds; back to 0 likewise.
    steer, _ = actuate_sequence(params(steering_rate={"s_per_60deg": 0.5}), np.array([5.0, 0.0]), np.ones(2), 8, H)
    np.testing.assert_allclose(steer, [1, 2, 3, 4, 5, 5, 5, 5, 4, 3, 2, 1, 0, 0, 0, 0])


def test_slew_rate_after_the_lag_limits_only_fast_changes():
    # A lag whose fastest change (its first substep, 20·(1 - e^(-h/τ)) ≈ 0.83°) is below the slew limit's 1° a
    # substep passes through unchanged.
    lag = {"steering_lag": {"tau_s": 0.2}}
    cmd = np.array([20.0, 20.0])
    free, _ = actuate_sequence(params(**lag), cmd, np.ones(2), 8, H)
    both, _ = actuate_sequence(params(**lag, steering_rate={"s_per_60deg": 0.5}), cmd, np.ones(2), 8, H)
    np.testing.assert_allclose(both, free, rtol=1e-12)


def test_understeer_divides_by_one_plus_k_v_squared():
    p = params(understeer={"k_s2pm2": 0.25})
    steer, _ = actuate_sequence(p, np.array([20.0, 20.0]), np.array([1.0, 2.0]), 1, H)
    np.testing.assert_allclose(steer, [20 / 1.25, 20 / 2.0])


def test_streaming_equals_batch():
    cal = CarCalibration.from_values(
        {
            "steering_delay": {"delay_s": 0.07},
            "steering_lag": {"tau_s": 0.3},
            "steering_rate": {"s_per_60deg": 0.2},
            "speed_delay": {"delay_s": 0.03},
            "speed_lag": {"tau_s": 0.2},
            "understeer": {"k_s2pm2": 0.1},
        }
    )
    rng = np.random.default_rng(0)
    steer_cmd, speed_cmd = rng.uniform(-30, 30, 40), rng.uniform(0.5, 3, 40)
    batch = actuate_sequence(ActuationParams.from_calibration(cal), steer_cmd, speed_cmd, 8, H)
    act = Actuation(cal, H)
    pieces = [act.step(s, v, 8) for s, v in zip(steer_cmd, speed_cmd, strict=True)]
    np.testing.assert_allclose(np.concatenate([p[0] for p in pieces]), batch[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.concatenate([p[1] for p in pieces]), batch[1], rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------------------------- in the car


def _physics(cal: CarCalibration | None) -> CarPhysics:
    ph = CarPhysics(build_model(TextureFrame(x0=-20, y1=20, ppm=1, width=40, height=40)))
    ph.set_calibration(cal)
    return ph


def test_steering_lag_slows_the_hinges_of_the_car():
    fast, slow = _physics(None), _physics(CarCalibration.from_values({"steering_lag": {"tau_s": 0.5}}))
    for ph in (fast, slow):
        ph.reset(Pose(0, 0, 0))
        ph.command(20.0, 1.0)
        for _ in range(5):  # 1/3 s
            ph.step()
    assert fast.steering_deg == pytest.approx(20.0, abs=0.5)
    # The servo follows its lagged target closely: 20 · (1 - e^(-1/3 / 0.5)) = 9.7 degrees, give or take.
    assert slow.steering_deg == pytest.approx(20 * (1 - math.exp(-(1 / 3) / 0.5)), abs=1.0)


def test_reset_clears_the_actuation_state():
    ph = _physics(CarCalibration.from_values({"speed_lag": {"tau_s": 0.3}}))
    ph.reset(Pose(0, 0, 0))
    ph.command(0.0, 2.0)
    for _ in range(15):
        ph.step()
    ph.reset(Pose(0, 0, 0))
    ph.step()  # still commanded 2 m/s, but the lag starts again from rest
    assert ph.speed < 0.5


def test_tyre_friction_sets_the_contact_friction():
    ph = _physics(CarCalibration.from_values({"tyre_friction": {"mu": 0.4}}))
    tyres = [ph.model.geom(f"{w}_tyre").id for w in ("fl", "fr", "rl", "rr")]
    np.testing.assert_allclose(ph.model.geom_friction[tyres, 0], 0.4)
    ph.reset(Pose(0, 0, 0))
    ph.command(0.0, 1.0)
    ph.step()
    # The tyres' priority makes their friction the contact's, not the larger of tyre and ground.
    contact_mu = [ph.data.contact[i].friction[0] for i in range(ph.data.ncon)]
    assert contact_mu and np.allclose(contact_mu, 0.4)


def test_env_applies_the_calibration_from_its_config():
    cal = CarCalibration.from_values({"speed_lag": {"tau_s": 0.5}})
    plain, calibrated = RacerEnv(EnvConfig(track=DEFAULT_TRACK)), RacerEnv(EnvConfig(track=DEFAULT_TRACK, car=cal))
    speeds = []
    for env in (plain, calibrated):
        env.reset(seed=1, options={"start_index": 0})
        straight_fast = max(
            range(env.actions.n), key=lambda a: env.actions.command(a)[1] - abs(env.actions.command(a)[0])
        )
        for _ in range(4):
            env.step(straight_fast)
        speeds.append(env.physics.speed)
    assert speeds[1] < 0.75 * speeds[0]
    assert json.loads(EnvConfig(car=cal).model_dump_json())["car"]["effects"][0]["name"] == "speed_lag"


def test_the_lag_loop_gives_lfilters_floats_bit_for_bit():
    """A control period's few substeps go through a Python loop (4 us a call faster than lfilter), long replays
    through lfilter: both must give the very same floats, or a replay and the env disagree."""
    from scipy.signal import lfilter

    from sim.actuation import _LOOP_MAX, _lag

    rng = np.random.default_rng(0)
    for n in (1, 8, _LOOP_MAX, _LOOP_MAX + 1, 500):
        u = rng.normal(size=n) * 10
        a = math.exp(-H / 0.5)
        expected, _ = lfilter([1 - a], [1, -a], u, zi=[a * 0.7])
        assert _lag(u, 0.7, 0.5, H).tolist() == expected.tolist()
