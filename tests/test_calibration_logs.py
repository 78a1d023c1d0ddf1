"""sim.calibration.logs: reading measured logs (DeepRacer sim-traces, RoboMaker logs, plain CSV) into Trajectories.

The format tests run on sim-traces that racer writes here (:func:`synthetic_simtrace`, through
``common.simtrace.simtrace_row``, DeepRacer's row format); bad files are written to tmp_path. The tests on
DeepRacer's own logs read the public Gazebo logs in place from ../shared/data (tests/shared_data.py) and skip
without them.
"""

import csv
import logging
import math
from pathlib import Path

import numpy as np
import pytest

from common.simtrace import COLUMNS, simtrace_row
from sim.calibration.logs import (
    DEEPRACER_REFERENCE_POINT_M,
    MAX_STEP_M,
    MIN_ROWS,
    PLAIN_COLUMNS,
    SIMTRACE_2026_EXTRA,
    LogError,
    Trajectory,
    read_log,
    read_logs,
)
from tests.shared_data import shared_data

ROS1_SET = "gazebo-ros1-console2022-reinvent_base"
ROS2_SET = "gazebo-ros2-simapp6-reInvent2019_wide_cw"
STEERS = (-30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0)


def synthetic_simtrace(lengths: tuple[int, ...] = (30,) * 15, continuous: bool = False) -> list[str]:
    """Sim-trace lines (header first) written by racer in DeepRacer's format: episodes of the given numbers of rows,
    a car driven from rest by a kinematic bicycle (0.164 m wheelbase) at 15 Hz, cycling through DeepRacer's
    default discrete actions (7 steering angles × 1 or 2 m/s), or with ``continuous`` the 2026 format: the action as
    ``[steer speed]`` and the columns ``obstacle_crash_counter,wall_clock`` appended. Every episode starts with its
    ``prepare`` row; the car leaves the track on its last row."""
    lines = [",".join(COLUMNS + (SIMTRACE_2026_EXTRA if continuous else []))]
    t = 20.0
    for episode, n in enumerate(lengths):
        x, y, yaw = 3.0 + 0.05 * episode, 0.7, 0.0
        for k in range(n):
            steer, speed = STEERS[(3 * k + episode) % 7], 1.0 + (k // 4 + episode) % 2
            index = STEERS.index(steer) + 7 * (speed == 2.0)
            row = simtrace_row(
                episode=episode,
                steps=k + 1,
                x=x,
                y=y,
                yaw_deg=yaw,
                steer_deg=steer + (0.25 if continuous else 0.0),
                throttle=speed * (0.9 if continuous else 1.0),
                action=(steer + 0.25, speed * 0.9) if continuous else index,
                reward=0.0 if k == 0 else 1.0,
                done=k == n - 1,
                all_wheels_on_track=k < n - 1,
                progress=100.0 * k / 200,
                closest_waypoint=k // 3,
                track_len=17.6,
                tstamp=t,
                episode_status="prepare" if k == 0 else "off_track" if k == n - 1 else "in_progress",
            )
            lines.append(",".join(row + (["0", repr(round(1.7e9 + t, 3))] if continuous else [])))
            dt = 1 / 15  # the action of this row drives the car to the next one
            x += speed * dt * math.cos(math.radians(yaw))
            y += speed * dt * math.sin(math.radians(yaw))
            yaw = (yaw + math.degrees(speed * dt * math.tan(math.radians(0.5 * steer)) / 0.164) + 180.0) % 360.0 - 180.0
            t += dt
        t += 1.5
    return lines


def robomaker_log(lines: list[str]) -> str:
    """A RoboMaker log holding the sim-trace rows (no header) as ``SIM_TRACE_LOG:`` lines between other lines."""
    out = ["Executing simulation-entrypoint.sh script", "[RL] Agent init successful", "Created agent: agent"]
    for line in lines[1:]:
        if line.split(",")[1] == "1.0":
            out += ["Reset agent", "Reset agent finished"]
        out.append(f"SIM_TRACE_LOG:{line}")
    return "\n".join([*out, "Training> Name=main_level/agent, Worker=0, Episode=3, Total reward=12.0"]) + "\n"


def write_lines(path: Path, lines: list[str]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


def csv_episodes(path: Path) -> dict[int, list[dict[str, str]]]:
    """The file's rows grouped by episode, read independently of the module under test."""
    out: dict[int, list[dict[str, str]]] = {}
    with path.open() as f:
        for row in csv.DictReader(f):
            out.setdefault(int(row["episode"]), []).append(row)
    return out


def assert_matches_rows(traj: Trajectory, rows: list[dict[str, str]]) -> None:
    """Every sample equals the sim-trace row it came from, column for column."""
    assert len(traj) == len(rows)
    for mine, col in [("t", "tstamp"), ("steer_cmd_deg", "steer"), ("speed_cmd_mps", "throttle")]:
        np.testing.assert_array_equal(getattr(traj, mine), [float(r[col]) for r in rows])
    for mine, col in [("x", "X"), ("y", "Y"), ("heading_deg", "yaw")]:
        np.testing.assert_array_equal(getattr(traj, mine), [float(r[col]) for r in rows])


def stale_first(rows: list[dict[str, str]]) -> bool:
    """Whether an episode's first pose is more than MAX_STEP_M from its second (read independently)."""
    (a, b) = rows[:2]
    return math.hypot(float(b["X"]) - float(a["X"]), float(b["Y"]) - float(a["Y"])) > MAX_STEP_M


# ------------------------------------------------------------------------------------------ sim-traces


def test_simtrace_csv(tmp_path):
    path = write_lines(tmp_path / "0-iteration.csv", synthetic_simtrace((30, 20, 15, 18)))
    rows = csv_episodes(path)
    trajs = read_log(path)
    assert [t.episode for t in trajs] == [0, 1, 3]  # episode 2 has 15 rows (< MIN_ROWS): skipped
    for traj in trajs:
        assert_matches_rows(traj, rows[traj.episode])
        assert np.all(np.diff(traj.t) > 0)
        assert traj.reference_point_m == DEEPRACER_REFERENCE_POINT_M
        assert traj.track is None and traj.source == str(path)
        assert set(traj.steer_cmd_deg) <= set(STEERS) and set(traj.speed_cmd_mps) <= {1.0, 2.0}
    first, prepare = trajs[0], rows[0][0]  # the prepare row is sample 0: the car at rest with the first action
    assert prepare["episode_status"] == "prepare" and len(first) == 30
    assert (first.t[0], first.steer_cmd_deg[0], first.x[0]) == (20.0, float(prepare["steer"]), 3.0)


def test_simtrace_csv_with_2026_columns(tmp_path):
    path = write_lines(tmp_path / "0-iteration.csv", synthetic_simtrace((23, 10, 17), continuous=True))
    rows = csv_episodes(path)
    assert "wall_clock" in rows[0][0] and rows[0][0]["action"] == "[-29.75 0.9]"
    trajs = read_log(path)
    assert [t.episode for t in trajs] == [0, 2]  # episode 1 is shorter than 16 rows
    for traj in trajs:
        assert_matches_rows(traj, rows[traj.episode])
        # continuous actions: the "[steer speed]" action column repeats steer and throttle
        action = np.array([r["action"].strip("[]").split() for r in rows[traj.episode]], dtype=float)
        np.testing.assert_allclose(action, np.c_[traj.steer_cmd_deg, traj.speed_cmd_mps])


@pytest.mark.parametrize(
    ("folder", "track"),
    [
        (ROS1_SET, "reinvent_base"),
        (ROS2_SET, "reInvent2019_wide_cw"),  # the longest name in the path: the clockwise route DeepRacer drove
        ("my-racer_loop_cw-laps", "racer_loop_cw"),
        ("laps", None),
    ],
    ids=["deepracer", "longest", "racer", "none"],
)
def test_track_from_the_path(tmp_path, folder, track):
    path = write_lines(tmp_path / folder / "training-simtrace" / "0-iteration.csv", synthetic_simtrace((20,)))
    assert read_log(path)[0].track == track
    assert read_log(path, track="Oval_track")[0].track == "Oval_track"  # unless told


def test_stale_prepare_pose_is_dropped(tmp_path, caplog):
    lines = synthetic_simtrace((20, 25))
    k = next(i for i, line in enumerate(lines) if line.startswith("1,1.0,"))  # episode 1's prepare row ...
    fields = lines[k].split(",")
    fields[2] = repr(float(fields[2]) + 3.5)  # ... still holding the previous episode's end pose, 3.5 m away
    lines[k] = ",".join(fields)
    path = write_lines(tmp_path / "stale.csv", lines)
    rows = csv_episodes(path)[1]
    with caplog.at_level(logging.WARNING, logger="sim.calibration.logs"):
        traj = read_log(path)[1]
    assert_matches_rows(traj, rows[1:])
    assert "episode 1" in caplog.text and "stale" in caplog.text


def test_robomaker_log_reads_like_the_csv(tmp_path):
    lines = synthetic_simtrace((30, 20, 25, 12))
    log = tmp_path / "robomaker.log"
    log.write_text(robomaker_log(lines))
    from_log, from_csv = read_log(log), read_log(write_lines(tmp_path / "0-iteration.csv", lines))
    assert [t.episode for t in from_log] == [0, 1, 2]
    for a, b in zip(from_log, from_csv, strict=True):
        for name in ("t", "steer_cmd_deg", "speed_cmd_mps", "x", "y", "heading_deg"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert a.reference_point_m == 0.14
    assert from_log[0].track is None  # its path names no track ...
    assert read_log(log, track="reinvent_base")[0].track == "reinvent_base"  # ... unless told


def test_robomaker_log_2026_rows_after_a_timestamp(tmp_path):
    lines = synthetic_simtrace((23, 18, 10, 20), continuous=True)
    text = ["starting", *(f"2026-03-11T08:00:{i % 60:02d}Z SIM_TRACE_LOG:{line}" for i, line in enumerate(lines[1:]))]
    path = tmp_path / "ros2-robomaker.log"
    path.write_text("\n".join(text) + "\nbye\n")
    got, want = read_log(path), read_log(write_lines(tmp_path / "0-iteration.csv", lines))
    assert [len(t) for t in got] == [len(t) for t in want] == [23, 18, 20]
    np.testing.assert_array_equal(got[-1].speed_cmd_mps, want[-1].speed_cmd_mps)


def test_read_logs_on_folders_and_files(tmp_path):
    ros1 = write_lines(tmp_path / "a" / "training-simtrace" / "0-iteration.csv", synthetic_simtrace((20,) * 14))
    write_lines(tmp_path / "b" / "training-simtrace" / "0-iteration.csv", synthetic_simtrace((20,) * 10, True))
    robomaker = tmp_path / "robomaker.log"
    robomaker.write_text(robomaker_log(synthetic_simtrace((20,) * 3)))
    trajs = read_logs(tmp_path)
    assert len(trajs) == 14 + 10 + 3
    assert trajs[0].source == str(ros1) and trajs[-1].source == str(robomaker)
    assert [t.episode for t in read_logs(str(ros1))] == list(range(14))
    assert len(read_logs([ros1, robomaker])) == 17
    assert read_logs([]) == []


def test_natural_order_of_iterations(tmp_path):
    for n in (10, 2):
        write_lines(tmp_path / f"{n}-iteration.csv", synthetic_simtrace()[:40])
    assert [Path(t.source).name for t in read_logs(tmp_path)] == ["2-iteration.csv", "10-iteration.csv"]


# ------------------------------------------------------------------------------------------ DeepRacer's own logs


def test_deepracer_ros1_simtrace_csv():
    path = shared_data("logs", ROS1_SET, "training-simtrace", "0-iteration.csv")
    rows = csv_episodes(path)
    trajs = read_log(path)
    assert [t.episode for t in trajs] == [e for e, r in rows.items() if len(r) >= MIN_ROWS]
    for traj in trajs:
        assert_matches_rows(traj, rows[traj.episode])
        assert np.all(np.diff(traj.t) > 0)
        assert traj.reference_point_m == DEEPRACER_REFERENCE_POINT_M
        assert traj.track == "reinvent_base" and traj.source == str(path)
        assert set(traj.steer_cmd_deg.round(6)) <= set(STEERS)
        assert set(traj.speed_cmd_mps) <= {1.0, 2.0}
        prepare = rows[traj.episode][0]  # the prepare row is sample 0: the car at rest with the first action
        assert prepare["episode_status"] == "prepare" and traj.t[0] == float(prepare["tstamp"])


def test_deepracer_ros2_simtrace_csv_with_2026_columns():
    path = shared_data("logs", ROS2_SET, "training-simtrace", "0-iteration.csv")
    rows = csv_episodes(path)
    assert "wall_clock" in next(iter(rows.values()))[0]
    kept = {e: r[1:] if stale_first(r) else r for e, r in rows.items()}
    trajs = read_log(path)
    assert [t.episode for t in trajs] == [e for e, r in kept.items() if len(r) >= MIN_ROWS]
    for traj in trajs:
        assert_matches_rows(traj, kept[traj.episode])
        assert traj.track == "reInvent2019_wide_cw"
        action = np.array([r["action"].strip("[]").split() for r in kept[traj.episode]], dtype=float)
        np.testing.assert_allclose(action, np.c_[traj.steer_cmd_deg, traj.speed_cmd_mps])


def test_deepracer_stale_prepare_pose_is_dropped(caplog):
    path = shared_data("logs", ROS2_SET, "training-simtrace", "11-iteration.csv")
    rows = csv_episodes(path)[225]
    assert rows[0]["episode_status"] == "prepare" and stale_first(rows)
    with caplog.at_level(logging.WARNING, logger="sim.calibration.logs"):
        (traj,) = [t for t in read_log(path) if t.episode == 225]
    assert_matches_rows(traj, rows[1:])  # the prepare row still held the previous episode's end pose
    assert "episode 225" in caplog.text and "stale" in caplog.text


def test_deepracer_log_sets_read_whole():
    folder = shared_data("logs", ROS1_SET)
    trajs = read_logs(folder)
    files = list(dict.fromkeys(Path(t.source).name for t in trajs))
    assert files == [f"{n}-iteration.csv" for n in range(28)]  # natural order: 2 before 10
    assert all(t.track == "reinvent_base" for t in trajs) and len(trajs) > 500


# ------------------------------------------------------------------------------------------ plain CSV


def plain_rows(n: int = 20, episode: int | None = None) -> list[list[str]]:
    """n rows of a car at 1.5 m/s along a 30° line, commanded 5° left at 1.5 m/s, with uneven time steps."""
    t = np.cumsum(np.r_[0.0, np.tile([0.06, 0.07], n)[: n - 1]]).tolist()
    h = math.radians(30.0)
    rows = [[repr(ti), "5.0", "1.5", repr(1.5 * ti * math.cos(h)), repr(1.5 * ti * math.sin(h)), "30.0"] for ti in t]
    return [[*r, str(episode)] for r in rows] if episode is not None else rows


def write_plain(path: Path, rows: list[list[str]], header: list[str] | None = None, pre: str = "") -> Path:
    header = header or (PLAIN_COLUMNS + ["episode"] if len(rows[0]) == 7 else PLAIN_COLUMNS)
    path.write_text(pre + "\n".join(",".join(r) for r in [header, *rows]) + "\n")
    return path


def test_plain_csv(tmp_path):
    path = write_plain(tmp_path / "car.csv", plain_rows(20))
    (traj,) = read_log(path)
    assert (traj.episode, traj.reference_point_m, traj.track, len(traj)) == (0, 0.0, None, 20)
    np.testing.assert_allclose(traj.speed_measured_mps, 1.5)  # exact for a straight line, even with uneven steps
    assert traj.steer_cmd_deg[0] == 5.0 and traj.heading_deg[-1] == 30.0


def test_plain_csv_episodes_comments_and_spaces(tmp_path):
    rows = plain_rows(20, episode=3) + plain_rows(17, episode=4) + plain_rows(5, episode=5)
    header = [" time_s", "steer_cmd_deg ", "speed_cmd_mps", "x_m", "y_m", "heading_deg", "episode"]
    pre = "# a car in the lab\n# reference_point_m: 0.14\n# track: Oval_track\n\n"
    trajs = read_log(write_plain(tmp_path / "car.csv", rows, header, pre))
    assert [(t.episode, len(t)) for t in trajs] == [(3, 20), (4, 17)]  # episode 5 is too short
    assert {(t.reference_point_m, t.track) for t in trajs} == {(0.14, "Oval_track")}


def test_trajectory_is_checked_and_read_only():
    ok = dict(source="s", episode=0, t=[0, 1], steer_cmd_deg=[0, 0], speed_cmd_mps=[1, 1], x=[0, 1], y=[0, 0])
    traj = Trajectory(**ok, heading_deg=[0, 0])
    assert traj.speed_measured_mps.tolist() == [1.0, 1.0]
    with pytest.raises(ValueError, match="read-only"):
        traj.x[0] = 5.0
    with pytest.raises(ValueError, match="one length"):
        Trajectory(**ok, heading_deg=[0, 0, 0])
    with pytest.raises(ValueError, match="strictly increasing"):
        Trajectory(**{**ok, "t": [1, 1]}, heading_deg=[0, 0])


# ------------------------------------------------------------------------------------------ bad files


def assert_log_error(path, *problem: str, reader=read_log) -> None:
    """The reader raises LogError with a one-line message naming the file and every given part of the problem."""
    with pytest.raises(LogError) as err:
        reader(path)
    msg = str(err.value)
    assert "\n" not in msg
    assert str(path) in msg
    for part in problem:
        assert part in msg, msg


def ros1_lines() -> list[str]:
    """15 episodes of 30 rows: line 41 of the file is in episode 1."""
    return synthetic_simtrace()


def set_field(line: str, index: int, value: str) -> str:
    fields = line.split(",")
    fields[index] = value
    return ",".join(fields)


def test_missing_file_and_folder(tmp_path):
    assert_log_error(tmp_path / "nope.csv", "no such file")
    assert_log_error(tmp_path, "is a folder")
    assert_log_error(tmp_path / "nope", "no such file", reader=read_logs)
    (tmp_path / "empty").mkdir()
    assert_log_error(tmp_path / "empty", "no .csv or .log files", reader=read_logs)


@pytest.mark.parametrize(
    ("text", "problem"),
    [("", "file is empty"), ("  \n\n", "file is empty"), ("# only\n", "comments only"), (None, "no data rows")],
)
def test_empty_files(tmp_path, text, problem):
    path = tmp_path / "e.csv"
    path.write_text(ros1_lines()[0] + "\n" if text is None else text)
    assert_log_error(path, problem)


def test_not_text(tmp_path):
    path = tmp_path / "bin.csv"
    path.write_bytes(b"\xff\xfe\x00\x01garbage")
    assert_log_error(path, "not a text file")


def test_unknown_header(tmp_path):
    assert_log_error(write_lines(tmp_path / "u.csv", ["a,b,c", "1,2,3"]), "unknown header", "'a,b,c'")


def test_missing_columns_are_named(tmp_path):
    lines = [",".join(f for i, f in enumerate(line.split(",")) if i not in (4, 14)) for line in ros1_lines()]
    assert_log_error(write_lines(tmp_path / "m.csv", lines), "lacks column(s) yaw, tstamp")
    rows = [r[:5] for r in plain_rows()]
    assert_log_error(write_plain(tmp_path / "p.csv", rows, PLAIN_COLUMNS[:5]), "lacks column(s) heading_deg")


def test_wrong_field_count(tmp_path):
    lines = ros1_lines()
    lines[5] += ",extra"
    assert_log_error(write_lines(tmp_path / "w.csv", lines), "line 6:", "18 fields, the header has 17")


@pytest.mark.parametrize(
    ("index", "value", "problem"),
    [
        (2, "abc", "X is not a number: 'abc'"),
        (3, "", "Y is not a number: ''"),
        (14, "nan", "tstamp is not finite: 'nan'"),
        (6, "inf", "throttle is not finite: 'inf'"),
        (0, "1.5", "episode is not an integer: 1.5"),
    ],
)
def test_bad_values_name_the_line(tmp_path, index, value, problem):
    lines = ros1_lines()
    lines[40] = set_field(lines[40], index, value)
    assert_log_error(write_lines(tmp_path / "v.csv", lines), "line 41:", problem)


def test_time_going_backwards_names_episode_and_line(tmp_path):
    lines = ros1_lines()
    lines[40] = set_field(lines[40], 14, "1.0")  # line 41 is in episode 1
    assert_log_error(write_lines(tmp_path / "b.csv", lines), "line 41, episode 1:", "time goes backwards", "tstamp 1.0")


def test_duplicate_timestamps(tmp_path):
    lines = ros1_lines()
    lines[40] = set_field(lines[40], 14, lines[39].split(",")[14])
    assert_log_error(write_lines(tmp_path / "d.csv", lines), "line 41, episode 1:", "duplicate timestamp")


def test_heading_not_in_degrees_range(tmp_path):
    lines = ros1_lines()
    lines[7] = set_field(lines[7], 4, "270.0")
    assert_log_error(write_lines(tmp_path / "h.csv", lines), "line 8:", "yaw 270.0 is outside [-180, 180] degrees")
    rows = plain_rows()
    rows[3][5] = "-200"
    assert_log_error(write_plain(tmp_path / "p.csv", rows), "line 5:", "heading_deg -200.0 is outside")


def test_episode_that_starts_again(tmp_path):
    lines = ros1_lines()
    lines.append(set_field(lines[1], 14, "999.0"))  # episode 0 again, after episodes 1..14
    assert_log_error(write_lines(tmp_path / "r.csv", lines), f"line {len(lines)}:", "episode 0 starts again")


def test_short_episodes_skipped_but_not_all(tmp_path):
    assert len(read_log(write_plain(tmp_path / "ok.csv", plain_rows(16)))) == 1
    path = write_plain(tmp_path / "short.csv", plain_rows(15, episode=0) + plain_rows(3, episode=1))
    assert_log_error(path, "no usable episode", "of 2, 2 have fewer than 16 rows")


def test_position_jump_skips_the_episode(tmp_path, caplog):
    rows = plain_rows(20, episode=0) + plain_rows(20, episode=1)
    rows[30][3] = str(float(rows[30][3]) + 2 * MAX_STEP_M)
    with caplog.at_level(logging.WARNING, logger="sim.calibration.logs"):
        trajs = read_log(write_plain(tmp_path / "j.csv", rows))
    assert [t.episode for t in trajs] == [0]
    assert "episode 1 skipped" in caplog.text
    assert_log_error(write_plain(tmp_path / "jj.csv", rows[20:]), "no usable episode", "1 jump more than 0.5 m")


def test_bad_reference_point(tmp_path):
    path = write_plain(tmp_path / "r.csv", plain_rows(), pre="# reference_point_m: 14 cm\n")
    assert_log_error(path, "'# reference_point_m: 14 cm' is not a distance")


def test_robomaker_line_with_wrong_field_count(tmp_path):
    lines = robomaker_log(synthetic_simtrace((20,) * 3)).splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("SIM_TRACE_LOG:"))
    lines[k] = lines[k].rsplit(",", 2)[0]
    assert_log_error(write_lines(tmp_path / "x.log", lines), f"line {k + 1}:", "SIM_TRACE_LOG has 15 fields")


def test_action_lists_split_at_commas_are_rejoined(tmp_path):
    ros2 = write_lines(tmp_path / "0-iteration.csv", synthetic_simtrace((20, 17), continuous=True))
    lines = ros2.read_text().splitlines()
    lines = [lines[0], *(line.replace(" ", ", ", 1) if "[" in line else line for line in lines[1:])]
    assert "[-29.75, 0.9]" in lines[1]
    assert [len(t) for t in read_log(write_lines(tmp_path / "c.csv", lines))] == [len(t) for t in read_log(ros2)]
