"""racer bench race: its figures from an evaluation curve, computed by hand."""

from __future__ import annotations

import json
import statistics
from pathlib import Path
from types import SimpleNamespace

import pytest

from model_store import LocalStore, RunStore
from model_store.runs import METRICS_FILE, evaluation_name
from racer.bench.race import race_curve, seed_figures


def point(version: int, completion: float, mean_lap: float | None = None) -> dict:
    return {
        "version": version,
        "time_s": 60.0 * version,
        "env_steps": 1000 * version,
        "completion": completion,
        "mean_lap_s": mean_lap,
        "best_lap_s": mean_lap,
    }


def test_figures_of_a_run_that_collapses_twice_and_recovers_once() -> None:
    curve = [
        point(1, 0.2),
        point(2, 1.0, 9.0),  # first robust
        point(3, 1.0, 7.5),  # best robust
        point(4, 0.3),  # collapse 1 starts
        point(5, 0.0),  # still collapse 1
        point(6, 1.0, 8.0),  # recovered
        point(7, 0.4),  # collapse 2, never recovered
    ]
    figures = seed_figures(curve, limit_s=6.0)
    assert figures["time_to_robust_s"] == 120.0 and figures["env_steps_to_robust"] == 2000
    assert figures["best_robust_lap_s"] == 7.5
    assert figures["ratio_to_limit"] == pytest.approx(1.25)
    assert figures["collapses"] == 2 and figures["collapses_recovered"] == 1
    assert figures["final_completion"] == 0.4


def test_figures_of_a_run_that_never_laps() -> None:
    figures = seed_figures([point(1, 0.0), point(2, 0.5)], limit_s=6.0)
    assert figures["time_to_robust_s"] is None and figures["best_robust_lap_s"] is None
    assert figures["ratio_to_limit"] is None and figures["collapses"] == 0
    assert figures["final_completion"] == 0.5


def test_a_dip_that_stays_above_half_is_not_a_collapse() -> None:
    figures = seed_figures([point(1, 1.0, 8.0), point(2, 0.6), point(3, 1.0, 7.0)], limit_s=6.0)
    assert figures["collapses"] == 0 and figures["best_robust_lap_s"] == 7.0


def _reward_module(path: Path) -> SimpleNamespace:
    """The reward file at ``path``, loaded as the worker loads a user's reward function
    (``sim.reward.load_reward_function``), with its module's names as attributes."""
    from sim.reward import load_reward_function

    return SimpleNamespace(**load_reward_function(path).fn.__globals__)


def test_the_reward_examples_constants_are_set_to_the_car(tmp_path) -> None:  # noqa: ANN001
    """80 % of the median lateral acceleration from 2 m/s and of the median braking from 1 m/s, written into a copy
    of the example that still runs as a reward function."""
    from racer.bench.race import reward_constants, reward_file

    limits = {
        "speeds": [0.5, 1.0, 2.0, 3.0, 4.0],
        "max_lateral_accel": [9.0, 9.0, 3.0, 4.0, 5.0],  # median from 2 m/s: 4.0
        "brake": [1.0, 4.0, 5.0, 6.0, 7.0],  # median from 1 m/s: 5.5
    }
    constants = reward_constants(limits)
    assert constants == {"MAX_SPEED": 4.0, "LATERAL_ACCEL": 3.2, "BRAKE": 4.4}
    module = _reward_module(reward_file(tmp_path, constants))
    assert (module.MAX_SPEED, module.LATERAL_ACCEL, module.BRAKE) == (4.0, 3.2, 4.4)
    assert callable(module.reward_function)


def test_the_bench_turns_racers_stability_knobs_on_and_keeps_deepracers_rates(tmp_path) -> None:  # noqa: ANN001
    """bench race's hyperparameters file loads as racer train reads it: the collapse guard from a nearly robust best
    and target-KL early stopping on, with the guard's pace rule; learning rate and entropy constant, as in DeepRacer;
    bench oa the same without the pace rule."""
    from common.hyperparams import Hyperparameters, load_hyperparameters
    from racer.bench.oa import OA_HYPERPARAMS
    from racer.bench.race import GUARD_HYPERPARAMS, _files

    _, path = _files(tmp_path)
    hp = load_hyperparameters(path)
    assert hp.collapse_guard and hp.collapse_min_best == 0.9 and hp.target_kl == 0.05
    assert hp.collapse_slowdown == 0.15  # the guard's pace rule: on in bench race
    defaults = Hyperparameters()
    assert (hp.lr_schedule, hp.entropy_schedule, hp.lr, hp.beta_entropy) == (
        "constant",
        "constant",
        defaults.lr,
        defaults.beta_entropy,
    )
    assert OA_HYPERPARAMS == GUARD_HYPERPARAMS and "collapse_slowdown" not in OA_HYPERPARAMS


