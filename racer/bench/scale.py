"""``racer bench scale``: how one trainer and one Redis take the load of 1, 4, 16, 64… workers.

Real segments are recorded once: a real ``RolloutWorker`` drives a real ``RacerEnv`` with the run's untrained
policy (version 0, published by a real trainer) and its segments are encoded with ``encode_segment``. Each level
then starts a fresh Redis, a fresh store and the real ``Trainer`` (in this process, in a thread), and forks one
process per synthetic worker that replays the recorded entries at ``rate`` segments/s. A synthetic worker sends
what a real one sends: it pushes each entry with its heartbeat (``Bus.push_segments``), its header re-stamped
(worker id, the policy version it acts with, ``created``: the header JSON only, never the arrays), then GETs the
published policy version and acts with it from its next segment on, as ``RolloutWorker`` polls after each push.

After a warm-up (until the trainer has published version 1) a level is measured for ``seconds``, extended until
two updates have finished in it: the steps that went into PPO updates, Redis memory and CPU, the policy lag of
what was learned, and the segments lost (dropped by the trainer, by reason, and ``trimmed``: pushed but cut from
the capped stream before the trainer read them).
"""

from __future__ import annotations

import copy
import gc
import json
import multiprocessing
import os
import random
import socket
import statistics
import tempfile
import threading
import time
from dataclasses import KW_ONLY, dataclass
from typing import Any

import redis
import torch
from rich.table import Table
from torch.utils.flop_counter import FlopCounterMode

from common.bus import Bus
from common.config import RunConfig
from common.defaults import DEFAULT_TRACK
from common.errors import OptionError
from common.protocol import Heartbeat, decode_segment, encode_segment
from model_store import LocalStore, RunStore
from racer.bench import Report
from racer.embedded_redis import EmbeddedRedis
from racer.runconfig import build_run
from rollout_worker.worker import RolloutWorker, WorkerOptions
from trainer.peak import cpu_model
from trainer.ppo import StepArgs, minibatch_step
from trainer.process import Trainer, TrainerOptions, make_batch, make_optimizer

WARMUP_LIMIT_S = 120.0
"""A level's window opens after the trainer's first update (which also times the precisions, ``trainer.precision``),
or this long after its start if no update came; it closes once two updates have finished in it, or this long after
``seconds`` if they have not. Both are decided between updates, never in the middle of one."""
SAMPLE_EVERY_S = 0.25
"""How often Redis memory is sampled during a level."""
GROWTH = 1.1
"""Intake within 1 / GROWTH of the best level's counts as "stopped growing"."""
BUSY = 0.9
"""A trainer updating this fraction of a level's window or more is the bound on intake ("trainer-bound")."""


@dataclass
class ScaleSettings:
    """The run the levels train (the same for every level) and how each level is run."""

    track: str = DEFAULT_TRACK
    hyperparams: str | None = None
    """A DeepRacer hyperparameters.json; default DeepRacer's (batch 64, 10 epochs, 20 episodes per update)."""
    max_policy_lag: int = 1
    """The trainer's ``max_policy_lag``: synthetic workers never wait for an update (as with any lag above 0)."""
    record_steps: int = 256
    """Env steps recorded from the real worker (at least one finished episode is recorded in any case)."""
    trainer_threads: int = 2
    """PyTorch threads of the trainer (``racer train`` gives it 2)."""
    precision: str = "auto"
    """The trainer's PPO arithmetic (``racer trainer --precision``)."""
    warmup_limit_s: float = WARMUP_LIMIT_S
    """See ``WARMUP_LIMIT_S``."""


