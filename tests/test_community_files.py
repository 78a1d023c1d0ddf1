"""DeepRacer users' files run unchanged: the reward-function patterns found in public community files, and real public
model_metadata.json, hyperparameters.json and DRfC run.env files.

Reward functions: racer's own files in ``tests/data/reward_patterns`` (its README says which pattern each covers).
Each working one runs after the pre-start check for 300 steps in both directions on racer's own track and, when
DeepRacer's routes are in ``../shared/data/tracks``, on reinvent_base, Spain_track (clockwise, negative coordinates)
and 2022_summit_speedway; what each relies on is checked (return types, state kept across calls, prints). The files in
``broken/`` fail as they would in DeepRacer (the same exception on the same line) and racer says so in one line naming
the file and the line.

model_metadata.json, hyperparameters.json and run.env: real public files, read in place from
``../shared/data/community`` (never copied into the repository; ``SOURCES.md`` there gives their provenance). Their
tests skip, saying so, without that folder. What racer can honour loads and trains (the stereo-camera and LiDAR files
drive the env through a network built for their sensors); the rest is refused in one line naming the file, the key
and the value. Every hyperparameters.json loads, and what racer does not use is listed.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from collections.abc import Callable
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
from sim.reward import RewardFunctionError, load_reward_function
from sim.track import DEFAULT_TRACK
from tests.shared_data import SHARED_DATA, needs_deepracer_tracks, shared_data
from trainer.process import Trainer, TrainerOptions

PATTERNS = Path(__file__).parent / "data" / "reward_patterns"
BROKEN = PATTERNS / "broken"
WORKING = sorted(p.name for p in PATTERNS.glob("*.py"))
# racer's own track always; DeepRacer's when their routes are in the shared folder.
TRACKS = [
    DEFAULT_TRACK,
    pytest.param("reinvent_base", marks=needs_deepracer_tracks),
    pytest.param("Spain_track", marks=needs_deepracer_tracks),  # clockwise, negative coordinates
    pytest.param("2022_summit_speedway", marks=needs_deepracer_tracks),
]

# Broken on every call, as Python fails in DeepRacer's simapp too: what racer's one-line error must say.
BROKEN_ON_EVERY_CALL = {
    "syntax_error.py": "has a syntax error at line 4",  # a dict literal misses a comma; found when loading
    "undefined_name.py": "raised NameError: name 'turn_ahead' is not defined (line 13)",
    "raceline_two_columns.py": "raised IndexError: list index out of range (line 17)",  # [x, y] rows read at [2]
    "returns_none.py": "returned None (NoneType), which float() refuses",  # no return statement
}
# Broken at some poses only: (exception, line).
BROKEN_AT_SOME_POSES = {
    "if_elif_no_else.py": ("UnboundLocalError", 15),  # right of the centre, beyond a quarter width
    "modulo_precedence.py": ("IndexError", 9),  # waypoints[i + 1 % n] when i is the last index
}

# The public files the tests read from ../shared/data/community (SOURCES.md there says where each comes from).
METADATA = [
    "analysis_console_lidar_config_v4.0.json",
    "codeiwomple_discrete30.json",
    "cpravin_discrete29.json",
    "cydia_discrete62_float_angles.json",
    "davidj24_discrete14.json",
    "digant_discrete4.json",
    "dots_discrete5_varied_speed.json",
    "dots_sac_stereo.json",
    "dpr401_front_lidar_deep_discrete10.json",
    "dpr401_stereo_deep_discrete10.json",
    "dpr401_stereo_lidar_shallow_discrete5.json",
    "drfc_default_continuous.json",
    "drfc_default_discrete5.json",
    "drfc_default_sac.json",
    "iryna_discrete17.json",
    "markjamesross_continuous_greyscale.json",
    "mattcamp_discrete7_v2_indexed.json",
    "nishanthartham_stereo_ppo_continuous.json",
    "ronaldrogers_action_space_only_discrete10.json",
    "simapp_sample_no_version.json",
    "stevenjulbrich_discrete21_v4.json",
    "tokyodrift_deepcnn_continuous_v4.json",
    "vishalloke_sac_stereo_INVERTED_STEERING.json",
    "workshops_discrete9_v3_indexed.json",
]
HYPERPARAMS = [
    "analysis_console.json",
    "codeiwomple_ppo_bs256.json",
    "codeiwomple_sac.json",
    "cydia_ppo.json",
    "dots_default.json",
    "dots_sac.json",
    "drfc_default.json",
    "markjamesross_user.json",
    "mattcamp_rl_coach_2020.json",
    "tokyodrift_drfc_user.json",
]
RUN_ENVS = ["codeiwomple_run.env", "dots_run.env", "drfc_template-run.env"]
SHARED_FILES = (
    [("metadata", n) for n in METADATA] + [("hyperparams", n) for n in HYPERPARAMS] + [("drfc", n) for n in RUN_ENVS]
)

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


def community(*parts: str) -> Path:
    """A public community file, read in place from the shared folder; skips the test without it."""
    return shared_data("community", *parts)


# --- reward-function patterns ------------------------------------------------------------------------------------


def documented(section: str) -> set[str]:
    """The file names in the first column of a README table, for one section (## heading) of it."""
    text = (PATTERNS / "README.md").read_text()
    body = text.split(section, 1)[1].split("\n## ", 1)[0]
    return set(re.findall(r"^\| `([^`]+\.py)` \|", body, flags=re.MULTILINE))


def test_every_pattern_file_is_written_for_racer_and_documented() -> None:
    assert len(WORKING) >= 26 and len(BROKEN_ON_EVERY_CALL) + len(BROKEN_AT_SOME_POSES) == 6
    assert documented("## Working patterns") == set(WORKING)
    assert documented("## `broken/`") == {p.name for p in BROKEN.glob("*.py")}
    assert set(BROKEN_ON_EVERY_CALL) | set(BROKEN_AT_SOME_POSES) == {p.name for p in BROKEN.glob("*.py")}
    assert documented("## `oa/`") == {p.name for p in (PATTERNS / "oa").glob("*.py")}
    # Written for racer: no file of a community repository (licence texts, provenance tables) lives beside them.
    files = [p for p in PATTERNS.rglob("*") if p.is_file() and "__pycache__" not in p.parts]
    assert [p for p in files if p.suffix not in (".py", ".md")] == []
    assert not (Path(__file__).parent / "data" / "community").exists()


def drive(
    path: Path, track: str, steps: int = 300, watch: Callable[[dict, object, float, dict], None] | None = None
) -> tuple[set[bool], list[float]]:
    """The pre-start check, then ``steps`` random steps alternating direction: the directions driven and the
    rewards. ``watch(params, raw, reward, info)`` sees each call's params, what the function returned, the step's
    reward and its info."""
    config = EnvConfig(track=track, reward_fn=str(path), camera="ground", randomization={"alternate_direction": True})
    preflight_reward(config)
    env = RacerEnv(config=config)
    calls: list[tuple[dict, object]] = []
    user_fn = env.reward_fn.fn

    def watched(params: dict) -> object:
        raw = user_fn(params)
        calls.append((params, raw))
        return raw

    env.reward_fn.fn = watched
    env.reset(seed=1)
    rng, directions, rewards = np.random.default_rng(0), set(), []
    try:
        for _ in range(steps):
            _, reward, terminated, truncated, info = env.step(int(rng.integers(env.actions.n)))
            assert type(reward) is float and math.isfinite(reward), reward
            rewards.append(reward)
            directions.add(info["params"]["is_reversed"])
            if watch is not None:
                watch(*calls[-1], reward, info)
            if terminated or truncated:
                env.reset()
    finally:
        env.close()
    assert len(calls) == steps  # one call per step
    return directions, rewards


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize("track", TRACKS)
@pytest.mark.parametrize("pattern", WORKING)
def test_reward_patterns_run_unchanged_in_both_directions(pattern: str, track: str, capsys) -> None:
    directions, _ = drive(PATTERNS / pattern, track)
    assert directions == {False, True}
    capsys.readouterr()  # many of them print every step, as community functions do in DeepRacer's logs


@pytest.mark.parametrize(("pattern", "raw_type"), [("waypoint_lanes_int.py", int), ("returns_bool.py", bool)])
def test_an_int_or_a_bool_reward_is_taken_as_its_float(pattern: str, raw_type: type, capsys) -> None:
    seen: set[type] = set()

    def watch(params: dict, raw: object, reward: float, info: dict) -> None:
        seen.add(type(raw))
        assert reward == float(raw)

    drive(PATTERNS / pattern, DEFAULT_TRACK, watch=watch)
    assert seen == {raw_type}
    capsys.readouterr()


def test_negative_rewards_and_the_params_own_speed_come_back_as_returned(capsys) -> None:
    statuses: list[tuple[str, float]] = []
    drive(
        PATTERNS / "returns_negative.py",
        DEFAULT_TRACK,
        watch=lambda params, raw, reward, info: statuses.append((info["episode_status"], reward)),
    )
    off = [reward for status, reward in statuses if status == "off_track"]
    assert off and set(off) == {-5.0}  # the bare -5.0 off the track
    assert {16.0, -14.999} & {reward for _, reward in statuses}  # 31 - 15 near the centre, 1e-3 - 15 near the edge

    def same_speed(params: dict, raw: object, reward: float, info: dict) -> None:
        if params["all_wheels_on_track"]:
            assert raw is params["speed"] and reward == info["params"]["speed"]

    drive(PATTERNS / "speed_only.py", DEFAULT_TRACK, watch=same_speed)
    capsys.readouterr()


def user_module(env: RacerEnv) -> dict:
    """The globals of the reward file an env loaded."""
    return env.reward_fn.fn.__globals__


def test_state_kept_across_calls_sees_every_step_from_step_2(capsys) -> None:
    """The framework pattern keeps one history per episode, reset at steps <= 2: one entry per call means racer calls
    it once per step, first with steps == 2, as the simapp does."""
    env = RacerEnv(track=DEFAULT_TRACK, reward_fn=str(PATTERNS / "framework_history.py"), camera="ground")
    assert user_module(env)["framework"] is None  # built on the first call, not at import
    env.reset(seed=0)
    rng = np.random.default_rng(3)
    episodes = 0
    for _ in range(200):
        _, _, terminated, truncated, info = env.step(int(rng.integers(env.actions.n)))
        framework = user_module(env)["framework"]
        assert framework.steps == info["params"]["steps"] >= 2
        assert len(framework.history) == info["params"]["steps"] - 1
        if terminated or truncated:
            episodes += 1
            env.reset()
    assert episodes >= 1
    env.close()
    capsys.readouterr()


def test_first_call_caches_are_built_once_per_load_and_not_shared_with_the_check(capsys) -> None:
    config = EnvConfig(
        track=DEFAULT_TRACK,
        reward_fn=str(PATTERNS / "smoothed_path_first_call.py"),
        camera="ground",
        randomization={"alternate_direction": True},
    )
    preflight_reward(config)  # builds the smoothed line in its own copy of the module
    env = RacerEnv(config=config)
    smoothed = user_module(env)["Smoothed"]
    assert smoothed.builds == 0 and smoothed.POINTS == []
    env.reset(seed=0)
    _, _, _, _, info = env.step(0)
    line = smoothed.POINTS
    assert smoothed.builds == 1 and len(line) == len(info["params"]["waypoints"])
    for i in range(100):
        _, _, terminated, truncated, _ = env.step(i % env.actions.n)
        if terminated or truncated:
            env.reset()
    assert smoothed.builds == 1 and smoothed.POINTS is line
    env.close()

    env = RacerEnv(config=config.model_copy(update={"reward_fn": str(PATTERNS / "turn_cache_globals.py")}))
    module = user_module(env)
    assert module["turn_points"] is None
    env.reset(seed=0)
    env.step(0)
    turns = module["turn_points"]
    assert turns and all(0 < i < 200 for i in turns)
    env.step(0)
    assert module["turn_points"] is turns
    env.close()
    capsys.readouterr()


def test_prints_go_to_the_logs_not_to_the_check(capsys) -> None:
    config = EnvConfig(track=DEFAULT_TRACK, reward_fn=str(PATTERNS / "rules_trace.py"), camera="ground")
    preflight_reward(config)
    assert capsys.readouterr().out == ""  # racer check and racer train print their own lines only
    env = RacerEnv(config=config)
    env.reset(seed=0)
    for _ in range(5):
        env.step(0)
    env.close()
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == ["TRACE_STATUS", "TRACE_WAYPOINTS"] * 5
    assert len(lines[1].split()) == 1 + 3 * len(env.track.center)  # every waypoint, unpacked as [x, y]


def test_the_last_of_two_definitions_is_the_reward_function(capsys) -> None:
    """The first definition raises UnboundLocalError at speeds <= 2 (every action of racer's default space); the
    second, which Python keeps, is what runs."""

    def second(params: dict, raw: object, reward: float, info: dict) -> None:
        if params["all_wheels_on_track"]:
            expected = params["speed"] + (1 - params["distance_from_center"] / (params["track_width"] / 2)) * 0.1
            expected += params["progress"] / 100
        else:
            expected = 1e-3
        assert reward == pytest.approx(expected)

    drive(PATTERNS / "two_definitions.py", DEFAULT_TRACK, watch=second)
    capsys.readouterr()


@pytest.mark.parametrize("pattern", sorted(BROKEN_ON_EVERY_CALL))
def test_broken_patterns_fail_in_one_line_naming_the_file_and_line(pattern: str) -> None:
    with pytest.raises(RewardFunctionError) as info:
        drive(BROKEN / pattern, DEFAULT_TRACK)
    message = str(info.value)
    assert pattern in message and BROKEN_ON_EVERY_CALL[pattern] in message and "\n" not in message, message


def params_at_start(track: str = DEFAULT_TRACK) -> dict:
    env = RacerEnv(track=track, camera="ground", randomization={"random_start": False})
    _, info = env.reset(seed=0, options={"start_index": 0})
    env.close()
    return info["params"]


@pytest.mark.parametrize("pattern", sorted(BROKEN_AT_SOME_POSES))
def test_patterns_broken_at_some_poses_fail_there_in_one_line(pattern: str) -> None:
    kind, line = BROKEN_AT_SOME_POSES[pattern]
    fn = load_reward_function(BROKEN / pattern)
    good = params_at_start()
    n = len(good["waypoints"])
    if pattern == "if_elif_no_else.py":
        bad = dict(good, is_left_of_center=False, distance_from_center=0.3 * good["track_width"])
    else:
        bad = dict(good, closest_waypoints=[n - 5, n - 4])  # ahead = n - 1
    assert math.isfinite(fn(good, step=2))
    with pytest.raises(RewardFunctionError) as info:
        fn(bad, step=7)
    message = str(info.value)
    assert f"{pattern}' at step 7 raised {kind}" in message and f"(line {line})" in message, message
    assert "\n" not in message


@pytest.mark.parametrize("track", TRACKS)
@pytest.mark.parametrize("pattern", sorted(BROKEN_AT_SOME_POSES))
def test_patterns_broken_at_some_poses_run_or_fail_as_in_deepracer(pattern: str, track: str) -> None:
    kind, line = BROKEN_AT_SOME_POSES[pattern]
    try:
        assert drive(BROKEN / pattern, track)[0] == {False, True}
    except RewardFunctionError as exc:
        message = str(exc)
        assert pattern in message and f"raised {kind}" in message and f"(line {line})" in message, message
        assert "\n" not in message and "checked before training" not in message  # the check drives good poses


def test_racer_check_names_the_file_and_line_of_a_broken_function() -> None:
    path = BROKEN / "undefined_name.py"
    done = subprocess.run(
        [sys.executable, "-m", "racer", "check", "--reward-fn", str(path), "--track", DEFAULT_TRACK],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "undefined_name.py" in lines[0] and "(line 13)" in lines[0], lines


# --- public model_metadata.json, hyperparameters.json and run.env files (../shared/data/community) ----------------


def test_the_shared_community_files_are_all_there_with_their_provenance() -> None:
    sources = community("SOURCES.md").read_text()
    for folder, name in SHARED_FILES:
        assert (SHARED_DATA / "community" / folder / name).is_file(), f"{folder}/{name} is not in the shared folder"
        assert f"`{folder}/{name}`" in sources, f"{folder}/{name} has no provenance row in SOURCES.md"


@pytest.mark.parametrize("name", METADATA)
def test_community_model_metadata_loads_or_is_refused_in_one_line(name: str) -> None:
    path = community("metadata", name)
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
    env = RacerEnv(track=DEFAULT_TRACK, action_space=str(path), camera="ground")
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


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize("name", SENSOR_METADATA)
def test_stereo_and_lidar_community_files_drive_the_env_through_their_network(name: str) -> None:
    """The env gives the observation the file's sensors promise, and a network built for them acts on it."""
    path = community("metadata", name)
    space = load_action_space(path)
    spec = observation_spec(space.sensor)
    env = RacerEnv(track=DEFAULT_TRACK, action_space=str(path), camera="ground")
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
    path = community("hyperparams", name)
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


@pytest.mark.slow(reason="a real trainer and worker over Redis")
@pytest.mark.parametrize(("metadata", "hyperparams"), TRAIN_PAIRS)
def test_community_files_train(metadata: str, hyperparams: str, redis_url, run_id, tmp_path) -> None:
    run, files = build_run(
        run_id,
        track=DEFAULT_TRACK,
        reward_fn=str(PATTERNS / "direction_from_closest.py"),
        action_space=str(community("metadata", metadata)),
        hyperparams=str(community("hyperparams", hyperparams)),
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


def drfc_folder_with(tmp_path: Path, run_env: str, edit: Callable[[str], str] = lambda text: text) -> Path:
    """A DRfC folder holding a community run.env (``edit`` applied to its text) beside DRfC's default
    model_metadata.json and hyperparameters.json and one of racer's reward patterns."""
    folder = tmp_path / "drfc"
    (folder / "custom_files").mkdir(parents=True)
    (folder / "run.env").write_text(edit(community("drfc", run_env).read_text()))
    (folder / "custom_files" / "reward_function.py").write_bytes((PATTERNS / "direction_from_closest.py").read_bytes())
    for name, (kind, src) in {
        "model_metadata.json": ("metadata", "drfc_default_discrete5.json"),
        "hyperparameters.json": ("hyperparams", "drfc_default.json"),
    }.items():
        (folder / "custom_files" / name).write_bytes(community(kind, src).read_bytes())
    return folder


@needs_deepracer_tracks
def test_community_run_env_files_import_as_drfc_reads_them(tmp_path: Path) -> None:
    from racer.check import merge_inputs
    from racer.options import RunOptions

    # DR_LOCAL_S3_MODEL_PREFIX=training/$DR_WORLD_NAME/first-model: expanded as the shell DRfC sources it with.
    dots, dots_drfc = merge_inputs(RunOptions(), drfc_folder_with(tmp_path / "a", "dots_run.env"))
    assert dots.track == "reInvent2019_track" and dots.run_id == "training-reInvent2019_track-first-model"
    assert dots.eval_episodes == 3 and "DR_EVAL_OFF_TRACK_PENALTY" in dots_drfc.mapped
    # A time trial: its DR_OA_*/DR_H2B_* lines (DRfC's template writes them all) place nothing.
    assert dots.race.race_type == "TIME_TRIAL" and dots.race.obstacle_count == dots.race.bot_car_count == 0
    assert dots.race.penalties.off_track_penalty == 5.0
    template, template_drfc = merge_inputs(RunOptions(), drfc_folder_with(tmp_path / "b", "drfc_template-run.env"))
    assert template.track == "reinvent_base" and template.randomization_update["round_robin_divisions"] == 20
    assert template.race.race_type == "TIME_TRIAL" and template.race.penalties.number_of_resets == 100
    assert not [k for k in template_drfc.unmapped if k.startswith(("DR_OA_", "DR_H2B_", "DR_RACE_"))]


def test_a_community_run_env_imports_on_the_track_given(tmp_path: Path) -> None:
    from racer.check import merge_inputs
    from racer.options import RunOptions

    folder = drfc_folder_with(tmp_path, "codeiwomple_run.env")  # DR_WORLD_NAME=2022_april_pro_ccw
    inputs, _ = merge_inputs(RunOptions(track=DEFAULT_TRACK), folder)
    assert inputs.track == DEFAULT_TRACK and inputs.pretrained == "conor-model-finals-v4-16:latest"
    done = subprocess.run(
        [sys.executable, "-m", "racer", "check", "--from-drfc", str(folder), "--track", DEFAULT_TRACK],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "no racer meaning, not used:" in done.stdout and "DR_CAR_NAME" in done.stdout


def test_a_drfc_track_racer_cannot_find_is_one_line_unless_track_is_given(tmp_path: Path) -> None:
    from racer.check import merge_inputs
    from racer.drfc import DrfcError
    from racer.options import RunOptions

    folder = drfc_folder_with(
        tmp_path, "codeiwomple_run.env", edit=lambda text: text.replace("=2022_april_pro_ccw", "=no_such_track")
    )
    with pytest.raises(DrfcError) as info:
        merge_inputs(RunOptions(), folder)
    message = str(info.value)
    assert "run.env" in message and "DR_WORLD_NAME='no_such_track'" in message and "\n" not in message
    assert merge_inputs(RunOptions(track=DEFAULT_TRACK), folder)[0].track == DEFAULT_TRACK


def test_racer_check_prints_its_own_lines_only_for_a_printing_function() -> None:
    """The function prints when its file is run and on every call; racer check's output holds only racer's lines."""
    path = PATTERNS / "timer_rtf_window.py"
    done = subprocess.run(
        [sys.executable, "-m", "racer", "check", "--reward-fn", str(path), "--track", DEFAULT_TRACK],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "timer_rtf_window.py" in done.stdout
    assert "timer ready" not in done.stdout + done.stderr and "TIME:" not in done.stdout + done.stderr
