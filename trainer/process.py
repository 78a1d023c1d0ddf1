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

import contextlib
import json
import logging
import resource
import statistics
import tempfile
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import NamedTuple

import torch

from common.bus import Bus
from common.config import PretrainedError, RunConfig
from common.deadline import Deadline
from common.policy import (
    ActorCritic,
    Precision,
    acting_to_bytes,
    action_space_spec,
    build_policy,
    checkpoint_from_bytes,
    checkpoint_to_bytes,
    load_weights,
    misfit,
    state_dict_from_bytes,
    state_dict_to_bytes,
)
from common.protocol import EpisodeSummary, PolicyVersion, ProtocolError, Segment, decode_segment
from common.redis_util import redact
from common.retry import DEFAULT_GIVE_UP_S, Outage, redis_transient
from common.sensors import ObsSpec, camera_frame_size, observation_spec
from model_store import RunStore, StoreKeyError, is_transient, open_store
from model_store.localize import localize_env
from model_store.runs import METRICS_FILE, checkpoint_key, evaluation_name, local_run_dir
from sim.env import RacerEnv
from trainer.device import resolve_device
from trainer.ppo import PPOBatch, compute_gae, cooldown_factor, scheduled, update
from trainer.precision import fastest, grad_scaler, precision_candidates, time_precisions

log = logging.getLogger("racer.trainer")

EVALUATION_WINDOW = 64
"""Newest evaluation summaries the collapse guard reads from Redis each time: the evaluator adds one per
checkpoint it scores (tens of seconds each), so far fewer than this arrive between two looks a second apart."""


@dataclass
class TrainerOptions:
    """How to reach the run and when to stop."""

    redis_url: str
    store: str = "."
    s3_endpoint: str | None = None
    resume: bool = False
    """Continue from the run's latest checkpoint instead of starting it."""
    deadline: Deadline | None = None
    """When to stop (``common.deadline``: the run's one deadline, fixed as its roles started); None = until
    stopped. The learning-rate cool-down counts back from it."""
    torch_threads: int = 1
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


SEEN_SEGMENTS = 4096
"""Segments remembered for dropping duplicates: minutes of segments, longer than TCP keeps retrying a lost one."""


@dataclass
class Stats:
    """What the trainer has seen, for the status line and the metrics."""

    env_steps: int = 0
    episodes: int = 0
    iteration: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    dropped_steps: int = 0
    """Env steps in the dropped segments that could be decoded (a malformed one's steps are unknown)."""
    lag: deque[int] = field(default_factory=lambda: deque(maxlen=1000))
    """Policy lag of the most recent segments (bounded: a run lasts hours)."""
    recent: list[EpisodeSummary] = field(default_factory=list)
    by_worker: dict[str, int] = field(default_factory=dict)
    """Segments accepted from each worker id."""
    started: float = field(default_factory=time.monotonic)

    def drop(self, reason: str, steps: int = 0) -> None:
        """Count a dropped segment (of ``steps`` env steps, where it could be read)."""
        self.dropped[reason] = self.dropped.get(reason, 0) + 1
        self.dropped_steps += steps


@dataclass
class Stability:
    """What the collapse guard has done to the run; kept in every checkpoint's metadata, so a resumed run keeps it."""

    lr_scale: float = 1.0
    """Product of ``collapse_lr_factor`` over the rollbacks so far, never below ``collapse_lr_floor``
    (:func:`rolled_back_lr_scale`): it multiplies the scheduled learning rate."""
    collapses: int = 0
    """Collapses detected."""
    rollbacks: int = 0
    """Collapses rolled back (one fewer than ``collapses`` only if the best checkpoint could not be read)."""
    floor: int = 0
    """First version of the current lineage (the version a rollback published): evaluations and segments of older
    versions belong to the abandoned policies and are ignored."""
    slow_rollbacks: int = 0
    """Rollbacks whose streak held an evaluation collapsed by its pace alone (``collapse_slowdown``), not by its
    completion: so a run's figures say which rule acted."""

    @classmethod
    def from_meta(cls, meta: dict) -> Stability:
        """The state saved in a checkpoint's metadata; the initial state for a checkpoint from before the guard."""
        saved = meta.get("stability") or {}
        return cls(
            lr_scale=float(saved.get("lr_scale", 1.0)),
            collapses=int(saved.get("collapses", 0)),
            rollbacks=int(saved.get("rollbacks", 0)),
            floor=int(saved.get("floor", 0)),
            slow_rollbacks=int(saved.get("slow_rollbacks", 0)),
        )


def rolled_back_lr_scale(scale: float, factor: float, floor: float) -> float:
    """The learning-rate scale after one more rollback: ``scale * factor``, but not below ``floor`` (nor above
    ``scale``: a floor added to a resumed run whose scale is already lower does not raise it)."""
    return min(scale, max(scale * factor, floor))


def is_collapsed(completion: float, best_completion: float, min_best: float, drop: float) -> bool:
    """True when an evaluation's completion has collapsed against the best checkpoint's.

    Only a best that completes at least ``min_best`` of its trials can collapse (``racer train`` evaluates 6 or 12
    trials: one lap more or less is noise); collapsed means at most ``best_completion * (1 - drop)``: a relative
    drop, so 0.5 means "half the best's completion or less" whatever the best's.
    """
    return best_completion >= min_best and completion <= best_completion * (1.0 - drop)


