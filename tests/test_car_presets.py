"""Car presets (``--car NAME``): the shipped car files, how physics applies them, how they score on DeepRacer's logs.

Their fit's reproducibility is tests/test_preset_refit.py. DeepRacer's public Gazebo logs are read in place from
../shared/data (tests/shared_data.py); the tests that need them skip without it.
"""

import json
import math
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from common.car_calibration import (
    CANDIDATE_EFFECTS,
    CAR_PRESETS,
    EFFECTS,
    MODEL_EFFECTS,
    CalibrationError,
    CarCalibration,
    load_calibration,
    load_car,
)
from racer.calibrate import run_calibrate
from racer.cli import app
from sim.physics import CarPhysics, Pose
from sim.texture import TextureFrame
from sim.world import build_model
from tests.shared_data import shared_data

CARS = Path(str(resources.files("sim") / "cars"))
GAZEBO = ("deepracer-gazebo", "deepracer-gazebo-ros2")
_MODEL_FIELDS = ("body_mass", "body_inertia", "body_ipos", "body_iquat", "body_invweight0", "dof_invweight0")
_MODEL_FIELDS += ("actuator_gainprm", "actuator_biasprm", "actuator_forcerange", "geom_friction")


def _physics(car: CarCalibration | None = None) -> CarPhysics:
    ph = CarPhysics(build_model(TextureFrame(x0=-20, y1=20, ppm=1, width=40, height=40)))
    ph.set_calibration(car)
    return ph


# ------------------------------------------------------------------------------------------------ the files


@pytest.mark.parametrize("name", GAZEBO)
def test_a_preset_loads_by_name_and_as_a_file(name):
    by_name = load_car(name)
    path = CARS / f"{name}.json"
    assert by_name == load_car(str(path)) == load_calibration(path) == CAR_PRESETS[name]
    assert by_name.about and "simapp" in by_name.about  # says where its values came from
    # Built from the simapp's car: its mass and friction, and a steering servo that lags.
    assert by_name.value("chassis", "mass_kg") == pytest.approx(5.0, abs=1.0)
    assert by_name.value("wheels", "mass_kg") == pytest.approx(0.34055)
    assert by_name.value("steering_lag", "tau_s") > 0.1
    # Fitted values carry their standard errors; the design's masses and drives do not.
    assert all(e.stderr for e in by_name.effects if EFFECTS[e.name].candidate and e.params != _design(name, e.name))
    assert not any(e.stderr for e in by_name.effects if not EFFECTS[e.name].candidate)


def test_default_is_the_car_as_modelled_and_bad_names_are_one_line():
    assert load_car("default") == CarCalibration() and load_car("default").is_identity
    assert list(CAR_PRESETS) == ["default", *GAZEBO]
    with pytest.raises(CalibrationError) as err:
        load_car("deepracer-gazbo")
    message = str(err.value)
    assert "\n" not in message and "deepracer-gazbo" in message and "deepracer-gazebo" in message


def test_old_car_files_still_load(tmp_path):
    path = tmp_path / "car.json"
    path.write_text(json.dumps({"version": 1, "effects": [{"name": "steering_lag", "params": {"tau_s": 0.5}}]}))
    car = load_calibration(path)
    assert car.about is None and car.value("chassis", "mass_kg") == EFFECTS["chassis"].params["mass_kg"].identity
    path.write_text(json.dumps({"effects": [{"name": "chassis", "params": {"mass_kg": 5.0}}]}))
    with pytest.raises(CalibrationError, match="chassis"):
        load_calibration(path)


# ------------------------------------------------------------------------------------------------ physics


def test_physics_writes_the_preset_into_the_model_and_restores_the_default_exactly():
    compiled = _physics()
    car = load_car("deepracer-gazebo")
    ph = _physics(car)
    m = ph.model
    assert m.body_mass[m.body("car").id] == car.value("chassis", "mass_kg")
    np.testing.assert_allclose(m.body_inertia[m.body("car").id], [car.value("chassis", f"i{a}{a}_kgm2") for a in "xyz"])
    assert m.body_mass[m.body("rl_wheel").id] == car.value("wheels", "mass_kg")
    assert m.body_inertia[m.body("rl_wheel").id][1] == car.value("wheels", "spin_inertia_kgm2")
    assert m.body_mass[m.body("fl_steer").id] == car.value("wheels", "hinge_mass_kg")
    assert m.geom_friction[m.geom("fl_tyre").id, 0] == car.value("tyre_friction", "mu")
    rear, front = m.actuator("rl_drive").id, m.actuator("fl_drive").id
    assert m.actuator_gainprm[rear, 0] == car.value("drive", "rear_gain_nms")
    assert m.actuator_gainprm[front, 0] == car.value("drive", "front_gain_nms")
    assert m.actuator_forcerange[rear, 1] == car.value("drive", "max_torque_nm")
    # MuJoCo's constants derived from the masses follow the new car.
    assert m.body_subtreemass[m.body("car").id] == pytest.approx(sum(m.body_mass[1:]))
    # Back to the default: bit for bit the compiled model, as a car that never had a preset.
    ph.set_calibration(None)
    for field in _MODEL_FIELDS:
        assert np.array_equal(getattr(m, field), getattr(compiled.model, field)), field


def test_default_car_is_untouched_by_set_calibration():
    fresh = build_model(TextureFrame(x0=-20, y1=20, ppm=1, width=40, height=40))
    ph = _physics(CarCalibration())
    for field in (*_MODEL_FIELDS, "body_subtreemass"):
        assert np.array_equal(getattr(ph.model, field), getattr(fresh, field)), field


