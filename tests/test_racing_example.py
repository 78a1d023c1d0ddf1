"""The shipped racing reward example (sim/reward_examples/racing_line.py): DeepRacer's API only, runs on every kind
of track in both directions, and pays for the racing line at its target speed."""

from __future__ import annotations

import ast
import math

import numpy as np
import pytest

from common.config import EnvConfig
from sim.env import RacerEnv, preflight_reward
from sim.reward import example_path, load_reward_function

PATH = example_path("racing_line")


def test_it_imports_nothing_but_math() -> None:
    # It must run unchanged in the DeepRacer console, which documents math, random, numpy, scipy and shapely.
    imports = [n for n in ast.walk(ast.parse(PATH.read_text())) if isinstance(n, ast.Import | ast.ImportFrom)]
    assert [a.name for n in imports for a in n.names] == ["math"]


@pytest.mark.parametrize("track", ["reinvent_base", "Spain_track", "2022_summit_speedway"])
def test_it_runs_300_steps_both_directions(track: str) -> None:
    config = EnvConfig(track=track, reward_fn=str(PATH), camera="ground", randomization={"alternate_direction": True})
    preflight_reward(config)
    env = RacerEnv(config=config)
    env.reset(seed=1)
    rng, directions = np.random.default_rng(0), set()
    for _ in range(300):
        _, reward, terminated, truncated, info = env.step(int(rng.integers(env.actions.n)))
        assert math.isfinite(reward) and 0.0 < reward <= 3.0 + 1e-9
        directions.add(info["params"]["is_reversed"])
        if terminated or truncated:
            env.reset()
    assert directions == {False, True}


def test_it_pays_for_the_line_at_its_speed_more_than_for_the_centre_slowly() -> None:
    env = RacerEnv(track="reinvent_base", reward_fn=str(PATH))
    _, info = env.reset(seed=0, options={"start_index": 30})
    fn = load_reward_function(PATH)
    params = dict(info["params"], steps=40, progress=20.0)
    fn(params)  # builds the line
    line, speeds, _ = next(iter(fn.fn.__globals__["_LINES"].values()))
    i = params["closest_waypoints"][1]
    on_line = dict(params, x=line[i][0], y=line[i][1], speed=speeds[i])
    centre_slow = dict(params, speed=0.5)
    assert fn(on_line) > fn(centre_slow) + 0.2
    assert fn(dict(params, is_offtrack=True)) == pytest.approx(1e-3)
    finished = dict(on_line, progress=100.0)
    assert fn(finished) > fn(on_line) + 1.0  # a completed lap pays a bonus
