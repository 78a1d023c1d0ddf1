"""``racer eval`` (a checkpoint driven from several starts) and ``racer plot`` (a run's PNGs)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from racer.commands.options import Endpoint, JsonOut, Store, console, device_option, print_table, write_json


def evaluate(
    run_id: Annotated[str, typer.Option("--run-id", help="Run id.")],
    store: Store = ".",
    s3_endpoint: Endpoint = None,
    checkpoint: Annotated[str, typer.Option(help="best, latest or a version number.")] = "best",
    track: Annotated[list[str] | None, typer.Option(help="Track(s) to drive (default: the run's).")] = None,
    episodes: Annotated[int, typer.Option(min=1, help="Start positions per direction and track.")] = 6,
    both_directions: Annotated[bool, typer.Option("--both-directions/--one-direction")] = True,
    action_noise: Annotated[float, typer.Option(min=0, max=1, help="Action noise fraction.")] = 0.1,
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
) -> None:
    """Evaluate a checkpoint of a run from a store: a table per trial, and the JSON summary."""
    from racer.evaluate import run_eval, video_lines

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
        resets,
        greedy_action,
        device,
        video_trial,
    )
    if json_out != "-":
        print_table(_trials_table(record["trials"]))
        best = "-" if record["best_lap_s"] is None else f"{record['best_lap_s']:.2f} s"
        console.print(
            f"version {record['version']}: completion {100 * record['completion_rate']:.0f}%, "
            f"mean progress {record['mean_progress']:.1f}%, best lap {best}, score {record['score']:.1f}"
        )
    if "video" in record:  # said even with --json -: on stderr then, so that standard output stays JSON
        for line in video_lines(record["video"]):
            (console if json_out != "-" else Console(stderr=True)).print(line, highlight=False, soft_wrap=True)
    summary = {k: v for k, v in record.items() if k != "trials"}
    summary["trials"] = [{k: v for k, v in t.items() if k != "trajectory"} for t in record["trials"]]
    write_json(summary, json_out)


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
    store: Store = ".",
    s3_endpoint: Endpoint = None,
    out: Annotated[Path, typer.Option(help="Folder for training.png and trajectories.png.")] = Path("."),
) -> None:
    """PNGs of a run: training curves with evaluation completion, and evaluation trajectories coloured by speed."""
    from model_store import RunStore, open_store
    from racer.plots import plot_run

    for p in plot_run(run_id, RunStore(open_store(store, s3_endpoint)), out):
        console.print(f"wrote {p}")
