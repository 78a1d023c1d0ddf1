"""racer/bench/wire.py: the wire figures it reports are of segments that decode bit for bit, and add up."""

from common.protocol import encode_segment
from racer.bench.wire import (
    codec_figures,
    driven_segments,
    policy_figures,
    schema1_bytes,
    segment_figures,
    wire_bytes,
)


def test_segment_and_codec_figures_of_a_stacked_run():
    segments = driven_segments(steps=8, segments=2, stack_size=2)
    assert [s.arrays["obs"].shape for s in segments] == [(8, 120, 160, 2)] * 2
    # Schema 1 carried every observation whole: 2 frames per observation, next_obs included.
    assert schema1_bytes(segments[0]) > 9 * 2 * 19200 > wire_bytes(encode_segment(segments[0]))
    figures = segment_figures(segments, repeats=1)
    assert abs(figures["bytes_per_step_before"] / figures["bytes_per_step"] - figures["ratio"]) < 0.01
    assert figures["ratio"] > 2 and figures["encode_us_per_step"] > 0 and figures["decode_us_per_step"] > 0
    codecs = codec_figures(segments, repeats=1)
    # Each observation adds one frame. The first segment starts an episode (o_0 is its first frame twice): 9
    # frames; the second starts mid-episode (o_0 holds 2 frames): 10.
    assert codecs["raw"]["bytes_per_step"] == (9 + 10) * 19200 / 16
    for name in ("zstd1", "zstd3", "lz4", "zlib1", "delta+zstd1"):
        assert 0 < codecs[name]["bytes_per_step"] < codecs["raw"]["bytes_per_step"], name


def test_policy_figures_compare_the_checkpoint_with_the_acting_copy():
    figures = policy_figures(repeats=1)
    assert figures["acting_bytes"] <= 12_000_000 < figures["checkpoint_bytes"]
    assert 1.9 < figures["ratio"] < 2.1
