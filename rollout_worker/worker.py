"""The rollout worker: poll the policy, run episodes, push segments to Redis, keep a heartbeat.

A worker runs K envs (``--envs-per-worker``, 1 by default) side by side on its track, each with its own seed (so
its own randomization), and acts for all K in one batched forward pass per step (:class:`Rollouts`), through an
ONNX Runtime copy of the network (``rollout_worker/onnx_policy.py``): a one-env worker's time goes mostly to that
forward pass, not to the env, and a batch of K costs much less than K batches of one (docs/speed.md). It reads
everything about the run from the store (``config.json``, the reward function, the action space) so a worker on
another machine needs only the run id, the Redis URL and the store URI.

Each env fills its own segment: the trainer's GAE (``trainer/process.py: make_batch``) takes a segment as
consecutive steps of one env, so a collect pushes K segments, in one Redis round trip. Env j of worker k:

* is seeded with run seed + 1000·k + j (env 0 has the seed a one-env worker always had, so K = 1 is the worker as
  it was, segment for segment);
* names its segments ``{worker_id}/{j}`` when K > 1 (``{worker_id}`` when K = 1): the trainer tells segments apart
  by worker id and creation time (``Trainer._accept``), and a segment's ``episode_id`` counts the episodes of the
  env that drove it (its own frame stack, episode counter and episode summaries);
* shares the worker's policy version: every step of a collect is acted by the version the collect started with,
  and a newer one is loaded only between collects, for all K at once.

The heartbeat stays one per worker process (``{worker_id}``), counting the env steps and segments of all K envs.
Training sim-traces stay one CSV per worker and policy version (``model_store/runs.py: simtrace_key``); see
:meth:`Rollouts.take_simtrace` for how the K envs' episodes are numbered in it.
"""

from __future__ import annotations

import logging
import os
import resource
import socket
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
import torch

from common.bus import Bus
from common.config import ENV_SEED_STRIDE, MAX_ENVS_PER_WORKER, EnvConfig, RunConfig
from common.errors import OptionError
from common.framestack import FrameStack
from common.policy import ActorCritic, acting_from_bytes, action_space_spec, build_policy, checkpoint_from_bytes
from common.protocol import EpisodeSummary, Heartbeat, PolicyVersion, ProtocolError, Segment, encode_segment
from common.redis_util import redact
from common.retry import DEFAULT_GIVE_UP_S, Outage, redis_transient
from common.sensors import ObsSpec, camera_frame_size, observation_spec, split_observation
from common.simtrace import SimTraceRecorder, merged_csv
from model_store import RunStore, StoreError, is_transient, open_store
from model_store.localize import localize_env
from model_store.runs import simtrace_key
from rollout_worker.onnx_policy import Actor, acting_copy
from rollout_worker.watch import WatchPublisher
from sim.env import RacerEnv

log = logging.getLogger("racer.worker")


@dataclass
class WorkerOptions:
    """How to reach the run, and who this worker is."""

    run_id: str
    redis_url: str
    store: str = "."
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


@dataclass
class _Rollout:
    """Arrays being filled for the current segment."""

    obs: list = field(default_factory=list)
    lidar: list = field(default_factory=list)
    """The LiDAR part of each o_t (only with a LiDAR sensor)."""
    actions: list = field(default_factory=list)
    rewards: list = field(default_factory=list)
    terminated: list = field(default_factory=list)
    truncated: list = field(default_factory=list)
    logp: list = field(default_factory=list)
    values: list = field(default_factory=list)
    next_values: list = field(default_factory=list)
    episode_id: list = field(default_factory=list)
    episodes: list = field(default_factory=list)