def test_a_users_hyperparameters_are_laid_over_the_benchs(tmp_path) -> None:  # noqa: ANN001
    """``--hyperparams F``: the user's keys win, the bench's others stay, and the seeds train with the merge."""
    from common.hyperparams import load_hyperparameters
    from racer.bench.race import RACE_HYPERPARAMS, BenchRaceSettings, _files

    settings = BenchRaceSettings(hyperparams={"stack_size": 3, "target_kl": 0.02})
    merged = settings.race_hyperparams()
    assert merged == {**RACE_HYPERPARAMS, "stack_size": 3, "target_kl": 0.02}
    _, path = _files(tmp_path, merged)
    hp = load_hyperparameters(path)
    assert hp.stack_size == 3 and hp.target_kl == 0.02 and hp.collapse_guard
    assert BenchRaceSettings().race_hyperparams() == RACE_HYPERPARAMS


def test_a_continuous_space_is_judged_on_its_expected_action_unless_the_user_says_otherwise(tmp_path) -> None:  # noqa: ANN001
    """A continuous space adds ``greedy_action`` ``expected`` (a discrete one would refuse it); the user's file wins."""
    from common.hyperparams import load_hyperparameters
    from racer.bench.race import RACE_HYPERPARAMS, BenchRaceSettings, _files

    ranges = {"steering_angle": {"low": -25.0, "high": 25.0}, "speed": {"low": 1.5, "high": 4.0}}
    merged = BenchRaceSettings(actions=ranges).race_hyperparams()
    assert merged == {**RACE_HYPERPARAMS, "greedy_action": "expected"}
    assert load_hyperparameters(_files(tmp_path, merged)[1]).greedy_action == "expected"
    mean = BenchRaceSettings(actions=ranges, hyperparams={"greedy_action": "mean"}).race_hyperparams()
    assert mean["greedy_action"] == "mean"
    assert "greedy_action" not in BenchRaceSettings().race_hyperparams()


def test_a_user_can_turn_the_benchs_collapse_guard_off(tmp_path) -> None:  # noqa: ANN001
    """``{"collapse_guard": false}`` (DeepRacer's behaviour) drops the bench's guard settings, which would change
    nothing without the guard, and keeps its other knobs; the merged file loads with no idle key noted."""
    from common.hyperparams import load_hyperparameters
    from racer.bench.race import BenchRaceSettings, _files

    merged = BenchRaceSettings(hyperparams={"collapse_guard": False}).race_hyperparams()
    assert merged == {"collapse_guard": False, "target_kl": 0.05}
    _, path = _files(tmp_path, merged)
    hp = load_hyperparameters(path)
    assert not hp.collapse_guard and hp.collapse_slowdown is None and hp.target_kl == 0.05
    assert not [note for note in hp.ignored() if "collapse_" in note]