@dataclass
class Recording:
    """Real encoded segments, and what the worker that made them measured."""

    entries: list[dict[str, bytes]]
    """Stream-entry fields as ``encode_segment`` made them."""
    steps: int
    """Env steps in all entries."""
    episodes: int
    """Finished episodes in all entries."""
    _: KW_ONLY
    worker_steps_per_s: float
    """Env steps per second of the real worker's ``collect`` (env + policy on one PyTorch thread), from the median
    time of a segment."""
    bytes_per_policy: int
    """Bytes the worker read from the store to switch to a policy version (``poll_policy`` → its ``_load``)."""
    track: str
    update_flops_per_step: float
    """FLOPs of the trainer's PPO update per env step learned (``update_flops_per_step``)."""

    @property
    def bytes_per_step_up(self) -> float:
        """Mean bytes per env step of the encoded entries: every field's name and value."""
        return sum(entry_bytes(e) for e in self.entries) / self.steps


def entry_bytes(fields: dict[str, bytes]) -> int:
    """Bytes of a stream entry's field names and values (what XADD sends, less the Redis protocol's framing)."""
    return sum(len(k) + len(v) for k, v in fields.items())


def restamp(fields: dict[str, bytes], worker_id: str, policy_version: int, created: float) -> dict[str, bytes]:
    """The entry as worker ``worker_id`` would push it now, acting with ``policy_version``: only the header JSON is
    rewritten; the array fields are the same bytes objects."""
    header = json.loads(fields["header"])
    header.update(worker_id=worker_id, policy_version=policy_version, created=created)
    return {**fields, "header": json.dumps(header, separators=(",", ":")).encode()}


# --- recording real segments ------------------------------------------------------------------------------------
class _CountingStore(LocalStore):
    """A directory store that counts the bytes read from it: what a worker downloads."""

    bytes_read = 0

    def get(self, key: str) -> bytes:
        data = super().get(key)
        self.bytes_read += len(data)
        return data


def record_segments(run: RunConfig, files: dict[str, bytes], min_steps: int) -> Recording:
    """Run a real trainer (publishing version 0) and a real worker against a private Redis and store; keep the
    worker's encoded segments (at least ``min_steps`` env steps and one finished episode)."""
    with EmbeddedRedis() as server, tempfile.TemporaryDirectory(prefix="racer-scale-") as store:
        trainer = Trainer(run, TrainerOptions(server.url, store, run_files=files, tensorboard=False))
        trainer.start()
        counting = _CountingStore(store)
        worker = RolloutWorker(WorkerOptions(run.run_id, server.url, store, worker_index=0), runs=RunStore(counting))
        threads = torch.get_num_threads()
        torch.set_num_threads(1)  # as run_worker: one thread per worker process
        try:
            worker.start()
            entries, steps, episodes, times = [], 0, 0, []
            while steps < min_steps or episodes == 0:
                if steps > 64 * max(min_steps, run.segment_steps):
                    raise RuntimeError(f"no episode ended in {steps} env steps of the untrained policy")
                t0 = time.perf_counter()
                (seg,) = worker.collect()  # one env per worker: one segment per collect
                times.append(time.perf_counter() - t0)
                entries.append(encode_segment(seg))
                steps, episodes = steps + seg.steps, episodes + len(seg.episodes)
            # What a worker downloads per policy version: the store objects its switch to a new version reads.
            counting.bytes_read = 0
            worker.poll_policy(reload=True)
            per_policy = counting.bytes_read
            track = worker.rollouts.track_name
            flops = update_flops_per_step(trainer, entries)
        finally:
            worker.close()
            trainer.close()
            torch.set_num_threads(threads)
    timed = times[1:] or times  # the first segment also pays the network's first calls
    rate = run.segment_steps / statistics.median(timed)  # the median: a shared machine's spikes move it less
    return Recording(
        entries,
        steps,
        episodes,
        worker_steps_per_s=rate,
        bytes_per_policy=per_policy,
        track=track,
        update_flops_per_step=flops,
    )


