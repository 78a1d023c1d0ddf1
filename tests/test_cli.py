"""The racer command line: tracks, pictures, the env benchmark and the random drive."""

import json
import subprocess
import sys

import cv2
import pytest
from typer.testing import CliRunner

from common.defaults import DEFAULT_TRACK
from racer.cli import app
from sim.track_gen import racer_track_names

runner = CliRunner()


def test_tracks_ls_lists_racers_tracks_the_cached_ones_and_what_can_be_pulled(tmp_path, monkeypatch):
    monkeypatch.setenv("RACER_TRACKS_DIR", str(tmp_path))
    monkeypatch.setenv("COLUMNS", "200")
    (tmp_path / "Oval_track.npy").write_bytes(_ring_npy())  # a track in the folder, by the name of a DeepRacer one
    result = runner.invoke(app, ["tracks", "ls"])
    assert result.exit_code == 0, result.output
    for name in racer_track_names():
        assert name in result.output
    assert "CW" in result.output and "open" in result.output
    cached = [line for line in result.output.splitlines() if "Oval_track" in line and "DeepRacer" in line]
    assert cached and "12.57" in cached[0]  # its own length (a 2 m ring), read from the folder
    assert "126 DeepRacer tracks can be pulled" in result.output and "reinvent_base" in result.output


def _ring_npy() -> bytes:
    import io

    import numpy as np

    theta = np.linspace(0, 2 * np.pi, 201)
    c, s = np.cos(theta), np.sin(theta)
    arr = np.column_stack([2 * c, 2 * s, 1.6 * c, 1.6 * s, 2.4 * c, 2.4 * s])
    arr[-1] = arr[0]
    buf = io.BytesIO()
    np.save(buf, arr)
    return buf.getvalue()


def test_tracks_show_writes_a_picture_of_track_and_camera(tmp_path):
    png = tmp_path / "track.png"
    result = runner.invoke(app, ["tracks", "show", DEFAULT_TRACK, "--png", str(png)])
    assert result.exit_code == 0, result.output
    img = cv2.imread(str(png))
    assert img is not None and img.shape[1] > img.shape[0]
    assert img.std() > 20  # not blank
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    assert (gray > 200).mean() > 0.005  # white border lines are there


def test_bad_track_is_a_one_line_error_with_nonzero_exit(tmp_path):
    bad = tmp_path / "broken.npy"
    bad.write_text("not numpy")
    result = runner.invoke(app, ["tracks", "show", str(bad), "--png", str(tmp_path / "x.png")])
    assert result.exit_code == 2
    assert "broken.npy" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "x.png").exists()


def test_drive_reports_episodes_as_json(tmp_path):
    out = tmp_path / "drive.json"
    result = runner.invoke(app, ["drive", "--episodes", "2", "--json", str(out)])
    assert result.exit_code == 0, result.output
    rows = json.loads(out.read_text())
    assert len(rows) == 2 and all(r["steps"] >= 1 for r in rows)
    assert {r["status"] for r in rows} <= {"off_track", "lap_complete", "immobilized", "reversed", "time_up"}


@pytest.mark.slow(reason="starts real racer processes")
def test_bench_env_json_has_rate_and_parts(tmp_path):
    # A subprocess: the benchmark pins its process to one core, which must not pin the test runner.
    out = tmp_path / "bench.json"
    cmd = [sys.executable, "-m", "racer", "bench", "env", "--steps", "200", "--repeats", "1", "--json", str(out)]
    subprocess.run(cmd, check=True, capture_output=True, timeout=300)
    result = json.loads(out.read_text())
    assert result["steps_per_s"] > 0
    for part in ("physics", "camera", "task", "reward"):
        assert result[f"{part}_us_per_step"] > 0
    # Without --sensor or --race-type the JSON is what it always was.
    assert not {"sensor", "race_type", "objects", "lidar_us_per_step", "objects_us_per_step"} & set(result)


@pytest.mark.slow(reason="starts real racer processes")
def test_bench_env_with_sensors_and_a_race_adds_them_and_their_parts(tmp_path):
    out = tmp_path / "bench.json"
    cmd = [sys.executable, "-m", "racer", "bench", "env", "--steps", "100", "--repeats", "1", "--json", str(out)]
    cmd += ["--sensor", "STEREO_CAMERAS,SECTOR_LIDAR", "--race-type", "OBJECT_AVOIDANCE", "--obstacles", "2"]
    subprocess.run(cmd, check=True, capture_output=True, timeout=300)
    result = json.loads(out.read_text())
    assert result["steps_per_s"] > 0 and len(result["steps_per_s_runs"]) == 1
    assert result["sensor"] == ["STEREO_CAMERAS", "SECTOR_LIDAR"]
    assert result["race_type"] == "OBJECT_AVOIDANCE" and result["objects"] == 2
    for part in ("physics", "camera", "lidar", "objects", "task", "reward"):
        assert result[f"{part}_us_per_step"] > 0


@pytest.mark.slow(reason="starts real racer processes")
def test_bench_env_reports_none_for_the_parts_an_env_does_not_have():
    from common.config import EnvConfig
    from racer.bench.env import race_config

    # A child process: bench_env pins its process to one core.
    code = (
        "import json, sys; from common.config import EnvConfig; from racer.bench.env import bench_env, race_config; "
        "r = bench_env(EnvConfig(), steps=20, repeats=1, race=race_config('HEAD_TO_BOT', 0)); "
        "sys.stdout.write(json.dumps(r))"
    )
    done = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True, timeout=300)
    result = json.loads(done.stdout)
    assert result["race_type"] == "HEAD_TO_BOT" and result["objects"] == 0
    assert result["sensor"] == ["FRONT_FACING_CAMERA"]
    assert result["lidar_us_per_step"] is None and result["objects_us_per_step"] is None
    assert race_config("OBJECT_AVOIDANCE").obstacle_count == 6 and race_config("head_to_bot").bot_car_count == 3
    assert race_config("TIME_TRIAL") == EnvConfig().race


def test_bench_env_refuses_bad_sensor_and_race_options():
    for args, message in (
        (["--obstacles", "3"], "--obstacles needs --race-type"),
        (["--race-type", "F1"], "--race-type 'F1' is not one of"),
        (["--race-type", "TIME_TRIAL", "--obstacles", "2"], "--obstacles needs --race-type"),
        (["--sensor", "LIDAR"], "exactly one camera"),
        (["--sensor", "FRONT_FACING_CAMERA,RADAR"], "not a DeepRacer sensor"),
    ):
        result = runner.invoke(app, ["bench", "env", "--steps", "100", *args])
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output and "Traceback" not in result.output


def test_racer_bench_only_registers_the_benchmarks():
    """Each ``racer bench`` command parses its options and shows what its module's ``command`` returns: no table,
    check or figure is built in the CLI (racer/bench/ holds them)."""
    import ast
    import inspect

    import racer.commands.bench as cli_bench

    tree = ast.parse(inspect.getsource(cli_bench))
    commands = [f for f in tree.body if isinstance(f, ast.FunctionDef) and f.decorator_list]
    assert len(commands) == 14
    for f in commands:
        calls = [n.func for n in ast.walk(f) if isinstance(n, ast.Call)]
        shown = [c for c in calls if isinstance(c, ast.Name) and c.id == "_show"]
        assert len(shown) == 1, f.name
        assert len(f.body) <= 7, f"racer bench {f.name}: {len(f.body)} statements"
        assert not any(isinstance(c, ast.Name) and c.id in ("Table", "OptionError") for c in calls), f.name
