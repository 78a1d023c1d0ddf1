"""The collapse guard (trainer.process): its rule by hand, and a rollback against a real Redis and store.

The evaluations are fabricated but travel the evaluator's own way: ``save_evaluation`` stores the record and moves
``best``, then ``Bus.report_evaluation`` pushes the summary to the Redis list, as ``run_evaluator`` does after each
checkpoint.
"""

from __future__ import annotations

import json
import logging
import time

import pytest
import redis
import torch

from common.bus import Bus
from common.deadline import Deadline
from common.defaults import STRAIGHT_TRACK
from common.errors import OptionError
from common.keys import Keys
from common.protocol import PolicyVersion
from common.weights import acting_from_bytes, acting_to_bytes, checkpoint_from_bytes, state_dict_from_bytes
from model_store import RunStore, open_store
from model_store.runs import METRICS_FILE
from racer.options import RunOptions
from racer.runconfig import build_run, open_run, trainer_role_run
from rollout_worker.worker import RolloutWorker
from tests.test_training_loop import fill, start
from trainer.evaluator import evaluation_summary, save_evaluation, score
from trainer.guard import CollapseWatch, Stability, is_collapsed, is_slower, rolled_back_lr_scale
from trainer.process import Trainer, TrainerOptions

# --- the rule ------------------------------------------------------------------------------------------------


def test_rolled_back_lr_scale_by_hand() -> None:
    """Halved per rollback down to the floor, then held there: 1 -> 0.5 -> 0.25 -> 0.125 -> 0.1 -> 0.1."""
    scales = [1.0]
    for _ in range(5):
        scales.append(rolled_back_lr_scale(scales[-1], 0.5, 0.1))
    assert scales == pytest.approx([1.0, 0.5, 0.25, 0.125, 0.1, 0.1])
    assert rolled_back_lr_scale(0.125, 0.5, 0.0) == pytest.approx(0.0625)  # 0: no floor (racer before the floor)
    assert rolled_back_lr_scale(1.0, 1.0, 0.1) == 1.0  # a factor of 1 keeps the rate
    assert rolled_back_lr_scale(0.01, 0.5, 0.1) == pytest.approx(0.01)  # a floor never raises a lower scale


def test_is_collapsed_by_hand() -> None:
    # best 0.75, drop 0.5: collapsed at or below 0.375
    assert is_collapsed(0.0, 0.75, min_best=0.25, drop=0.5)
    assert is_collapsed(0.375, 0.75, min_best=0.25, drop=0.5)
    assert not is_collapsed(0.4, 0.75, min_best=0.25, drop=0.5)
    # a best below min_best has nothing to collapse from: 1 lap in 12 against none is noise
    assert not is_collapsed(0.0, 1 / 12, min_best=0.25, drop=0.5)
    # drop 1: only a completion of 0 is a collapse
    assert is_collapsed(0.0, 0.5, min_best=0.25, drop=1.0) and not is_collapsed(0.01, 0.5, min_best=0.25, drop=1.0)


def _e(version: int, completion: float) -> dict:
    return {"version": version, "completion_rate": completion}


def test_watch_needs_patience_consecutive_collapses_newer_than_the_best() -> None:
    watch = CollapseWatch(min_best=0.25, drop=0.5, patience=2)
    best = (5, 0.75)
    assert not watch.observe(_e(5, 0.75), best)  # the best itself
    assert not watch.observe(_e(6, 0.0), best)  # one: maybe noise
    assert not watch.observe(_e(7, 0.5), best)  # a good one ends the streak
    assert not watch.observe(_e(8, 0.1), best)
    assert watch.observe(_e(9, 0.0), best)  # two in a row
    assert [e["version"] for e in watch.streak] == [8, 9]
    assert not watch.observe(_e(9, 0.0), best)  # looked at already


def test_watch_ignores_versions_before_the_floor_and_older_than_the_best() -> None:
    watch = CollapseWatch(min_best=0.25, drop=0.5, patience=1)
    assert not watch.observe(_e(3, 0.0), (4, 1.0))  # older than the best: not a collapse of the best
    assert not watch.observe(_e(3, 0.0), None)  # no best yet
    watch.restart(floor=10)
    assert watch.fresh([_e(12, 0.0), _e(9, 0.0), _e(11, 0.0)]) == [_e(11, 0.0), _e(12, 0.0)]
    assert not watch.observe(_e(9, 0.0), (4, 1.0))  # a policy the rollback abandoned
    assert watch.observe(_e(10, 0.0), (4, 1.0))


