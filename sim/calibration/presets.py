"""How the car presets' fitted values were made, so that anyone with DeepRacer's public Gazebo logs can make them again.

The presets ``deepracer-gazebo`` and ``deepracer-gazebo-ros2`` (``sim/cars/NAME.json``; their story is in
``sim/cars/SOURCES.md``) were fitted by ``racer calibrate`` from a design car (``sim/cars/design/NAME.json``) on a
selection of the episodes of one public log set each. Racer does not ship those logs: the user gives the folder
(:data:`PRESET_FITS` names the set, ``sim/cars/SOURCES.md`` where to get it), and this module makes the fit log from
it by code:

1. read the set's folder as ``racer calibrate`` reads it (``sim.calibration.logs.read_logs``);
2. order the episodes as the fit splits them (by file path, as text, then episode number:
   ``sim.calibration.fit.split_episodes``) and keep one in ``every``, starting at ``first``;
3. write them as one plain CSV (``sim/calibration/logs.py``, format 3) rounded to 0.1 ms, 1e-4 ° and m/s,
   1 µm and 1e-5 ° (:data:`DIGITS`).

The fit then ran on that one file: ``racer calibrate FIT.csv --car sim/cars/design/NAME.json --max-windows 120``
chose the effects, and :func:`sim.calibration.fit.refit` fitted them once more, jointly from the design, on the same
120 fit windows: those are the values, with their standard errors, in ``NAME.json``.

Why steps 2 and 3 matter: the fit's cost (the contact-rich replay) is rough, so its optimum moves with details
that carry no information. Measured with the refit (:func:`refit_preset`): the same 85 ROS2 episodes
read from their 15 files instead of the one fit log are split differently (the split orders by file) and give a
tyre friction of 0.87 instead of 1.11 (22 standard errors); the same 50 ROS1 episodes unrounded (changes under
5e-6) give a steering lag of 0.478 s instead of 0.502 s (7 standard errors). The standard errors in the car files
measure the spread over episodes of one fit, not this. Written as above, the fit log holds exactly the values of
the file the presets were fitted on, and the refit lands on the shipped values.

``python -m sim.calibration.presets NAME LOGS [--fit-log FIT.csv] [--out car.json]`` writes the fit log, refits the
preset on it and prints each value against the shipped one (``tests/test_preset_refit.py`` runs the same).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from common.car_calibration import CAR_PRESETS, CarCalibration, load_calibration, save_calibration
from common.errors import UserError
from sim.calibration.logs import LogError, Trajectory, read_log, read_logs


@dataclass(frozen=True)
class PresetFit:
    """The logs and the episodes a preset was fitted on."""

    log_set: str
    """The public log set (a folder of DeepRacer sim-traces; ``sim/cars/SOURCES.md`` says where to get it)."""
    episodes: int
    """Usable episodes ``read_logs`` finds in the whole set: a check that the folder given is that set."""
    first: int
    """The first episode kept, in the fit's order (file path as text, then episode number)."""
    every: int
    """One episode in this many is kept."""
    max_windows: int = 120
    """``racer calibrate --max-windows``: the windows the fit ran on."""
    about: str = ""
    """One line on where the set was logged, written at the head of the fit log."""


PRESET_FITS: dict[str, PresetFit] = {
    "deepracer-gazebo": PresetFit(
        "gazebo-ros1-console2022-reinvent_base",
        episodes=552,
        first=5,
        every=11,
        about="DeepRacer's Gazebo car (ROS1 simapp, AWS console, June 2022) on reinvent_base, training-simtrace",
    ),
    "deepracer-gazebo-ros2": PresetFit(
        "gazebo-ros2-simapp6-reInvent2019_wide_cw",
        episodes=256,
        first=1,
        every=3,
        about="DeepRacer's Gazebo car (ROS2 simapp 6, gz-sim, DeepRacer-on-AWS, March 2026) on reInvent2019_wide "
        "clockwise, training-simtrace",
    ),
}
"""Each fitted preset: the public log set and the selection of its episodes that it was fitted on."""

DIGITS = {"t": 4, "steer_cmd_deg": 4, "speed_cmd_mps": 4, "x": 6, "y": 6, "heading_deg": 5}
"""Decimals of each column of the fit log: 0.1 ms, 1e-4 ° and m/s, 1 µm, 1e-5 °."""


class PresetError(UserError):
    """A preset that was not fitted, or logs that are not the set it was fitted on; one line."""


def preset_fit(name: str) -> PresetFit:
    """The fit of a preset; PresetError (one line, naming the fitted presets) for any other name."""
    if name not in PRESET_FITS:
        raise PresetError(f"{name!r} is not a fitted car preset; fitted: {', '.join(PRESET_FITS)}")
    return PRESET_FITS[name]


def design_path(name: str) -> Path:
    """The design car the preset's fit started from (``sim/cars/design/NAME.json``, shipped with the package)."""
    preset_fit(name)
    return Path(str(resources.files("sim") / "cars" / "design" / f"{name}.json"))


