"""DeepRacer users' files behave as in DeepRacer: params computed the simapp's way at the poses where a platform can
differ, reward functions that cache state, DRfC folders, racer check, and starting from another run.

Expected values are computed as the simapp computes them: with shapely, the simapp's own geometry library
(aws-deepracer-community/deepracer-simapp, markov/track_geom/track_data.py: ``TrackLine``, ``get_nearest_points``;
markov/track_geom/utils.py ``find_prev_next``; markov/agent_ctrl/utils.py ``set_reward_and_metrics``).
"""

from __future__ import annotations

import bisect
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import LinearRing, LineString, Point

from common.config import EnvConfig, PolicyConfig, RunConfig
from common.defaults import DEFAULT_TRACK, STRAIGHT_TRACK
from model_store import LocalStore, RunStore
from racer.drfc import DrfcError, import_drfc
from racer.runconfig import PretrainedError, build_run, check_pretrained
from sim.env import RacerEnv, preflight_reward
from sim.physics import FRONT_POINT_M, Pose
from sim.reward import RewardFunctionError
from sim.task import RacingTask
from sim.track import Track, load_track
from tests.shared_data import SHARED_TRACKS, deepracer_track_names, needs_deepracer_tracks

PATTERNS = Path(__file__).parent / "data" / "reward_patterns"


# --- the simapp's computation, with shapely ---------------------------------------------------------------------


def simapp_sanitize(waypoints: np.ndarray) -> np.ndarray:
    """The simapp's ``TrackData._sanitize_waypoints`` (track_data.py at 01f5f015), written out again here as the
    reference: a loop (first row == last row, every column) keeps its closing row; zero-length centre-line steps
    (<= 1e-9 m) are dropped."""
    is_loop = bool(np.all(waypoints[0, :] == waypoints[-1, :]))
    body = waypoints[:-1] if is_loop and len(waypoints) > 2 else waypoints
    keep = np.ones(len(body), dtype=bool)
    keep[1:] = np.linalg.norm(np.diff(body[:, 0:2], axis=0), axis=1) > 1e-9
    return np.vstack((body[keep], waypoints[-1:])) if body is not waypoints else body[keep]


def simapp_params(rows: np.ndarray, x: float, y: float, reverse: bool = False) -> dict:
    """closest_waypoints, track_width, distance_from_center and is_left_of_center as the simapp computes them, for
    ``rows`` already in the direction of travel (``reverse`` says whether that is the file's order reversed)."""
    loop = bool(np.all(rows[0] == rows[-1]))
    line = LinearRing if loop else LineString
    center, inner, outer = line(rows[:, 0:2]), line(rows[:, 2:4]), line(rows[:, 4:6])
    # TrackData.is_ccw: the forward centre line's orientation (True for an open line), flipped when reversed; for a
    # loop, the reversed ring's own orientation is the same thing.
    ccw = center.is_ccw if loop else not reverse
    ndists = [center.project(Point(p), normalized=True) for p in center.coords[:-1]] + [1.0]
    point = Point(x, y)
    ndist = center.project(point, normalized=True)
    nxt = bisect.bisect_right(ndists, ndist)
    prev = nxt - 1 if nxt > 0 else len(ndists) - 1
    nxt = 0 if nxt == len(ndists) else nxt
    near_ctr = center.interpolate(ndist, normalized=True)
    near_in = inner.interpolate(inner.project(near_ctr))
    near_out = outer.interpolate(outer.project(near_ctr))
    return {
        "closest_waypoints": [prev, nxt],
        "track_width": near_in.distance(near_out),
        "distance_from_center": near_ctr.distance(point),
        "is_left_of_center": (point.distance(near_in) < point.distance(near_out)) ^ (not ccw),
    }


def observe_front_at(task: RacingTask, track_name: str, x: float, y: float, yaw: float, command=(0.0, 1.0)) -> dict:
    """The task's params with the car's front point (DeepRacer's x, y) at (x, y), heading yaw."""
    base = Pose(x - FRONT_POINT_M * math.cos(yaw), y - FRONT_POINT_M * math.sin(yaw), yaw)
    wheels = np.array([[base.x, base.y]] * 4)
    return task.observe(base, wheels, True, 0.1, command).params


