"""Robust evaluation (DeepRacer paper, Sec. 5): drive a checkpoint from spread start positions, in both
directions, with action noise, possibly on other tracks; score it; keep the ``best`` pointer.

Score (higher is better), documented in the README::

    score = 100 × completion_rate + mean_progress − 0.1 × mean lap time of completed laps (s)

so completing more laps always wins, then getting further, then lapping faster.
"""

from __future__ import annotations

import json
import logging
import statistics
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import KW_ONLY, asdict, dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
import torch

from common.action_space import default_action_space, load_action_space
from common.bus import Bus
from common.conditions import Condition, apply_condition
from common.config import EnvConfig, RunConfig
from common.defaults import CHECK_EPISODES, DEFAULT_GIVE_UP_S, EVAL_ACTION_NOISE
from common.framestack import FrameStack
from common.policy import PolicyNetwork
from common.protocol import EvaluationSummary, PolicyVersion, ProtocolError
from common.redis_util import redact
from common.retry import Outage, redis_transient
from common.sensors import split_observation
from common.simtrace import SimTraceRecorder
from common.weights import load_policy
from model_store import RunStore, StoreKeyError, is_transient, open_store
from model_store.localize import localize_env
from model_store.runs import evaluation_name, evaluation_stamp, simtrace_key
from sim.env import RacerEnv
from trainer.device import resolve_device

log = logging.getLogger("racer.evaluator")


@dataclass
class EvalSettings:
    """How to evaluate a checkpoint."""

    episodes: int = CHECK_EPISODES
    """Start positions per direction and track, spread evenly around the lap."""
    both_directions: bool = True
    """Also drive every start in the reverse direction."""
    action_noise: float = EVAL_ACTION_NOISE
    """Uniform noise on the commands, as in the env's randomization (0.1 = ±3° steering, ±10 % speed)."""
    tracks: list[str] = field(default_factory=list)
    """Tracks to evaluate on; empty = the run's track."""
    seed: int = 12345
    deterministic: bool = True
    """Act with the most likely action (DeepRacer evaluates this way); False = sample."""
    resets: bool = False
    """DeepRacer's evaluation: after an off-track or a crash the car is put back with the run's penalty
    (``common/race.py: PenaltyConfig``, up to ``number_of_resets`` times). False (racer's robust evaluation, beside
    training): a trial ends at the first one."""


@dataclass
class Trial:
    """One evaluation episode."""

    track: str
    reverse: bool
    start_index: int
    _: KW_ONLY
    progress: float
    status: str
    steps: int
    lap_time_s: float | None
    trajectory: list[list[float]]
    """[x, y, commanded speed] per step, x/y at DeepRacer's point 0.14 m ahead of base_link."""
    resets: int = 0
    """Times the car was put back on the track (``EvalSettings.resets``)."""
    penalty_s: float = 0.0
    """Penalty seconds those resets added to the lap time."""


def score(completion_rate: float, mean_progress: float, lap_times: list[float]) -> float:
    """The documented checkpoint score (see the module docstring)."""
    lap_penalty = 0.1 * statistics.fmean(lap_times) if lap_times else 0.0
    return 100.0 * completion_rate + mean_progress - lap_penalty


def summarize(trials: list[Trial]) -> dict:
    """The figures of an evaluation, as ``racer eval`` reports them."""
    laps = [t.lap_time_s for t in trials if t.lap_time_s is not None]
    completion = len(laps) / len(trials) if trials else 0.0
    progress = statistics.fmean(t.progress for t in trials) if trials else 0.0
    return {
        "episodes": len(trials),
        "completion_rate": completion,
        "mean_progress": progress,
        "lap_times_s": laps,
        "best_lap_s": min(laps) if laps else None,
        "mean_lap_s": statistics.fmean(laps) if laps else None,
        "off_track": sum(t.status == "off_track" for t in trials),
        "crashed": sum(t.status == "crashed" for t in trials),
        "resets": sum(t.resets for t in trials),
        "score": score(completion, progress, laps),
    }


