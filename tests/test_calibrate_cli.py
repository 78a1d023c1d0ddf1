"""``racer calibrate`` on one iteration of DeepRacer's public Gazebo logs, ``--apply``, and its bad input.

The logs are read in place from ../shared/data (tests/shared_data.py); the tests that need them skip without it.
"""

import json
from pathlib import Path

import cv2
import pytest
from typer.testing import CliRunner

from common.car_calibration import CarCalibration, load_calibration, save_calibration
from racer.cli import app
from racer.runconfig import build_run
from tests.shared_data import shared_data

runner = CliRunner()


@pytest.fixture(scope="module")
def ros1() -> Path:
    """The first iteration (20 episodes) of the ROS1 console training logs: DeepRacer's Gazebo car."""
    return shared_data("logs", "gazebo-ros1-console2022-reinvent_base", "training-simtrace", "0-iteration.csv")


@pytest.fixture(scope="module")
def fitted(tmp_path_factory, ros1) -> dict:
    """One fit on those logs (candidates limited to three effects to keep the test short)."""
    out = tmp_path_factory.mktemp("cal")
    args = ["calibrate", str(ros1), "--out", str(out / "car.json"), "--json", str(out / "r.json")]
    args += ["--png", str(out / "r.png"), "--max-windows", "40"]
    for effect in ("steering_lag", "speed_lag", "steering_gain"):
        args += ["--effect", effect]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    return {"dir": out, "output": result.output, "report": json.loads((out / "r.json").read_text())}


@pytest.mark.slow(reason="fits a car to logs")
def test_calibrate_writes_the_design_report_and_a_calibration(fitted):
    report = fitted["report"]
    assert {"effects", "error_before", "error_after", "fit_on", "evaluated_on"} <= set(report)
    for key in ("error_before", "error_after"):
        assert {"position_m", "heading_deg", "speed_mps"} <= set(report[key])
    # The Gazebo car's steering lags far behind our car's: the fit finds it and the held-out error drops.
    names = [e["name"] for e in report["effects"]]
    assert "steering_lag" in names
    tau = next(e for e in report["effects"] if e["name"] == "steering_lag")["params"]["tau_s"]
    assert 0.2 < tau < 1.5  # a few tenths of a second (19 episodes: a loose bound)
    # 19 episodes, 12 choosing windows: a loose bound (measured: heading 11.9° -> 7.4°, steering gain 0.46 and
    # lag 0.38 s, a pair the fit cannot separate on so little data and says so)
    assert report["error_after"]["heading_deg"] < 0.7 * report["error_before"]["heading_deg"]
    assert report["error_after"]["position_m"] < 0.9 * report["error_before"]["position_m"]  # measured 0.146 -> 0.126
    fit_eps = {(f["file"], e) for f in report["fit_on"] for e in f["episodes"]}
    eval_eps = {(f["file"], e) for f in report["evaluated_on"] for e in f["episodes"]}
    assert fit_eps and eval_eps and not fit_eps & eval_eps
    cal = load_calibration(fitted["dir"] / "car.json")
    assert [e.name for e in cal.effects] == names
    assert "steering_lag" in fitted["output"] and "heading" in fitted["output"]


def test_calibrate_writes_a_picture(fitted):
    img = cv2.imread(str(fitted["dir"] / "r.png"))
    assert img is not None and img.shape[0] > 400 and img.shape[1] > 600
    assert img.std() > 20


def test_apply_scores_a_calibration_on_other_logs(fitted, ros1, tmp_path):
    out = tmp_path / "apply.json"
    result = runner.invoke(
        app, ["calibrate", "--apply", str(fitted["dir"] / "car.json"), str(ros1), "--json", str(out)]
    )
    assert result.exit_code == 0, result.output
    report = json.loads(out.read_text())
    assert report["fit_on"] == []
    assert [f["file"] for f in report["evaluated_on"]] == [str(ros1)]
    # The car applied is the car fitted: its base and its effects, each with the values the fit reported.
    fitted_car = fitted["report"]["base"] + fitted["report"]["effects"]
    assert sorted((e["name"], e["params"]) for e in report["effects"]) == sorted(
        (e["name"], e["params"]) for e in fitted_car
    )
    assert all("value" in e for e in report["effects"])
    # Scored on every window of the log, the calibrated car still beats the uncalibrated one.
    assert report["error_after"]["position_m"] < report["error_before"]["position_m"]


def test_json_to_stdout_is_only_json(fitted, ros1):
    result = runner.invoke(app, ["calibrate", "--apply", str(fitted["dir"] / "car.json"), str(ros1), "--json", "-"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["error_before"]["position_m"] > 0  # nothing but the JSON on stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--effect", "warp_drive"], "warp_drive"),
        (["--apply", "{missing}"], "cannot read"),
        (["--apply", "{bad}"], "unknown effect"),
        (["--apply", "{good}", "--out", "x.json"], "--apply"),
    ],
)
def test_bad_input_is_one_line_and_nonzero(tmp_path, args, message):
    bad = tmp_path / "bad.json"
    bad.write_text('{"effects": [{"name": "nitro", "params": {}}]}')
    good = tmp_path / "good.json"
    save_calibration(CarCalibration(), good)
    paths = {"missing": str(tmp_path / "none.json"), "bad": str(bad), "good": str(good)}
    args = [a.format(**paths) for a in args]
    log = tmp_path / "car.csv"  # a car driving straight at 1 m/s, 20 rows at 15 Hz (racer's plain CSV)
    rows = [f"{k / 15},0,1,{k / 15},0,0" for k in range(20)]
    log.write_text("\n".join(["time_s,steer_cmd_deg,speed_cmd_mps,x_m,y_m,heading_deg", *rows]) + "\n")
    result = runner.invoke(app, ["calibrate", str(log), *args])
    assert result.exit_code != 0
    assert message in result.output and "Traceback" not in result.output


def test_missing_log_is_one_line(tmp_path):
    result = runner.invoke(app, ["calibrate", str(tmp_path / "nope.csv")])
    assert result.exit_code != 0 and "nope.csv" in result.output and "Traceback" not in result.output


def test_train_stores_the_calibration_in_the_run_config(tmp_path):
    cal = CarCalibration.from_values({"steering_lag": {"tau_s": 0.5}})
    save_calibration(cal, tmp_path / "car.json")
    run, _ = build_run("r1", car_calibration=str(tmp_path / "car.json"))
    assert run.env.car == cal
    # Workers read config.json from the store: the calibration travels inside it.
    assert json.loads(run.model_dump_json())["env"]["car"]["effects"][0]["params"] == {"tau_s": 0.5}


def test_bench_env_takes_a_calibration(tmp_path):
    save_calibration(CarCalibration.from_values({"speed_lag": {"tau_s": 0.3}}), tmp_path / "car.json")
    out = tmp_path / "b.json"
    args = ["bench", "env", "--steps", "100", "--repeats", "1", "--car-calibration", str(tmp_path / "car.json")]
    result = runner.invoke(app, [*args, "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert json.loads(out.read_text())["steps_per_s"] > 0
