"""Tests of DeepRacer action spaces (common.action_space) and their use by the env."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import sim  # noqa: F401  (registers Racer-v0)
from common.action_space import (
    MAX_SPEED_MPS,
    MAX_STEERING_DEG,
    MIN_SPEED_MPS,
    ActionSpace,
    ActionSpaceError,
    ContinuousSpace,
    DiscreteAction,
    Range,
    clip_command,
    default_action_space,
    load_action_space,
)
from common.defaults import DEFAULT_TRACK
from sim.env import RacerEnv

DISCRETE_METADATA = (
    '{"action_space": [{"steering_angle": -30.0, "speed": 1.0, "index": 0}, '
    '{"steering_angle": 30.0, "speed": 2.0, "index": 1}], "action_space_type": "discrete", '
    '"neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW", "sensor": ["FRONT_FACING_CAMERA"], '
    '"version": "4.0", "training_algorithm": "clipped_ppo", "lidar_config": {"num_sectors": 8}}'
)
CONTINUOUS_METADATA = (
    '{"action_space": {"steering_angle": {"high": 30.0, "low": -30.0}, "speed": {"high": 4.0, "low": 1.0}}, '
    '"action_space_type": "continuous"}'
)


def write(tmp_path: Path, text: str, name: str = "model_metadata.json") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def continuous(steer: tuple[float, float], speed: tuple[float, float]) -> ActionSpace:
    return ActionSpace(
        action_space_type="continuous",
        action_space=ContinuousSpace(
            steering_angle=Range(low=steer[0], high=steer[1]), speed=Range(low=speed[0], high=speed[1])
        ),
    )


@pytest.fixture(scope="module")
def continuous_env(tmp_path_factory: pytest.TempPathFactory) -> RacerEnv:
    path = write(tmp_path_factory.mktemp("continuous"), CONTINUOUS_METADATA)
    return RacerEnv(track=DEFAULT_TRACK, action_space=str(path))


# --- the default space ----------------------------------------------------------------------------------


def test_default_action_space() -> None:
    space = default_action_space()
    assert space.discrete and space.action_space_type == "discrete"
    assert space.n == 10
    pairs = [(a.steering_angle, a.speed) for a in space.action_space]
    assert sorted(pairs) == sorted((s, v) for s in (-30.0, -15.0, 0.0, 15.0, 30.0) for v in (0.5, 1.0))
    assert [a.index for a in space.action_space] == list(range(10))
    assert [space.command(i) for i in range(10)] == pairs


def test_default_env_has_discrete_10() -> None:
    env = RacerEnv(track=DEFAULT_TRACK)
    assert env.action_space == gymnasium.spaces.Discrete(10)
    assert env.actions == default_action_space()


# --- loading model_metadata.json ------------------------------------------------------------------------


def test_load_discrete_metadata(tmp_path: Path) -> None:
    path = write(tmp_path, DISCRETE_METADATA)
    space = load_action_space(path)
    assert space.discrete and space.n == 2
    assert space.command(0) == (-30.0, 1.0)
    assert space.command(1) == (30.0, 2.0)
    assert space.version == "4.0"
    # Keys racer does not use are kept as given.
    out = json.loads(space.to_json())
    assert out["lidar_config"] == {"num_sectors": 8}
    original = json.loads(DISCRETE_METADATA)
    for key in ("action_space_type", "neural_network", "sensor", "version", "training_algorithm"):
        assert out[key] == original[key]
    assert [(a["steering_angle"], a["speed"], a["index"]) for a in out["action_space"]] == [
        (-30.0, 1.0, 0),
        (30.0, 2.0, 1),
    ]
    # And the written file loads back to the same space.
    again = load_action_space(write(tmp_path, space.to_json(), "again.json"))
    assert again == space
    assert json.loads(again.to_json()) == out


def test_load_discrete_metadata_into_env(tmp_path: Path) -> None:
    path = write(tmp_path, DISCRETE_METADATA)
    env = gymnasium.make("sim:Racer-v0", track=DEFAULT_TRACK, action_space=str(path))
    try:
        assert env.action_space == gymnasium.spaces.Discrete(2)
        env.reset(seed=0)
        *_, info = env.step(1)
        assert info["command"] == (30.0, 2.0)
    finally:
        env.close()


def test_load_continuous_metadata(tmp_path: Path) -> None:
    space = load_action_space(write(tmp_path, CONTINUOUS_METADATA))
    assert not space.discrete and space.n == 0
    assert space.action_space.steering_angle == Range(low=-30.0, high=30.0)
    assert space.action_space.speed == Range(low=1.0, high=4.0)
    assert space.command([10.0, 1.5]) == (10.0, 1.5)
    assert json.loads(space.to_json())["action_space"] == json.loads(CONTINUOUS_METADATA)["action_space"]


def test_continuous_env_has_box_space(continuous_env: RacerEnv) -> None:
    space = continuous_env.action_space
    assert isinstance(space, gymnasium.spaces.Box)
    assert space.shape == (2,) and space.dtype == np.float32
    np.testing.assert_array_equal(space.low, [-30.0, 1.0])
    np.testing.assert_array_equal(space.high, [30.0, 4.0])


@pytest.mark.parametrize(
    ("action_space", "discrete"),
    [
        ([{"steering_angle": 0.0, "speed": 1.0}], True),
        ({"steering_angle": {"low": -20.0, "high": 20.0}, "speed": {"low": 0.5, "high": 2.0}}, False),
    ],
    ids=["discrete", "continuous"],
)
def test_type_inferred_for_older_files(tmp_path: Path, action_space, discrete: bool) -> None:
    path = write(tmp_path, json.dumps({"action_space": action_space, "version": "3"}))
    space = load_action_space(path)
    assert space.discrete is discrete
    assert space.action_space_type == ("discrete" if discrete else "continuous")
    assert json.loads(space.to_json())["action_space_type"] == space.action_space_type


# --- clipping -------------------------------------------------------------------------------------------


def test_discrete_commands_are_clipped_to_car_limits() -> None:
    space = ActionSpace(
        action_space=[
            DiscreteAction(steering_angle=45.0, speed=6.0),
            DiscreteAction(steering_angle=-45.0, speed=0.01),
            DiscreteAction(steering_angle=12.5, speed=-1.0),
        ]
    )
    assert space.command(0) == (30.0, 4.0)
    assert space.command(1) == (-30.0, 0.1)
    assert space.command(2) == (12.5, 0.1)
    assert (MAX_STEERING_DEG, MIN_SPEED_MPS, MAX_SPEED_MPS) == (30.0, 0.1, 4.0)


def test_discrete_command_accepts_numpy_and_rejects_out_of_range() -> None:
    space = default_action_space()
    assert space.command(np.int64(9)) == (30.0, 1.0)
    assert space.command(np.array(0)) == (-30.0, 0.5)
    for bad in (-1, 10):
        with pytest.raises(IndexError):
            space.command(bad)


def test_continuous_commands_are_clipped_to_ranges() -> None:
    space = continuous((-20.0, 25.0), (0.5, 2.0))
    assert space.command([10.0, 1.5]) == (10.0, 1.5)
    assert space.command([-40.0, 3.0]) == (-20.0, 2.0)
    assert space.command((40.0, 0.1)) == (25.0, 0.5)
    assert space.command(np.array([5.0, 1.0], np.float32)) == (5.0, 1.0)
    # A space wider than the car's limits is still held to them.
    wide = continuous((-45.0, 45.0), (0.0, 6.0))
    assert wide.command([44.0, 5.5]) == (30.0, 4.0)
    assert wide.command([-44.0, 0.0]) == (-30.0, 0.1)


def test_clip_command() -> None:
    assert clip_command(31, 5) == (30.0, 4.0)
    assert clip_command(-31, 0) == (-30.0, 0.1)
    assert clip_command(7.5, 2.5) == (7.5, 2.5)


# --- bad files ------------------------------------------------------------------------------------------


def assert_rejected(path: Path, *words: str) -> ActionSpaceError:
    with pytest.raises(ActionSpaceError) as info:
        load_action_space(path)
    message = str(info.value)
    assert str(path) in message
    for word in words:
        assert word in message, message
    return info.value


def test_missing_file(tmp_path: Path) -> None:
    assert_rejected(tmp_path / "nowhere" / "model_metadata.json", "does not exist")


def test_invalid_json(tmp_path: Path) -> None:
    assert_rejected(write(tmp_path, '{"action_space": [}'), "not valid JSON")


def test_not_an_object(tmp_path: Path) -> None:
    assert_rejected(write(tmp_path, '[{"steering_angle": 0, "speed": 1}]'), "JSON object")


def test_empty_action_list(tmp_path: Path) -> None:
    assert_rejected(write(tmp_path, '{"action_space": [], "action_space_type": "discrete"}'), "empty")


def test_type_mismatch_discrete_with_dict(tmp_path: Path) -> None:
    text = CONTINUOUS_METADATA.replace('"continuous"', '"discrete"')
    assert_rejected(write(tmp_path, text), "does not match")


def test_type_mismatch_continuous_with_list(tmp_path: Path) -> None:
    text = DISCRETE_METADATA.replace('"action_space_type": "discrete"', '"action_space_type": "continuous"')
    assert_rejected(write(tmp_path, text), "does not match")


def test_unknown_type(tmp_path: Path) -> None:
    text = DISCRETE_METADATA.replace('"action_space_type": "discrete"', '"action_space_type": "hybrid"')
    assert_rejected(write(tmp_path, text), "action_space_type")


def test_missing_field(tmp_path: Path) -> None:
    assert_rejected(write(tmp_path, '{"action_space": [{"steering_angle": 0.0}]}'), "speed")


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-Infinity"])
def test_non_finite_discrete_value(tmp_path: Path, literal: str) -> None:
    text = DISCRETE_METADATA.replace('"speed": 2.0', f'"speed": {literal}')
    assert_rejected(write(tmp_path, text), "finite")


def test_non_finite_continuous_value(tmp_path: Path) -> None:
    text = CONTINUOUS_METADATA.replace('"high": 4.0', '"high": Infinity')
    assert_rejected(write(tmp_path, text), "finite")


def test_nan_continuous_value_rejected(tmp_path: Path) -> None:
    assert_rejected(write(tmp_path, CONTINUOUS_METADATA.replace('"high": 4.0', '"high": NaN')))


def test_low_above_high_rejected(tmp_path: Path) -> None:
    text = CONTINUOUS_METADATA.replace('"high": 30.0, "low": -30.0', '"high": -30.0, "low": 30.0')
    assert_rejected(write(tmp_path, text))
    with pytest.raises(ValueError, match="above high"):
        Range(low=2.0, high=1.0)


@pytest.mark.parametrize(
    ("old", "new", "word"),
    [('"high": 30.0, "low": -30.0', '"high": -30.0, "low": 30.0', "above high"), ('"high": 4.0', '"high": NaN', "nan")],
    ids=["low_above_high", "nan"],
)
def test_continuous_range_error_names_the_problem(tmp_path: Path, old: str, new: str, word: str) -> None:
    error = assert_rejected(write(tmp_path, CONTINUOUS_METADATA.replace(old, new)))
    message = str(error)
    assert "valid list" not in message and "DiscreteAction" not in message, message
    assert word in message.lower(), message


# --- the env with a continuous space --------------------------------------------------------------------


def test_continuous_env_passes_check_env(continuous_env: RacerEnv) -> None:
    with warnings.catch_warnings():
        # gymnasium's advice on normalized Box ranges and on building through make(): not failures.
        warnings.simplefilter("ignore", UserWarning)
        check_env(continuous_env, skip_render_check=True)


def test_continuous_env_step(continuous_env: RacerEnv) -> None:
    continuous_env.reset(seed=0, options={"start_index": 3, "reverse": False})
    obs, reward, terminated, truncated, info = continuous_env.step(np.array([10.0, 1.5], np.float32))
    assert obs.shape == (120, 160, 1)
    assert info["command"] == (10.0, 1.5)
    assert info["params"]["steering_angle"] == 10.0 and info["params"]["speed"] == 1.5
    assert np.isfinite(reward)
    assert not terminated and not truncated
    # Out-of-range actions are clipped to the space.
    *_, info = continuous_env.step([50.0, 0.2])
    assert info["command"] == (30.0, 1.0)


def test_continuous_env_drives(continuous_env: RacerEnv) -> None:
    continuous_env.reset(seed=0, options={"start_index": 3, "reverse": False})
    start = continuous_env.physics.pose
    for _ in range(15):
        continuous_env.step([0.0, 1.5])
    end = continuous_env.physics.pose
    assert np.hypot(end.x - start.x, end.y - start.y) > 0.5
