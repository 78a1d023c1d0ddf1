"""A worker's envs stepped together: ``Rollouts`` acts for K envs with one batched network call a step and cuts each
env's steps into segments; ``rollout_worker.worker`` runs it against Redis and the store.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from common.config import EnvConfig, RunConfig
from common.framestack import FrameStack
from common.policy import PolicyNetwork, policy_for_run
from common.privileged import state_vector
from common.protocol import EpisodeSummary, Segment
from common.sensors import ObsSpec, camera_frame_size, observation_spec, split_observation
from common.simtrace import SimTraceRecorder, merged_csv
from rollout_worker.onnx_policy import Actor
from rollout_worker.teacher import Teacher
from rollout_worker.watch import WatchPublisher
from sim.env import RacerEnv

log = logging.getLogger("racer.worker")


@dataclass
class _Rollout:
    """Arrays being filled for the current segment."""

    obs: list = field(default_factory=list)
    lidar: list = field(default_factory=list)
    """The LiDAR part of each o_t (only with a LiDAR sensor)."""
    teacher: list = field(default_factory=list)
    """The teacher's action distribution at each o_t (only in a distilling run)."""
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
    stack: FrameStack | None
    """The camera frame stack; None for state vectors (a teacher run), which are not stacked."""
    simtrace: SimTraceRecorder = field(default_factory=SimTraceRecorder)
    """DeepRacer sim-trace rows of the current iteration."""
    episode: int = 0
    """Episodes this env has finished: the number of the one it is driving."""
    ep_reward: float = 0.0
    obs: np.ndarray | None = None
    """The stacked camera observation the next action is chosen from."""
    lidar: np.ndarray | None = None
    """Its LiDAR vector (None without a LiDAR sensor)."""
    labelled: bool = False
    """A distilling run's env: its steps carry the teacher's action distribution."""
    state: np.ndarray | None = None
    """The car's privileged state at that observation (only in a distilling run: the teacher acts on it)."""
    watch: WatchPublisher | None = None
    """What ``racer view`` shows of this env (its pose and camera), published only while a page watches."""

    def observe(self, observation: np.ndarray | dict, info: dict, first: bool = False) -> None:
        """Take an env observation apart: its camera frame onto the stack (``obs``), its LiDAR vector (not stacked,
        as in DeepRacer) into ``lidar``; a teacher run's state vector as it is. In a distilling run, the car's
        state from the step's ``info`` params into ``state``."""
        if self.stack is None:
            self.obs = observation
            return
        camera, self.lidar = split_observation(observation)
        self.obs = self.stack.reset(camera) if first else self.stack.push(camera)
        if self.labelled:
            self.state = state_vector(info["params"])


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
        self,
        run: RunConfig,
        config: EnvConfig,
        seeds: Sequence[int],
        segment_worker_ids: Sequence[str],
        teacher: Teacher | None = None,
    ) -> None:
        self.run = run
        self.teacher = teacher
        """A distilling run's teacher (``run.distill``): it labels every step and drives a share of them."""
        if (teacher is None) != (run.distill is None):
            raise ValueError(f"run {run.run_id!r} {'distills: it needs' if run.distill else 'has no'} a teacher")
        state = config.observation == "state"
        self.envs: list[_Env] = [
            _Env(RacerEnv(config=config), j, seed, wid, None if state else FrameStack(run.hyperparams.stack_size))
            for j, (seed, wid) in enumerate(zip(seeds, segment_worker_ids, strict=True))
        ]
        for e in self.envs:
            e.labelled = teacher is not None
        env = self.envs[0].env
        self.actions = env.actions
        self.obs_spec: ObsSpec = observation_spec(env.actions.sensor, run.hyperparams.stack_size)
        self.frame = None if state else camera_frame_size(env.observation_space)
        """The camera frames' (height, width); None for a teacher run's state vectors."""
        self._mix = np.random.default_rng(list(seeds))
        """Draws which steps the teacher drives (``DistillConfig.teacher_share_at``)."""
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

    def build_policy(self) -> PolicyNetwork:
        """A network for these envs' observations and actions (its weights to be loaded), in eval mode."""
        model = policy_for_run(self.run, self.actions, *([self.frame] if self.frame else []))
        model.eval()
        return model

    def reset(self) -> None:
        """Start every env's first episode from its seed."""
        for e in self.envs:
            observation, info = e.env.reset(seed=e.seed)
            e.observe(observation, info, first=True)
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
            labels = None
            if self.teacher is not None:
                labels, actions = self._teach(actions, policy_version)
            clock["act"] += time.perf_counter() - t0
            truncated: list[tuple[_Rollout, int, np.ndarray, np.ndarray | None]] = []
            for j, (e, ro, action, logp, value) in enumerate(zip(envs, ros, actions, logps, values, strict=True)):
                ro.obs.append(e.obs)
                if e.lidar is not None:
                    ro.lidar.append(e.lidar)
                if labels is not None:
                    ro.teacher.append(labels[j])
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
                    final = camera if e.stack is None else e.stack.push(camera)
                    if trunc:
                        truncated.append((ro, len(ro.next_values), final, lidar))
                    ro.next_values.append(0.0)  # a truncated step's value is set below
                    ro.episodes.append(self._summary(e, info))
                    self._new_episode(e)
                else:
                    e.observe(observation, info)
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
        if ro.lidar:
            arrays["lidar"] = np.stack(ro.lidar)
            arrays["next_lidar"] = e.lidar[None]
        if ro.teacher:
            arrays["teacher"] = np.stack(ro.teacher)
        return Segment(
            self.run.run_id, e.segment_worker_id, policy_version, e.seed, arrays=arrays, episodes=ro.episodes
        )

    def _teach(self, actions: np.ndarray, policy_version: int) -> tuple[np.ndarray, np.ndarray]:
        """The teacher's labels of this step's states, and the actions the envs take: the teacher's own (drawn from
        its distribution) on the run's share of them (``DistillConfig.teacher_share_at``), the student's elsewhere."""
        labels, taught = self.teacher.act(np.stack([e.state for e in self.envs]))
        share = self.run.distill.teacher_share_at(policy_version)
        if share <= 0:
            return labels, actions
        mixed = self._mix.random(len(self.envs)) < share
        mask = mixed.reshape(-1, *([1] * (actions.ndim - 1)))
        return labels, np.where(mask, taught, actions).astype(actions.dtype)

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
        return EpisodeSummary(
            e.episode, info["steps"], p["progress"], e.ep_reward, status, track=e.env.track.name, lap_time_s=lap
        )

    def _new_episode(self, e: _Env) -> None:
        e.episode += 1
        e.ep_reward = 0.0
        observation, info = e.env.reset()
        e.observe(observation, info, first=True)
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
