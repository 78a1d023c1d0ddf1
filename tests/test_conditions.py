"""Held-out conditions (``common/conditions.py``, ``sim/conditions.py``): each changes what the camera sees or how
the car drives, as documented; they combine; a user's JSON file is one; bad input is one line; ``racer eval
--condition`` reports laps per condition."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from common.car_calibration import CAR_PRESETS
from common.conditions import CONDITIONS, apply_condition, combine, load_condition, load_conditions
from common.config import EnvConfig
from common.defaults import DEFAULT_TRACK
from common.errors import OptionError
from sim.env import RacerEnv


def _fastest_straight(env: RacerEnv) -> int:
    listed = env.actions.action_space
    return max(range(len(listed)), key=lambda i: (listed[i].speed, -abs(listed[i].steering_angle)))


def _drive(condition: str | None, steps: int = 0, action: int | None = None) -> tuple[RacerEnv, list[np.ndarray]]:
    cfg = EnvConfig(track=DEFAULT_TRACK)
    if condition is not None:
        cfg = apply_condition(cfg, load_condition(condition))
    env = RacerEnv(config=cfg)
    obs, _ = env.reset(seed=3, options={"start_index": 0, "reverse": False})
    frames = [obs[..., 0]]
    act = _fastest_straight(env) if action is None else action
    for _ in range(steps):
        obs, *_ = env.step(act)
        frames.append(obs[..., 0])
    return env, frames


@pytest.fixture(scope="module")
def baseline() -> list[np.ndarray]:
    return _drive(None, steps=3)[1]


@pytest.mark.parametrize("name", ["sunlight", "no-barriers", "tape", "camera-up", "camera-down", "blur", "noise"])
def test_each_visual_condition_changes_what_the_camera_sees(name, baseline):
    _, frames = _drive(name)
    diff = np.abs(frames[0].astype(int) - baseline[0].astype(int))
    assert diff.mean() > 2.0, (name, diff.mean())


def test_sunlight_brightens_and_casts_hard_shadows(baseline):
    _, frames = _drive("sunlight")
    ratio = (frames[0].astype(float) + 1) / (baseline[0].astype(float) + 1)
    assert np.median(ratio) > 1.2  # exposure up across most of the frame
    assert (ratio < 0.6).mean() > 0.03  # and shadows: a part of the frame far darker than the scene


def test_tape_leaves_only_the_borders_on_a_plain_floor():
    env, frames = _drive("tape")
    frame = frames[0][60:]  # the ground (the sky above the horizon is the room's, unchanged)
    floor = np.median(frame)
    assert (np.abs(frame.astype(int) - floor) < 6).mean() > 0.6  # mostly one plain grey: floor, road and all
    assert frame.max() > floor + 60  # the white tape stands out
    assert env.palette.road == env.palette.background == env.palette.center


def test_latency_shows_the_frame_of_one_step_before(baseline):
    _, frames = _drive("latency", steps=3)
    assert np.array_equal(frames[0], baseline[0]) and np.array_equal(frames[1], baseline[0])
    assert np.array_equal(frames[2], baseline[1]) and np.array_equal(frames[3], baseline[2])


@pytest.mark.parametrize(("name", "cap"), [("speed-0.5", 0.5), ("speed-1.0", 1.0)])
def test_a_speed_cap_holds_the_car_below_it_whatever_the_policy_asks(name, cap):
    env, _ = _drive(name, steps=30)
    assert env.physics.speed <= cap * 1.05
    if cap < 0.9:  # the default actions' fastest is 1 m/s: uncapped, the same actions go faster
        free, _ = _drive(None, steps=30)
        assert free.physics.speed > cap * 1.5


def test_the_gazebo_car_condition_drives_that_car():
    env, _ = _drive("gazebo-car")
    assert env.config.car == CAR_PRESETS["deepracer-gazebo"]


def test_conditions_combine_into_one_world_and_conflicts_are_refused():
    both = load_condition("tape+sunlight")
    assert both.name == "tape+sunlight"
    assert both.world.sunlight == 1.0 and both.world.border == CONDITIONS["tape"].world.border
    with pytest.raises(OptionError, match="speed_cap_mps"):
        combine([CONDITIONS["speed-0.5"], CONDITIONS["speed-1.0"]])
    assert [c.name for c in load_conditions(["sunlight,tape", "blur"])] == ["sunlight", "tape", "blur"]
    with pytest.raises(OptionError, match="more than once"):
        load_conditions(["blur,blur"])


def test_a_users_json_file_is_a_condition(tmp_path):
    path = tmp_path / "dusk.json"
    path.write_text(json.dumps({"name": "dusk", "about": "dim", "world": {"sensor_noise": 20, "blur_px": 0.8}}))
    c = load_condition(str(path))
    assert c.name == "dusk" and c.world.sensor_noise == 20 and c.world.blur_px == 0.8


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('{"name": "x", "world": {"sunlight": 3}}', "world.sunlight"),
        ('{"name": "x", "world": {"fog": 1}}', "world.fog"),
        ('{"name": "x", "car": "no-such-car"}', "no-such-car"),
        ("{", "not JSON"),
    ],
)
def test_a_bad_condition_file_is_one_line_naming_file_key_and_value(tmp_path, content, message):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(Exception, match=message) as err:
        load_condition(str(path))
    assert "\n" not in str(err.value)


@pytest.mark.slow(reason="runs racer train with its real processes")
def test_racer_eval_reports_laps_per_condition_and_refuses_a_bad_name(tmp_path):
    from common.policy import action_space_spec, build_policy
    from common.weights import checkpoint_to_bytes
    from racer.cli import app
    from tests.test_evaluator import _stored_run

    run, _, runs = _stored_run(tmp_path, "cond", track=DEFAULT_TRACK)
    model = build_policy((120, 160, 1), action_space_spec(RacerEnv(track=DEFAULT_TRACK).actions), run.policy)
    runs.save_checkpoint("cond", 1, checkpoint_to_bytes(model.state_dict()), {"env_steps": 100})
    base = [
        "eval",
        "--run-id",
        "cond",
        "--store",
        str(tmp_path),
        "--checkpoint",
        "1",
        "--episodes",
        "1",
        "--one-direction",
    ]
    out = tmp_path / "eval.json"
    result = CliRunner().invoke(app, [*base, "--condition", "speed-0.5,tape+sunlight", "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "as trained" in result.output and "tape+sunlight" in result.output
    rows = json.loads(out.read_text())["conditions"]
    assert [r["name"] for r in rows] == ["speed-0.5", "tape+sunlight"]
    for r in rows:
        assert r["episodes"] == 1 and 0 <= r["laps"] <= 1 and 0 <= r["mean_progress"] <= 100
        assert len(r["trials"]) == 1 and "trajectory" not in r["trials"][0]
    bad = CliRunner().invoke(app, [*base, "--condition", "fog"])
    assert bad.exit_code == 2 and "'fog'" in bad.output and "sunlight" in bad.output


def test_racer_evaluator_refuses_a_bad_condition_before_reaching_redis(tmp_path):
    from racer.cli import app

    args = ["evaluator", "--redis", "redis://127.0.0.1:1", "--run-id", "r", "--store", str(tmp_path)]
    result = CliRunner().invoke(app, [*args, "--condition", "sunlight+fog"])
    assert result.exit_code == 2 and "'fog'" in result.output and "Traceback" not in result.output


def test_the_evaluator_role_drives_each_checkpoint_in_its_conditions_too(tmp_path):
    import threading
    import time

    import redis
    import torch

    from common.action_space import ActionSpace
    from common.keys import Keys
    from common.policy import action_space_spec, build_policy
    from common.protocol import PolicyVersion
    from common.weights import checkpoint_to_bytes
    from model_store import LocalStore, RunStore
    from model_store.runs import checkpoint_key
    from racer.embedded_redis import EmbeddedRedis
    from racer.runconfig import build_run
    from tests.faults import wait_for
    from trainer.evaluator import EvalSettings, EvaluatorOptions, run_evaluator

    run, files = build_run("ev-cond", track=DEFAULT_TRACK)
    runs = RunStore(LocalStore(tmp_path))
    for name, data in files.items():
        runs.write_file(run.run_id, name, data)
    runs.write_config(run)
    model = build_policy(
        (120, 160, 1), action_space_spec(ActionSpace.model_validate_json(files["model_metadata.json"]))
    )
    runs.save_checkpoint(run.run_id, 1, checkpoint_to_bytes(model.state_dict()), {"env_steps": 100})
    threads, stop = torch.get_num_threads(), threading.Event()
    with EmbeddedRedis() as server:
        settings = EvalSettings(episodes=1, both_directions=False)
        conditions = load_conditions(["tape,speed-0.5"])
        opts = EvaluatorOptions(run.run_id, server.url, str(tmp_path), settings=settings, conditions=conditions)
        thread = threading.Thread(target=run_evaluator, args=(opts, stop), daemon=True)
        thread.start()
        try:
            pv = PolicyVersion(version=1, checkpoint_key=checkpoint_key(run.run_id, 1), created=time.time())
            r = redis.Redis.from_url(server.url)
            r.set(Keys(run.run_id).policy, pv.to_json())
            wait_for(lambda: runs.evaluation_versions(run.run_id), 60, "the evaluation")
        finally:
            stop.set()
            thread.join(10)
            torch.set_num_threads(threads)  # run_evaluator sets this process's torch to one thread
    record = runs.read_evaluation(run.run_id, 1)
    assert [c["name"] for c in record["conditions"]] == ["tape", "speed-0.5"]
    assert all(c["episodes"] == 1 and 0 <= c["laps"] <= 1 for c in record["conditions"])