@dataclass
class _Env:
    """One of a worker's envs, and what it carries from one segment to the next."""

    env: RacerEnv
    index: int
    """j, its place among the worker's envs."""
    seed: int
    segment_worker_id: str
    """The worker id its segments carry."""
    stack: FrameStack
    simtrace: SimTraceRecorder = field(default_factory=SimTraceRecorder)
    """DeepRacer sim-trace rows of the current iteration."""
    episode: int = 0
    """Episodes this env has finished: the number of the one it is driving."""
    ep_reward: float = 0.0
    obs: np.ndarray | None = None
    """The stacked camera observation the next action is chosen from."""
    lidar: np.ndarray | None = None
    """Its LiDAR vector (None without a LiDAR sensor)."""
    watch: WatchPublisher | None = None
    """What ``racer view`` shows of this env (its pose and camera), published only while a page watches."""

    def observe(self, observation: np.ndarray | dict, first: bool = False) -> None:
        """Take an env observation apart: its camera frame onto the stack (``obs``), its LiDAR vector (not stacked,
        as in DeepRacer) into ``lidar``."""
        camera, self.lidar = split_observation(observation)
        self.obs = self.stack.reset(camera) if first else self.stack.push(camera)


def segment_worker_ids(worker_id: str, envs: int) -> list[str]:
    """The worker ids of the segments of a worker's ``envs`` envs: its own with one env, ``{worker_id}/{j}`` with
    more (the trainer drops a segment whose worker id and creation time it has seen: each env needs its own)."""
    return [worker_id] if envs == 1 else [f"{worker_id}/{j}" for j in range(envs)]


