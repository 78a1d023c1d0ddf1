"""The evaluator: its score, the best pointer, the robust-stop streak, and a real evaluation of a checkpoint."""

import json

import pytest

from common.defaults import DEFAULT_TRACK, STRAIGHT_TRACK
from model_store import LocalStore, RunStore
from racer.launcher import robust_streak
from racer.runconfig import build_run
from trainer.evaluator import (
    EvalSettings,
    Trial,
    evaluate_checkpoint,
    save_evaluation,
    score,
    summarize,
)


def trial(progress, status, lap=None, reverse=False):
    return Trial(
        DEFAULT_TRACK,
        reverse,
        0,
        progress=progress,
        status=status,
        steps=10,
        lap_time_s=lap,
        trajectory=[[0.0, 0.0, 1.0]],
    )


def test_score_ranks_completion_then_progress_then_lap_time():
    # Hand-computed: 100·completion + progress − 0.1·mean lap time.
    assert score(1.0, 100.0, [20.0, 30.0]) == pytest.approx(100 + 100 - 2.5)
    assert score(0.5, 75.0, [20.0]) == pytest.approx(50 + 75 - 2.0)
    assert score(0.0, 40.0, []) == pytest.approx(40.0)
    assert score(1.0, 100.0, [12.0]) > score(1.0, 100.0, [15.0])  # faster laps win among full completions
    assert score(0.5, 60.0, [10.0]) > score(0.0, 99.0, [])  # a completed lap beats more progress


def test_summarize_counts_laps_progress_and_off_track():
    s = summarize(
        [
            trial(100.0, "lap_complete", 14.0),
            trial(40.0, "off_track"),
            trial(100.0, "lap_complete", 12.0),
            trial(10.0, "reversed"),
        ]
    )
    assert s["episodes"] == 4 and s["completion_rate"] == 0.5
    assert s["mean_progress"] == pytest.approx(62.5)
    assert s["lap_times_s"] == [14.0, 12.0] and s["best_lap_s"] == 12.0 and s["off_track"] == 1
    assert s["score"] == pytest.approx(50 + 62.5 - 1.3)


def test_robust_streak_counts_the_latest_full_completions():
    evals = [{"completion_rate": r} for r in (1.0, 0.5, 1.0, 1.0, 1.0)]
    assert robust_streak(evals) == 3
    assert robust_streak(evals[:2]) == 0
    assert robust_streak([]) == 0


def _stored_run(store, run_id, **options):
    """A run built as ``racer train`` builds it (``build_run(run_id, **options)``), its files and config stored."""
    run, files = build_run(run_id, **options)
    runs = RunStore(LocalStore(store))
    for name, data in files.items():
        runs.write_file(run_id, name, data)
    runs.write_file(run_id, "config.json", run.model_dump_json())
    return run, files, runs


def _runs_with_checkpoints(tmp_path, versions):
    runs = RunStore(LocalStore(tmp_path))
    for v in versions:
        runs.save_checkpoint("r", v, b"weights", {"env_steps": 100 * v})
    return runs


def test_best_pointer_moves_only_to_a_higher_score(tmp_path):
    runs = _runs_with_checkpoints(tmp_path, [1, 2, 3])
    rec = lambda v, s: {"run_id": "r", "version": v, "score": s, "trials": []}  # noqa: E731
    assert save_evaluation(runs, rec(1, 50.0)) is True
    assert runs.pointer("r", "best")["version"] == 1
    assert save_evaluation(runs, rec(2, 40.0)) is False
    assert runs.pointer("r", "best")["version"] == 1
    assert save_evaluation(runs, rec(3, 150.0)) is True
    assert runs.pointer("r", "best")["version"] == 3
    assert json.loads(runs.read_file("r", "evaluations/000000002.json"))["score"] == 40.0  # every one is kept
    assert runs.pointer("r", "latest")["version"] == 3


