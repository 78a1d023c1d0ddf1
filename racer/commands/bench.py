"""``racer bench``: the benchmarks behind the figures in the README and docs/ (the package ``racer.bench``), each
printing its tables and lines and optionally writing its JSON. Each command here parses its options and calls its
module's ``command``; what a benchmark checks, runs and shows lives in that module."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from common.defaults import DEFAULT_TRACK, STRAIGHT_TRACK
from racer.bench import Report
from racer.commands.options import Car, Hyperparams, JsonOut, Track, console, int_list, print_table, write_json

app = typer.Typer(no_args_is_help=True, help="Benchmarks.")


@app.command("env")
def env(
    track: Track = DEFAULT_TRACK,
    steps: Annotated[int, typer.Option(min=100, help="Env steps per timed run.")] = 3000,
    repeats: Annotated[int, typer.Option(min=1, help="Timed runs; the median is reported.")] = 5,
    camera: Annotated[str, typer.Option(help="Camera path: ground or mujoco.")] = "ground",
    car_calibration: Car = None,
    sensor: Annotated[
        str | None,
        typer.Option(help="model_metadata sensor list, comma-separated (STEREO_CAMERAS,LIDAR); default: the camera."),
    ] = None,
    race_type: Annotated[
        str | None, typer.Option(help="TIME_TRIAL, OBJECT_AVOIDANCE (6 boxes) or HEAD_TO_BOT (3 bot cars).")
    ] = None,
    obstacles: Annotated[
        int | None, typer.Option(min=0, help="Boxes (OBJECT_AVOIDANCE) or bot cars (HEAD_TO_BOT) instead of 6 / 3.")
    ] = None,
    json_out: JsonOut = None,
) -> None:
    """Env steps per second on one core (physics + camera + reward), and its parts."""
    from racer.bench import env as bench

    _show(
        bench.command(
            track,
            steps,
            repeats,
            camera=camera,
            car_calibration=car_calibration,
            sensor=sensor,
            race_type=race_type,
            obstacles=obstacles,
        ),
        json_out,
    )


@app.command("transport")
def transport(
    track: Track = DEFAULT_TRACK,
    segments: Annotated[int, typer.Option(min=3, help="Segments to time.")] = 30,
    segment_steps: Annotated[int, typer.Option(min=1, help="Env steps per segment.")] = 32,
    json_out: JsonOut = None,
) -> None:
    """Redis transport cost of a segment as a fraction of the time to simulate it (one core)."""
    from racer.bench import loop as bench

    _show(bench.transport_command(track, segments, segment_steps), json_out)


@app.command("loop")
def loop(
    workers: Annotated[str, typer.Option(help="Comma-separated worker counts.")] = "1,2,4",
    duration: Annotated[str, typer.Option(help="Run time per worker count (90s, 5m).")] = "90s",
    track: Track = DEFAULT_TRACK,
    hyperparams: Hyperparams = None,
    json_out: JsonOut = None,
) -> None:
    """End-to-end throughput (env steps/s consumed by the trainer), policy propagation and memory, per N workers."""
    from common.deadline import parse_duration
    from racer.bench import loop as bench

    seconds = parse_duration(duration, "--duration")
    counts = int_list(workers, "--workers")
    _show(bench.command(counts, seconds, track, str(hyperparams) if hyperparams else None), json_out)


@app.command("train")
def train(
    seeds: Annotated[str, typer.Option(help="Comma-separated seeds; medians are over them.")] = "0,1,2",
    time_limit: Annotated[str, typer.Option(help="Give up on a seed after this long, per system (10m).")] = "10m",
    track: Track = DEFAULT_TRACK,
    workers: Annotated[int, typer.Option(min=1, help="racer's workers and SB3's SubprocVecEnv envs.")] = 2,
    hyperparams: Hyperparams = None,
    eval_episodes: Annotated[int, typer.Option(min=1, help="Evaluation starts per direction.")] = 3,
    sb3: Annotated[bool, typer.Option("--sb3/--no-sb3", help="Also train Stable-Baselines3 PPO.")] = True,
    sb3_n_steps: Annotated[
        int | None, typer.Option(min=8, help="SB3's steps per env between updates (default: racer's batch / workers).")
    ] = None,
    precision: Annotated[str, typer.Option(help="racer's PPO update arithmetic: auto, fp32, bf16.")] = "auto",
    teacher: Annotated[
        bool, typer.Option("--teacher", help="Each seed also with racer train --teacher (the JSON's teacher block).")
    ] = False,
    json_out: JsonOut = None,
) -> None:
    """Time and env steps from scratch to a robust lap (every evaluation lap completed), racer vs SB3 PPO."""
    from common.deadline import parse_duration
    from racer.bench import train as bench

    seed_numbers, limit = int_list(seeds, "--seeds"), parse_duration(time_limit, "--time-limit")
    hp = str(hyperparams) if hyperparams else None
    settings = bench.BenchTrainSettings(
        seeds=seed_numbers,
        time_limit_s=limit,
        track=track,
        hyperparams=hp,
        workers=workers,
        eval_episodes=eval_episodes,
        sb3=sb3,
        sb3_n_steps=sb3_n_steps,
        precision=precision,
        teacher=teacher,
    )
    _show(bench.command(settings, console), json_out)


@app.command("race")
def race(
    car: Annotated[str, typer.Option(help="Car: a preset name (default) or a car.json.")] = "default",
    track: Annotated[str, typer.Option(help="Track name or .npy path (a loop).")] = DEFAULT_TRACK,
    minutes: Annotated[float, typer.Option(min=0.5, help="Training budget per seed, minutes.")] = 30.0,
    seeds: Annotated[str, typer.Option(help="Comma-separated seeds; medians are over them.")] = "0,1,2",
    workers: Annotated[int, typer.Option(min=1, help="Rollout workers.")] = 2,
    eval_starts: Annotated[int, typer.Option(min=1, help="Evaluation start points (track direction).")] = 10,
    hyperparams: Hyperparams = None,
    reward_constants: Annotated[
        Path | None,
        typer.Option(help='JSON of the racing example\'s constants over those set to the car: {"MARGIN": 0.25}.'),
    ] = None,
    randomization: Annotated[
        Path | None,
        typer.Option(help='JSON of domain randomization the workers train with: {"action_noise": 0.1}.'),
    ] = None,
    action_space: Annotated[
        Path | None,
        typer.Option(
            "--action-space",
            help="model_metadata.json with a discrete or continuous action space (default: 4 m/s, 15 actions).",
        ),
    ] = None,
    png: Annotated[Path | None, typer.Option("--png", help="Learning curves with the limit drawn.")] = None,
    teacher: Annotated[
        bool,
        typer.Option(
            "--teacher", help="Each seed also with a privileged teacher (racer train --teacher), same budget."
        ),
    ] = False,
    json_out: JsonOut = None,
) -> None:
    """Learn to race from scratch (4 m/s actions, the racing reward example) and compare with racer limit."""
    from racer.bench import race as bench

    files = bench.RaceFiles(hyperparams, reward_constants, randomization, action_space)
    seed_numbers = int_list(seeds, "--seeds")
    _show(
        bench.command(
            seed_numbers,
            minutes,
            track,
            car=car,
            workers=workers,
            eval_starts=eval_starts,
            files=files,
            png=png,
            progress=console,
            teacher=teacher,
        ),
        json_out,
    )


@app.command("oa")
def oa(
    race_type: Annotated[
        str, typer.Option(help="OBJECT_AVOIDANCE (3 random boxes) or HEAD_TO_BOT (2 bots at 0.5 m/s).")
    ] = "OBJECT_AVOIDANCE",
    minutes: Annotated[float, typer.Option(min=0.5, help="Training budget per seed, minutes.")] = 60.0,
    seeds: Annotated[str, typer.Option(help="Comma-separated seeds; medians are over them.")] = "0",
    track: Annotated[str, typer.Option(help="Track name or .npy path (a loop).")] = DEFAULT_TRACK,
    workers: Annotated[int, typer.Option(min=1, help="Rollout workers.")] = 2,
    eval_trials: Annotated[
        int, typer.Option(min=1, help="Evaluation trials per checkpoint (start points, each its own placement).")
    ] = 10,
    png: Annotated[Path | None, typer.Option("--png", help="Completion and crash rate over time.")] = None,
    json_out: JsonOut = None,
) -> None:
    """Learn object avoidance (or head-to-bot) from scratch with stereo cameras: time to robust, crash rate."""
    from racer.bench import oa as bench

    seed_numbers = int_list(seeds, "--seeds")
    _show(
        bench.command(
            race_type,
            seed_numbers,
            minutes,
            track=track,
            workers=workers,
            eval_trials=eval_trials,
            png=png,
            progress=console,
        ),
        json_out,
    )


@app.command("update")
def update(
    threads: Annotated[int, typer.Option(min=1, help="PyTorch threads (racer train's trainer uses 2).")] = 2,
    batch: Annotated[int, typer.Option(min=1, help="Minibatch size (DeepRacer's batch_size).")] = 64,
    repeats: Annotated[int, typer.Option(min=1, help="Timed runs of 10 steps; the median is reported.")] = 5,
    breakdown: Annotated[
        bool, typer.Option(help="Also profile auto's setting: its GEMM operators' time against the rest, top ops.")
    ] = False,
    json_out: JsonOut = None,
) -> None:
    """Milliseconds per PPO minibatch step (forward, backward, Adam): fp32/bf16 trunk × Adam loop/fused, and the share
    of the machine's GEMM peak (same arithmetic, same threads, timed in the same run) each gets."""
    from racer.bench import update as bench

    _show(bench.command(threads, batch, repeats, breakdown), json_out)