def update_flops_per_step(trainer: Trainer, entries: list[dict[str, bytes]]) -> float:
    """FLOPs of ``trainer``'s PPO update per env step learned: one minibatch step (forward, backward) on recorded
    steps, on a copy of its network, counted by ``torch.utils.flop_counter`` (convolutions and matrix products;
    Adam's few per weight are left out), ÷ the minibatch's steps × ``num_epochs``. The basis of an accelerator's
    ceiling: its peak FLOP/s ÷ this."""
    hp = trainer.hp
    learner = trainer.learner
    shape, n, lidar = learner.obs_shape, learner.n_actions, learner.obs_spec.lidar
    segments = [decode_segment(e, trainer.run.run_id, shape, n, lidar=lidar) for e in entries]
    batch = make_batch(segments, hp.discount_factor, hp.gae_lambda)
    size = min(len(batch), hp.batch_size)
    model = copy.deepcopy(trainer.model).train()
    optimizer = make_optimizer(model, hp.lr, trainer.run.policy.l2)
    args = StepArgs(
        clip_eps=hp.clip_epsilon,
        beta_entropy=hp.beta_entropy,
        value_coef=hp.value_loss_coef,
        loss_type=hp.value_loss_kind,
        max_grad_norm=hp.max_grad_norm,
    )
    with FlopCounterMode(display=False) as counter:
        minibatch_step(model, optimizer, batch.select(torch.arange(size)), **args)
    return counter.get_total_flops() / size * hp.num_epochs


# --- synthetic workers ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _PushPlan:
    """What one pusher process does: workers ``first`` .. ``first + count - 1`` at ``rate`` segments/s each."""

    url: str
    run_id: str
    _: KW_ONLY
    first: int
    count: int
    rate: float
    maxlen: int
    heartbeat_ttl_s: int
    track: str


def _push_loop(
    plan: _PushPlan, entries: list[dict[str, bytes]], stop: Any, segments: Any, steps: Any, failed: Any
) -> None:
    """A pusher process: the synthetic workers of ``plan``, each on its own schedule, until ``stop`` is set."""
    try:
        _push(plan, entries, stop, segments, steps)
    except (redis.RedisError, OSError):
        if not stop.is_set():  # Redis going away at the end of a level is expected
            failed.value = 1


@dataclass
class _Synthetic:
    """One synthetic worker's state in its pusher process."""

    worker_id: str
    slot: int
    due: float
    """When its next segment is ready (``time.monotonic()``)."""
    version: int
    """The policy version it acts with: read after its previous push, as a real worker polls after each push."""
    loaded_at: float
    sent: int = 0


def _push(plan: _PushPlan, entries: list[dict[str, bytes]], stop: Any, segments: Any, steps: Any) -> None:
    bus = Bus(redis.Redis.from_url(plan.url), plan.run_id)
    period = 1.0 / plan.rate
    rng = random.Random(plan.first)
    host, pid = socket.gethostname(), os.getpid()
    while (pv := bus.policy()) is None:  # the trainer publishes version 0 after its start-up
        if stop.wait(0.1):
            return
    now = time.monotonic()
    workers = [  # not in step with each other: each starts at a random point of its period
        _Synthetic(f"scale-{slot}", slot, now + rng.uniform(0.0, period), pv.version, time.time())
        for slot in range(plan.first, plan.first + plan.count)
    ]
    while not stop.is_set():
        w = min(workers, key=lambda x: x.due)
        wait = w.due - time.monotonic()
        if wait > 0:
            stop.wait(wait)
            continue
        entry = entries[(w.slot + w.sent) % len(entries)]
        n_steps = json.loads(entry["header"])["steps"]
        beat = Heartbeat(
            worker_id=w.worker_id,
            pid=pid,
            host=host,
            policy_version=w.version,
            env_steps=steps[w.slot] + n_steps,
            segments=w.sent + 1,
            time=time.time(),
            track=plan.track,
            policy_loaded_at=w.loaded_at,
            max_rss_mb=0.0,
        )
        fields = restamp(entry, w.worker_id, w.version, time.time())
        bus.push_segments([fields], beat, plan.maxlen, plan.heartbeat_ttl_s)
        w.sent += 1
        segments[w.slot] += 1
        steps[w.slot] += n_steps
        pv = bus.policy()  # as RolloutWorker.poll_policy after each push
        if pv is not None and pv.version > w.version:
            w.version, w.loaded_at = pv.version, time.time()
        # A worker that fell behind (a busy machine) pushes again at once but does not burst to catch up.
        w.due = max(w.due + period, time.monotonic() - period)