def wedge_point(rows: np.ndarray, i: int, offset: float = 0.05) -> tuple[float, float]:
    """A point in the wedge between the normals of the two segments at waypoint i (on the outer side of the bend),
    where every point projects exactly onto waypoint i: the simapp then says [i, i + 1]."""
    p, a, b = rows[i, :2], rows[i - 1, :2], rows[i + 1, :2]
    u, v = (p - a) / np.linalg.norm(p - a), (b - p) / np.linalg.norm(b - p)
    turn = u[0] * v[1] - u[1] * v[0]
    bisector = (u - v) / np.linalg.norm(u - v) * np.sign(turn)  # away from the inside of the bend
    q = p + offset * bisector
    return float(q[0]), float(q[1])


@pytest.mark.parametrize("name", [DEFAULT_TRACK, pytest.param("Spain_track", marks=needs_deepracer_tracks)])
def test_closest_waypoints_at_a_vertex_are_i_and_i_plus_1(name: str) -> None:
    track = load_track(name)
    rows = track.waypoints
    task = RacingTask(track)
    checked = 0
    for i in range(5, len(rows) - 5, 7):
        a, b = rows[i, :2] - rows[i - 1, :2], rows[i + 1, :2] - rows[i, :2]
        if abs(a[0] * b[1] - a[1] * b[0]) / (np.linalg.norm(a) * np.linalg.norm(b)) < 0.02:
            continue  # too straight for a wedge of any size
        x, y = wedge_point(rows, i)
        if LinearRing(rows[:, 0:2]).distance(Point(x, y)) < math.dist((x, y), rows[i, :2]) - 1e-12:
            continue  # the vertex is not the nearest point (the bend's inside): a tie between two segments
        expected = simapp_params(rows, x, y)
        if expected["closest_waypoints"] != [i, i + 1]:
            continue  # the point fell just off the vertex (a neighbouring segment is nearer)
        task.begin(max(i - 2, 0), False)
        got = observe_front_at(task, name, x, y, 0.0)
        assert got["closest_waypoints"] == [i, i + 1], (i, got["closest_waypoints"])
        checked += 1
    assert checked >= 3


def test_closest_waypoints_on_the_last_segment_are_n_minus_2_and_n_minus_1() -> None:
    track = load_track(DEFAULT_TRACK)
    rows = track.waypoints
    n = len(rows)
    mid = (rows[n - 2, :2] + rows[n - 1, :2]) / 2
    task = RacingTask(track)
    task.begin(n - 4, False)
    got = observe_front_at(task, DEFAULT_TRACK, float(mid[0]), float(mid[1]), 0.0)
    assert got["closest_waypoints"] == simapp_params(rows, *mid)["closest_waypoints"] == [n - 2, n - 1]
    assert len(got["waypoints"]) == n  # the closing row is kept, as in the simapp


@pytest.mark.parametrize("name", ["racer_loop", "racer_wide", "racer_straight"])
def test_params_match_the_simapp_at_random_poses(name: str) -> None:
    track = load_track(name)
    rows = track.waypoints
    task = RacingTask(track)
    rng = np.random.default_rng(7)
    for _ in range(60):
        s = rng.uniform(0, track.length)
        assert_params_match_the_simapp(task, track, rows, s, rng.uniform(-0.6, 0.6), reverse=False)