def test_is_slower_by_hand() -> None:
    # best mean lap 8 s, slowdown 0.15: slower beyond 9.2 s
    assert is_slower(9.3, 8.0, 0.15) and not is_slower(9.2, 8.0, 0.15) and not is_slower(7.0, 8.0, 0.15)
    # off, or no lap to compare: never
    assert not is_slower(30.0, 8.0, None) and not is_slower(None, 8.0, 0.15) and not is_slower(9.3, None, 0.15)


def test_watch_with_slowdown_rolls_back_a_drift_to_slower_laps() -> None:
    def e(version: int, completion: float, lap: float | None) -> dict:
        return {"version": version, "completion_rate": completion, "mean_lap_s": lap}

    best = (5, 1.0, 7.0)  # slower beyond 7 * 1.15 = 8.05 s
    watch = CollapseWatch(min_best=0.9, drop=0.5, patience=2, slowdown=0.15)
    assert not watch.observe(e(6, 1.0, 8.3), best)  # one slower evaluation: maybe noise
    assert not watch.observe(e(7, 1.0, 7.9), best)  # within 15 %: ends the streak
    assert not watch.observe(e(8, 1.0, 8.3), best)
    assert watch.observe(e(9, 0.9, 8.6), best)  # two slower in a row
    assert [x["version"] for x in watch.streak] == [8, 9]
    # A lost completion still counts, with or without laps; a best below min_best has no pace to hold.
    watch = CollapseWatch(min_best=0.9, drop=0.5, patience=1, slowdown=0.15)
    assert watch.observe(e(10, 0.0, None), best)
    assert not watch.observe(e(11, 0.8, 30.0), (5, 0.8, 7.0))
    # Without slowdown (the default), the same drift is not a collapse; a best without a lap time neither.
    watch = CollapseWatch(min_best=0.9, drop=0.5, patience=1)
    assert not watch.observe(e(12, 1.0, 30.0), best)
    assert not CollapseWatch(0.9, 0.5, 1, slowdown=0.15).observe(e(13, 1.0, 30.0), (5, 1.0))


def test_stability_state_from_checkpoint_metadata() -> None:
    assert Stability.from_meta({}) == Stability()  # a checkpoint from before the guard
    saved = {"lr_scale": 0.25, "collapses": 3, "rollbacks": 2, "floor": 17, "slow_rollbacks": 1}
    assert Stability.from_meta({"stability": saved}) == Stability(0.25, 3, 2, 17, 1)


# --- the trainer, with a real Redis and store ----------------------------------------------------------------

HP = {
    "batch_size": 32,
    "num_epochs": 1,
    "num_episodes_between_training": 2,
    "discount_factor": 0.99,
    "lr": 0.001,
    "lr_schedule": "linear",
    "lr_final_fraction": 0.5,
    "beta_entropy": 0.01,
    "entropy_schedule": "linear",
    "entropy_final_fraction": 0.0,
    "schedule_updates": 4,
    "collapse_guard": True,
    "collapse_drop": 0.5,
    "collapse_lr_factor": 0.5,
}


def evaluated(
    runs: RunStore, r: redis.Redis, run_id: str, version: int, completion: float, lap: float | None = None
) -> None:
    """A robust evaluation of ``version`` completing ``completion`` of 12 trials, stored and reported as the
    evaluator does (``run_evaluator`` after ``evaluate_checkpoint``). Without ``lap`` the record is one from
    before evaluations had a ``mean_lap_s`` (its laps 20 s each); with it, every lap takes ``lap`` seconds."""
    laps = [lap or 20.0] * round(12 * completion)
    progress = 100.0 * completion
    record = {
        "run_id": run_id,
        "version": version,
        "env_steps": 0,
        "completion_rate": completion,
        "mean_progress": progress,
        "best_lap_s": min(laps, default=None),
        "off_track": 12 - len(laps),
        "score": score(completion, progress, laps),
        "trials": [],
    }
    if lap is not None:
        record["lap_times_s"], record["mean_lap_s"] = laps, (lap if laps else None)
    moved = save_evaluation(runs, record)
    Bus(r, run_id).report_evaluation(evaluation_summary(record, moved))