def test_a_real_checkpoint_is_evaluated_from_spread_starts_in_both_directions(tmp_path):
    from common.policy import action_space_spec, build_policy
    from common.weights import checkpoint_to_bytes
    from model_store.localize import localize_env
    from sim.env import RacerEnv

    run, files = build_run("ev", track=DEFAULT_TRACK)
    runs = RunStore(LocalStore(tmp_path / "store"))
    for name, data in files.items():
        runs.write_file("ev", name, data)
    env_cfg = localize_env(run, runs, tmp_path)
    env = RacerEnv(config=env_cfg)
    model = build_policy((120, 160, 1), action_space_spec(env.actions), run.policy)
    runs.save_checkpoint("ev", 0, checkpoint_to_bytes(model.state_dict()), {"env_steps": 0})
    settings = EvalSettings(episodes=2, both_directions=True, action_noise=0.1)
    record = evaluate_checkpoint(runs, run, env_cfg, "latest", settings)
    assert record["episodes"] == 4 and len(record["trials"]) == 4
    starts = {(t["reverse"], t["start_index"]) for t in record["trials"]}
    # Two starts spread over the loop's 117 distinct waypoints (racer_loop's 118 rows repeat the first as the
    # last): round(i * 117 / 2) for i = 0, 1, and Python rounds 58.5 to the even 58.
    assert starts == {(False, 0), (False, 58), (True, 0), (True, 58)}
    assert all(len(t["trajectory"]) == t["steps"] for t in record["trials"])
    assert 0 <= record["mean_progress"] <= 100 and record["version"] == 0
    again = evaluate_checkpoint(runs, run, env_cfg, 0, settings)
    assert [t["progress"] for t in again["trials"]] == [t["progress"] for t in record["trials"]]  # deterministic


@pytest.mark.slow(reason="runs racer commands end to end")
def test_racer_eval_cli_prints_writes_json_and_video(tmp_path):
    import cv2
    from typer.testing import CliRunner

    from common.policy import action_space_spec, build_policy
    from common.weights import checkpoint_to_bytes
    from racer.cli import app
    from sim.env import RacerEnv

    run, _, runs = _stored_run(tmp_path, "cli-ev", track=DEFAULT_TRACK)
    actions = RacerEnv(track=DEFAULT_TRACK).actions
    model = build_policy((120, 160, 1), action_space_spec(actions), run.policy)
    runs.save_checkpoint("cli-ev", 3, checkpoint_to_bytes(model.state_dict()), {"env_steps": 300})
    out, video = tmp_path / "eval.json", tmp_path / "eval.mp4"
    args = [
        "eval",
        "--run-id",
        "cli-ev",
        "--store",
        str(tmp_path),
        "--checkpoint",
        "3",
        "--episodes",
        "1",
        "--json",
        str(out),
        "--video",
        str(video),
    ]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "completion" in result.output and "forward" in result.output and "reverse" in result.output
    data = json.loads(out.read_text())
    for key in ("episodes", "completion_rate", "mean_progress", "lap_times_s", "best_lap_s"):
        assert key in data
    assert data["episodes"] == 2 and data["version"] == 3
    cap = cv2.VideoCapture(str(video))
    frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    ok, first = cap.read()
    assert ok and frames == data["video"]["frames"] and first.std() > 10
    missing = CliRunner().invoke(app, ["eval", "--run-id", "nope", "--store", str(tmp_path)])
    assert missing.exit_code == 2 and "nope" in missing.output


