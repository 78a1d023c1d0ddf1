"""``racer tracks`` (racer's and DeepRacer's tracks: listed, pulled and drawn) and ``racer drive`` (a random policy on
one)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from common.defaults import DEFAULT_TRACK
from racer.commands.options import (
    ActionSpace,
    RaceFile,
    RaceTypeOpt,
    Track,
    console,
    json_option,
    print_table,
    write_json,
)

app = typer.Typer(no_args_is_help=True, help="racer's tracks and DeepRacer's: list, pull (verified) and draw them.")


@app.command("ls")
def ls() -> None:
    """List racer's own tracks and the DeepRacer tracks in the track folder (length, width, direction), then the
    DeepRacer tracks that can be pulled."""
    from sim.routes import cached_route_names, deepracer_route_names, tracks_dir
    from sim.track import load_track
    from sim.track_gen import racer_track_names

    folder = tracks_dir()
    cached = cached_route_names(folder)
    table = Table("track", "kind", "length m", "width m", "direction", "waypoints")
    for kind, names in (("racer", racer_track_names()), ("DeepRacer", cached)):
        for name in names:
            t = load_track(name if kind == "racer" else folder / f"{name}.npy")
            direction = "open" if not t.closed else ("CW" if t.clockwise else "CCW")
            table.add_row(name, kind, f"{t.length:.2f}", f"{t.width:.2f}", direction, str(len(t.center)))
    print_table(table)
    missing = sorted(set(deepracer_route_names()) - set(cached))
    console.print(f"track folder: {folder} (RACER_TRACKS_DIR)", highlight=False, soft_wrap=True)
    if missing:
        console.print(
            f"{len(missing)} DeepRacer tracks can be pulled (`racer tracks pull NAME...` or `--all`): "
            + ", ".join(missing),
            highlight=False,
            soft_wrap=True,
        )


@app.command("pull")
def pull(
    names: Annotated[list[str] | None, typer.Argument(help="DeepRacer track names (see racer tracks ls).")] = None,
    all_: Annotated[bool, typer.Option("--all", help="Pull all 127 DeepRacer tracks.")] = False,
    source: Annotated[
        str | None,
        typer.Option(
            "--from",
            envvar="RACER_TRACKS_FROM",
            help="Base URL (http, https, file) or local folder to pull from; offline, a folder of DeepRacer .npy "
            "routes (a simapp or DRfC checkout's bundle/routes).",
            show_default="the community simapp's bundle/routes at the commit racer follows",
        ),
    ] = None,
    folder: Annotated[
        Path | None,
        typer.Option("--dir", help="Track folder to write.", show_default="RACER_TRACKS_DIR or ~/.cache/racer/tracks"),
    ] = None,
) -> None:
    """Download DeepRacer route files into the track folder, each checked against the sha256 racer ships."""
    from common.errors import OptionError
    from sim.routes import deepracer_route_names, pull, tracks_dir

    if all_ == bool(names):
        raise OptionError("racer tracks pull: give track names or --all (not both)")
    wanted = deepracer_route_names() if all_ else list(names or [])
    pulled = pull(wanted, source, folder)
    fresh = sum(p.fresh for p in pulled)
    where = folder or tracks_dir()
    console.print(f"{fresh} pulled, {len(pulled) - fresh} already there, in {where}", highlight=False, soft_wrap=True)


@app.command("show")
def show(
    track: Annotated[str, typer.Argument(help="Track name or path to a DeepRacer .npy file.")],
    png: Annotated[Path, typer.Option("--png", help="Write the picture to this PNG file.")],
    start: Annotated[int, typer.Option(help="Waypoint where the car is placed.")] = 0,
    camera: Annotated[str, typer.Option(help="Camera path: ground or mujoco.")] = "ground",
) -> None:
    """Write a PNG: the track from above with the car at a start waypoint, and its camera view."""
    from racer.plots import write_track_picture

    write_track_picture(track, png, start, camera)
    console.print(f"wrote {png}")


def drive(
    track: Track = DEFAULT_TRACK,
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
    print_table(table)
    write_json(rows, json_out)