def assert_params_match_the_simapp(
    task: RacingTask, line: Track, directed: np.ndarray, s: float, share: float, reverse: bool
) -> dict:
    """Put the car's front point ``share`` of the track width left of the centre line at ``s`` (metres along the
    direction driven, ``line``; ``directed``: the simapp's rows in that direction) and compare the params."""
    (cx, cy), heading = line.point_at(s)
    offset = share * line.width
    x, y = cx - offset * math.sin(heading), cy + offset * math.cos(heading)
    seg = int(np.searchsorted(line.cumulative, s, side="right") - 1)
    task.begin(max(seg - 1, 0), reverse)
    got = observe_front_at(task, line.name, x, y, heading)
    want = simapp_params(directed, x, y, reverse)
    assert got["closest_waypoints"] == want["closest_waypoints"], (reverse, s)
    assert got["track_width"] == pytest.approx(want["track_width"], abs=1e-6)
    assert got["distance_from_center"] == pytest.approx(want["distance_from_center"], abs=1e-6)
    assert got["is_left_of_center"] == want["is_left_of_center"]
    return got


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@needs_deepracer_tracks
@pytest.mark.parametrize("name", deepracer_track_names())
def test_every_deepracer_route_reads_as_the_simapp_reads_it_both_ways(name: str) -> None:
    # The simapp's waypoints and closest_waypoints on all 127 routes, both directions, at poses spread over the lap
    # and across the road (reward functions index racing lines by them; one row too many shifts every index).
    raw = np.load(SHARED_TRACKS / f"{name}.npy")
    rows = simapp_sanitize(raw)
    track = load_track(name)
    assert np.array_equal(track.waypoints, rows[:, :6])
    assert track.closed == bool(np.all(rows[0] == rows[-1]))
    task = RacingTask(track)
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    for reverse in (False, True):
        line = track.reversed() if reverse else track
        directed = rows[::-1] if reverse else rows
        end = line.length if line.closed else line.length - 0.3  # an open line's last 0.3 m ends the episode
        for s in np.sort(rng.uniform(0.3 if not line.closed else 0.0, end, 12)):
            got = assert_params_match_the_simapp(task, line, directed, s, rng.uniform(-0.45, 0.45), reverse)
            assert got["waypoints"] == [tuple(p) for p in directed[:, 0:2].tolist()]


def test_speed_and_steering_are_the_actions_values_not_the_cars_limits(tmp_path: Path) -> None:
    # simapp set_reward_and_metrics: params speed = float(json_actions["speed"]), never clipped to 4 m/s.
    meta = {"action_space": [{"steering_angle": 0.0, "speed": 12.0}, {"steering_angle": 35.0, "speed": 4.89}]}
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps(meta))
    env = RacerEnv(track=DEFAULT_TRACK, action_space=str(path))
    env.reset(seed=0, options={"start_index": 0})
    _, _, _, _, info = env.step(0)
    assert info["params"]["speed"] == 12.0 and info["command"][1] == 4.0
    _, _, _, _, info = env.step(1)
    assert (info["params"]["steering_angle"], info["params"]["speed"]) == (35.0, 4.89)
    assert info["command"][0] == 30.0


# --- reward functions (the patterns run unchanged in tests/test_community_files.py) ---------------------------


def test_a_failing_reward_fails_in_one_line_naming_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "reward_function.py"
    path.write_text("def reward_function(params):\n    wp = params['waypoints']\n    return wp[len(wp)][0]\n")
    with pytest.raises(RewardFunctionError) as info:
        preflight_reward(EnvConfig(reward_fn=str(path)))
    message = str(info.value)
    assert "reward_function.py" in message and "line 3" in message and "IndexError" in message
    assert "step 2" in message and "\n" not in message


# --- DRfC folders and racer check --------------------------------------------------------------------------------


def drfc_folder(tmp_path: Path, run_env: str) -> Path:
    custom = tmp_path / "custom_files"
    custom.mkdir(parents=True)
    (custom / "reward_function.py").write_text((PATTERNS / "class_instance_once.py").read_text())
    (custom / "hyperparameters.json").write_text(json.dumps({"batch_size": 64, "lr": 0.0003, "sac_alpha": 0.2}))
    (tmp_path / "run.env").write_text(run_env)
    return tmp_path


