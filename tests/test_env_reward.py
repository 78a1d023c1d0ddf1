"""The env runs users' DeepRacer reward functions unchanged, and stops clearly when one is broken."""

import math
import textwrap

import pytest

from common.config import EnvConfig
from common.defaults import DEFAULT_TRACK
from sim.env import RacerEnv, preflight_reward
from sim.reward import RewardFunctionError, example_path


def write(tmp_path, name, body):
    path = tmp_path / name
    path.write_text(textwrap.dedent(body))
    return path


@pytest.mark.parametrize("example", ["follow_center_line", "stay_inside_two_borders", "prevent_zig_zag"])
def test_examples_run_in_env_and_match_params(example):
    env = RacerEnv(track=DEFAULT_TRACK, reward_fn=str(example_path(example)))
    env.reset(seed=3)
    for _ in range(5):
        _, reward, term, _, info = env.step(5)  # (0°, 1 m/s): straight ahead
        p = info["params"]
        assert info["reward_terms"]["reward_function"] == reward
        if example == "follow_center_line":
            w, d = p["track_width"], p["distance_from_center"]
            expected = 1.0 if d <= 0.1 * w else 0.5 if d <= 0.25 * w else 0.1 if d <= 0.5 * w else 1e-3
            assert reward == pytest.approx(expected)
        if term:
            break


def test_user_reward_sees_every_key_and_its_values(tmp_path):
    path = write(
        tmp_path,
        "reward.py",
        """
        import math
        def reward_function(params):
            assert params["steps"] >= 1 and isinstance(params["waypoints"], list)
            return float(params["speed"]) + params["steering_angle"] / 100.0
        """,
    )
    env = RacerEnv(track=DEFAULT_TRACK, reward_fn=str(path))
    env.reset(seed=0)
    command = env.actions.command(7)
    _, reward, *_ = env.step(7)
    assert reward == pytest.approx(command[1] + command[0] / 100.0)


def test_raising_reward_function_names_file_and_step(tmp_path):
    path = write(
        tmp_path,
        "bad_reward.py",
        """
        def reward_function(params):
            if params["steps"] == 3:
                raise KeyError("no_such_key")
            return 1.0
        """,
    )
    env = RacerEnv(track=DEFAULT_TRACK, reward_fn=str(path), randomization={"random_start": False})
    env.reset(seed=0)
    env.step(5)  # DeepRacer's steps 2: step 1 is the prepare step
    with pytest.raises(RewardFunctionError, match=r"bad_reward\.py.*step 3.*KeyError"):
        env.step(5)


@pytest.mark.parametrize(
    "body, match",
    [
        ("def reward_function(params)\n    return 1.0\n", "syntax"),
        ("def reward(params):\n    return 1.0\n", "reward_function"),
        ("def reward_function(params):\n    return float('nan')\n", "nan|finite"),
        ("def reward_function(params):\n    return 'high'\n", "str|number"),
    ],
)
def test_broken_reward_file_fails_before_the_first_episode(tmp_path, body, match):
    path = write(tmp_path, "r.py", body)
    with pytest.raises(RewardFunctionError, match=f"(?i)r\\.py.*({match})"):
        preflight_reward(EnvConfig(track=DEFAULT_TRACK, reward_fn=str(path)))


def test_missing_reward_file_is_refused():
    with pytest.raises(RewardFunctionError, match="nope_reward.py"):
        RacerEnv(track=DEFAULT_TRACK, reward_fn="/nonexistent/nope_reward.py")


def test_reward_is_finite_over_an_episode():
    env = RacerEnv(track="racer_loop_cw")
    env.reset(seed=1)
    done = False
    while not done:
        _, reward, term, trunc, _ = env.step(env.action_space.sample())
        assert math.isfinite(reward)
        done = term or trunc