def run_trial(
    env: RacerEnv,
    model: PolicyNetwork,
    stack: int,
    start: int,
    reverse: bool,
    *,
    seed: int,
    deterministic: bool,
    on_step: Callable[[np.ndarray | dict[str, np.ndarray], dict], None] | None = None,
    recorder: SimTraceRecorder | None = None,
    episode: int = 0,
    resets: bool = False,
) -> Trial:
    """Drive one episode from waypoint ``start`` and record it; ``on_step(observation, info)`` sees every observation
    as the env gives it (``common.sensors.split_observation`` takes it apart) and ``recorder`` gets DeepRacer sim-trace
    rows (as ``episode``); ``resets`` as ``EvalSettings.resets``."""
    observation, info = env.reset(seed=seed, options={"start_index": start, "reverse": reverse, "evaluation": resets})
    if recorder:
        recorder.reset(info, episode)
    stacker = FrameStack(stack)
    frame, lidar = split_observation(observation)
    obs = stacker.reset(frame)
    if on_step:
        on_step(observation, info)
    trajectory: list[list[float]] = []
    pauses: list[float] = []
    done = False
    while not done:
        batch_lidar = None if lidar is None else lidar[None]
        action, _, _ = model.act_numpy(obs[None], deterministic=deterministic, lidar=batch_lidar)
        observation, reward, term, trunc, info = env.step(action[0])
        frame, lidar = split_observation(observation)  # the LiDAR is not stacked: the latest vector only
        obs = stacker.push(frame)
        if recorder:
            recorder.step(action[0], info, reward, term or trunc)
        p = info["params"]
        trajectory.append([round(p["x"], 4), round(p["y"], 4), round(p["speed"], 3)])
        if "pause_duration" in info:
            pauses.append(info["pause_duration"])
        if on_step:
            on_step(observation, info)
        done = term or trunc
    p, status = info["params"], info["episode_status"]
    lap = p["sim_time"] if status == "lap_complete" else None
    steps = info["steps"]
    return Trial(
        env.track.name,
        reverse,
        start,
        progress=p["progress"],
        status=status,
        steps=steps,
        lap_time_s=lap,
        trajectory=trajectory,
        resets=len(pauses),
        penalty_s=sum(pauses),
    )


@dataclass
class _Driving:
    """One trial in progress in ``evaluate``'s lockstep: its own env, frame stack, sim-trace and path."""

    env: RacerEnv
    start: int
    reverse: bool
    _: KW_ONLY
    stacker: FrameStack
    obs: np.ndarray
    """The stacked camera observation."""
    lidar: np.ndarray | None
    """The latest LiDAR vector (not stacked), None without a LiDAR sensor."""
    info: dict
    recorder: SimTraceRecorder | None
    trajectory: list[list[float]] = field(default_factory=list)
    pauses: list[float] = field(default_factory=list)
    done: bool = False

    def step(self, action: np.ndarray) -> None:
        """Apply one action; record the step; note the end of the episode."""
        observation, reward, term, trunc, self.info = self.env.step(action)
        frame, self.lidar = split_observation(observation)
        self.obs = self.stacker.push(frame)
        if self.recorder:
            self.recorder.step(action, self.info, reward, term or trunc)
        p = self.info["params"]
        self.trajectory.append([round(p["x"], 4), round(p["y"], 4), round(p["speed"], 3)])
        if "pause_duration" in self.info:
            self.pauses.append(self.info["pause_duration"])
        self.done = bool(term or trunc)

    def trial(self) -> Trial:
        """The finished episode as a Trial (as ``run_trial`` returns it)."""
        p, status = self.info["params"], self.info["episode_status"]
        lap = p["sim_time"] if status == "lap_complete" else None
        return Trial(
            self.env.track.name,
            self.reverse,
            self.start,
            progress=p["progress"],
            status=status,
            steps=self.info["steps"],
            lap_time_s=lap,
            trajectory=self.trajectory,
            resets=len(self.pauses),
            penalty_s=sum(self.pauses),
        )


