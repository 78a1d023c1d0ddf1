"""sim.calibration.values: the report's values in their physical sense, against hand-computed figures."""

from __future__ import annotations

import pytest

from common.car_calibration import CarCalibration
from sim.calibration.values import describe, determined


def test_total_delay_counts_half_the_rate_limits_ramp_over_the_logs_step():
    cal = CarCalibration.from_values(
        {"steering_delay": {"delay_s": 0.05}, "steering_lag": {"tau_s": 0.1}, "steering_rate": {"s_per_60deg": 0.3}},
        {"steering_lag": {"tau_s": 0.03}, "steering_rate": {"s_per_60deg": 0.06}},
    )
    # A 20° step slews for 20/60 · 0.3 = 0.1 s: its mean delay is half that, after the dead time and the lag.
    out = determined(cal, "steering_rate", 1.0, {"steering": 20.0, "speed": 0.5})
    assert out["steering_total_delay_s"] == pytest.approx(0.05 + 0.1 + 0.05)
    assert out["stderr"] == pytest.approx((0.03**2 + (20 / 60 / 2 * 0.06) ** 2) ** 0.5, abs=1e-5)
    assert out["at_step"] == 20.0


def test_speed_rate_is_reported_as_seconds_per_mps_with_its_partner_total():
    cal = CarCalibration.from_values({"speed_rate": {"s_per_mps": 0.25}}, {"speed_rate": {"s_per_mps": 0.01}})
    (entry,) = describe(
        cal, ["speed_rate"], ambiguous={"speed_rate": ["speed_lag"]}, steps={"steering": 15, "speed": 1}
    )
    assert entry["value"] == 0.25 and entry["unit"] == "s/(m/s)"
    assert entry["interval_95"] == pytest.approx([0.25 - 1.96 * 0.01, 0.25 + 1.96 * 0.01])
    assert entry["ambiguous_with"] == ["speed_lag"]
    assert entry["determined"]["speed_total_delay_s"] == pytest.approx(0.125)  # half of 1 m/s at 4 m/s²
