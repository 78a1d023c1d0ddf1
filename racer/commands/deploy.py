"""``racer export`` (a checkpoint's policy as ONNX, for a car) and ``racer car`` (the on-car runtime)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from common.errors import OptionError
from racer.commands.options import Endpoint, Store, console, json_option, write_json


def export(
    run_id: Annotated[str, typer.Option("--run-id", help="Run id.")],
    out: Annotated[
        Path, typer.Option("-o", "--out", help="Where to write the model (model_metadata.json goes beside).")
    ],
    store: Store = ".",
    s3_endpoint: Endpoint = None,
    checkpoint: Annotated[str, typer.Option(help="best, latest or a version number.")] = "best",
    fmt: Annotated[str, typer.Option("--format", help="Export format: onnx.")] = "onnx",
    json_out: Annotated[str | None, json_option("what was exported")] = None,
) -> None:
    """Export a checkpoint's policy for a car (ONNX), with the run's model_metadata.json beside it."""
    from deploy.export import export_onnx
    from model_store import RunStore, open_store

    if fmt != "onnx":
        raise OptionError(f"--format {fmt!r} is not supported: use onnx")
    runs = RunStore(open_store(store, s3_endpoint))
    if checkpoint == "best" and runs.pointer(run_id, "best") is None:
        checkpoint = "latest"  # a run without an evaluator has no best: its newest policy is the one to drive
    result = export_onnx(runs, run_id, checkpoint, out)
    console.print(f"exported run {run_id} v{result['version']} to {result['model']} (+ {result['model_metadata']})")
    write_json(result, json_out)


def car(
    model: Annotated[Path, typer.Option(help="model.onnx from racer export (model_metadata.json beside it).")],
    source: Annotated[
        str,
        typer.Option(
            help="Camera index (0) or a video file / image sequence (frames/%04d.png); the left camera of a "
            "STEREO_CAMERAS model."
        ),
    ],
    right_source: Annotated[
        str | None,
        typer.Option(
            "--right-source",
            help="The right camera of a STEREO_CAMERAS model (index, video file or image sequence), read in step "
            "with --source; give it exactly when the model is stereo.",
        ),
    ] = None,
    vehicle: Annotated[Path | None, typer.Option(help="Vehicle calibration JSON (default: the defaults).")] = None,
    out: Annotated[str, typer.Option(help="CSV of motor commands, one row per frame (- = stdout).")] = "-",
    max_frames: Annotated[int | None, typer.Option(min=1, help="Stop after N frames.")] = None,
    json_out: Annotated[str | None, json_option("frames and rates")] = None,
) -> None:
    """The on-car runtime: camera frames → policy (ONNX, one CPU thread) → vehicle calibration → motor commands.

    No LIDAR / SECTOR_LIDAR models: racer has no LiDAR driver (deploy.runtime.drive takes a LidarSource).
    """
    from deploy.runtime import CsvSink, Policy, drive
    from deploy.vehicle import VehicleCalibration, load_vehicle_calibration

    calibration = load_vehicle_calibration(vehicle) if vehicle else VehicleCalibration()
    result = drive(Policy(model), source, calibration, CsvSink(out), max_frames, right_source=right_source)
    Console(stderr=True).print(
        f"{result.frames} frames at {result.fps:.1f} frames/s (inference {result.infer_ms_median:.2f} ms, "
        f"loop {result.loop_ms_median:.2f} ms, medians)"
    )
    write_json(asdict(result), json_out)
