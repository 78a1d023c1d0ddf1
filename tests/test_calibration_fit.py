"""Calibration on logs from a car with an effect the log does not declare: does it name and measure the effect?

The logs are made here, by driving the simulator's MuJoCo car one physics substep at a time with this file's
own implementation of each effect (forward-Euler lags, a queue for dead time, a plain multiplier for gain),
not with ``sim.actuation``, and are written as plain CSVs with measurement noise. The calibration must choose
the right effect (and none on a clean car), recover its value within a tolerance, and cut the error on
episodes it did not fit on.
"""

from __future__ import annotations

import collections
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from common.car_calibration import CarCalibration, load_calibration
from common.config import EnvConfig
from sim.calibration import read_log
from sim.calibration.fit import BASE_EFFECTS, PARTNERS, calibrate, score
from sim.calibration.logs import Trajectory
from sim.calibration.replay import Replayer, detect_timing, make_windows, residuals
from sim.calibration.response import command_response
from sim.env import RacerEnv
from sim.physics import CarPhysics, Pose
from sim.texture import TextureFrame
from sim.world import build_model

SUBSTEPS, H = 8, 1 / 120
REF = 0.14  # the measured point, ahead of base_link, as in DeepRacer logs


class Injected:
    """An effect between command and servos, written independently of sim/actuation.py."""

    def __init__(self, name: str | None, value: float) -> None:
        self.name, self.value = name, value
        self.queue: collections.deque = collections.deque()
        self.y_steer = self.y_speed = 0.0

    def targets(self, steer: float, speed: float) -> tuple[float, float]:
        """Servo targets for one substep of the command (steer, speed)."""
        if self.name == "steering_gain":
            return self.value * steer, speed
        if self.name == "steering_lag":
            self.y_steer += (steer - self.y_steer) * H / self.value  # forward Euler, not the exact form
            return self.y_steer, speed
        if self.name == "speed_lag":
            self.y_speed += (speed - self.y_speed) * H / self.value
            return steer, self.y_speed
        if self.name == "speed_rate":  # at most 1 m/s every `value` seconds
            self.y_speed += float(np.clip(speed - self.y_speed, -H / self.value, H / self.value))
            return steer, self.y_speed
        if self.name == "steering_delay":
            self.queue.append(steer)
            n = round(self.value / H)
            return (self.queue.popleft() if len(self.queue) > n else 0.0), speed
        assert self.name is None
        return steer, speed


