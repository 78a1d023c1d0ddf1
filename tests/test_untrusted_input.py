"""Property-based tests: malformed protocol messages and malformed user files get the loader's own error (one line,
naming the file) or a valid result, never another exception that would crash a role process with a traceback."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from common.action_space import ActionSpaceError, load_action_space
from common.car_calibration import CalibrationError, load_calibration
from common.hyperparams import HyperparametersError, load_hyperparameters
from common.protocol import (
    Heartbeat,
    PolicyVersion,
    ProtocolError,
    Segment,
    decode_segment,
    encode_segment,
)
from racer.runconfig import RandomizationFileError, load_randomization
from sim.track import TrackError, load_track

OBS = (4, 5, 1)
SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats(allow_nan=True) | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=12,
)


def valid_fields(steps: int = 3) -> dict[str, bytes]:
    arrays = {
        "obs": np.zeros((steps, *OBS), np.uint8),
        "next_obs": np.zeros((1, *OBS), np.uint8),
        "actions": np.zeros(steps, np.int64),
        "rewards": np.ones(steps, np.float32),
        "terminated": np.zeros(steps, np.uint8),
        "truncated": np.zeros(steps, np.uint8),
        "logp": np.zeros(steps, np.float32),
        "values": np.zeros(steps, np.float32),
        "next_values": np.zeros(steps, np.float32),
        "episode_id": np.zeros(steps, np.int64),
    }
    return encode_segment(Segment("r", "w", 0, 0, arrays=arrays))


def decode(fields: dict) -> Segment | None:
    """Decode, accepting only ProtocolError as a failure; check what a decoded segment promises the trainer."""
    try:
        seg = decode_segment(fields, "r", OBS, 10)
    except ProtocolError:
        return None
    assert seg.arrays["obs"].shape[1:] == OBS
    assert np.isfinite(seg.arrays["rewards"]).all()
    for e in seg.episodes:  # the trainer averages these: they must be numbers
        assert all(isinstance(v, int | float) and not isinstance(v, bool) for v in (e.progress, e.reward, e.steps))
    return seg


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
@SETTINGS
@given(
    header_patch=st.dictionaries(
        st.sampled_from(
            [
                "schema",
                "kind",
                "run_id",
                "worker_id",
                "steps",
                "policy_version",
                "env_seed",
                "episodes",
                "created",
                "arrays",
                "extra",
            ]
        ),
        json_values,
        max_size=4,
    )
)
def test_decoder_refuses_malformed_headers_with_protocol_errors_only(header_patch):
    fields = valid_fields()
    header = {**json.loads(fields["header"]), **header_patch}
    fields["header"] = json.dumps(header).encode()
    decode(fields)


@SETTINGS
@given(
    episodes=st.lists(
        st.fixed_dictionaries(
            {
                "episode_id": json_values,
                "steps": json_values,
                "progress": json_values,
                "reward": json_values,
                "status": json_values,
            },
            optional={"track": json_values, "lap_time_s": json_values, "junk": json_values},
        ),
        max_size=3,
    )
)
def test_decoder_checks_episode_summaries(episodes):
    fields = valid_fields()
    fields["header"] = json.dumps({**json.loads(fields["header"]), "episodes": episodes}).encode()
    decode(fields)


@SETTINGS
@given(
    name=st.sampled_from(
        ["header", "a:frames", "a:frame_index", "a:actions", "a:rewards", "a:terminated", "a:episode_id"]
    ),
    data=st.binary(max_size=200),
)
def test_decoder_refuses_corrupt_fields(name, data):
    fields = valid_fields()
    fields[name] = data
    decode(fields)


@SETTINGS
@given(raw=st.binary(max_size=100) | json_values.map(lambda v: json.dumps(v).encode()))
def test_policy_version_and_heartbeat_parsers(raw):
    for parse in (PolicyVersion.from_json, Heartbeat.from_json):
        try:
            parsed = parse(raw)
        except ProtocolError:
            continue
        assert all(not isinstance(v, float) or np.isfinite(v) for v in parsed.__dict__.values())


@SETTINGS
@given(
    content=st.binary(max_size=120)
    | json_values.map(lambda v: json.dumps(v).encode())
    | st.fixed_dictionaries({"action_space": json_values}, optional={"action_space_type": json_values}).map(
        lambda v: json.dumps(v).encode()
    )
)
def test_action_space_loader(tmp_path, content):
    check_loader(tmp_path / "model_metadata.json", content, load_action_space, ActionSpaceError)


@SETTINGS
@given(
    content=st.binary(max_size=120)
    | st.dictionaries(
        st.sampled_from(["batch_size", "lr", "num_epochs", "discount_factor", "loss_type", "x"]),
        json_values,
        max_size=3,
    ).map(lambda v: json.dumps(v).encode())
)
def test_hyperparameters_loader(tmp_path, content):
    check_loader(tmp_path / "hyperparameters.json", content, load_hyperparameters, HyperparametersError)


@SETTINGS
@given(
    content=st.binary(max_size=120)
    | st.fixed_dictionaries({"effects": json_values}).map(lambda v: json.dumps(v).encode())
    | json_values.map(lambda v: json.dumps(v).encode())
)
def test_calibration_loader(tmp_path, content):
    check_loader(tmp_path / "car.json", content, load_calibration, CalibrationError)


@SETTINGS
@given(
    content=st.binary(max_size=120)
    | st.dictionaries(st.sampled_from(["friction", "lighting", "seed", "x"]), json_values, max_size=3).map(
        lambda v: json.dumps(v).encode()
    )
)
def test_randomization_loader(tmp_path, content):
    check_loader(tmp_path / "randomization.json", content, load_randomization, RandomizationFileError)


@SETTINGS
@given(content=st.binary(max_size=200))
def test_track_loader_with_garbage_bytes(tmp_path, content):
    check_loader(tmp_path / "track.npy", content, load_track, TrackError)


@SETTINGS
@given(
    points=st.lists(st.floats(allow_nan=True, allow_infinity=True, width=32), max_size=60),
    cols=st.sampled_from([2, 4, 6, 7]),
)
def test_track_loader_with_malformed_arrays(tmp_path, points, cols):
    arr = np.asarray(points[: len(points) // cols * cols], dtype=np.float64).reshape(-1, cols)
    path = tmp_path / "track.npy"
    np.save(path, arr)
    check_loader(path, path.read_bytes(), load_track, TrackError)


def check_loader(path: Path, content: bytes, loader, error: type[Exception]) -> None:
    """The loader returns, or raises ``error`` with a one-line message naming the file."""
    path.write_bytes(content)
    try:
        loader(path)
    except error as exc:
        message = str(exc)
        assert "\n" not in message, message
        assert path.name in message, message


def test_a_key_with_a_newline_is_quoted_so_the_error_stays_one_line(tmp_path):
    """Found by hypothesis: ``{"\\n": null}`` in a car.json printed its key raw, splitting the error over two lines."""
    check_loader(tmp_path / "car.json", b'{"\\n": null}', load_calibration, CalibrationError)
    from common.errors import error_location

    assert error_location(["a", "\n", 0, ""]) == "a.'\\n'.0.''"