@app.command("worker")
def worker(
    envs_per_worker: Annotated[
        str, typer.Option("--envs-per-worker", help="Comma-separated K: envs per worker to time, interleaved.")
    ] = "1,4,8",
    seconds: Annotated[float, typer.Option(min=0.1, help="Length of one timed run, seconds.")] = 5.0,
    repeats: Annotated[int, typer.Option(min=1, help="Timed runs per K; the median is reported.")] = 5,
    track: Track = DEFAULT_TRACK,
    acting: Annotated[str, typer.Option(help="What acts: onnx (the worker's ONNX Runtime copy) or torch.")] = "onnx",
    json_out: JsonOut = None,
) -> None:
    """A rollout worker's env steps/s on one core with K envs per worker (no Redis), and where a step's time goes."""
    from racer.bench import worker as bench

    _show(bench.command(int_list(envs_per_worker, "--envs-per-worker"), seconds, repeats, track, acting), json_out)


@app.command("soak")
def soak(
    duration: Annotated[str, typer.Option(help="Run time (90s, 10m, 2h).")] = "10m",
    workers: Annotated[int, typer.Option(min=1, help="Rollout worker processes.")] = 2,
    track: Track = STRAIGHT_TRACK,
    stream_maxlen: Annotated[int, typer.Option(min=4, help="Cap of the segment stream, entries.")] = 16,
    json_out: JsonOut = None,
) -> None:
    """A long racer train run sampling Redis memory, keys, the stream and each role's memory: is it bounded?"""
    from common.deadline import parse_duration
    from racer.bench import soak as bench

    _show(bench.command(parse_duration(duration, "--duration"), workers, track, stream_maxlen), json_out)


