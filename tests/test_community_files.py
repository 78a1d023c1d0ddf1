"""Real DeepRacer community files (tests/data/community, provenance and licences in SOURCES.md), run unchanged.

Reward functions: the pre-start check, then 300 steps on three tracks (reinvent_base; Spain_track, clockwise with
negative coordinates; 2022_summit_speedway), in both directions. The files that are broken upstream fail as they
would in DeepRacer (the same exception on the same line) and racer says so in one line naming the file and line.
model_metadata.json: what racer can honour loads and trains (the stereo-camera and LiDAR files drive the env through a
network built for their sensors); the rest is refused in one line naming the file, the key and the value.
hyperparameters.json: every file loads, and what racer does not use is listed.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from common.action_space import ActionSpaceError, load_action_space
from common.config import EnvConfig, PolicyConfig, network_from_metadata
from common.hyperparams import load_hyperparameters
from common.policy import action_space_spec, build_policy
from common.sensors import camera_frame_size, check_lidar, observation_spec, split_observation
from racer.runconfig import build_run
from rollout_worker.worker import RolloutWorker, WorkerOptions
from sim.env import RacerEnv, preflight_reward
from sim.reward import RewardFunctionError
from trainer.process import Trainer, TrainerOptions

COMMUNITY = Path(__file__).parent / "data" / "community"
REWARDS = sorted(p.name for p in (COMMUNITY / "reward").glob("*.py"))
METADATA = sorted(p.name for p in (COMMUNITY / "metadata").glob("*.json"))
HYPERPARAMS = sorted(p.name for p in (COMMUNITY / "hyperparams").glob("*.json"))
TRACKS = ("reinvent_base", "Spain_track", "2022_summit_speedway")

# Files broken upstream: (exception, line) as Python raises it in DeepRacer's simapp too, on every call.
BROKEN_ON_EVERY_CALL = {
    "anjrew_blog_fragment_returns_none.py": ("NameError", 42),  # is_heading_in_right_direction is never defined
    "anjrew_prev_state_class_attrs.py": ("NameError", 86),  # the same undefined name
    "codeiwomple_refactor_SYNTAX_ERROR.py": ("syntax error", 76),  # a dict literal misses a comma
    "jenniferclemens_capstone_class_verbose.py": ("IndexError", 363),  # its racing line has 2 columns, reads [2]
}
# Broken upstream at some poses only: (exception, the lines it may come from).
BROKEN_AT_SOME_POSES = {
    # An if/elif chain without else leaves a local unset.
    "dhruvaggarwal_global_turn_cache.py": ("UnboundLocalError", (219, 221)),
    # waypoints[i + 1 % n] is waypoints[i + 1]: past the end when closest_waypoints[1] is n - 6.
    "alosaurus_memory_class_prev_steps.py": ("IndexError", (40,)),
}

# model_metadata.json files racer refuses: the key and value the one-line error must name.
REFUSED_METADATA = {
    "dots_sac_stereo.json": 'training_algorithm = "sac"',  # racer builds its stereo cameras, not SAC
    "drfc_default_sac.json": 'training_algorithm = "sac"',
    "vishalloke_sac_stereo_INVERTED_STEERING.json": "steering_angle: Value error, low 20.0 is above high -30.0",
}
# model_metadata.json files with the other sensors racer builds (stereo cameras, LiDAR): they load and drive.
SENSOR_METADATA = (
    "dpr401_front_lidar_deep_discrete10.json",
    "dpr401_stereo_deep_discrete10.json",
    "dpr401_stereo_lidar_shallow_discrete5.json",
    "nishanthartham_stereo_ppo_continuous.json",
)


def test_the_collection_is_as_large_as_the_issue_asks() -> None:
    assert len(REWARDS) >= 15 and len(METADATA) >= 8 and len(HYPERPARAMS) >= 4
    sources = (COMMUNITY / "SOURCES.md").read_text()
    for folder, names in (("reward", REWARDS), ("metadata", METADATA), ("hyperparams", HYPERPARAMS)):
        for name in names:
            assert f"`{folder}/{name}`" in sources, f"{folder}/{name} has no provenance row in SOURCES.md"


def drive(reward: str, track: str, steps: int = 300) -> set[bool]:
    """The pre-start check, then ``steps`` random steps alternating direction; the directions driven."""
    config = EnvConfig(
        track=track,
        reward_fn=str(COMMUNITY / "reward" / reward),
        camera="ground",
        randomization={"alternate_direction": True},
    )
    preflight_reward(config)
    env = RacerEnv(config=config)
    env.reset(seed=1)
    rng, directions = np.random.default_rng(0), set()
    for _ in range(steps):
        _, value, terminated, truncated, info = env.step(int(rng.integers(env.actions.n)))
        assert math.isfinite(value)
        directions.add(info["params"]["is_reversed"])
        if terminated or truncated:
            env.reset()
    env.close()
    return directions


@pytest.mark.parametrize("reward", REWARDS)
def test_community_reward_functions_run_unchanged_or_fail_as_in_deepracer(reward: str, capsys) -> None:
    for track in TRACKS:
        if reward in BROKEN_ON_EVERY_CALL:
            kind, line = BROKEN_ON_EVERY_CALL[reward]
            with pytest.raises(RewardFunctionError) as info:
                drive(reward, track)
            message = str(info.value)
            assert reward in message and kind in message and f"line {line}" in message, message
            assert "\n" not in message
            continue
        try:
            assert drive(reward, track) == {False, True}
        except RewardFunctionError as exc:
            if reward not in BROKEN_AT_SOME_POSES:
                raise
            kind, lines = BROKEN_AT_SOME_POSES[reward]
            message = str(exc)
            line = re.search(r"\(line (\d+)\)", message)
            assert kind in message and reward in message and "\n" not in message, message
            assert line and int(line.group(1)) in lines, message
    capsys.readouterr()  # many community functions print every step, as they do in DeepRacer's logs


def test_racer_check_names_the_file_and_line_of_a_broken_community_function() -> None:
    path = COMMUNITY / "reward" / "anjrew_prev_state_class_attrs.py"
    done = subprocess.run(
        [sys.executable, "-m", "racer", "check", "--reward-fn", str(path)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "anjrew_prev_state_class_attrs.py" in lines[0] and "(line 86)" in lines[0], lines


@pytest.mark.parametrize("name", METADATA)
def test_community_model_metadata_loads_or_is_refused_in_one_line(name: str) -> None:
    path = COMMUNITY / "metadata" / name
    if name in REFUSED_METADATA:
        with pytest.raises(ActionSpaceError) as info:
            load_action_space(path)
        message = str(info.value)
        assert name in message and REFUSED_METADATA[name] in message and "\n" not in message, message
        return
    space = load_action_space(path)
    # A file without a sensor list drives the front camera (the simapp's default).
    assert space.sensor == json.loads(path.read_text()).get("sensor", ["FRONT_FACING_CAMERA"])
    assert space.training_algorithm == "clipped_ppo"
    # It drives: the env takes each of its actions (or its range's corners) and the reward is told their values.
    env = RacerEnv(track="reinvent_base", action_space=str(path), camera="ground")
    env.reset(seed=0)
    data = json.loads(path.read_text())["action_space"]
    if space.discrete:
        for i in range(space.n):
            _, _, terminated, truncated, info = env.step(i)
            assert info["params"]["speed"] == float(data[i]["speed"])
            assert info["params"]["steering_angle"] == float(data[i]["steering_angle"])
            if terminated or truncated:
                env.reset()
    else:
        low = [space.action_space.steering_angle.low, space.action_space.speed.low]
        _, _, _, _, info = env.step(np.array(low, np.float32))
        assert (info["params"]["steering_angle"], info["params"]["speed"]) == pytest.approx(low)
    env.close()


@pytest.mark.parametrize("name", SENSOR_METADATA)
def test_stereo_and_lidar_community_files_drive_the_env_through_their_network(name: str) -> None:
    """The env gives the observation the file's sensors promise, and a network built for them acts on it."""
    path = COMMUNITY / "metadata" / name
    space = load_action_space(path)
    spec = observation_spec(space.sensor)
    env = RacerEnv(track="reinvent_base", action_space=str(path), camera="ground")
    obs_shape = spec.camera_shape(camera_frame_size(env.observation_space))
    cfg = PolicyConfig(network=network_from_metadata(space.neural_network))
    torch.manual_seed(0)
    model = build_policy(obs_shape, action_space_spec(space), cfg, space.sensor).eval()
    observation, _ = env.reset(seed=0)
    for _ in range(50):
        camera, lidar = split_observation(observation)
        assert camera.shape == obs_shape and camera.dtype == np.uint8
        assert (lidar is None) == (spec.lidar is None)
        if lidar is not None:
            assert check_lidar(spec.lidar, lidar) is None
        action, _, value = model.act_numpy(camera[None], lidar=None if lidar is None else lidar[None])
        assert np.isfinite(value).all()
        observation, _, terminated, truncated, _ = env.step(action[0])
        if terminated or truncated:
            observation, _ = env.reset()
    env.close()