def is_slower(mean_lap_s: float | None, best_mean_lap_s: float | None, slowdown: float | None) -> bool:
    """True when an evaluation's mean lap is more than ``1 + slowdown`` times the best checkpoint's (never when
    ``slowdown`` is None or either evaluation finished no lap)."""
    if slowdown is None or mean_lap_s is None or best_mean_lap_s is None:
        return False
    return mean_lap_s > best_mean_lap_s * (1.0 + slowdown)


def _mean_lap(record: dict) -> float | None:
    """An evaluation record's mean lap, s: its ``mean_lap_s``, or from its ``lap_times_s`` (records from before
    the evaluator wrote ``mean_lap_s``); None when it has no lap."""
    if record.get("mean_lap_s") is not None:
        return float(record["mean_lap_s"])
    laps = [float(lap) for lap in record.get("lap_times_s") or []]
    return statistics.fmean(laps) if laps else None


class BestEvaluation(NamedTuple):
    """What the collapse guard compares new evaluations with: the ``best`` checkpoint's."""

    version: int
    completion: float
    mean_lap_s: float | None = None


@dataclass
class CollapseWatch:
    """The collapse guard's memory: the evaluations it has looked at, and the current streak of collapsed ones.

    A streak counts consecutive evaluated checkpoints newer than the best that have all collapsed; any other
    evaluation (a good one, the best itself, an older one) ends it. ``patience`` of them in a row is a collapse:
    with 2 (the default), one unlucky evaluation is not enough, and a real collapse (issue 16 saw 5 or 6 versions
    in a row at 0 %) costs one checkpoint more.
    """

    min_best: float
    drop: float
    patience: int
    slowdown: float | None = None
    """``collapse_slowdown``: an evaluation this much slower than the best (mean lap) counts too; None: never."""
    floor: int = 0
    seen: int = -1
    """Newest version looked at."""
    streak: list[dict] = field(default_factory=list)

    def fresh(self, evaluations: list[dict]) -> list[dict]:
        """The summaries not looked at yet, of the current lineage, oldest first."""
        return sorted(
            (e for e in evaluations if e["version"] > self.seen and e["version"] >= self.floor),
            key=lambda e: e["version"],
        )

    def observe(self, evaluation: dict, best: tuple[int, float] | tuple[int, float, float | None] | None) -> bool:
        """Look at one new summary (``version``, ``completion_rate``, optionally ``mean_lap_s``) given the best
        (version, completion[, mean lap]), in version order; True when it completes a streak of ``patience``
        collapsed evaluations."""
        version = evaluation["version"]
        if version <= self.seen or version < self.floor:
            return False
        self.seen = version
        if not (best is not None and version > best[0] and self.collapsed(evaluation, BestEvaluation(*best))):
            self.streak = []
            return False
        self.streak.append(evaluation)
        return len(self.streak) >= self.patience

    def collapsed(self, evaluation: dict, best: BestEvaluation) -> bool:
        """One evaluation against the best: lost completion (``is_collapsed``) or, once the best completes
        ``min_best`` of its trials, a mean lap ``slowdown`` slower (``is_slower``)."""
        if is_collapsed(evaluation["completion_rate"], best.completion, self.min_best, self.drop):
            return True
        slower = is_slower(evaluation.get("mean_lap_s"), best.mean_lap_s, self.slowdown)
        return best.completion >= self.min_best and slower

    def restart(self, floor: int) -> None:
        """Forget the streak; from now on look only at versions from ``floor`` on."""
        self.floor, self.streak = floor, []