@app.command("scale")
def scale(
    levels: Annotated[
        str, typer.Option(help="Comma-separated counts of synthetic workers, one level each.")
    ] = "1,4,16,64",
    seconds: Annotated[
        float, typer.Option(min=1, help="Measured seconds per level (then until two updates have finished in it).")
    ] = 20.0,
    rate: Annotated[
        float | None, typer.Option(help="Segments/s per synthetic worker (default: one real worker's, measured).")
    ] = None,
    max_policy_lag: Annotated[int, typer.Option(min=1, help="The trainer's max_policy_lag.")] = 1,
    processes: Annotated[
        int | None, typer.Option(min=1, help="Pusher processes per level (default: one per synthetic worker).")
    ] = None,
    track: Track = DEFAULT_TRACK,
    hyperparams: Hyperparams = None,
    json_out: JsonOut = None,
) -> None:
    """Trainer intake, Redis memory and CPU, staleness and lost segments with 1…64 workers' load (real segments)."""
    from racer.bench import scale as bench

    counts = int_list(levels, "--levels")
    settings = bench.ScaleSettings(
        track=track, hyperparams=str(hyperparams) if hyperparams else None, max_policy_lag=max_policy_lag
    )
    _show(bench.command(counts, seconds, rate, settings, processes), json_out)


