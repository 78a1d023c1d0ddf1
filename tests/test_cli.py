"""The racer command line: tracks, pictures, the env benchmark and the random drive."""

import json
import subprocess
import sys

import cv2
from typer.testing import CliRunner

from racer.cli import app
from sim.track import bundled_track_names

runner = CliRunner()


def test_tracks_ls_lists_every_bundled_track():
    result = runner.invoke(app, ["tracks", "ls"])
    assert result.exit_code == 0
    for name in bundled_track_names():
        assert name in result.output
    assert "CW" in result.output and "open" in result.output


def test_tracks_show_writes_a_picture_of_track_and_camera(tmp_path):
    png = tmp_path / "track.png"
    result = runner.invoke(app, ["tracks", "show", "reinvent_base", "--png", str(png)])
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


def test_bench_env_json_has_rate_and_parts(tmp_path):
    # A subprocess: the benchmark pins its process to one core, which must not pin the test runner.
    out = tmp_path / "bench.json"
    cmd = [sys.executable, "-m", "racer", "bench", "env", "--steps", "200", "--repeats", "1", "--json", str(out)]
    subprocess.run(cmd, check=True, capture_output=True, timeout=300)
    result = json.loads(out.read_text())
    assert result["steps_per_s"] > 0
    for part in ("physics", "camera", "task", "reward"):
        assert result[f"{part}_us_per_step"] > 0
