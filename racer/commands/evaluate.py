"""``racer eval`` (a checkpoint driven from several starts) and ``racer plot`` (a run's PNGs)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from common.defaults import CHECK_EPISODES, EVAL_ACTION_NOISE
from racer.commands.options import (
    Endpoint,
    JsonOut,
    ReadStore,
    console,
    device_option,
    print_table,
    write_json,
)
from racer.console import new_console


def evaluate(
    run_id: Annotated[str, typer.Option("--run-id", help="Run id.")],
    store: ReadStore = ".",
    s3_endpoint: Endpoint = None,
    checkpoint: Annotated[str, typer.Option(help="best, latest or a version number.")] = "best",
    track: Annotated[list[str] | None, typer.Option(help="Track(s) to drive (default: the run's).")] = None,
    episodes: Annotated[int, typer.Option(min=1, help="Start positions per direction and track.")] = CHECK_EPISODES,
    both_directions: Annotated[bool, typer.Option("--both-directions/--one-direction")] = True,
    action_noise: Annotated[float, typer.Option(min=0, max=1, help="Action noise fraction.")] = EVAL_ACTION_NOISE,
    json_out: JsonOut = None,
    sim_trace: Annotated[Path | None, typer.Option("--sim-trace", help="Write a DeepRacer sim-trace CSV.")] = None,
    video: Annotated[
        Path | None, typer.Option("--video", help="Write an MP4 of the trials, one after another (see --video-trial).")
    ] = None,
    video_trial: Annotated[
        int | None, typer.Option("--video-trial", min=1, help="Only this trial in the video (its # in the table).")
    ] = None,
    car_calibration: Annotated[
        str | None,
        typer.Option("--car", "--car-calibration", help="Drive this car (a preset or a car.json), not the run's."),
    ] = None,
    resets: Annotated[
        bool,
        typer.Option(
            "--resets/--no-resets",
            help="DeepRacer's evaluation: put the car back after an off-track or crash with the run's penalties "
            "(its race's number_of_resets); --no-resets ends a trial there, as racer's robust evaluation does.",
        ),
    ] = True,
    # A plain str, checked in racer.evaluate: importing the choices' owner (common.hyperparams, pydantic) here would
    # add 0.1 s to the start of every racer process, workers included.
    greedy_action: Annotated[
        str | None,
        typer.Option(
            help="How a continuous policy acts: mean (its Gaussian's mean, DeepRacer's) or expected (the mean of its "
            "clipped action). Default: the run's greedy_action."
        ),
    ] = None,
    device: Annotated[str, device_option()] = "auto",
    condition: Annotated[
        list[str] | None,
        typer.Option(
            "--condition",
            help="Also drive the trials in held-out conditions the model never trained in: speed-0.5, speed-1.0, "
            "sunlight, no-barriers, tape, camera-up, camera-down, blur, noise, latency, gazebo-car, or a JSON file "
            "(docs/transfer.md). A,B (or the option repeated) evaluates each; A+B combines them into one world.",
        ),
    ] = None,
    quiet: Annotated[
        bool,
        typer.Option(
            "--quiet", "-q", help="No progress on stderr: the table and summary, or with --json - the JSON alone."
        ),
    ] = False,
) -> None:
    """Evaluate a checkpoint of a run from a store: a table per trial, and the JSON summary. Progress goes to stderr
    as it is made (standard output stays the table, or the JSON of ``--json -``)."""
    from racer.evaluate import run_eval, video_lines

    record = run_eval(
        run_id,
        store,
        s3_endpoint,
        checkpoint=checkpoint,
        tracks=track or [],
        episodes=episodes,
        both_directions=both_directions,
        action_noise=action_noise,
        sim_trace=sim_trace,
        video=video,
        car_calibration=car_calibration,
        resets=resets,
        greedy_action=greedy_action,
        device=device,
        video_trial=video_trial,
        conditions=condition,
        on_progress=None if quiet else _say,
    )
    if json_out != "-":
        print_table(_trials_table(record["trials"]))
        console.print(_summary_line(record))
        if "conditions" in record:
            print_table(_conditions_table(record))
    elif not quiet:  # said with --json - too: on stderr, so that standard output stays JSON
        _say(_summary_line(record))
    if "video" in record and (json_out != "-" or not quiet):
        for line in video_lines(record["video"]):
            (console if json_out != "-" else _stderr).print(line, highlight=False, soft_wrap=True)
    summary = {k: v for k, v in record.items() if k != "trials"}  # each condition's trials have no trajectory
    summary["trials"] = [{k: v for k, v in t.items() if k != "trajectory"} for t in record["trials"]]
    write_json(summary, json_out)


_stderr = new_console(stderr=True)


def _say(line: str) -> None:
    """A line of progress on stderr, as it is made: an evaluation takes minutes, and ``--json -`` owns stdout."""
    _stderr.print(line, highlight=False, soft_wrap=True, markup=False)


def _summary_line(record: dict) -> str:
    """The evaluation's figures in one line: completion, mean progress, best lap, score."""
    best = "-" if record["best_lap_s"] is None else f"{record['best_lap_s']:.2f} s"
    return (
        f"version {record['version']}: completion {100 * record['completion_rate']:.0f}%, "
        f"mean progress {record['mean_progress']:.1f}%, best lap {best}, score {record['score']:.1f}"
    )


def _conditions_table(record: dict) -> Table:
    """Laps out of the trials per held-out condition, beside the run's own world."""
    table = Table("condition", "laps", "progress %", "best lap s", "mean lap s", "off track", "car")
    rows = [{"name": "as trained", "laps": len(record["lap_times_s"]), "car": None, **record}, *record["conditions"]]
    for c in rows:
        laps, progress = f"{c['laps']}/{c['episodes']}", f"{c['mean_progress']:.1f}"
        times = ["-" if v is None else f"{v:.2f}" for v in (c["best_lap_s"], c["mean_lap_s"])]
        table.add_row(c["name"], laps, progress, *times, str(c["off_track"]), c["car"] or "-")
    return table


def _trials_table(trials: list[dict]) -> Table:
    table = Table("#", "track", "direction", "start", "status", "progress %", "steps", "lap s", "resets")
    for number, t in enumerate(trials, 1):
        lap = "-" if t["lap_time_s"] is None else f"{t['lap_time_s']:.2f}"
        direction = "reverse" if t["reverse"] else "forward"
        resets = f"{t['resets']} (+{t['penalty_s']:g} s)" if t.get("resets") else "-"
        status = (t["status"], f"{t['progress']:.1f}", str(t["steps"]), lap, resets)
        table.add_row(str(number), t["track"], direction, str(t["start_index"]), *status)
    return table


def plot(
    run_id: Annotated[str, typer.Argument(help="Run id.")],
    store: ReadStore = ".",
    s3_endpoint: Endpoint = None,
    out: Annotated[Path, typer.Option(help="Folder for training.png and trajectories.png.")] = Path("."),
    checkpoint: Annotated[
        str,
        typer.Option(
            help="The checkpoint whose evaluation trajectories.png draws: best (the evaluator's pick, as `racer "
            "models ls` marks it), latest or a version number."
        ),
    ] = "best",
) -> None:
    """PNGs of a run: training curves with evaluation completion, and evaluation trajectories coloured by speed."""
    from model_store import RunStore, open_store
    from racer.commands.options import checkpoint_choice
    from racer.plots import plot_run

    version = checkpoint_choice(checkpoint)  # before the store is opened: a typo is the user's first error to fix
    for p in plot_run(run_id, RunStore(open_store(store, s3_endpoint)), out, checkpoint=version):
        console.print(f"wrote {p}")