def _start(
    env: RacerEnv, stack: int, start: int, reverse: bool, *, seed: int, record: bool, episode: int, resets: bool = False
) -> _Driving:
    """Reset ``env`` for one trial and hold its first observation."""
    observation, info = env.reset(seed=seed, options={"start_index": start, "reverse": reverse, "evaluation": resets})
    recorder = SimTraceRecorder() if record else None
    if recorder:
        recorder.reset(info, episode)
    stacker = FrameStack(stack)
    frame, lidar = split_observation(observation)
    return _Driving(
        env, start, reverse, stacker=stacker, obs=stacker.reset(frame), lidar=lidar, info=info, recorder=recorder
    )


def drive_lockstep(model: PolicyNetwork, trials: list[_Driving], deterministic: bool) -> None:
    """Drive every trial to its end, all trials' frames through the network as one batch per step.

    One batch of K frames costs far less than K single frames (the dense layer's 23 MB of weights are read once),
    and each trial's env, seed and actions are its own, so the trials come out as ``run_trial`` would drive them.
    """
    while active := [t for t in trials if not t.done]:
        obs = np.stack([t.obs for t in active])
        # The trials' envs share one sensor list: all have a LiDAR vector or none does (as in run_trial, the
        # network refuses a LiDAR batch it does not take, or the lack of one it needs).
        lidar = None if active[0].lidar is None else np.stack([t.lidar for t in active])
        actions, _, _ = model.act_numpy(obs, deterministic=deterministic, lidar=lidar)
        for t, action in zip(active, actions, strict=True):
            t.step(action)


def trial_plan(settings: EvalSettings, run_track: str) -> list[tuple[str, bool, int]]:
    """(track, reverse, i) of every trial, in the order ``evaluate`` drives and lists them: per track, the forward
    starts, then the reverse ones; ``i`` is the start's number in its direction."""
    directions = (False, True) if settings.both_directions else (False,)
    return [
        (track, reverse, i)
        for track in settings.tracks or [run_track]
        for reverse in directions
        for i in range(settings.episodes)
    ]


def trial_start(env: RacerEnv, settings: EvalSettings, reverse: bool, i: int) -> tuple[int, int]:
    """(start waypoint, reset seed) of the ``i``-th start in a direction: ``settings.episodes`` starts spread evenly
    round the lap, each with its own seed, so that a trial driven again (``racer eval --video``) is the same trial."""
    count = env.task.start_indices(reverse)
    return round(i * count / settings.episodes) % count, settings.seed + 1000 * i + (500 if reverse else 0)


def evaluation_env_config(env_cfg: EnvConfig, settings: EvalSettings, track: str) -> EnvConfig:
    """The env of an evaluation's trials on ``track``: the run's, with the evaluation's action noise and no random
    start (each trial sets its own)."""
    noise = env_cfg.randomization.model_copy(update={"action_noise": settings.action_noise, "random_start": False})
    return env_cfg.model_copy(update={"track": track, "randomization": noise})


def evaluate(
    model: PolicyNetwork,
    env_cfg: EnvConfig,
    stack: int,
    settings: EvalSettings,
    recorder: SimTraceRecorder | None = None,
) -> list[Trial]:
    """All trials of a robust evaluation: every track × direction × spread start, driven in lockstep per track."""
    model.eval()
    trials: list[Trial] = []
    plan = trial_plan(settings, env_cfg.track)
    for track in dict.fromkeys(t for t, _, _ in plan):
        cfg = evaluation_env_config(env_cfg, settings, track)
        driving: list[_Driving] = []
        for _, reverse, i in [p for p in plan if p[0] == track]:
            env = RacerEnv(config=cfg)
            start, seed = trial_start(env, settings, reverse, i)
            episode = len(trials) + len(driving)
            record = recorder is not None
            driving.append(
                _start(env, stack, start, reverse, seed=seed, record=record, episode=episode, resets=settings.resets)
            )
        try:
            drive_lockstep(model, driving, settings.deterministic)
        finally:
            for d in driving:
                d.env.close()
        for d in driving:
            if recorder and d.recorder:
                recorder.extend(d.recorder)
            trials.append(d.trial())
    return trials


