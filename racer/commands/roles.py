"""The role processes alone, for docker compose and workers on other machines: ``racer trainer``, ``racer
worker`` and ``racer evaluator``. ``racer train`` starts the same commands (``racer/launcher.py``)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from common.bus import TRAINER_BEAT_TTL_S
from common.config import PRECISION_HELP
from common.defaults import (
    DEFAULT_EVAL_EPISODES,
    DEFAULT_EVAL_NICE,
    DEFAULT_TRACK,
    DEFAULT_TRAINER_THREADS,
    EVAL_ACTION_NOISE,
)
from racer.commands.options import (
    DEFAULT_OUTAGE,
    Endpoint,
    EnvsPerWorker,
    Outage,
    Redis,
    RunId,
    Store,
    Verbose,
    WorkerConfig,
    console,
    device_option,
    json_option,
    write_json,
)


def trainer(
    redis_url: Redis,
    store: Store = ".",
    s3_endpoint: Endpoint = None,
    config: Annotated[Path | None, typer.Option(help="RunConfig JSON (written by racer train).")] = None,
    files: Annotated[Path | None, typer.Option(help="Folder with the run's files (written by racer train).")] = None,
    options: Annotated[
        Path | None,
        typer.Option(help="The run's options as JSON (written by racer train); they replace the flags below."),
    ] = None,
    run_id: Annotated[str | None, typer.Option("--run-id", envvar="RACER_RUN_ID", help="Run id.")] = None,
    track: Annotated[str, typer.Option(envvar="RACER_TRACK", help="Track name or .npy path.")] = DEFAULT_TRACK,
    reward_fn: Annotated[Path | None, typer.Option("--reward-fn", envvar="RACER_REWARD_FN")] = None,
    action_space: Annotated[Path | None, typer.Option("--action-space", envvar="RACER_ACTION_SPACE")] = None,
    hyperparams: Annotated[Path | None, typer.Option("--hyperparams", envvar="RACER_HYPERPARAMS")] = None,
    race_type: Annotated[
        str | None,
        typer.Option("--race-type", envvar="RACER_RACE_TYPE", help="TIME_TRIAL, OBJECT_AVOIDANCE, HEAD_TO_BOT."),
    ] = None,
    race: Annotated[Path | None, typer.Option("--race", envvar="RACER_RACE", help="JSON of race settings.")] = None,
    resume: Annotated[bool, typer.Option("--resume", envvar="RACER_RESUME")] = False,
    time_limit: Annotated[str | None, typer.Option("--time-limit", envvar="RACER_TIME_LIMIT")] = None,
    threads: Annotated[
        int, typer.Option(min=1, envvar="RACER_TRAINER_THREADS", help="PyTorch threads.")
    ] = DEFAULT_TRAINER_THREADS,
    precision: Annotated[str, typer.Option(envvar="RACER_PRECISION", help=PRECISION_HELP)] = "auto",
    worker_config: WorkerConfig = None,
    device: Annotated[str, device_option("RACER_DEVICE")] = "auto",
    outage_timeout: Outage = DEFAULT_OUTAGE,
    verbose: Verbose = False,
) -> None:
    """Run the PPO trainer role alone (for docker compose and multi-machine runs)."""
    from common.deadline import parse_duration
    from common.errors import OptionError
    from common.jsonfile import load_json_model
    from model_store import RunStore, open_store
    from racer.lifecycle import setup_logging, stop_event_on_signals
    from racer.options import RunOptions
    from racer.runconfig import load_race, trainer_role_run, worker_settings
    from trainer.device import resolve_device
    from trainer.precision import precision_candidates
    from trainer.process import TrainerOptions, run_trainer

    setup_logging(verbose)
    if options is not None:  # racer train's: its flags, its deadline
        opts = load_json_model(options, "run options", RunOptions, OptionError)
    else:
        opts = RunOptions.from_flags(
            run_id=run_id,
            store=store,
            s3_endpoint=s3_endpoint,
            redis_url=redis_url,
            resume=resume,
            track=track,
            reward_fn=reward_fn,
            action_space=action_space,
            hyperparams=hyperparams,
            race=load_race(race, race_type),
            worker_settings=worker_settings(None, worker_config, None, None),
            time_limit_s=time_limit,
            trainer_threads=threads,
            precision=precision,
            device=device,
        )
    precision_candidates(opts.precision, resolve_device(opts.device))  # bad values fail before any file is written
    runs = RunStore(open_store(opts.store, opts.s3_endpoint))
    run, run_files, resume = trainer_role_run(runs, config, files, opts)
    # The deadline counts from here when this role runs alone; under racer train it came fixed in --options.
    opts = opts.started()
    trainer_opts = TrainerOptions(
        str(opts.redis_url),
        opts.store,
        s3_endpoint=opts.s3_endpoint,
        resume=resume,
        deadline=opts.deadline,
        torch_threads=opts.trainer_threads,
        run_files=run_files,
        outage_s=parse_duration(outage_timeout),
        precision=opts.precision,
        device=opts.device,
    )
    run_trainer(run, trainer_opts, stop_event_on_signals())


def worker(
    redis_url: Redis,
    run_id: RunId,
    store: Store = ".",
    s3_endpoint: Endpoint = None,
    index: Annotated[int | None, typer.Option(envvar="RACER_WORKER_INDEX", help="Worker index (seed, track).")] = None,
    worker_id: Annotated[str, typer.Option("--worker-id", envvar="RACER_WORKER_ID")] = "",
    envs_per_worker: EnvsPerWorker = 1,
    outage_timeout: Outage = DEFAULT_OUTAGE,
    simtrace_log: Annotated[
        bool,
        typer.Option(
            "--simtrace-log/--no-simtrace-log",
            envvar="RACER_SIMTRACE_LOG",
            help="Also log every step's SIM_TRACE_LOG line, as DeepRacer's RoboMaker log does (the CSVs are always "
            "written).",
        ),
    ] = False,
    verbose: Verbose = False,
) -> None:
    """Run one rollout worker (for docker compose and workers on other machines)."""
    from common.deadline import parse_duration
    from racer.lifecycle import setup_logging, stop_event_on_signals
    from rollout_worker.worker import WorkerOptions, run_worker

    setup_logging(verbose, simtrace_lines=simtrace_log)
    # Without --index, the worker takes the next free index from Redis (scaled compose workers: 0, 1, …).
    opts = WorkerOptions(
        run_id,
        redis_url,
        store,
        s3_endpoint=s3_endpoint,
        worker_index=index,
        worker_id=worker_id,
        outage_s=parse_duration(outage_timeout),
        envs_per_worker=envs_per_worker,
    )
    run_worker(opts, stop_event_on_signals())


def evaluator(
    redis_url: Redis,
    run_id: RunId,
    store: Store = ".",
    s3_endpoint: Endpoint = None,
    every: Annotated[int, typer.Option(min=1, envvar="RACER_EVAL_EVERY", help="Evaluate every N-th version.")] = 1,
    episodes: Annotated[
        int, typer.Option(min=1, envvar="RACER_EVAL_EPISODES", help="Starts per direction.")
    ] = DEFAULT_EVAL_EPISODES,
    action_noise: Annotated[float, typer.Option(min=0, max=1, help="Action noise fraction.")] = EVAL_ACTION_NOISE,
    track: Annotated[list[str] | None, typer.Option(help="Evaluate on these tracks (default: the run's).")] = None,
    forward_only: Annotated[
        bool, typer.Option("--forward-only", help="Drive the track's own direction only, as a DeepRacer race.")
    ] = False,
    nice: Annotated[
        int, typer.Option(min=0, max=19, envvar="RACER_EVAL_NICE", help="Lower CPU priority (Unix nice increment).")
    ] = DEFAULT_EVAL_NICE,
    device: Annotated[str, device_option("RACER_DEVICE")] = "auto",
    outage_timeout: Outage = DEFAULT_OUTAGE,
    verbose: Verbose = False,
    condition: Annotated[
        list[str] | None,
        typer.Option(
            "--condition",
            help="Also drive each checkpoint in these held-out conditions (as racer eval --condition; "
            "docs/transfer.md): its evaluation record's 'conditions'. The best pointer stays the run's own world's.",
        ),
    ] = None,
) -> None:
    """Run the evaluator role: robust evaluation of each new checkpoint, and the best pointer."""
    import os

    if nice:
        os.nice(nice)  # first, so that even importing torch yields the CPU to the trainer and the workers
    from common.conditions import load_conditions
    from common.deadline import parse_duration
    from racer.lifecycle import setup_logging, stop_event_on_signals
    from trainer.device import resolve_device
    from trainer.evaluator import EvalSettings, EvaluatorOptions, run_evaluator

    setup_logging(verbose)
    resolve_device(device)  # a bad value fails before Redis is reached
    conditions = load_conditions(condition or [])  # a bad name or file, too
    settings = EvalSettings(
        episodes=episodes, action_noise=action_noise, tracks=track or [], both_directions=not forward_only
    )
    opts = EvaluatorOptions(
        run_id,
        redis_url,
        store,
        s3_endpoint=s3_endpoint,
        every=every,
        settings=settings,
        outage_s=parse_duration(outage_timeout),
        device=device,
        conditions=conditions,
    )
    run_evaluator(opts, stop_event_on_signals())


def status(
    redis_url: Annotated[
        str | None,
        typer.Option(
            "--redis",
            envvar="RACER_REDIS_URL",
            help="redis://[:password@]host:port/db (default: the one racer train recorded in runs/<id>/redis.json).",
        ),
    ] = None,
    run_id: Annotated[
        str | None,
        typer.Option(
            "--run-id", envvar="RACER_RUN_ID", help="Run id (default: the newest racer train running from --store)."
        ),
    ] = None,
    store: Store = ".",
    json_out: Annotated[str | None, json_option("the run's state")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="Print nothing; only the exit code.")] = False,
) -> None:
    """The state of a run from its Redis: the trainer (starting, collecting, updating, or stopped and why), live
    workers, newest policy, last evaluation, and the Redis server's version. Exits 0 while the run's trainer is
    alive (its heartbeat, refreshed by a thread of its own, is younger than ``TRAINER_BEAT_TTL_S``, even in the
    middle of a long PPO update), else 1: docker compose's health check uses it. Without --redis it finds a racer
    train running on this machine by --run-id, or the newest one, from the record it keeps in the store's run
    folder."""
    from common.bus import Bus
    from racer.redis_record import locate_run

    run_id, redis_url = locate_run(store, run_id, redis_url)
    state = Bus.connect(redis_url, run_id).snapshot()
    if not quiet and json_out != "-":
        console.print(status_lines(state, time.time()), highlight=False, soft_wrap=True)
    if not quiet:
        write_json(state, json_out)
    if not trainer_alive(state):
        raise typer.Exit(1)


def trainer_alive(state: dict) -> bool:
    """The run's trainer is running: its heartbeat is live, or (a trainer without one) its status is fresh."""
    beat = state["trainer_beat"]
    return (beat is not None and beat["phase"] != "stopping") or (beat is None and state["trainer"] is not None)


