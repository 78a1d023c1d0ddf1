"""The rollout worker: poll the policy, run episodes, push segments to Redis, keep a heartbeat.

One worker runs one env with its own seed (so its own randomization) and possibly its own track.
It reads everything about the run from the store (``config.json``, the reward function, the action
space) so a worker on another machine needs only the run id, the Redis URL and the store URI.
"""

from __future__ import annotations

import logging
import os
import resource
import socket
import tempfile
import threading
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
import torch

from common.bus import Bus
from common.config import EnvConfig, RunConfig
from common.framestack import FrameStack
from common.policy import ActorCritic, action_space_spec, build_policy, checkpoint_from_bytes
from common.protocol import EpisodeSummary, Heartbeat, PolicyVersion, ProtocolError, Segment, encode_segment
from common.redis_util import redact
from common.retry import DEFAULT_GIVE_UP_S, Outage, redis_transient
from common.sensors import ObsSpec, camera_frame_size, observation_spec, split_observation
from common.simtrace import SimTraceRecorder
from model_store import RunStore, StoreError, is_transient, open_store
from model_store.localize import localize_env
from model_store.runs import simtrace_key
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
    """Index k: seeds the env with run seed + 1000·k, drives the run's worker_env(k) and names the sim-trace folder.
    None = take the next free index from Redis (scaled compose workers share one set of options)."""
    worker_id: str = ""
    """Name in heartbeats and segments; default ``{host}-{pid}-{index}``."""
    policy_wait_s: float = 300.0
    """How long to wait for the trainer's first policy before giving up, seconds."""
    outage_s: float = DEFAULT_GIVE_UP_S
    """How long to ride out one Redis or store outage before exiting with an error, seconds."""


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


