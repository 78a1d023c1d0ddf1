"""The car presets' fitted values follow from DeepRacer's public Gazebo logs and their design cars.

``sim.calibration.presets`` makes each preset's fit log from its public log set (read in place from ../shared/data,
never the holdout sets; these tests skip without it) and fits the preset's effects again, jointly from the design,
as the last step of the preset's fit did (sim/cars/SOURCES.md). The tests on the selection and the errors run on
sim-traces written here.
"""

import numpy as np
import pytest

from common.car_calibration import CAR_PRESETS, load_calibration
from sim.calibration import Trajectory, read_log, read_logs
from sim.calibration.presets import (
    DIGITS,
    PRESET_FITS,
    PresetError,
    PresetFit,
    compare,
    fit_log_text,
    main,
    select_episodes,
    write_fit_log,
)
from tests.shared_data import shared_data
from tests.test_calibration_logs import synthetic_simtrace, write_lines

TOLERANCE_SE = 1.0
"""How far, in the preset's own standard errors, a refitted value may land from the shipped one. On the same fit log
the refit is the same computation, so it lands on the shipped value up to its rounding to 4 digits (measured: within
0.04 standard errors); one standard error leaves room for floating-point differences between machines and still
catches what a change of the selection, the reader or the replay does: the same episodes split differently, or
unrounded, move the values by 7 to 22 standard errors (sim/calibration/presets.py)."""


@pytest.mark.slow(reason="20 s a preset on 2 idle cores, a minute under load: reads a whole log set, refits 3 effects")
@pytest.mark.parametrize("name", list(PRESET_FITS))
def test_refit_on_the_public_logs_lands_within_the_shipped_error_bars(name, tmp_path, capsys):
    """The documented command, ``python -m sim.calibration.presets NAME LOGS --fit-log F --out car.json``, on the
    public log set the preset was fitted on: each fitted value lands within TOLERANCE_SE of the shipped one."""
    fit = PRESET_FITS[name]
    logs = shared_data("logs", fit.log_set)
    fit_log, out = tmp_path / f"{name}-fit.csv", tmp_path / "car.json"
    assert main([name, str(logs.parent), "--fit-log", str(fit_log), "--out", str(out)]) == 0
    # The fit log: one episode in `every` of the whole set, its values those of the public logs, rounded.
    chosen = select_episodes(read_logs(logs), fit.first, fit.every)
    written = read_log(fit_log)
    assert [t.episode for t in written] == [t.episode for t in chosen]
    assert len(written) == len(range(fit.first, fit.episodes, fit.every))  # 50 of 552 (ROS1), 85 of 256 (ROS2)
    for a, b in zip(written, chosen, strict=True):
        for key, digits in DIGITS.items():
            np.testing.assert_allclose(getattr(a, key), getattr(b, key), rtol=0, atol=0.51 * 10.0**-digits)
    # The refit.
    rows = compare(name, load_calibration(out))
    assert {label.split(".")[0] for label, *_ in rows} == {e.name for e in CAR_PRESETS[name].effects if e.stderr}
    for label, shipped, got, z in rows:
        assert abs(z) <= TOLERANCE_SE, f"{label}: refitted {got}, shipped {shipped} ({z:+.2f} standard errors)"
    printed = capsys.readouterr().out
    assert all(f"{label}: shipped" in printed for label, *_ in rows)


def _trajectory(source: str, episode: int) -> Trajectory:
    t = np.arange(16) / 15
    return Trajectory(
        source,
        episode,
        t,
        steer_cmd_deg=0 * t,
        speed_cmd_mps=1 + 0 * t,
        x=t,
        y=0 * t,
        heading_deg=0 * t,
        reference_point_m=0.14,
    )


def test_selection_is_in_the_order_the_fit_splits_episodes():
    # By file path as text (10-iteration before 2-iteration), then episode number; not in the order read.
    trajectories = [_trajectory(f"s/{n}-iteration.csv", e) for n, e in [(2, 5), (2, 4), (10, 1), (10, 0), (1, 9)]]
    chosen = select_episodes(trajectories, first=1, every=2)
    assert [(t.source, t.episode) for t in chosen] == [("s/10-iteration.csv", 0), ("s/2-iteration.csv", 4)]


def test_fit_log_of_a_set(tmp_path, monkeypatch):
    folder = tmp_path / "gazebo-ros1-console2022-reinvent_base" / "training-simtrace"
    write_lines(folder / "0-iteration.csv", synthetic_simtrace((20, 21, 22)))
    write_lines(folder / "10-iteration.csv", synthetic_simtrace((23, 24, 25)))
    fit = PresetFit("gazebo-ros1-console2022-reinvent_base", episodes=6, first=1, every=2, about="synthetic")
    monkeypatch.setitem(PRESET_FITS, "deepracer-gazebo", fit)
    text = fit_log_text("deepracer-gazebo", tmp_path)  # the folder holding the set, or the set itself
    assert text == fit_log_text("deepracer-gazebo", tmp_path / fit.log_set)
    path = tmp_path / "fit.csv"
    path.write_text(text)
    first = text.splitlines()[6]  # after five comment lines and the header
    assert first.count(".") == 6 and len(first.split(",")[5].split(".")[1]) == DIGITS["heading_deg"]
    written = read_log(path)
    chosen = select_episodes(read_logs(tmp_path / fit.log_set), fit.first, fit.every)
    assert [len(t) for t in written] == [21, 23, 25]  # 0-iteration's 2nd episode, 10-iteration's 1st and 3rd
    for a, b in zip(written, chosen, strict=True):
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=5.1e-7)
        assert a.track == "reinvent_base" and a.reference_point_m == 0.14


def test_logs_not_given_or_not_the_set_are_one_line(tmp_path, capsys):
    def one_line(call, *parts):
        with pytest.raises(PresetError) as err:
            call()
        assert "\n" not in str(err.value) and all(p in str(err.value) for p in parts), str(err.value)

    one_line(lambda: fit_log_text("deepracer-gazebo", None), "gazebo-ros1-console2022-reinvent_base", "SOURCES.md")
    one_line(lambda: fit_log_text("deepracer-gazebo", tmp_path / "nope"), "no such folder")
    one_line(lambda: fit_log_text("default", tmp_path), "'default' is not a fitted car preset")
    write_lines(tmp_path / "gazebo-ros1-console2022-reinvent_base" / "0.csv", synthetic_simtrace((20,)))
    one_line(lambda: fit_log_text("deepracer-gazebo", tmp_path), "1 usable episodes", "has 552")
    assert main(["deepracer-gazebo-ros2"]) == 2  # no LOGS
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "gazebo-ros2-simapp6-reInvent2019_wide_cw" in err
    with pytest.raises(PresetError):
        write_fit_log("deepracer-gazebo", None, tmp_path / "fit.csv")