class _Pushers:
    """One forked process per synthetic worker (or per group of them, with ``processes`` fewer than workers)."""

    def __init__(self, recording: Recording, plan: _PushPlan, workers: int, processes: int) -> None:
        ctx = multiprocessing.get_context("fork")  # the recorded entries are shared, not copied through a pipe
        self.stop = ctx.Event()
        self.segments = ctx.RawArray("q", workers)  # one slot per synthetic worker, written by one process only
        self.steps = ctx.RawArray("q", workers)
        self.failed = ctx.RawValue("i", 0)
        groups = _groups(workers, max(1, min(processes, workers)))
        gc.freeze()  # forked children then leave the parent's objects' pages shared
        self.procs = [
            ctx.Process(
                target=_push_loop,
                args=(
                    _replace(plan, first=first, count=count),
                    recording.entries,
                    self.stop,
                    self.segments,
                    self.steps,
                    self.failed,
                ),
                daemon=True,
            )
            for first, count in groups
        ]
        for p in self.procs:
            p.start()
        gc.unfreeze()

    def totals(self) -> tuple[int, int]:
        """Segments and env steps pushed so far, all workers."""
        return sum(self.segments), sum(self.steps)

    def close(self) -> None:
        """Stop every pusher (killing one that does not stop within 5 s)."""
        self.stop.set()
        for p in self.procs:
            p.join(5)
            if p.is_alive():
                p.kill()
                p.join()
        if self.failed.value:
            raise RuntimeError("a synthetic worker lost its Redis connection during the level")


def _groups(workers: int, processes: int) -> list[tuple[int, int]]:
    """(first worker, count) for each of ``processes`` processes, as even as can be."""
    base, extra = divmod(workers, processes)
    out, first = [], 0
    for i in range(processes):
        count = base + (i < extra)
        out.append((first, count))
        first += count
    return out


def _replace(plan: _PushPlan, **changes: int) -> _PushPlan:
    return _PushPlan(**{**plan.__dict__, **changes})


# --- one level --------------------------------------------------------------------------------------------------
class _MemorySampler(threading.Thread):
    """Redis used memory, sampled until stopped; the highest value seen."""

    def __init__(self, bus: Bus) -> None:
        super().__init__(daemon=True)
        self.bus, self.used_max = bus, 0
        self.halt = threading.Event()

    def run(self) -> None:
        while not self.halt.wait(SAMPLE_EVERY_S):
            try:
                self.used_max = max(self.used_max, self.bus.memory()["used"])
            except redis.RedisError:
                continue


class _Window:
    """A level's measured window: opened once the trainer has published version 1 (or after ``warmup_s``), closed
    after ``seconds`` once two updates have finished in it (or ``extend_s`` later), with counters at both ends."""

    def __init__(self, bus: Bus, pushers: _Pushers, seconds: float, warmup_s: float, extend_s: float) -> None:
        self.bus, self.pushers = bus, pushers
        self.seconds, self.warmup_s, self.extend_s = seconds, warmup_s, extend_s
        self.created = time.monotonic()
        self.start: dict[str, Any] | None = None
        self.end: dict[str, Any] | None = None
        self.sampler = _MemorySampler(bus)

    def check(self, trainer: Trainer) -> bool:
        """Open or close the window as due (called between updates); True once it is closed."""
        now = time.monotonic()
        if self.start is None:
            if trainer.version >= 1 or now - self.created >= self.warmup_s:
                self.start = _snapshot(trainer, self.bus, self.pushers)
                self.sampler.start()
            return False
        elapsed = now - self.start["mono"]
        updates = sum(r["time"] > self.start["wall"] for r in trainer.reporter.metrics)
        if elapsed >= self.seconds and (updates >= 2 or elapsed >= self.seconds + self.extend_s):
            self.end = _snapshot(trainer, self.bus, self.pushers)
            self.sampler.halt.set()
            return True
        return False