@app.command("wire")
def wire(
    segments: Annotated[int, typer.Option(min=1, help="Segments collected per run.")] = 8,
    steps: Annotated[int, typer.Option(min=1, help="Env steps per segment.")] = 32,
    repeats: Annotated[int, typer.Option(min=1, help="Timed repeats (medians).")] = 5,
    json_out: JsonOut = None,
) -> None:
    """Bytes per env step a worker sends (schema 1 against today's segments) and per policy version it downloads,
    with the CPU cost of encoding and decoding a segment."""
    from racer.bench import wire as bench

    _show(bench.command(segments, steps, repeats), json_out)


@app.command("view")
def view(
    seconds: Annotated[float, typer.Option(min=0.5, help="Length of each timed block, s.")] = 5.0,
    repeats: Annotated[int, typer.Option(min=1, help="Blocks of each condition, interleaved.")] = 8,
    track: Track = DEFAULT_TRACK,
    json_out: JsonOut = None,
) -> None:
    """A rollout worker's step time with no racer view publisher, nobody watching and one page watching."""
    from racer.bench import view as bench

    _show(bench.command(seconds, repeats, track), json_out)


@app.command("calibrate")
def calibrate(
    logs: Annotated[
        list[Path] | None, typer.Argument(help="Logs to calibrate (default: a synthetic 45-episode log).")
    ] = None,
    repeats: Annotated[int, typer.Option(min=1, help="Calibrations per log; the median time is reported.")] = 3,
    threads: Annotated[int, typer.Option(min=1, help="Replay threads; 1 pins the process to one core.")] = 1,
    max_windows: Annotated[int | None, typer.Option(min=20, help="Replay windows to fit on; default 120.")] = None,
    json_out: JsonOut = None,
) -> None:
    """Seconds racer calibrate takes for one log, and its parts."""
    from racer.bench import calibrate as bench

    _show(bench.command(logs or [], repeats=repeats, threads=threads, max_windows=max_windows), json_out)


@app.command("transfer")
def transfer(
    rows: Annotated[
        str | None, typer.Option(help="Comma-separated rows of Table II (default: all 17; see docs/transfer.md).")
    ] = None,
    minutes: Annotated[float, typer.Option(min=0.5, help="Training minutes per row.")] = 20.0,
    out: Annotated[Path, typer.Option(help="Folder of the finished rows: a rerun resumes from it.")] = Path("transfer"),
    tracks: Annotated[
        str | None, typer.Option(help="A=TRACK,B=TRACK,C=TRACK,D=TRACK over the defaults (A is driven, never trained).")
    ] = None,
    car: Annotated[
        str | None, typer.Option(help="The 'real' car: a preset or a car.json (default: deepracer-gazebo).")
    ] = None,
    fresh: Annotated[bool, typer.Option("--fresh", help="Train every row again, ignoring finished ones.")] = False,
    png: Annotated[Path | None, typer.Option("--png", help="Write the figure: racer's totals and the paper's.")] = None,
    json_out: JsonOut = None,
) -> None:
    """The DeepRacer paper's Table II in simulation: each row trained, its checkpoint chosen by robust evaluation,
    driven 6 times in each of the five held-out conditions on a track it never saw, beside the paper's totals."""
    from racer.bench import transfer as bench

    names = [n.strip() for n in rows.split(",") if n.strip()] if rows else None
    _show(bench.command(names, minutes, out, tracks=tracks, car=car, fresh=fresh, png=png), json_out)


def _show(report: Report, json_out: str | None) -> None:
    """Print a benchmark's tables and lines, in order, and write its result as JSON if asked."""
    for item in report.shown:
        if isinstance(item, Table):
            print_table(item)
        else:
            console.print(item, highlight=False)
    write_json(report.result, json_out)