class Trainer:
    """PPO over segments from Redis; see the module docstring."""

    def __init__(self, run: RunConfig, opts: TrainerOptions, stop: threading.Event | None = None) -> None:
        self.run, self.opts = run, opts
        self.device = resolve_device(opts.device)
        precision_candidates(opts.precision, self.device)  # a precision this device cannot run fails before Redis
        self.stop = stop or threading.Event()
        self.bus = Bus.connect(opts.redis_url, run.run_id)
        self.runs = RunStore(open_store(opts.store, opts.s3_endpoint))
        self.redis_outage = Outage(f"Redis at {redact(opts.redis_url)}", redis_transient, log, self.stop, opts.outage_s)
        self.store_outage = Outage(f"store {self.runs.store.uri}", is_transient, log, self.stop, opts.outage_s)
        self.live: dict[str, dict] = {}
        """Last heartbeat of each worker seen alive (worker id → Heartbeat fields)."""
        self.silent: dict[str, dict] = {}
        """Workers whose heartbeat expired: worker id → their last heartbeat."""
        self.hp = run.hyperparams
        self.version = 0
        self.stats = Stats()
        self.buffer: list[Segment] = []
        self.last_id = "0-0"
        self._seen: deque[tuple[str, float]] = deque(maxlen=SEEN_SEGMENTS)
        """(worker id, created) of the segments read last, to drop a second copy of one (see ``_accept``)."""
        self.metrics: list[dict] = []
        self.stability = Stability()
        self.watch = CollapseWatch(
            self.hp.collapse_min_best, self.hp.collapse_drop, self.hp.collapse_patience, self.hp.collapse_slowdown
        )
        self.tb = _summary_writer(opts.store, run.run_id) if opts.tensorboard else None
        self.tb_evaluated = -1
        """Newest evaluated version whose figures are in TensorBoard (``tensorboard_evaluations``)."""
        self._workdir = tempfile.TemporaryDirectory(prefix="racer-trainer-")

    # --- start --------------------------------------------------------------------------------
    def start(self) -> None:
        """Resume from the newest whole checkpoint, or write the run's files and publish version 0."""
        if not self.opts.resume:
            self.store_outage.call("write the run's files", self._write_run_files)
        self._build()
        if self.opts.resume:
            self.store_outage.call("read the newest checkpoint", self._resume)
        else:
            if self.run.pretrained:
                self.store_outage.call("read the pretrained checkpoint", self._load_pretrained)
            self._checkpoint()
        # A predecessor killed mid-update leaves its "training" mark, which would hold the workers back.
        self.redis_outage.call("publish the policy", lambda: (self.bus.clear_training(), self._publish()))
        log.info(
            "run %s: policy v%d published; store %s, Redis %s; PPO updates on %s in %s with %d CPU threads",
            self.run.run_id,
            self.version,
            self.runs.store.uri,
            redact(self.opts.redis_url),
            self.device,
            " or ".join(self.precision_choices)
            + (" (the faster, timed on the first batch)" if len(self.precision_choices) > 1 else ""),
            torch.get_num_threads(),
        )

    def _write_run_files(self) -> None:
        for name, data in self.opts.run_files.items():
            self.runs.write_file(self.run.run_id, name, data)
            # deepracer-utils looks for DeepRacer's copies of these two in model/ and ip/.
            mirror = {"model_metadata.json": "model/", "hyperparameters.json": "ip/"}.get(name)
            if mirror:
                self.runs.write_file(self.run.run_id, mirror + name, data)
        self.runs.write_config(self.run)

    def _build(self) -> None:
        """Network and optimizer for the run's action space (read from the run's stored files)."""
        env_cfg = localize_env(self.run, self.runs, Path(self._workdir.name))
        probe = RacerEnv(config=env_cfg)  # the action space and observation shape the workers will see
        sensors = probe.actions.sensor
        self.obs_spec: ObsSpec = observation_spec(sensors, self.hp.stack_size)
        """The sensors' observation: the camera channels segments carry, and their LiDAR (if any)."""
        self.obs_shape = self.obs_spec.camera_shape(camera_frame_size(probe.observation_space))
        self.n_actions = probe.actions.n if probe.actions.discrete else None
        spec = action_space_spec(probe.actions)
        probe.close()
        torch.manual_seed(self.run.seed)
        # Initialized on the CPU, then moved: the same initial weights on every device.
        self.model: ActorCritic = build_policy(self.obs_shape, spec, self.run.policy, sensors).to(self.device)
        self.precision_choices = precision_candidates(self.opts.precision, self.device)
        """Precisions still in the running: more than one until the first update times them (``auto`` on a CPU)."""
        self.precision: Precision = self.precision_choices[0]
        self.precision_ms: dict[str, float] = {}
        """Milliseconds per minibatch step of each precision timed (empty where only one could run)."""
        self.model.set_trunk_precision(self.precision)
        self.scaler = grad_scaler(self.precision, self.device)
        """The loss scaler of an fp16 trunk on a GPU; None otherwise."""
        self.optimizer = make_optimizer(self.model, self.hp.lr, self.run.policy.l2)
        self.generator = torch.Generator().manual_seed(self.run.seed)

    def _resume(self) -> None:
        newest = self.runs.newest_whole(self.run.run_id)
        pointer = (self.runs.pointer(self.run.run_id, "latest") or {}).get("version")
        if newest is None:
            raise StoreKeyError(
                f"run {self.run.run_id!r} has no whole checkpoint to resume from in {self.runs.store.uri}"
            )
        if pointer != newest:
            # The previous trainer died after writing checkpoint `newest` whole but before moving the pointer.
            log.warning("latest pointer names version %s but version %d is whole: resuming from it", pointer, newest)
            self.runs.set_pointer(self.run.run_id, "latest", newest)
        payload, meta = self.runs.load_checkpoint(self.run.run_id, newest)
        self._load_state(payload, self.runs.load_optimizer(self.run.run_id, newest), newest)
        self.version = int(meta["version"])
        self.stats.env_steps = int(meta.get("env_steps", 0))
        self.stats.episodes = int(meta.get("episodes", 0))
        self.stats.iteration = int(meta.get("iteration", self.version))
        self.stability = Stability.from_meta(meta)
        self.watch.restart(self.stability.floor)
        # A Redis that outlived the previous trainer (compose) still lists the evaluations it wrote to TensorBoard.
        self.tb_evaluated = self.version
        with contextlib.suppress(StoreKeyError):
            lines = self.runs.read_file(self.run.run_id, METRICS_FILE).decode().splitlines()
            self.metrics = [json.loads(line) for line in lines if line.strip()]
        log.info("resumed run %s at version %d (%d env steps)", self.run.run_id, self.version, self.stats.env_steps)

    def _load_state(self, payload: bytes, optimizer: bytes | None, version: int) -> None:
        """Weights from the bytes of checkpoint ``version``, and the optimizer state saved beside them (or, from a
        trainer before racer kept it apart, inside them); without either the optimizer starts afresh. Weights made
        for another network are one CheckpointError naming the run and the version."""
        model_sd, optim_sd = checkpoint_from_bytes(payload)
        load_weights(self.model, model_sd, f"run {self.run.run_id} version {version}")
        if optimizer is not None:
            optim_sd = state_dict_from_bytes(optimizer)
        if optim_sd is None:
            self.optimizer = make_optimizer(self.model, self.hp.lr, self.run.policy.l2)
        else:
            self.optimizer.load_state_dict(optim_sd)
            for group in self.optimizer.param_groups:  # a checkpoint from an older trainer says fused=None
                group["fused"] = self.optimizer.defaults["fused"]

    def _load_pretrained(self) -> None:
        """Version 0 takes another run's weights (``run.pretrained``); a shape mismatch is one clear error."""
        source, _, which = str(self.run.pretrained).partition(":")
        payload, meta = self.runs.load_checkpoint(source, which)
        model_sd, _ = checkpoint_from_bytes(payload)
        detail = misfit(self.model, model_sd)
        if detail:
            raise PretrainedError(
                f"pretrained {self.run.pretrained}: the network's shapes differ from this run's ({detail})"
            )
        self.model.load_state_dict(model_sd)
        log.info("run %s starts from run %s version %s", self.run.run_id, source, meta.get("version"))

    def _checkpoint(self, **extra: object) -> dict:
        """Save the current version (``extra`` goes into its metadata); through a store outage, retry the same
        bytes and metadata until it is whole."""
        payload = checkpoint_to_bytes(self.model.state_dict())
        acting = acting_to_bytes(self.model.state_dict())  # what workers load (float16 weights, half the bytes)
        optimizer = state_dict_to_bytes(self.optimizer.state_dict())
        meta = {
            "env_steps": self.stats.env_steps,
            "episodes": self.stats.episodes,
            "iteration": self.stats.iteration,
            "config": json.loads(self.run.model_dump_json()),
            "stability": asdict(self.stability),
            "created": time.time(),  # fixed here, so that a retried save writes the very same metadata
            **extra,
        }
        return self.store_outage.call(
            f"save checkpoint {self.version}",
            lambda: self.runs.save_checkpoint(self.run.run_id, self.version, payload, meta, optimizer, acting),
        )

    def _prune(self) -> None:
        """Keep the newest ``keep_checkpoints`` checkpoints (and the pointed ones), and the optimizer state only of
        the newest (a resume reads it) and, with the collapse guard on, of those a roll-back may read: the best,
        and every version the guard has not seen evaluated yet (the evaluator lags; any of them may become best)."""
        self.runs.prune_checkpoints(self.run.run_id, self.run.keep_checkpoints)  # with their optimizer states
        keep = {self.version}
        if self.hp.collapse_guard:
            best = (self.runs.pointer(self.run.run_id, "best") or {}).get("version")
            keep |= {best} if isinstance(best, int) else set()
            keep |= set(range(self.watch.seen + 1, self.version))
        self.runs.keep_optimizer_states(self.run.run_id, keep)

    def _publish(self) -> None:
        key = checkpoint_key(self.run.run_id, self.version)
        self.bus.publish_policy(PolicyVersion(version=self.version, checkpoint_key=key, created=time.time()))

    # --- the loop -----------------------------------------------------------------------------
    def run_forever(self) -> None:
        """Read, train, publish until stopped or out of time."""
        deadline = self.opts.deadline
        last_status = 0.0
        while not self.stop.is_set() and (deadline is None or not deadline.passed()):
            self.redis_outage.call("read segments", lambda: self.read(block_ms=500))
            if self.ready():
                self.train()
            if time.monotonic() - last_status > 1.0:
                self.redis_outage.call("write the status", self.housekeeping)
                if self.tb is not None:
                    self.redis_outage.call("read the evaluations", self.tensorboard_evaluations)
                if self.hp.collapse_guard:
                    self.guard()
                last_status = time.monotonic()
            if self._done():
                break
        self.redis_outage.call("write the status", self.write_status)

    def housekeeping(self) -> None:
        """Once a second: the status for ``racer train``, and the policy key again if Redis lost it (a restarted
        Redis without persistence comes back empty; workers and the evaluator need the key to find the policy)."""
        if not self.bus.has_policy():
            log.warning("the policy key was missing from Redis (restarted?): publishing version %d again", self.version)
            self._publish()
        self.write_status()

    def read(self, block_ms: int = 500, count: int = 64) -> int:
        """Pull new segments into the buffer (validating, dropping stale ones); returns how many were kept."""
        entries = self.bus.read_segments(self.last_id, count, block_ms)
        kept = 0
        for entry_id, fields in entries:
            self.last_id = entry_id
            kept += self._accept(fields)
        if entries:
            # Entries read are in the buffer now: free them in Redis at once rather than when MAXLEN pushes them out.
            self.bus.drop_segments_through(self.last_id)
        return kept

    def _accept(self, fields: dict) -> int:
        try:
            seg = decode_segment(fields, self.run.run_id, self.obs_shape, self.n_actions, lidar=self.obs_spec.lidar)
        except ProtocolError as exc:
            self.stats.drop(exc.reason)
            log.warning("dropped a segment: %s", exc)
            return 0
        # A push cut off mid-way can reach Redis twice: redis-py or the worker retries it after a timeout while the
        # first copy is still in flight (TCP delivers it once the network heals). Both copies are the same bytes.
        key = (seg.worker_id, seg.created)
        if key in self._seen:
            self.stats.drop("duplicate", seg.steps)
            log.warning("dropped a duplicate segment from worker %s: a second copy of one already read", seg.worker_id)
            return 0
        self._seen.append(key)
        lag = self.version - seg.policy_version
        self.stats.lag.append(lag)
        if seg.policy_version < self.stability.floor:  # acted by a policy a rollback abandoned
            self.stats.drop("rolled_back", seg.steps)
            return 0
        if lag > self.run.max_policy_lag or lag < 0:
            self.stats.drop("stale" if lag > 0 else "future_version", seg.steps)
            return 0
        self.buffer.append(seg)
        self.stats.by_worker[seg.worker_id] = self.stats.by_worker.get(seg.worker_id, 0) + 1
        self.stats.env_steps += seg.steps
        self.stats.episodes += len(seg.episodes)
        self.stats.recent = (self.stats.recent + seg.episodes)[-100:]
        return 1

    def ready(self) -> bool:
        """True once the buffer holds ``num_episodes_between_training`` finished episodes and a batch."""
        episodes = sum(len(s.episodes) for s in self.buffer)
        steps = sum(s.steps for s in self.buffer)
        return episodes >= self.hp.num_episodes_between_training and steps >= self.hp.batch_size

    def train(self) -> dict[str, float]:
        """One PPO iteration on the buffer, then checkpoint and publish the next version."""
        t0 = time.monotonic()
        self.redis_outage.call("mark the update", lambda: self.bus.mark_training(self.version))
        batch = make_batch(self.buffer, self.hp.discount_factor, self.run.hyperparams.gae_lambda).to(self.device)
        episodes = [e for s in self.buffer for e in s.episodes]
        lags = [self.version - s.policy_version for s in self.buffer]
        self.buffer = []
        self._set_lr(self.learning_rate())
        beta_entropy = self.entropy_coef()
        self._choose_precision(batch, beta_entropy)
        self.model.train()
        result = update(
            self.model,
            self.optimizer,
            batch,
            epochs=self.hp.num_epochs,
            minibatch_size=self.hp.batch_size,
            clip_eps=self.hp.clip_epsilon,
            beta_entropy=beta_entropy,
            value_coef=self.hp.value_loss_coef,
            loss_type=self.hp.value_loss_kind,
            max_grad_norm=self.hp.max_grad_norm,
            generator=self.generator,
            target_kl=self.hp.target_kl,
            scaler=self.scaler,
        )
        result["beta_entropy"] = beta_entropy
        self.model.eval()
        self.version += 1
        self.stats.iteration += 1
        self._checkpoint()
        self.redis_outage.call("publish the policy", lambda: (self._publish(), self.bus.clear_training()))
        self.store_outage.call("prune checkpoints", self._prune)
        self._record(result, episodes, lags, batch, time.monotonic() - t0)
        log.info("iteration %d: version %d, %s", self.stats.iteration, self.version, result)
        return result

    def _choose_precision(self, batch: PPOBatch, beta_entropy: float) -> None:
        """``auto`` on a CPU with native bf16: before the first update, time both precisions on a copy of the
        network and the batch's first minibatch, and train in the faster from then on."""
        if len(self.precision_choices) < 2:
            return
        hp = self.hp
        minibatch = batch.select(torch.arange(min(len(batch), hp.batch_size), device=batch.obs.device))
        step_args = (hp.clip_epsilon, beta_entropy, hp.value_loss_coef, hp.value_loss_kind, hp.max_grad_norm)
        self.precision_ms = time_precisions(self.model, minibatch, self.precision_choices, step_args, hp.lr)
        self.precision = fastest(self.precision_ms)
        self.precision_choices = (self.precision,)
        self.model.set_trunk_precision(self.precision)
        timings = ", ".join(f"{p} {ms:.1f} ms" for p, ms in self.precision_ms.items())
        log.info("PPO updates in %s: the faster per minibatch step on this machine (%s)", self.precision, timings)

    def learning_rate(self) -> float:
        """The learning rate of the next policy update: the schedule's value (``lr`` itself when constant, as in
        DeepRacer), times the cool-down's factor in the last ``lr_cooldown`` of the time limit (counted back from the
        run's deadline, the one ``racer train`` stops every process at), times the rollbacks' ``lr_scale``."""
        hp = self.hp
        base = scheduled(hp.lr_schedule, hp.lr, hp.lr_final_fraction, self.stats.iteration, hp.schedule_updates)
        deadline = self.opts.deadline
        if hp.lr_cooldown is not None and deadline is not None:
            base *= cooldown_factor(deadline.left(), deadline.limit_s, hp.lr_cooldown, hp.lr_final_fraction)
        return base * self.stability.lr_scale

    def entropy_coef(self) -> float:
        """The entropy coefficient of the next policy update: ``beta_entropy`` itself when constant (DeepRacer)."""
        hp = self.hp
        return scheduled(
            hp.entropy_schedule, hp.beta_entropy, hp.entropy_final_fraction, self.stats.iteration, hp.schedule_updates
        )

    def _set_lr(self, lr: float) -> None:
        for group in self.optimizer.param_groups:
            group["lr"] = lr

    # --- the collapse guard -------------------------------------------------------------------
    def guard(self) -> bool:
        """Read the evaluator's new summaries; roll back when they have collapsed (see ``CollapseWatch``).

        The evaluator stores each evaluation (and moves ``best``) before it pushes the summary to Redis, so the
        best read here already accounts for every summary read. Returns True if it rolled the run back.
        """
        fresh = self.redis_outage.call("read the evaluations", self._new_evaluations)
        if not fresh:
            return False
        best = self.store_outage.call("read the best evaluation", self._best_evaluation)
        for evaluation in fresh:
            if self.watch.observe(evaluation, best) and best is not None:
                return self._roll_back(best, list(self.watch.streak))
        return False

    def _new_evaluations(self) -> list[dict]:
        """The evaluator's summaries (``trainer.evaluator._report``) the watch has not looked at yet."""
        # A malformed entry (not the evaluator's) is skipped: it says nothing about a checkpoint.
        summaries, _ = self.bus.evaluations(last=EVALUATION_WINDOW)
        return self.watch.fresh([s.model_dump() for s in summaries])

    def _best_evaluation(self) -> BestEvaluation | None:
        """The ``best`` checkpoint's evaluation (version, completion rate, mean lap), or None while there is none."""
        pointer = self.runs.pointer(self.run.run_id, "best")
        if pointer is None:
            return None
        version = int(pointer["version"])
        try:
            record = json.loads(self.runs.read_file(self.run.run_id, evaluation_name(version)))
            return BestEvaluation(version, float(record["completion_rate"]), _mean_lap(record))
        except (StoreKeyError, KeyError, TypeError, ValueError):
            return None

    def _roll_back(self, best: BestEvaluation, collapsed: list[dict]) -> bool:
        """Go back to the best checkpoint's weights and optimizer at a lower learning rate, as a new version.

        The buffer and later segments of older versions are dropped (``rolled_back``): they were acted by the
        collapsed policies. Returns False if the best checkpoint could not be read (counted as a collapse only).
        """
        best_version, best_completion, best_lap = best
        self.stability.collapses += 1
        try:
            payload, _ = self.store_outage.call(
                f"read best checkpoint {best_version}", lambda: self.runs.load_checkpoint(self.run.run_id, best_version)
            )
            optimizer = self.store_outage.call(
                f"read best checkpoint {best_version}'s optimizer",
                lambda: self.runs.load_optimizer(self.run.run_id, best_version),
            )
        except StoreKeyError as exc:
            log.warning("collapse guard: collapse %d detected but not rolled back: %s", self.stability.collapses, exc)
            self.watch.restart(self.watch.floor)
            return False
        old_lr = self.learning_rate()
        if optimizer is None:  # not kept (a best from before the guard was on): its weights, a fresh optimizer
            log.warning("collapse guard: v%d's optimizer state was not kept; rolling back its weights", best_version)
        self._load_state(payload, optimizer, best_version)
        self.stability.lr_scale = rolled_back_lr_scale(
            self.stability.lr_scale, self.hp.collapse_lr_factor, self.hp.collapse_lr_floor
        )
        self.stability.rollbacks += 1
        if any(not self._lost_completion(e, best_completion) for e in collapsed):
            self.stability.slow_rollbacks += 1
        for _ in self.buffer:
            self.stats.drop("rolled_back")
        self.buffer = []
        self.version += 1
        self.stability.floor = self.version
        self.watch.restart(self.version)
        self._set_lr(self.learning_rate())  # the best's optimizer state carries the best's learning rate
        self._checkpoint(rolled_back_to=best_version)
        self.redis_outage.call("publish the policy", self._publish)
        self.store_outage.call("prune checkpoints", self._prune)
        log.warning(
            "collapse guard: v%s completed %s of their evaluation trials against best v%d's %.2f "
            "(collapsed at <= %.2f)%s; rolled back to v%d's weights and optimizer as v%d, learning rate %.3g -> %.3g "
            "(collapses %d, rollbacks %d)",
            ", v".join(str(e["version"]) for e in collapsed),
            ", ".join(f"{e['completion_rate']:.2f}" for e in collapsed),
            best_version,
            best_completion,
            best_completion * (1.0 - self.hp.collapse_drop),
            self._slowdown_words(collapsed, best_lap),
            best_version,
            self.version,
            old_lr,
            self.learning_rate(),
            self.stability.collapses,
            self.stability.rollbacks,
        )
        if self.tb is not None:
            self.tb.add_scalar("trainer/rollbacks", self.stability.rollbacks, self.stats.env_steps)
        return True

    def _lost_completion(self, evaluation: dict, best_completion: float) -> bool:
        """The evaluation collapsed by its completion (``is_collapsed``), whatever its pace."""
        hp = self.hp
        return is_collapsed(evaluation["completion_rate"], best_completion, hp.collapse_min_best, hp.collapse_drop)

    def _slowdown_words(self, collapsed: list[dict], best_lap: float | None) -> str:
        """The mean laps of the collapsed evaluations against the best's, for the rollback's log line (when the
        guard watches lap times)."""
        if self.hp.collapse_slowdown is None or best_lap is None:
            return ""
        laps = ", ".join("-" if e.get("mean_lap_s") is None else f"{e['mean_lap_s']:.2f}" for e in collapsed)
        limit = best_lap * (1.0 + self.hp.collapse_slowdown)
        return f", mean laps {laps} s against its {best_lap:.2f} s (slower than {limit:.2f} s)"

    def _record(
        self, losses: dict, episodes: list[EpisodeSummary], lags: list[int], batch: PPOBatch, train_s: float
    ) -> None:
        """Append this iteration's figures to the run's metrics.jsonl (rewritten whole: object stores can't append)."""
        row = {
            "iteration": self.stats.iteration,
            "policy_version": self.version,
            "env_steps": self.stats.env_steps,
            "episodes": len(episodes),
            "batch_steps": int(batch.actions.shape[0]),
            "mean_progress": statistics.fmean(e.progress for e in episodes) if episodes else 0.0,
            "mean_reward": statistics.fmean(e.reward for e in episodes) if episodes else 0.0,
            "laps_completed": sum(e.status == "lap_complete" for e in episodes),
            "mean_episode_steps": statistics.fmean(e.steps for e in episodes) if episodes else 0.0,
            "mean_lap_time_s": statistics.fmean(laps)
            if (laps := [e.lap_time_s for e in episodes if e.lap_time_s])
            else None,
            "learning_rate": self.optimizer.param_groups[0]["lr"],
            "steps_per_s": self._steps_per_s(),
            "mean_policy_lag": statistics.fmean(lags) if lags else 0.0,
            "train_s": train_s,
            "dropped": dict(self.stats.dropped),
            "dropped_steps": self.stats.dropped_steps,
            "collapses": self.stability.collapses,
            "rollbacks": self.stability.rollbacks,
            "slow_rollbacks": self.stability.slow_rollbacks,
            "time": time.time(),
            **{k: float(v) for k, v in losses.items()},
        }
        self.metrics.append(row)
        text = "".join(json.dumps(m) + "\n" for m in self.metrics)
        self.store_outage.call("write metrics", lambda: self.runs.write_file(self.run.run_id, METRICS_FILE, text))
        self._tensorboard(row, losses, episodes)

    def _tensorboard(self, row: dict, losses: dict, episodes: list[EpisodeSummary]) -> None:
        """The same figures as TensorBoard scalars (trainer/…, and episode/… per worker episode)."""
        if self.tb is None:
            return
        step = row["env_steps"]
        for name, value in losses.items():
            self.tb.add_scalar(f"trainer/{name}", value, step)
        self.tb.add_scalar("trainer/learning_rate", self.optimizer.param_groups[0]["lr"], step)
        self.tb.add_scalar("trainer/policy_lag", row["mean_policy_lag"], step)
        self.tb.add_scalar("trainer/steps_per_s", row["steps_per_s"], step)
        self.tb.add_scalar("trainer/mean_progress", row["mean_progress"], step)
        self.tb.add_scalar("trainer/collapses", row["collapses"], step)
        self.tb.add_scalar("trainer/rollbacks", row["rollbacks"], step)
        for e in episodes:
            self.tb.add_scalar("episode/reward", e.reward, step)
            self.tb.add_scalar("episode/progress", e.progress, step)
            self.tb.add_scalar("episode/length", e.steps, step)
            if e.lap_time_s is not None:
                self.tb.add_scalar("episode/lap_time_s", e.lap_time_s, step)
        self.tb.flush()

    def tensorboard_evaluations(self) -> int:
        """The evaluator's new summaries as TensorBoard scalars (``evaluation/…``, at the evaluated checkpoint's env
        steps, beside the training curves); returns how many were new.

        The trainer writes them, not the evaluator: it owns the run's one TensorBoard writer, and the evaluator may
        run on another machine (compose), whose summaries reach the trainer through Redis as the collapse guard's do.
        """
        if self.tb is None:
            return 0
        summaries, _ = self.bus.evaluations(last=EVALUATION_WINDOW)
        new = sorted((s for s in summaries if s.version > self.tb_evaluated), key=lambda s: s.version)
        for s in new:
            step = self.stats.env_steps if s.env_steps is None else s.env_steps
            self.tb.add_scalar("evaluation/completion_rate", s.completion_rate, step)
            self.tb.add_scalar("evaluation/mean_progress", s.mean_progress, step)
            self.tb.add_scalar("evaluation/score", s.score, step)
            for name, value in (("mean_lap_s", s.mean_lap_s), ("best_lap_s", s.best_lap_s)):
                if value is not None:  # no lap completed: no lap time
                    self.tb.add_scalar(f"evaluation/{name}", value, step)
            self.tb_evaluated = s.version
        if new:
            self.tb.flush()
        return len(new)

    def _done(self) -> bool:
        # As the simapp's training_worker.py: term_cond_max_episodes bounds the policy updates (its loop counts one
        # per train() call); term_cond_avg_score stops nothing there, so it stops nothing here.
        return self.stats.iteration >= self.hp.term_cond_max_episodes

    def _steps_per_s(self) -> float:
        elapsed = time.monotonic() - self.stats.started
        return self.stats.env_steps / elapsed if elapsed > 0 else 0.0

    def status(self) -> dict:
        """Progress figures for the display and for ``racer train``."""
        recent = self.stats.recent[-20:]
        return {
            "iteration": self.stats.iteration,
            "policy_version": self.version,
            "env_steps": self.stats.env_steps,
            "episodes": self.stats.episodes,
            "steps_per_s": self._steps_per_s(),
            "mean_progress": statistics.fmean(e.progress for e in recent) if recent else 0.0,
            "mean_reward": statistics.fmean(e.reward for e in recent) if recent else 0.0,
            "dropped": dict(self.stats.dropped),
            "dropped_steps": self.stats.dropped_steps,
            "max_lag": max(list(self.stats.lag)[-200:], default=0),
            "workers": self.workers(),
            "silent_workers": sorted(self.silent),
            "segments_by_worker": dict(self.stats.by_worker),
            "outages": {"redis": self.redis_outage.outages, "store": self.store_outage.outages},
            "collapses": self.stability.collapses,
            "rollbacks": self.stability.rollbacks,
            "slow_rollbacks": self.stability.slow_rollbacks,
            "precision": self.precision,
            "precision_ms": dict(self.precision_ms),
            "device": str(self.device),
            "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "time": time.time(),
        }

    def write_status(self) -> None:
        """Publish the status to Redis (a key with a TTL) for ``racer train``'s live line."""
        self.bus.set_trainer_status(self.status())

    def workers(self) -> list[dict]:
        """Live workers from their heartbeat keys (SCAN, never KEYS); names, once, each worker that went silent."""
        beats, bad = self.bus.heartbeats()
        for _ in range(bad):
            self.stats.drop("bad_heartbeat")
        out = [hb.model_dump() for hb in beats]
        self._note_silent({w["worker_id"]: w for w in out})
        return out

    def _note_silent(self, alive: dict[str, dict]) -> None:
        """Log a worker whose heartbeat key expired (killed, hung or cut off), and one that comes back."""
        for wid, hb in self.live.items():
            if wid not in alive and wid not in self.silent:
                self.silent[wid] = hb
                log.warning(
                    "worker %s is silent: no heartbeat for %.0f s (TTL %.0f s expired); last seen at policy v%d "
                    "after %d segments; training goes on without it",
                    wid,
                    time.time() - hb["time"],
                    self.run.heartbeat_ttl_s,
                    hb["policy_version"],
                    hb["segments"],
                )
        for wid in alive:
            if self.silent.pop(wid, None) is not None:
                log.warning("worker %s is sending heartbeats again", wid)
        self.live.update(alive)