def test_racer_eval_says_its_progress_on_stderr_as_it_goes_and_keeps_json_on_stdout(tmp_path):
    """A new user waited minutes on a silent ``racer eval``: it says which checkpoint it drives, each pass of the
    trials and each condition on stderr as they end, its summary last; ``--json -`` keeps standard output JSON, and
    ``--quiet`` says nothing."""
    from typer.testing import CliRunner

    from common.policy import action_space_spec, build_policy
    from common.weights import checkpoint_to_bytes
    from racer.cli import app
    from sim.env import RacerEnv

    run, _, runs = _stored_run(tmp_path, "says", track=DEFAULT_TRACK)
    model = build_policy((120, 160, 1), action_space_spec(RacerEnv(track=DEFAULT_TRACK).actions), run.policy)
    runs.save_checkpoint("says", 3, checkpoint_to_bytes(model.state_dict()), {"env_steps": 300})
    runs.set_pointer("says", "best", 3)
    args = ["eval", "--run-id", "says", "--store", str(tmp_path), "--episodes", "1", "--one-direction"]
    args += ["--device", "cpu", "--json", "-"]
    result = CliRunner().invoke(app, [*args, "--condition", "blur"])
    assert result.exit_code == 0, result.output
    record = json.loads(result.stdout)
    lines = result.stderr.splitlines()
    assert len(lines) == 5, lines
    assert lines[0] == "checkpoint v3 of run says (best, 300 env steps), on cpu"
    assert lines[1] == "driving 1 trial on racer_loop (1 start per direction, forward only), side by side"
    ends = f"{record['off_track']} off track, {record['crashed']} crashed"
    assert lines[2].startswith("as trained: 1 trial in ")
    assert lines[2].endswith(f"{ends}, mean progress {record['mean_progress']:.1f} %")
    blur = record["conditions"][0]
    assert lines[3].startswith("condition 1/1 blur: 1 trial in ")
    assert lines[3].endswith(f"mean progress {blur['mean_progress']:.1f} %")
    best = "-" if record["best_lap_s"] is None else f"{record['best_lap_s']:.2f} s"
    completion, progress = 100 * record["completion_rate"], record["mean_progress"]
    summary = f"completion {completion:.0f}%, mean progress {progress:.1f}%, best lap {best}"
    assert lines[4] == f"version 3: {summary}, score {record['score']:.1f}"
    quiet = CliRunner().invoke(app, [*args, "--quiet"])
    assert quiet.exit_code == 0, quiet.output
    assert quiet.stderr == "" and json.loads(quiet.stdout)["version"] == 3


def test_a_store_that_refuses_the_eval_video_warns_and_keeps_the_local_file(tmp_path, caplog):
    from racer.evaluate import store_video

    runs = RunStore(LocalStore(tmp_path / "store"))
    runs.write_file("r", "videos", b"a file where the videos folder would be")
    mp4 = tmp_path / "lap.mp4"
    mp4.write_bytes(b"an mp4")
    assert store_video(runs, "r", 3, mp4) is None
    assert "racer view will not show" in caplog.text and str(mp4) in caplog.text and mp4.read_bytes() == b"an mp4"


def test_evaluation_sim_trace_is_read_by_deepracer_utils(tmp_path):
    pytest.importorskip("deepracer.logs", reason="deepracer-utils is in the dev extra")
    from deepracer.logs import DeepRacerLog

    from common.policy import action_space_spec, build_policy
    from common.simtrace import SimTraceRecorder
    from common.weights import checkpoint_to_bytes
    from model_store.localize import localize_env
    from model_store.runs import evaluation_stamp, simtrace_key
    from sim.env import RacerEnv

    run, files = build_run("evtrace", track=DEFAULT_TRACK)
    runs = RunStore(LocalStore(tmp_path))
    for name, data in files.items():
        runs.write_file("evtrace", name, data)
    env_cfg = localize_env(run, runs, tmp_path)
    model = build_policy((120, 160, 1), action_space_spec(RacerEnv(config=env_cfg).actions), run.policy)
    runs.save_checkpoint("evtrace", 0, checkpoint_to_bytes(model.state_dict()), {"env_steps": 0})
    recorder = SimTraceRecorder()
    record = evaluate_checkpoint(runs, run, env_cfg, 0, EvalSettings(episodes=2), recorder=recorder)
    text = recorder.take(include_open=True)
    key = simtrace_key("evtrace", "evaluation", 0, evaluation=evaluation_stamp(record["created"]))
    runs.store.put(key, text.encode())
    # deepracer-utils' DRfC layout needs worker 0's training folder to recognise the run folder.
    runs.store.put(simtrace_key("evtrace", "training", 0, 0), text.encode())
    log = DeepRacerLog(str(tmp_path / "runs" / "evtrace"))
    log.load_evaluation_trace()
    df = log.dataframe()
    assert len(df) == sum(t["steps"] + 1 for t in record["trials"])  # a prepare row per episode
    assert df["episode"].nunique() == len(record["trials"])
    # The trial's progress is its last step's (a car that rolled back before it left the track has a lower progress
    # than its best): the last row of each episode, as deepracer-utils reads it.
    last = df.sort_values(["episode", "steps"]).groupby("episode")["progress"].last().tolist()
    assert last == pytest.approx([t["progress"] for t in record["trials"]], abs=1e-6)


