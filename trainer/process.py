"""The trainer process: pull segments from Redis, run PPO, write checkpoints, publish policy versions.

DeepRacer trains after every ``num_episodes_between_training`` episodes; so do we: segments are
buffered until that many episodes have ended in them, then PPO runs ``num_epochs`` epochs over the
buffer in minibatches of ``batch_size``, a checkpoint is written to the store (pointer last) and the
new version is announced in Redis, where workers pick it up between segments.

racer's stability knobs (all off by default, as DeepRacer has none) act here: the learning-rate and entropy
schedules set each update's coefficients, ``target_kl`` stops an update's epochs early (``trainer.ppo.update``),
and the collapse guard (``Trainer.guard``) rolls the run back to its ``best`` checkpoint when the evaluator's
robust evaluations of newer checkpoints collapse.
"""

from __future__ import annotations

import logging
import resource
import threading
import time
from collections.abc import Callable
from dataclasses import KW_ONLY, asdict, dataclass, field
from functools import partial

import torch

from common.action_space import action_space_from_json
from common.bus import Bus
from common.config import RunConfig
from common.deadline import Deadline
from common.defaults import DEFAULT_GIVE_UP_S, DEFAULT_TRAINER_THREADS
from common.policy import PolicyNetwork
from common.protocol import EndReason
from common.redis_util import redact
from common.retry import Outage, redis_transient
from model_store import RunStore, is_transient, open_store
from trainer.checkpoints import Checkpoints
from trainer.device import resolve_device
from trainer.guard import BestEvaluation, CollapseGuard, Stability
from trainer.intake import SegmentIntake, Stats
from trainer.learner import Learner, make_batch, make_optimizer
from trainer.liveness import Liveness, end_reason
from trainer.precision import precision_candidates
from trainer.reporting import Reporter, WorkerWatch, metrics_row, summary_writer

__all__ = ["Trainer", "TrainerOptions", "make_batch", "make_optimizer", "run_trainer"]

log = logging.getLogger("racer.trainer")


@dataclass
class TrainerOptions:
    """How to reach the run and when to stop (keyword-only after the store)."""

    redis_url: str
    store: str = "."
    _: KW_ONLY
    s3_endpoint: str | None = None
    resume: bool = False
    """Continue from the run's latest checkpoint instead of starting it."""
    deadline: Deadline | None = None
    """When to stop (``common.deadline``: the run's one deadline, fixed as its roles started); None = until
    stopped. The learning-rate cool-down counts back from it."""
    torch_threads: int = DEFAULT_TRAINER_THREADS
    """Threads for PyTorch in the trainer (the workers use one each)."""
    run_files: dict[str, bytes] = field(default_factory=dict)
    """Files written into a new run: reward_function.py, model_metadata.json, hyperparameters.json."""
    tensorboard: bool = True
    """Write TensorBoard scalars to ``runs/<id>/tensorboard/`` (in the store folder, or ./ for an S3 store)."""
    outage_s: float = DEFAULT_GIVE_UP_S
    """How long to ride out one Redis or store outage before exiting with an error, seconds."""
    precision: str = "auto"
    """The trunk's arithmetic in PPO updates: ``fp32``, ``bf16``, ``fp16`` (CUDA only, loss-scaled), or ``auto`` (on
    a CPU where bf16 runs natively, both are timed on the first batch and the faster is kept; on a GPU bf16, else
    fp16: ``trainer.precision``). Checkpoints are float32 either way."""
    device: str = "auto"
    """Where the network and Adam live and PPO runs: ``auto``, ``cpu``, ``cuda`` or ``cuda:N`` (``trainer.device``).
    Checkpoints are saved as CPU tensors whatever it is."""