def three_versions(
    run_id: str, redis_url: str, tmp_path, hp: dict
) -> tuple[Trainer, RolloutWorker, redis.Redis, RunStore]:
    """A trainer with hyperparameters ``hp`` and a worker, after three policy updates (versions 1, 2, 3) the worker
    has polled; with a Redis client and the run store."""
    path = tmp_path / "hyperparameters.json"
    path.write_text(json.dumps(hp))
    store = str(tmp_path / "store")
    trainer, worker = start(run_id, redis_url, store, str(path))
    for _ in range(3):
        fill(trainer, worker)
        trainer.train()
        worker.poll_policy()
    return trainer, worker, redis.Redis.from_url(redis_url), RunStore(open_store(store))


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_a_collapse_rolls_back_to_the_best_weights_and_optimizer_at_a_lower_lr(
    redis_url, run_id, tmp_path, caplog
) -> None:
    trainer, worker, r, runs = three_versions(run_id, redis_url, tmp_path, HP)
    assert worker.policy_version == 3

    # The schedules, by hand: lr 0.001 → 0.0005 and beta 0.01 → 0 over 4 updates (updates k = 0, 1, 2).
    rows = [json.loads(line) for line in runs.read_file(run_id, METRICS_FILE).decode().splitlines()]
    assert [row["learning_rate"] for row in rows] == pytest.approx([0.001, 0.000875, 0.00075])
    assert [row["beta_entropy"] for row in rows] == pytest.approx([0.01, 0.0075, 0.005])
    assert [(row["collapses"], row["rollbacks"], row["epochs_run"]) for row in rows] == [(0, 0, 1)] * 3

    evaluated(runs, r, run_id, 1, 0.75)  # the best
    evaluated(runs, r, run_id, 2, 0.0)
    assert runs.pointer(run_id, "best")["version"] == 1
    assert trainer.guard() is False and trainer.version == 3  # one collapsed evaluation could be noise
    evaluated(runs, r, run_id, 3, 1 / 12)

    # Switched off (DeepRacer), the loop never looks.
    trainer.hp.collapse_guard = False
    trainer.opts.deadline = Deadline.after(1.2)
    trainer.run_forever()
    assert trainer.version == 3 and trainer.stability == Stability()

    # Switched on, the loop rolls back: v4 is v1's weights and optimizer state.
    trainer.hp.collapse_guard = True
    trainer.opts.deadline = Deadline.after(1.2)
    with caplog.at_level(logging.WARNING, logger="racer.trainer"):
        trainer.run_forever()
    assert trainer.version == 4
    assert trainer.stability == Stability(lr_scale=0.5, collapses=1, rollbacks=1, floor=4)
    best_model, _ = checkpoint_from_bytes(runs.load_checkpoint(run_id, 1)[0])
    new_model, _ = checkpoint_from_bytes(runs.load_checkpoint(run_id, 4)[0])
    # v1's optimizer state was kept for the roll-back (the guard had seen no evaluation when v2 and v3 were saved).
    best_optim = state_dict_from_bytes(runs.load_optimizer(run_id, 1))
    new_optim = state_dict_from_bytes(runs.load_optimizer(run_id, 4))
    assert _same(new_model, best_model) and _same(trainer.model.state_dict(), best_model)
    assert _same(trainer.optimizer.state_dict()["state"][0], best_optim["state"][0])
    # lr at update k = 3: 0.001 * (1 - 0.5 * 3/4) = 0.000625, halved by the rollback
    assert trainer.optimizer.param_groups[0]["lr"] == pytest.approx(0.0003125)
    assert new_optim["param_groups"][0]["lr"] == pytest.approx(0.0003125)
    meta = runs.checkpoint_meta(run_id, 4)
    assert meta["rolled_back_to"] == 1 and meta["stability"]["floor"] == 4
    assert PolicyVersion.from_json(r.get(Keys(run_id).policy)).version == 4
    lines = [rec.getMessage() for rec in caplog.records if "collapse guard" in rec.getMessage()]
    assert lines == [
        "collapse guard: v2, v3 completed 0.00, 0.08 of their evaluation trials against best v1's 0.75 "
        "(collapsed at <= 0.38); rolled back to v1's weights and optimizer as v4, learning rate 0.000625 -> 0.000313 "
        "(collapses 1, rollbacks 1)"
    ]

    # A segment acted by the abandoned v3 is dropped; the worker switches to v4 = v1's weights.
    worker.push(worker.collect())
    assert trainer.read(block_ms=500) == 0 and trainer.stats.dropped.get("rolled_back") == 1
    assert worker.poll_policy() and worker.policy_version == 4
    # The worker acts with v4's acting copy: v1's weights through float16 (common/policy.py: acting_to_bytes).
    assert _same(worker.model.state_dict(), acting_from_bytes(acting_to_bytes(best_model)))

    # Numbering goes on upward, and the metrics count the rollback.
    fill(trainer, worker)
    trainer.train()
    assert trainer.version == 5
    row = json.loads(runs.read_file(run_id, METRICS_FILE).decode().splitlines()[-1])
    assert (row["policy_version"], row["collapses"], row["rollbacks"]) == (5, 1, 1)
    assert row["learning_rate"] == pytest.approx(0.0003125)
    worker.close()

    # A resumed trainer keeps the lower learning rate, the counters and the floor.
    again = Trainer(trainer.run, TrainerOptions(redis_url, str(tmp_path / "store"), resume=True, tensorboard=False))
    again.start()
    assert again.stability == Stability(lr_scale=0.5, collapses=1, rollbacks=1, floor=4)
    assert again.learning_rate() == pytest.approx(0.001 * (1 - 0.5) * 0.5)  # k = 4: the schedule's end, halved
    assert again.guard() is False  # the evaluations of v2 and v3 are below the floor


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_a_drift_to_slower_laps_rolls_back_with_collapse_slowdown(redis_url, run_id, tmp_path, caplog) -> None:
    trainer, worker, r, runs = three_versions(
        run_id,
        redis_url,
        tmp_path,
        HP | {"collapse_min_best": 0.9, "collapse_slowdown": 0.15, "collapse_lr_floor": 0.75},
    )
    evaluated(runs, r, run_id, 1, 1.0, lap=8.0)  # the best: every trial a lap, 8 s each
    evaluated(runs, r, run_id, 2, 1.0, lap=9.5)  # all laps still, but more than 8 * 1.15 = 9.2 s
    assert runs.pointer(run_id, "best")["version"] == 1
    assert trainer.guard() is False  # one slow evaluation could be noise
    evaluated(runs, r, run_id, 3, 1.0, lap=9.4)
    with caplog.at_level(logging.WARNING, logger="racer.trainer"):
        assert trainer.guard() is True
    # The rollback halves the rate, but collapse_lr_floor 0.75 holds it at three quarters of the schedule's.
    assert trainer.stability == Stability(lr_scale=0.75, collapses=1, rollbacks=1, floor=4, slow_rollbacks=1)
    assert trainer.version == 4
    best_model, _ = checkpoint_from_bytes(runs.load_checkpoint(run_id, 1)[0])
    assert _same(trainer.model.state_dict(), best_model)
    lines = [rec.getMessage() for rec in caplog.records if "collapse guard" in rec.getMessage()]
    assert len(lines) == 1
    assert "v2, v3 completed 1.00, 1.00 of their evaluation trials against best v1's 1.00" in lines[0]
    assert "mean laps 9.50, 9.40 s against its 8.00 s (slower than 9.20 s)" in lines[0]
    worker.close()


