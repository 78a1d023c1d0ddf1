"""The ``racer`` command line. Thin: each command parses options and calls one function."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.table import Table

app = typer.Typer(add_completion=False, no_args_is_help=True, help="racer: DeepRacer-style RL on MuJoCo.")
tracks_app = typer.Typer(no_args_is_help=True, help="The bundled DeepRacer tracks.")
bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks.")
app.add_typer(tracks_app, name="tracks")
app.add_typer(bench_app, name="bench")
console = Console()


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
    from common.action_space import ActionSpaceError
    from sim.reward import RewardFunctionError
    from sim.track import TrackError

    return (TrackError, ActionSpaceError, RewardFunctionError)


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
    from sim.views import write_track_picture

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
    json_out: Annotated[str | None, typer.Option("--json", help="Write the result as JSON to F (- = stdout).")] = None,
) -> None:
    """Env steps per second on one core (physics + camera + reward), and its parts."""
    from common.config import EnvConfig
    from sim.bench import bench_env

    try:
        result = bench_env(EnvConfig(track=track, camera=camera), steps=steps, repeats=repeats)
    except _user_errors() as exc:
        fail(str(exc))
    table = Table("figure", "value")
    table.add_row("env steps/s (median)", f"{result['steps_per_s']:.0f}")
    table.add_row("runs", ", ".join(f"{r:.0f}" for r in result["steps_per_s_runs"]))
    for part in ("physics", "camera", "task", "reward"):
        table.add_row(f"{part} µs/step", f"{result[f'{part}_us_per_step']:.1f}")
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


def main() -> None:
    """Entry point for ``python -m racer``."""
    app()