def _snapshot(trainer: Trainer, bus: Bus, pushers: _Pushers) -> dict[str, Any]:
    """Counters at one moment of a level: pushed, read and dropped by the trainer, queued, Redis CPU."""
    pushed, pushed_steps = pushers.totals()
    return {
        "wall": time.time(),
        "mono": time.monotonic(),
        "pushed": pushed,
        "pushed_steps": pushed_steps,
        "accepted": sum(trainer.stats.by_worker.values()),
        "accepted_steps": trainer.stats.env_steps,
        "dropped": dict(trainer.stats.dropped),
        "dropped_steps": trainer.stats.dropped_steps,
        "queued": bus.segments_queued(),
        "cpu_s": bus.cpu_seconds(),
    }


def _run_level(
    run: RunConfig,
    files: dict[str, bytes],
    rec: Recording,
    *,
    workers: int,
    rate: float,
    seconds: float,
    settings: ScaleSettings,
    processes: int | None,
) -> dict[str, Any]:
    """One level: fresh Redis and store, the real trainer in a thread, ``workers`` synthetic workers."""
    with EmbeddedRedis() as server, tempfile.TemporaryDirectory(prefix="racer-scale-") as store:
        bus = Bus(redis.Redis.from_url(server.url), run.run_id)
        plan = _PushPlan(
            server.url,
            run.run_id,
            first=0,
            count=workers,
            rate=rate,
            maxlen=run.stream_maxlen,
            heartbeat_ttl_s=int(run.heartbeat_ttl_s) + 1,
            track=rec.track,
        )
        pushers = _Pushers(rec, plan, workers, processes or workers)  # forked before the trainer's threads exist
        errors: list[BaseException] = []
        try:
            torch.set_num_threads(settings.trainer_threads)
            opts = TrainerOptions(server.url, store, run_files=files, tensorboard=False, precision=settings.precision)
            trainer = Trainer(run, opts)
            trainer.start()
            limit = settings.warmup_limit_s
            # The trainer opens and closes the level's window between two updates and stops after it: a level ends
            # at the end of an update, not in the middle of one that it would have to wait for.
            window = _Window(bus, pushers, seconds, limit, limit)
            trainer.stop_when = window.check
            thread = threading.Thread(target=_train, args=(trainer, errors), daemon=True)
            thread.start()
            thread.join()  # the trainer stops at the first update's end after the window closed
            trainer.close()
            peak = bus.memory()["peak"]
        finally:
            pushers.close()
        if errors:
            raise errors[0]
        if window.start is None or window.end is None:
            raise RuntimeError(f"the trainer stopped before the end of the {workers}-worker level")
        rows = [r for r in trainer.reporter.metrics if window.start["wall"] < r["time"] <= window.end["wall"]]
    used_max = window.sampler.used_max
    return _level_figures(
        workers, rate, run.segment_steps, start=window.start, end=window.end, rows=rows, used_max=used_max, peak=peak
    )


def _train(trainer: Trainer, errors: list[BaseException]) -> None:
    try:
        trainer.run_forever()
    except BaseException as exc:  # handed to the level, which raises it
        errors.append(exc)