def _commands(rng: np.random.Generator, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """DeepRacer-like actions (7 steering angles × 2 speeds), each held for 1 to 4 steps."""
    steer, speed = [], []
    while len(steer) < steps:
        hold = int(rng.integers(1, 5))
        steer += [float(rng.choice([-30, -20, -10, 0, 10, 20, 30]))] * hold
        speed += [float(rng.choice([1.0, 2.0]))] * hold
    return np.array(steer[:steps]), np.array(speed[:steps])


def write_log(
    path: Path,
    effect: str | None,
    value: float,
    episodes: int = 40,
    steps: int = 60,
    seed: int = 0,
    noise: float = 1.0,
    jitter: bool = False,
) -> Path:
    """Drive the car with the injected effect and write a plain CSV (noisy positions and headings). With
    ``jitter`` each row lasts 6 to 10 substeps instead of 8, and the time stamps say so."""
    rng = np.random.default_rng(seed)
    ph = CarPhysics(build_model(TextureFrame(x0=-50, y1=50, ppm=1, width=100, height=100)))
    lines = ["# reference_point_m: 0.14", "episode,time_s,steer_cmd_deg,speed_cmd_mps,x_m,y_m,heading_deg"]
    for ep in range(episodes):
        ph.reset(Pose(0.0, 0.0, float(rng.uniform(-math.pi, math.pi))))
        inject = Injected(effect, value)
        steer, speed = _commands(rng, steps)
        t = 0.0
        for k in range(steps):
            p = ph.pose
            x, y = p.ahead(REF) + rng.normal(0, 0.003 * noise, 2)  # 3 mm and 0.2° of measurement noise
            heading = math.degrees(math.remainder(p.yaw + math.radians(rng.normal(0, 0.2 * noise)), 2 * math.pi))
            lines.append(f"{ep},{t:.6f},{steer[k]},{speed[k]},{x:.5f},{y:.5f},{heading:.4f}")
            substeps = int(rng.integers(6, 11)) if jitter else SUBSTEPS
            t += substeps * H
            for _ in range(substeps):
                ph.command(*inject.targets(steer[k], speed[k]))
                ph.step(substeps=1)
    path.write_text("\n".join(lines) + "\n")
    return path


CASES = [
    # (effect, injected value, the parameter, relative tolerance on it)
    ("steering_lag", 0.25, "tau_s", 0.15),
    ("steering_lag", 0.6, "tau_s", 0.15),
    ("steering_delay", 0.1, "delay_s", 0.2),
    ("speed_lag", 0.3, "tau_s", 0.15),
    ("steering_gain", 0.6, "gain", 0.1),
    ("speed_rate", 0.4, "s_per_mps", 0.15),
]


@pytest.mark.slow(reason="fits a car to logs")
@pytest.mark.parametrize(("effect", "value", "param", "rtol"), CASES)
def test_calibration_names_and_measures_an_undeclared_effect(tmp_path, effect, value, param, rtol):
    trajectories = read_log(write_log(tmp_path / "car.csv", effect, value))
    result = calibrate(trajectories, max_windows=120, progress=lambda _: None)
    found = {e["name"]: e["params"] for e in result.report["effects"]}
    partner = PARTNERS.get(effect)
    assert set(found) - {partner} == {effect}, f"found {found}"
    if partner in found:  # a dead time and a lag both chosen: together they give the delay, and say so
        total = next(e for e in result.report["effects"] if e["name"] == effect)["determined"]
        assert next(v for k, v in total.items() if k.endswith("total_delay_s")) == pytest.approx(value, rel=rtol)
    else:
        assert found[effect][param] == pytest.approx(value, rel=rtol)
    # The report's rounds account for the result: what was chosen and not dropped since, or the base car's fit.
    rounds = result.report["selection"]
    chosen = {r["chosen"] for r in rounds if r["chosen"]} - {name for r in rounds for name in r["dropped"]}
    assert set(found) <= chosen | set(BASE_EFFECTS)
    entry = next(e for e in result.report["effects"] if e["name"] == effect)
    stderr = entry["stderr"][param]
    assert 0 < stderr < 0.5 * value  # an uncertainty is reported, and it is smaller than the value
    lo, hi = entry["interval_95"]
    assert lo < entry["value"] < hi
    before, after = result.report["error_before"], result.report["error_after"]
    assert after["position_m"] < 0.5 * before["position_m"]
    assert after["heading_deg"] < 0.5 * before["heading_deg"] or effect == "speed_lag"
    assert after["speed_mps"] < before["speed_mps"] or effect != "speed_lag"
    # The report is scored on episodes that neither fitted the parameters nor chose the effects.
    fitted = {(f["file"], e) for f in result.report["fit_on"] for e in f["episodes"]}
    chosen_on = {(f["file"], e) for f in result.report["selected_on"] for e in f["episodes"]}
    scored = {(f["file"], e) for f in result.report["evaluated_on"] for e in f["episodes"]}
    assert scored and not scored & (fitted | chosen_on)


@pytest.mark.slow(reason="fits a car to logs")
def test_clean_car_gets_no_effect(tmp_path):
    trajectories = read_log(write_log(tmp_path / "clean.csv", None, 0.0))
    result = calibrate(trajectories, max_windows=120, progress=lambda _: None)
    assert result.report["effects"] == []
    # racer's own car is its own base: what the base keeps is within a hair of racer's car
    for entry in result.report["base"]:
        assert entry["value"] == pytest.approx(1.0, abs=0.02 if entry["name"].endswith("gain") else 0.2), entry
    # The simulator's own car replays its own log closely: what is left is the noise and the initial state.
    assert result.report["error_before"]["position_m"] < 0.05
    assert result.report["error_before"]["heading_deg"] < 3.0


@pytest.mark.slow(reason="fits a car to logs")
def test_candidates_without_the_base_effects_fit_on_racers_car(tmp_path):
    """``--effect steering_lag`` alone: no base effect to fit first, and the effect is still found."""
    trajectories = read_log(write_log(tmp_path / "car.csv", "steering_lag", 0.3, episodes=12))
    result = calibrate(trajectories, ["steering_lag"], max_windows=30, progress=lambda _: None)
    assert result.report["base"] == []
    assert [e["name"] for e in result.report["effects"]] == ["steering_lag"]


def test_replay_drives_the_simulators_car(tmp_path):
    """A replay window equals stepping the env's car (CarPhysics) from the same state with the same commands."""
    trajectories = read_log(write_log(tmp_path / "c.csv", "steering_lag", 0.3, episodes=2, steps=40))
    cal = CarCalibration.from_values({"steering_lag": {"tau_s": 0.3}, "speed_lag": {"tau_s": 0.2}})
    windows = make_windows(trajectories, stride=7)
    replayer = Replayer(nthread=1)
    sim = replayer.replay(windows, cal)
    starts = replayer.initial_states(windows, cal)
    ph = CarPhysics(build_model(TextureFrame(x0=-50, y1=50, ppm=1, width=100, height=100)))
    ph.set_calibration(cal)
    for i in range(len(windows)):
        tr, k = windows.trajectories[windows.traj[i]], int(windows.start[i])
        ph.reset(Pose(0, 0, 0))
        for j in range(k):  # brings the actuation (lags) to its state at the window start...
            ph.command(tr.steer_cmd_deg[j], tr.speed_cmd_mps[j])
            ph.step()
        # ...then the car is put in the window's measured starting state
        mujoco.mj_setState(ph.model, ph.data, starts[i], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        xs = []
        for j in range(k, k + windows.horizon):
            ph.command(tr.steer_cmd_deg[j], tr.speed_cmd_mps[j])
            ph.step()
            xs.append(ph.pose.ahead(REF))
        np.testing.assert_allclose(np.array(xs)[:, 0], sim["x"][i, 1:], atol=1e-9)
        np.testing.assert_allclose(np.array(xs)[:, 1], sim["y"][i, 1:], atol=1e-9)


@pytest.mark.slow(reason="fits a car to logs")
def test_env_built_with_the_calibration_reproduces_the_measured_car(tmp_path):
    """Fit, write car.json, load it into an env, drive the logged commands: it follows the log, the plain env not."""
    from racer.calibrate import run_calibrate

    log = write_log(tmp_path / "lag.csv", "steering_lag", 0.4, seed=3)
    run_calibrate([log], out=tmp_path / "car.json", max_windows=120, say=lambda _: None)
    car = load_calibration(tmp_path / "car.json")
    errors = {}
    for name, cfg in (("plain", EnvConfig()), ("calibrated", EnvConfig(car=car))):
        env = RacerEnv(cfg)
        errs = []
        for tr in read_log(log)[:6]:
            h0 = math.radians(tr.heading_deg[0])
            env.physics.reset(Pose(tr.x[0] - REF * math.cos(h0), tr.y[0] - REF * math.sin(h0), h0))
            for k in range(len(tr) - 1):
                env.physics.command(tr.steer_cmd_deg[k], tr.speed_cmd_mps[k])
                env.physics.step()
            end = env.physics.pose.ahead(REF)
            errs.append(math.hypot(end[0] - tr.x[-1], end[1] - tr.y[-1]))  # after 4 s of open-loop driving
        errors[name] = float(np.sqrt(np.mean(np.square(errs))))
    assert errors["calibrated"] < 0.25 * errors["plain"], errors
    assert errors["calibrated"] < 0.15


def test_score_on_other_logs_uses_all_their_windows(tmp_path):
    trajectories = read_log(write_log(tmp_path / "g.csv", "steering_gain", 0.6, episodes=6, seed=5))
    right = CarCalibration.from_values({"steering_gain": {"gain": 0.6}})
    result = score(right, trajectories)
    assert result.report["windows_evaluated"] == len(make_windows(trajectories))
    assert result.report["error_after"]["heading_deg"] < 0.3 * result.report["error_before"]["heading_deg"]
    meas = result.windows.measured()
    assert np.allclose(residuals(result.replays["measured"], meas)["dx"], 0)


def test_rows_of_uneven_length_are_replayed_for_their_logged_time(tmp_path):
    """A log whose rows last 50 to 83 ms, with honest time stamps: replayed for the logged steps, the car's own
    log replays almost exactly; replayed on a fixed 1/15 s grid, it does not."""
    trajectories = read_log(write_log(tmp_path / "j.csv", None, 0.0, episodes=8, noise=0.0, jitter=True))
    assert detect_timing(trajectories) == "logged"
    logged = score(CarCalibration(), trajectories).report
    nominal = score(CarCalibration(), trajectories, timing="nominal").report
    assert logged["row_timing"] == "logged" and nominal["row_timing"] == "nominal"
    assert logged["error_before"]["speed_mps"] < 0.3 * nominal["error_before"]["speed_mps"]
    assert logged["error_before"]["position_m"] < 0.05


@pytest.mark.parametrize("rule", ["nominal", "logged", "logged_previous"])
def test_detect_timing_tells_the_three_rules_apart(rule):
    """A point at 1 m/s whose rows last 50–83 ms: the time stamps follow its rows, lead them by one, or jitter."""
    rng = np.random.default_rng(1)
    trajectories = []
    for ep in range(5):
        dur = rng.uniform(0.05, 0.083, 80)
        x = np.r_[0.0, np.cumsum(dur)]  # 1 m/s: the distance of row k is its duration
        stamps = {
            "logged": x,
            "logged_previous": np.r_[0.0, np.cumsum(np.r_[dur[1:], 1 / 15])],
            "nominal": np.arange(81) / 15 + rng.uniform(-0.015, 0.015, 81),
        }[rule]
        zeros = np.zeros(81)
        trajectories.append(
            Trajectory(
                "synthetic", ep, stamps, steer_cmd_deg=zeros, speed_cmd_mps=zeros + 1, x=x, y=zeros, heading_deg=zeros
            )
        )
    assert detect_timing(trajectories) == rule


def test_episodes_too_short_for_a_window_are_a_clear_error(tmp_path):
    trajectories = read_log(write_log(tmp_path / "short.csv", None, 0.0, episodes=2, steps=16))
    with pytest.raises(ValueError, match="no replay window: every episode is shorter than 17 rows"):
        make_windows(trajectories)


def test_command_response_shows_the_lag_and_its_absence(tmp_path):
    """The per-row response of a car with a 0.4 s steering lag decays by exp(-T/τ) a row; our car's own is
    over within two rows. The report carries it for the log and for the model before and after."""
    lagged = read_log(write_log(tmp_path / "lag.csv", "steering_lag", 0.4, episodes=10, noise=0.0))
    weights = command_response(lagged)["steering"]["weights"]
    ratios = np.array(weights[3:8]) / np.array(weights[2:7])
    assert np.median(ratios) == pytest.approx(math.exp(-1 / 15 / 0.4), abs=0.06)
    clean = command_response(read_log(write_log(tmp_path / "c.csv", None, 0.0, episodes=10, noise=0.0)))["steering"]
    assert sum(clean["weights"][:2]) > 0.9 * clean["gain"]
    report = score(CarCalibration(), lagged[:3]).report
    assert set(report["response"]) == {"measured", "before", "after"}
    assert (
        report["response"]["before"]["steering"]["weights"][0]
        > 3 * report["response"]["measured"]["steering"]["weights"][0]
    )
