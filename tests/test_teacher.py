"""Teacher–student training (``racer train --teacher``, docs/teacher.md): the teacher's state observations, network
and segments; the student's labelled segments and distillation; the two stages end to end.

The contract under test: a teacher run's env returns ``common.privileged.state_vector`` of the step's params and
renders nothing; its network is a ``StatePolicy``; its segments carry float32 state vectors raw. A distilling run
copies its teacher's checkpoint into itself; its workers label every step with the teacher's action distribution
and drive the scheduled share of steps with the teacher's action; its trainer distills for ``DistillConfig.updates``
versions, then runs PPO.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import redis
import torch
from pydantic import ValidationError

from common.action_space import default_action_space, load_action_space
from common.bus import Bus
from common.config import DistillConfig, EnvConfig, RunConfig
from common.defaults import STRAIGHT_TRACK
from common.errors import UserError
from common.keys import Keys
from common.policy import ActorCritic, StatePolicy, label_width, policy_for_run
from common.privileged import STATE_SIZE, state_vector
from common.protocol import CarPose, ProtocolError, decode_segment, encode_segment
from common.weights import load_policy
from deploy.export import export_onnx
from model_store import RunStore, open_store
from model_store.localize import localize_env
from model_store.runs import TEACHER_FILE, TEACHER_META_FILE
from racer.evaluate import write_video
from racer.options import RunOptions
from racer.runconfig import build_run
from racer.teacher import split_time, teacher_checkpoint, teacher_run
from rollout_worker.onnx_policy import OnnxPolicy
from rollout_worker.rollouts import Rollouts
from rollout_worker.teacher import Teacher
from rollout_worker.watch import WatchPublisher
from rollout_worker.worker import RolloutWorker, WorkerOptions
from sim.env import RacerEnv
from trainer.evaluator import EvalSettings, evaluate_checkpoint
from trainer.process import Trainer, TrainerOptions

N_ACTIONS = default_action_space().n


def _state_run(run_id: str = "t") -> RunConfig:
    return RunConfig(run_id=run_id, env=EnvConfig(track=STRAIGHT_TRACK, observation="state"))


def _sure_teacher(action: int) -> StatePolicy:
    """A discrete teacher that picks ``action`` with probability ~1, whatever the state."""
    model = StatePolicy(STATE_SIZE, "discrete", n_actions=N_ACTIONS)
    with torch.no_grad():
        model.policy_head.weight.zero_()
        model.policy_head.bias.fill_(-30.0)
        model.policy_head.bias[action] = 30.0
    return model


# --- configuration ---------------------------------------------------------------------------------------------------


def test_the_teacher_share_falls_linearly_to_zero_and_distilling_ends_at_updates() -> None:
    d = DistillConfig(teacher="t:3", updates=6, teacher_share=0.5, teacher_share_updates=4)
    assert [d.teacher_share_at(v) for v in range(6)] == [0.5, 0.375, 0.25, 0.125, 0.0, 0.0]
    assert [d.distilling(v) for v in (0, 5, 6, 7)] == [True, True, False, False]
    with pytest.raises(ValidationError, match="must not exceed updates"):
        DistillConfig(teacher="t:3", updates=3, teacher_share_updates=4)
    with pytest.raises(ValidationError, match="pattern"):
        DistillConfig(teacher="t:best")  # resolved to a version before the run is written


def test_a_teacher_run_observes_the_state_with_no_frame_stack() -> None:
    run, _ = build_run("s", track=STRAIGHT_TRACK)
    run = run.model_copy(update={"hyperparams": run.hyperparams.model_copy(update={"stack_size": 3})})
    teacher = teacher_run(run.model_copy(update={"run_id": "s-teacher"}))
    assert teacher.env.observation == "state" and teacher.hyperparams.stack_size == teacher.policy.stack_size == 1
    assert teacher.env.track == run.env.track and teacher.distill is None
    assert run.env.observation == "sensors"  # the student's own run is left as it was


def test_the_teacher_gets_a_third_of_the_time_unless_told() -> None:
    assert split_time(RunOptions(time_limit_s=600), None) == 200
    assert split_time(RunOptions(time_limit_s=600), 120) == 120
    with pytest.raises(ValueError, match="--teacher needs --time-limit or --teacher-time"):
        split_time(RunOptions(), None)
    with pytest.raises(ValueError, match="shorter than --time-limit"):
        split_time(RunOptions(time_limit_s=60), 90)


# --- the teacher's observation, network and segments -------------------------------------------------------------


def test_a_state_env_returns_the_params_state_vector() -> None:
    env = RacerEnv(config=EnvConfig(track=STRAIGHT_TRACK, observation="state"))
    obs, info = env.reset(seed=0)
    assert env.observation_space.shape == (STATE_SIZE,) and obs.dtype == np.float32
    np.testing.assert_array_equal(obs, state_vector(info["params"]))
    for _ in range(3):
        obs, _, _, _, info = env.step(1)
        np.testing.assert_array_equal(obs, state_vector(info["params"]))
    env.close()


def test_the_state_network_acts_on_float_vectors_and_refuses_frames() -> None:
    model = policy_for_run(_state_run(), default_action_space())
    assert isinstance(model, StatePolicy) and model.obs_shape == (STATE_SIZE,)
    states = np.random.default_rng(0).normal(size=(5, STATE_SIZE)).astype(np.float32)
    actions, logp, values = model.act_numpy(states)
    assert actions.shape == logp.shape == values.shape == (5,) and actions.dtype == np.int64
    with pytest.raises(TypeError, match="float32"):
        model(torch.zeros((1, STATE_SIZE), dtype=torch.uint8))
    with pytest.raises(ValueError, match="state network"):
        model(torch.zeros((1, 120, 160, 1)))
    # The worker's ONNX Runtime copy gives the network's own outputs.
    params, value = model(torch.from_numpy(states))
    onnx_params, onnx_value = OnnxPolicy(model).session.run(None, {"obs": states})
    np.testing.assert_allclose(onnx_params, params.detach().numpy(), atol=1e-5)
    np.testing.assert_allclose(onnx_value, value.detach().numpy(), atol=1e-5)
    # A camera run's network is DeepRacer's, whatever else the run holds.
    assert isinstance(policy_for_run(RunConfig(run_id="c"), default_action_space()), ActorCritic)


def test_state_segments_go_raw_and_decode_bit_for_bit() -> None:
    rollouts = Rollouts(_state_run(), EnvConfig(track=STRAIGHT_TRACK, observation="state"), [1], ["w"])
    model = rollouts.build_policy()
    rollouts.reset()
    [seg] = rollouts.collect(model, 0)
    rollouts.close()
    fields = encode_segment(seg)
    assert "a:frames" not in fields and "a:frame_index" not in fields
    back = decode_segment(fields, "t", (STATE_SIZE,), N_ACTIONS)
    for name in ("obs", "next_obs", "actions", "rewards"):
        np.testing.assert_array_equal(back.arrays[name], seg.arrays[name])
    assert back.arrays["obs"].shape == (seg.steps, STATE_SIZE) and back.arrays["obs"].dtype == np.float32
    # A camera run refuses them (no frames); a state run refuses a non-finite state.
    with pytest.raises(ProtocolError, match="missing_array"):
        decode_segment(fields, "t", (120, 160, 1), N_ACTIONS)
    bad = dict(seg.arrays, obs=np.where(np.arange(STATE_SIZE) == 3, np.nan, seg.arrays["obs"]).astype(np.float32))
    seg.arrays = bad
    with pytest.raises(ProtocolError, match="non_finite"):
        decode_segment(encode_segment(seg), "t", (STATE_SIZE,), N_ACTIONS)


def test_a_watched_teacher_worker_publishes_its_pose_and_no_frame(redis_url, run_id) -> None:
    """racer view on a teacher run: the page asks for the camera, the state env has none; the pose still goes."""
    client = redis.Redis.from_url(redis_url)
    bus, keys = Bus(client, run_id), Keys(run_id)
    env = RacerEnv(config=EnvConfig(track=STRAIGHT_TRACK, observation="state"))
    observation, info = env.reset(seed=1)
    publisher = WatchPublisher(bus, "w-0", 0, env.track.name)
    bus.watch(["w-0"])
    end = time.monotonic() + 3.0
    while time.monotonic() < end and client.get(keys.pose("w-0")) is None:
        observation, _, term, trunc, info = env.step(1)
        publisher.step(observation, info)
        if term or trunc:
            observation, info = env.reset()
    pose = CarPose.from_json(client.get(keys.pose("w-0")))
    assert pose.track == STRAIGHT_TRACK and pose.frames == 0 and client.get(keys.frame("w-0")) is None
    publisher.close()
    env.close()


# --- the student's labelled steps ---------------------------------------------------------------------------------


@pytest.mark.parametrize(("share", "taught"), [(1.0, True), (0.0, False)])
def test_the_student_s_workers_label_every_step_and_drive_the_teacher_s_share(share, taught) -> None:
    distill = DistillConfig(teacher="t:1", updates=2, teacher_share=share, teacher_share_updates=1)
    run = RunConfig(run_id="s", env=EnvConfig(track=STRAIGHT_TRACK), distill=distill, segment_steps=12)
    teacher = Teacher(_sure_teacher(7), seed=0)
    rollouts = Rollouts(run, run.env, [3], ["w"], teacher)
    student = rollouts.build_policy()
    rollouts.reset()
    [seg] = rollouts.collect(student, 0)
    [later] = rollouts.collect(student, 1)  # the share is 0 from teacher_share_updates on
    rollouts.close()
    labels = seg.arrays["teacher"]
    assert labels.shape == (12, label_width("discrete", N_ACTIONS)) and labels.dtype == np.float32
    assert np.all(labels.argmax(axis=1) == 7)
    assert np.all(seg.arrays["actions"] == 7) == taught
    assert not np.all(later.arrays["actions"] == 7)  # the student's own draws over 10 actions
    back = decode_segment(encode_segment(seg), "s", student.obs_shape, N_ACTIONS, teacher_width=labels.shape[1])
    np.testing.assert_array_equal(back.arrays["teacher"], labels)
    with pytest.raises(ProtocolError, match="bad_shape"):
        decode_segment(encode_segment(seg), "s", student.obs_shape, N_ACTIONS, teacher_width=4)
    with pytest.raises(ValueError, match="needs a teacher"):
        Rollouts(run, run.env, [3], ["w"])


def test_continuous_labels_carry_the_teacher_s_means_and_standard_deviations() -> None:
    teacher = StatePolicy(STATE_SIZE, "continuous", action_low=(-30.0, 0.5), action_high=(30.0, 4.0))
    states = np.zeros((3, STATE_SIZE), np.float32)
    labels, actions = Teacher(teacher, seed=1).act(states)
    with torch.no_grad():
        mean, _ = teacher(torch.from_numpy(states))
    np.testing.assert_allclose(labels[:, :2], mean.numpy(), atol=1e-6)
    np.testing.assert_allclose(labels[:, 2:], np.tile([30.0, 1.75], (3, 1)), atol=1e-6)  # half ranges, exp(0)
    assert actions.shape == (3, 2) and actions.dtype == np.float32 and not np.allclose(actions, labels[:, :2])


# --- end to end: the trainer, a worker, Redis and the store ---------------------------------------------------------


def _hyperparams(folder: Path) -> str:
    path = folder / "hyperparameters.json"
    path.write_text(json.dumps({"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 1, "lr": 1e-3}))
    return str(path)


def _iterate(trainer: Trainer, worker: RolloutWorker) -> dict:
    """Collect until the trainer has a batch, then train once; the worker takes the new policy."""
    for _ in range(80):
        if trainer.ready():
            break
        worker.push(worker.collect())
        trainer.read(block_ms=100)
    assert trainer.ready(), "not enough episodes for an iteration"
    stats = trainer.train()
    assert worker.poll_policy()
    return stats


@pytest.mark.slow(reason="trains a teacher and a student through a real Redis and store: over 10 s")
def test_a_teacher_trains_on_states_and_a_student_distills_it_then_runs_ppo(redis_url, run_id, tmp_path):
    store = str(tmp_path / "store")
    runs = RunStore(open_store(store))
    hp = _hyperparams(tmp_path)
    base, files = build_run(run_id, track=STRAIGHT_TRACK, hyperparams=hp)
    base = base.model_copy(update={"segment_steps": 16})

    teacher_id = f"{run_id}-teacher"
    trainer = Trainer(
        teacher_run(base.model_copy(update={"run_id": teacher_id})), TrainerOptions(redis_url, store, run_files=files)
    )
    trainer.start()
    worker = RolloutWorker(WorkerOptions(teacher_id, redis_url, store, worker_index=0))
    try:
        worker.start()
        assert isinstance(trainer.model, StatePolicy) and isinstance(worker.model, StatePolicy)
        stats = _iterate(trainer, worker)
        assert trainer.version == 1 and trainer.stats.dropped == {} and "policy_loss" in stats
    finally:
        worker.close()
        trainer.close()
    # The evaluator drives the teacher's checkpoint on states, as any run's.
    (tmp_path / "eval").mkdir()
    teacher_cfg = runs.read_config(teacher_id)
    env_cfg = localize_env(teacher_cfg, runs, tmp_path / "eval")
    record = evaluate_checkpoint(runs, teacher_cfg, env_cfg, 1, EvalSettings(episodes=1, both_directions=False))
    assert record["episodes"] == 1 and record["trials"][0]["steps"] >= 1
    assert teacher_checkpoint(runs, teacher_id) == 1  # no best yet: the latest trained version
    # racer eval --video films a teacher's trial with what the camera would have seen.
    settings = EvalSettings(episodes=1, both_directions=False)
    video = write_video(runs, teacher_cfg, env_cfg, 1, settings, path=tmp_path / "teacher.mp4")
    assert video["frames"] >= 2 and (tmp_path / "teacher.mp4").stat().st_size > 0
    # A teacher cannot be exported to a car: it needs the car's state.
    with pytest.raises(UserError, match="privileged teacher"):
        export_onnx(runs, teacher_id, "latest", tmp_path / "t.onnx")

    distill = DistillConfig(teacher=f"{teacher_id}:1", updates=1, teacher_share_updates=1)
    student = Trainer(base.model_copy(update={"distill": distill}), TrainerOptions(redis_url, store, run_files=files))
    student.start()
    worker = RolloutWorker(WorkerOptions(run_id, redis_url, store, worker_index=0))
    try:
        worker.start()
        assert json.loads(runs.read_file(run_id, TEACHER_META_FILE))["version"] == 1
        assert runs.read_file(run_id, TEACHER_FILE) == runs.load_checkpoint(teacher_id, 1)[0]
        assert isinstance(student.model, ActorCritic)
        first = _iterate(student, worker)  # version 0 -> 1: distillation
        assert "distill_kl" in first and np.isfinite(first["distill_kl"]) and "policy_loss" not in first
        second = _iterate(student, worker)  # version 1 -> 2: PPO on the reward
        assert "policy_loss" in second and student.stats.dropped == {}
    finally:
        worker.close()
        student.close()
    # The student is a camera network like any racer model: it exports, and loads as DeepRacer's network.
    written = export_onnx(runs, run_id, "latest", tmp_path / "s.onnx")
    assert (tmp_path / "s.onnx").stat().st_size > 0 and written
    model, _ = load_policy(runs, run_id, load_action_space(env_cfg.action_space), "latest")
    assert isinstance(model, ActorCritic)


@pytest.mark.slow(reason="starts racer train --teacher: two stages of real processes, about 2 minutes")
def test_racer_train_teacher_trains_both_stages_end_to_end(tmp_path):
    store = tmp_path / "store"
    hp = _hyperparams(tmp_path)
    cmd = [sys.executable, "-m", "racer", "train", "--teacher", "--time-limit", "100s", "--teacher-time", "45s"]
    cmd += ["--workers", "1", "--track", STRAIGHT_TRACK, "--hyperparams", hp, "--store", str(store)]
    cmd += ["--run-id", "tt", "--distill-updates", "1", "--eval-episodes", "1"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=400)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    runs = RunStore(open_store(str(store)))
    assert runs.read_config("tt-teacher").env.observation == "state"
    student = runs.read_config("tt")
    assert student.env.observation == "sensors" and student.distill is not None
    source, _, version = student.distill.teacher.partition(":")
    assert source == "tt-teacher" and int(version) >= 1
    assert runs.read_file("tt", TEACHER_FILE) == runs.load_checkpoint("tt-teacher", int(version))[0]
    assert runs.newest_whole("tt") >= 1, out.stdout[-2000:]
    assert "teacher tt-teacher" in out.stdout and "student tt" in out.stdout
    again = [*cmd[:5], "--resume", "--run-id", "tt", "--store", str(store)]
    refused = subprocess.run(again, capture_output=True, text=True, timeout=120)
    assert refused.returncode == 2 and "--teacher starts a new run" in refused.stderr


# --- the benches' comparison ------------------------------------------------------------------------------------


def _figures(best: float | None, robust_s: float | None, teacher_best: float | None = None) -> dict:
    figures = {
        "time_to_robust_s": robust_s,
        "env_steps_to_robust": None if robust_s is None else int(robust_s * 50),
        "best_robust_lap_s": best,
        "ratio_to_limit": None if best is None else best / 6.0,
        "final_completion": 1.0,
        "late_robust_lap_s": best,
        "drift_after_best": 1.0,
        "collapses": 1,
        "collapses_recovered": 0,
        "ratio_at_minutes": {
            "5": None if best is None else best / 6.0 + 0.1,
            "10": None if best is None else best / 6.0,
        },
    }
    if teacher_best is not None:
        figures["teacher"] = {"ratio_to_limit": teacher_best / 6.0, "time_to_robust_s": 30.0, "env_steps": 90000}
        figures["student_gap"] = None if best is None else best / teacher_best
    return figures


def test_bench_race_sets_the_teacher_block_beside_the_plain_one() -> None:
    from racer.bench.race import seed_block, teacher_block

    plain = seed_block([_figures(9.0, 300.0), _figures(None, None), _figures(7.5, 500.0)])
    assert plain["median_ratio_to_limit"] == plain["ratio_to_limit"] == pytest.approx((9.0 + 7.5) / 2 / 6.0)
    assert plain["robust_seeds"] == 2 and plain["collapses"] == 3 and plain["env_steps_to_robust"] == 20000
    taught = teacher_block([_figures(6.6, 120.0, 6.0), _figures(7.2, 100.0, 6.3), _figures(6.9, 140.0, 6.9)])
    assert taught["median_ratio_to_limit"] == pytest.approx(6.9 / 6.0) and taught["time_to_robust_s"] == 120.0
    assert taught["teacher_ratio_to_limit"] == pytest.approx(6.3 / 6.0)
    assert taught["student_gap"] == pytest.approx(1.1)  # 6.6/6.0, 7.2/6.3 = 1.143, 6.9/6.9: the median
    assert taught["teacher_time_to_robust_s"] == 30.0 and taught["teacher_env_steps"] == 90000
    assert taught["median_ratio_at_minutes"] == pytest.approx({"5": 6.9 / 6.0 + 0.1, "10": 6.9 / 6.0})


def test_the_best_robust_lap_is_read_at_5_10_and_30_minutes() -> None:
    from racer.bench.race import ratio_at_minutes

    curve = [
        {"time_s": 100.0, "completion": 1.0, "mean_lap_s": 9.0},
        {"time_s": 250.0, "completion": 0.9, "mean_lap_s": 6.0},  # not robust: not counted
        {"time_s": 290.0, "completion": 1.0, "mean_lap_s": 7.5},
        {"time_s": 540.0, "completion": 1.0, "mean_lap_s": 6.6},
    ]
    assert ratio_at_minutes(curve, 6.0, 600.0) == {"5": 7.5 / 6.0, "10": 6.6 / 6.0}  # 30 min: past the budget
    assert ratio_at_minutes(curve[1:2], 6.0, 1800.0) == {"5": None, "10": None, "30": None}


def test_bench_train_reports_the_teacher_s_time_to_lap_and_its_speedup() -> None:
    from racer.bench.train import BenchTrainSettings, LapRun, summarize_bench

    def lap(system: str, seed: int, time_s: float | None) -> LapRun:
        lapped = time_s is not None
        return LapRun(
            system, seed, lapped=lapped, time_to_lap_s=time_s, env_steps_to_lap=int(time_s * 40) if lapped else None,
            wall_s=time_s or 600.0, curve=[], batch_steps=400, confirmed_s=time_s + 5.0 if lapped else None,
        )  # fmt: skip

    settings = BenchTrainSettings(seeds=[0, 1, 2], time_limit_s=600.0, sb3=False, teacher=True)
    runs = [lap("racer", 0, 300.0), lap("teacher", 0, 90.0), lap("racer", 1, None), lap("teacher", 1, 100.0)]
    runs += [lap("racer", 2, 240.0), lap("teacher", 2, 80.0)]
    out = summarize_bench(runs, settings)
    assert out["time_to_lap_s"] == 270.0 and out["time_to_lap_bound_s"] == 300.0 and out["lapped"] == "2/3"
    assert out["teacher"]["time_to_lap_s"] == 90.0 and out["teacher"]["lapped"] == "3/3"
    assert out["teacher"]["speedup"] == pytest.approx(300.0 / 90.0)
    assert len(out["runs"]) == 6 and "runs" not in out["teacher"]


@pytest.mark.slow(reason="starts racer train --teacher and stops it: about 30 s of real processes")
def test_ctrl_c_in_the_teacher_s_stage_stops_the_whole_command(tmp_path):
    store = tmp_path / "store"
    cmd = [sys.executable, "-m", "racer", "train", "--teacher", "--time-limit", "300s", "--teacher-time", "200s"]
    cmd += ["--workers", "1", "--track", STRAIGHT_TRACK, "--store", str(store), "--run-id", "cc", "--no-eval"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    runs = RunStore(open_store(str(store)))
    end = time.monotonic() + 120
    while time.monotonic() < end and not (runs.newest_whole("cc-teacher") or 0) >= 1:
        time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=120)
    assert "teacher cc-teacher" in out and "student cc:" not in out, out[-2000:]
    assert "stopped in the teacher's stage" in out and runs.newest_whole("cc") is None