def evaluate_checkpoint(
    runs: RunStore,
    run: RunConfig,
    env_cfg: EnvConfig,
    version: int | str,
    settings: EvalSettings,
    *,
    recorder: SimTraceRecorder | None = None,
    device: torch.device | str = "cpu",
) -> dict:
    """Evaluate one stored checkpoint; the full record (summary, settings and trials). ``recorder`` collects the
    DeepRacer sim-trace rows of every trial; the network acts on ``device``."""
    torch.manual_seed(settings.seed)
    # The network needs only the action space and the frame size, not a whole world (texture, MuJoCo model).
    actions = load_action_space(env_cfg.action_space) if env_cfg.action_space else default_action_space()
    model, meta = load_policy(runs, run, actions, version, device=device)
    trials = evaluate(model, env_cfg, run.hyperparams.stack_size, settings, recorder)
    return {
        "run_id": run.run_id,
        "version": int(meta["version"]),
        "env_steps": meta.get("env_steps"),
        "track": env_cfg.track,
        **summarize(trials),
        "settings": asdict(settings),
        "greedy_action": run.policy.greedy_action,
        "created": time.time(),
        "trials": [asdict(t) for t in trials],
    }


def save_evaluation(runs: RunStore, record: dict) -> bool:
    """Store an evaluation; move the ``best`` pointer if it scores higher than the current best. True if moved."""
    run_id, version = record["run_id"], record["version"]
    runs.write_file(run_id, evaluation_name(version), json.dumps(record))
    best = runs.pointer(run_id, "best")
    if best is not None:
        try:
            previous = json.loads(runs.read_file(run_id, evaluation_name(int(best["version"]))))["score"]
        except (StoreKeyError, KeyError, ValueError):
            previous = float("-inf")
        if record["score"] <= previous:
            return False
    runs.set_pointer(run_id, "best", version)
    return True


def evaluate_conditions(
    runs: RunStore,
    run: RunConfig,
    env_cfg: EnvConfig,
    version: int,
    settings: EvalSettings,
    *,
    conditions: list[Condition],
    device: torch.device | str = "cpu",
) -> list[dict]:
    """The checkpoint's trials driven again in each held-out condition (``common.conditions``): per condition its
    name and what it is, laps out of the trials, progress and lap times, and its trials (without trajectories)."""
    keep = ("episodes", "completion_rate", "mean_progress", "best_lap_s", "mean_lap_s", "off_track", "crashed", "score")
    rows = []
    for condition in conditions:
        record = evaluate_checkpoint(
            runs, run, apply_condition(env_cfg, condition), version, settings, recorder=None, device=device
        )
        rows.append(
            {
                "name": condition.name,
                "about": condition.about,
                "car": condition.car,
                "laps": len(record["lap_times_s"]),
                **{k: record[k] for k in keep},
                "trials": [{k: v for k, v in t.items() if k != "trajectory"} for t in record["trials"]],
            }
        )
    return rows


@dataclass
class EvaluatorOptions:
    """How the evaluator process reaches the run and how often it evaluates (keyword-only after the store)."""

    run_id: str
    redis_url: str
    store: str = "."
    _: KW_ONLY
    s3_endpoint: str | None = None
    every: int = 1
    """Evaluate every N-th policy version (always the newest one when it falls behind)."""
    settings: EvalSettings = field(default_factory=EvalSettings)
    outage_s: float = DEFAULT_GIVE_UP_S
    """How long to ride out one Redis or store outage before exiting with an error, seconds."""
    device: str = "auto"
    """Where the network acts: ``auto``, ``cpu``, ``cuda`` or ``cuda:N`` (``trainer.device``)."""
    conditions: list[Condition] = field(default_factory=list)
    """Held-out conditions each checkpoint is also driven in (``racer evaluator --condition``): reported in its
    evaluation record's ``conditions``; ``best`` stays the run's own world's."""


