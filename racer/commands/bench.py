"""``racer bench``: the benchmarks behind the figures in the README and docs/, each printing a table and
optionally writing its JSON."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from common.defaults import DEFAULT_TRACK, STRAIGHT_TRACK
from common.errors import OptionError
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
    from common.car_calibration import CarCalibration, load_car
    from common.config import EnvConfig
    from common.race import RaceType
    from sim.bench import bench_env, race_config

    sensors = [s.strip() for s in sensor.split(",") if s.strip()] if sensor is not None else None
    if sensors is not None:
        from common.sensors import sensor_problem

        problem = sensor_problem(sensors) if sensors else "no sensor given"
        if problem:
            raise OptionError(f"--sensor {sensor!r}: {problem}")
    race = None
    if race_type is not None:
        names = [t.value for t in RaceType]
        if race_type.upper() not in names:
            raise OptionError(f"--race-type {race_type!r} is not one of {', '.join(names)}")
        if obstacles and race_type.upper() == RaceType.TIME_TRIAL:
            raise OptionError("--obstacles needs --race-type OBJECT_AVOIDANCE or HEAD_TO_BOT")
        race = race_config(race_type, obstacles)
    elif obstacles is not None:
        raise OptionError("--obstacles needs --race-type OBJECT_AVOIDANCE or HEAD_TO_BOT")
    car = load_car(car_calibration) if car_calibration else CarCalibration()
    config = EnvConfig(track=track, camera=camera, car=car)
    result = bench_env(config, steps=steps, repeats=repeats, sensors=sensors, race=race)
    table = Table("figure", "value")
    table.add_row("env steps/s (median)", f"{result['steps_per_s']:.0f}")
    table.add_row("runs", ", ".join(f"{r:.0f}" for r in result["steps_per_s_runs"]))
    extended = "sensor" in result
    if extended:
        table.add_row("sensors", ", ".join(result["sensor"]))
        table.add_row("race", f"{result['race_type']}, {result['objects']} objects")
    parts = ("physics", "camera", "lidar", "objects", "task", "reward") if extended else _ENV_PARTS
    for part in parts:
        value = result[f"{part}_us_per_step"]
        table.add_row(f"{part} µs/step", "-" if value is None else f"{value:.1f}")
    print_table(table)
    write_json(result, json_out)


_ENV_PARTS = ("physics", "camera", "task", "reward")


@app.command("transport")
def transport(
    track: Track = DEFAULT_TRACK,
    segments: Annotated[int, typer.Option(min=3, help="Segments to time.")] = 30,
    segment_steps: Annotated[int, typer.Option(min=1, help="Env steps per segment.")] = 32,
    json_out: JsonOut = None,
) -> None:
    """Redis transport cost of a segment as a fraction of the time to simulate it (one core)."""
    from racer.bench_loop import bench_transport
    from sim.bench import pin_to_one_core

    pin_to_one_core()
    _print_figures(bench_transport(track, segment_steps, segments), json_out, "{:.4g}")


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
    from racer.bench_loop import bench_loop

    seconds = parse_duration(duration)
    counts = int_list(workers, "--workers")
    hp = str(hyperparams) if hyperparams else None
    results = [bench_loop(n, seconds, track, hp) for n in counts]
    table = Table(
        "workers", "steps/s consumed", "iterations", "propagation s (median/max)", "trainer MB", "worker MB", "redis MB"
    )
    for r in results:
        median, worst = r["propagation_s_median"], r["propagation_s_max"]
        table.add_row(
            str(r["workers"]),
            f"{r['consumed_steps_per_s']:.0f}",
            str(r["iterations"]),
            "-" if median is None else f"{median:.2f}/{worst:.2f}",
            f"{r['trainer_peak_rss_mb']:.0f}",
            ", ".join(f"{m:.0f}" for m in r["worker_peak_rss_mb"]),
            f"{r['redis_peak_memory_mb']:.0f}",
        )
    print_table(table)
    write_json(results, json_out)


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
    json_out: JsonOut = None,
) -> None:
    """Time and env steps from scratch to a robust lap (every evaluation lap completed), racer vs SB3 PPO."""
    from common.config import check_precision
    from common.deadline import parse_duration
    from racer.bench_train import BenchTrainSettings, bench_train
    from racer.runconfig import build_run

    seed_numbers = int_list(seeds, "--seeds")
    check_precision(precision)
    limit = parse_duration(time_limit)
    hp = str(hyperparams) if hyperparams else None
    build_run("bench-check", track=track, hyperparams=hp)  # bad files fail here, in one line
    if sb3:
        try:
            import stable_baselines3  # noqa: F401
        except ImportError:
            raise OptionError("--sb3 needs Stable-Baselines3: pip install 'racer[bench]' (or pass --no-sb3)") from None
    settings = BenchTrainSettings(seed_numbers, limit, track, hp, workers, eval_episodes, sb3, sb3_n_steps, precision)
    result = bench_train(settings, console)
    table = Table("figure", "racer", "SB3 PPO")
    for label, key in (("time to lap s (median)", "time_to_lap_s"), ("env steps to lap", "env_steps_to_lap")):
        table.add_row(label, _whole(result.get(key)), _whole(result.get(f"sb3_{key}")))
    table.add_row("seeds lapped", str(result.get("lapped")), str(result.get("sb3_lapped", "-")))
    print_table(table)
    if "speedup_vs_sb3" in result:
        console.print(f"racer reaches a robust lap {result['speedup_vs_sb3']:.2f}× as fast as SB3 PPO")
    write_json(result, json_out)


def _whole(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


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
    json_out: JsonOut = None,
) -> None:
    """Learn to race from scratch (4 m/s actions, the racing reward example) and compare with racer limit."""
    from common.car_calibration import load_car
    from common.hyperparams import HyperparametersError, load_hyperparameters
    from common.jsonfile import read_json_object
    from racer.bench_race import (
        BenchRaceSettings,
        bench_race,
        load_race_actions,
        load_reward_constants,
        plot_race,
        seconds_text,
    )
    from racer.runconfig import load_randomization
    from sim.track import load_track

    seed_numbers = int_list(seeds, "--seeds")
    load_car(car)  # a bad car, track or hyperparameters file fails now, not after the first seed's training
    load_track(track)
    overrides = {}
    if hyperparams:
        load_hyperparameters(hyperparams)
        overrides = read_json_object(hyperparams, "hyperparameters file", HyperparametersError)
    constants = load_reward_constants(reward_constants) if reward_constants else {}
    if randomization:
        load_randomization(randomization)
    actions = load_race_actions(action_space) if action_space else None
    if overrides.get("greedy_action", "mean") != "mean" and not isinstance(actions, dict):
        # A discrete space acts by its argmax: refused now, naming the user's file, not after the limit has run.
        raise HyperparametersError(
            f"{hyperparams}: greedy_action {overrides['greedy_action']!r} applies to a continuous action space; "
            "the bench's is discrete"
        )
    settings = BenchRaceSettings(
        seed_numbers,
        minutes,
        track,
        car,
        workers,
        eval_starts,
        overrides,
        constants,
        str(randomization) if randomization else None,
        actions,
    )
    result = bench_race(settings, console)
    if png:
        plot_race(result, png)
    ratio = result["ratio_to_limit"]
    console.print(
        f"median best robust lap {seconds_text(result['best_robust_lap_s'])}, limit {result['limit_s']:.2f} s"
        + (f" ({ratio:.2f} x)" if ratio else "")
        + f", collapses {result['collapses']} ({result['collapses_recovered']} recovered)"
        + f", late robust lap {seconds_text(result['late_robust_lap_s'])}",
        highlight=False,
    )
    write_json(result, json_out)


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
    from racer.bench_oa import BenchOASettings, bench_oa, oa_race, plot_oa
    from sim.track import load_track

    seed_numbers = int_list(seeds, "--seeds")
    try:
        race = oa_race(race_type)
    except ValueError:
        raise OptionError(f"--race-type {race_type!r}: racer bench oa races OBJECT_AVOIDANCE or HEAD_TO_BOT") from None
    load_track(track)  # a bad track fails now, not after the first seed's training
    settings = BenchOASettings(seed_numbers, minutes, race.race_type.value, track, workers, eval_trials)
    result = bench_oa(settings, console)
    if png:
        plot_oa(result, png)
    crash = result["final_crash_rate"]
    console.print(
        f"{result['race_type']}: median time to robust {result['time_to_robust_s']} s "
        f"({result['robust_seeds']} of {len(result['seeds'])} seeds robust), final completion "
        f"{result['final_completion']:.2f}, final crash rate {'-' if crash is None else f'{crash:.2f}'}",
        highlight=False,
    )
    write_json(result, json_out)


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
    from racer.bench_update import bench_update

    result = bench_update(threads, batch, repeats=repeats, with_breakdown=breakdown)
    table = Table("setting", "ms per minibatch (median)", "speed-up vs fp32 + Adam loop", "GFLOP/s", "of GEMM peak")
    for name, ms in result["ms_per_step"].items():
        fraction = result["fraction_of_peak_by_setting"][name]
        share = "- (bf16 emulated)" if fraction is None else f"{fraction:.2f}"
        table.add_row(
            name, f"{ms:.1f}", f"{result['speedup_vs_fp32_loop'][name]:.2f}×", f"{result['gflops'][name]:.0f}", share
        )
    print_table(table)
    peaks = ", ".join(f"{p} {g:.0f}" for p, g in result["peak_gflops"].items() if g is not None)
    console.print(
        f"{result['update_gflop']:.2f} GFLOP a minibatch step; GEMM peak ({result['gemm_size']}², "
        f"{threads} threads): {peaks} GFLOP/s",
        highlight=False,
    )
    console.print(
        f"racer train --precision auto trains in {result['auto']} on this machine, at "
        f"{result['fraction_of_peak']:.2f} of its GEMM peak",
        highlight=False,
    )
    if breakdown:
        parts = result["breakdown"]
        ops = Table("operator (profiled)", "input shapes", "ms a step")
        for kind in ("gemm_ops", "other_ops"):
            for op in parts[kind][:8]:
                ops.add_row(op["op"], " ".join(str(tuple(s)) for s in op["shapes"]), f"{op['ms']:.2f}")
            ops.add_section()
        console.print(ops)
        console.print(
            f"{parts['precision']} step {parts['step_ms']:.1f} ms: GEMM operators {parts['gemm_ms']:.1f} ms "
            f"at {parts['gemm_fraction_of_peak']:.2f} of the GEMM peak, the rest {parts['other_ms']:.1f} ms "
            "(the profiler slows large copies: the other operators' figures are for their order only); with every "
            f"GEMM at the peak the step would get {parts['fraction_if_gemms_at_peak']:.2f} of it",
            highlight=False,
        )
    write_json(result, json_out)


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
    from common.config import MAX_ENVS_PER_WORKER
    from racer.bench_worker import bench_worker

    ks = int_list(envs_per_worker, "--envs-per-worker")
    bad = [k for k in ks if not 1 <= k <= MAX_ENVS_PER_WORKER]
    if bad or len(set(ks)) != len(ks):
        raise OptionError(
            f"--envs-per-worker takes distinct integers from 1 to {MAX_ENVS_PER_WORKER} (got {envs_per_worker!r})"
        )
    if acting not in ("onnx", "torch"):
        raise OptionError(f"--acting must be onnx or torch (got {acting!r})")
    result = bench_worker(ks, seconds, repeats, track, acting)
    table = Table("K", "env steps/s (median)", f"vs K={ks[0]}", "act µs/step", "env µs/step", "bookkeeping µs/step")
    for k, r in result["per_k"].items():
        us = r["us_per_step"]
        table.add_row(
            k,
            f"{r['steps_per_s']:.0f}",
            f"{r['speedup_vs_first']:.2f}×",
            f"{us['act']:.0f}",
            f"{us['env']:.0f}",
            f"{us['bookkeeping']:.0f}",
        )
    console.print(table)
    act = result["act_ms"]
    console.print(
        "forward pass + sampling, ms per batch (torch / onnxruntime): "
        + ", ".join(f"B={b} {act['torch'][b]:.2f} / {act['onnxruntime'][b]:.2f}" for b in act["torch"]),
        highlight=False,
    )
    console.print(f"acting with {result['acting']} on {result['machine']['cpu']}", highlight=False)
    write_json(result, json_out)


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
    from racer.bench_soak import bench_soak

    result = bench_soak(parse_duration(duration), workers, track, stream_maxlen)
    summary = {k: v for k, v in result.items() if k != "samples"}
    _print_figures(summary, None, "{:.3f}")
    write_json(result, json_out)


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
    from racer.bench_scale import ScaleSettings, bench_scale, scale_summary, scale_table

    counts = int_list(levels, "--levels")
    hp = str(hyperparams) if hyperparams else None
    settings = ScaleSettings(track=track, hyperparams=hp, max_policy_lag=max_policy_lag)
    result = bench_scale(counts, seconds, rate, settings, processes)
    print_table(scale_table(result))
    console.print(scale_summary(result), highlight=False)
    write_json(result, json_out)


@app.command("wire")
def wire(
    segments: Annotated[int, typer.Option(min=1, help="Segments collected per run.")] = 8,
    steps: Annotated[int, typer.Option(min=1, help="Env steps per segment.")] = 32,
    repeats: Annotated[int, typer.Option(min=1, help="Timed repeats (medians).")] = 5,
    json_out: JsonOut = None,
) -> None:
    """Bytes per env step a worker sends (schema 1 against today's segments) and per policy version it downloads,
    with the CPU cost of encoding and decoding a segment."""
    from racer.bench_wire import bench_wire

    result = bench_wire(segments, steps, repeats)
    table = Table("run", "bytes/step before", "bytes/step", "ratio", "encode µs/step", "decode µs/step")
    for name, f in result["segments"].items():
        table.add_row(
            name,
            f"{f['bytes_per_step_before']:,.0f}",
            f"{f['bytes_per_step']:,.0f}",
            f"{f['ratio']:.1f}",
            f"{f['encode_us_per_step']:.0f}",
            f"{f['decode_us_per_step']:.0f}",
        )
    print_table(table)
    policy = result["policy"]
    console.print(
        f"policy version: checkpoint {policy['checkpoint_bytes']:,} bytes, acting copy {policy['acting_bytes']:,} "
        f"bytes ({policy['ratio']:.2f}x smaller); machine {result['machine']}",
        highlight=False,
    )
    write_json(result, json_out)


@app.command("view")
def view(
    seconds: Annotated[float, typer.Option(min=0.5, help="Length of each timed block, s.")] = 5.0,
    repeats: Annotated[int, typer.Option(min=1, help="Blocks of each condition, interleaved.")] = 8,
    track: Track = DEFAULT_TRACK,
    json_out: JsonOut = None,
) -> None:
    """A rollout worker's step time with no racer view publisher, nobody watching and one page watching."""
    from racer.bench_view import bench_view, report_lines

    result = bench_view(seconds, repeats, track)
    for line in report_lines(result):
        console.print(line, highlight=False)
    write_json(result, json_out)


def _print_figures(figures: dict, json_out: str | None, float_format: str) -> None:
    """A two-column table of ``figures`` (floats in ``float_format``), and the JSON if asked."""
    table = Table("figure", "value")
    for k, v in figures.items():
        table.add_row(k, float_format.format(v) if isinstance(v, float) else str(v))
    print_table(table)
    write_json(figures, json_out)