def test_lockstep_evaluation_drives_each_trial_as_run_trial_does():
    """evaluate() batches every trial's frame into one forward pass per step; each trial and its sim-trace rows
    must come out as the one-at-a-time run_trial drives and records them."""
    import torch

    from common.policy import action_space_spec, build_policy
    from common.simtrace import SimTraceRecorder
    from sim.env import RacerEnv
    from trainer.evaluator import evaluate, run_trial

    run, _ = build_run("lock", track=DEFAULT_TRACK)
    env = RacerEnv(config=run.env)
    torch.manual_seed(5)
    model = build_policy((120, 160, 1), action_space_spec(env.actions), run.policy)
    with torch.no_grad():  # decisive logits: a batch-vs-single rounding difference cannot flip an argmax
        model.policy_head.weight.mul_(300.0)
    settings = EvalSettings(episodes=2, both_directions=True, action_noise=0.1, seed=7)
    batched_trace = SimTraceRecorder()
    batched = evaluate(model, run.env, 1, settings, batched_trace)

    noise = run.env.randomization.model_copy(update={"action_noise": 0.1, "random_start": False})
    one_env = RacerEnv(config=run.env.model_copy(update={"randomization": noise}))
    single_trace = SimTraceRecorder()
    single = []
    for reverse in (False, True):
        count = one_env.task.start_indices(reverse)
        for i in range(2):
            start, seed = round(i * count / 2) % count, 7 + 1000 * i + (500 if reverse else 0)
            single.append(
                run_trial(
                    one_env,
                    model,
                    1,
                    start,
                    reverse,
                    seed=seed,
                    deterministic=True,
                    on_step=None,
                    recorder=single_trace,
                    episode=len(single),
                )
            )
    assert [t.steps for t in batched] == [t.steps for t in single]
    assert len({t.steps for t in batched}) > 1, "trials of different lengths should run side by side"
    assert batched == single  # status, progress, lap time and every point of every path
    assert batched_trace.take(include_open=True) == single_trace.take(include_open=True)


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_the_evaluator_rides_out_a_short_redis_outage_and_ends_on_a_longer_one(tmp_path, caplog):
    """As the worker and trainer do: a Redis restart shorter than ``outage_s`` pauses the evaluator (it then evaluates
    the version published after it), an outage longer than ``outage_s`` ends it with OutageError."""
    import logging
    import threading
    import time

    import redis
    import torch

    from common.action_space import ActionSpace
    from common.keys import Keys
    from common.policy import action_space_spec, build_policy
    from common.protocol import PolicyVersion
    from common.retry import OutageError
    from common.weights import checkpoint_to_bytes
    from model_store.runs import checkpoint_key
    from racer.embedded_redis import EmbeddedRedis, free_port
    from tests.faults import wait_for
    from trainer.evaluator import EvaluatorOptions, run_evaluator

    run, files = build_run("ev-outage", track=STRAIGHT_TRACK)
    runs = RunStore(LocalStore(tmp_path))
    for name, data in files.items():
        runs.write_file(run.run_id, name, data)
    runs.write_config(run)
    actions = ActionSpace.model_validate_json(files["model_metadata.json"])
    model = build_policy((120, 160, 1), action_space_spec(actions), run.policy)
    runs.save_checkpoint(run.run_id, 1, checkpoint_to_bytes(model.state_dict()), {"env_steps": 100})
    port, keys, threads = free_port(), Keys(run.run_id), torch.get_num_threads()
    server = EmbeddedRedis(port=port)
    settings = EvalSettings(episodes=1, both_directions=False)
    opts = EvaluatorOptions(run.run_id, server.url, str(tmp_path), settings=settings, outage_s=4.0)
    stop, errors = threading.Event(), []

    def evaluator() -> None:
        try:
            run_evaluator(opts, stop)
        except Exception as exc:
            errors.append(exc)

    caplog.set_level(logging.WARNING, "racer.evaluator")
    thread = threading.Thread(target=evaluator, daemon=True)
    thread.start()
    try:
        time.sleep(1.0)  # polling for a policy version
        server.stop()
        wait_for(lambda: "unreachable while trying to read the policy version" in caplog.text, 10, "the outage")
        time.sleep(1.0)
        server = EmbeddedRedis(port=port)  # no persistence: it comes back empty
        pv = PolicyVersion(version=1, checkpoint_key=checkpoint_key(run.run_id, 1), created=time.time())
        r = redis.Redis.from_url(server.url)
        r.set(keys.policy, pv.to_json())
        wait_for(lambda: r.llen(keys.evaluations) or errors, 60, "the evaluation after the outage")
        assert not errors and "reachable again after" in caplog.text
        assert json.loads(r.lindex(keys.evaluations, 0))["version"] == 1 and runs.evaluation_versions("ev-outage")
        server.stop()  # now for good
        t0 = time.monotonic()
        thread.join(30)
        assert not thread.is_alive() and len(errors) == 1 and isinstance(errors[0], OutageError), errors
        assert "unreachable for" in str(errors[0]) and 4.0 <= time.monotonic() - t0 < 20
    finally:
        stop.set()
        thread.join(10)
        server.stop()
        torch.set_num_threads(threads)  # run_evaluator sets this process's torch to one thread


