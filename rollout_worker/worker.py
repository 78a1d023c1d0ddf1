"""The rollout worker: poll the policy, run episodes, push segments to Redis, keep a heartbeat.

A worker runs K envs (``--envs-per-worker``, 1 by default) side by side on its track, each with its own seed (so
its own randomization), and acts for all K in one batched forward pass per step (``rollout_worker.rollouts``),
through an ONNX Runtime copy of the network (``rollout_worker/onnx_policy.py``): a one-env worker's time goes
mostly to that forward pass, not to the env, and a batch of K costs much less than K batches of one
(docs/speed.md). It reads everything about the run from the store (``config.json``, the reward function, the
action space) so a worker on another machine needs only the run id, the Redis URL and the store URI.

Each env fills its own segment: the trainer's GAE (``trainer/learner.py: make_batch``) takes a segment as
consecutive steps of one env, so a collect pushes K segments, in one Redis round trip. Env j of worker k:

* is seeded with run seed + 1000·k + j (env 0 has the seed a one-env worker always had, so K = 1 is the worker as
  it was, segment for segment);
* names its segments ``{worker_id}/{j}`` when K > 1 (``{worker_id}`` when K = 1): the trainer tells segments apart
  by worker id and creation time (``trainer/intake.py: SegmentIntake.accept``), and a segment's ``episode_id``
  counts the episodes of the env that drove it (its own frame stack, episode counter and episode summaries);
* shares the worker's policy version: every step of a collect is acted by the version the collect started with,
  and a newer one is loaded only between collects, for all K at once.

The heartbeat stays one per worker process (``{worker_id}``), counting the env steps and segments of all K envs.
Training sim-traces stay one CSV per worker and policy version (``model_store/runs.py: simtrace_key``); see
:meth:`rollout_worker.rollouts.Rollouts.take_simtrace` for how the K envs' episodes are numbered in it.
"""

from __future__ import annotations

import logging
import os
import resource
import socket
import tempfile
import threading
import time
from dataclasses import KW_ONLY, dataclass
from functools import partial
from pathlib import Path

import torch

from common.action_space import load_action_space
from common.bus import Bus
from common.config import ENV_SEED_STRIDE, MAX_ENVS_PER_WORKER, EnvConfig, RunConfig
from common.defaults import DEFAULT_GIVE_UP_S
from common.errors import OptionError
from common.policy import PolicyNetwork
from common.protocol import Heartbeat, PolicyVersion, ProtocolError, Segment, encode_segment
from common.redis_util import redact
from common.retry import Outage, redis_transient
from common.weights import acting_from_bytes, checkpoint_from_bytes, load_teacher
from model_store import RunStore, StoreError, is_transient, open_store
from model_store.localize import localize_env
from model_store.runs import simtrace_key
from rollout_worker.onnx_policy import Actor, acting_copy
from rollout_worker.rollouts import Rollouts, segment_worker_ids
from rollout_worker.teacher import Teacher
from rollout_worker.watch import WatchPublisher

log = logging.getLogger("racer.worker")


@dataclass
class WorkerOptions:
    """How to reach the run, and who this worker is (keyword-only after the store)."""

    run_id: str
    redis_url: str
    store: str = "."
    _: KW_ONLY
    s3_endpoint: str | None = None
    worker_index: int | None = 0
    """Index k: seeds env j with run seed + 1000·k + j, drives the run's worker_env(k) and names the sim-trace folder.
    None = take the next free index from Redis (scaled compose workers share one set of options)."""
    worker_id: str = ""
    """Name in heartbeats and segments; default ``{host}-{pid}-{index}``."""
    policy_wait_s: float = 300.0
    """How long to wait for the trainer's first policy before giving up, seconds."""
    outage_s: float = DEFAULT_GIVE_UP_S
    """How long to ride out one Redis or store outage before exiting with an error, seconds."""
    envs_per_worker: int = 1
    """K: envs stepped side by side, acted for in one batched forward pass per step (see the module doc)."""

    def __post_init__(self) -> None:
        k = self.envs_per_worker
        if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= MAX_ENVS_PER_WORKER:
            raise OptionError(f"--envs-per-worker must be an integer from 1 to {MAX_ENVS_PER_WORKER}, got {k!r}")