def select_episodes(trajectories: Sequence[Trajectory], first: int, every: int) -> list[Trajectory]:
    """Episodes ``first``, ``first + every``, ... in the order the fit splits them (file path as text, episode)."""
    ordered = sorted(trajectories, key=lambda t: (t.source, t.episode))
    return ordered[first::every]


def _set_folder(fit: PresetFit, logs: str | Path | None) -> Path:
    """The set's folder: ``logs`` itself, or its subfolder named after the set; one-line PresetError otherwise."""
    if logs is None or str(logs) == "":
        raise PresetError(
            f"give the folder of the public log set {fit.log_set} (DeepRacer's Gazebo logs are not shipped with "
            "racer: sim/cars/SOURCES.md says where to get them)"
        )
    path = Path(logs)
    if (path / fit.log_set).is_dir():
        return path / fit.log_set
    if not path.is_dir():
        raise PresetError(f"{path}: no such folder (give the folder of the public log set {fit.log_set})")
    return path


def fit_log_text(name: str, logs: str | Path | None) -> str:
    """The fit log of preset ``name`` made from ``logs`` (the set's folder, or the folder holding it): the plain
    CSV the preset was fitted on. PresetError or LogError (one line) if ``logs`` is not that set."""
    fit = preset_fit(name)
    folder = _set_folder(fit, logs)
    trajectories = read_logs(folder)
    if len(trajectories) != fit.episodes:
        raise PresetError(
            f"{folder}: {len(trajectories)} usable episodes, the log set {fit.log_set} has {fit.episodes}: "
            "not the logs the preset was fitted on"
        )
    chosen = select_episodes(trajectories, fit.first, fit.every)
    head = [
        f"# {fit.about}",
        f"# from {folder}: one episode in {fit.every} of the {fit.episodes} racer reads there (sorted by file and "
        f"episode, starting at index {fit.first}),",
        "# rounded to 0.1 ms, 1e-4 deg and m/s, 1 um and 1e-5 deg (sim.calibration.presets). Columns: see "
        "sim/calibration/logs.py.",
        f"# reference_point_m: {chosen[0].reference_point_m}",
    ]
    tracks = {tr.track for tr in chosen}
    if len(tracks) == 1 and None not in tracks:
        head.append(f"# track: {tracks.pop()}")
    lines = [*head, "time_s,steer_cmd_deg,speed_cmd_mps,x_m,y_m,heading_deg,episode"]
    for tr in chosen:
        columns = [getattr(tr, key) for key in DIGITS]
        for k in range(len(tr)):
            values = [f"{col[k]:.{digits}f}" for col, digits in zip(columns, DIGITS.values(), strict=True)]
            lines.append(",".join([*values, str(tr.episode)]))
    return "\n".join(lines) + "\n"


def write_fit_log(name: str, logs: str | Path | None, path: str | Path) -> Path:
    """Write the fit log of preset ``name`` (:func:`fit_log_text`) to ``path``."""
    path = Path(path)
    path.write_text(fit_log_text(name, logs))
    return path


def refit_preset(name: str, fit_log: str | Path) -> CarCalibration:
    """The preset's fitted effects fitted again, jointly from its design, on its fit log (written by
    :func:`write_fit_log`): the last step of the preset's fit, which gave the values in ``NAME.json``."""
    from sim.calibration.fit import refit

    fit = preset_fit(name)
    return refit(read_log(fit_log), CAR_PRESETS[name], load_calibration(design_path(name)), fit.max_windows)


def compare(name: str, refitted: CarCalibration) -> list[tuple[str, float, float, float]]:
    """``(effect.param, shipped, refitted, z)`` for each fitted value of the preset, ``z`` in shipped standard
    errors."""
    rows = []
    for effect in CAR_PRESETS[name].effects:
        for key, err in (effect.stderr or {}).items():
            shipped, got = effect.params[key], refitted.value(effect.name, key)
            rows.append((f"{effect.name}.{key}", shipped, got, (got - shipped) / err))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m sim.calibration.presets NAME LOGS``: write the fit log, refit, print shipped against refitted."""
    parser = argparse.ArgumentParser(
        prog="python -m sim.calibration.presets",
        description="Make a car preset's fit log from DeepRacer's public Gazebo logs and refit the preset on it.",
    )
    parser.add_argument("name", choices=list(PRESET_FITS), help="the preset")
    parser.add_argument("logs", nargs="?", help="the public log set's folder, or the folder that holds it")
    parser.add_argument("--fit-log", type=Path, help="write the fit log here (default: a temporary file)")
    parser.add_argument("--out", type=Path, help="write the refitted car here")
    parser.add_argument("--no-refit", action="store_true", help="only write the fit log")
    args = parser.parse_args(argv)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            fit_log = write_fit_log(args.name, args.logs, args.fit_log or Path(tmp) / f"{args.name}-fit.csv")
            if args.fit_log:
                print(f"wrote {fit_log}")
            if args.no_refit:
                return 0
            refitted = refit_preset(args.name, fit_log)
    except (PresetError, LogError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for label, shipped, got, z in compare(args.name, refitted):
        print(f"{label}: shipped {shipped:g}, refitted {got:.4f} ({z:+.2f} standard errors)")
    if args.out:
        save_calibration(refitted, args.out)
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
