"""The simulated car against the world: ``racer calibrate`` (fit it to measured logs) and ``racer limit`` (its
minimum lap time on a track)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from racer.commands.options import console, json_option, print_table, write_json
from racer.console import new_console


def calibrate(
    logs: Annotated[
        list[Path] | None,
        typer.Argument(help="Measured logs: sim-trace CSVs, RoboMaker logs, plain CSVs, folders."),
    ] = None,
    plan: Annotated[
        bool, typer.Option("--plan", help="Print the manoeuvres to drive so that every effect can be identified.")
    ] = False,
    apply: Annotated[
        str | None, typer.Option("--apply", help="Score this car (NAME|FILE: a preset or a car.json) on LOGS.")
    ] = None,
    car: Annotated[
        str | None, typer.Option("--car", help="Fit on top of this car (NAME|FILE), keeping its design values.")
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write the fitted calibration (car.json) here.")] = None,
    json_out: Annotated[str | None, json_option("the report")] = None,
    png: Annotated[Path | None, typer.Option("--png", help="Write trajectories and residuals before/after.")] = None,
    effects: Annotated[
        list[str] | None, typer.Option("--effect", help="Candidate effect (repeatable; default: all of them).")
    ] = None,
    track: Annotated[str | None, typer.Option(help="Track the logs were driven on (for the picture).")] = None,
    max_windows: Annotated[
        int | None, typer.Option(min=20, help="Replay windows to fit on (and to choose on); default 120.")
    ] = None,
    timing: Annotated[
        str, typer.Option(help="Row durations: auto, nominal, logged or logged_previous (see docs/calibration.md).")
    ] = "auto",
) -> None:
    """Fit the car to measured logs (base car, effects, error before/after on held-out episodes), or --apply one;
    --plan prints what to drive."""
    from racer.calibrate import run_calibrate

    if plan:
        from sim.calibration.plan import plan_text

        if logs or apply is not None or out is not None:
            from common.errors import OptionError

            raise OptionError("racer calibrate --plan prints what to drive: it takes no logs, --apply or --out")

        print(plan_text())  # plain: the plan's lines are already wrapped, and a pipe must not re-wrap them
        return
    if not logs:
        from common.errors import OptionError

        raise OptionError("racer calibrate: give the logs to fit (or --plan for what to drive)")
    # Progress goes to stderr, so that --json - leaves standard output to the JSON alone.
    progress = new_console(stderr=True, highlight=False).print
    report = run_calibrate(
        logs,
        apply=apply,
        out=out,
        png=png,
        effects=effects,
        track=track,
        max_windows=max_windows,
        say=progress,
        timing=timing,
        base=car,
    )
    if json_out != "-":
        _show_calibration(report)
    write_json(report, json_out)


def _show_calibration(report: dict) -> None:
    """The error table, the base car and the effects with their values, and what the report warns about."""
    table = Table("error (1 s replay)", "before", "after", "cut")
    for key, unit in (("position_m", "m"), ("heading_deg", "deg"), ("speed_mps", "m/s")):
        b, a = report["error_before"][key], report["error_after"][key]
        table.add_row(f"{key.split('_')[0]} ({unit})", f"{b:.3f}", f"{a:.3f}", f"{100 * (1 - a / b):.0f}%")
    print_table(table)
    for title, key in (("the car (base)", "base"), ("effects", "effects")):
        entries = report.get(key) or []
        if key == "base" and not entries:
            continue
        console.print(f"{title}:" + ("" if entries else " none"), markup=False)
        for e in entries:
            console.print(f"  {_effect_line(e)}", markup=False, highlight=False, soft_wrap=True)
    for item in report.get("identifiability", []):
        if not item["identifiable"]:
            console.print(f"  not identifiable: {item['effect']} (drive: {item['drive']})", markup=False)
    structure = report.get("residual")
    if structure and structure.get("structured"):
        console.print("  the residual is structured, not noise: an effect racer lacks?", markup=False)
        for where in structure.get("where", [])[:3]:
            console.print(f"    {where.get('says', where)}", markup=False, highlight=False, soft_wrap=True)


def _effect_line(e: dict) -> str:
    """``name: value ± stderr unit [95 % interval]`` (the file's params where there is no physical value)."""
    if "value" not in e:
        errors = e.get("stderr") or {}
        return f"{e['name']}: " + ", ".join(
            f"{k} = {v:.3g}" + (f" ± {errors[k]:.2g}" if k in errors else "") for k, v in e["params"].items()
        )
    line = f"{e['name']}: {e['value']:.4g}"
    if "value_stderr" in e:
        lo, hi = e["interval_95"]
        line += f" ± {e['value_stderr']:.2g} {e['unit']} (95 %: {lo:.4g} to {hi:.4g})"
    if e.get("provisional"):
        line += " [provisional: the residual is structured]"
    if e.get("ambiguous_with"):
        line += f"; not told apart from {', '.join(e['ambiguous_with'])}: {e['determined']}"
    return line


def limit(
    track: Annotated[str, typer.Argument(help="Track name or .npy path (a loop).")],
    car: Annotated[str, typer.Option(help="Car: a preset name (default) or a car.json from racer calibrate.")] = (
        "default"
    ),
    action_space: Annotated[
        Path | None, typer.Option("--action-space", help="model_metadata.json: its top speed caps the car's.")
    ] = None,
    margin: Annotated[
        float, typer.Option(min=0.0, max=0.08, help="Metres the car's centre keeps inside DeepRacer's off-track line.")
    ] = 0.05,
    png: Annotated[Path | None, typer.Option("--png", help="Write the line coloured by speed over the track.")] = None,
    json_out: Annotated[str | None, json_option("the report")] = None,
    cache: Annotated[
        bool,
        typer.Option(help="Reuse the car's limits measured before for the same car and code ($RACER_CACHE_DIR)."),
    ] = True,
) -> None:
    """The minimum lap time of a car on a track: its racing line and speed profile, and a lap driven on it."""
    from racer.limit import compute_limit, plot_limit, public

    report = compute_limit(track, car, action_space, margin, cache)
    if png:
        plot_limit(report, png)
    if json_out != "-":
        driven = report["driven_lap_time_s"]
        ratio = report["driven_over_limit"]
        console.print(
            f"{track}, car {car}: limit {report['lap_time_s']:.2f} s from a standing start "
            f"(flying lap {report['flying_lap_time_s']:.2f} s) on a {report['line_length_m']:.2f} m line, "
            f"top speed {report['max_speed_mps']:.2f} m/s",
            highlight=False,
        )
        console.print(
            "driven in the env by a predictive line follower: "
            + (f"{driven:.2f} s ({100 * (ratio - 1):+.1f} % of the limit)" if driven else report["driven_status"])
            + (f" at {100 * report['driven_pace']:.0f} % of the profile's speeds" if report["driven_pace"] < 1 else "")
            + f"; {report['seconds']['total']:.1f} s in all",
            highlight=False,
        )
    write_json(public(report), json_out)
