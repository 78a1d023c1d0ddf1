"""Residual structure: noise must read as noise, and an effect the model lacks as structure, in the right place
and with the right sign.

The windows come from hand-made trajectories (a kinematic car driven by DeepRacer-like held actions); the
residuals are made directly, as noise plus a planted effect, so each test knows the answer.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim.calibration.logs import Trajectory
from sim.calibration.replay import Windows, make_windows
from sim.calibration.residual import residual_structure, window_rows

DT = 1 / 15
WHEELBASE_M = 0.16


def _trajectory(rng: np.random.Generator, episode: int, steps: int) -> Trajectory:
    """A kinematic car: held actions (7 steering angles × 3 speeds, 1 to 4 rows each); speed follows the
    command with a 0.3 s lag, so windows after a speed-up accelerate."""
    steer, speed = [], []
    while len(steer) < steps:
        hold = int(rng.integers(1, 5))
        steer += [float(rng.choice([-30, -20, -10, 0, 10, 20, 30]))] * hold
        speed += [float(rng.choice([1.0, 2.0, 3.0]))] * hold
    steer_a, speed_a = np.array(steer[:steps]), np.array(speed[:steps])
    x, y, h, v = np.zeros(steps), np.zeros(steps), np.zeros(steps), np.zeros(steps)
    h[0], v[0] = rng.uniform(-np.pi, np.pi), 1.0
    for k in range(steps - 1):
        v[k + 1] = v[k] + (speed_a[k] - v[k]) * (1 - np.exp(-DT / 0.3))
        h[k + 1] = h[k] + v[k] * np.tan(np.radians(steer_a[k])) / WHEELBASE_M * DT
        x[k + 1] = x[k] + v[k] * np.cos(h[k]) * DT
        y[k + 1] = y[k] + v[k] * np.sin(h[k]) * DT
    heading = np.degrees(np.remainder(h + np.pi, 2 * np.pi) - np.pi)
    return Trajectory(
        "synthetic",
        episode,
        np.arange(steps) * DT,
        steer_cmd_deg=steer_a,
        speed_cmd_mps=speed_a,
        x=x,
        y=y,
        heading_deg=heading,
    )


def _windows(seed: int = 0, episodes: int = 30, steps: int = 150) -> Windows:
    rng = np.random.default_rng(seed)
    return make_windows([_trajectory(rng, ep, steps) for ep in range(episodes)], timing="nominal")


def _noise(windows: Windows, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """White noise of a calibrated car's size: 3 cm, 1°, 0.1 m/s per row (speeds: as many as replay measures)."""
    shape = (len(windows), windows.horizon)
    return {
        "dx": rng.normal(0, 0.03, shape),
        "dy": rng.normal(0, 0.03, shape),
        "dheading": rng.normal(0, 1.0, shape),
        "dspeed": rng.normal(0, 0.1, windows.measured()["speed"].shape),
    }


WINDOWS = _windows()


def test_white_noise_is_not_structure():
    flagged = 0
    for seed in range(20):
        out = residual_structure(_noise(WINDOWS, np.random.default_rng(seed)), WINDOWS)
        flagged += out["structured"]
        assert out["structured"] == bool(out["where"])  # nothing pointed at unless something is flagged
    assert flagged <= 1
    assert out["tests"]["tests"] > 100  # bins × channels and the regressions, all under one threshold


@pytest.mark.parametrize(("gain", "wording"), [(0.06, "turns less than the model"), (-0.06, "turns more")])
def test_heading_error_in_fast_turns_is_found_with_its_sign(gain, wording):
    """Heading error (model minus car) proportional to the steering command, growing over the window, in fast
    windows only: positive gain = the model turns more than the car."""
    rng = np.random.default_rng(1)
    res = _noise(WINDOWS, rng)
    steer, speed = WINDOWS.commands()
    fast = speed.mean(axis=1) >= np.quantile(speed.mean(axis=1), 2 / 3)
    growth = np.arange(1, WINDOWS.horizon + 1) / WINDOWS.horizon
    res["dheading"] += np.where(fast[:, None], gain * steer.mean(axis=1)[:, None] * growth, 0.0)
    out = residual_structure(res, WINDOWS)
    assert out["structured"]
    top = out["where"][0]
    assert top["channel"] == "heading_deg"
    assert "fast" in top["condition"] and "turn" in top["condition"]
    assert wording in top["says"] and "fast" in top["says"]
    assert not any("slow" in w["condition"] for w in out["where"])  # no effect planted there
    json.loads(json.dumps(out, allow_nan=False))  # the report is plain JSON


def test_speed_bias_when_accelerating_is_found():
    rng = np.random.default_rng(2)
    res = _noise(WINDOWS, rng)
    _, speed = WINDOWS.commands()
    accelerating = speed.mean(axis=1) - WINDOWS.measured()["speed"][:, 0] > 0.2
    res["dspeed"] += np.where(accelerating[:, None], 0.08, 0.0)  # the model speeds up more than the car
    out = residual_structure(res, WINDOWS)
    assert out["structured"]
    top = out["where"][0]
    assert (top["channel"], top["condition"]) == ("speed_mps", "accelerating")
    assert top["mean"] == pytest.approx(0.08, abs=0.02) and top["t"] > 0
    assert top["says"] == "the car is slower than the model when accelerating"
    assert not residual_structure(res, WINDOWS, z_max=40.0)["structured"]  # z_max is the threshold


def test_residuals_not_of_the_windows_shape_are_refused():
    res = _noise(WINDOWS, np.random.default_rng(0))
    res["dheading"] = res["dheading"][:, :-1]
    with pytest.raises(ValueError, match="'dheading' has shape"):
        residual_structure(res, WINDOWS)
    res = _noise(WINDOWS, np.random.default_rng(0))
    res["dspeed"] = res["dspeed"][:-1]
    with pytest.raises(ValueError, match="'dspeed' has shape"):
        residual_structure(res, WINDOWS)


def test_position_errors_are_read_along_and_across_the_measured_path():
    """Windows of a car heading north (+y): a model east of it (+x) is to its right: negative cross-track."""
    n = 40
    t = np.arange(n) * DT
    north = Trajectory(
        "synthetic",
        0,
        t,
        steer_cmd_deg=np.zeros(n),
        speed_cmd_mps=np.ones(n),
        x=np.zeros(n),
        y=t.copy(),
        heading_deg=np.full(n, 90.0),
    )
    windows = make_windows([north], timing="nominal")
    shape = (len(windows), windows.horizon)
    res = {"dx": np.full(shape, 0.05), "dy": np.full(shape, -0.02), "dheading": np.zeros(shape)}
    rows = window_rows({**res, "dspeed": np.zeros(windows.measured()["speed"].shape)}, windows)
    assert np.allclose(rows["cross_track_m"], -0.05) and np.allclose(rows["along_track_m"], -0.02)