def test_the_cool_down_lowers_the_learning_rate_towards_the_time_limit(redis_url, run_id, tmp_path) -> None:
    """``lr_cooldown`` 0.5 of a 100 s limit, cooling to ``lr_final_fraction`` 0.1: with 25 s left the rate is
    0.001 * (0.1 + 0.9 * 25 / 50), times a rollback's scale; with more than 50 s left it is ``lr``."""
    path = tmp_path / "hyperparameters.json"
    path.write_text(json.dumps({"lr": 0.001, "lr_cooldown": 0.5, "lr_final_fraction": 0.1}))
    run, files = build_run(run_id, track=STRAIGHT_TRACK, hyperparams=str(path))
    trainer = Trainer(run, TrainerOptions(redis_url, str(tmp_path / "store"), run_files=files))
    trainer.start()
    assert trainer.learning_rate() == pytest.approx(0.001)  # no deadline: no cool-down
    trainer.opts.deadline = Deadline(at=time.time() + 80.0, limit_s=100.0)
    assert trainer.learning_rate() == pytest.approx(0.001)
    trainer.opts.deadline = Deadline(at=time.time() + 25.0, limit_s=100.0)
    assert trainer.learning_rate() == pytest.approx(0.001 * (0.1 + 0.9 * 0.5), rel=1e-3)
    trainer.stability.lr_scale = 0.5
    assert trainer.learning_rate() == pytest.approx(0.0005 * (0.1 + 0.9 * 0.5), rel=1e-3)


def test_a_cool_down_without_a_time_limit_is_refused(redis_url, run_id, tmp_path) -> None:
    path = tmp_path / "hyperparameters.json"
    path.write_text(json.dumps({"lr_cooldown": 0.2}))
    runs = RunStore(open_store(str(tmp_path / "store")))
    opts = RunOptions(run_id=run_id, track=STRAIGHT_TRACK, hyperparams=str(path))
    with pytest.raises(OptionError, match=r"hyperparameters.json: lr_cooldown 0.2 needs a time limit"):
        open_run(runs, opts)  # racer train: before anything starts
    with pytest.raises(OptionError, match=r"hyperparameters.json: lr_cooldown 0.2 needs a time limit"):
        trainer_role_run(runs, None, None, opts)  # racer trainer alone
    run, _, _ = open_run(runs, opts.model_copy(update={"time_limit_s": 60.0}))
    assert run.hyperparams.lr_cooldown == 0.2