@needs_deepracer_tracks
def test_drfc_run_env_is_mapped_and_the_rest_listed(tmp_path: Path) -> None:
    folder = drfc_folder(
        tmp_path,
        "# DRfC run.env\nDR_WORLD_NAME=Spain_track\nDR_RACE_TYPE=TIME_TRIAL\nDR_CAR_NAME=FastCar\n"
        "DR_TRAIN_CHANGE_START_POSITION=True\nDR_TRAIN_ROUND_ROBIN_ADVANCE_DIST=0.1\n"
        "DR_TRAIN_ALTERNATE_DRIVING_DIRECTION=True\nDR_EVAL_NUMBER_OF_TRIALS=5\nDR_WORKERS=3\n"
        'DR_LOCAL_S3_MODEL_PREFIX="my-model"\nDR_LOCAL_S3_PRETRAINED=True\n'
        "DR_LOCAL_S3_PRETRAINED_PREFIX=base-model\nDR_LOCAL_S3_PRETRAINED_CHECKPOINT=best\n",
    )
    got = import_drfc(folder)
    assert got.track == "Spain_track" and got.workers == 3 and got.run_id == "my-model" and got.eval_episodes == 5
    assert got.randomization == {"alternate_direction": True, "random_start": False, "round_robin_divisions": 10}
    assert got.pretrained == "base-model:best"
    assert got.unmapped == ["DR_CAR_NAME"]
    assert got.reward_fn == folder / "custom_files" / "reward_function.py"


@pytest.mark.parametrize(
    ("line", "fragment"),
    [
        ("DR_RACE_TYPE=F1", "DR_RACE_TYPE='F1': expected one of TIME_TRIAL, OBJECT_AVOIDANCE, HEAD_TO_BOT"),
        ("DR_OA_NUMBER_OF_OBSTACLES=six", "DR_OA_NUMBER_OF_OBSTACLES='six': expected an integer"),
        ("DR_H2B_IS_LANE_CHANGE=1", "DR_H2B_IS_LANE_CHANGE='1': expected True or False"),
        ("DR_RACE_TYPE=OBJECT_AVOIDANCE\nDR_OA_OBJECT_POSITIONS=23,1", "for 23.0 % write 0.23"),
        ("DR_RACE_TYPE=HEAD_TO_BOT\nDR_H2B_LOWER_LANE_CHANGE_TIME=9", "is above upper_lane_change_time"),
        ("DR_TRAIN_ALTERNATE_DRIVING_DIRECTION=sometimes", "expected True or False"),
        ("DR_WORKERS=two", "DR_WORKERS='two': expected an integer"),
    ],
)
def test_drfc_values_racer_cannot_honour_are_one_line_errors(tmp_path: Path, line: str, fragment: str) -> None:
    folder = drfc_folder(tmp_path, line + "\n")
    with pytest.raises(DrfcError) as info:
        import_drfc(folder)
    assert fragment in str(info.value) and "run.env" in str(info.value) and "\n" not in str(info.value)


def racer(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "racer", *args], capture_output=True, text=True, timeout=120, env=env)


def test_a_drfc_world_not_in_the_track_folder_is_one_line_giving_the_pull_command(tmp_path: Path) -> None:
    folder = drfc_folder(tmp_path / "drfc", "DR_WORLD_NAME=2024_reinvent_champ_ccw\n")
    empty = tmp_path / "tracks"
    empty.mkdir()
    done = racer("check", "--from-drfc", str(folder), env={**os.environ, "RACER_TRACKS_DIR": str(empty)})
    assert done.returncode == 2
    err = done.stderr.strip()
    assert "DR_WORLD_NAME='2024_reinvent_champ_ccw'" in err and "`racer tracks pull 2024_reinvent_champ_ccw`" in err
    assert len(err.splitlines()) == 1, err


