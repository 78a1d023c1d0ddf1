"""Trainer and rollout worker against a real Redis and a real store (a directory, and S3 via moto)."""

import json

import numpy as np
import pytest
import redis
import torch

from common.defaults import STRAIGHT_TRACK
from common.keys import Keys
from common.protocol import PolicyVersion
from common.weights import acting_from_bytes, acting_to_bytes, checkpoint_from_bytes
from model_store import RunStore, open_store
from model_store.runs import METRICS_FILE, acting_key
from racer.runconfig import build_run
from rollout_worker.worker import RolloutWorker, WorkerOptions
from tests.conftest import S3_BUCKET
from trainer.device import resolve_device
from trainer.precision import bf16_is_fast, fastest
from trainer.process import Trainer, TrainerOptions


@pytest.fixture
def hp_file(tmp_path):
    path = tmp_path / "hyperparameters.json"
    hp = {"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2, "lr": 0.001, "discount_factor": 0.99}
    path.write_text(json.dumps(hp))
    return str(path)


def start(run_id, redis_url, store, hp_file, **run_updates):
    run, files = build_run(run_id, track=STRAIGHT_TRACK, hyperparams=hp_file)
    run = run.model_copy(update={"segment_steps": 16, **run_updates})
    trainer = Trainer(run, TrainerOptions(redis_url, store, run_files=files))
    trainer.start()
    worker = RolloutWorker(WorkerOptions(run_id, redis_url, store, worker_index=0))
    worker.start()
    return trainer, worker


def fill(trainer, worker, max_segments=40):
    """Push segments until the trainer has enough episodes for an iteration."""
    for _ in range(max_segments):
        worker.push(worker.collect())
        trainer.read(block_ms=100)
        if trainer.ready():
            return
    raise AssertionError("not enough episodes for an iteration")


def test_trainer_publishes_v0_and_worker_pushes_segments(redis_url, run_id, tmp_path, hp_file):
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, hp_file)
    r, keys = redis.Redis.from_url(redis_url), Keys(run_id)
    assert PolicyVersion.from_json(r.get(keys.policy)).version == 0
    runs = RunStore(open_store(store))
    assert runs.pointer(run_id, "latest")["version"] == 0
    for name in ("config.json", "reward_function.py", "model_metadata.json", "hyperparameters.json"):
        assert runs.read_file(run_id, name)
    assert worker.policy_version == 0
    worker.push(worker.collect())
    assert trainer.read(block_ms=500) == 1
    assert trainer.stats.env_steps == 16
    heartbeat = json.loads(r.get(keys.heartbeat(worker.worker_id)))
    assert heartbeat["segments"] == 1 and 0 < r.ttl(keys.heartbeat(worker.worker_id)) <= 16
    assert [w["worker_id"] for w in trainer.workers()] == [worker.worker_id]
    worker.close()


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_an_iteration_publishes_a_version_the_worker_switches_to(redis_url, run_id, tmp_path, hp_file):
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, hp_file)
    fill(trainer, worker)
    stats = trainer.train()
    assert all(np.isfinite(v) for v in stats.values())
    assert trainer.version == 1
    runs = RunStore(open_store(store))
    assert [c["version"] for c in runs.list_checkpoints(run_id)] == [0, 1]
    rows = [json.loads(line) for line in runs.read_file(run_id, METRICS_FILE).decode().splitlines()]
    assert rows[0]["iteration"] == 1 and rows[0]["episodes"] >= 2 and 0 <= rows[0]["mean_progress"] <= 100
    assert worker.poll_policy() is True and worker.policy_version == 1
    # The worker acts with the version's acting copy: the trainer's weights rounded to float16, nothing else.
    acting = acting_from_bytes(acting_to_bytes(trainer.model.state_dict()))
    assert runs.load_acting(run_id, 1) == acting_to_bytes(trainer.model.state_dict())
    for name, tensor in acting.items():
        assert torch.equal(tensor, worker.model.state_dict()[name]), name
    assert worker.poll_policy() is False  # nothing newer
    # precision auto: where bf16 is native both were timed before this first update and the faster kept for good.
    status = trainer.status()
    if bf16_is_fast():
        assert set(status["precision_ms"]) == {"fp32", "bf16"}
        assert status["precision"] == fastest(status["precision_ms"]) and trainer.learner.precision_choices == (
            status["precision"],
        )
    else:
        assert status["precision_ms"] == {} and status["precision"] == "fp32"
    # --device auto: the trainer's network and Adam on the device it names, the checkpoints on the CPU for the worker.
    assert status["device"] == str(resolve_device("auto")) == str(next(trainer.model.parameters()).device)
    worker.close()