def test_domain_randomization_scales_the_preset_and_restores_it():
    ph = _physics(load_car("deepracer-gazebo"))
    car = ph.model.body("car").id
    ph.set_dynamics(friction_scale=0.8, mass_scale=1.2)
    assert ph.model.body_mass[car] == pytest.approx(1.2 * load_car("deepracer-gazebo").value("chassis", "mass_kg"))
    ph.set_dynamics()
    assert ph.model.body_mass[car] == load_car("deepracer-gazebo").value("chassis", "mass_kg")


def _drive(ph: CarPhysics, steer: float, speed: float, steps: int) -> list[tuple[float, float]]:
    ph.reset(Pose(0.0, 0.0, 0.0))
    out = []
    for _ in range(steps):
        ph.command(steer, speed)
        ph.step()
        out.append((ph.speed, ph.yaw_rate))
    return out


@pytest.mark.parametrize(("name", "accelerates"), [("deepracer-gazebo", "slower"), ("deepracer-gazebo-ros2", "faster")])
def test_the_gazebo_cars_differ_from_the_default_as_their_logs_do(name, accelerates):
    default, gazebo = _physics(), _physics(load_car(name))
    # Straight ahead from rest to 2 m/s: both get there. The ROS1 car takes longer (a 0.25 s speed lag on top of
    # its tyres' grip); the ROS2 car gets there within about two control steps, sooner than the default car,
    # whose wheel drives are weak (0.12 N·m).
    d, g = _drive(default, 0.0, 2.0, 30), _drive(gazebo, 0.0, 2.0, 30)
    assert g[-1][0] == pytest.approx(2.0, abs=0.1) and d[-1][0] == pytest.approx(2.0, abs=0.1)
    early_d, early_g = sum(v for v, _ in d[:6]), sum(v for v, _ in g[:6])
    assert early_g < 0.9 * early_d if accelerates == "slower" else early_g > 1.1 * early_d
    # A 20° turn at 1 m/s: the default car's hinges are there within a step; the Gazebo cars' steering lags
    # (their simapp servos), so they turn less in the first 0.4 s, and on no tighter a circle once settled
    # (curvature = yaw rate / speed: the default car's weak drives lose speed in the turn).
    d, g = _drive(default, 20.0, 1.0, 30), _drive(gazebo, 20.0, 1.0, 30)
    assert sum(r for _, r in g[:6]) < 0.8 * sum(r for _, r in d[:6])
    assert g[-1][1] / g[-1][0] < d[-1][1] / d[-1][0] + 0.05
    assert gazebo.upright and all(math.isfinite(v) for v, _ in g)


# ------------------------------------------------------------------------------------------------ the fit


def _design(name: str, effect: str) -> dict[str, float] | None:
    design = load_calibration(CARS / "design" / f"{name}.json")
    return next((e.params for e in design.effects if e.name == effect), None)


def _ros1_log() -> Path:
    """The first iteration (20 episodes) of the ROS1 console training logs, the set ``deepracer-gazebo`` was fitted
    on (tests/test_preset_refit.py refits it on its selection of all 28)."""
    return shared_data("logs", "gazebo-ros1-console2022-reinvent_base", "training-simtrace", "0-iteration.csv")


def test_calibrate_applies_a_preset_by_name():
    report = run_calibrate([_ros1_log()], apply="deepracer-gazebo", say=lambda _: None)
    assert report["calibration"] == "deepracer-gazebo"
    for key in ("position_m", "heading_deg"):
        assert report["error_after"][key] < 0.6 * report["error_before"][key]


def test_calibrate_names_an_unknown_car_in_one_line(tmp_path):
    result = CliRunner().invoke(app, ["calibrate", str(tmp_path / "log.csv"), "--apply", "no-such-car"])
    assert result.exit_code == 2 and "no-such-car" in result.output and "Traceback" not in result.output


def test_calibrate_builds_on_a_base_car_and_keeps_its_design(tmp_path):
    lines = _ros1_log().read_text().splitlines()
    keep = [line for line in lines[1:] if int(line.split(",", 1)[0]) < 8]  # eight episodes: fit, choose, report
    log = tmp_path / "gazebo-ros1-reinvent_base.csv"
    log.write_text("\n".join([lines[0], *keep]) + "\n")
    report = run_calibrate(
        [log],
        base=str(CARS / "design" / "deepracer-gazebo.json"),
        effects=["speed_gain"],
        max_windows=20,
        say=lambda _: None,
    )
    by_name = {e["name"]: e for e in report["base"]}  # the design is the car: its base, not effects
    design = load_calibration(CARS / "design" / "deepracer-gazebo.json")
    for effect in ("chassis", "wheels", "drive"):
        assert by_name[effect]["params"] == _design("deepracer-gazebo", effect) and "stderr" not in by_name[effect]
    assert "error_base" in report and {e.name for e in design.effects} <= set(by_name)
    assert not {e.name for e in design.effects} & {e["name"] for e in report["effects"]}


def test_model_effects_are_not_fitted_unless_asked():
    assert {"chassis", "wheels", "drive"} <= set(MODEL_EFFECTS) - set(CANDIDATE_EFFECTS)
    assert "tyre_friction" in CANDIDATE_EFFECTS and "tyre_friction" in MODEL_EFFECTS