@needs_deepracer_tracks
def test_racer_check_says_what_racer_does_with_each_file(tmp_path: Path) -> None:
    folder = drfc_folder(tmp_path, "DR_WORLD_NAME=Spain_track\nDR_CAR_NAME=FastCar\n")
    done = racer("check", "--from-drfc", str(folder))
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "reward_function.py: ran on Spain_track" in out
    assert "sac_alpha (not used by clipped PPO)" in out
    assert "no racer meaning, not used: DR_CAR_NAME" in out
    assert "ok: racer train would accept these files" in out


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize(
    ("metadata", "fragment"),
    [
        ({"training_algorithm": "sac"}, 'training_algorithm = "sac" is not supported'),
        # The simapp's own rules (markov/boto/s3/files/model_metadata.py parse_model_metadata): exactly one camera,
        # at most one LiDAR; the stereo cameras and a LiDAR with a camera are accepted (tests/test_sensors_net.py).
        ({"sensor": ["LIDAR"]}, 'sensor = ["LIDAR"] is not supported (DeepRacer needs exactly one camera'),
        ({"sensor": ["SECTOR_LIDAR"]}, 'sensor = ["SECTOR_LIDAR"] is not supported (DeepRacer needs exactly one'),
        ({"sensor": ["FRONT_FACING_CAMERA", "STEREO_CAMERAS"]}, "needs exactly one camera, this list has 2"),
        ({"sensor": ["STEREO_CAMERAS", "LIDAR", "SECTOR_LIDAR"]}, "takes at most one LiDAR, this list has 2"),
        # Names the simapp knows (markov/architecture/constants.py Input) that racer does not build.
        ({"sensor": ["LEFT_CAMERA"]}, 'sensor = ["LEFT_CAMERA"] is not supported (racer does not build LEFT_CAMERA'),
        ({"sensor": ["FRONT_FACING_CAMERA", "DISCRETIZED_SECTOR_LIDAR"]}, "racer does not build DISCRETIZED_SECTOR"),
        ({"sensor": ["FRONT_FACING_CAMERA", "SONAR"]}, '"SONAR" is not a DeepRacer sensor'),
        ({"neural_network": "RESNET"}, 'neural_network = "RESNET" is not supported'),
    ],
)
def test_racer_check_refuses_what_racer_cannot_honour(tmp_path: Path, metadata: dict, fragment: str) -> None:
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": [{"steering_angle": 0, "speed": 1}], **metadata}))
    done = racer("check", "--action-space", str(path))
    assert done.returncode == 2
    assert fragment in done.stderr and "model_metadata.json" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


# --- starting from another run (DRfC pretrained, the console's clone) -------------------------------------------


def stored_source(tmp_path: Path, files: dict[str, bytes], run: RunConfig) -> RunStore:
    runs = RunStore(LocalStore(tmp_path / "store"))
    for name, data in files.items():
        runs.write_file("source", name, data)
    runs.write_file("source", "config.json", run.model_copy(update={"run_id": "source"}).model_dump_json())
    runs.save_checkpoint("source", 0, b"weights", {"created": 1.0})
    runs.set_pointer("source", "best", 0)
    return runs


def test_pretrained_needs_the_same_action_space_and_network(tmp_path: Path) -> None:
    run, files = build_run("new-run")
    runs = stored_source(tmp_path, files, run)
    assert check_pretrained(runs, run, files, "source:best").pretrained == "source:0"
    assert check_pretrained(runs, run, files, "source").pretrained == "source:0"

    other = dict(files)
    other["model_metadata.json"] = json.dumps({"action_space": [{"steering_angle": 0.0, "speed": 2.0}]}).encode()
    with pytest.raises(PretrainedError, match="action space differs"):
        check_pretrained(runs, run, other, "source:best")
    deep = run.model_copy(update={"policy": PolicyConfig(network="deep")})
    with pytest.raises(PretrainedError, match="network"):
        check_pretrained(runs, deep, files, "source:best")
    with pytest.raises(PretrainedError, match="no_such_run"):
        check_pretrained(runs, run, files, "no_such_run:best")
    stereo = dict(files)
    meta = json.loads(files["model_metadata.json"])
    stereo["model_metadata.json"] = json.dumps(dict(meta, sensor=["STEREO_CAMERAS"])).encode()
    with pytest.raises(PretrainedError, match="sensors"):
        check_pretrained(runs, run, stereo, "source:best")