_END_REASONS = {
    "time_limit": "its time limit was reached",
    "max_updates": "term_cond_max_episodes policy updates done",
    "stopped": "it was asked to stop",
}


def _trainer_line(state: dict, now: float) -> str:
    """What the trainer is doing, from its heartbeat, status and end record (``status``)."""
    trainer, beat, end = state["trainer"], state["trainer_beat"], state["trainer_end"]
    progress = ""
    if trainer is not None:
        progress = (
            f"iteration {trainer.get('iteration')}, {trainer.get('env_steps', 0):,} env steps, "
            f"{trainer.get('steps_per_s', 0.0):.0f} steps/s"
        )
    if beat is not None:
        for_s = max(0.0, now - beat["since"])
        doing = {
            "starting": f"starting (for {for_s:.0f} s: loading the run and publishing its first policy)",
            "collecting": "collecting segments",
            "updating": f"updating policy v{beat['policy_version']} (PPO update running for {for_s:.0f} s)",
            "stopping": "stopping",
        }[beat["phase"]]
        return f"trainer: {doing}" + (f"; {progress}" if progress else "")
    if trainer is not None:
        return f"trainer: {progress}"
    if end is not None:
        ago = max(0.0, now - end["time"])
        return (
            f"trainer: stopped {ago:.0f} s ago ({_END_REASONS[end['reason']]}) at policy v{end['policy_version']}, "
            f"{end['env_steps']:,} env steps; its checkpoints: racer models ls --run-id {state['run_id']}"
        )
    if state["policy"] is None and not state["workers"] and state["last_evaluation"] is None:
        return f"trainer: none: this Redis holds nothing of run {state['run_id']} (check --run-id)"
    return f"trainer: not running (no heartbeat in the last {TRAINER_BEAT_TTL_S} s)"


def status_lines(state: dict, now: float) -> str:
    """``racer status``'s text for a ``Bus.snapshot`` taken at ``now`` (epoch seconds)."""
    policy, last = state["policy"], state["last_evaluation"]
    lines = [f"run {state['run_id']} (Redis {state['redis_version']})", _trainer_line(state, now)]
    lines.append(f"policy: v{policy['version']}" if policy else "policy: none published")
    lines.append(f"workers: {len(state['workers'])} alive")
    for w in state["workers"]:
        lines.append(f"  {w['worker_id']}: v{w['policy_version']}, {w['env_steps']:,} steps on {w['track']}")
    if last:
        lap = "-" if last["best_lap_s"] is None else f"{last['best_lap_s']:.2f} s"
        lines.append(f"last evaluation: v{last['version']}, {100 * last['completion_rate']:.0f}% laps, best lap {lap}")
    lines.append(f"segments queued: {state['segments_queued']}")
    return "\n".join(lines)