def _level_figures(
    workers: int,
    rate: float,
    segment_steps: int,
    *,
    start: dict,
    end: dict,
    rows: list[dict],
    used_max: int,
    peak: int,
) -> dict[str, Any]:
    """A level's figures from the counters at the start and end of its measured window and its updates."""
    span = end["mono"] - start["mono"]
    read = (end["accepted"] + sum(end["dropped"].values())) - (start["accepted"] + sum(start["dropped"].values()))
    pushed = end["pushed"] - start["pushed"]
    dropped = {k: v - start["dropped"].get(k, 0) for k, v in end["dropped"].items() if v - start["dropped"].get(k, 0)}
    # Pushed but neither read nor still queued: cut from the capped stream (XADD MAXLEN ~) before the trainer read it.
    dropped["trimmed"] = max(0, pushed - read - (end["queued"] - start["queued"]))
    learned = sum(r["batch_steps"] for r in rows)
    train_s = sum(r["train_s"] for r in rows)
    return {
        "workers": workers,
        "seconds": span,
        "rate_segments_per_s": rate,
        "offered_steps_per_s": workers * rate * segment_steps,
        "pushed_steps_per_s": (end["pushed_steps"] - start["pushed_steps"]) / span,
        "intake_steps_per_s": intake_steps_per_s(rows, start["wall"], end["wall"]),
        "accepted_steps_per_s": (end["accepted_steps"] - start["accepted_steps"]) / span,
        "updates": len(rows),
        "versions_per_s": len(rows) / span,
        "update_steps_per_s": learned / train_s if train_s else None,
        # Near 1: the trainer was updating all the time, so its update rate bounds the intake, not the workers.
        "trainer_busy_fraction": train_s / span,
        "train_s_mean": train_s / len(rows) if rows else None,
        "batch_steps_mean": learned / len(rows) if rows else None,
        "redis_mb": used_max / 2**20,
        "redis_peak_mb": peak / 2**20,
        "redis_cpu_s": end["cpu_s"] - start["cpu_s"],
        "redis_cpu_fraction": (end["cpu_s"] - start["cpu_s"]) / span,
        "staleness_versions": (
            sum(r["mean_policy_lag"] * r["batch_steps"] for r in rows) / learned if learned else None
        ),
        "dropped": dropped,
        "dropped_steps": end["dropped_steps"] - start["dropped_steps"],
        "pushed_segments": pushed,
        "read_segments": read,
        "queued_end": end["queued"],
    }


def intake_steps_per_s(rows: list[dict], t0: float, t1: float) -> float:
    """Env steps learned per second from the update rows (``metrics.jsonl``) that finished in (t0, t1]: with two
    or more, the steps of all but the first over the time between the first and the last (whole update cycles);
    with one, its steps over the window."""
    if len(rows) >= 2:
        return sum(r["batch_steps"] for r in rows[1:]) / (rows[-1]["time"] - rows[0]["time"])
    return sum(r["batch_steps"] for r in rows) / (t1 - t0)


# --- the bench --------------------------------------------------------------------------------------------------
def bench_scale(
    levels: list[int],
    seconds: float,
    rate: float | None = None,
    settings: ScaleSettings | None = None,
    processes: int | None = None,
) -> dict[str, Any]:
    """Trainer intake, Redis memory and CPU, staleness and lost segments with ``levels`` synthetic workers each.

    ``rate``: segments per second per synthetic worker (default: what the recording worker produced: its env
    steps/s ÷ ``segment_steps``). ``processes``: pusher processes per level (default: one per worker).
    """
    settings = settings or ScaleSettings()
    _check_options(levels, seconds, rate, settings)
    run, files = build_run("bench-scale", track=settings.track, hyperparams=settings.hyperparams)
    run = run.model_copy(update={"max_policy_lag": settings.max_policy_lag})
    rec = record_segments(run, files, settings.record_steps)
    per_worker = rate if rate is not None else rec.worker_steps_per_s / run.segment_steps
    results = [
        _run_level(run, files, rec, workers=n, rate=per_worker, seconds=seconds, settings=settings, processes=processes)
        for n in levels
    ]
    hp = run.hyperparams
    return {
        "levels": results,
        "bytes_per_step_up": rec.bytes_per_step_up,
        "bytes_per_policy": rec.bytes_per_policy,
        "worker_steps_per_s": rec.worker_steps_per_s,
        "update_flops_per_step": rec.update_flops_per_step,
        "rate_segments_per_s": per_worker,
        "segment_steps": run.segment_steps,
        "recorded_steps": rec.steps,
        "recorded_episodes": rec.episodes,
        "max_policy_lag": run.max_policy_lag,
        "stream_maxlen": run.stream_maxlen,
        "hyperparameters": {
            "batch_size": hp.batch_size,
            "num_epochs": hp.num_epochs,
            "num_episodes_between_training": hp.num_episodes_between_training,
        },
        "intake_stops_growing_at": stops_growing_at(results),
        "trainer_bound_from": trainer_bound_from(results),
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
    }


