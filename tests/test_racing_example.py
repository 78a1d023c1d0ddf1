"""The shipped racing reward example (sim/reward_examples/racing_line.py): DeepRacer's API only, runs on every kind
of track in both directions, and pays for the racing line at its target speed."""

from __future__ import annotations

import ast
import math

import numpy as np
import pytest

from common.config import EnvConfig
from common.defaults import DEFAULT_TRACK
from sim.env import RacerEnv, preflight_reward
from sim.reward import example_path, load_reward_function
from tests.shared_data import needs_deepracer_tracks

PATH = example_path("racing_line")


def test_it_imports_nothing_but_math() -> None:
    # It must run unchanged in the DeepRacer console, which documents math, random, numpy, scipy and shapely.
    imports = [n for n in ast.walk(ast.parse(PATH.read_text())) if isinstance(n, ast.Import | ast.ImportFrom)]
    assert [a.name for n in imports for a in n.names] == ["math"]


@pytest.mark.parametrize(
    "track",
    [
        DEFAULT_TRACK,  # a counter-clockwise loop
        "racer_loop_cw",  # a clockwise one
        "racer_wide",  # the 2019-2022 tracks' 1.07 m width
        # A route from DeepRacer's own files, as the console runs the example on: Spain_track's waypoints are spaced
        # unevenly (0.11-0.32 m), which racer's generated tracks are not.
        pytest.param("Spain_track", marks=needs_deepracer_tracks),
    ],
)
def test_it_runs_300_steps_both_directions(track: str) -> None:
    config = EnvConfig(track=track, reward_fn=str(PATH), camera="ground", randomization={"alternate_direction": True})
    preflight_reward(config)
    env = RacerEnv(config=config)
    env.reset(seed=1)
    rng, directions = np.random.default_rng(0), set()
    for _ in range(300):
        _, reward, terminated, truncated, info = env.step(int(rng.integers(env.actions.n)))
        assert math.isfinite(reward) and 0.0 < reward <= 2.0 + 1e-9
        directions.add(info["params"]["is_reversed"])
        if terminated or truncated:
            env.reset()
    assert directions == {False, True}


def test_it_pays_for_the_line_at_its_speed_more_than_for_the_centre_slowly() -> None:
    env = RacerEnv(track=DEFAULT_TRACK, reward_fn=str(PATH))
    _, info = env.reset(seed=0, options={"start_index": 30})
    fn = load_reward_function(PATH)
    params = dict(info["params"], steps=40, progress=20.0)
    fn(params)  # builds the line
    line, speeds, _ = next(iter(fn.fn.__globals__["_LINES"].values()))
    i = params["closest_waypoints"][1]
    on_line = dict(params, x=line[i][0], y=line[i][1], speed=speeds[i])
    centre_slow = dict(params, speed=0.5)
    # Both are paid the same pace (20 % in 40 steps against the line's ideal lap), times the mean of the line and
    # speed terms: 1 on the line at its speed. Waypoint 30 is in the loop's right-hand bend, where the line runs at
    # its margin, 0.38 - 0.1 = 0.28 m inside the centre: the centre's line term is 1 - 0.28 / 0.38 = 0.26, and
    # 0.5 m/s, about 1 m/s under the bend's target, scores 1 - 1 / 4 = 0.75: about half the line's pay.
    assert fn(on_line) > 1.8 * fn(centre_slow)
    assert fn(dict(params, is_offtrack=True)) == pytest.approx(1e-3)
    finished = dict(on_line, progress=100.0)
    assert fn(finished) > fn(on_line) + 1.0  # a completed lap pays a bonus


def _lap_partials(fn, params: dict, line: list, speeds: list, steps: int) -> list[float]:
    """What a lap on the line at its target speeds, taking ``steps`` steps, has earned after each step
    (undiscounted; the last is the whole lap's return)."""
    total, partial, n = 0.0, [], len(line)
    for step in range(1, steps + 1):
        i = min(int(n * step / steps), n - 1)
        at = dict(x=line[i][0], y=line[i][1], speed=speeds[i], closest_waypoints=[i, (i + 1) % n])
        total += fn(dict(params, **at, steps=step, progress=100.0 * step / steps))
        partial.append(total)
    return partial


def _lap_return(fn, params: dict, line: list, speeds: list, steps: int) -> float:
    """What a whole lap on the line at its target speeds, taking ``steps`` steps, earns (undiscounted)."""
    return _lap_partials(fn, params, line, speeds, steps)[-1]


def test_a_faster_lap_earns_more_than_a_slower_one() -> None:
    # The bug this guards against: a per-step reward not weighted by pace pays a slow lap more (it has more
    # steps), and the learner drifts to slower laps (docs/racing.md, the 2026-11-25 bench).
    env = RacerEnv(track=DEFAULT_TRACK, reward_fn=str(PATH))
    _, info = env.reset(seed=0, options={"start_index": 0})
    fn = load_reward_function(PATH)
    fn(info["params"])
    line, speeds, ideal = next(iter(fn.fn.__globals__["_LINES"].values()))
    returns = [_lap_return(fn, info["params"], line, speeds, int(ideal * k)) for k in (1.1, 1.3, 1.6, 2.0)]
    assert all(a > b for a, b in zip(returns, returns[1:], strict=False)), returns
    assert returns[0] > 1.2 * returns[-1], returns


def _lap_and_failure(fn, params: dict, line: list, speeds: list, steps: int) -> tuple[float, float]:
    """A lap's return and the mean return of the same lap lost at a uniformly random step."""
    partial = _lap_partials(fn, params, line, speeds, steps)
    return partial[-1], sum(partial[:-1]) / (steps - 1)


def test_lap_bonus_pays_every_completed_lap_and_lowers_the_risk_a_faster_lap_is_worth(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The failure rate at which a lap 10 % faster than 1.3 x the line's steps earns as much as the slower lap
    # (the header's figures): 10 % with LAP_BONUS 0, about half of that with 1.0. A faster lap still earns more.
    env = RacerEnv(track=DEFAULT_TRACK, reward_fn=str(PATH))
    _, info = env.reset(seed=0, options={"start_index": 0})
    fn = load_reward_function(PATH)
    fn(info["params"])
    line, speeds, ideal = next(iter(fn.fn.__globals__["_LINES"].values()))
    assert fn.fn.__globals__["LAP_BONUS"] == 0.0  # shipped: the pace-only bonus the measured runs used
    slow, fast = int(ideal * 1.3), int(ideal * 1.3 / 1.1)
    i = len(line) // 2
    done = dict(info["params"], x=line[i][0], y=line[i][1], speed=speeds[i], steps=slow, progress=100.0)
    pace_only = fn(done)
    breakeven = {}
    for bonus in (0.0, 1.0):
        monkeypatch.setitem(fn.fn.__globals__, "LAP_BONUS", bonus)
        assert fn(done) - pace_only == pytest.approx(bonus * ideal)  # the same for every completed lap
        (slow_lap, _), (fast_lap, fast_lost) = (
            _lap_and_failure(fn, info["params"], line, speeds, k) for k in (slow, fast)
        )
        assert fast_lap > slow_lap
        breakeven[bonus] = (fast_lap - slow_lap) / (fast_lap - fast_lost)
    assert breakeven[0.0] == pytest.approx(0.10, abs=0.01)
    assert breakeven[1.0] == pytest.approx(0.055, abs=0.01)