def test_stale_and_malformed_segments_are_dropped_and_counted(redis_url, run_id, tmp_path, hp_file):
    trainer, worker = start(run_id, redis_url, str(tmp_path / "store"), hp_file, max_policy_lag=0)
    [seg] = worker.collect()
    trainer.version = 1  # as if the trainer had moved on while the worker was still acting with v0
    worker.push([seg])
    r = redis.Redis.from_url(redis_url)
    r.xadd(Keys(run_id).segments, {"header": b"not json"})
    r.xadd(Keys(run_id).segments, {"junk": b"1"})
    assert trainer.read(block_ms=200) == 0
    assert trainer.stats.dropped == {"stale": 1, "bad_header": 1, "no_header": 1}
    assert trainer.stats.dropped_steps == seg.steps == 16  # the malformed entries' steps are unknown
    assert trainer.intake.buffer == []
    worker.close()


def test_a_segment_that_reaches_the_stream_twice_is_counted_once(redis_url, run_id, tmp_path, hp_file):
    """A push cut off mid-way is retried while TCP may still deliver the first copy: the second is dropped."""
    trainer, worker = start(run_id, redis_url, str(tmp_path / "store"), hp_file)
    segments = worker.collect()
    worker.push(segments)
    worker.push(segments)  # the same bytes again, as a late first copy would arrive
    worker.push(worker.collect())
    assert trainer.read(block_ms=500) == 2
    assert trainer.stats.dropped == {"duplicate": 1}
    assert trainer.stats.by_worker == {worker.worker_id: 2} and trainer.stats.env_steps == 32
    worker.close()


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_resume_restores_version_steps_and_optimizer(redis_url, run_id, tmp_path, hp_file):
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, hp_file)
    fill(trainer, worker)
    trainer.train()
    worker.close()
    again = Trainer(trainer.run, TrainerOptions(redis_url, store, resume=True))
    again.start()
    assert again.version == 1 and again.stats.env_steps == trainer.stats.env_steps
    before = trainer.optimizer.state_dict()["state"]
    after = again.optimizer.state_dict()["state"]
    assert before.keys() == after.keys() and torch.equal(before[0]["exp_avg"], after[0]["exp_avg"])
    assert len(again.reporter.metrics) == 1


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_a_worker_of_a_run_from_before_acting_copies_loads_the_checkpoint(redis_url, run_id, tmp_path, hp_file):
    """A resumed older run has no acting copy of its newest version: workers load the checkpoint itself (float32),
    and the next version the resumed trainer writes has its acting copy again."""
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, hp_file)
    fill(trainer, worker)
    trainer.train()
    worker.close()
    runs = RunStore(open_store(store))
    for version in (0, 1):  # as an older trainer left them
        runs.store.delete(acting_key(run_id, version))
    again = Trainer(trainer.run, TrainerOptions(redis_url, store, resume=True))
    again.start()
    late = RolloutWorker(WorkerOptions(run_id, redis_url, store, worker_index=1))
    late.start()
    assert late.policy_version == 1
    for name, tensor in trainer.model.state_dict().items():
        assert torch.equal(tensor, late.model.state_dict()[name]), name
    fill(again, late)
    again.train()
    assert runs.load_acting(run_id, 2) is not None
    late.close()


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_only_the_newest_checkpoint_keeps_the_optimizer_state(redis_url, run_id, tmp_path, hp_file):
    """Adam's state is twice the weights: a run keeps it for the checkpoint a resume reads, not for every one."""
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, hp_file)
    for _ in range(3):
        fill(trainer, worker)
        trainer.train()
        worker.poll_policy()
    worker.close()
    runs = RunStore(open_store(store))
    assert [runs.load_optimizer(run_id, v) is not None for v in (1, 2, 3)] == [False, False, True]
    payload, meta = runs.load_checkpoint(run_id, 3)
    assert checkpoint_from_bytes(payload)[1] is None  # the weights alone
    optimizer = runs.load_optimizer(run_id, 3)
    assert 1.9 < len(optimizer) / len(payload) < 2.2  # Adam's two moments per weight
    assert meta["size_bytes"] == len(payload)


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_the_loop_works_with_an_s3_store(redis_url, run_id, s3_server, hp_file, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # TensorBoard files of an S3 run go to ./runs/<id>/tensorboard
    store = f"s3://{S3_BUCKET}/it"
    run, files = build_run(run_id, track=STRAIGHT_TRACK, hyperparams=hp_file)
    run = run.model_copy(update={"segment_steps": 16})
    trainer = Trainer(run, TrainerOptions(redis_url, store, s3_endpoint=s3_server, run_files=files))
    trainer.start()
    worker = RolloutWorker(WorkerOptions(run_id, redis_url, store, s3_endpoint=s3_server))
    worker.start()
    fill(trainer, worker)
    trainer.train()
    assert worker.poll_policy() and worker.policy_version == 1
    runs = RunStore(open_store(store, s3_server))
    assert runs.pointer(run_id, "latest")["version"] == 1
    assert list((tmp_path / "runs" / run_id / "tensorboard").glob("events.out.tfevents.*"))
    worker.close()


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_continuous_actions_and_frame_stacking(redis_url, run_id, tmp_path):
    meta = tmp_path / "model_metadata.json"
    meta.write_text(
        json.dumps(
            {
                "action_space": {"steering_angle": {"low": -20.0, "high": 20.0}, "speed": {"low": 0.5, "high": 1.5}},
                "action_space_type": "continuous",
            }
        )
    )
    hp = tmp_path / "hp.json"
    hp.write_text(json.dumps({"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2, "stack_size": 2}))
    store = str(tmp_path / "store")
    run, files = build_run(run_id, track=STRAIGHT_TRACK, action_space=str(meta), hyperparams=str(hp))
    run = run.model_copy(update={"segment_steps": 16})
    trainer = Trainer(run, TrainerOptions(redis_url, store, run_files=files))
    trainer.start()
    worker = RolloutWorker(WorkerOptions(run_id, redis_url, store))
    worker.start()
    [seg] = worker.collect()
    assert seg.arrays["obs"].shape == (16, 120, 160, 2)
    assert seg.arrays["actions"].dtype == np.float32 and seg.arrays["actions"].shape == (16, 2)
    worker.push([seg])
    fill(trainer, worker)
    assert np.isfinite(list(trainer.train().values())).all()
    assert worker.poll_policy() and worker.policy_version == 1
    worker.close()


@pytest.mark.slow(reason="runs racer train with its real processes")
def test_models_ls_lists_the_checkpoints_as_json(redis_url, run_id, tmp_path, hp_file):
    from typer.testing import CliRunner

    from racer.cli import app

    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, hp_file)
    fill(trainer, worker)
    trainer.train()
    worker.close()
    result = CliRunner().invoke(app, ["models", "ls", "--store", store, "--json", "-"])
    assert result.exit_code == 0, result.output
    rows = json.loads(result.output)
    assert [(r["run_id"], r["version"]) for r in rows] == [(run_id, 0), (run_id, 1)]
    assert rows[1]["latest"] and rows[1]["env_steps"] == trainer.stats.env_steps and rows[0]["env_steps"] == 0


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_tensorboard_scalars_and_checkpoint_pruning(redis_url, run_id, tmp_path, hp_file):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, hp_file, keep_checkpoints=2)
    for _ in range(3):
        fill(trainer, worker)
        trainer.train()
        worker.poll_policy()
    worker.close()
    trainer.tb.flush()
    runs = RunStore(open_store(store))
    assert [c["version"] for c in runs.list_checkpoints(run_id)] == [2, 3]  # the window of 2; 0 and 1 pruned
    assert [runs.load_acting(run_id, v) is not None for v in range(4)] == [False, False, True, True]  # with them
    events = EventAccumulator(str(tmp_path / "store" / "runs" / run_id / "tensorboard"))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    for tag in (
        "trainer/policy_loss",
        "trainer/value_loss",
        "trainer/entropy",
        "trainer/approx_kl",
        "trainer/clip_fraction",
        "trainer/explained_variance",
        "trainer/learning_rate",
        "trainer/policy_lag",
        "trainer/steps_per_s",
        "episode/reward",
        "episode/progress",
        "episode/length",
    ):
        assert tag in tags, tag
    assert len(events.Scalars("trainer/policy_loss")) == 3
