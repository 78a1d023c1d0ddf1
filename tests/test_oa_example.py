"""The shipped object-avoidance reward example (sim/reward_examples/object_avoidance.py): DeepRacer's API only, runs
with boxes on every kind of track in both directions, pays for the free lane near an object, 1e-3 for a crash, and
more for a faster lap."""

from __future__ import annotations

import ast
import math

import numpy as np
import pytest

from common.config import EnvConfig
from common.defaults import DEFAULT_TRACK
from common.race import RaceConfig
from sim.env import RacerEnv, preflight_reward
from sim.reward import example_path, load_reward_function
from sim.track import load_track

PATH = example_path("object_avoidance")
TRACKS = (DEFAULT_TRACK, "racer_wide", "racer_loop_cw")
"""Every kind of track: a loop of reinvent_base's size, a wide one (1.07 m, as the 2022 tracks), a clockwise one."""
BOXES = RaceConfig(
    race_type="OBJECT_AVOIDANCE", object_avoidance={"number_of_obstacles": 3, "randomize_obstacle_locations": True}
)


def one_box(track: str, metres_ahead: float, lane: int) -> RaceConfig:
    """One box ``metres_ahead`` of the first start waypoint along the centre line, in lane 1 (inner) or -1 (outer)."""
    fraction = metres_ahead / load_track(track).length
    return RaceConfig(
        race_type="OBJECT_AVOIDANCE", object_avoidance={"object_positions": [{"progress": fraction, "lane": lane}]}
    )


def test_it_imports_nothing_but_math() -> None:
    # It must run unchanged in the DeepRacer console, which documents math, random, numpy, scipy and shapely.
    source = PATH.read_text()
    imports = [n for n in ast.walk(ast.parse(source)) if isinstance(n, ast.Import | ast.ImportFrom)]
    assert [type(n) for n in imports] == [ast.Import]
    assert [a.name for n in imports for a in n.names] == ["math"]
    assert source.startswith("# ruff: noqa\n# fmt: off\n")


@pytest.mark.parametrize("track", TRACKS)
def test_it_runs_300_steps_both_directions_with_boxes(track: str) -> None:
    config = EnvConfig(
        track=track, reward_fn=str(PATH), camera="ground", race=BOXES, randomization={"alternate_direction": True}
    )
    preflight_reward(config)
    env = RacerEnv(config=config)
    env.reset(seed=1)
    rng, directions, boxes_seen = np.random.default_rng(0), set(), 0
    for _ in range(300):
        _, reward, terminated, truncated, info = env.step(int(rng.integers(env.actions.n)))
        params = info["params"]
        assert type(reward) is float and math.isfinite(reward)
        if params["progress"] < 100:
            assert 1e-3 <= reward <= 2.0 + 1e-9  # the pace weight is capped at 2, the other terms at 1
        if params["is_crashed"] or params["is_offtrack"]:
            assert reward == 1e-3
        directions.add(params["is_reversed"])
        boxes_seen += len(params["objects_location"]) == 3
        if terminated or truncated:
            env.reset()
    assert directions == {False, True} and boxes_seen == 300
    env.close()


@pytest.mark.parametrize("track", TRACKS)
@pytest.mark.parametrize("lane", [1, -1])
@pytest.mark.parametrize("reverse", [False, True])
def test_it_pays_more_in_the_free_lane_than_in_the_lane_of_the_box_ahead(track: str, lane: int, reverse: bool) -> None:
    # A training start within 1 m of a box puts the car in the other lane (as the simapp does): one step on,
    # the real params have the box 0.3-0.5 m ahead and the car in the free lane.
    env = RacerEnv(track=track, camera="ground", race=one_box(track, 0.8, lane), randomization={"random_start": False})
    env.reset(seed=0, options={"reverse": reverse})
    straight = next(i for i, a in enumerate(env.actions.action_space) if a.steering_angle == 0)
    _, _, terminated, _, info = env.step(straight)
    env.close()
    assert not terminated
    params = info["params"]
    fn = load_reward_function(PATH)
    ahead = params["closest_objects"][1]
    box_left = params["objects_left_of_center"][ahead]
    assert params["is_left_of_center"] != box_left
    gap = params["objects_distance"][ahead] - params["projection_distance"]
    assert 0.2 < gap < 0.7, gap

    free = fn(params)
    # The same car on the other side of the centre line, as deep in the box's lane.
    in_its_lane = fn(dict(params, is_left_of_center=box_left))
    assert free > 2 * in_its_lane
    # The same car nearer the centre line, still in the free lane, earns less than deep in it.
    assert fn(dict(params, distance_from_center=0.02)) < free

    # In the box's lane, the closer the box the less it pays; out of reach, the lane does not matter.
    def with_gap(metres: float, left: bool) -> float:
        distances = list(params["objects_distance"])
        distances[ahead] = params["projection_distance"] + metres
        return fn(dict(params, is_left_of_center=left, objects_distance=distances))

    same_lane = [with_gap(g, box_left) for g in (1.4, 1.0, 0.6, 0.2)]
    assert all(a > b for a, b in zip(same_lane, same_lane[1:], strict=False)), same_lane
    assert with_gap(2.0, box_left) == pytest.approx(with_gap(2.0, not box_left))
    assert with_gap(2.0, box_left) >= free


