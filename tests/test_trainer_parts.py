"""The trainer's parts, each alone (``trainer/learner.py``, ``intake.py``, ``checkpoints.py``, ``guard.py``,
``reporting.py``), and the trainer's bounds: no simulator imported, no class over 250 lines."""

from __future__ import annotations

import ast
import json
import logging
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from common.action_space import ActionSpace, action_space_from_json, default_action_space
from common.config import EnvConfig, RunConfig
from common.deadline import Deadline
from common.defaults import STRAIGHT_TRACK
from common.hyperparams import Hyperparameters
from common.protocol import EpisodeSummary, EvaluationSummary, encode_segment
from common.retry import Outage
from common.sensors import camera_frame_size, observation_spec
from model_store import RunStore, is_transient, open_store
from model_store.runs import METRICS_FILE, checkpoint_key, evaluation_name
from tests.test_protocol import make_segment
from trainer.checkpoints import Checkpoints
from trainer.guard import BestEvaluation, CollapseGuard, Stability
from trainer.intake import SegmentIntake, Stats
from trainer.learner import Learner
from trainer.reporting import Reporter, WorkerWatch, metrics_row

ROOT = Path(__file__).resolve().parents[1]
LOG = logging.getLogger("test")
LIDAR_SPACE = {
    "action_space": {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 2}},
    "action_space_type": "continuous",
    "sensor": ["FRONT_FACING_CAMERA", "SECTOR_LIDAR"],
    "neural_network": "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW",
    "training_algorithm": "clipped_ppo",
    "version": "5",
}


def test_the_trainer_imports_nothing_from_sim() -> None:
    code = "import sys, trainer.process; print(sorted(m for m in sys.modules if m == 'sim' or m.startswith('sim.')))"
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


