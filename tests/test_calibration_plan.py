"""sim.calibration.plan: the system-identification drives, and which effects given logs can identify.

The logs are built by hand: command sequences (holds of one command, steps) driven by a kinematic bicycle at
15 Hz, so each test controls exactly which excitation the logs hold.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.car_calibration import CANDIDATE_EFFECTS, EFFECTS
from sim.calibration.logs import PLAIN_COLUMNS, Trajectory
from sim.calibration.plan import (
    HOLD_S,
    MANOEUVRES,
    MIN_CONDITION_ROWS,
    MIN_STEPS,
    command_steps,
    identifiability,
    pairs_confounded,
    plan_text,
)
from sim.calibration.values import DEFAULT_STEPS
from sim.physics import WHEELBASE_M

HZ = 15.0


def drive(segments: list[tuple[float, float, float]], hz: float = HZ) -> Trajectory:
    """A log of (steer deg, speed m/s, seconds) segments driven by a kinematic bicycle that obeys at once."""
    steer = np.concatenate([np.full(round(s * hz), d) for d, _, s in segments])
    speed = np.concatenate([np.full(round(s * hz), v) for _, v, s in segments])
    n, dt = len(steer), 1.0 / hz
    x, y, h = np.zeros(n), np.zeros(n), np.zeros(n)
    for k in range(n - 1):  # row k's command drives the car from sample k to k+1
        x[k + 1] = x[k] + speed[k] * math.cos(h[k]) * dt
        y[k + 1] = y[k] + speed[k] * math.sin(h[k]) * dt
        h[k + 1] = h[k] + speed[k] * math.tan(math.radians(steer[k])) / WHEELBASE_M * dt
    heading = np.degrees(np.angle(np.exp(1j * h)))
    return Trajectory(
        "test", 0, np.arange(n) * dt, steer_cmd_deg=steer, speed_cmd_mps=speed, x=x, y=y, heading_deg=heading
    )


def circles(steers: tuple[float, ...], speeds: tuple[float, ...], seconds: float = 3.0) -> Trajectory:
    """Steady circles: each steering angle at each speed, held ``seconds``."""
    return drive([(d, v, seconds) for v in speeds for d in steers])


def verdicts(trajectories: list[Trajectory]) -> dict[str, dict]:
    return {e["effect"]: e for e in identifiability(trajectories)}


def full_plan() -> list[Trajectory]:
    """Logs of every manoeuvre of the plan, short versions."""
    steps = [(10.0 if k % 2 else 25.0, 1.0, 1.0) for k in range(12)]
    large_steps = [(20.0 if k % 2 else -20.0, 1.0, 1.0) for k in range(12)]
    speed_steps = [(0.0, 1.5 if k % 2 else 0.5, 1.5) for k in range(12)]
    large_speed_steps = [(0.0, 2.5 if k % 2 else 0.5, 1.5) for k in range(12)]
    return [
        circles((15.0, -15.0, 10.0, -10.0), (0.5, 1.0, 1.5)),
        circles((30.0, -30.0, 20.0), (0.5, 1.0)),
        drive(steps),
        drive(large_steps),
        circles((0.0,), (0.5, 1.0, 1.5, 2.0)),
        drive(speed_steps),
        drive(large_speed_steps),
        circles((20.0, -20.0), (1.5, 2.0)),
    ]


def test_the_plan_covers_every_candidate_effect_and_the_log_format():
    text = plan_text()
    assert {e for m in MANOEUVRES for e in m.identifies} == set(CANDIDATE_EFFECTS)
    assert all(e in EFFECTS for m in MANOEUVRES for e in m.identifies)
    for effect in CANDIDATE_EFFECTS:
        assert effect in text, effect
    for m in MANOEUVRES:
        assert m.name in text and m.why and "m/s" in m.drive and "°" in m.drive
    assert ",".join(PLAIN_COLUMNS) in text


def test_every_missing_excitation_names_a_manoeuvre_that_identifies_it():
    entries = identifiability([])
    assert [e["effect"] for e in entries] == list(CANDIDATE_EFFECTS)
    by_name = {m.name: m for m in MANOEUVRES}
    for e in entries:
        assert not e["identifiable"] and e["needs"], e
        assert e["effect"] in by_name[e["drive"]].identifies, e


def test_circles_at_one_speed_confound_steering_gain_and_understeer():
    v = verdicts([circles((15.0, -15.0, 10.0, -10.0), (1.0,))])
    assert v["steering_gain"]["identifiable"]
    assert v["steering_offset"]["identifiable"]  # mirrored turns
    assert not v["understeer"]["identifiable"]
    assert v["understeer"]["drive"] == "steady circles at several speeds"
    assert v["understeer"]["evidence"]["speed_levels_mps"] == [1.0]
    assert ["steering_gain", "understeer"] in pairs_confounded([circles((15.0, 10.0), (1.0,))])


def test_circles_at_speeds_apart_identify_understeer():
    log = [circles((15.0, -15.0), (0.5, 1.0, 1.5))]
    v = verdicts(log)
    assert v["understeer"]["identifiable"]
    # Speeds from positions: the chord of a tight circle is a little shorter than its arc.
    assert v["understeer"]["evidence"]["speed_levels_mps"] == pytest.approx([0.5, 1.0, 1.5], abs=0.02)
    assert ["steering_gain", "understeer"] not in pairs_confounded(log)
    # Two speeds too close together are still one level.
    assert not verdicts([circles((15.0,), (1.0, 1.2))])["understeer"]["identifiable"]


def test_a_hold_shorter_than_the_settling_time_is_not_steady():
    seconds = 0.8 * HOLD_S
    # Alternate left and right so every hold is a new command, with enough rows in all.
    short = drive([(15.0 if k % 2 else -15.0, 1.0, seconds) for k in range(4 * MIN_CONDITION_ROWS)])
    assert verdicts([short])["steering_gain"]["evidence"]["steady_turn_rows"] == 0


def test_a_one_sided_turn_does_not_identify_the_offset():
    assert not verdicts([circles((15.0,), (1.0,))])["steering_offset"]["identifiable"]
    assert ["steering_offset", "steering_gain"] in pairs_confounded([circles((15.0,), (1.0,))])
    assert verdicts([circles((15.0, -15.0), (1.0,))])["steering_offset"]["identifiable"]
    assert verdicts([circles((0.0,), (1.0,))])["steering_offset"]["identifiable"]  # straight running


def test_steering_steps_separate_delay_from_lag_only_when_enough_and_fine_enough():
    def steps(n: int, hz: float = HZ) -> Trajectory:
        return drive([(10.0 if k % 2 else 25.0, 1.0, 1.0) for k in range(n + 1)], hz)

    few, enough = steps(MIN_STEPS - 1), steps(MIN_STEPS)
    assert verdicts([few])["steering_delay"]["evidence"]["steering_steps"] == MIN_STEPS - 1
    assert not verdicts([few])["steering_lag"]["identifiable"]
    assert ["steering_delay", "steering_lag"] in pairs_confounded([few])
    assert verdicts([enough])["steering_delay"]["identifiable"]
    assert ["steering_delay", "steering_lag"] not in pairs_confounded([enough])
    coarse = steps(MIN_STEPS, hz=5.0)  # 0.2 s rows hide a dead time inside one row
    assert verdicts([coarse])["steering_delay"]["identifiable"]
    assert ["steering_delay", "steering_lag"] in pairs_confounded([coarse])


def test_steps_of_two_sizes_tell_a_rate_limit_from_a_lag():
    """A rate limit stretches large steps and not small ones: steps of one size leave it confounded with the lag."""
    small = [(10.0 if k % 2 else 25.0, 1.0, 1.0) for k in range(MIN_STEPS + 1)]  # 15° steps
    large = [(20.0 if k % 2 else -20.0, 1.0, 1.0) for k in range(MIN_STEPS + 1)]  # 40° steps
    one_size = [drive(small)]
    assert not verdicts(one_size)["steering_rate"]["identifiable"]
    assert verdicts(one_size)["steering_rate"]["drive"] == "steering steps"
    assert ["steering_lag", "steering_rate"] in pairs_confounded(one_size)
    both = [drive(small), drive(large)]
    evidence = verdicts(both)["steering_rate"]["evidence"]
    assert evidence == {"large_steering_steps": MIN_STEPS, "small_steering_steps": MIN_STEPS}
    assert ["steering_lag", "steering_rate"] not in pairs_confounded(both)
    speed = [drive([(0.0, 1.5 if k % 2 else 0.5, 1.5) for k in range(MIN_STEPS + 1)])]
    assert ["speed_lag", "speed_rate"] in pairs_confounded(speed)
    speed.append(drive([(0.0, 2.5 if k % 2 else 0.5, 1.5) for k in range(MIN_STEPS + 1)]))
    assert verdicts(speed)["speed_rate"]["identifiable"]
    assert ["speed_lag", "speed_rate"] not in pairs_confounded(speed)


def test_command_steps_are_the_median_change_where_a_command_changes():
    log = drive([(10.0, 1.0, 1.0), (25.0, 1.0, 1.0), (10.0, 1.5, 1.0), (10.0, 2.5, 1.0)])
    assert command_steps([log]) == {"steering": 15.0, "speed": 0.75}
    assert command_steps([circles((10.0,), (1.0,))]) == DEFAULT_STEPS


def test_small_command_changes_are_not_steps():
    small = drive([(10.0 if k % 2 else 15.0, 1.0, 1.0) for k in range(2 * MIN_STEPS)])  # 5° < 10°
    assert verdicts([small])["steering_delay"]["evidence"]["steering_steps"] == 0
    small = drive([(0.0, 1.0 if k % 2 else 1.3, 1.0) for k in range(2 * MIN_STEPS)])  # 0.3 < 0.5 m/s
    assert verdicts([small])["speed_delay"]["evidence"]["speed_steps"] == 0


def test_steps_while_standing_still_do_not_count():
    standing = drive([(10.0 if k % 2 else 25.0, 0.0, 1.0) for k in range(2 * MIN_STEPS)])
    assert verdicts([standing])["steering_delay"]["evidence"]["steering_steps"] == 0


def test_speed_steps_and_straight_runs_identify_the_speed_effects():
    one_speed = [circles((0.0,), (1.0,), seconds=10.0)]
    v = verdicts(one_speed)
    assert not v["speed_gain"]["identifiable"] and v["speed_gain"]["drive"] == "straight runs at several speeds"
    assert not v["speed_delay"]["identifiable"]
    assert ["speed_delay", "speed_lag"] in pairs_confounded(one_speed)
    log = [drive([(0.0, 1.5 if k % 2 else 0.5, 1.5) for k in range(MIN_STEPS + 1)])]
    v = verdicts(log)
    assert v["speed_gain"]["identifiable"] and v["speed_lag"]["identifiable"]
    assert v["speed_delay"]["evidence"]["speed_steps"] == MIN_STEPS
    assert ["speed_delay", "speed_lag"] not in pairs_confounded(log)


def test_saturation_needs_commands_beyond_the_limit_and_below_it():
    small = [circles((10.0, 15.0), (1.0,))]
    assert not verdicts(small)["steering_saturation"]["identifiable"]
    assert ["steering_gain", "steering_saturation"] not in pairs_confounded(small)
    lock_only = [circles((30.0, 25.0), (1.0,))]
    assert verdicts(lock_only)["steering_saturation"]["identifiable"]
    assert ["steering_gain", "steering_saturation"] in pairs_confounded(lock_only)


def test_tyre_friction_needs_high_commanded_lateral_acceleration():
    slow = verdicts([circles((20.0, -20.0), (0.5,))])["tyre_friction"]  # 0.25·tan 20°/0.164 ≈ 0.55 m/s²
    assert not slow["identifiable"] and slow["drive"] == "high-speed circles"
    fast = verdicts([circles((20.0, -20.0), (2.0,))])["tyre_friction"]  # ≈ 8.9 m/s²
    assert fast["identifiable"] and fast["evidence"]["max_lateral_mps2"] > 8.0


def test_logs_of_the_whole_plan_identify_every_effect():
    logs = full_plan()
    v = verdicts(logs)
    assert [e for e, entry in v.items() if not entry["identifiable"]] == []
    assert all("needs" not in entry and "drive" not in entry for entry in v.values())
    assert pairs_confounded(logs) == []