@pytest.mark.parametrize("name", HYPERPARAMS)
def test_community_hyperparameters_load_and_what_racer_ignores_is_listed(name: str) -> None:
    path = COMMUNITY / "hyperparams" / name
    hp = load_hyperparameters(path)
    data = json.loads(path.read_text())
    for key in ("batch_size", "lr", "num_epochs", "discount_factor", "beta_entropy"):
        if key in data:
            assert getattr(hp, key) == pytest.approx(float(data[key])), key
    listed = " ".join(hp.ignored())
    for key in ("sac_alpha", "term_cond_avg_score"):
        assert (key in listed) == (key in data), key
    for key in set(data) - set(type(hp).model_fields):
        assert key in listed, key


# One training iteration for each pairing: discrete with many actions, continuous, the deep network, a legacy file.
TRAIN_PAIRS = [
    ("cydia_discrete62_float_angles.json", "codeiwomple_ppo_bs256.json"),
    ("drfc_default_continuous.json", "drfc_default.json"),
    ("tokyodrift_deepcnn_continuous_v4.json", "tokyodrift_drfc_user.json"),
    ("ronaldrogers_action_space_only_discrete10.json", "mattcamp_rl_coach_2020.json"),
]


@pytest.mark.parametrize(("metadata", "hyperparams"), TRAIN_PAIRS)
def test_community_files_train(metadata: str, hyperparams: str, redis_url, run_id, tmp_path) -> None:
    run, files = build_run(
        run_id,
        track="Straight_track",
        reward_fn=str(COMMUNITY / "reward" / "drfc_default_steering_penalty.py"),
        action_space=str(COMMUNITY / "metadata" / metadata),
        hyperparams=str(COMMUNITY / "hyperparams" / hyperparams),
    )
    # The file's own PPO settings, with fewer episodes per update and epochs so that one update takes seconds.
    hp = run.hyperparams.model_copy(update={"num_episodes_between_training": 2, "num_epochs": 1})
    run = run.model_copy(update={"segment_steps": 16, "hyperparams": hp})
    store = str(tmp_path / "store")
    trainer = Trainer(run, TrainerOptions(redis_url, store, run_files=files))
    trainer.start()
    worker = RolloutWorker(WorkerOptions(run_id, redis_url, store))
    worker.start()
    try:
        for _ in range(60):
            worker.push(worker.collect())
            trainer.read(block_ms=100)
            if trainer.ready():
                break
        stats = trainer.train()
        assert all(np.isfinite(v) for v in stats.values())
        assert worker.poll_policy() and worker.policy_version == 1
    finally:
        worker.close()


