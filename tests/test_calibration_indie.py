"""``racer calibrate`` on logs from a car that is not racer's: the independent model of ``tests/indie_car.py``.

That car (a dynamic bicycle with saturating tyres, its own servo and motor, none of racer's code) differs from
racer's MuJoCo car in kind, so the calibration must fit its base (grip, geometry, speed scale) apart from the
undeclared effect, report the effect's value in its physical sense within 10 % of what was injected, and, where
it cannot tell a dead time from a lag, say so rather than give a confident split. 45 episodes of 100 rows of
DeepRacer-like actions, as one training log. An effect outside racer's library must leave a structured residual
and no confident value. What this car still defeats (offset, saturation, understeer, a speed dead time) is
listed in docs/calibration.md.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from sim.calibration import read_log
from sim.calibration.fit import calibrate
from tests.indie_car import Effects, write_log

pytestmark = pytest.mark.slow(reason="one calibration of a 45-episode log each: about a minute on one core")


def _calibrate(tmp_path: Path, effects: dict[str, float]) -> dict:
    log = write_log(tmp_path / "indie.csv", Effects.of(effects), episodes=45, steps=100, seed=1)
    return calibrate(read_log(log), progress=lambda _: None).report


def _by_name(entries: list[dict]) -> dict[str, dict]:
    return {e["name"]: e for e in entries}


@pytest.mark.slow(reason="fits a car to logs")
def test_a_clean_independent_car_gets_a_base_and_no_effect(tmp_path):
    report = _calibrate(tmp_path, {})
    assert report["effects"] == [], report["effects"]
    base = _by_name(report["base"])
    assert "tyre_friction" in base  # the other car grips differently: that is the car, not an effect
    assert all("value" in e and "interval_95" in e for e in report["base"])
    assert report["error_after"]["position_m"] < report["error_before"]["position_m"]


@pytest.mark.slow(reason="fits a car to logs")
@pytest.mark.parametrize(
    "injected",
    [{"steering_gain": 0.6}, {"steering_lag": 0.3}, {"speed_gain": 0.8}, {"steering_lag": 0.25, "speed_lag": 0.3}],
    ids=["steering_gain", "steering_lag", "speed_gain", "steering_and_speed_lag"],
)
def test_an_undeclared_effect_is_named_and_measured_within_10_percent(tmp_path, injected):
    report = _calibrate(tmp_path, injected)
    found = _by_name(report["effects"])
    assert set(found) == set(injected), sorted(found)
    for name, value in injected.items():
        entry = found[name]
        assert entry["value"] == pytest.approx(value, rel=0.10), (name, entry["value"])
        lo, hi = entry["interval_95"]
        assert lo < entry["value"] < hi and hi - lo < 0.5 * value  # an uncertainty, smaller than the value
        # DeepRacer's actions (held 1-4 rows, 2 speeds) hold no steady circle: a gain may be flagged as not told
        # apart from understeer or an offset, and then the report says what the data does fix.
        assert not entry.get("ambiguous_with") or entry["determined"]


@pytest.mark.slow(reason="fits a car to logs")
def test_a_dead_time_is_within_10_percent_or_flagged_with_its_total_delay(tmp_path):
    """A 0.2 s steering dead time on top of this car's own servo: either the dead time comes back within 10 %, or
    the report says it cannot tell it from a lag (and a rate limit, where one was fitted beside them) and gives
    the total delay instead of a confident split."""
    report = _calibrate(tmp_path, {"steering_delay": 0.2})
    found = _by_name(report["effects"])
    assert "steering_delay" in found, sorted(found)
    delay = found["steering_delay"]
    if delay["value"] != pytest.approx(0.2, rel=0.10):
        assert delay["ambiguous_with"] == ["steering_lag"], delay
        total = delay["determined"]["steering_total_delay_s"]
        # The dead time plus the lag (and rate) it was split into, and this car's own ~30 ms. Measured: 0.296 s with
        # a 0.13 s dead time, a 0.12 s lag and a 0.27 s/60° rate over a 20° step; 0.24 s before the rate existed.
        assert 0.2 <= total <= 0.3
    assert set(found) <= {"steering_delay", "steering_lag", "steering_rate"}
    if "steering_rate" in found:  # a rate beside the lag is one more split of the same delay, and said so
        assert found["steering_rate"]["ambiguous_with"] == ["steering_lag"]
        assert "steering_rate" in found["steering_lag"]["ambiguous_with"]


@pytest.mark.slow(reason="fits a car to logs")
def test_a_servo_slew_rate_is_found_as_its_seconds_per_60_degrees(tmp_path):
    """A servo that turns at most 120°/s (this car's own parameter): racer's ``steering_rate`` gives it as the
    datasheet's 0.5 s/60°, within 10 %, or, where it cannot tell it from a lag, says so with the total delay."""
    report = _calibrate(tmp_path, {"steering_rate_limit": 120.0})
    found = _by_name(report["effects"])
    assert "steering_rate" in found, sorted(found)
    rate = found["steering_rate"]
    assert rate["unit"] == "s/60°"
    if rate["value"] != pytest.approx(0.5, rel=0.10):
        assert rate["ambiguous_with"] == ["steering_lag"], rate
        assert rate["determined"]["steering_total_delay_s"] > 0
    assert set(found) <= {"steering_rate", "steering_lag"}


@pytest.mark.slow(reason="fits a car to logs")
@pytest.mark.parametrize(
    "injected",
    [{"steering_backlash": 3.0}, {"steering_asymmetry": 0.7}],
    ids=["backlash", "asymmetry"],
)
def test_an_effect_outside_the_library_leaves_a_structured_residual_and_no_confident_value(tmp_path, injected):
    """A ±3° steering play, or right turns at 0.7 of the left's angle: racer's library has neither. The report
    must say that what is left is structure, say where, and give whatever nearest effect it fitted as provisional
    only."""
    report = _calibrate(tmp_path, injected)
    residual = report["residual"]
    assert residual["structured"] is True
    assert residual["where"] and all(w["says"] for w in residual["where"])
    assert all(e.get("provisional") for e in report["effects"]), report["effects"]
