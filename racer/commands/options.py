"""What the commands share: the console, ``--json`` output, and the options that several commands take."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Literal

import typer
from rich.measure import Measurement
from rich.table import Table

from common.config import MAX_ENVS_PER_WORKER
from common.defaults import DEFAULT_GIVE_UP_S
from common.errors import OptionError
from racer.console import new_console
from trainer.device import DEVICE_HELP

console = new_console()
"""Standard output of every command (progress and messages that must not mix with ``--json -`` go to stderr)."""

_UNBOUNDED = 10_000
"""Columns a piped table may take: more than any table racer prints needs."""


def print_table(table: Table) -> None:
    """A table on standard output: in a terminal, fitted to its width; piped or redirected, whole at its natural
    width. A pipe has no width, and rich's 80 columns for one cut cells (``racer models ls --wide``'s run ids and
    versions, ``racer eval``'s track names)."""
    if console.is_terminal:
        console.print(table)
        return
    natural = Measurement.get(console, console.options.update_width(_UNBOUNDED), table).maximum
    # A console of its own: the shared one's width is the environment's, and print(width=) cannot exceed it.
    new_console(file=console.file, width=max(natural, console.width), color_system=None).print(table)


def write_json(data: object, target: str | None) -> None:
    """Write machine-readable output to a file, or to standard output for ``-``."""
    if target is None:
        return
    text = json.dumps(data, indent=2)
    if target == "-":
        sys.stdout.write(text + "\n")
    else:
        Path(target).write_text(text + "\n")


def checkpoint_choice(text: str, option: str = "--checkpoint") -> int | Literal["best", "latest"]:
    """A checkpoint as given to ``option``: ``best``, ``latest`` or a version number; otherwise an OptionError naming
    the option and the value (rather than the store's "invalid pointer", which names neither)."""
    folded = text.strip().lower()
    if folded == "best":
        return "best"
    if folded == "latest":
        return "latest"
    if folded.isdecimal() and int(folded) < 10**9:  # the store's version range (model_store.runs)
        return int(folded)
    raise OptionError(f"{option} must be best, latest or a checkpoint version number (got {text!r})")


def _duration_text(text: str, option: str) -> str:
    """``text`` if it is a duration (``90s``, ``10m``), checked as the option is read, so that a bad one is refused
    with the option's name before the command starts; the command parses it again."""
    from common.deadline import parse_duration

    parse_duration(text, option)
    return text


def int_list(text: str, option: str) -> list[int]:
    """``0,1,2`` given to ``option`` as integers, or an OptionError naming the option and what was given."""
    try:
        return [int(s) for s in text.split(",")]
    except ValueError:
        raise OptionError(f"{option} must be comma-separated integers (got {text!r})") from None


def existing_store(uri: str) -> str:
    """``--store`` of a command that reads a store and makes none: a local directory must exist. An S3 store is
    asked when read. Without this a mistyped path read as an empty store: ``racer models ls --store /nonexistent``
    printed nothing and exited 0."""
    from model_store import local_store

    local = local_store(uri)
    if local is not None and not local.root.is_dir():
        what = "is not a directory" if local.root.exists() else "no such directory"
        raise OptionError(f"--store {uri}: {what} (racer train makes a store; the others read one)")
    return uri


_STORE_HELP = "s3://bucket/prefix or a directory (runs go in runs/)."
Store = Annotated[str, typer.Option("--store", envvar="RACER_STORE", help=_STORE_HELP)]
"""A store that the command may create (racer train, racer import)."""
ReadStore = Annotated[str, typer.Option("--store", envvar="RACER_STORE", help=_STORE_HELP, callback=existing_store)]
"""A store that the command only reads (or prunes): it must exist, checked before the command starts."""
Endpoint = Annotated[
    str | None, typer.Option("--s3-endpoint", envvar="AWS_ENDPOINT_URL", help="S3 endpoint URL (MinIO, moto).")
]
RunId = Annotated[str, typer.Option("--run-id", envvar="RACER_RUN_ID", help="Run id.")]
Redis = Annotated[str, typer.Option("--redis", envvar="RACER_REDIS_URL", help="redis://[:password@]host:port/db")]
DEFAULT_OUTAGE = f"{DEFAULT_GIVE_UP_S / 60:g}m"
"""``--outage-timeout``'s default, ``common.defaults.DEFAULT_GIVE_UP_S`` as a duration."""

Outage = Annotated[
    str,
    typer.Option(
        "--outage-timeout",
        envvar="RACER_OUTAGE_TIMEOUT",
        help="Ride out a Redis or store outage this long before exiting (90s, 10m).",
        callback=lambda text: _duration_text(text, "--outage-timeout"),
    ),
]
Car = Annotated[
    str | None,
    typer.Option(
        "--car", "--car-calibration", help="The car to simulate: a preset (default) or a car.json (racer calibrate)."
    ),
]
Track = Annotated[str, typer.Option(help="Track name or .npy path.")]
RewardFn = Annotated[Path | None, typer.Option("--reward-fn", help="DeepRacer reward function .py.")]
ActionSpace = Annotated[Path | None, typer.Option("--action-space", help="DeepRacer model_metadata.json.")]
Hyperparams = Annotated[Path | None, typer.Option("--hyperparams", help="DeepRacer hyperparameters.json.")]
FromDrfc = Annotated[
    Path | None,
    typer.Option("--from-drfc", help="A DeepRacer-for-Cloud folder: custom_files/ and run.env (options win)."),
]
RaceTypeOpt = Annotated[
    str | None,
    typer.Option("--race-type", help="TIME_TRIAL, OBJECT_AVOIDANCE or HEAD_TO_BOT (DeepRacer's defaults; see --race)."),
]
RaceFile = Annotated[
    Path | None,
    typer.Option(
        "--race", help="JSON of race settings: obstacles, bot cars, evaluation penalties (docs/object-avoidance.md)."
    ),
]
WorkerConfig = Annotated[
    list[str] | None,
    typer.Option(
        "--worker-config",
        help="Worker N's own world: N=FILE (a DRfC worker-N.env, N from 1), repeated; or one YAML list file.",
    ),
]
Verbose = Annotated[bool, typer.Option("--verbose", "-v", help="Debug logging.")]
EnvsPerWorker = Annotated[
    int,
    typer.Option(
        "--envs-per-worker",
        min=1,
        max=MAX_ENVS_PER_WORKER,
        envvar="RACER_ENVS_PER_WORKER",
        help="Envs each rollout worker steps side by side, acting for all in one batched forward pass.",
    ),
]


def device_option(envvar: str | None = None) -> object:
    """The ``--device auto|cpu|cuda|cuda:N`` option (``trainer.device``), read from ``envvar`` too if given."""
    return typer.Option("--device", envvar=envvar, help=DEVICE_HELP)


def json_option(what: str = "the result") -> object:
    """The ``--json F`` option (``-`` = standard output), saying what is written."""
    return typer.Option("--json", help=f"Write {what} as JSON to F (- = stdout).")


JsonOut = Annotated[str | None, json_option()]