def drfc_folder_with(tmp_path: Path, run_env: str) -> Path:
    """A DRfC folder holding a community run.env beside DRfC's default custom files."""
    folder = tmp_path / "drfc"
    (folder / "custom_files").mkdir(parents=True)
    (folder / "run.env").write_bytes((COMMUNITY / "drfc" / run_env).read_bytes())
    for name, src in (
        ("reward_function.py", "reward/drfc_default_steering_penalty.py"),
        ("model_metadata.json", "metadata/drfc_default_discrete5.json"),
        ("hyperparameters.json", "hyperparams/drfc_default.json"),
    ):
        (folder / "custom_files" / name).write_bytes((COMMUNITY / src).read_bytes())
    return folder


def test_community_run_env_files_import_as_drfc_reads_them(tmp_path: Path) -> None:
    from racer.check import merge_inputs

    # DR_LOCAL_S3_MODEL_PREFIX=training/$DR_WORLD_NAME/first-model: expanded as the shell DRfC sources it with.
    dots = merge_inputs(None, None, None, None, drfc_folder_with(tmp_path / "a", "dots_run.env"))
    assert dots.track == "reInvent2019_track" and dots.run_id == "training-reInvent2019_track-first-model"
    assert dots.eval_episodes == 3 and "DR_EVAL_OFF_TRACK_PENALTY" in dots.drfc.mapped
    # A time trial: its DR_OA_*/DR_H2B_* lines (DRfC's template writes them all) place nothing.
    assert dots.race.race_type == "TIME_TRIAL" and dots.race.obstacle_count == dots.race.bot_car_count == 0
    assert dots.race.penalties.off_track_penalty == 5.0
    template = merge_inputs(None, None, None, None, drfc_folder_with(tmp_path / "b", "drfc_template-run.env"))
    assert template.track == "reinvent_base" and template.randomization["round_robin_divisions"] == 20
    assert template.race.race_type == "TIME_TRIAL" and template.race.penalties.number_of_resets == 100
    assert not [k for k in template.drfc.unmapped if k.startswith(("DR_OA_", "DR_H2B_", "DR_RACE_"))]


def test_a_drfc_track_racer_does_not_ship_is_one_line_unless_track_is_given(tmp_path: Path) -> None:
    from racer.check import merge_inputs
    from racer.drfc import DrfcError

    folder = drfc_folder_with(tmp_path, "codeiwomple_run.env")
    with pytest.raises(DrfcError) as info:
        merge_inputs(None, None, None, None, folder)
    message = str(info.value)
    assert "run.env" in message and "DR_WORLD_NAME='2022_april_pro_ccw'" in message and "\n" not in message
    inputs = merge_inputs("reinvent_base", None, None, None, folder)
    assert inputs.track == "reinvent_base" and inputs.pretrained == "conor-model-finals-v4-16:latest"
    done = subprocess.run(
        [sys.executable, "-m", "racer", "check", "--from-drfc", str(folder), "--track", "reinvent_base"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "no racer meaning, not used:" in done.stdout and "DR_CAR_NAME" in done.stdout