def test_it_pays_more_in_the_free_lane_while_passing_a_box() -> None:
    """A box just passed (closest_objects[0], a few centimetres behind the car's front) is still beside the car."""
    env = RacerEnv(track=DEFAULT_TRACK, camera="ground", race=one_box(DEFAULT_TRACK, 0.8, 1))
    _, info = env.reset(seed=0, options={"start_index": 0})
    env.close()
    params = info["params"]
    fn = load_reward_function(PATH)
    distances = [params["projection_distance"] - 0.1]
    box_left = params["objects_left_of_center"][0]
    beside = dict(params, objects_distance=distances, distance_from_center=0.25 * params["track_width"], steps=10)
    assert fn(dict(beside, is_left_of_center=not box_left)) > 2 * fn(dict(beside, is_left_of_center=box_left))


@pytest.mark.parametrize("track", TRACKS)
@pytest.mark.parametrize("lane", [1, -1])
def test_it_pays_1e_3_when_crashed(track: str, lane: int) -> None:
    # A pinned start is on the centre line regardless of the box, which then sits across the car's path.
    env = RacerEnv(track=track, reward_fn=str(PATH), camera="ground", race=one_box(track, 1.0, lane))
    env.reset(seed=0, options={"start_index": 0})
    straight = next(i for i, a in enumerate(env.actions.action_space) if a.steering_angle == 0)
    for _ in range(60):
        _, reward, terminated, truncated, info = env.step(straight)
        if terminated or truncated:
            break
    env.close()
    assert info["episode_status"] == "crashed" and info["params"]["is_crashed"]
    assert reward == 1e-3


def _lap_return(fn, params: dict, steps: int) -> float:
    """What a whole lap along the centre line (past the boxes, in whichever lane), taking ``steps`` steps, earns."""
    waypoints = params["waypoints"]
    n = len(waypoints) - 1
    total = 0.0
    for step in range(1, steps + 1):
        i = min(int(n * step / steps), n - 1)
        at = dict(x=waypoints[i][0], y=waypoints[i][1], closest_waypoints=[i, i + 1])
        total += fn(dict(params, **at, steps=step, progress=100.0 * step / steps))
    return total


def test_a_faster_lap_earns_more_than_a_slower_one() -> None:
    # The bug this guards against: a per-step reward not weighted by pace pays a slow lap more (it has more
    # steps), and the learner drifts to slower laps (docs/racing.md, the 2026-11-25 bench).
    env = RacerEnv(track=DEFAULT_TRACK, camera="ground", race=BOXES)
    _, info = env.reset(seed=0, options={"start_index": 0})
    env.close()
    params = dict(info["params"], distance_from_center=0.0, all_wheels_on_track=True)
    assert len(params["objects_location"]) == 3
    fn = load_reward_function(PATH)
    ideal = params["track_length"] / fn.fn.__globals__["TARGET_SPEED"] * 15
    returns = [_lap_return(fn, params, int(ideal * k)) for k in (1.1, 1.3, 1.6, 2.0)]
    assert all(a > b for a, b in zip(returns, returns[1:], strict=False)), returns
    assert returns[0] > 1.2 * returns[-1], returns
