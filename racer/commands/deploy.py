"""``racer export`` (a checkpoint's policy as ONNX for racer's car runtime, or in DeepRacer's formats), ``racer import``
(a DeepRacer model as a run) and ``racer car`` (the on-car runtime)."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Annotated

import typer

from common.errors import OptionError
from racer.commands.options import Endpoint, ReadStore, Store, console, json_option, write_json
from racer.console import new_console

FORMATS = ("onnx", "deepracer-car", "deepracer-sim")
"""``racer export --format`` values: racer's ONNX model, DeepRacer's car archive, DeepRacer's simulator folder."""


def export(
    run_id: Annotated[str, typer.Option("--run-id", help="Run id.")],
    out: Annotated[
        Path,
        typer.Option(
            "-o",
            "--out",
            help="Where to write: onnx, the model file (model_metadata.json goes beside); deepracer-car, a .tar.gz; "
            "deepracer-sim, a new folder.",
        ),
    ],
    store: ReadStore = ".",
    s3_endpoint: Endpoint = None,
    checkpoint: Annotated[str, typer.Option(help="best, latest or a version number.")] = "best",
    fmt: Annotated[
        str,
        typer.Option(
            "--format",
            help="onnx (racer's car runtime), deepracer-car (the DeepRacer car's .tar.gz) or deepracer-sim (a model "
            "folder for DRfC / DeepRacer on AWS). The deepracer formats need TensorFlow: racer's deepracer extra.",
        ),
    ] = "onnx",
    upload: Annotated[
        str | None,
        typer.Option(help="deepracer-sim only: also upload the folder to s3://bucket/prefix as dr-upload-model does."),
    ] = None,
    json_out: Annotated[str | None, json_option("what was exported")] = None,
) -> None:
    """Export a checkpoint's policy: ONNX for racer's car runtime, or DeepRacer's car archive or simulator folder
    (docs/deepracer-models.md)."""
    from model_store import RunStore, open_store

    if fmt not in FORMATS:
        raise OptionError(f"--format {fmt!r} is not supported: use {', '.join(FORMATS)}")
    if upload and fmt != "deepracer-sim":
        raise OptionError(f"--upload applies to --format deepracer-sim, not {fmt}")
    if fmt != "onnx":
        from deploy.deepracer_graph import tensorflow

        tensorflow(f"--format {fmt}")  # the missing extra is one line before anything is read
    runs = RunStore(open_store(store, s3_endpoint))
    if checkpoint == "best" and runs.pointer(run_id, "best") is None:
        checkpoint = "latest"  # a run without an evaluator has no best: its newest policy is the one to drive
    if fmt == "onnx":
        from deploy.export import export_onnx

        result = export_onnx(runs, run_id, checkpoint, out)
        console.print(f"exported run {run_id} v{result['version']} to {result['model']} (+ {result['model_metadata']})")
    elif fmt == "deepracer-car":
        from deploy.deepracer_format import export_car

        result = export_car(runs, run_id, checkpoint, out)
        console.print(f"exported run {run_id} v{result['version']} for the DeepRacer car to {result['model']}")
    else:
        from deploy.deepracer_format import export_sim

        result = export_sim(runs, run_id, checkpoint, out, upload=upload, s3_endpoint=s3_endpoint)
        where = f" and {upload}" if upload else ""
        console.print(f"exported run {run_id} as a DeepRacer model folder to {out}{where}")
    write_json(result, json_out)


def import_model(
    source: Annotated[
        str, typer.Argument(help="A DeepRacer model: its folder, the car's .tar.gz or s3://bucket/prefix.")
    ],
    run_id: Annotated[str, typer.Option("--run-id", help="The new run to hold it.")],
    store: Store = ".",
    s3_endpoint: Endpoint = None,
    json_out: Annotated[str | None, json_option("what was imported")] = None,
) -> None:
    """Import a DeepRacer model (car archive or simulator folder) as a new run's version 0, to evaluate it with
    racer eval or keep training it with racer train --pretrained (docs/deepracer-models.md). Needs: pip install
    'racer\\[deepracer]'."""
    from deploy.importer import import_model as read_model
    from model_store import RunStore, open_store
    from racer.runconfig import build_run

    runs = RunStore(open_store(store, s3_endpoint))
    result = read_model(runs, source, run_id, s3_endpoint, build_run=build_run)
    for note in result["notes"]:
        console.print(f"note: {note}", highlight=False)
    weights, value = result["weights"], result["value_head"]
    console.print(f"imported {source} as run {run_id} version 0 ({weights}; value head {value})")
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

    No LIDAR / SECTOR_LIDAR models: racer has no LiDAR driver (deploy.car.runtime.drive takes a LidarSource).
    """
    from deploy.car.runtime import CsvSink, Policy, drive
    from deploy.car.vehicle import VehicleCalibration, load_vehicle_calibration

    calibration = load_vehicle_calibration(vehicle) if vehicle else VehicleCalibration()
    result = drive(Policy(model), source, calibration, CsvSink(out), max_frames, right_source=right_source)
    new_console(stderr=True).print(
        f"{result.frames} frames at {result.fps:.1f} frames/s (inference {result.infer_ms_median:.2f} ms, "
        f"loop {result.loop_ms_median:.2f} ms, medians)"
    )
    write_json(asdict(result), json_out)