class RolloutWorker:
    """One worker process's state: its envs, the policy, Redis and store handles."""

    def __init__(
        self, opts: WorkerOptions, stop: threading.Event | None = None, *, runs: RunStore | None = None
    ) -> None:
        """``runs``: the run store to read the run and its policies from, instead of opening ``opts.store`` (a bench
        passes one over a store that counts the bytes it reads)."""
        self.opts = opts
        self.stop = stop or threading.Event()
        self.bus = Bus.connect(opts.redis_url, opts.run_id)
        self.runs = runs or RunStore(open_store(opts.store, opts.s3_endpoint))
        self.redis_outage = Outage(f"Redis at {redact(opts.redis_url)}", redis_transient, log, self.stop, opts.outage_s)
        self.store_outage = Outage(f"store {self.runs.store.uri}", is_transient, log, self.stop, opts.outage_s)
        if opts.worker_index is None:
            opts.worker_index = self.redis_outage.call("take a worker index", self.bus.take_worker_slot)
        self.worker_id = opts.worker_id or f"{socket.gethostname()}-{os.getpid()}-{opts.worker_index}"
        self.policy_version = -1
        self.segments = 0
        self.rollouts: Rollouts | None = None
        self._acting: tuple[int, Actor] | None = None
        """(policy version, the copy of the network that acts for it)."""
        self._workdir = tempfile.TemporaryDirectory(prefix="racer-worker-")

    @property
    def env_steps(self) -> int:
        """Env steps of all this worker's envs so far."""
        return self.rollouts.env_steps if self.rollouts else 0

    @property
    def episodes(self) -> int:
        """Episodes finished by all this worker's envs so far."""
        return self.rollouts.episodes if self.rollouts else 0

    # --- set-up -------------------------------------------------------------------------------
    def start(self) -> None:
        """Wait for the first policy, then build the envs and the network from the run's files."""
        first = self._wait_for_policy()
        self.run: RunConfig = self.store_outage.call("read the run", partial(self.runs.read_config, self.opts.run_id))
        config = self.store_outage.call("read the run's files", self._env_config)
        k, n = self.opts.worker_index, self.opts.envs_per_worker
        seeds = [self.run.seed + ENV_SEED_STRIDE * k + j for j in range(n)]
        teacher = None
        if self.run.distill is not None:
            actions = load_action_space(config.action_space)
            model = self.store_outage.call("read the teacher", partial(load_teacher, self.runs, self.run, actions))
            teacher = Teacher(model, seeds[0])
        self.rollouts = Rollouts(self.run, config, seeds, segment_worker_ids(self.worker_id, n), teacher)
        log.info("worker %s: %d env(s) on %s, seeds %s", self.worker_id, n, self.rollouts.track_name, seeds)
        self.model: PolicyNetwork = self.rollouts.build_policy()
        self._load(first)
        for e in self.rollouts.envs:  # racer view: nearly free unless a page watches (rollout_worker/watch.py)
            e.watch = WatchPublisher(self.bus, e.segment_worker_id, self.opts.worker_index, self.rollouts.track_name)
        self.rollouts.reset()

    def _env_config(self) -> EnvConfig:
        """The run's env (reward function and action space from the store), in this worker's own world."""
        return localize_env(self.run, self.runs, Path(self._workdir.name), self.opts.worker_index)

    def _wait_for_policy(self) -> PolicyVersion:
        deadline = time.monotonic() + self.opts.policy_wait_s
        while not self.stop.is_set():
            pv = self.redis_outage.call("wait for the first policy", self.bus.policy)
            if pv is not None:
                return pv
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"no policy published for run {self.opts.run_id!r} after {self.opts.policy_wait_s} s"
                )
            self.stop.wait(0.2)
        raise InterruptedError("stopped while waiting for the first policy")

    def _load(self, pv: PolicyVersion) -> None:
        self._upload_simtrace()  # the iteration acted with the previous version ends here
        self.model.load_state_dict(self.store_outage.call(f"load policy v{pv.version}", partial(self._weights, pv)))
        self.policy_version = pv.version
        self.policy_loaded_at = time.time()
        log.info("worker %s acting with policy version %d", self.worker_id, pv.version)

    def _weights(self, pv: PolicyVersion) -> dict:
        """Version ``pv``'s acting copy (float16 weights, half the download), in float32; the checkpoint itself for a
        version without one (a run from before acting copies, resumed)."""
        acting = self.runs.load_acting(self.opts.run_id, pv.version)
        if acting is not None:
            return acting_from_bytes(acting)
        payload, _ = self.runs.load_checkpoint(self.opts.run_id, pv.version)
        return checkpoint_from_bytes(payload)[0]

    # --- the loop -----------------------------------------------------------------------------
    def run_forever(self) -> None:
        """Collect and push segments until stopped."""
        while not self.stop.is_set():
            segments = self.collect()
            # Through a Redis outage the segments wait here, whole; they are never sent in parts.
            self.redis_outage.call("push segments", partial(self.push, segments))
            if not self.redis_outage.call("poll the policy", self.poll_policy):
                self.redis_outage.call("wait for the update", self.wait_while_training)

    def wait_while_training(self, timeout_s: float = 300.0) -> None:
        """With ``max_policy_lag`` 0, segments collected during a PPO update would be dropped as stale: wait
        for the new policy instead, leaving the CPU to the trainer (DeepRacer's workers wait the same way)."""
        if self.run.max_policy_lag > 0:
            return
        deadline = time.monotonic() + timeout_s
        next_beat = time.monotonic() + 1.0
        while not self.stop.is_set() and time.monotonic() < deadline and self.bus.training():
            if self.poll_policy():
                return
            if time.monotonic() > next_beat:  # a long PPO update must not make the trainer think we died
                self.beat()
                next_beat = time.monotonic() + max(1.0, self.run.heartbeat_ttl_s / 3)
            self.stop.wait(0.05)
        self.poll_policy()

    def collect(self) -> list[Segment]:
        """Run ``segment_steps`` steps of each env with the current policy: one segment per env."""
        return self.rollouts.collect(self._actor(), self.policy_version)

    def _actor(self) -> Actor:
        """The copy of the loaded network that acts (``rollout_worker/onnx_policy.py``), made once per version."""
        if self._acting is None or self._acting[0] != self.policy_version:
            self._acting = (self.policy_version, acting_copy(self.model))
        return self._acting[1]

    def push(self, segments: list[Segment]) -> None:
        """Send a collect's segments (one XADD each to the capped stream, all in one round trip) and refresh the
        heartbeat."""
        fields = [encode_segment(seg) for seg in segments]
        self.bus.push_segments(fields, self._heartbeat(len(segments)), self.run.stream_maxlen, self._heartbeat_ex())
        self.segments += len(segments)

    def beat(self) -> None:
        """Refresh the heartbeat without sending a segment (while waiting for the trainer)."""
        self.bus.beat(self._heartbeat(), self._heartbeat_ex())

    def _heartbeat_ex(self) -> int:
        return int(self.run.heartbeat_ttl_s) + 1

    def _heartbeat(self, sending: int = 0) -> Heartbeat:
        return Heartbeat(
            worker_id=self.worker_id,
            pid=os.getpid(),
            host=socket.gethostname(),
            policy_version=self.policy_version,
            env_steps=self.env_steps,
            segments=self.segments + sending,
            time=time.time(),
            track=self.rollouts.track_name,
            policy_loaded_at=self.policy_loaded_at,
            max_rss_mb=peak_rss_mb(),
        )

    def poll_policy(self, *, reload: bool = False) -> bool:
        """Switch to a newer policy if one was published. Called between segments (every ~50 ms of work):
        one GET of the version key is cheaper than keeping a pub/sub connection and just as prompt. ``reload`` loads
        the published version even when it is the one acting (what a bench times as one policy download)."""
        try:
            pv = self.bus.policy()
        except ProtocolError as exc:
            log.warning("ignoring malformed policy version: %s", exc)
            return False
        if pv is None or (pv.version <= self.policy_version and not reload):
            return False
        self._load(pv)
        return True

    def close(self) -> None:
        """Upload the last (partial) iteration's sim-trace; release the envs and the temporary files."""
        self._upload_simtrace(include_open=True)
        if self.rollouts is not None:
            for e in self.rollouts.envs:
                if e.watch is not None:
                    e.watch.close()
            self.rollouts.close()
        self._workdir.cleanup()

    # --- DeepRacer sim-traces (common/simtrace.py) ----------------------------------------------
    def _upload_simtrace(self, include_open: bool = False) -> None:
        """Put the rows recorded with ``policy_version`` in ``runs/<id>/<k>/training-simtrace/<version>-iteration.csv``.

        One small object per iteration (a few ms on a local store). A failed upload loses that log, not the run."""
        text = self.rollouts.take_simtrace(include_open) if self.rollouts is not None else None
        if text is None or self.policy_version < 0:
            return
        try:
            key = simtrace_key(self.opts.run_id, "training", self.policy_version, self.opts.worker_index)
            self.runs.store.put(key, text.encode())
        except (StoreError, OSError, ValueError) as exc:
            log.warning("could not upload the sim-trace of iteration %d: %s", self.policy_version, exc)


def peak_rss_mb() -> float:
    """Peak resident memory of this process, MB (Linux reports ru_maxrss in kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_worker(opts: WorkerOptions, stop: threading.Event | None = None) -> None:
    """The ``racer worker`` process: set up, then collect and push until stopped."""
    torch.set_num_threads(1)  # workers are many single-core processes
    worker = RolloutWorker(opts, stop)
    try:
        worker.start()
        worker.run_forever()
    except InterruptedError:
        pass
    finally:
        worker.close()
