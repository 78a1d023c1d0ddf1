"""A soak run of ``racer train`` (90 s, 2 workers, many short iterations): Redis memory, Redis keys, the segment
stream and each role's memory stay bounded. ``racer bench soak --duration 10m`` runs the same for longer."""

import pytest

from racer.bench.soak import bench_soak

SEGMENT_MB = 16 * 120 * 160 / 2**20  # one 16-step segment of 160×120 frames


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_soak_keeps_redis_and_process_memory_bounded():
    result = bench_soak(90, workers=2, stream_maxlen=16, every_s=2.0)
    assert result["iterations"] >= 20, result["iterations"]  # many updates, checkpoints and prunings happened
    assert result["stream_len_max"] <= 16 + 1, result["stream_len_max"]
    # Redis holds at most a capped stream plus a few small keys (an empty Redis uses ~1 MB).
    assert result["redis_used_mb_max"] < 2 + 17 * SEGMENT_MB, result["redis_used_mb_max"]
    assert result["redis_keys_max"] <= 8, result["samples"][-1]
    # Peak memory has stopped growing: within 5 % over the last third of the run.
    assert result["trainer_rss_growth_last_third"] is not None and result["trainer_rss_growth_last_third"] <= 0.05
    assert result["worker_rss_growth_last_third"] is not None and result["worker_rss_growth_last_third"] <= 0.05