def test_greedy_action_expected_is_refused_for_a_discrete_space_in_one_line(tmp_path):
    from common.hyperparams import HyperparametersError

    hp = tmp_path / "hyperparameters.json"
    hp.write_text(json.dumps({"greedy_action": "expected"}))
    with pytest.raises(HyperparametersError) as info:
        build_run("g", hyperparams=str(hp))
    message = str(info.value)
    assert "\n" not in message and str(hp) in message and "greedy_action 'expected'" in message


def test_greedy_action_reaches_the_evaluated_policy(tmp_path):
    from common.action_space import ActionSpace
    from common.policy import action_space_spec, build_policy
    from common.weights import checkpoint_to_bytes, load_policy

    space = tmp_path / "model_metadata.json"
    space.write_text(
        json.dumps(
            {
                "action_space_type": "continuous",
                "action_space": {"steering_angle": {"low": -25, "high": 25}, "speed": {"low": 1.5, "high": 4.0}},
            }
        )
    )
    hp = tmp_path / "hyperparameters.json"
    hp.write_text(json.dumps({"greedy_action": "expected"}))
    run, files, runs = _stored_run(tmp_path / "store", "g", action_space=str(space), hyperparams=str(hp))
    assert run.policy.greedy_action == "expected"
    actions = ActionSpace.model_validate_json(files["model_metadata.json"])
    network = build_policy((120, 160, 1), action_space_spec(actions))
    runs.save_checkpoint("g", 1, checkpoint_to_bytes(network.state_dict()), {})
    model, _ = load_policy(runs, "g", actions, 1)
    assert model.cfg.greedy_action == "expected"
    # racer eval re-judges it under either rule and says which in the record; the discrete run above refuses.
    from racer.evaluate import run_eval

    for rule in ("mean", "expected"):
        record = run_eval(
            "g",
            str(tmp_path / "store"),
            None,
            checkpoint="1",
            tracks=[],
            episodes=1,
            both_directions=False,
            action_noise=0.0,
            greedy_action=rule,
        )
        assert record["greedy_action"] == rule and record["episodes"] == 1


def test_racer_eval_refuses_greedy_action_expected_for_a_discrete_run_in_one_line(tmp_path):
    from typer.testing import CliRunner

    from racer.cli import app

    _stored_run(tmp_path, "d", track=DEFAULT_TRACK)
    args = ["eval", "--run-id", "d", "--store", str(tmp_path), "--greedy-action", "expected"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2 and "--greedy-action expected: run 'd' has a discrete action space" in result.output
    bad = CliRunner().invoke(app, [*args[:-1], "median"])
    assert bad.exit_code == 2 and "--greedy-action 'median' is not one of mean, expected" in bad.output