class Rollouts:
    """K envs stepped side by side under one policy, and the segments they fill: the part of a worker that needs
    neither Redis nor the store (``racer bench worker`` times it as it is).

    ``time_s`` adds up the seconds of ``collect`` (``collect``), of the forward passes with sampling (``act``) and
    of ``env.step`` (``env``: physics, camera, task, reward function); the rest of ``collect`` is bookkeeping
    (frame stacks, sim-trace rows, building the segments)."""

    def __init__(
        self, run: RunConfig, config: EnvConfig, seeds: Sequence[int], segment_worker_ids: Sequence[str]
    ) -> None:
        self.run = run
        self.envs: list[_Env] = [
            _Env(RacerEnv(config=config), j, seed, wid, FrameStack(run.hyperparams.stack_size))
            for j, (seed, wid) in enumerate(zip(seeds, segment_worker_ids, strict=True))
        ]
        env = self.envs[0].env
        self.actions = env.actions
        self.obs_spec: ObsSpec = observation_spec(env.actions.sensor, run.hyperparams.stack_size)
        self.obs_shape = self.obs_spec.camera_shape(camera_frame_size(env.observation_space))
        self.env_steps = 0
        """Env steps of all envs so far."""
        self.time_s: dict[str, float] = {"collect": 0.0, "act": 0.0, "env": 0.0}

    @property
    def track_name(self) -> str:
        """The track the envs drive (a worker's envs share its track)."""
        return self.envs[0].env.track.name

    @property
    def episodes(self) -> int:
        """Episodes finished by all envs so far."""
        return sum(e.episode for e in self.envs)

    def build_policy(self) -> ActorCritic:
        """A network for these envs' observations and actions (its weights to be loaded), in eval mode."""
        model = build_policy(self.obs_shape, action_space_spec(self.actions), self.run.policy, self.actions.sensor)
        model.eval()
        return model

    def reset(self) -> None:
        """Start every env's first episode from its seed."""
        for e in self.envs:
            observation, info = e.env.reset(seed=e.seed)
            e.observe(observation, first=True)
            e.simtrace.reset(info, self._trace_episode(e))
            e.ep_reward = 0.0

    def collect(self, actor: Actor, policy_version: int) -> list[Segment]:
        """``segment_steps`` steps of every env, acted by ``actor`` (the network of ``policy_version``) in one batched
        forward pass per step for all envs; one segment per env, in env order."""
        started = time.perf_counter()
        clock, envs = self.time_s, self.envs
        ros = [_Rollout() for _ in envs]
        for _ in range(self.run.segment_steps):
            t0 = time.perf_counter()
            actions, logps, values = actor.act_numpy(
                _batch([e.obs for e in envs]), lidar=_lidar_batch([e.lidar for e in envs])
            )
            clock["act"] += time.perf_counter() - t0
            truncated: list[tuple[_Rollout, int, np.ndarray, np.ndarray | None]] = []
            for e, ro, action, logp, value in zip(envs, ros, actions, logps, values, strict=True):
                ro.obs.append(e.obs)
                if e.lidar is not None:
                    ro.lidar.append(e.lidar)
                ro.actions.append(action)
                ro.logp.append(logp)
                ro.values.append(value)
                ro.episode_id.append(e.episode)
                t0 = time.perf_counter()
                observation, reward, term, trunc, info = e.env.step(action)
                clock["env"] += time.perf_counter() - t0
                e.simtrace.step(action, info, reward, term or trunc)
                if e.watch is not None:
                    e.watch.step(observation, info)
                e.ep_reward += reward
                ro.rewards.append(reward)
                ro.terminated.append(term)
                ro.truncated.append(trunc)
                if term or trunc:
                    # The final observation is pushed onto the stack only to bootstrap a truncated step's value.
                    camera, lidar = split_observation(observation)
                    final = e.stack.push(camera)
                    if trunc:
                        truncated.append((ro, len(ro.next_values), final, lidar))
                    ro.next_values.append(0.0)  # a truncated step's value is set below
                    ro.episodes.append(self._summary(e, info))
                    self._new_episode(e)
                else:
                    e.observe(observation)
                    ro.next_values.append(None)  # V(o_{t+1}) is the next step's value
            if truncated:  # the envs whose episode hit its time limit this step, valued together
                bootstrap = self._values(actor, [t[2] for t in truncated], [t[3] for t in truncated])
                for (ro, t, _, _), v in zip(truncated, bootstrap, strict=True):
                    ro.next_values[t] = v
        self.env_steps += self.run.segment_steps * len(envs)
        segments = self._segments(actor, policy_version, ros)
        clock["collect"] += time.perf_counter() - started
        return segments

    def _segments(self, actor: Actor, policy_version: int, ros: list[_Rollout]) -> list[Segment]:
        # V(o_T) of every env whose segment ends inside an episode, in one forward pass.
        ending = [i for i, ro in enumerate(ros) if ro.next_values[-1] is None]
        if ending:
            last = self._values(actor, [self.envs[i].obs for i in ending], [self.envs[i].lidar for i in ending])
            for i, v in zip(ending, last, strict=True):
                ros[i].next_values[-1] = v
        return [self._segment(e, ro, policy_version) for e, ro in zip(self.envs, ros, strict=True)]

    def _segment(self, e: _Env, ro: _Rollout, policy_version: int) -> Segment:
        values = np.asarray(ro.values, np.float32)
        nxt = [v if v is not None else values[t + 1] for t, v in enumerate(ro.next_values)]
        actions = np.asarray(ro.actions)
        arrays = {
            "obs": np.stack(ro.obs),
            "next_obs": e.obs[None],
            "actions": actions.astype(np.int64 if self.actions.discrete else np.float32),
            "rewards": np.asarray(ro.rewards, np.float32),
            "terminated": np.asarray(ro.terminated, np.uint8),
            "truncated": np.asarray(ro.truncated, np.uint8),
            "logp": np.asarray(ro.logp, np.float32),
            "values": values,
            "next_values": np.asarray(nxt, np.float32),
            "episode_id": np.asarray(ro.episode_id, np.int64),
        }
        if self.obs_spec.lidar:
            arrays["lidar"] = np.stack(ro.lidar)
            arrays["next_lidar"] = e.lidar[None]
        return Segment(self.run.run_id, e.segment_worker_id, policy_version, e.seed, arrays, ro.episodes)

    def _values(self, actor: Actor, obs: list[np.ndarray], lidar: list[np.ndarray | None]) -> list[float]:
        """V(o) of stacked camera observations and their LiDAR vectors, in one forward pass."""
        t0 = time.perf_counter()
        values = actor.act_numpy(_batch(obs), lidar=_lidar_batch(lidar))[2]
        self.time_s["act"] += time.perf_counter() - t0
        return [float(v) for v in values]

    def _summary(self, e: _Env, info: dict) -> EpisodeSummary:
        p = info["params"]
        status = info["episode_status"]
        lap = p["sim_time"] if status == "lap_complete" else None
        return EpisodeSummary(e.episode, info["steps"], p["progress"], e.ep_reward, status, e.env.track.name, lap)

    def _new_episode(self, e: _Env) -> None:
        e.episode += 1
        e.ep_reward = 0.0
        observation, info = e.env.reset()
        e.observe(observation, first=True)
        e.simtrace.reset(info, self._trace_episode(e))

    def _trace_episode(self, e: _Env) -> int:
        """The sim-trace ``episode`` of env j's n-th episode: n·K + j (see :meth:`take_simtrace`)."""
        return e.episode * len(self.envs) + e.index

    def take_simtrace(self, include_open: bool = False) -> str | None:
        """The CSV of the sim-trace rows recorded since the last take (with ``include_open``, the episodes in
        progress too), None if there are none (``common.simtrace.merged_csv``).

        The K envs write one file, the one a one-env worker writes (``{k}/training-simtrace/{N}-iteration.csv``),
        not one folder each: deepracer-utils reads worker folders 0-9 only (``common/simtrace.py``), which K folders
        per worker would soon pass, and a worker is what DeepRacer's layout calls a worker. Env j's n-th episode is
        episode n·K + j, unique within the worker (deepracer-utils groups by worker and episode) and, with one env,
        the episode numbers a worker always wrote; each episode's rows are whole and in order, episodes in the
        order of their numbers."""
        return merged_csv([e.simtrace for e in self.envs], include_open)

    def close(self) -> None:
        """Release the envs."""
        for e in self.envs:
            e.env.close()