class Trainer:
    """PPO over segments from Redis; see the module docstring. It runs the loop and owns the run's version; each
    concern is a part of its own: ``intake`` (segments), ``learner`` (network, PPO step), ``checkpoints`` (store
    and policy key), ``collapse_guard``, ``reporter`` (metrics, TensorBoard) and ``heartbeats`` (live workers)."""

    stop_when: Callable[[Trainer], bool] | None = None
    """A public hook: asked once each turn of the loop, before the check for a batch; True stops the loop there,
    between two updates (a bench closes its measured window with it)."""

    def __init__(self, run: RunConfig, opts: TrainerOptions, stop: threading.Event | None = None) -> None:
        self.run, self.opts, self.hp = run, opts, run.hyperparams
        self.device = resolve_device(opts.device)
        precision_candidates(opts.precision, self.device)  # a precision this device cannot run fails before Redis
        self.stop = stop or threading.Event()
        self.bus = Bus.connect(opts.redis_url, run.run_id)
        self.runs = RunStore(open_store(opts.store, opts.s3_endpoint))
        self.redis_outage = Outage(f"Redis at {redact(opts.redis_url)}", redis_transient, log, self.stop, opts.outage_s)
        self.store_outage = Outage(f"store {self.runs.store.uri}", is_transient, log, self.stop, opts.outage_s)
        self.version = 0
        self.stats = Stats()
        self.checkpoints = Checkpoints(run, self.runs, self.bus, self.store_outage)
        self.collapse_guard = CollapseGuard(
            self.hp, run.run_id, self.bus, self.runs, redis_outage=self.redis_outage, store_outage=self.store_outage
        )
        self.tb = summary_writer(opts.store, run.run_id) if opts.tensorboard else None
        self.reporter = Reporter(self.runs, run.run_id, self.store_outage, self.tb)
        self.heartbeats = WorkerWatch(self.bus, run.heartbeat_ttl_s)
        self.liveness = Liveness(self.bus, stopping=self.stop)

    @property
    def stability(self) -> Stability:
        """What the collapse guard has done to the run (``CollapseGuard.stability``)."""
        return self.collapse_guard.stability

    @property
    def model(self) -> PolicyNetwork:
        """The network (``Learner.model``)."""
        return self.learner.model

    @property
    def optimizer(self) -> torch.optim.Optimizer:
        """Adam (``Learner.optimizer``)."""
        return self.learner.optimizer

    # --- start --------------------------------------------------------------------------------
    def start(self) -> None:
        """Resume from the newest whole checkpoint, or write the run's files and publish version 0."""
        self.liveness.start()
        if not self.opts.resume:
            files = self.opts.run_files
            self.store_outage.call("write the run's files", lambda: self.checkpoints.write_run_files(files))
        self._build()
        if self.opts.resume:
            self.store_outage.call("read the newest checkpoint", self._resume)
        else:
            if self.run.pretrained:
                self.store_outage.call("read the pretrained checkpoint", self._load_pretrained)
            self._checkpoint()
        # A predecessor killed mid-update leaves its "training" mark, which would hold the workers back.
        self.redis_outage.call("publish the policy", lambda: (self.bus.clear_training(), self._publish()))
        choices = self.learner.precision_choices
        log.info(
            "run %s: policy v%d published; store %s, Redis %s; PPO updates on %s in %s with %d CPU threads",
            self.run.run_id,
            self.version,
            self.runs.store.uri,
            redact(self.opts.redis_url),
            self.device,
            " or ".join(choices) + (" (the faster, timed on the first batch)" if len(choices) > 1 else ""),
            torch.get_num_threads(),
        )
        self.liveness.set_phase("collecting", self.version)

    def _build(self) -> None:
        """The learner and the intake for the run's sensors and action space (its stored model_metadata.json)."""
        actions = action_space_from_json(self.runs.read_file(self.run.run_id, "model_metadata.json"))
        self.learner = Learner(self.run, actions, self.device, self.opts.precision)
        self.intake = segment_intake(self.bus, self.run.run_id, self.learner, self.stats)

    def _resume(self) -> None:
        payload, optimizer, meta = self.checkpoints.newest()
        self.version = int(meta["version"])
        self.learner.load_state(payload, optimizer, f"run {self.run.run_id} version {self.version}")
        self.stats.env_steps = int(meta.get("env_steps", 0))
        self.stats.episodes = int(meta.get("episodes", 0))
        self.stats.iteration = int(meta.get("iteration", self.version))
        self.collapse_guard.resume(meta)
        # A Redis that outlived the previous trainer (compose) still lists the evaluations it wrote to TensorBoard.
        self.reporter.tb_evaluated = self.version
        self.reporter.metrics[:] = self.checkpoints.metrics()
        log.info("resumed run %s at version %d (%d env steps)", self.run.run_id, self.version, self.stats.env_steps)

    def _load_pretrained(self) -> None:
        """Version 0 takes another run's weights (``run.pretrained``)."""
        payload, source, version = self.checkpoints.pretrained()
        self.learner.load_pretrained(payload, str(self.run.pretrained))
        log.info("run %s starts from run %s version %s", self.run.run_id, source, version)

    def _checkpoint(self, **extra: object) -> dict:
        """Save the current version (``extra`` goes into its metadata)."""
        meta = {**self.stats.counts(), "stability": asdict(self.stability), "created": time.time(), **extra}
        state = self.model.state_dict()
        return self.checkpoints.save(self.version, state, self.optimizer.state_dict(), meta)

    def _prune(self) -> None:
        """Prune checkpoints; keep the optimizer state only of the newest (a resume reads it) and, with the collapse
        guard on, of those a roll-back may read: the best, and every version the guard has not seen evaluated yet
        (the evaluator lags; any of them may become best)."""
        keep = {self.version}
        if self.hp.collapse_guard:
            best = self.checkpoints.best_version()
            keep |= {best} if best is not None else set()
            keep |= set(range(self.collapse_guard.watch.seen + 1, self.version))
        self.checkpoints.prune(keep)

    def _publish(self) -> None:
        self.checkpoints.publish(self.version)

    def close(self) -> None:
        """Stop the heartbeat thread and close TensorBoard's file: ``run_trainer`` does; code that drives a Trainer
        itself calls it when done."""
        self.liveness.stop()
        self.reporter.close()

    # --- the loop -----------------------------------------------------------------------------
    def run_forever(self) -> EndReason:
        """Read, train, publish until stopped, past the deadline or done; returns why it stopped."""
        last_status = 0.0
        while not self.stop.is_set() and (self.opts.deadline is None or not self.opts.deadline.passed()):
            self.redis_outage.call("read segments", lambda: self.read(block_ms=500))
            if self.stop_when is not None and self.stop_when(self):
                break
            if self.ready():
                self.train()
            if time.monotonic() - last_status > 1.0:
                self.redis_outage.call("write the status", self.housekeeping)
                if self.tb is not None:
                    read = partial(self.reporter.tensorboard_evaluations, self.bus, self.stats.env_steps)
                    self.redis_outage.call("read the evaluations", read)
                if self.hp.collapse_guard:
                    self.guard()
                last_status = time.monotonic()
            if self.stats.iteration >= max_updates(self.run):
                # As the simapp's training_worker.py: term_cond_max_episodes bounds the policy updates (its loop
                # counts one per train() call); term_cond_avg_score stops nothing there, so it stops nothing here.
                break
        self.redis_outage.call("write the status", self.write_status)
        return end_reason(self.stats.iteration, max_updates(self.run), self.opts.deadline)

    def housekeeping(self) -> None:
        """Once a second: the status for ``racer train``, and the policy key again if Redis lost it (a restarted
        Redis without persistence comes back empty; workers and the evaluator need the key to find the policy)."""
        if not self.bus.has_policy():
            log.warning("the policy key was missing from Redis (restarted?): publishing version %d again", self.version)
            self.checkpoints.publish(self.version)
        self.write_status()

    def read(self, block_ms: int = 500, count: int = 64) -> int:
        """Pull new segments into the buffer (``SegmentIntake.read``); returns how many were kept."""
        return self.intake.read(self.version, self.stability.floor, self.run.max_policy_lag, block_ms, count)

    def ready(self) -> bool:
        """True once the buffer holds ``num_episodes_between_training`` finished episodes and a batch."""
        return self.intake.ready(self.hp.num_episodes_between_training, self.hp.batch_size)

    def train(self) -> dict[str, float]:
        """One PPO iteration on the buffer, then checkpoint and publish the next version."""
        t0 = time.monotonic()
        self.redis_outage.call("mark the update", lambda: self.bus.mark_training(self.version))
        self.liveness.set_phase("updating", self.version)  # its thread beats on through the update
        batch = make_batch(self.intake.buffer, self.hp.discount_factor, self.hp.gae_lambda).to(self.device)
        segments = self.intake.take()
        lr = self.learning_rate()
        result = self.learner.learn(batch, lr, version=self.version, iteration=self.stats.iteration)
        self.version += 1
        self.stats.iteration += 1
        self._checkpoint()
        self.redis_outage.call("publish the policy", lambda: (self._publish(), self.bus.clear_training()))
        self.store_outage.call("prune checkpoints", self._prune)
        self.liveness.set_phase("collecting", self.version)
        steps, lr, dt = int(batch.actions.shape[0]), self.optimizer.param_groups[0]["lr"], time.monotonic() - t0
        row = metrics_row(self.stats, self.version, self.stability, segments, steps, lr=lr, train_s=dt, losses=result)
        self.reporter.record(row, result, segments)
        log.info("iteration %d: version %d, %s", self.stats.iteration, self.version, result)
        return result

    def learning_rate(self) -> float:
        """The learning rate of the next policy update (``Learner.learning_rate``)."""
        return self.learner.learning_rate(self.stats.iteration, self.stability.lr_scale, self.opts.deadline)

    # --- the collapse guard -------------------------------------------------------------------
    def guard(self) -> bool:
        """Roll back when the evaluator's new summaries have collapsed (``CollapseGuard.collapse``); True if so."""
        found = self.collapse_guard.collapse()
        return found is not None and self._roll_back(*found)

    def _roll_back(self, best: BestEvaluation, collapsed: list[dict]) -> bool:
        """Go back to the best checkpoint's weights and optimizer at a lower learning rate, as a new version.

        The buffer and later segments of older versions are dropped (``rolled_back``): they were acted by the
        collapsed policies. Returns False if the best checkpoint could not be read (counted as a collapse only).
        """
        state = self.collapse_guard.read_best(best.version)
        if state is None:
            return False
        old_lr = self.learning_rate()
        self.learner.load_state(*state, f"run {self.run.run_id} version {best.version}")
        self.intake.discard("rolled_back")
        self.version += 1
        self.collapse_guard.rolled_back(best, collapsed, self.version)
        self.learner.set_lr(self.learning_rate())  # the best's optimizer state carries the best's learning rate
        self._checkpoint(rolled_back_to=best.version)
        self.redis_outage.call("publish the policy", self._publish)
        self.store_outage.call("prune checkpoints", self._prune)
        log.warning(self.collapse_guard.message(best, collapsed, self.version, (old_lr, self.learning_rate())))
        self.reporter.rollback(self.stability.rollbacks, self.stats.env_steps)
        return True

    # --- reporting ----------------------------------------------------------------------------
    def status(self) -> dict:
        """Progress figures for the display and for ``racer train``."""
        stability = asdict(self.stability)
        return {
            **self.stats.figures(),
            "trained_env_steps": self.reporter.trained_env_steps(),
            "policy_version": self.version,
            "workers": self.workers(),
            "silent_workers": sorted(self.heartbeats.silent),
            "outages": {"redis": self.redis_outage.outages, "store": self.store_outage.outages},
            **{k: stability[k] for k in ("collapses", "rollbacks", "slow_rollbacks")},
            "precision": self.learner.precision,
            "precision_ms": dict(self.learner.precision_ms),
            "device": str(self.device),
            "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "time": time.time(),
        }

    def write_status(self) -> None:
        """Publish the status to Redis (a key with a TTL) for ``racer train``'s live line."""
        self.bus.set_trainer_status(self.status())

    def workers(self) -> list[dict]:
        """Live workers from their heartbeat keys (``WorkerWatch``); an unreadable heartbeat is counted."""
        beats, bad = self.heartbeats.workers()
        for _ in range(bad):
            self.stats.drop("bad_heartbeat")
        return beats


