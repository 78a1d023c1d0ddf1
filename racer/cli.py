"""The ``racer`` command line. Thin: each command parses options and calls one function."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.table import Table

app = typer.Typer(no_args_is_help=True, help="racer: DeepRacer-style RL on MuJoCo.")
tracks_app = typer.Typer(no_args_is_help=True, help="The bundled DeepRacer tracks.")
bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks.")
app.add_typer(tracks_app, name="tracks")
app.add_typer(bench_app, name="bench")
console = Console()


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        console.print(f"racer {version('racer')}", highlight=False)
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Show racer's version and exit.")
    ] = False,
) -> None:
    """racer: DeepRacer-style RL on MuJoCo."""


def fail(message: str) -> NoReturn:
    """Print a one-line error and exit non-zero (user errors get no traceback)."""
    Console(stderr=True).print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(2)


def write_json(data: object, target: str | None) -> None:
    """Write machine-readable output to a file, or to standard output for ``-``."""
    if target is None:
        return
    text = json.dumps(data, indent=2)
    if target == "-":
        sys.stdout.write(text + "\n")
    else:
        Path(target).write_text(text + "\n")


def _user_errors() -> tuple[type[Exception], ...]:
    import redis
    from pydantic import ValidationError

    from common.action_space import ActionSpaceError
    from common.car_calibration import CalibrationError
    from common.hyperparams import HyperparametersError
    from common.redis_util import RedisUrlError
    from common.retry import OutageError
    from model_store import StoreError
    from racer.embedded_redis import RedisStartError
    from sim.reward import RewardFunctionError
    from sim.track import TrackError

    return (
        redis.ConnectionError,
        redis.AuthenticationError,
        TimeoutError,
        TrackError,
        ActionSpaceError,
        CalibrationError,
        RewardFunctionError,
        HyperparametersError,
        StoreError,
        RedisUrlError,
        RedisStartError,
        OutageError,
        ValidationError,
        ValueError,
        FileNotFoundError,
    )


def _setup_logging(verbose: bool = False) -> None:
    import logging

    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    # Never debug-log the HTTP libraries: botocore's request dumps carry the Authorization header (the access key
    # id and a signature), and -v is what a user pastes into a bug report.
    for name in ("botocore", "boto3", "s3transfer", "urllib3"):
        logging.getLogger(name).setLevel(logging.INFO)


def _stop_event_on_signals():
    """A threading.Event set by SIGTERM/SIGINT, so a role process finishes its step and exits cleanly."""
    import signal
    import threading

    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    return stop


StoreOpt = Annotated[
    str, typer.Option("--store", envvar="RACER_STORE", help="s3://bucket/prefix or a directory (runs go in runs/).")
]
EndpointOpt = Annotated[
    str | None, typer.Option("--s3-endpoint", envvar="AWS_ENDPOINT_URL", help="S3 endpoint URL (MinIO, moto).")
]
RunIdOpt = Annotated[str, typer.Option("--run-id", envvar="RACER_RUN_ID", help="Run id.")]
RedisOpt = Annotated[str, typer.Option("--redis", envvar="RACER_REDIS_URL", help="redis://[:password@]host:port/db")]
OutageOpt = Annotated[
    str,
    typer.Option(
        "--outage-timeout",
        envvar="RACER_OUTAGE_TIMEOUT",
        help="Ride out a Redis or store outage this long before exiting (90s, 10m).",
    ),
]
CarCalibrationOpt = Annotated[
    str | None,
    typer.Option(
        "--car", "--car-calibration", help="The car to simulate: a preset (default) or a car.json (racer calibrate)."
    ),
]


@app.command("train")
def train_cmd(
    track: Annotated[str | None, typer.Option(help="Track name or .npy path [default: reinvent_base].")] = None,
    workers: Annotated[int | None, typer.Option(min=1, help="Rollout worker processes [default: 2].")] = None,
    time_limit: Annotated[str | None, typer.Option("--time-limit", help="Stop after this long (90s, 5m, 2h).")] = None,
    run_id: Annotated[str | None, typer.Option("--run-id", help="Run id (default: run-<UTC time>).")] = None,
    store: StoreOpt = ".",
    s3_endpoint: EndpointOpt = None,
    redis_url: Annotated[str | None, typer.Option("--redis", help="Use this Redis instead of an embedded one.")] = None,
    reward_fn: Annotated[Path | None, typer.Option("--reward-fn", help="DeepRacer reward function .py.")] = None,
    action_space: Annotated[Path | None, typer.Option("--action-space", help="DeepRacer model_metadata.json.")] = None,
    hyperparams: Annotated[Path | None, typer.Option("--hyperparams", help="DeepRacer hyperparameters.json.")] = None,
    randomization: Annotated[Path | None, typer.Option(help="JSON of domain randomization settings.")] = None,
    worker_track: Annotated[list[str] | None, typer.Option("--worker-track", help="Per-worker tracks.")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue the run from its latest checkpoint.")] = False,
    seed: Annotated[int, typer.Option(help="Base random seed.")] = 0,
    car_calibration: CarCalibrationOpt = None,
    max_policy_lag: Annotated[int, typer.Option(min=0, help="Drop segments this many versions old.")] = 0,
    segment_steps: Annotated[int, typer.Option(min=1, help="Env steps per segment sent to Redis.")] = 32,
    evaluate: Annotated[bool, typer.Option("--eval/--no-eval", help="Run the evaluator beside the trainer.")] = True,
    eval_every: Annotated[int, typer.Option(min=1, help="Evaluate every N-th checkpoint.")] = 1,
    eval_episodes: Annotated[int, typer.Option(min=1, help="Evaluation starts per direction.")] = 3,
    eval_track: Annotated[list[str] | None, typer.Option("--eval-track", help="Evaluate on these tracks.")] = None,
    stop_when_robust: Annotated[
        int | None, typer.Option(min=1, help="Stop after K consecutive checkpoints complete every evaluation lap.")
    ] = None,
    precision: Annotated[
        str, typer.Option(help="The trainer's PPO update arithmetic: auto (bf16 where native), fp32, bf16.")
    ] = "auto",
    from_drfc: Annotated[
        Path | None,
        typer.Option("--from-drfc", help="A DeepRacer-for-Cloud folder: custom_files/ and run.env (options win)."),
    ] = None,
    pretrained: Annotated[
        str | None,
        typer.Option(help="Start from another run's weights in the store: RUN[:best|latest|N] (DRfC pretrained)."),
    ] = None,
) -> None:
    """Train: an embedded Redis (unless --redis), the PPO trainer and N rollout workers on this machine."""
    from common.config import RunConfig, check_precision
    from model_store import RunStore, open_store
    from racer.check import drfc_lines, merge_inputs
    from racer.launcher import TrainOptions, new_run_id, run_summary, run_train
    from racer.runconfig import build_run, check_pretrained, parse_duration

    try:
        limit = parse_duration(time_limit) if time_limit else None
        check_precision(precision)
        inputs = merge_inputs(track, reward_fn, action_space, hyperparams, from_drfc)
        track, workers = inputs.track, workers or inputs.workers or 2
        eval_episodes = inputs.eval_episodes if eval_episodes == 3 and inputs.eval_episodes else eval_episodes
        rid = run_id or inputs.run_id or new_run_id()
        if resume and not run_id:
            fail("--resume needs --run-id")
        runs = RunStore(open_store(store, s3_endpoint))
        if resume:
            run = RunConfig.model_validate_json(runs.read_file(rid, "config.json"))
            files: dict[str, bytes] = {}
        else:
            if runs.newest_whole(rid) is not None:
                fail(f"run {rid!r} already exists in {store}: add --resume to continue it, or choose another --run-id")
            notes: list[str] = []
            run, files = build_run(
                rid,
                track,
                inputs.reward_fn,
                inputs.action_space,
                inputs.hyperparams,
                str(randomization) if randomization else None,
                worker_track,
                seed,
                str(car_calibration) if car_calibration else None,
                notes=notes,
                randomization_update=inputs.randomization,
            )
            run = run.model_copy(update={"max_policy_lag": max_policy_lag, "segment_steps": segment_steps})
            source = pretrained or inputs.pretrained
            if source:
                run = check_pretrained(runs, run, files, source)
            for line in notes + drfc_lines(inputs.drfc):
                console.print(line, highlight=False, soft_wrap=True)
        opts = TrainOptions(
            workers,
            redis_url,
            store,
            s3_endpoint,
            limit,
            resume,
            evaluate=evaluate,
            eval_every=eval_every,
            eval_episodes=eval_episodes,
            stop_when_robust=stop_when_robust,
            eval_tracks=eval_track or [],
            precision=precision,
        )
        console.print(f"run [bold]{rid}[/]: {workers} workers on {run.env.track}, store {store}")
        status = run_train(run, opts, files, console)
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    except typer.Exit:
        raise
    except RuntimeError as exc:
        fail(str(exc))
    console.print(
        f"done: {status.get('iteration', 0)} iterations, {status.get('env_steps', 0):,} env steps "
        f"in {status.get('trained_s', 0.0):.0f} s",
        highlight=False,
    )
    try:
        for line in run_summary(rid, runs, store, s3_endpoint):
            console.print(line, highlight=False, soft_wrap=True)
    except _user_errors() as exc:  # the run is trained and saved; only its description failed
        console.print(f"[yellow]could not read the run's summary: {str(exc).splitlines()[0]}", highlight=False)


@app.command("check")
def check_cmd(
    reward_fn: Annotated[Path | None, typer.Option("--reward-fn", help="DeepRacer reward function .py.")] = None,
    action_space: Annotated[Path | None, typer.Option("--action-space", help="DeepRacer model_metadata.json.")] = None,
    hyperparams: Annotated[Path | None, typer.Option("--hyperparams", help="DeepRacer hyperparameters.json.")] = None,
    track: Annotated[str | None, typer.Option(help="Track name or .npy path [default: reinvent_base].")] = None,
    from_drfc: Annotated[
        Path | None, typer.Option("--from-drfc", help="A DeepRacer-for-Cloud folder: custom_files/ and run.env.")
    ] = None,
) -> None:
    """Validate DeepRacer files exactly as racer train would, start nothing, and say what racer does with each."""
    from racer.check import check_files, merge_inputs

    try:
        lines = check_files(merge_inputs(track, reward_fn, action_space, hyperparams, from_drfc))
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    for line in lines:
        console.print(line, highlight=False, soft_wrap=True)
    console.print("ok: racer train would accept these files", highlight=False)


@app.command("trainer")
def trainer_cmd(
    redis_url: RedisOpt,
    store: StoreOpt = ".",
    s3_endpoint: EndpointOpt = None,
    config: Annotated[Path | None, typer.Option(help="RunConfig JSON (written by racer train).")] = None,
    files: Annotated[Path | None, typer.Option(help="Folder with the run's files (written by racer train).")] = None,
    run_id: Annotated[str | None, typer.Option("--run-id", envvar="RACER_RUN_ID", help="Run id.")] = None,
    track: Annotated[str, typer.Option(envvar="RACER_TRACK", help="Track name or .npy path.")] = "reinvent_base",
    reward_fn: Annotated[Path | None, typer.Option("--reward-fn", envvar="RACER_REWARD_FN")] = None,
    action_space: Annotated[Path | None, typer.Option("--action-space", envvar="RACER_ACTION_SPACE")] = None,
    hyperparams: Annotated[Path | None, typer.Option("--hyperparams", envvar="RACER_HYPERPARAMS")] = None,
    resume: Annotated[bool, typer.Option("--resume", envvar="RACER_RESUME")] = False,
    time_limit: Annotated[str | None, typer.Option("--time-limit", envvar="RACER_TIME_LIMIT")] = None,
    threads: Annotated[int, typer.Option(min=1, envvar="RACER_TRAINER_THREADS", help="PyTorch threads.")] = 1,
    precision: Annotated[
        str,
        typer.Option(envvar="RACER_PRECISION", help="PPO update arithmetic: auto (bf16 where native), fp32, bf16."),
    ] = "auto",
    outage_timeout: OutageOpt = "10m",
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Run the PPO trainer role alone (for docker compose and multi-machine runs)."""
    from common.config import RunConfig
    from model_store import RunStore, open_store
    from racer.runconfig import build_run, parse_duration
    from trainer.process import TrainerOptions, run_trainer

    _setup_logging(verbose)
    try:
        from common.config import check_precision

        check_precision(precision)  # a bad value fails before any file is written
        run_files: dict[str, bytes] = {}
        if config:
            run = RunConfig.model_validate_json(config.read_text())
            if files:
                run_files = {p.name: p.read_bytes() for p in files.iterdir() if p.is_file() and p.name != config.name}
        elif resume:
            if not run_id:
                fail("--resume needs --run-id")
            run = RunConfig.model_validate_json(
                RunStore(open_store(store, s3_endpoint)).read_file(run_id, "config.json")
            )
        else:
            if not run_id:
                fail("give --run-id (or RACER_RUN_ID) or --config")
            run, run_files = build_run(
                run_id,
                track,
                str(reward_fn) if reward_fn else None,
                str(action_space) if action_space else None,
                str(hyperparams) if hyperparams else None,
            )
        runs = RunStore(open_store(store, s3_endpoint))
        if not resume and runs.newest_whole(run.run_id) is not None:
            # A restarted trainer (compose's restart: on-failure, a crashed host) continues its run, never restarts it.
            import logging

            logging.getLogger("racer.trainer").warning(
                "run %s already has checkpoints in %s: continuing it (as --resume)", run.run_id, store
            )
            resume, run = True, RunConfig.model_validate_json(runs.read_file(run.run_id, "config.json"))
        opts = TrainerOptions(
            redis_url,
            store,
            s3_endpoint,
            resume,
            parse_duration(time_limit) if time_limit else None,
            threads,
            run_files,
            outage_s=parse_duration(outage_timeout),
            precision=precision,
        )
        run_trainer(run, opts, _stop_event_on_signals())
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])