def test_drfc_race_variables_map_to_the_race(tmp_path: Path) -> None:
    # DRfC's defaults/template-run.env names, read as its scripts/*/prepare-config.py read them.
    folder = drfc_folder(
        tmp_path,
        "DR_RACE_TYPE=OBJECT_AVOIDANCE\nDR_OA_NUMBER_OF_OBSTACLES=3\nDR_OA_RANDOMIZE_OBSTACLE_LOCATIONS=True\n"
        "DR_OA_MIN_DISTANCE_BETWEEN_OBSTACLES=5\nDR_EVAL_OFF_TRACK_PENALTY=3.0\nDR_COLLISION_PENALTY=6.0\n"
        "DR_EVAL_MAX_RESETS=100\nDR_EVAL_COLLISION_PENALTY=5.0\nDR_H2B_BOT_CAR_SPEED=0.4\n",
    )
    race = import_drfc(folder).race
    assert race.race_type == "OBJECT_AVOIDANCE" and race.obstacle_count == 3 and race.bot_car_count == 0
    oa = race.object_avoidance
    assert oa.randomize_obstacle_locations and oa.min_distance_between_obstacles == 5.0
    assert (race.penalties.off_track_penalty, race.penalties.collision_penalty) == (3.0, 6.0)
    assert race.penalties.number_of_resets == 100
    fixed = drfc_folder(tmp_path / "b", "DR_RACE_TYPE=OBJECT_AVOIDANCE\nDR_OA_OBJECT_POSITIONS=0.23,-1;0.5,1\n")
    positions = import_drfc(fixed).race.object_avoidance.object_positions
    assert [(p.progress, int(p.lane)) for p in positions] == [(0.23, -1), (0.5, 1)]
    bots = drfc_folder(
        tmp_path / "c", "DR_RACE_TYPE=HEAD_TO_BOT\nDR_H2B_NUMBER_OF_BOT_CARS=2\nDR_H2B_IS_LANE_CHANGE=True\n"
    )
    race = import_drfc(bots).race
    assert race.bot_car_count == 2 and race.head_to_bot.is_lane_change and race.obstacle_count == 0
    run, _ = build_run("oa-run", race=race)
    assert run.env.race == race


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_racer_check_and_train_take_the_race_on_the_command_line(tmp_path: Path) -> None:
    race = tmp_path / "race.json"
    race.write_text(json.dumps({"race_type": "OBJECT_AVOIDANCE", "object_avoidance": {"number_of_obstacles": 4}}))
    done = racer("check", "--race", str(race))
    assert done.returncode == 0, done.stderr
    assert "race: OBJECT_AVOIDANCE, 4 obstacles (evenly spaced)" in done.stdout
    done = racer("check", "--race-type", "head_to_bot")
    assert "race: HEAD_TO_BOT, 3 bot cars at 0.2 m/s" in done.stdout
    race.write_text(json.dumps({"race_type": "OBJECT_AVOIDANCE", "object_avoidance": {"number_of_obstacles": -1}}))
    done = racer("check", "--race", str(race))
    assert done.returncode == 2 and str(race) in done.stderr and "number_of_obstacles" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


# --- model_metadata.json as the simapp's parse_model_metadata reads it ------------------------------------------


@pytest.mark.parametrize(
    ("extra", "sensor", "algorithm", "space_type"),
    [
        ({"version": 3}, ["FRONT_FACING_CAMERA"], "clipped_ppo", "discrete"),  # a JSON number: float() takes it
        ({"version": "1", "sensor": ["STEREO_CAMERAS"]}, ["FRONT_FACING_CAMERA"], "clipped_ppo", "discrete"),  # < 2
        ({"sensor": ["observation"]}, ["FRONT_FACING_CAMERA"], "clipped_ppo", "discrete"),  # the legacy camera name
        ({"sensor": ["observation", "LIDAR"]}, ["FRONT_FACING_CAMERA", "LIDAR"], "clipped_ppo", "discrete"),
        ({"sensor": ["STEREO_CAMERAS"]}, ["STEREO_CAMERAS"], "clipped_ppo", "discrete"),  # version 2+: as listed
        ({"sensor": ["LIDAR", "STEREO_CAMERAS"]}, ["LIDAR", "STEREO_CAMERAS"], "clipped_ppo", "discrete"),  # any order
        ({"version": "5", "sensor": ["FRONT_FACING_CAMERA", "SECTOR_LIDAR"]}, None, "clipped_ppo", "discrete"),
        ({"training_algorithm": " Clipped_PPO ", "action_space_type": "Discrete"}, None, "clipped_ppo", "discrete"),
    ],
)
def test_model_metadata_values_read_as_the_simapp_reads_them(tmp_path, extra, sensor, algorithm, space_type) -> None:
    # simapp markov/boto/s3/files/model_metadata.py parse_model_metadata: version float()-ed, sensor ignored below
    # version 2, training_algorithm and action_space_type lower-cased and stripped.
    from common.action_space import load_action_space

    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": [{"steering_angle": 0, "speed": 1}], **extra}))
    space = load_action_space(path)
    assert space.sensor == (sensor or extra.get("sensor", ["FRONT_FACING_CAMERA"]))
    assert (space.training_algorithm, space.action_space_type) == (algorithm, space_type)