@pytest.mark.slow(reason="runs racer train with its real processes")
def test_the_trainer_role_under_racer_train_imports_nothing_from_sim(tmp_path: Path) -> None:
    """``racer trainer --config --files --options`` as ``racer train`` starts it, up to ``run_trainer``."""
    from racer.options import RunOptions
    from racer.runconfig import build_run

    run, files = build_run("role", track=STRAIGHT_TRACK)
    (tmp_path / "run.json").write_text(run.model_dump_json())
    (tmp_path / "options.json").write_text(RunOptions(run_id="role", time_limit_s=60).started().model_dump_json())
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    args = ["trainer", "--config", str(tmp_path / "run.json"), "--files", str(tmp_path)]
    args += ["--options", str(tmp_path / "options.json"), "--redis", "redis://127.0.0.1:1/0"]
    args += ["--store", str(tmp_path / "store")]
    code = (
        "import sys\n"
        "import trainer.process\n"
        "from typer.testing import CliRunner\n"
        "from racer.cli import app\n"
        "trainer.process.run_trainer = lambda run, opts, stop=None: print('deadline', opts.deadline.limit_s)\n"
        f"done = CliRunner().invoke(app, {args!r})\n"
        "print(done.exit_code, done.output.strip())\n"
        "print(sorted(m for m in sys.modules if m == 'sim' or m.startswith('sim.')))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines() == ["0 deadline 60.0", "[]"], done.stdout


def test_no_class_in_trainer_is_over_250_lines() -> None:
    sizes = {}
    for path in sorted((ROOT / "trainer").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                first = min([node.lineno, *(d.lineno for d in node.decorator_list)])
                sizes[f"{path.name}: {node.name}"] = int(node.end_lineno or 0) - first + 1
    assert "process.py: Trainer" in sizes and max(sizes.values()) <= 250, sizes


# --- the learner ---------------------------------------------------------------------------------------------------


def _run(**hp: object) -> RunConfig:
    return RunConfig(run_id="parts", env=EnvConfig(track=STRAIGHT_TRACK), hyperparams=Hyperparameters(**hp))


@pytest.mark.parametrize("space", [None, LIDAR_SPACE])
def test_the_learner_takes_the_shapes_the_env_gives_from_the_action_space_alone(space: dict | None, tmp_path) -> None:
    from sim.env import RacerEnv

    actions = default_action_space() if space is None else ActionSpace.model_validate(space)
    path = tmp_path / "model_metadata.json"
    path.write_text(actions.to_json())
    assert action_space_from_json(path.read_bytes()) == actions  # as the trainer reads the run's stored file
    learner = Learner(_run(), actions, torch.device("cpu"), "fp32")
    env = RacerEnv(config=EnvConfig(track=STRAIGHT_TRACK, action_space=str(path)))
    try:
        assert learner.obs_shape == learner.obs_spec.camera_shape(camera_frame_size(env.observation_space))
        assert learner.n_actions == (env.action_space.n if actions.discrete else None)
        assert learner.obs_spec == observation_spec(env.actions.sensor, 1)
    finally:
        env.close()


def test_the_learners_weights_follow_the_runs_seed() -> None:
    a, b = (Learner(_run(), default_action_space(), torch.device("cpu"), "fp32") for _ in range(2))
    mine, theirs = a.model.state_dict(), b.model.state_dict()
    assert mine.keys() == theirs.keys() and all(torch.equal(mine[k], theirs[k]) for k in mine)


def test_the_learning_rate_cools_down_towards_the_deadline_by_hand() -> None:
    learner = Learner(
        _run(lr=0.001, lr_cooldown=0.5, lr_final_fraction=0.1), default_action_space(), torch.device("cpu"), "fp32"
    )
    assert learner.learning_rate(0, 1.0, None) == pytest.approx(0.001)
    assert learner.learning_rate(0, 1.0, Deadline(at=time.time() + 80.0, limit_s=100.0)) == pytest.approx(0.001)
    left_25 = Deadline(at=time.time() + 25.0, limit_s=100.0)
    assert learner.learning_rate(0, 0.5, left_25) == pytest.approx(0.0005 * (0.1 + 0.9 * 0.5), rel=1e-3)
    learner.set_lr(0.123)
    assert learner.optimizer.param_groups[0]["lr"] == 0.123


# --- the intake ----------------------------------------------------------------------------------------------------


def _fields(seg) -> dict:
    return {k.encode(): v for k, v in encode_segment(seg).items()}


def test_the_intake_keeps_a_fresh_segment_and_counts_each_drop_by_reason() -> None:
    intake = SegmentIntake(
        SimpleNamespace(),
        "run-a",
        None,
        obs_shape=(120, 160, 1),
        n_actions=10,
        stats=Stats(),
    )
    seg = make_segment()  # policy version 3, 4 steps, one episode
    assert intake.accept(_fields(seg), version=3, floor=0, max_lag=0) == 1
    assert intake.accept(_fields(seg), version=3, floor=0, max_lag=0) == 0  # the same push twice
    assert intake.accept(_fields(make_segment(seed=1)), version=5, floor=0, max_lag=1) == 0
    assert intake.accept(_fields(make_segment(seed=2)), version=2, floor=0, max_lag=0) == 0
    assert intake.accept(_fields(make_segment(seed=3)), version=4, floor=4, max_lag=9) == 0
    assert intake.accept({b"header": b"{"}, version=3, floor=0, max_lag=0) == 0
    stats = intake.stats
    assert (stats.env_steps, stats.episodes, stats.by_worker) == (4, 1, {"w-0": 1})
    assert stats.dropped == {"duplicate": 1, "stale": 1, "future_version": 1, "rolled_back": 1, "bad_header": 1}
    assert stats.dropped_steps == 16  # the four decoded ones, 4 steps each
    assert intake.ready(1, 4) and not intake.ready(2, 4) and not intake.ready(1, 5)
    buffer = intake.buffer
    assert [(s.worker_id, s.created) for s in intake.take()] == [(seg.worker_id, seg.created)]
    assert intake.buffer == [] and intake.buffer is buffer  # emptied in place


# --- checkpoint and publish ----------------------------------------------------------------------------------------


class _Bus:
    """What the parts ask of ``common.bus.Bus``, recorded."""

    def __init__(self, evaluations: list[EvaluationSummary] | None = None, beats: list[list] | None = None) -> None:
        self.published: list = []
        self._evaluations, self._beats = evaluations or [], beats or []

    def publish_policy(self, policy) -> None:
        self.published.append(policy)

    def evaluations(self, last: int) -> tuple[list[EvaluationSummary], int]:
        return self._evaluations[-last:], 0

    def heartbeats(self) -> tuple[list, int]:
        return self._beats.pop(0), 1


def _store(tmp_path: Path) -> tuple[RunStore, Outage]:
    runs = RunStore(open_store(str(tmp_path / "store")))
    return runs, Outage("store", is_transient, LOG, give_up_s=1.0)


def test_checkpoints_save_resume_prune_and_publish(tmp_path: Path) -> None:
    runs, outage = _store(tmp_path)
    run, bus = _run().model_copy(update={"keep_checkpoints": 2}), _Bus()
    parts = Checkpoints(run, runs, bus, outage)
    parts.write_run_files({"model_metadata.json": default_action_space().to_json().encode()})
    assert runs.read_file("parts", "model/model_metadata.json") == runs.read_file("parts", "model_metadata.json")
    model = torch.nn.Linear(3, 2)
    optimizer = torch.optim.Adam(model.parameters())
    for version in range(4):
        meta = {"env_steps": 10 * version, "episodes": version, "iteration": version, "stability": {}, "created": 1.0}
        parts.save(version, model.state_dict(), optimizer.state_dict(), meta)
        parts.prune({version})
        parts.publish(version)
    payload, optim, meta = parts.newest()
    assert meta["version"] == 3 and meta["env_steps"] == 30 and meta["config"]["run_id"] == "parts"
    assert optim is not None and runs.load_optimizer("parts", 2) is None  # only the newest kept its optimizer
    assert [p.version for p in bus.published] == [0, 1, 2, 3]
    assert bus.published[-1].checkpoint_key == checkpoint_key("parts", 3)
    assert parts.metrics() == [] and parts.best_version() is None


# --- the collapse guard --------------------------------------------------------------------------------------------


def _summary(version: int, completion: float) -> EvaluationSummary:
    return EvaluationSummary(
        version=version,
        env_steps=100 * version,
        completion_rate=completion,
        mean_progress=100 * completion,
        best_lap_s=None,
        off_track=0,
        score=completion,
        best=False,
    )


def test_the_guard_finds_a_collapse_against_the_best_and_records_the_rollback(tmp_path: Path) -> None:
    runs, outage = _store(tmp_path)
    run = _run(collapse_guard=True, collapse_patience=2, collapse_lr_factor=0.5)
    parts = Checkpoints(run, runs, _Bus(), outage)
    model = torch.nn.Linear(3, 2)
    for version in range(4):
        meta = {"env_steps": 0, "episodes": 0, "iteration": version, "stability": {}, "created": 1.0}
        parts.save(version, model.state_dict(), torch.optim.Adam(model.parameters()).state_dict(), meta)
    runs.set_pointer("parts", "best", 1)
    runs.write_file("parts", evaluation_name(1), json.dumps({"completion_rate": 0.75, "mean_lap_s": 9.0}))
    bus = _Bus([_summary(1, 0.75), _summary(2, 0.0)])
    guard = CollapseGuard(run.hyperparams, "parts", bus, runs, redis_outage=outage, store_outage=outage)
    assert guard.collapse() is None  # one collapsed evaluation could be noise
    bus._evaluations.append(_summary(3, 1 / 12))
    found = guard.collapse()
    assert found is not None
    best, streak = found
    assert best == BestEvaluation(1, 0.75, 9.0) and [e["version"] for e in streak] == [2, 3]
    assert guard.read_best(1) is not None
    guard.rolled_back(best, streak, version=4)
    assert guard.stability == Stability(lr_scale=0.5, collapses=1, rollbacks=1, floor=4)
    assert guard.message(best, streak, 4, (0.001, 0.0005)).startswith(
        "collapse guard: v2, v3 completed 0.00, 0.08 of their evaluation trials against best v1's 0.75"
    )
    assert guard.read_best(9) is None and guard.stability.collapses == 2  # unreadable: counted, not rolled back


# --- reporting -----------------------------------------------------------------------------------------------------


class _Board:
    """A TensorBoard writer that remembers its scalars."""

    def __init__(self) -> None:
        self.scalars: list[tuple[str, float, int]] = []

    def add_scalar(self, tag: str, value: float, step: int) -> None:
        self.scalars.append((tag, value, step))

    def flush(self) -> None:
        pass


def test_a_metrics_row_by_hand_and_the_reporters_files(tmp_path: Path) -> None:
    runs, outage = _store(tmp_path)
    stats = Stats(env_steps=40, iteration=2, started=time.monotonic() - 10.0)
    lap = EpisodeSummary(1, 30, 100.0, 9.0, "lap_complete", track=STRAIGHT_TRACK, lap_time_s=12.0)
    off = EpisodeSummary(2, 10, 20.0, 1.0, "off_track", track=STRAIGHT_TRACK, lap_time_s=None)
    segments = [SimpleNamespace(episodes=[lap], policy_version=2), SimpleNamespace(episodes=[off], policy_version=1)]
    row = metrics_row(
        stats, 3, Stability(collapses=1), segments, batch_steps=64, lr=0.0003, train_s=1.5, losses={"policy_loss": 0.25}
    )
    assert (row["episodes"], row["batch_steps"], row["laps_completed"]) == (2, 64, 1)
    assert row["mean_progress"] == 60.0 and row["mean_reward"] == 5.0 and row["mean_lap_time_s"] == 12.0
    assert row["mean_policy_lag"] == 0.5 and row["policy_version"] == 3 and row["collapses"] == 1
    assert row["steps_per_s"] == pytest.approx(4.0, rel=0.05) and row["policy_loss"] == 0.25
    board = _Board()
    reporter = Reporter(runs, "parts", outage, board)
    reporter.record(row, {"policy_loss": 0.25}, segments)
    assert [json.loads(line) for line in runs.read_file("parts", METRICS_FILE).decode().splitlines()] == [row]
    assert ("trainer/policy_loss", 0.25, 40) in board.scalars and ("episode/lap_time_s", 12.0, 40) in board.scalars
    bus = _Bus([_summary(1, 0.5), _summary(2, 1.0)])
    assert reporter.tensorboard_evaluations(bus, 40) == 2 and reporter.tensorboard_evaluations(bus, 40) == 0
    assert ("evaluation/completion_rate", 1.0, 200) in board.scalars


def test_the_worker_watch_names_a_worker_that_goes_silent_and_comes_back(caplog) -> None:
    beat = SimpleNamespace(
        model_dump=lambda: {"worker_id": "w-1", "time": time.time(), "policy_version": 2, "segments": 5}
    )
    watch = WorkerWatch(_Bus(beats=[[beat], [], [beat]]), heartbeat_ttl_s=30.0)
    with caplog.at_level(logging.WARNING, logger="racer.trainer"):
        assert [w["worker_id"] for w in watch.workers()[0]] == ["w-1"]
        assert watch.workers() == ([], 1) and set(watch.silent) == {"w-1"}
        watch.workers()
    assert watch.silent == {}
    messages = [r.getMessage() for r in caplog.records]
    assert any("worker w-1 is silent" in m for m in messages) and any(
        "w-1 is sending heartbeats again" in m for m in messages
    )