def max_updates(run: RunConfig) -> int:
    """The policy updates a run ends at: ``term_cond_max_episodes``, or sooner a distilling run without fine-tuning
    once it has distilled (``DistillConfig.fine_tune``)."""
    limit = run.hyperparams.term_cond_max_episodes
    if run.distill is not None and not run.distill.fine_tune:
        return min(limit, run.distill.updates)
    return limit


def segment_intake(bus: Bus, run_id: str, learner: Learner, stats: Stats) -> SegmentIntake:
    """The intake of the segments ``learner`` trains on: its observations (camera frames and LiDAR, or a teacher's
    state vectors), its actions and, in a distilling run, the teacher's labels."""
    return SegmentIntake(
        bus,
        run_id,
        learner.lidar,
        learner.obs_shape,
        n_actions=learner.n_actions,
        stats=stats,
        label_width=learner.label_width,
    )


def run_trainer(run: RunConfig, opts: TrainerOptions, stop: threading.Event | None = None) -> dict:
    """The ``racer trainer`` process: start or resume the run, then train until stopped; returns the status."""
    torch.set_num_threads(max(1, opts.torch_threads))
    trainer = Trainer(run, opts, stop)
    try:
        trainer.start()
        reason = trainer.run_forever()
        version, steps = trainer.version, trainer.stats.env_steps
        trainer.redis_outage.call("record the end", lambda: trainer.liveness.end(reason, version, steps))
        return trainer.status()
    except InterruptedError:  # stopped (SIGTERM) while Redis or the store was unreachable
        log.warning("stopped during an outage at version %d", trainer.version)
        return {"policy_version": trainer.version, "env_steps": trainer.stats.env_steps}
    finally:
        trainer.close()