def test_a_version_float_refuses_is_refused_in_one_line(tmp_path) -> None:
    from common.action_space import ActionSpaceError, load_action_space

    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": [{"steering_angle": 0, "speed": 1}], "version": "five"}))
    with pytest.raises(ActionSpaceError, match=r"model_metadata\.json.*version 'five' is not a number"):
        load_action_space(path)


def test_a_pretrained_run_starts_from_the_source_runs_weights(redis_url, tmp_path: Path) -> None:
    import torch

    from trainer.process import Trainer, TrainerOptions

    store = str(tmp_path / "store")
    source, files = build_run("source-run", track=STRAIGHT_TRACK)
    Trainer(source, TrainerOptions(redis_url, store, run_files=files)).start()
    with torch.no_grad():  # give the source weights no fresh run could have by chance
        trained = Trainer(source, TrainerOptions(redis_url, store, resume=True))
        trained.start()
        for p in trained.model.parameters():
            p.fill_(0.125)
        trained.version = 1  # as after an update
        trained._checkpoint()
    run, files = build_run("clone-run", track=STRAIGHT_TRACK)
    runs = RunStore(LocalStore(tmp_path / "store"))
    run = check_pretrained(runs, run, files, "source-run:latest")
    clone = Trainer(run, TrainerOptions(redis_url, store, run_files=files))
    clone.start()
    assert clone.version == 0
    assert all(torch.all(p == 0.125) for p in clone.model.parameters())


def test_env_files_expand_variables_as_the_shell_does(tmp_path: Path) -> None:
    from racer.drfc import read_env_file

    path = tmp_path / "run.env"
    path.write_text("A=one\nB=$A/two\nC=\"${A}-x\"\nD='$A'\nE=$UNSET_RACER_TEST_VAR\n")
    assert read_env_file(path) == {"A": "one", "B": "one/two", "C": "one-x", "D": "$A", "E": ""}


def test_what_the_function_prints_stays_out_of_racer_checks_output(tmp_path: Path) -> None:
    path = tmp_path / "reward_function.py"
    path.write_text(
        "print('LOADED')\n\ndef reward_function(params):\n    print('PARAMS', params['steps'])\n    return 1.0\n"
    )
    done = racer("check", "--reward-fn", str(path))
    assert done.returncode == 0, done.stderr
    assert "LOADED" not in done.stdout and "PARAMS" not in done.stdout
    assert f"reward_function.py: ran on {DEFAULT_TRACK} in a throwaway env: ok" in done.stdout


def test_the_libraries_deepracer_documents_for_reward_functions_come_with_a_plain_install() -> None:
    # DeepRacer's developer guide: reward functions may import math, random, numpy, scipy and shapely. They must be
    # runtime dependencies of racer (not only of its dev or bench extras).
    from importlib.metadata import requires

    plain = {
        r.split(";")[0].split(">")[0].split("<")[0].split("=")[0].strip()
        for r in requires("racer") or []
        if "extra" not in r
    }
    assert {"numpy", "scipy", "shapely"} <= plain
