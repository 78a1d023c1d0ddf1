"""``racer tracks`` (the bundled tracks, listed and drawn) and ``racer drive`` (a random policy on one)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from racer.commands.options import ActionSpace, RaceFile, RaceTypeOpt, Track, console, json_option, write_json

app = typer.Typer(no_args_is_help=True, help="The bundled DeepRacer tracks.")


@app.command("ls")
def ls() -> None:
    """List the bundled tracks with their length, width and direction."""
    from sim.track import bundled_track_names, load_track

    table = Table("track", "length m", "width m", "direction", "waypoints")
    for name in bundled_track_names():
        t = load_track(name)
        direction = "open" if not t.closed else ("CW" if t.clockwise else "CCW")
        table.add_row(name, f"{t.length:.2f}", f"{t.width:.2f}", direction, str(len(t.center)))
    console.print(table)


@app.command("show")
def show(
    track: Annotated[str, typer.Argument(help="Bundled track name or path to a DeepRacer .npy file.")],
    png: Annotated[Path, typer.Option("--png", help="Write the picture to this PNG file.")],
    start: Annotated[int, typer.Option(help="Waypoint where the car is placed.")] = 0,
    camera: Annotated[str, typer.Option(help="Camera path: ground or mujoco.")] = "ground",
) -> None:
    """Write a PNG: the track from above with the car at a start waypoint, and its camera view."""
    from racer.plots import write_track_picture

    write_track_picture(track, png, start, camera)
    console.print(f"wrote {png}")


def drive(
    track: Track = "reinvent_base",
    episodes: Annotated[int, typer.Option(min=1, help="Episodes to drive.")] = 5,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    reward_fn: Annotated[Path | None, typer.Option("--reward-fn", help="DeepRacer reward function file.")] = None,
    action_space: ActionSpace = None,
    race_type: RaceTypeOpt = None,
    race: RaceFile = None,
    json_out: Annotated[str | None, json_option("the episodes")] = None,
) -> None:
    """Drive a random policy for a few episodes and print what happened (a smoke test of the simulator)."""
    from common.config import EnvConfig
    from common.race import RaceConfig
    from racer.runconfig import load_race
    from sim.drive import drive_random

    cfg = EnvConfig(
        track=track,
        reward_fn=str(reward_fn) if reward_fn else None,
        action_space=str(action_space) if action_space else None,
        race=load_race(race, race_type) or RaceConfig(),
    )
    rows = drive_random(cfg, episodes, seed)
    table = Table("episode", "steps", "status", "progress %", "return")
    for r in rows:
        table.add_row(str(r["episode"]), str(r["steps"]), r["status"], f"{r['progress']:.1f}", f"{r['return']:.2f}")
    console.print(table)
    write_json(rows, json_out)