def _check_options(levels: list[int], seconds: float, rate: float | None, settings: ScaleSettings) -> None:
    """One OptionError naming the option, for a value the bench cannot run with."""
    if not levels or min(levels) < 1:
        raise OptionError(f"--levels must be worker counts of 1 or more (got {','.join(map(str, levels))})")
    if rate is not None and not rate > 0:
        raise OptionError(f"--rate must be above 0 segments/s per worker (got {rate})")
    if not seconds > 0:
        raise OptionError(f"--seconds must be above 0 (got {seconds})")
    if settings.max_policy_lag < 1:
        # With 0 a real worker waits out each update; the synthetic ones never do, so nearly all would be dropped.
        raise OptionError(f"--max-policy-lag must be 1 or more (got {settings.max_policy_lag})")


def stops_growing_at(levels: list[dict]) -> int | None:
    """The fewest workers whose intake is within ``GROWTH`` of the best level's (None without any intake)."""
    best = max((lv["intake_steps_per_s"] for lv in levels), default=0.0)
    if best <= 0:
        return None
    return min(lv["workers"] for lv in levels if lv["intake_steps_per_s"] * GROWTH >= best)


def trainer_bound_from(levels: list[dict]) -> int | None:
    """The fewest workers at which the trainer spent ``BUSY`` of the window or more in updates (None: at none)."""
    return min((lv["workers"] for lv in levels if lv["trainer_busy_fraction"] >= BUSY), default=None)


def scale_table(result: dict[str, Any]) -> Table:
    """The levels of a ``bench_scale`` result as a table, one row per level."""
    table = Table(
        "workers",
        "offered / pushed steps/s",
        "intake steps/s",
        "updates",
        "trainer busy",
        "staleness (versions)",
        "Redis MiB (used max / peak)",
        "Redis CPU s",
        "dropped",
    )
    for lv in result["levels"]:
        stale = lv["staleness_versions"]
        table.add_row(
            str(lv["workers"]),
            f"{lv['offered_steps_per_s']:.0f} / {lv['pushed_steps_per_s']:.0f}",
            f"{lv['intake_steps_per_s']:.0f}",
            str(lv["updates"]),
            f"{lv['trainer_busy_fraction']:.0%}",
            "-" if stale is None else f"{stale:.2f}",
            f"{lv['redis_mb']:.0f} / {lv['redis_peak_mb']:.0f}",
            f"{lv['redis_cpu_s']:.2f}",
            ", ".join(f"{k} {v}" for k, v in lv["dropped"].items()),
        )
    return table


def scale_summary(result: dict[str, Any]) -> str:
    """The figures of a ``bench_scale`` result that are not per level, in one line."""
    grows, bound = result["intake_stops_growing_at"], result["trainer_bound_from"]
    return (
        f"{result['bytes_per_step_up']:.0f} bytes up per env step, {result['bytes_per_policy'] / 1e6:.1f} MB down "
        f"per policy version and worker; one worker {result['worker_steps_per_s']:.0f} env steps/s; intake stops "
        f"growing at {'-' if grows is None else grows} workers; the trainer bounds it from "
        f"{'-' if bound is None else bound} workers ({result['cpu']}, {result['cores']} cores)"
    )


def command(
    counts: list[int], seconds: float, rate: float | None, settings: ScaleSettings, processes: int | None
) -> Report:
    """``racer bench scale``: the levels' table and the summary line."""
    result = bench_scale(counts, seconds, rate, settings, processes)
    return Report(result, [scale_table(result), scale_summary(result)])
