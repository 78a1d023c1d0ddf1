"""Races in the env: time trial unchanged, obstacles and bot cars in the params, the crash rule ending an episode,
and every sensor seeing the objects (issue 19; semantics in docs/object-avoidance.md)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from common.defaults import DEFAULT_TRACK
from common.race import RaceConfig
from common.sensors import CAMERA_KEY, LIDAR_KEY
from sim.env import RacerEnv
from sim.obstacles import BOT_CAR, as_boxes
from sim.physics import FRONT_POINT_M, Pose

ONE_BOX = RaceConfig(
    race_type="OBJECT_AVOIDANCE", object_avoidance={"object_positions": [{"progress": 0.1, "lane": 1}]}
)
BOTS = RaceConfig(race_type="HEAD_TO_BOT", head_to_bot={"number_of_bot_cars": 2, "bot_car_speed": 0.5})


def metadata(tmp_path: Path, sensors: list[str]) -> str:
    path = tmp_path / "model_metadata.json"
    space = [{"steering_angle": 0.0, "speed": 1.0}, {"steering_angle": 30.0, "speed": 1.0}]
    path.write_text(json.dumps({"action_space": space, "sensor": sensors, "version": "5"}))
    return str(path)


def test_a_time_trial_has_no_objects_and_the_simapps_empty_object_params() -> None:
    env = RacerEnv(track=DEFAULT_TRACK)
    _, info = env.reset(seed=0)
    _, _, _, _, info = env.step(0)
    p = info["params"]
    assert env.objects == [] and p["is_crashed"] is False and p["closest_objects"] == [0, 0]
    assert p["objects_location"] == [] and p["objects_distance"] == [] and p["object_in_camera"] is False
    for key in ("objects_left_of_center", "objects_speed", "objects_heading", "objects_distance_from_center"):
        assert p[key] == []  # the simapp's defaults (agent_ctrl/constants.py: RewardParam)


def test_obstacle_params_follow_the_placed_objects() -> None:
    env = RacerEnv(track=DEFAULT_TRACK, race=RaceConfig(race_type="OBJECT_AVOIDANCE"))
    _, info = env.reset(seed=0, options={"start_index": 0})
    p = info["params"]
    assert len(env.objects) == 6  # DRfC's default count
    assert p["objects_location"] == [[o.x, o.y] for o in env.objects]
    assert sorted(p["objects_distance"]) == p["objects_distance"]  # evenly spaced from the start line
    assert p["objects_speed"] == [0.0] * 6 and p["objects_heading"] == [0.0] * 6
    behind, ahead = p["closest_objects"]
    assert p["objects_distance"][ahead] > 0.14  # the nearest object ahead of the car's front point


def _drive_into(env: RacerEnv, target: Pose, gap: float, steps: int = 60) -> dict:
    """Put the car ``gap`` m behind ``target`` facing it, drive straight at it (action 0), return the last info."""
    start = Pose(target.x - gap * math.cos(target.yaw), target.y - gap * math.sin(target.yaw), target.yaw)
    index = int(env.track.project(np.array([[start.x, start.y]])).segment[0])
    env.reset(seed=0, options={"start_index": index})
    env.physics.reset(start)  # the episode's start waypoint, moved sideways into the target's lane
    env.place_objects()
    info = {}
    for _ in range(steps):
        _, _, terminated, _, info = env.step(0)
        if terminated:
            break
    return info


def test_driving_into_a_box_is_a_crash_that_ends_the_episode(tmp_path: Path) -> None:
    env = RacerEnv(track=DEFAULT_TRACK, race=ONE_BOX, action_space=metadata(tmp_path, ["FRONT_FACING_CAMERA"]))
    env.reset(seed=0, options={"start_index": 0})
    box = env.objects[0]
    info = _drive_into(env, Pose(box.x, box.y, box.yaw), 1.0)
    assert env.objects[0] == box  # fixed positions: the same box after the reset
    assert info["episode_status"] == "crashed" and info["params"]["is_crashed"] is True


def test_a_time_trial_car_drives_through_where_a_box_would_be(tmp_path: Path) -> None:
    boxed = RacerEnv(track=DEFAULT_TRACK, race=ONE_BOX)
    boxed.reset(seed=0, options={"start_index": 0})
    box = boxed.objects[0]
    env = RacerEnv(track=DEFAULT_TRACK, action_space=metadata(tmp_path, ["FRONT_FACING_CAMERA"]))
    env.reset(seed=0, options={"start_index": 0})
    info = _drive_into(env, Pose(box.x, box.y, box.yaw), 1.0, steps=30)
    assert info["params"]["is_crashed"] is False and info["episode_status"] == "in_progress"
    pose = info["pose"]
    ahead = (pose.x - box.x) * math.cos(box.yaw) + (pose.y - box.y) * math.sin(box.yaw)
    assert ahead > 0.3  # drove on past it, along the box's heading


def test_bot_cars_drive_their_lanes_and_report_their_speed() -> None:
    env = RacerEnv(track=DEFAULT_TRACK, race=BOTS)
    _, info = env.reset(seed=0, options={"start_index": 0})
    before = np.array(info["params"]["objects_location"])
    for _ in range(15):
        _, _, _, _, info = env.step(0)
    after = np.array(info["params"]["objects_location"])
    moved = np.hypot(*(after - before).T)
    assert all(o.kind == BOT_CAR for o in env.objects)
    assert np.all((moved > 0.35) & (moved < 0.65)), moved  # 0.5 m/s for 1 s, along a lane a little off centre
    assert info["params"]["objects_speed"] == [0.5, 0.5]


@pytest.mark.parametrize("sensors", [["STEREO_CAMERAS", "LIDAR"], ["FRONT_FACING_CAMERA", "SECTOR_LIDAR"]])
def test_the_lidar_and_the_camera_see_a_box(tmp_path: Path, sensors: list[str]) -> None:
    space = metadata(tmp_path, sensors)
    seen = RacerEnv(track=DEFAULT_TRACK, action_space=space, race=ONE_BOX)
    empty = RacerEnv(track=DEFAULT_TRACK, action_space=space)
    frames = []
    for env in (seen, empty):
        env.reset(seed=0, options={"start_index": 0})
        box = seen.objects[0]
        # The car beside the box, looking past it: inside the LiDAR's field, outside its blind cone ahead; nearer
        # for SECTOR_LIDAR, whose sectors read 1 only below 0.5 m.
        side, off = box.yaw + math.pi / 2, 0.6 if sensors[1] == "LIDAR" else 0.4
        x = box.x + off * math.cos(side) - 0.3 * math.cos(box.yaw)
        y = box.y + off * math.sin(side) - 0.3 * math.sin(box.yaw)
        env.physics.reset(Pose(x, y, box.yaw + 0.3))
        env.place_objects()
        beside = env.observe()
        env.physics.reset(Pose(box.x - math.cos(box.yaw), box.y - math.sin(box.yaw), box.yaw))  # 1 m behind it
        env.place_objects()
        behind = env.observe()
        assert env.observation_space.contains(beside) and env.observation_space.contains(behind)
        frames.append((beside, behind))
    (with_box, seen_ahead), (without, empty_ahead) = frames
    if sensors[1] == "LIDAR":
        assert with_box[LIDAR_KEY].min() < 0.9 and without[LIDAR_KEY].min() == pytest.approx(1.0)
    else:
        assert with_box[LIDAR_KEY].max() == 1.0 and without[LIDAR_KEY].max() == 0.0
    changed = np.abs(seen_ahead[CAMERA_KEY].astype(int) - empty_ahead[CAMERA_KEY]).max(axis=2) > 20
    assert 200 < changed.sum() < 0.5 * changed.size  # the box, not the whole picture


def test_stereo_frames_are_two_views_of_the_objects(tmp_path: Path) -> None:
    env = RacerEnv(track=DEFAULT_TRACK, action_space=metadata(tmp_path, ["STEREO_CAMERAS"]), race=ONE_BOX)
    obs, _ = env.reset(seed=0, options={"start_index": 0})
    assert obs.shape == (120, 160, 2) and obs.dtype == np.uint8
    assert not np.array_equal(obs[..., 0], obs[..., 1])  # 6 cm apart


def test_box_colours_change_with_the_track_colour_randomization() -> None:
    env = RacerEnv(track=DEFAULT_TRACK, race=ONE_BOX, randomization={"track_color": 0.5})
    env.reset(seed=0)
    first = env._box_colors.copy()
    env.reset()
    assert first.shape == (1, 3) and not np.array_equal(first, env._box_colors)
    assert as_boxes(env.objects).shape == (1, 6)


def test_the_sim_trace_of_a_race_with_objects_has_the_simapps_crash_column(tmp_path: Path) -> None:
    import pandas as pd

    from common.simtrace import COLUMNS, OBSTACLE_COLUMN, SimTraceRecorder

    env = RacerEnv(track=DEFAULT_TRACK, race=ONE_BOX, action_space=metadata(tmp_path, ["FRONT_FACING_CAMERA"]))
    env.reset(seed=0, options={"start_index": 0})
    box = env.objects[0]
    recorder = SimTraceRecorder()
    start = Pose(box.x - math.cos(box.yaw), box.y - math.sin(box.yaw), box.yaw)
    index = int(env.track.project(np.array([[start.x, start.y]])).segment[0])
    _, info = env.reset(seed=0, options={"start_index": index})
    env.physics.reset(start)
    env.place_objects()
    recorder.reset(info, 0)
    for _ in range(60):
        _, reward, terminated, truncated, info = env.step(0)
        recorder.step(0, info, reward, terminated or truncated)
        if terminated:
            break
    (tmp_path / "0-iteration.csv").write_text(recorder.take())
    trace = pd.read_csv(tmp_path / "0-iteration.csv")
    assert list(trace.columns) == [*COLUMNS, OBSTACLE_COLUMN]
    assert trace["episode_status"].iloc[-1] == "crashed" and trace[OBSTACLE_COLUMN].tolist()[-1] == 1
    assert trace[OBSTACLE_COLUMN].iloc[0] == 0
    plain = RacerEnv(track=DEFAULT_TRACK)
    _, info = plain.reset(seed=0)
    assert OBSTACLE_COLUMN not in info  # a time trial keeps DeepRacer's 17 columns


def test_an_evaluation_puts_the_car_back_behind_the_box_with_the_collision_penalty(tmp_path: Path) -> None:
    # simapp RolloutCtrl._get_car_reset_model_state: after a crash the car goes RESET_BEHIND_DIST behind the
    # obstacle, in the lane the obstacle is not in, paused for COLLISION_PENALTY seconds.
    penalties = {"number_of_resets": 2, "collision_penalty": 5.0, "reset_behind_dist": 1.0}
    race = RaceConfig.model_validate(ONE_BOX.model_dump() | {"penalties": penalties})
    env = RacerEnv(track=DEFAULT_TRACK, race=race, action_space=metadata(tmp_path, ["FRONT_FACING_CAMERA"]))
    env.reset(seed=0, options={"start_index": 0})
    box = env.objects[0]
    start = Pose(box.x - math.cos(box.yaw), box.y - math.sin(box.yaw), box.yaw)
    index = int(env.track.project(np.array([[start.x, start.y]])).segment[0])
    env.reset(seed=0, options={"start_index": index, "evaluation": True})
    env.physics.reset(start)
    env.place_objects()
    for _ in range(40):
        _, _, terminated, _, info = env.step(0)
        if info["episode_status"] == "crashed":
            break
    assert info["episode_status"] == "crashed" and not terminated and info["pause_duration"] == 5.0
    pose = info["pose"]
    where = env.track.project(np.array([[pose.x, pose.y], [box.x, box.y]]))
    assert abs((where.s[1] - where.s[0]) - 1.0) < 0.05  # a metre behind it along the track ...
    assert 0.25 < abs(where.lateral[0] - where.lateral[1]) < 0.5  # ... in the other lane, half a track width across
    _, _, _, _, after = env.step(0)
    assert after["params"]["sim_time"] > 5.0  # the penalty runs on the lap's clock
    training = RacerEnv(track=DEFAULT_TRACK, race=race, action_space=metadata(tmp_path, ["FRONT_FACING_CAMERA"]))
    training.reset(seed=0, options={"start_index": index})
    training.physics.reset(start)
    training.place_objects()
    for _ in range(40):
        _, _, terminated, _, info = training.step(0)
        if terminated:
            break
    assert terminated and info["episode_status"] == "crashed"  # training: a crash ends the episode


def test_an_evaluation_pauses_the_car_where_it_ran_into_a_bot_while_the_bots_drive_on(tmp_path: Path) -> None:
    # simapp RolloutCtrl._judge_action_at_run_phase: after a crash into a bot (a name without "obstacle") the car is
    # paused where it is, non-collidable (BlinkEffect), for COLLISION_PENALTY seconds; the bots' poses follow the
    # sim time (BotCarsCtrl._get_dist_from_sim_time), so they drive on through the pause and the car goes on behind.
    race = RaceConfig(race_type="HEAD_TO_BOT", head_to_bot={"number_of_bot_cars": 1}, penalties={"number_of_resets": 3})
    env = RacerEnv(track=DEFAULT_TRACK, race=race, action_space=metadata(tmp_path, ["FRONT_FACING_CAMERA"]))
    env.reset(seed=0, options={"start_index": 0, "evaluation": True})
    bot = env.objects[0]
    start = Pose(bot.x - 0.8 * math.cos(bot.yaw), bot.y - 0.8 * math.sin(bot.yaw), bot.yaw)  # behind it, in its lane
    index = int(env.track.project(np.array([[start.x, start.y]])).segment[0])
    env.reset(seed=0, options={"start_index": index, "evaluation": True})
    env.physics.reset(start)
    env.place_objects()
    for _ in range(40):
        bot_before = env.objects[0]
        _, _, terminated, _, info = env.step(0)
        if info["episode_status"] == "crashed":
            break
    assert info["episode_status"] == "crashed" and not terminated and info["pause_duration"] == 5.0
    front = info["pose"].ahead(FRONT_POINT_M)
    assert (front[0], front[1]) == pytest.approx((info["params"]["x"], info["params"]["y"]), abs=1e-9)  # not moved
    where = env.track.project(np.array([[bot_before.x, bot_before.y], [env.objects[0].x, env.objects[0].y]]))
    assert where.s[1] - where.s[0] == pytest.approx(5.0 * 0.2, abs=0.08)  # 5 s at 0.2 m/s, on its lane
    for _ in range(15):  # the next second: the car drives on behind the bot without touching it
        _, _, terminated, _, info = env.step(0)
        assert info["episode_status"] == "in_progress" and not info["params"]["is_crashed"]
    assert env.race.crash_count == 1


@pytest.mark.parametrize("reverse", [False, True])
def test_the_envs_object_params_equal_a_fresh_computation(reverse: bool) -> None:
    # The task hands object_params its own projection of the car's model point (a speed-up): same values.
    from sim.object_params import object_params

    race = RaceConfig(race_type="OBJECT_AVOIDANCE", object_avoidance={"randomize_obstacle_locations": True})
    env = RacerEnv(track="racer_loop_cw", race=race)  # a clockwise loop
    env.reset(seed=3, options={"reverse": reverse})
    rng = np.random.default_rng(0)
    for _ in range(150):
        _, _, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
        fresh = object_params(env.track, info["pose"], env.objects, reverse)
        for key, value in fresh.items():
            got = info["params"][key]
            assert got == pytest.approx(value, abs=1e-9) if key == "objects_distance" else got == value, key
        if terminated or truncated:
            env.reset(options={"reverse": reverse})


def test_deepracers_evaluation_resets_count_in_the_trial_and_its_summary(tmp_path: Path) -> None:
    # A policy that always turns hard leaves the track at once: with 2 resets allowed it is put back twice, then the
    # third off-track ends the trial; the robust evaluation (no resets) ends at the first.
    import torch

    from common.policy import action_space_spec, build_policy
    from trainer.evaluator import EvalSettings, evaluate, run_trial, summarize

    penalties = {"number_of_resets": 2, "off_track_penalty": 3.0}
    race = RaceConfig(race_type="TIME_TRIAL", penalties=penalties)
    space = tmp_path / "model_metadata.json"
    space.write_text(json.dumps({"action_space": [{"steering_angle": 30.0, "speed": 2.0}], "version": "5"}))
    env = RacerEnv(track=DEFAULT_TRACK, race=race, action_space=str(space))
    torch.manual_seed(0)
    model = build_policy((120, 160, 1), action_space_spec(env.actions))
    trial = run_trial(env, model, 1, 0, False, seed=0, deterministic=True, resets=True)
    assert (trial.status, trial.resets, trial.penalty_s) == ("off_track", 2, 6.0)
    assert summarize([trial])["resets"] == 2
    robust = run_trial(env, model, 1, 0, False, seed=0, deterministic=True)
    assert (robust.status, robust.resets) == ("off_track", 0) and robust.steps < trial.steps
    cfg = env.config.model_copy(update={"action_space": str(space)})
    lockstep = evaluate(model, cfg, 1, EvalSettings(episodes=2, both_directions=False, resets=True))
    assert [t.resets for t in lockstep] == [2, 2]


def test_the_10_hz_lidar_repeats_its_last_scan_on_one_step_in_three(tmp_path: Path) -> None:
    """DeepRacer's agent takes the latest 10 Hz scan without waiting (sensors_rollout.py: Lidar.get_state), so at
    15 Hz steps 1, 4, 7… see the scan before them again; the others see a new one (its noise differs)."""
    from sim.lidar import scan_due

    assert [scan_due(i) for i in range(8)] == [True, False, True, True, False, True, True, False]
    env = RacerEnv(track=DEFAULT_TRACK, action_space=metadata(tmp_path, ["STEREO_CAMERAS", "LIDAR"]), race=ONE_BOX)
    env.reset(seed=0, options={"start_index": 0})
    box = env.objects[0]
    side = box.yaw + math.pi / 2
    beside = Pose(
        box.x + 0.6 * math.cos(side) - 0.6 * math.cos(box.yaw),
        box.y + 0.6 * math.sin(side) - 0.6 * math.sin(box.yaw),
        box.yaw + 0.3,
    )
    env.physics.reset(beside)
    env.place_objects()
    scans = [env.observe()[LIDAR_KEY]]
    for _ in range(7):
        obs, *_ = env.step(0)
        scans.append(obs[LIDAR_KEY])
    assert scans[0].min() < 0.9  # the box is in range, so fresh scans carry fresh noise
    for i in range(1, 8):
        assert np.array_equal(scans[i], scans[i - 1]) == (not scan_due(i)), i
