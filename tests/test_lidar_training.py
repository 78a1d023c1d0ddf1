"""Stereo-camera and LiDAR runs through the whole loop: a rollout worker and the trainer against a real Redis and a
real store, then the evaluator on the trained checkpoint.

The observation contract under test (``common.sensors``): the env gives the camera part (H, W, 2 for the stereo
pair) and, with a LiDAR, the LiDAR vector beside it; the worker stacks the camera frames only, sends the LiDAR
vectors as the segment's ``lidar`` / ``next_lidar`` arrays; the trainer decodes them against the run's sensors,
batches them and trains; the evaluator drives the checkpoint with the LiDAR beside the camera; ``racer car`` reads a
stereo model's two cameras.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from common.action_space import load_action_space
from common.defaults import STRAIGHT_TRACK
from common.policy import action_space_spec, build_policy
from common.protocol import decode_segment, encode_segment
from common.sensors import LIDARS, check_lidar, observation_spec, split_observation
from common.weights import checkpoint_to_bytes, load_policy
from deploy.export import export_onnx
from model_store import RunStore, open_store
from model_store.localize import localize_env
from racer.evaluate import write_video
from racer.runconfig import build_run
from rollout_worker.worker import RolloutWorker, WorkerOptions
from sim.env import RacerEnv
from trainer.evaluator import EvalSettings, evaluate_checkpoint, run_trial
from trainer.process import Trainer, TrainerOptions

DISCRETE = [
    {"steering_angle": -20.0, "speed": 1.0},
    {"steering_angle": 0.0, "speed": 1.0},
    {"steering_angle": 20.0, "speed": 1.0},
]
CONTINUOUS = {"steering_angle": {"low": -20.0, "high": 20.0}, "speed": {"low": 0.5, "high": 1.5}}

# (sensors, action space, stack_size): the stereo pair with the 64-range LiDAR and discrete actions, two stacked
# frames (4 camera channels); the front camera with the 8-sector LiDAR and continuous actions.
RUNS = [
    (["STEREO_CAMERAS", "LIDAR"], DISCRETE, 2),
    (["FRONT_FACING_CAMERA", "SECTOR_LIDAR"], CONTINUOUS, 1),
]


def write_files(folder: Path, sensors: list[str], actions: list | dict, stack_size: int) -> tuple[str, str]:
    """model_metadata.json with ``sensors`` and a shallow network, hyperparameters.json for quick iterations."""
    meta = folder / "model_metadata.json"
    kind = "discrete" if isinstance(actions, list) else "continuous"
    meta.write_text(
        json.dumps(
            {
                "action_space": actions,
                "action_space_type": kind,
                "sensor": sensors,
                "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW",
                "training_algorithm": "clipped_ppo",
                "version": "5",
            }
        )
    )
    hp = folder / "hyperparameters.json"
    hp.write_text(
        json.dumps(
            {
                "batch_size": 32,
                "num_epochs": 1,
                "num_episodes_between_training": 2,
                "lr": 0.001,
                "discount_factor": 0.99,
                "stack_size": stack_size,
            }
        )
    )
    return str(meta), str(hp)


def start(run_id: str, redis_url: str, store: str, meta: str, hp: str) -> tuple[Trainer, RolloutWorker]:
    """A trainer (version 0 published) and one worker acting with it, on the short straight track."""
    run, files = build_run(run_id, track=STRAIGHT_TRACK, action_space=meta, hyperparams=hp)
    run = run.model_copy(update={"segment_steps": 16})
    trainer = Trainer(run, TrainerOptions(redis_url, store, run_files=files))
    trainer.start()
    worker = RolloutWorker(WorkerOptions(run_id, redis_url, store, worker_index=0))
    worker.start()
    return trainer, worker


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize(("sensors", "actions", "stack_size"), RUNS)
def test_a_lidar_run_pushes_lidar_segments_the_trainer_accepts_and_trains_on(
    sensors, actions, stack_size, redis_url, run_id, tmp_path
):
    meta, hp = write_files(tmp_path, sensors, actions, stack_size)
    spec = observation_spec(sensors, stack_size)
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, meta, hp)
    try:
        learner = trainer.learner
        assert learner.obs_spec == spec and learner.obs_shape == spec.camera_shape((120, 160))
        assert trainer.model.lidar_size == spec.lidar_size == LIDARS[sensors[1]].size
        [seg] = worker.collect()
        a = seg.arrays
        assert a["obs"].shape == (16, *learner.obs_shape) and a["next_obs"].shape == (1, *learner.obs_shape)
        assert a["lidar"].shape == (16, spec.lidar_size) and a["next_lidar"].shape == (1, spec.lidar_size)
        assert check_lidar(spec.lidar, a["lidar"]) is None and check_lidar(spec.lidar, a["next_lidar"]) is None
        # What goes on the wire decodes to the same arrays (the trainer's check, against the run's sensors).
        wire = decode_segment(encode_segment(seg), run_id, learner.obs_shape, learner.n_actions, spec.lidar)
        assert np.array_equal(wire.arrays["lidar"], a["lidar"])

        worker.push([seg])
        assert trainer.read(block_ms=500) == 1
        assert "lidar" in trainer.intake.buffer[0].arrays
        for _ in range(60):
            if trainer.ready():
                break
            worker.push(worker.collect())
            trainer.read(block_ms=100)
        assert trainer.ready(), "not enough episodes for an iteration"
        assert trainer.stats.dropped == {}
        stats = trainer.train()
        assert all(np.isfinite(v) for v in stats.values()), stats
        assert trainer.version == 1 and trainer.stats.dropped == {}
        assert worker.poll_policy() and worker.policy_version == 1
        worker.push(worker.collect())  # the worker acts on with the new policy, the trainer still accepts
        assert trainer.read(block_ms=500) == 1 and trainer.stats.dropped == {}
    finally:
        worker.close()


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_the_evaluator_drives_a_stereo_lidar_checkpoint(redis_url, run_id, tmp_path):
    sensors, actions, stack_size = RUNS[0]
    meta, hp = write_files(tmp_path, sensors, actions, stack_size)
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, meta, hp)
    worker.close()  # version 0 is checkpointed: the evaluator needs nothing more
    runs = RunStore(open_store(store))
    (tmp_path / "eval").mkdir()
    env_cfg = localize_env(trainer.run, runs, tmp_path / "eval")
    settings = EvalSettings(episodes=1, both_directions=True, action_noise=0.0)
    record = evaluate_checkpoint(runs, trainer.run, env_cfg, 0, settings)
    assert record["episodes"] == 2 and len(record["trials"]) == 2
    assert all(t["steps"] >= 1 and 0 <= t["progress"] <= 100 for t in record["trials"])

    # One trial alone (``racer eval``'s video path) drives the same way, and hands on_step the env's observations.
    model, _ = load_policy(runs, trainer.run, load_action_space(env_cfg.action_space), 0)
    env = RacerEnv(config=env_cfg)
    seen: list[tuple[tuple[int, ...], tuple[int, ...]]] = []

    def on_step(observation, info) -> None:
        camera, lidar = split_observation(observation)
        seen.append((camera.shape, lidar.shape))

    trial = run_trial(env, model, stack_size, 0, False, seed=1, deterministic=True, on_step=on_step)
    env.close()
    assert trial.steps >= 1 and len(seen) == trial.steps + 1 and set(seen) == {((120, 160, 2), (64,))}

    # racer eval's video: the stereo pair and the LiDAR, as the policy sees them.
    video = write_video(runs, trainer.run, env_cfg, 0, settings, path=tmp_path / "eval.mp4")
    assert video["frames"] >= 2 and (tmp_path / "eval.mp4").stat().st_size > 0


@pytest.mark.slow(reason="starts real racer processes")
def test_racer_car_drives_a_stereo_model_from_two_cameras(tmp_path):
    """``racer car --right-source``: the exported stereo model reads the left and right cameras in step."""
    meta, hp = write_files(tmp_path, ["STEREO_CAMERAS"], DISCRETE, 1)
    run, files = build_run("stereo", track=STRAIGHT_TRACK, action_space=meta, hyperparams=hp)
    runs = RunStore(open_store(str(tmp_path / "store")))
    for name, data in files.items():
        runs.write_file("stereo", name, data)
    runs.write_config(run)
    actions = load_action_space(meta)
    model = build_policy((120, 160, 2), action_space_spec(actions), run.policy, actions.sensor)
    runs.save_checkpoint("stereo", 0, checkpoint_to_bytes(model.state_dict()), {"env_steps": 0})
    onnx = tmp_path / "out" / "model.onnx"
    export_onnx(runs, "stereo", "latest", onnx)
    rng = np.random.default_rng(0)
    for side in ("left", "right"):
        writer = cv2.VideoWriter(str(tmp_path / f"{side}.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 15, (160, 120), False)
        for _ in range(5):
            writer.write(rng.integers(0, 256, (120, 160), np.uint8))
        writer.release()
    base = [sys.executable, "-m", "racer", "car", "--model", str(onnx), "--source", str(tmp_path / "left.avi")]
    out = subprocess.run(
        [*base, "--right-source", str(tmp_path / "right.avi"), "--out", str(tmp_path / "cmds.csv"), "--json", "-"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["frames"] == 5
    alone = subprocess.run([*base, "--out", str(tmp_path / "x.csv")], capture_output=True, text=True, timeout=120)
    assert alone.returncode == 2 and "give the right camera too" in alone.stderr, alone.stderr
