"""``racer models``: the runs and checkpoints in a store, listed (``ls``) and shrunk (``prune``)."""

from __future__ import annotations

import datetime
from typing import Annotated

import typer
from rich.table import Table

from racer.commands.options import Endpoint, ReadStore, console, json_option, print_table, write_json

app = typer.Typer(no_args_is_help=True, help="Runs and checkpoints in a store.")


@app.command("ls")
def ls(
    store: ReadStore = ".",
    s3_endpoint: Endpoint = None,
    run_id: Annotated[str | None, typer.Option("--run-id", help="Only this run.")] = None,
    wide: Annotated[bool, typer.Option("--wide", help="All columns, the run id on every row.")] = False,
    json_out: Annotated[str | None, json_option("the list")] = None,
) -> None:
    """List checkpoints, one line each under their run: version, env steps, time, size, evaluation, latest/best."""
    from racer.evaluate import models_table

    rows = models_table(store, s3_endpoint, run_id)
    if json_out != "-":
        for table in models_tables(rows, wide):
            print_table(table)
    write_json(rows, json_out)


@app.command("prune")
def prune(
    store: ReadStore = ".",
    s3_endpoint: Endpoint = None,
    run_id: Annotated[list[str] | None, typer.Option("--run-id", help="Only this run (repeatable).")] = None,
    keep: Annotated[int, typer.Option(min=0, help="Newest checkpoints to keep beside latest and best.")] = 1,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Say what would go; delete nothing.")] = False,
    json_out: Annotated[str | None, json_option("what went")] = None,
) -> None:
    """Shrink runs you are done training: delete all checkpoints but the newest --keep and the latest and best
    ones, and every optimizer state but the newest checkpoint's. Do not prune a run that is still training."""
    from model_store import RunStore, open_store

    runs = RunStore(open_store(store, s3_endpoint))
    results = [runs.prune_run(r, keep, dry_run) for r in run_id or runs.list_runs()]
    if json_out != "-":
        verb = "would free" if dry_run else "freed"
        for r in results:
            console.print(
                f"{r['run_id']}: {verb} {r['bytes'] / 1e6:.1f} MB ({len(r['checkpoints'])} checkpoints, "
                f"{len(r['optimizer_states'])} optimizer states)",
                highlight=False,
            )
    write_json(results, json_out)


COLUMNS = ["v", "env steps", "created (UTC)", "size", "laps", "progress", "best lap", ""]
"""``racer models ls``'s columns: at 80 terminal columns nothing is cut (tested)."""


def models_tables(rows: list[dict], wide: bool) -> list[Table]:
    """One table per run that fits 80 columns (the run id as its title), or with --wide one table of all."""
    runs = [None] if wide else list(dict.fromkeys(r["run_id"] for r in rows))
    tables = []
    for run in runs:
        table = Table(box=None, pad_edge=False, title=run, title_justify="left")
        for name in ["run", *COLUMNS] if wide else COLUMNS:
            table.add_column(name, no_wrap=True)
        for r in rows if wide else [r for r in rows if r["run_id"] == run]:
            cells = _cells(r)
            table.add_row(*([r["run_id"], *cells] if wide else cells))
        tables.append(table)
    return tables


def _cells(r: dict) -> list[str]:
    created = datetime.datetime.fromtimestamp(r.get("created") or 0, datetime.UTC)
    ev = r.get("evaluation") or {}
    return [
        str(r["version"]),
        "-" if r.get("env_steps") is None else f"{r['env_steps']:,}",
        f"{created:%Y-%m-%d %H:%M}",
        f"{(r.get('size_bytes') or 0) / 1e6:.1f} MB",
        "-" if not ev else f"{100 * ev['completion_rate']:.0f}%",
        "-" if not ev else f"{ev['mean_progress']:.1f}%",
        "-" if ev.get("best_lap_s") is None else f"{ev['best_lap_s']:.2f} s",
        " ".join(m for m in ("latest", "best") if r.get(m)),
    ]