@pytest.mark.slow(reason="runs racer train with its real processes")
@pytest.mark.parametrize(
    ("option", "text", "key", "value"),
    [
        ("--hyperparams", '{"stack_size": 0}', "stack_size", "0"),
        ("--reward-constants", '{"MARGIN": 0}', "MARGIN", "got 0"),
        ("--hyperparams", '{"greedy_action": "expected"}', "greedy_action", "'expected'"),
        ("--randomization", '{"action_noise": 2}', "action_noise", "2"),
        ("--action-space", '{"action_space": [{"steering_angle": 0, "speed": "fast"}]}', "speed", "fast"),
        (
            "--action-space",
            '{"action_space_type": "continuous", "action_space": {"steering_angle": {"low": -30, "high": 30}, '
            '"speed": {"low": 4, "high": 1}}}',
            "speed",
            "low 4.0 is above high 1.0",
        ),
        (
            "--action-space",
            '{"action_space": [{"steering_angle": 0, "speed": 2}], "sensor": ["STEREO_CAMERAS"]}',
            "sensor",
            "STEREO_CAMERAS",
        ),
        (
            "--action-space",
            '{"action_space_type": "continuous", "action_space": {"steering_angle": {"low": -30, "high": 30}, '
            '"speed": {"low": 1, "high": 4}}, "neural_network": "DEEP_CONVOLUTIONAL_NETWORK"}',
            "neural_network",
            "DEEP_CONVOLUTIONAL_NETWORK",
        ),
    ],
)
def test_a_bad_settings_file_stops_the_bench_before_any_training(tmp_path, option, text, key, value) -> None:  # noqa: ANN001
    """One line naming the file, the key and the value, and a non-zero exit, before the limit or a seed runs."""
    import subprocess
    import sys

    bad = tmp_path / "settings.json"
    bad.write_text(text)
    done = subprocess.run(
        [sys.executable, "-m", "racer", "bench", "race", option, str(bad), "--minutes", "0.5"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode != 0
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and str(bad) in lines[0] and key in lines[0] and value in lines[0], done.stderr


def test_the_late_window_says_where_a_seed_ended_not_its_luckiest_checkpoint() -> None:
    """A 10-minute budget: the late window is its last 2 minutes (from 480 s); its robust laps are 8.0 and 9.0 s (the
    0.7 checkpoint does not count), median 8.5 s against a best of 7.0 s at minute 2."""
    curve = [
        point(1, 0.5),
        point(2, 1.0, 7.0),  # the best, early
        point(5, 1.0, 7.5),
        point(8, 1.0, 9.0),  # 480 s: the late window's first
        point(9, 0.7),
        point(10, 1.0, 8.0),
    ]
    figures = seed_figures(curve, limit_s=6.0, budget_s=600.0)
    assert figures["best_robust_lap_s"] == 7.0
    assert figures["late_robust_lap_s"] == 8.5
    assert figures["drift_after_best"] == pytest.approx(8.5 / 7.0)
    # Without the budget the window ends at the last checkpoint (600 s here too).
    assert seed_figures(curve, limit_s=6.0)["late_robust_lap_s"] == 8.5


def test_no_late_robust_checkpoint_means_no_drift_figure() -> None:
    curve = [point(1, 1.0, 7.0), point(9, 0.8), point(10, 0.9)]
    figures = seed_figures(curve, limit_s=6.0, budget_s=600.0)
    assert figures["late_robust_lap_s"] is None and figures["drift_after_best"] is None
    assert seed_figures([], limit_s=6.0)["late_robust_lap_s"] is None


def test_the_curve_leaves_out_a_rollbacks_copy_of_the_best(tmp_path) -> None:  # noqa: ANN001
    """v3 is the guard's republished copy of v1 (no metrics row): evaluated 10 of 10, but not a policy the learner
    reached, so it is neither on the curve nor the final checkpoint."""
    runs = RunStore(LocalStore(tmp_path))
    rows = [{"policy_version": v, "time": 100.0 + 10 * v, "env_steps": 500 * v} for v in (1, 2, 4)]
    runs.write_file("r", METRICS_FILE, "".join(json.dumps(r) + "\n" for r in rows))
    for version, completion, laps in ((1, 1.0, [11.0, 12.0]), (2, 0.3, []), (3, 1.0, [11.0, 12.0]), (4, 0.7, [13.0])):
        record = {"completion_rate": completion, "lap_times_s": laps}
        runs.write_file("r", evaluation_name(version), json.dumps(record))
    curve = race_curve("r", runs, t0=100.0)
    assert [p["version"] for p in curve] == [1, 2, 4]
    assert curve[0].pop("command_speeds") == {}  # a record without trajectories
    assert curve[0] == pytest.approx(
        {"version": 1, "time_s": 10.0, "env_steps": 500, "completion": 1.0, "mean_lap_s": 11.5, "best_lap_s": 11.0}
    )
    assert seed_figures(curve, limit_s=10.0)["final_completion"] == 0.7


def test_the_share_of_steps_at_each_commanded_speed_of_the_best_robust_checkpoint(tmp_path) -> None:  # noqa: ANN001
    runs = RunStore(LocalStore(tmp_path))
    runs.write_file(
        "r",
        METRICS_FILE,
        "".join(json.dumps({"policy_version": v, "time": 0.0, "env_steps": 0}) + "\n" for v in (1, 2)),
    )
    slow = [[0.0, 0.0, 1.5]] * 3  # x, y, commanded speed per step, as the evaluator records a trial
    mixed = [[0.0, 0.0, 1.5], [0.0, 0.0, 4.0], [0.0, 0.0, 2.75], [0.0, 0.0, 4.0]]
    trials = {1: [{"trajectory": slow}, {"trajectory": slow}], 2: [{"trajectory": mixed}, {"trajectory": slow[:1]}]}
    for version, laps in ((1, [14.0, 15.0]), (2, [10.0, 11.0])):
        record = {"completion_rate": 1.0, "lap_times_s": laps, "trials": trials[version]}
        runs.write_file("r", evaluation_name(version), json.dumps(record))
    curve = race_curve("r", runs, t0=0.0)
    assert curve[0]["command_speeds"] == {"1.5": 1.0}
    assert curve[1]["command_speeds"] == pytest.approx({"1.5": 0.4, "2.75": 0.2, "4": 0.4})  # 2, 1 and 2 of 5 steps
    assert list(curve[1]["command_speeds"]) == ["1.5", "2.75", "4"]
    assert seed_figures(curve, limit_s=8.0)["best_command_speeds"] == curve[1]["command_speeds"]  # v2: 10.5 s
    assert seed_figures([point(1, 0.5)], limit_s=8.0)["best_command_speeds"] is None  # no robust checkpoint


def test_a_users_reward_constants_are_laid_over_the_cars_and_written_into_the_example(tmp_path) -> None:  # noqa: ANN001
    """``--reward-constants F``: the example's own constants only, positive numbers (integers where the example's
    is one); the copy the seeds train with holds them and still runs as a reward function."""
    from common.errors import OptionError
    from racer.bench.race import load_reward_constants, reward_file

    good = tmp_path / "constants.json"
    good.write_text('{"MARGIN": 0.25, "ITERATIONS": 200}')
    constants = {"MAX_SPEED": 4.0, "LATERAL_ACCEL": 2.6, "BRAKE": 3.4, **load_reward_constants(good)}
    module = _reward_module(reward_file(tmp_path, constants))
    assert (module.MARGIN, module.ITERATIONS, module.LATERAL_ACCEL) == (0.25, 200, 2.6)
    assert callable(module.reward_function)

    for text, words in (
        ('{"MARGN": 0.25}', ("MARGN", "MARGIN")),
        ('{"MARGIN": "wide"}', ("MARGIN", "'wide'")),
        ('{"MARGIN": -0.1}', ("MARGIN", "-0.1")),
        ('{"ITERATIONS": 2.5}', ("ITERATIONS", "2.5", "integer")),
        ('{"BRAKE": true}', ("BRAKE", "True")),
    ):
        bad = tmp_path / "bad.json"
        bad.write_text(text)
        with pytest.raises(OptionError) as err:
            load_reward_constants(bad)
        assert str(bad) in str(err.value) and all(w in str(err.value) for w in words), str(err.value)


def test_the_seeds_train_with_the_users_randomization_and_the_json_records_it(tmp_path) -> None:  # noqa: ANN001
    """``--randomization F``: the workers' env gets the file's settings (racer's defaults otherwise: no action
    noise), and the bench's JSON records what the seeds trained with."""
    from racer.bench.race import BenchRaceSettings, example_constants, seed_run, training_randomization

    noisy = tmp_path / "randomization.json"
    noisy.write_text('{"action_noise": 0.1}')
    run, _ = seed_run(BenchRaceSettings(car="deepracer-gazebo", randomization=str(noisy)), 1, example_constants())
    assert run.env.randomization.action_noise == 0.1 and run.env.randomization.random_start
    assert run.env.car.effects and run.seed == 1
    plain, _ = seed_run(BenchRaceSettings(), 1, example_constants())
    assert plain.env.randomization.action_noise == 0.0
    assert training_randomization(str(noisy))["action_noise"] == 0.1
    assert training_randomization(None) == plain.env.randomization.model_dump(mode="json")


def test_the_seeds_train_with_the_users_action_space_and_the_example_tops_at_its_speed(tmp_path) -> None:  # noqa: ANN001
    """``--action-space F``: a discrete space's actions go to the seeds' model_metadata.json, the reward example's
    MAX_SPEED is the space's top speed, and the default stays the bench's 4 m/s space."""
    from common.action_space import load_action_space
    from racer.bench.race import (
        RACE_ACTIONS,
        BenchRaceSettings,
        example_constants,
        load_race_actions,
        reward_constants,
        seed_run,
    )

    actions = [{"steering_angle": s, "speed": v} for v in (1.5, 3.5) for s in (-12.0, -4.0, 0.0, 4.0, 12.0)]
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": actions, "action_space_type": "discrete", "version": "5"}))
    assert load_race_actions(path) == actions
    settings = BenchRaceSettings(actions=load_race_actions(path))
    _, files = seed_run(settings, 0, example_constants())
    (tmp_path / "written.json").write_bytes(files["model_metadata.json"])
    written = load_action_space(tmp_path / "written.json").action_space
    assert [(a.steering_angle, a.speed) for a in written] == [(a["steering_angle"], a["speed"]) for a in actions]
    limits = {"speeds": [1.0, 2.0, 3.0], "max_lateral_accel": [3.0, 3.0, 3.0], "brake": [4.0, 4.0, 4.0]}
    assert reward_constants(limits, settings.race_actions())["MAX_SPEED"] == 3.5
    assert BenchRaceSettings().race_actions() == RACE_ACTIONS and reward_constants(limits)["MAX_SPEED"] == 4.0


def test_a_continuous_action_space_trains_the_seeds_and_its_speeds_are_counted_in_bins(tmp_path) -> None:  # noqa: ANN001
    """``--action-space F`` with a continuous space (what many DeepRacer racers train): the seeds' model_metadata.json
    holds its ranges and type, the reward example's MAX_SPEED is the speed range's top, and ``command_speeds`` counts
    the speeds, all different, in 0.25 m/s bins keyed by the bin's lower edge."""
    from common.action_space import load_action_space
    from racer.bench.race import (
        BenchRaceSettings,
        command_speeds,
        example_constants,
        load_race_actions,
        reward_constants,
        seed_run,
    )

    ranges = {"steering_angle": {"low": -25.0, "high": 25.0}, "speed": {"low": 1.5, "high": 3.8}}
    path = tmp_path / "model_metadata.json"
    path.write_text(json.dumps({"action_space": ranges, "action_space_type": "continuous"}))
    assert load_race_actions(path) == ranges
    settings = BenchRaceSettings(actions=load_race_actions(path))
    _, files = seed_run(settings, 0, example_constants())
    (tmp_path / "written.json").write_bytes(files["model_metadata.json"])
    written = load_action_space(tmp_path / "written.json")
    assert not written.discrete
    assert (written.action_space.speed.low, written.action_space.speed.high) == (1.5, 3.8)
    assert (written.action_space.steering_angle.low, written.action_space.steering_angle.high) == (-25.0, 25.0)
    limits = {"speeds": [1.0, 2.0, 3.0], "max_lateral_accel": [3.0, 3.0, 3.0], "brake": [4.0, 4.0, 4.0]}
    assert reward_constants(limits, settings.race_actions())["MAX_SPEED"] == 3.8

    # 1.5 and 1.74 in [1.5, 1.75); 1.75 on an edge in [1.75, 2); 3.8 in [3.75, 4): 2, 1 and 1 of 4 steps.
    record = {"trials": [{"trajectory": [[0, 0, 1.5], [0, 0, 1.74]]}, {"trajectory": [[0, 0, 1.75], [0, 0, 3.8]]}]}
    assert command_speeds(record, 0.25) == {"1.5": 0.5, "1.75": 0.25, "3.75": 0.25}
    assert list(command_speeds(record, 0.25)) == ["1.5", "1.75", "3.75"]
    assert command_speeds(record) == {"1.5": 0.25, "1.74": 0.25, "1.75": 0.25, "3.8": 0.25}  # a discrete space's


def test_console_figures_are_rounded_and_say_when_a_seed_never_got_there() -> None:
    from racer.bench.race import seconds_text, shares_text

    # A mean of laps counted in 1/15 s steps is not a round float (12.02 printed as 12.019999999999957).
    assert seconds_text(statistics.fmean([12.0 + 1 / 15, 11.0 + 14 / 15, 12.0 + 1 / 15])) == "12.02 s"
    assert seconds_text(None) == "-"
    assert shares_text({"1.5": 0.3134, "1.75": 0.6866}) == "1.5 m/s 31%, 1.75 m/s 69%"
    assert shares_text(None) == shares_text({}) == "-"
