"""racer bench oa: its figures from evaluation records and curves, computed by hand; its race and files."""

from __future__ import annotations

import json

import pytest

from common.action_space import load_action_space
from common.config import EnvConfig
from common.race import RaceType
from racer.bench.oa import (
    BOT_SPEED,
    BenchOASettings,
    _files,
    checkpoint_point,
    oa_race,
    plot_oa,
    seed_figures,
    summarize,
)


def point(version: int, completion: float, crash_rate: float = 0.0, trials: int = 10) -> dict:
    return {
        "version": version,
        "time_s": 60.0 * version,
        "env_steps": 1000 * version,
        "trials": trials,
        "completion": completion,
        "crash_rate": crash_rate,
        "off_track_rate": 0.0,
        "mean_progress": 100.0 * completion,
    }


def test_a_point_counts_crashed_and_off_track_trials():
    statuses = ["crashed"] * 3 + ["off_track"] * 2 + ["lap_complete"] * 4 + ["time_up"]
    record = {
        "version": 7,
        "completion_rate": 0.4,
        "mean_progress": 61.5,
        "episodes": 10,
        "trials": [{"status": s} for s in statuses],
    }
    p = checkpoint_point(record, 123.456, 9000)
    assert p == {
        "version": 7,
        "time_s": 123.5,
        "env_steps": 9000,
        "trials": 10,
        "completion": 0.4,
        "crash_rate": 0.3,
        "off_track_rate": 0.2,
        "mean_progress": 61.5,
    }


def test_figures_of_a_run_that_becomes_robust_then_crashes_again():
    curve = [
        point(1, 0.0, 0.9),
        point(2, 0.6, 0.3),
        point(3, 1.0, 0.0),  # first robust
        point(4, 0.8, 0.2),
        point(5, 1.0, 0.0),
        point(6, 0.9, 0.1),  # the last one
    ]
    figures = seed_figures(curve)
    assert figures["time_to_robust_s"] == 180.0 and figures["env_steps_to_robust"] == 3000
    assert figures["final_completion"] == 0.9 and figures["final_crash_rate"] == 0.1
    assert figures["best_completion"] == 1.0 and figures["checkpoints"] == 6


def test_all_trials_completed_counts_only_with_enough_trials():
    curve = [point(1, 1.0, trials=3), point(2, 1.0, trials=9), point(3, 1.0, trials=10)]
    assert seed_figures(curve)["time_to_robust_s"] == 180.0
    assert seed_figures(curve, min_trials=3)["time_to_robust_s"] == 60.0


def test_figures_of_a_run_that_never_completes_and_of_no_evaluation():
    figures = seed_figures([point(1, 0.0, 1.0), point(2, 0.5, 0.5)])
    assert figures["time_to_robust_s"] is None and figures["env_steps_to_robust"] is None
    assert figures["final_completion"] == 0.5 and figures["final_crash_rate"] == 0.5
    empty = seed_figures([])
    assert empty["time_to_robust_s"] is None and empty["final_completion"] == 0.0 and empty["final_crash_rate"] is None


def test_medians_over_seeds_skip_the_seeds_that_never_got_there(tmp_path):
    seeds = []
    for seed, curve in enumerate(
        [
            [point(1, 0.5, 0.5), point(2, 1.0, 0.0)],
            [point(1, 0.2, 0.8), point(4, 1.0, 0.0), point(5, 0.9, 0.1)],
            [point(1, 0.0, 1.0), point(2, 0.3, 0.6)],
        ]
    ):
        seeds.append({**seed_figures(curve), "seed": seed, "rollbacks": 0, "curve": curve})
    result = summarize(BenchOASettings(seeds=[0, 1, 2], minutes=5), seeds)
    assert result["time_to_robust_s"] == pytest.approx(180.0)  # median of 120 and 240
    assert result["robust_seeds"] == 2
    assert result["final_completion"] == 0.9 and result["final_crash_rate"] == pytest.approx(0.1)
    assert result["race_type"] == "OBJECT_AVOIDANCE" and result["sensor"] == ["STEREO_CAMERAS"]
    json.dumps(result, allow_nan=False)  # the --json output
    png = plot_oa(result, tmp_path / "oa.png")
    assert png.exists() and png.stat().st_size > 10_000


def test_the_races_and_the_action_space(tmp_path):
    oa = oa_race("OBJECT_AVOIDANCE")
    assert oa.obstacle_count == 3 and oa.object_avoidance.randomize_obstacle_locations and oa.bot_car_count == 0
    h2b = oa_race("head_to_bot")
    assert h2b.race_type is RaceType.HEAD_TO_BOT and h2b.bot_car_count == 2 and h2b.obstacle_count == 0
    assert h2b.head_to_bot.bot_car_speed == BOT_SPEED == 0.5
    with pytest.raises(ValueError):
        oa_race("TIME_TRIAL")
    space, hp = _files(tmp_path)
    actions = load_action_space(space)
    assert actions.sensor == ["STEREO_CAMERAS"] and actions.n == 10
    assert {a.speed for a in actions.action_space} == {1.0, 2.0}
    assert json.loads(hp.read_text())["collapse_guard"] is True


def test_each_evaluation_trial_gets_its_own_box_placement_and_each_checkpoint_the_same_ones():
    """The evaluator builds every trial's env from the run's config (race included) and resets it with the trial's
    seed (trainer/evaluator.py: evaluate): the boxes move from trial to trial, not from checkpoint to checkpoint."""
    from sim.env import RacerEnv

    env = RacerEnv(config=EnvConfig(race=oa_race("OBJECT_AVOIDANCE")))
    try:
        placements = []
        for seed in (12345, 13345, 12345):  # trials 0 and 1 of one evaluation, then trial 0 of the next
            env.reset(seed=seed, options={"start_index": 0, "reverse": False})
            placements.append([(round(o.x, 6), round(o.y, 6)) for o in env.objects])
        assert len(placements[0]) == 3
        assert placements[0] != placements[1] and placements[0] == placements[2]
    finally:
        env.close()
