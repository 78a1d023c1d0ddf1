"""Object-avoidance and head-to-bot reward functions, run unchanged in racer's object-avoidance and head-to-bot
worlds.

The functions are racer's own files in ``tests/data/reward_patterns/oa`` (its README says which pattern each covers):
they reproduce what public object-avoidance reward functions do with the object params, AWS's documented example
among them. Each is loaded as racer loads a user's file (``sim.reward.load_reward_function`` inside the env, after
the pre-start check ``sim.env.preflight_reward``) and driven 300 random steps in both directions with three randomly
placed boxes, on racer's own track and (with DeepRacer's routes in ``../shared/data/tracks``) on three DeepRacer
tracks; then once with two bot cars. Every reward must be a finite float, and every call must see the objects in its
params (so the functions' object code really runs), crashes included. None of them fails in DeepRacer, so none may
fail here.
"""

from __future__ import annotations

import contextlib
import io
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from common.config import EnvConfig
from common.race import RaceConfig
from sim.env import RacerEnv, preflight_reward
from sim.reward import load_reward_function
from sim.track import DEFAULT_TRACK, load_track
from tests.shared_data import needs_deepracer_tracks

OA_REWARDS = Path(__file__).parent / "data" / "reward_patterns" / "oa"
REWARDS = sorted(p.name for p in OA_REWARDS.glob("*.py"))
DEEPRACER_TRACKS = ("reinvent_base", "2022_summit_speedway", "Spain_track")
TRACKS = [DEFAULT_TRACK] + [pytest.param(t, marks=needs_deepracer_tracks) for t in DEEPRACER_TRACKS]
OBSTACLES = 3
BOTS = 2
BOT_SPEED = 0.5
OA_RACE = RaceConfig(
    race_type="OBJECT_AVOIDANCE",
    object_avoidance={"number_of_obstacles": OBSTACLES, "randomize_obstacle_locations": True},
)
H2B_RACE = RaceConfig(race_type="HEAD_TO_BOT", head_to_bot={"number_of_bot_cars": BOTS, "bot_car_speed": BOT_SPEED})
OBJECT_LISTS = (
    "objects_location",
    "objects_distance",
    "objects_distance_from_center",
    "objects_left_of_center",
    "objects_heading",
    "objects_speed",
)


def test_there_are_object_avoidance_functions_to_run() -> None:
    assert len(REWARDS) >= 4
    for name in REWARDS:
        text = (OA_REWARDS / name).read_text()
        assert "closest_objects" in text and "objects_location" in text, name


def drive(reward: str, track: str, race: RaceConfig, steps: int = 300) -> tuple[list[dict], set[bool], Counter]:
    """The pre-start check, then ``steps`` random steps alternating direction. Returns what the function saw at each
    call (a summary of its params and the reward it returned), the directions driven and how episodes ended."""
    config = EnvConfig(
        track=track,
        reward_fn=str(OA_REWARDS / reward),
        camera="ground",
        randomization={"alternate_direction": True},
        race=race,
    )
    preflight_reward(config)
    env = RacerEnv(config=config)
    seen: list[dict] = []
    user_fn = env.reward_fn.fn

    def watched(params: dict) -> object:
        # The function's own copy of the params, summarised before it runs (it may change its copy).
        summary = {key: len(params[key]) for key in OBJECT_LISTS}
        summary.update(
            closest=list(params["closest_objects"]),
            speeds=list(params["objects_speed"]),
            crashed=params["is_crashed"],
        )
        seen.append(summary)
        return user_fn(params)

    env.reward_fn.fn = watched
    env.reset(seed=1)
    rng, directions, endings = np.random.default_rng(0), set(), Counter()
    for step in range(steps):
        _, reward, terminated, truncated, info = env.step(int(rng.integers(env.actions.n)))
        assert type(reward) is float and math.isfinite(reward), (reward, step)
        seen[-1]["reward"] = reward
        seen[-1]["status"] = info["episode_status"]
        directions.add(info["params"]["is_reversed"])
        if terminated or truncated:
            endings[info["episode_status"]] += 1
            env.reset()
    env.close()
    assert len(seen) == steps  # one call per step, nothing skipped
    return seen, directions, endings