class RolloutWorker:
    """One worker process's state: env, policy, Redis and store handles."""

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
        self.env_steps = 0
        self.segments = 0
        self._episode = 0
        self._workdir = tempfile.TemporaryDirectory(prefix="racer-worker-")
        self.simtrace = SimTraceRecorder()  # DeepRacer sim-trace rows of the current iteration

    # --- set-up -------------------------------------------------------------------------------
    def start(self) -> None:
        """Wait for the first policy, then build the env and the network from the run's files."""
        first = self._wait_for_policy()
        self.run: RunConfig = self.store_outage.call("read the run", partial(self.runs.read_config, self.opts.run_id))
        self.env = RacerEnv(config=self.store_outage.call("read the run's files", self._env_config))
        self.stack = FrameStack(self.run.hyperparams.stack_size)
        sensors = self.env.actions.sensor
        self.obs_spec: ObsSpec = observation_spec(sensors, self.run.hyperparams.stack_size)
        obs_shape = self.obs_spec.camera_shape(camera_frame_size(self.env.observation_space))
        action_spec = action_space_spec(self.env.actions)
        self.model: ActorCritic = build_policy(obs_shape, action_spec, self.run.policy, sensors)
        self.model.eval()
        self._load(first)
        self.seed = self.run.seed + 1000 * self.opts.worker_index
        self.watch = WatchPublisher(self.bus, self.worker_id, self.opts.worker_index, self.env.track.name)
        observation, info = self.env.reset(seed=self.seed)
        self._observe(observation, first=True)
        self.simtrace.reset(info, self._episode)
        self._ep_reward = 0.0

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
        payload, _ = self.store_outage.call(
            f"load policy v{pv.version}", lambda: self.runs.load_checkpoint(self.opts.run_id, pv.version)
        )
        model_sd, _ = checkpoint_from_bytes(payload)
        self.model.load_state_dict(model_sd)
        self.policy_version = pv.version
        self.policy_loaded_at = time.time()
        log.info("worker %s acting with policy version %d", self.worker_id, pv.version)

    # --- the loop -----------------------------------------------------------------------------
    def run_forever(self) -> None:
        """Collect and push segments until stopped."""
        while not self.stop.is_set():
            seg = self.collect()
            # Through a Redis outage the segment waits here, whole; it is never sent in parts.
            self.redis_outage.call("push a segment", partial(self.push, seg))
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

    def collect(self) -> Segment:
        """Run ``segment_steps`` env steps with the current policy."""
        ro = _Rollout()
        for _ in range(self.run.segment_steps):
            action, logp, value = self.model.act_numpy(self.obs[None], lidar=self._lidar_batch(self.lidar))
            ro.obs.append(self.obs)
            if self.lidar is not None:
                ro.lidar.append(self.lidar)
            ro.actions.append(action[0])
            ro.logp.append(logp[0])
            ro.values.append(value[0])
            ro.episode_id.append(self._episode)
            observation, reward, term, trunc, info = self.env.step(action[0])
            self.simtrace.step(action[0], info, reward, term or trunc)
            self.watch.step(observation, info)  # racer view: nearly free unless a page watches
            self._ep_reward += reward
            ro.rewards.append(reward)
            ro.terminated.append(term)
            ro.truncated.append(trunc)
            if term or trunc:
                # The final observation is pushed onto the stack only to bootstrap a truncated step's value.
                camera, lidar = split_observation(observation)
                final = self.stack.push(camera)
                ro.next_values.append(self._value(final, lidar) if trunc else 0.0)
                ro.episodes.append(self._summary(info))
                self._new_episode()
            else:
                self._observe(observation)
                ro.next_values.append(None)  # V(o_{t+1}) is the next step's value
        self.env_steps += self.run.segment_steps
        return self._segment(ro)

    def _segment(self, ro: _Rollout) -> Segment:
        values = np.asarray(ro.values, np.float32)
        nxt = [
            v if v is not None else (values[t + 1] if t + 1 < len(values) else None)
            for t, v in enumerate(ro.next_values)
        ]
        if nxt[-1] is None:
            nxt[-1] = self._value(self.obs, self.lidar)
        actions = np.asarray(ro.actions)
        arrays = {
            "obs": np.stack(ro.obs),
            "next_obs": self.obs[None],
            "actions": actions.astype(np.int64 if self.env.actions.discrete else np.float32),
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
            arrays["next_lidar"] = self.lidar[None]
        return Segment(self.opts.run_id, self.worker_id, self.policy_version, self.seed, arrays, ro.episodes)

    def _value(self, obs: np.ndarray, lidar: np.ndarray | None) -> float:
        """V(o) of one stacked camera observation and its LiDAR vector (None without a LiDAR)."""
        return float(self.model.act_numpy(obs[None], lidar=self._lidar_batch(lidar))[2][0])

    @staticmethod
    def _lidar_batch(lidar: np.ndarray | None) -> np.ndarray | None:
        """A batch of one LiDAR vector, or None for a network without a LiDAR."""
        return None if lidar is None else lidar[None]

    def _observe(self, observation: np.ndarray | dict, first: bool = False) -> None:
        """Take an env observation apart: its camera frame onto the stack (``self.obs``), its LiDAR vector (not
        stacked, as in DeepRacer) into ``self.lidar``."""
        camera, self.lidar = split_observation(observation)
        self.obs = self.stack.reset(camera) if first else self.stack.push(camera)

    def _summary(self, info: dict) -> EpisodeSummary:
        p = info["params"]
        status = info["episode_status"]
        lap = p["sim_time"] if status == "lap_complete" else None
        return EpisodeSummary(
            self._episode, info["steps"], p["progress"], self._ep_reward, status, self.env.track.name, lap
        )

    def _new_episode(self) -> None:
        self._episode += 1
        self._ep_reward = 0.0
        observation, info = self.env.reset()
        self._observe(observation, first=True)
        self.simtrace.reset(info, self._episode)

    def push(self, seg: Segment) -> None:
        """Send a segment (one atomic XADD, capped stream) and refresh the heartbeat."""
        self.bus.push_segment(encode_segment(seg), self._heartbeat(1), self.run.stream_maxlen, self._heartbeat_ex())
        self.segments += 1

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
            track=self.env.track.name,
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
        """Upload the last (partial) iteration's sim-trace; release the env, the Redis connections and the temporary
        files."""
        self._upload_simtrace(include_open=True)
        if hasattr(self, "watch"):
            self.watch.close()
        if hasattr(self, "env"):
            self.env.close()
        self._workdir.cleanup()

    # --- DeepRacer sim-traces (common/simtrace.py) ----------------------------------------------
    def _upload_simtrace(self, include_open: bool = False) -> None:
        """Put the rows recorded with ``policy_version`` in ``runs/<id>/<k>/training-simtrace/<version>-iteration.csv``.

        One small object per iteration (a few ms on a local store). A failed upload loses that log, not the run."""
        text = self.simtrace.take(include_open)
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