def _batch(arrays: list[np.ndarray]) -> np.ndarray:
    """The arrays as a batch; one array as a view of itself, as a one-env worker always passed it (the same memory
    to the network gives the same float rounding, so K = 1 pushes bit for bit what it did)."""
    return arrays[0][None] if len(arrays) == 1 else np.stack(arrays)


def _lidar_batch(lidar: list[np.ndarray | None]) -> np.ndarray | None:
    """A batch of LiDAR vectors, or None for a network without a LiDAR."""
    return None if lidar[0] is None else _batch(lidar)  # type: ignore[arg-type]


class RolloutWorker:
    """One worker process's state: its envs, the policy, Redis and store handles."""

    def __init__(self, opts: WorkerOptions, stop: threading.Event | None = None) -> None:
        self.opts = opts
        self.stop = stop or threading.Event()
        self.bus = Bus.connect(opts.redis_url, opts.run_id)
        self.runs = RunStore(open_store(opts.store, opts.s3_endpoint))
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
        self.rollouts = Rollouts(self.run, config, seeds, segment_worker_ids(self.worker_id, n))
        log.info("worker %s: %d env(s) on %s, seeds %s", self.worker_id, n, self.rollouts.track_name, seeds)
        self.model: ActorCritic = self.rollouts.build_policy()
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

    def poll_policy(self) -> bool:
        """Switch to a newer policy if one was published. Called between segments (every ~50 ms of work):
        one GET of the version key is cheaper than keeping a pub/sub connection and just as prompt."""
        try:
            pv = self.bus.policy()
        except ProtocolError as exc:
            log.warning("ignoring malformed policy version: %s", exc)
            return False
        if pv is None or pv.version <= self.policy_version:
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