def make_optimizer(model: torch.nn.Module, lr: float, l2: float) -> torch.optim.Adam:
    """Adam with its fused kernel: the same update as the per-parameter loop, one vectorized pass over the 6 M
    weights. The loop took a quarter of each minibatch step on the CPU (docs/speed.md)."""
    return torch.optim.Adam(model.parameters(), lr=lr, weight_decay=l2, fused=True)


def _summary_writer(store: str, run_id: str):
    """A TensorBoard writer in the run's folder (TensorBoard writes local files: ./runs/<id>/ for an S3 store)."""
    from torch.utils.tensorboard import SummaryWriter

    return SummaryWriter(log_dir=str(local_run_dir(store, run_id) / "tensorboard"))


def make_batch(segments: list[Segment], gamma: float, lam: float) -> PPOBatch:
    """GAE per segment (bootstrapping from the values the workers sent), then one flat batch on the CPU (with the
    segments' LiDAR vectors when they carry them: all or none do, ``decode_segment`` checks them against the run's
    sensors); ``PPOBatch.to`` moves it to the trainer's device."""
    parts = {k: [] for k in ("obs", "actions", "logp", "adv", "ret", "values", "lidar")}
    for seg in segments:
        a = seg.arrays
        # Arrays decoded from Redis are read-only views of the message bytes: torch wants its own copy.
        t = {k: torch.tensor(a[k], dtype=torch.float32) for k in ("rewards", "values", "next_values")}
        adv, ret = compute_gae(
            t["rewards"],
            t["values"],
            torch.tensor(a["terminated"], dtype=torch.float32),
            torch.tensor(a["truncated"], dtype=torch.float32),
            t["next_values"],
            gamma,
            lam,
        )
        parts["obs"].append(torch.from_numpy(a["obs"].copy()))
        if "lidar" in a:
            parts["lidar"].append(torch.from_numpy(a["lidar"].copy()))
        parts["actions"].append(torch.from_numpy(a["actions"].copy()))
        parts["logp"].append(torch.from_numpy(a["logp"].copy()))
        parts["values"].append(t["values"])
        parts["adv"].append(adv)
        parts["ret"].append(ret)
    cat = {k: torch.cat(v) for k, v in parts.items() if v}
    return PPOBatch(
        obs=cat["obs"],
        actions=cat["actions"],
        old_logp=cat["logp"],
        advantages=cat["adv"],
        returns=cat["ret"],
        old_values=cat["values"],
        lidar=cat.get("lidar"),
    )


def run_trainer(run: RunConfig, opts: TrainerOptions, stop: threading.Event | None = None) -> dict:
    """The ``racer trainer`` process: start or resume the run, then train until stopped; returns the status."""
    torch.set_num_threads(max(1, opts.torch_threads))
    trainer = Trainer(run, opts, stop)
    try:
        trainer.start()
        trainer.run_forever()
        return trainer.status()
    except InterruptedError:  # stopped (SIGTERM) while Redis or the store was unreachable
        log.warning("stopped during an outage at version %d", trainer.version)
        return {"policy_version": trainer.version, "env_steps": trainer.stats.env_steps}
    finally:
        if trainer.tb is not None:
            trainer.tb.close()
        trainer._workdir.cleanup()