@app.command("worker")
def worker_cmd(
    redis_url: RedisOpt,
    run_id: RunIdOpt,
    store: StoreOpt = ".",
    s3_endpoint: EndpointOpt = None,
    index: Annotated[int | None, typer.Option(envvar="RACER_WORKER_INDEX", help="Worker index (seed, track).")] = None,
    worker_id: Annotated[str, typer.Option("--worker-id", envvar="RACER_WORKER_ID")] = "",
    outage_timeout: OutageOpt = "10m",
    simtrace_log: Annotated[
        bool,
        typer.Option(
            "--simtrace-log/--no-simtrace-log",
            envvar="RACER_SIMTRACE_LOG",
            help="Also log every step's SIM_TRACE_LOG line, as DeepRacer's RoboMaker log does (the CSVs are always "
            "written).",
        ),
    ] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Run one rollout worker (for docker compose and workers on other machines)."""
    import logging

    from common.simtrace import LOG as SIMTRACE_LOG
    from rollout_worker.worker import WorkerOptions, run_worker

    _setup_logging(verbose)
    # One line per step (15 a second per worker) fills a log fast; the sim-trace CSVs in the store hold the same rows.
    SIMTRACE_LOG.setLevel(logging.INFO if simtrace_log else logging.WARNING)
    try:
        # Without --index, the worker takes the next free index from Redis (scaled compose workers: 0, 1, …).
        from racer.runconfig import parse_duration

        opts = WorkerOptions(
            run_id, redis_url, store, s3_endpoint, index, worker_id, outage_s=parse_duration(outage_timeout)
        )
        run_worker(opts, _stop_event_on_signals())
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])


@app.command("evaluator")
def evaluator_cmd(
    redis_url: RedisOpt,
    run_id: RunIdOpt,
    store: StoreOpt = ".",
    s3_endpoint: EndpointOpt = None,
    every: Annotated[int, typer.Option(min=1, envvar="RACER_EVAL_EVERY", help="Evaluate every N-th version.")] = 1,
    episodes: Annotated[int, typer.Option(min=1, envvar="RACER_EVAL_EPISODES", help="Starts per direction.")] = 6,
    action_noise: Annotated[float, typer.Option(min=0, max=1, help="Action noise fraction.")] = 0.1,
    track: Annotated[list[str] | None, typer.Option(help="Evaluate on these tracks (default: the run's).")] = None,
    forward_only: Annotated[
        bool, typer.Option("--forward-only", help="Drive the track's own direction only, as a DeepRacer race.")
    ] = False,
    nice: Annotated[
        int, typer.Option(min=0, max=19, envvar="RACER_EVAL_NICE", help="Lower CPU priority (Unix nice increment).")
    ] = 0,
    verbose: Annotated[bool, typer.Option("--verbose", "-v")] = False,
) -> None:
    """Run the evaluator role: robust evaluation of each new checkpoint, and the best pointer."""
    import os

    if nice:
        os.nice(nice)  # first, so that even importing torch yields the CPU to the trainer and the workers
    from trainer.evaluator import EvalSettings, EvaluatorOptions, run_evaluator

    _setup_logging(verbose)
    settings = EvalSettings(
        episodes=episodes, action_noise=action_noise, tracks=track or [], both_directions=not forward_only
    )
    try:
        run_evaluator(
            EvaluatorOptions(run_id, redis_url, store, s3_endpoint, every, settings), _stop_event_on_signals()
        )
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])


@app.command("eval")
def eval_cmd(
    run_id: Annotated[str, typer.Option("--run-id", help="Run id.")],
    store: StoreOpt = ".",
    s3_endpoint: EndpointOpt = None,
    checkpoint: Annotated[str, typer.Option(help="best, latest or a version number.")] = "best",
    track: Annotated[list[str] | None, typer.Option(help="Track(s) to drive (default: the run's).")] = None,
    episodes: Annotated[int, typer.Option(min=1, help="Start positions per direction and track.")] = 6,
    both_directions: Annotated[bool, typer.Option("--both-directions/--one-direction")] = True,
    action_noise: Annotated[float, typer.Option(min=0, max=1, help="Action noise fraction.")] = 0.1,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the result as JSON to F (- = stdout).")] = None,
    sim_trace: Annotated[Path | None, typer.Option("--sim-trace", help="Write a DeepRacer sim-trace CSV.")] = None,
    video: Annotated[Path | None, typer.Option("--video", help="Write an MP4 of the first trial.")] = None,
    car_calibration: Annotated[
        str | None,
        typer.Option("--car", "--car-calibration", help="Drive this car (a preset or a car.json), not the run's."),
    ] = None,
) -> None:
    """Evaluate a checkpoint of a run from a store: a table per trial, and the JSON summary."""
    from racer.evaluate import run_eval

    try:
        record = run_eval(
            run_id,
            store,
            s3_endpoint,
            checkpoint,
            track or [],
            episodes,
            both_directions,
            action_noise,
            sim_trace,
            video,
            car_calibration,
        )
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    if json_out != "-":
        table = Table("track", "direction", "start", "status", "progress %", "steps", "lap s")
        for t in record["trials"]:
            lap = "-" if t["lap_time_s"] is None else f"{t['lap_time_s']:.2f}"
            table.add_row(
                t["track"],
                "reverse" if t["reverse"] else "forward",
                str(t["start_index"]),
                t["status"],
                f"{t['progress']:.1f}",
                str(t["steps"]),
                lap,
            )
        console.print(table)
        best = "-" if record["best_lap_s"] is None else f"{record['best_lap_s']:.2f} s"
        console.print(
            f"version {record['version']}: completion {100 * record['completion_rate']:.0f}%, "
            f"mean progress {record['mean_progress']:.1f}%, best lap {best}, score {record['score']:.1f}"
        )
    summary = {k: v for k, v in record.items() if k != "trials"}
    summary["trials"] = [{k: v for k, v in t.items() if k != "trajectory"} for t in record["trials"]]
    write_json(summary, json_out)


@app.command("export")
def export_cmd(
    run_id: Annotated[str, typer.Option("--run-id", help="Run id.")],
    out: Annotated[
        Path, typer.Option("-o", "--out", help="Where to write the model (model_metadata.json goes beside).")
    ],
    store: StoreOpt = ".",
    s3_endpoint: EndpointOpt = None,
    checkpoint: Annotated[str, typer.Option(help="best, latest or a version number.")] = "best",
    fmt: Annotated[str, typer.Option("--format", help="Export format: onnx.")] = "onnx",
    json_out: Annotated[
        str | None, typer.Option("--json", help="Write what was exported as JSON to F (- = stdout).")
    ] = None,
) -> None:
    """Export a checkpoint's policy for a car (ONNX), with the run's model_metadata.json beside it."""
    from deploy.export import export_onnx
    from model_store import RunStore, open_store

    if fmt != "onnx":
        fail(f"--format {fmt!r} is not supported: use onnx")
    try:
        runs = RunStore(open_store(store, s3_endpoint))
        if checkpoint == "best" and runs.pointer(run_id, "best") is None:
            checkpoint = "latest"  # a run without an evaluator has no best: its newest policy is the one to drive
        result = export_onnx(runs, run_id, checkpoint, out)
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    console.print(f"exported run {run_id} v{result['version']} to {result['model']} (+ {result['model_metadata']})")
    write_json(result, json_out)


@app.command("car")
def car_cmd(
    model: Annotated[Path, typer.Option(help="model.onnx from racer export (model_metadata.json beside it).")],
    source: Annotated[str, typer.Option(help="Camera index (0) or a video file / image sequence (frames/%04d.png).")],
    vehicle: Annotated[Path | None, typer.Option(help="Vehicle calibration JSON (default: the defaults).")] = None,
    out: Annotated[str, typer.Option(help="CSV of motor commands, one row per frame (- = stdout).")] = "-",
    max_frames: Annotated[int | None, typer.Option(min=1, help="Stop after N frames.")] = None,
    json_out: Annotated[
        str | None, typer.Option("--json", help="Write frames and rates as JSON to F (- = stdout).")
    ] = None,
) -> None:
    """The on-car runtime: camera frames → policy (ONNX, one CPU thread) → vehicle calibration → motor commands."""
    from dataclasses import asdict

    from deploy.runtime import CsvSink, Policy, drive
    from deploy.vehicle import VehicleCalibration, load_vehicle_calibration

    try:
        calibration = load_vehicle_calibration(vehicle) if vehicle else VehicleCalibration()
        policy = Policy(model)
        result = drive(policy, source, calibration, CsvSink(out), max_frames)
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    Console(stderr=True).print(
        f"{result.frames} frames at {result.fps:.1f} frames/s (inference {result.infer_ms_median:.2f} ms, "
        f"loop {result.loop_ms_median:.2f} ms, medians)"
    )
    write_json(asdict(result), json_out)


@app.command("calibrate")
def calibrate_cmd(
    logs: Annotated[
        list[Path], typer.Argument(help="Measured logs: sim-trace CSVs, RoboMaker logs, plain CSVs, folders.")
    ],
    apply: Annotated[
        str | None, typer.Option("--apply", help="Score this car (NAME|FILE: a preset or a car.json) on LOGS.")
    ] = None,
    car: Annotated[
        str | None, typer.Option("--car", help="Fit on top of this car (NAME|FILE), keeping its design values.")
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write the fitted calibration (car.json) here.")] = None,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the report as JSON to F (- = stdout).")] = None,
    png: Annotated[Path | None, typer.Option("--png", help="Write trajectories and residuals before/after.")] = None,
    effects: Annotated[
        list[str] | None, typer.Option("--effect", help="Candidate effect (repeatable; default: all of them).")
    ] = None,
    track: Annotated[str | None, typer.Option(help="Track the logs were driven on (for the picture).")] = None,
    max_windows: Annotated[int, typer.Option(min=20, help="Replay windows to fit on (and to choose on).")] = 400,
    timing: Annotated[
        str, typer.Option(help="Row durations: auto, nominal, logged or logged_previous (see docs/calibration.md).")
    ] = "auto",
) -> None:
    """Fit the car to measured logs (effects, values, error before/after on held-out episodes), or --apply one."""
    from racer.calibrate import run_calibrate

    try:
        # Progress goes to stderr, so that --json - leaves standard output to the JSON alone.
        progress = Console(stderr=True, highlight=False).print
        report = run_calibrate(logs, apply, out, png, effects, track, max_windows, progress, timing, base=car)
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    if json_out != "-":
        table = Table("error (1 s replay)", "before", "after", "cut")
        for key, unit in (("position_m", "m"), ("heading_deg", "deg"), ("speed_mps", "m/s")):
            b, a = report["error_before"][key], report["error_after"][key]
            table.add_row(f"{key.split('_')[0]} ({unit})", f"{b:.3f}", f"{a:.3f}", f"{100 * (1 - a / b):.0f}%")
        console.print(table)
        for e in report["effects"]:
            errors = e.get("stderr") or {}
            values = ", ".join(
                f"{k} = {v:.3g}" + (f" ± {errors[k]:.2g}" if k in errors else "") for k, v in e["params"].items()
            )
            console.print(f"  {e['name']}: {values}")
    write_json(report, json_out)


@app.command("limit")
def limit_cmd(
    track: Annotated[str, typer.Argument(help="Track name or .npy path (a loop).")],
    car: Annotated[str, typer.Option(help="Car: a preset name (default) or a car.json from racer calibrate.")] = (
        "default"
    ),
    action_space: Annotated[
        Path | None, typer.Option("--action-space", help="model_metadata.json: its top speed caps the car's.")
    ] = None,
    margin: Annotated[
        float, typer.Option(min=0.0, max=0.08, help="Metres the car's centre keeps inside DeepRacer's off-track line.")
    ] = 0.05,
    png: Annotated[Path | None, typer.Option("--png", help="Write the line coloured by speed over the track.")] = None,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the report as JSON to F (- = stdout).")] = None,
) -> None:
    """The minimum lap time of a car on a track: its racing line and speed profile, and a lap driven on it."""
    from racer.limit import compute_limit, plot_limit, public

    try:
        report = compute_limit(track, car, action_space, margin)
    except (*_user_errors(), ValueError) as exc:
        fail(str(exc).splitlines()[0])
    if png:
        plot_limit(report, png)
    if json_out != "-":
        driven = report["driven_lap_time_s"]
        ratio = report["driven_over_limit"]
        console.print(
            f"{track}, car {car}: limit {report['lap_time_s']:.2f} s from a standing start "
            f"(flying lap {report['flying_lap_time_s']:.2f} s) on a {report['line_length_m']:.2f} m line, "
            f"top speed {report['max_speed_mps']:.2f} m/s",
            highlight=False,
        )
        console.print(
            "driven in the env by a predictive line follower: "
            + (f"{driven:.2f} s ({100 * (ratio - 1):+.1f} % of the limit)" if driven else report["driven_status"])
            + (f" at {100 * report['driven_pace']:.0f} % of the profile's speeds" if report["driven_pace"] < 1 else "")
            + f"; {report['seconds']['total']:.1f} s in all",
            highlight=False,
        )
    write_json(public(report), json_out)


@app.command("plot")
def plot_cmd(
    run_id: Annotated[str, typer.Argument(help="Run id.")],
    store: StoreOpt = ".",
    s3_endpoint: EndpointOpt = None,
    out: Annotated[Path, typer.Option(help="Folder for training.png and trajectories.png.")] = Path("."),
) -> None:
    """PNGs of a run: training curves with evaluation completion, and evaluation trajectories coloured by speed."""
    from model_store import RunStore, open_store
    from racer.plots import plot_run

    try:
        paths = plot_run(run_id, RunStore(open_store(store, s3_endpoint)), out)
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    for p in paths:
        console.print(f"wrote {p}")


models_app = typer.Typer(no_args_is_help=True, help="Runs and checkpoints in a store.")
app.add_typer(models_app, name="models")


@models_app.command("ls")
def models_ls(
    store: StoreOpt = ".",
    s3_endpoint: EndpointOpt = None,
    run_id: Annotated[str | None, typer.Option("--run-id", help="Only this run.")] = None,
    wide: Annotated[bool, typer.Option("--wide", help="All columns, the run id on every row.")] = False,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the list as JSON to F (- = stdout).")] = None,
) -> None:
    """List checkpoints, one line each under their run: version, env steps, time, size, evaluation, latest/best."""
    from racer.evaluate import models_table

    try:
        rows = models_table(store, s3_endpoint, run_id)
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    if json_out != "-":
        for table in _models_tables(rows, wide):
            console.print(table)
    write_json(rows, json_out)


@models_app.command("prune")
def models_prune(
    store: StoreOpt = ".",
    s3_endpoint: EndpointOpt = None,
    run_id: Annotated[list[str] | None, typer.Option("--run-id", help="Only this run (repeatable).")] = None,
    keep: Annotated[int, typer.Option(min=0, help="Newest checkpoints to keep beside latest and best.")] = 1,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Say what would go; delete nothing.")] = False,
    json_out: Annotated[str | None, typer.Option("--json", help="Write what went as JSON to F (- = stdout).")] = None,
) -> None:
    """Shrink runs you are done training: delete all checkpoints but the newest --keep and the latest and best
    ones, and every optimizer state but the newest checkpoint's. Do not prune a run that is still training."""
    from model_store import RunStore, open_store

    try:
        runs = RunStore(open_store(store, s3_endpoint))
        results = [runs.prune_run(r, keep, dry_run) for r in run_id or runs.list_runs()]
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    if json_out != "-":
        verb = "would free" if dry_run else "freed"
        for r in results:
            console.print(
                f"{r['run_id']}: {verb} {r['bytes'] / 1e6:.1f} MB ({len(r['checkpoints'])} checkpoints, "
                f"{len(r['optimizer_states'])} optimizer states)",
                highlight=False,
            )
    write_json(results, json_out)


def _models_tables(rows: list[dict], wide: bool) -> list[Table]:
    """One table per run that fits 80 columns (the run id as its title), or with --wide one table of all."""
    import datetime

    columns = ["v", "env steps", "created (UTC)", "size", "laps", "progress", "best lap", ""]
    runs = [None] if wide else list(dict.fromkeys(r["run_id"] for r in rows))
    tables = []
    for run in runs:
        table = Table(box=None, pad_edge=False, title=run, title_justify="left")
        for name in ["run", *columns] if wide else columns:
            table.add_column(name, no_wrap=True)
        for r in rows if wide else [r for r in rows if r["run_id"] == run]:
            created = datetime.datetime.fromtimestamp(r.get("created") or 0, datetime.UTC)
            ev = r.get("evaluation") or {}
            cells = [
                str(r["version"]),
                "-" if r.get("env_steps") is None else f"{r['env_steps']:,}",
                f"{created:%Y-%m-%d %H:%M}",
                f"{(r.get('size_bytes') or 0) / 1e6:.1f} MB",
                "-" if not ev else f"{100 * ev['completion_rate']:.0f}%",
                "-" if not ev else f"{ev['mean_progress']:.1f}%",
                "-" if ev.get("best_lap_s") is None else f"{ev['best_lap_s']:.2f} s",
                " ".join(m for m in ("latest", "best") if r.get(m)),
            ]
            table.add_row(*([r["run_id"], *cells] if wide else cells))
        tables.append(table)
    return tables


@tracks_app.command("ls")
def tracks_ls() -> None:
    """List the bundled tracks with their length, width and direction."""
    from sim.track import bundled_track_names, load_track

    table = Table("track", "length m", "width m", "direction", "waypoints")
    for name in bundled_track_names():
        t = load_track(name)
        direction = "open" if not t.closed else ("CW" if t.clockwise else "CCW")
        table.add_row(name, f"{t.length:.2f}", f"{t.width:.2f}", direction, str(len(t.center)))
    console.print(table)


@tracks_app.command("show")
def tracks_show(
    track: Annotated[str, typer.Argument(help="Bundled track name or path to a DeepRacer .npy file.")],
    png: Annotated[Path, typer.Option("--png", help="Write the picture to this PNG file.")],
    start: Annotated[int, typer.Option(help="Waypoint where the car is placed.")] = 0,
    camera: Annotated[str, typer.Option(help="Camera path: ground or mujoco.")] = "ground",
) -> None:
    """Write a PNG: the track from above with the car at a start waypoint, and its camera view."""
    from racer.plots import write_track_picture

    try:
        write_track_picture(track, png, start, camera)
    except _user_errors() as exc:
        fail(str(exc))
    console.print(f"wrote {png}")


@bench_app.command("env")
def bench_env_cmd(
    track: Annotated[str, typer.Option(help="Track name or .npy path.")] = "reinvent_base",
    steps: Annotated[int, typer.Option(min=100, help="Env steps per timed run.")] = 3000,
    repeats: Annotated[int, typer.Option(min=1, help="Timed runs; the median is reported.")] = 5,
    camera: Annotated[str, typer.Option(help="Camera path: ground or mujoco.")] = "ground",
    car_calibration: CarCalibrationOpt = None,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the result as JSON to F (- = stdout).")] = None,
) -> None:
    """Env steps per second on one core (physics + camera + reward), and its parts."""
    from common.car_calibration import CarCalibration, load_car
    from common.config import EnvConfig
    from sim.bench import bench_env

    try:
        car = load_car(car_calibration) if car_calibration else CarCalibration()
        result = bench_env(EnvConfig(track=track, camera=camera, car=car), steps=steps, repeats=repeats)
    except _user_errors() as exc:
        fail(str(exc))
    table = Table("figure", "value")
    table.add_row("env steps/s (median)", f"{result['steps_per_s']:.0f}")
    table.add_row("runs", ", ".join(f"{r:.0f}" for r in result["steps_per_s_runs"]))
    for part in ("physics", "camera", "task", "reward"):
        table.add_row(f"{part} µs/step", f"{result[f'{part}_us_per_step']:.1f}")
    console.print(table)
    write_json(result, json_out)


@bench_app.command("transport")
def bench_transport_cmd(
    track: Annotated[str, typer.Option(help="Track name or .npy path.")] = "reinvent_base",
    segments: Annotated[int, typer.Option(min=3, help="Segments to time.")] = 30,
    segment_steps: Annotated[int, typer.Option(min=1, help="Env steps per segment.")] = 32,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the result as JSON to F (- = stdout).")] = None,
) -> None:
    """Redis transport cost of a segment as a fraction of the time to simulate it (one core)."""
    from racer.bench_loop import bench_transport
    from sim.bench import pin_to_one_core

    pin_to_one_core()
    result = bench_transport(track, segment_steps, segments)
    table = Table("figure", "value")
    for k, v in result.items():
        table.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
    console.print(table)
    write_json(result, json_out)


@bench_app.command("loop")
def bench_loop_cmd(
    workers: Annotated[str, typer.Option(help="Comma-separated worker counts.")] = "1,2,4",
    duration: Annotated[str, typer.Option(help="Run time per worker count (90s, 5m).")] = "90s",
    track: Annotated[str, typer.Option(help="Track name or .npy path.")] = "reinvent_base",
    hyperparams: Annotated[Path | None, typer.Option("--hyperparams", help="DeepRacer hyperparameters.json.")] = None,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the result as JSON to F (- = stdout).")] = None,
) -> None:
    """End-to-end throughput (env steps/s consumed by the trainer), policy propagation and memory, per N workers."""
    from racer.bench_loop import bench_loop
    from racer.runconfig import parse_duration

    seconds = parse_duration(duration)
    results = [
        bench_loop(int(n), seconds, track, str(hyperparams) if hyperparams else None) for n in workers.split(",")
    ]
    table = Table(
        "workers", "steps/s consumed", "iterations", "propagation s (median/max)", "trainer MB", "worker MB", "redis MB"
    )
    for r in results:
        prop = (
            "-"
            if r["propagation_s_median"] is None
            else f"{r['propagation_s_median']:.2f}/{r['propagation_s_max']:.2f}"
        )
        table.add_row(
            str(r["workers"]),
            f"{r['consumed_steps_per_s']:.0f}",
            str(r["iterations"]),
            prop,
            f"{r['trainer_peak_rss_mb']:.0f}",
            ", ".join(f"{m:.0f}" for m in r["worker_peak_rss_mb"]),
            f"{r['redis_peak_memory_mb']:.0f}",
        )
    console.print(table)
    write_json(results, json_out)


@bench_app.command("train")
def bench_train_cmd(
    seeds: Annotated[str, typer.Option(help="Comma-separated seeds; medians are over them.")] = "0,1,2",
    time_limit: Annotated[str, typer.Option(help="Give up on a seed after this long, per system (10m).")] = "10m",
    track: Annotated[str, typer.Option(help="Track name or .npy path.")] = "reinvent_base",
    workers: Annotated[int, typer.Option(min=1, help="racer's workers and SB3's SubprocVecEnv envs.")] = 2,
    hyperparams: Annotated[Path | None, typer.Option("--hyperparams", help="DeepRacer hyperparameters.json.")] = None,
    eval_episodes: Annotated[int, typer.Option(min=1, help="Evaluation starts per direction.")] = 3,
    sb3: Annotated[bool, typer.Option("--sb3/--no-sb3", help="Also train Stable-Baselines3 PPO.")] = True,
    sb3_n_steps: Annotated[
        int | None, typer.Option(min=8, help="SB3's steps per env between updates (default: racer's batch / workers).")
    ] = None,
    precision: Annotated[str, typer.Option(help="racer's PPO update arithmetic: auto, fp32, bf16.")] = "auto",
    json_out: Annotated[str | None, typer.Option("--json", help="Write the result as JSON to F (- = stdout).")] = None,
) -> None:
    """Time and env steps from scratch to a robust lap (every evaluation lap completed), racer vs SB3 PPO."""
    from racer.bench_train import BenchTrainSettings, bench_train
    from racer.runconfig import build_run, parse_duration

    seed_list = _seed_list(seeds)
    try:
        from common.config import check_precision

        check_precision(precision)
        limit = parse_duration(time_limit)
        hp = str(hyperparams) if hyperparams else None
        build_run("bench-check", track=track, hyperparams=hp)  # bad files fail here, in one line
        if sb3:
            import stable_baselines3  # noqa: F401
    except ImportError:
        fail("--sb3 needs Stable-Baselines3: pip install 'racer[bench]' (or pass --no-sb3)")
    except _user_errors() as exc:
        fail(str(exc))
    settings = BenchTrainSettings(seed_list, limit, track, hp, workers, eval_episodes, sb3, sb3_n_steps, precision)
    result = bench_train(settings, console)
    table = Table("figure", "racer", "SB3 PPO")
    for label, key in (("time to lap s (median)", "time_to_lap_s"), ("env steps to lap", "env_steps_to_lap")):
        table.add_row(label, _fmt(result.get(key)), _fmt(result.get(f"sb3_{key}")))
    table.add_row("seeds lapped", str(result.get("lapped")), str(result.get("sb3_lapped", "-")))
    console.print(table)
    if "speedup_vs_sb3" in result:
        console.print(f"racer reaches a robust lap {result['speedup_vs_sb3']:.2f}× as fast as SB3 PPO")
    write_json(result, json_out)


def _seed_list(seeds: str) -> list[int]:
    """``--seeds 0,1,2`` as integers, or a one-line usage error."""
    try:
        return [int(s) for s in seeds.split(",")]
    except ValueError:
        fail(f"--seeds must be comma-separated integers (got {seeds!r})")


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


@bench_app.command("race")
def bench_race_cmd(
    car: Annotated[str, typer.Option(help="Car: a preset name (default) or a car.json.")] = "default",
    track: Annotated[str, typer.Option(help="Track name or .npy path (a loop).")] = "reinvent_base",
    minutes: Annotated[float, typer.Option(min=0.5, help="Training budget per seed, minutes.")] = 30.0,
    seeds: Annotated[str, typer.Option(help="Comma-separated seeds; medians are over them.")] = "0,1,2",
    workers: Annotated[int, typer.Option(min=1, help="Rollout workers.")] = 2,
    eval_starts: Annotated[int, typer.Option(min=1, help="Evaluation start points (track direction).")] = 10,
    png: Annotated[Path | None, typer.Option("--png", help="Learning curves with the limit drawn.")] = None,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the result as JSON to F (- = stdout).")] = None,
) -> None:
    """Learn to race from scratch (4 m/s actions, the racing reward example) and compare with racer limit."""
    from common.car_calibration import load_car
    from racer.bench_race import BenchRaceSettings, bench_race, plot_race
    from sim.track import load_track

    seed_list = _seed_list(seeds)
    try:
        load_car(car)
        load_track(track)
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    result = bench_race(BenchRaceSettings(seed_list, minutes, track, car, workers, eval_starts), console)
    if png:
        plot_race(result, png)
    ratio = result["ratio_to_limit"]
    console.print(
        f"median best robust lap {result['best_robust_lap_s']} s, limit {result['limit_s']:.2f} s"
        + (f" ({ratio:.2f} x)" if ratio else "")
        + f", collapses {result['collapses']} ({result['collapses_recovered']} recovered)",
        highlight=False,
    )
    write_json(result, json_out)


@bench_app.command("update")
def bench_update_cmd(
    threads: Annotated[int, typer.Option(min=1, help="PyTorch threads (racer train's trainer uses 2).")] = 2,
    batch: Annotated[int, typer.Option(min=1, help="Minibatch size (DeepRacer's batch_size).")] = 64,
    repeats: Annotated[int, typer.Option(min=1, help="Timed runs of 10 steps; the median is reported.")] = 5,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the result as JSON to F (- = stdout).")] = None,
) -> None:
    """Milliseconds per PPO minibatch step (forward, backward, Adam): fp32/bf16 trunk × Adam loop/fused."""
    from racer.bench_update import bench_update

    result = bench_update(threads, batch, repeats=repeats)
    table = Table("setting", "ms per minibatch (median)", "speed-up vs fp32 + Adam loop")
    for name, ms in result["ms_per_step"].items():
        table.add_row(name, f"{ms:.1f}", f"{result['speedup_vs_fp32_loop'][name]:.2f}×")
    console.print(table)
    write_json(result, json_out)


@bench_app.command("soak")
def bench_soak_cmd(
    duration: Annotated[str, typer.Option(help="Run time (90s, 10m, 2h).")] = "10m",
    workers: Annotated[int, typer.Option(min=1, help="Rollout worker processes.")] = 2,
    track: Annotated[str, typer.Option(help="Track name or .npy path.")] = "Straight_track",
    stream_maxlen: Annotated[int, typer.Option(min=4, help="Cap of the segment stream, entries.")] = 16,
    json_out: Annotated[str | None, typer.Option("--json", help="Write the result as JSON to F (- = stdout).")] = None,
) -> None:
    """A long racer train run sampling Redis memory, keys, the stream and each role's memory: is it bounded?"""
    from racer.bench_soak import bench_soak
    from racer.runconfig import parse_duration

    try:
        result = bench_soak(parse_duration(duration), workers, track, stream_maxlen)
    except _user_errors() as exc:
        fail(str(exc).splitlines()[0])
    summary = {k: v for k, v in result.items() if k != "samples"}
    table = Table("figure", "value")
    for k, v in summary.items():
        table.add_row(k, f"{v:.3f}" if isinstance(v, float) else str(v))
    console.print(table)
    write_json(result, json_out)


@app.command("drive")
def drive_cmd(
    track: Annotated[str, typer.Option(help="Track name or .npy path.")] = "reinvent_base",
    episodes: Annotated[int, typer.Option(min=1, help="Episodes to drive.")] = 5,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    reward_fn: Annotated[Path | None, typer.Option("--reward-fn", help="DeepRacer reward function file.")] = None,
    action_space: Annotated[Path | None, typer.Option("--action-space", help="DeepRacer model_metadata.json.")] = None,
    json_out: Annotated[
        str | None, typer.Option("--json", help="Write the episodes as JSON to F (- = stdout).")
    ] = None,
) -> None:
    """Drive a random policy for a few episodes and print what happened (a smoke test of the simulator)."""
    from common.config import EnvConfig
    from sim.drive import drive_random

    try:
        cfg = EnvConfig(
            track=track,
            reward_fn=str(reward_fn) if reward_fn else None,
            action_space=str(action_space) if action_space else None,
        )
        rows = drive_random(cfg, episodes, seed)
    except _user_errors() as exc:
        fail(str(exc))
    table = Table("episode", "steps", "status", "progress %", "return")
    for r in rows:
        table.add_row(str(r["episode"]), str(r["steps"]), r["status"], f"{r['progress']:.1f}", f"{r['return']:.2f}")
    console.print(table)
    write_json(rows, json_out)


def _given_value(exc: Exception) -> str:
    """`` (got 'two')`` for a bad option value: typer's conversion messages do not repeat what the user typed."""
    opts = getattr(getattr(exc, "param", None), "opts", None) or []
    argv = sys.argv[1:]
    for i, arg in enumerate(argv):
        for opt in opts:
            if arg == opt and i + 1 < len(argv):
                return f" (got {argv[i + 1]!r})"
            if arg.startswith(f"{opt}="):
                return f" (got {arg.split('=', 1)[1]!r})"
    return ""


def main() -> None:
    """Entry point for ``racer`` and ``python -m racer``: a bad option or argument is one line too, not a box."""
    try:
        code = app(standalone_mode=False)  # a typer.Exit comes back as its exit code here
    except typer.TyperException as exc:  # click's usage errors (typer vendors click)
        ctx = getattr(exc, "ctx", None)
        hint = f" (see {ctx.command_path} --help)" if ctx is not None else ""
        message = f"{exc.format_message()}{_given_value(exc)}{hint}"
        Console(stderr=True).print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
        sys.exit(getattr(exc, "exit_code", 2))
    except typer.Abort:
        Console(stderr=True).print("aborted")
        sys.exit(130)
    sys.exit(code if isinstance(code, int) else 0)