def run_evaluator(opts: EvaluatorOptions, stop: threading.Event | None = None) -> None:
    """The evaluator process: evaluate new checkpoints as the trainer publishes them, keep ``best``, and
    push each summary to Redis for ``racer train`` (status line, ``--stop-when-robust``).

    A Redis or store outage shorter than ``opts.outage_s`` is ridden out (``common/retry.py: Outage``); a longer one
    ends it with OutageError."""
    torch.set_num_threads(1)
    device = resolve_device(opts.device)
    stop = stop or threading.Event()
    bus = Bus.connect(opts.redis_url, opts.run_id)
    runs = RunStore(open_store(opts.store, opts.s3_endpoint))
    on_redis = Outage(f"Redis at {redact(opts.redis_url)}", redis_transient, log, stop, opts.outage_s).call
    on_store = Outage(f"store {runs.store.uri}", is_transient, log, stop, opts.outage_s).call
    done = -1
    try:
        with tempfile.TemporaryDirectory(prefix="racer-eval-") as tmp:
            run = env_cfg = None
            while not stop.is_set():
                pv = on_redis("read the policy version", partial(_newest, bus))
                # Version 0 is the untrained initialization: evaluating it would take a core from the first
                # collection.
                if pv is None or pv.version == 0 or pv.version <= done or pv.version % max(1, opts.every):
                    stop.wait(0.5)
                    continue
                if run is None:
                    run = on_store("read the run", partial(runs.read_config, opts.run_id))
                    env_cfg = on_store("read the run's files", partial(localize_env, run, runs, Path(tmp)))
                recorder = SimTraceRecorder()
                evaluate = partial(
                    evaluate_checkpoint, runs, run, env_cfg, pv.version, opts.settings, recorder=recorder, device=device
                )
                try:
                    record = on_store(f"evaluate v{pv.version}", evaluate)
                    if opts.conditions:
                        held_out = partial(
                            evaluate_conditions,
                            runs,
                            run,
                            env_cfg,
                            pv.version,
                            opts.settings,
                            conditions=opts.conditions,
                            device=device,
                        )
                        record["conditions"] = on_store(f"evaluate v{pv.version} in the conditions", held_out)
                except StoreKeyError:  # pruned while we were behind: the next newest one will do
                    done = pv.version
                    continue
                moved = on_store("save the evaluation", partial(save_evaluation, runs, record))
                on_store("save the sim-trace", partial(_save_simtrace, runs, opts.run_id, recorder, record["created"]))
                summary = evaluation_summary(record, moved)
                on_redis("report the evaluation", partial(bus.report_evaluation, summary))
                log.info("evaluated version %d: %s%s", pv.version, summary, " (new best)" if moved else "")
                done = pv.version
    except InterruptedError:  # stopped (SIGTERM) while Redis or the store was unreachable
        log.warning("stopped during an outage (last evaluated version: %d)", done)


def evaluation_summary(record: dict, moved: bool) -> EvaluationSummary:
    """What the evaluator reports on the bus of an evaluation ``record``; ``moved``: it became the best."""
    fields = set(EvaluationSummary.model_fields) - {"best"}
    # A record from before a field was added (``mean_lap_s``) leaves it at its default.
    return EvaluationSummary.model_validate({**{k: record[k] for k in fields if k in record}, "best": moved})


def _save_simtrace(runs: RunStore, run_id: str, recorder: SimTraceRecorder, created: float) -> None:
    """The evaluation's DeepRacer sim-trace, where deepracer-utils finds evaluations (DRfC's layout)."""
    text = recorder.take(include_open=True)
    if text:
        key = simtrace_key(run_id, "evaluation", 0, evaluation=evaluation_stamp(created))
        runs.store.put(key, text.encode())


def _newest(bus: Bus) -> PolicyVersion | None:
    try:
        return bus.policy()
    except ProtocolError:
        return None
