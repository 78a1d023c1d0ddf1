"""``racer view``: a run followed live in the browser, or a finished one from its store (docs/view.md)."""

from __future__ import annotations

from typing import Annotated

import typer

from racer.commands.options import Endpoint, ReadStore, RunId, console


def view(
    run_id: RunId,
    store: ReadStore = ".",
    s3_endpoint: Endpoint = None,
    redis_url: Annotated[
        str | None,
        typer.Option(
            "--redis",
            envvar="RACER_REDIS_URL",
            help="The run's Redis (default: the one racer train recorded in runs/<id>/redis.json, if it answers; "
            "without one, the run as stored).",
        ),
    ] = None,
    host: Annotated[
        str, typer.Option(help="Address to listen on; beyond loopback every request needs the printed token.")
    ] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="Port to listen on; 0 = a free one.")] = 8090,
) -> None:
    """Serve a web page that shows the run: cars on the track, a worker's camera, training charts, checkpoints."""
    from racer.view.server import ViewOptions, ViewServer

    server = ViewServer(ViewOptions(run_id, store, s3_endpoint=s3_endpoint, redis_url=redis_url, host=host, port=port))
    console.print(f"run {run_id}: {server.note}", highlight=False, soft_wrap=True)
    if server.token:
        console.print("listening beyond loopback: the page needs the token in this URL", highlight=False)
    console.print(f"racer view: {server.url}  (Ctrl-C stops)", highlight=False, soft_wrap=True)
    server.serve_forever()