def check_objects_seen(seen: list[dict], count: int) -> None:
    for call in seen:
        for key in OBJECT_LISTS:
            assert call[key] == count, (key, call)
        assert len(call["closest"]) == 2 and all(0 <= int(i) < count for i in call["closest"]), call
        # A crash ends the episode; the function is told at that step.
        assert call["crashed"] == (call["status"] == "crashed"), call


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize("track", TRACKS)
@pytest.mark.parametrize("reward", REWARDS)
def test_oa_functions_run_unchanged_with_boxes(reward: str, track: str, capsys) -> None:
    seen, directions, endings = drive(reward, track, OA_RACE)
    assert directions == {False, True}
    check_objects_seen(seen, OBSTACLES)
    assert all(speed == 0.0 for call in seen for speed in call["speeds"])  # boxes stand still
    if track == DEFAULT_TRACK:
        # Random driving runs into a box there (every file gets the same actions): the functions see is_crashed
        # True, as in DeepRacer.
        assert endings["crashed"] >= 1
    capsys.readouterr()  # the framework pattern prints, as such functions do in DeepRacer's logs


@pytest.mark.parametrize("reward", REWARDS)
def test_oa_functions_run_unchanged_with_bot_cars(reward: str, capsys) -> None:
    seen, directions, _ = drive(reward, DEFAULT_TRACK, H2B_RACE)
    assert directions == {False, True}
    check_objects_seen(seen, BOTS)
    assert all(speed == BOT_SPEED for call in seen for speed in call["speeds"])
    capsys.readouterr()


@pytest.mark.parametrize("track", TRACKS)
@pytest.mark.parametrize("lane", [1, -1])
@pytest.mark.parametrize("reverse", [False, True])
def test_the_lane_function_finds_a_training_start_beside_a_box_in_the_free_lane(
    track: str, lane: int, reverse: bool
) -> None:
    """A training episode that starts within 1 m of a box starts in the other lane (as in the simapp). The lane
    function decides "same lane" from objects_left_of_center and is_left_of_center, as AWS's documented example does,
    and measures the straight-line distance. The box is 0.6 m ahead, inside its 0.9 m threshold. So it pays the full
    1 + 3 (+ 0.002) only if racer's two params agree that the car is in the other lane; the same lane would pay
    1 + 3 * 0.4."""
    length = load_track(track).length
    race = RaceConfig(
        race_type="OBJECT_AVOIDANCE", object_avoidance={"object_positions": [{"progress": 0.6 / length, "lane": lane}]}
    )
    path = OA_REWARDS / "oa_lane_distance.py"
    env = RacerEnv(track=track, reward_fn=str(path), camera="ground", race=race, randomization={"random_start": False})
    _, info = env.reset(seed=0, options={"reverse": reverse})
    params = info["params"]
    assert params["is_left_of_center"] != params["objects_left_of_center"][0]
    box = params["objects_location"][0]
    assert 0.5 < math.hypot(params["x"] - box[0], params["y"] - box[1]) < 0.9
    straight = next(i for i, a in enumerate(env.actions.action_space) if a.steering_angle == 0)
    _, reward, terminated, _, info = env.step(straight)
    assert not terminated and reward == pytest.approx(4.002)
    same_lane = dict(info["params"], is_left_of_center=info["params"]["objects_left_of_center"][0])
    assert load_reward_function(path)(same_lane) == pytest.approx(2.202)
    env.close()


def test_the_framework_prints_the_objects_at_step_2_as_log_tools_expect() -> None:
    """The framework pattern prints ``DRG-OBJECTS: [[x, y], ...]`` at step 2 for log tools: racer's
    objects_location is a list of [x, y] lists, so the line reads as DeepRacer's."""
    config = EnvConfig(
        track=DEFAULT_TRACK,
        reward_fn=str(OA_REWARDS / "oa_framework_objects.py"),
        camera="ground",
        race=OA_RACE,
    )
    env = RacerEnv(config=config)
    env.reset(seed=0)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        _, _, _, _, info = env.step(0)
        assert info["params"]["steps"] == 2
        _, _, _, _, after = env.step(0)
    lines = [line for line in out.getvalue().splitlines() if line.startswith("DRG-OBJECTS:")]
    assert lines == [f"DRG-OBJECTS: {info['params']['objects_location']}"]
    assert lines[0].startswith("DRG-OBJECTS: [[")
    tracker = env.reward_fn.fn.__globals__["tracker"]
    assert tracker.steps == 3 and tracker.front == int(after["params"]["closest_objects"][1])
    env.close()
