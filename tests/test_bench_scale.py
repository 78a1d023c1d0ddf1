"""``racer bench scale`` (racer/bench/scale.py): real segments replayed by synthetic workers into a real Redis and
the real trainer, at 1 and 4 workers' load; and the re-stamped entries the trainer reads are valid segments."""

from __future__ import annotations

import json

import numpy as np
import pytest
import redis

from common.bus import Bus
from common.errors import OptionError
from common.protocol import decode_segment, encode_segment
from racer.bench.scale import ScaleSettings, bench_scale, restamp, scale_summary, scale_table
from tests.test_protocol import OBS, make_segment

LEVEL_KEYS = {
    "workers",
    "intake_steps_per_s",
    "redis_mb",
    "redis_peak_mb",
    "redis_cpu_s",
    "staleness_versions",
    "dropped",
    "pushed_steps_per_s",
    "offered_steps_per_s",
    "updates",
}


def test_restamp_changes_the_header_only_and_the_trainer_can_read_it():
    seg = make_segment()
    fields = encode_segment(seg)
    out = restamp(fields, "synthetic-7", 5, 123.5)
    assert all(out[k] is fields[k] for k in fields if k != "header")  # the arrays are not re-encoded
    back = decode_segment(out, seg.run_id, OBS, 10)
    assert (back.worker_id, back.policy_version, back.created) == ("synthetic-7", 5, 123.5)
    assert back.episodes == seg.episodes and np.array_equal(back.arrays["obs"], seg.arrays["obs"])


def test_bus_reports_the_redis_servers_cpu_time(redis_url, run_id):
    bus = Bus(redis.Redis.from_url(redis_url), run_id)
    before = bus.cpu_seconds()
    for _ in range(2000):
        bus.segments_queued()
    assert bus.cpu_seconds() > before >= 0.0


@pytest.mark.parametrize(
    ("levels", "rate", "settings", "option"),
    [
        ([0], None, None, "--levels"),
        ([1], 0.0, None, "--rate"),
        ([1], None, ScaleSettings(max_policy_lag=0), "--max-policy-lag"),
    ],
)
def test_bad_levels_rate_or_lag_are_one_clear_error(levels, rate, settings, option):
    with pytest.raises(OptionError, match=option):
        bench_scale(levels, 1.0, rate, settings)


@pytest.mark.slow(reason="two levels of the real trainer, each until two updates have finished: a minute or more")
def test_bench_scale_at_1_and_4_workers(tmp_path):
    hp = tmp_path / "hyperparameters.json"  # short updates, so that a few seconds hold some
    hp.write_text(json.dumps({"batch_size": 32, "num_epochs": 1, "num_episodes_between_training": 2}))
    result = bench_scale([1, 4], 2.0, settings=ScaleSettings(hyperparams=str(hp), record_steps=128))
    assert [lv["workers"] for lv in result["levels"]] == [1, 4]
    for lv in result["levels"]:
        assert lv.keys() >= LEVEL_KEYS, lv
        assert lv["intake_steps_per_s"] > 0 and lv["updates"] >= 1, lv
        assert lv["redis_mb"] > 0 and lv["redis_peak_mb"] >= lv["redis_mb"] and lv["redis_cpu_s"] > 0, lv
        assert lv["staleness_versions"] >= 0, lv
        assert lv["dropped"] and all(isinstance(n, int) and n >= 0 for n in lv["dropped"].values()), lv
        assert lv["pushed_steps_per_s"] > 0, lv
    # Four workers offer four times one worker's load.
    one, four = result["levels"]
    assert four["offered_steps_per_s"] == pytest.approx(4 * one["offered_steps_per_s"])
    # At most a raw 160×120 frame per step plus the per-step arrays (less if segments are compressed); the policy's
    # weights are megabytes.
    assert 0 < result["bytes_per_step_up"] < 2 * 120 * 160, result["bytes_per_step_up"]
    assert result["bytes_per_policy"] > 1e6, result["bytes_per_policy"]
    assert result["worker_steps_per_s"] > 0 and result["recorded_episodes"] >= 1
    # One epoch over the default CNN: tens of MFLOP forward per step, about three times that with the backward pass.
    assert 5e7 < result["update_flops_per_step"] < 1e9, result["update_flops_per_step"]
    assert result["intake_stops_growing_at"] in (1, 4)
    assert all(0 < lv["trainer_busy_fraction"] < 1.5 for lv in result["levels"])
    json.dumps(result)  # the JSON written by --json
    assert scale_table(result).row_count == 2 and "bytes up per env step" in scale_summary(result)
