"""Rollout workers with several envs (``--envs-per-worker K``) against a real Redis and store: K segments per collect,
one per env, each that env's consecutive steps, all acted by the policy version they carry; with K = 1 the worker
is the one-env worker it always was."""

from __future__ import annotations

import copy
import csv
import io
import json
import subprocess
import sys

import numpy as np
import pytest
import redis
import torch
from deepracer.logs import DeepRacerLog

from common.defaults import STRAIGHT_TRACK
from common.errors import OptionError
from common.keys import Keys
from common.policy import build_policy
from common.protocol import decode_segment, encode_segment
from common.sensors import observation_spec
from common.weights import acting_from_bytes
from model_store import RunStore, open_store
from racer.runconfig import build_run
from rollout_worker.onnx_policy import OnnxPolicy
from rollout_worker.worker import RolloutWorker, WorkerOptions
from tests.test_bad_input import assert_one_line_error, racer
from trainer.process import Trainer, TrainerOptions

HP = {"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2, "lr": 0.001, "discount_factor": 0.99}
SEED = 7


@pytest.fixture
def setup(redis_url, run_id, tmp_path):
    """A started trainer (policy v0 published) and a function that starts workers of its run."""
    (tmp_path / "hp.json").write_text(json.dumps(HP))
    store = str(tmp_path / "store")
    run, files = build_run(run_id, track=STRAIGHT_TRACK, hyperparams=str(tmp_path / "hp.json"), seed=SEED)
    trainer = Trainer(run.model_copy(update={"segment_steps": 16}), TrainerOptions(redis_url, store, run_files=files))
    trainer.start()
    workers: list[RolloutWorker] = []

    def worker(**opts) -> RolloutWorker:
        w = RolloutWorker(WorkerOptions(run_id, redis_url, store, **opts))
        workers.append(w)
        w.start()
        return w

    yield trainer, worker, store
    for w in workers:
        w.close()


def _network(trainer: Trainer, store: str, version: int) -> torch.nn.Module:
    """The trainer's network with the weights workers act with at ``version`` (its acting copy, common/policy.py:
    acting_to_bytes), in fp32 as workers act (the trainer's own may train in bf16)."""
    acting = RunStore(open_store(store)).load_acting(trainer.run.run_id, version)
    model = copy.deepcopy(trainer.model)
    model.load_state_dict(acting_from_bytes(acting))
    model.set_trunk_precision("fp32")
    return model.eval()


def test_k_envs_push_k_segments_each_of_one_envs_consecutive_steps(setup):
    trainer, start_worker, _ = setup
    worker = start_worker(worker_index=2, envs_per_worker=3)
    run_id, shape, n_actions = trainer.run.run_id, trainer.learner.obs_shape, trainer.learner.n_actions
    per_env: dict[int, list] = {j: [] for j in range(3)}
    for _ in range(4):
        segments = worker.collect()
        assert [s.worker_id for s in segments] == [f"{worker.worker_id}/{j}" for j in range(3)]
        assert [s.env_seed for s in segments] == [SEED + 2000 + j for j in range(3)]  # seed + 1000·k + j
        assert [s.policy_version for s in segments] == [0, 0, 0]
        worker.push(segments)
        for j, seg in enumerate(segments):
            per_env[j].append(decode_segment(encode_segment(seg), run_id, shape, n_actions))
    assert trainer.read(block_ms=500) == 12 and trainer.stats.dropped == {}
    assert trainer.stats.by_worker == {f"{worker.worker_id}/{j}": 4 for j in range(3)}
    beat = json.loads(redis.Redis.from_url(worker.opts.redis_url).get(Keys(run_id).heartbeat(worker.worker_id)))
    assert beat["segments"] == 12 and beat["env_steps"] == 3 * 4 * 16 == worker.env_steps
    ended = 0
    for segments in per_env.values():
        ids = np.concatenate([s.arrays["episode_id"] for s in segments])
        ends = np.concatenate([s.arrays["terminated"] | s.arrays["truncated"] for s in segments]).astype(int)
        assert ids[0] == 0 and (np.diff(ids) == ends[:-1]).all()  # the env's next episode right after each end
        summaries = [e.episode_id for s in segments for e in s.episodes]
        assert summaries == list(range(ends.sum()))
        for a, b in zip(segments, segments[1:], strict=False):  # the env goes on where its last segment stopped
            if not (a.arrays["terminated"][-1] or a.arrays["truncated"][-1]):
                assert np.array_equal(a.arrays["next_obs"][0], b.arrays["obs"][0])
        ended += int(ends.sum())
    assert ended >= 1  # a random policy leaves the straight track within 64 steps in some env
    assert worker.episodes == ended


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_every_step_is_acted_by_its_segments_version_and_switches_come_between_collects(setup):
    trainer, start_worker, store = setup
    worker = start_worker(envs_per_worker=3)
    for _ in range(40):
        worker.push(worker.collect())
        trainer.read(block_ms=100)
        if trainer.ready():
            break
    trainer.train()
    assert trainer.version == 1
    before = worker.collect()  # collected after the update but before polling: still v0
    assert worker.poll_policy() and worker.policy_version == 1
    after = worker.collect()
    assert [s.policy_version for s in before] == [0] * 3 and [s.policy_version for s in after] == [1] * 3
    networks = {v: _network(trainer, store, v) for v in (0, 1)}
    for seg in before + after:
        obs, actions = torch.from_numpy(seg.arrays["obs"]), torch.from_numpy(seg.arrays["actions"])
        with torch.no_grad():
            logp, values = {}, {}
            for v, net in networks.items():
                logp[v], _, values[v] = net.evaluate(obs, actions)
        v = seg.policy_version
        assert np.allclose(values[v].numpy(), seg.arrays["values"], atol=1e-4)
        assert np.allclose(logp[v].numpy(), seg.arrays["logp"], atol=1e-4)
        assert not np.allclose(values[1 - v].numpy(), seg.arrays["values"], atol=1e-4)  # the versions differ
    for b, a in zip(before, after, strict=True):  # each env drives on across the switch
        end = int(b.arrays["terminated"][-1] or b.arrays["truncated"][-1])
        assert a.arrays["episode_id"][0] == b.arrays["episode_id"][-1] + end


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_one_env_is_the_one_env_worker_and_env_0_keeps_its_seed(setup):
    _, start_worker, _ = setup
    torch.manual_seed(11)
    given = start_worker(envs_per_worker=1)
    first = [given.collect() for _ in range(3)]
    torch.manual_seed(11)
    default = start_worker()  # the options a worker had before --envs-per-worker
    second = [default.collect() for _ in range(3)]
    for segs_a, segs_b in zip(first, second, strict=True):
        assert len(segs_a) == len(segs_b) == 1
        a, b = segs_a[0], segs_b[0]
        assert (a.worker_id, a.env_seed, a.policy_version) == (b.worker_id, b.env_seed, 0) == (given.worker_id, SEED, 0)
        assert a.arrays.keys() == b.arrays.keys() and a.episodes == b.episodes
        for name in a.arrays:
            assert np.array_equal(a.arrays[name], b.arrays[name]), name
    three = start_worker(envs_per_worker=3)
    [seg0, *_] = three.collect()
    assert seg0.env_seed == SEED and np.array_equal(seg0.arrays["obs"][0], first[0][0].arrays["obs"][0])


def test_the_envs_share_one_simtrace_csv_with_episodes_numbered_apart(setup, tmp_path):
    trainer, start_worker, store = setup
    worker = start_worker(envs_per_worker=3)
    for _ in range(4):
        worker.collect()
    steps, finished = worker.env_steps, worker.episodes
    worker.close()  # uploads the iteration, the episodes in progress included
    folder = tmp_path / "store" / "runs" / trainer.run.run_id
    assert sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*-iteration.csv")) == [
        "0/training-simtrace/0-iteration.csv"
    ]
    rows = list(csv.DictReader(io.StringIO((folder / "0/training-simtrace/0-iteration.csv").read_text())))
    order = [int(r["episode"]) for r in rows]
    episodes = list(dict.fromkeys(order))
    assert episodes == sorted(episodes) and order == sorted(order)  # whole episodes, in the order of their numbers
    # The episodes in progress are in (but for one that has only just started), each with its prepare row.
    assert finished < len(episodes) <= finished + 3 and len(rows) == steps + len(episodes)
    for j in range(3):  # env j's n-th episode is n·3 + j
        mine = [e for e in episodes if e % 3 == j]
        assert mine == [j + 3 * n for n in range(len(mine))]
    for e in episodes:
        assert [float(r["steps"]) for r in rows if int(r["episode"]) == e][0] == 1.0
    log = DeepRacerLog(str(folder))
    log.load()
    df = log.dataframe()
    assert df.groupby(["worker", "episode"]).ngroups == len(episodes) and len(df) == len(rows)


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_bad_envs_per_worker_is_one_line(tmp_path):
    with pytest.raises(OptionError, match="--envs-per-worker must be an integer from 1 to 1000, got 0"):
        WorkerOptions("run", "redis://127.0.0.1:1/0", envs_per_worker=0)
    worker = ["worker", "--run-id", "r", "--redis", "redis://127.0.0.1:1/0", "--envs-per-worker", "0"]
    expected = "Input should be greater than or equal to 1 (got '0')"
    for args in (worker, ["train", "--envs-per-worker", "0"]):
        out = racer(args, tmp_path)
        assert_one_line_error(out, expected)
        assert "Invalid value for '--envs-per-worker'" in out.stderr
    assert not (tmp_path / "runs").exists()
    bench = ["bench", "worker", "--envs-per-worker", "1,0"]
    assert_one_line_error(
        racer(bench, tmp_path), "--envs-per-worker takes distinct integers from 1 to 1000 (got '1,0')"
    )


@pytest.mark.slow(reason="starts real racer processes")
def test_bench_worker_json(tmp_path):
    out = tmp_path / "bench.json"
    args = ["bench", "worker", "--envs-per-worker", "1,2", "--seconds", "1", "--repeats", "1", "--json", str(out)]
    result = subprocess.run([sys.executable, "-m", "racer", *args], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    data = json.loads(out.read_text())
    assert set(data["per_k"]) == {"1", "2"} and data["acting"] == "onnxruntime"
    for figures in data["per_k"].values():
        assert figures["steps_per_s"] > 0 and len(figures["steps_per_s_runs"]) == 1
        assert set(figures["us_per_step"]) == {"act", "env", "bookkeeping"}
        assert all(v > 0 for v in figures["us_per_step"].values())
    assert data["per_k"]["1"]["speedup_vs_first"] == 1.0
    act = data["act_ms"]
    assert set(act["torch"]) == set(act["onnxruntime"]) == {"1", "2"} and act["same_actions"] is True
    assert all(d < 1e-4 for d in act["max_abs_diff"].values())
    assert data["env_parts_us"]["camera"] > 0 and data["machine"]["cpu"]


@pytest.mark.slow(reason="runs racer train with its real processes")
def test_racer_train_runs_workers_with_several_envs(tmp_path, redis_url):
    (tmp_path / "hp.json").write_text(json.dumps(HP))
    args = ["train", "--workers", "1", "--envs-per-worker", "2", "--track", STRAIGHT_TRACK, "--run-id", "k2"]
    args += ["--hyperparams", "hp.json", "--time-limit", "40s", "--no-eval", "--redis", redis_url]
    result = subprocess.run([sys.executable, "-m", "racer", *args], cwd=tmp_path, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 workers × 2 envs" in result.stdout
    logs = tmp_path / "runs" / "k2" / "logs"
    worker_log, trainer_log = (logs / "worker-0.log").read_text(), (logs / "trainer.log").read_text()
    assert "2 env(s) on racer_straight, seeds [0, 1]" in worker_log
    assert "duplicate" not in trainer_log
    # Both envs' episodes are in the worker's one sim-trace folder (env j's n-th episode is 2n + j).
    traces = sorted((tmp_path / "runs" / "k2" / "0" / "training-simtrace").glob("*-iteration.csv"))
    episodes = {int(r["episode"]) for t in traces for r in csv.DictReader(io.StringIO(t.read_text()))}
    assert {e % 2 for e in episodes} == {0, 1}


@pytest.mark.parametrize(
    ("sensors", "space"),
    [
        (["FRONT_FACING_CAMERA"], {"kind": "discrete", "n": 10}),
        (["STEREO_CAMERAS", "LIDAR"], {"kind": "continuous", "low": [-30.0, 0.5], "high": [30.0, 4.0]}),
    ],
)
def test_the_onnx_copy_acts_as_the_network(sensors, space):
    """Same actions from the same random state, log-probs and values to float rounding, greedy actions too."""
    spec = observation_spec(sensors, 1)
    torch.manual_seed(0)
    model = build_policy(spec.camera_shape((120, 160)), space, sensors=sensors).eval()
    copy_ = OnnxPolicy(model)
    rng = np.random.default_rng(0)
    for batch in (1, 3):
        obs = rng.integers(0, 256, (batch, *model.obs_shape), dtype=np.uint8)
        lidar = rng.uniform(0.15, 1.0, (batch, spec.lidar_size)).astype(np.float32) if spec.lidar else None
        for deterministic in (False, True):
            out = {}
            for name, actor in (("torch", model), ("onnx", copy_)):
                torch.manual_seed(batch)
                out[name] = actor.act_numpy(obs, deterministic, lidar=lidar)
            (a_t, lp_t, v_t), (a_o, lp_o, v_o) = out["torch"], out["onnx"]
            assert a_t.dtype == a_o.dtype and a_t.shape == a_o.shape
            assert np.allclose(a_t, a_o, atol=1e-4) if space["kind"] == "continuous" else np.array_equal(a_t, a_o)
            assert np.allclose(lp_t, lp_o, atol=1e-4) and np.allclose(v_t, v_o, atol=1e-4)
    with pytest.raises(ValueError, match="LiDAR"):
        copy_.act_numpy(obs, lidar=None if spec.lidar else np.zeros((batch, 8), np.float32))
