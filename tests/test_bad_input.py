"""Bad input on the command line: one line on stderr naming the bad value, exit code 2, no traceback, and nothing
written (``racer train`` validates everything before it starts a process or creates a folder)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from model_store import RunStore, open_store
from tests.conftest import S3_BUCKET

FILES = {
    "syntax.py": "def reward_function(params):\n    return 1.0 +\n",
    "signature.py": "def reward_function(a, b):\n    return 1.0\n",
    "raises.py": "def reward_function(params):\n    return params['no_such_key']\n",
    "slow.py": "import time\ndef reward_function(params):\n    time.sleep(5)\n    return 1.0\n",
    "nan.py": "def reward_function(params):\n    return float('nan')\n",
    "none.py": "def reward_function(params):\n    return None\n",
    "broken.json": "{not json",
    "hp.json": '{"batch_size": -3}',
    "space.json": '{"action_space": [{"steering_angle": "left", "speed": 1}]}',
    "car.json": '{"effects": [{"name": "warp_drive", "params": {}}]}',
    "dr.json": '{"lighting": "bright"}',
    "track.npy": "not an array",
}

# (arguments after `racer`, text the one error line must contain)
TRAIN_CASES = [
    (["--reward-fn", "missing.py"], "'missing.py' does not exist"),
    (["--reward-fn", "syntax.py"], "'syntax.py' has a syntax error at line 2"),
    (["--reward-fn", "signature.py"], "reward_function(a, b)"),
    (["--reward-fn", "raises.py"], "'raises.py' at step 2 raised KeyError: 'no_such_key'"),
    (["--reward-fn", "slow.py"], "'slow.py' took longer than 1.0 s"),
    (["--reward-fn", "nan.py"], "'nan.py' at step 2 returned nan"),
    (["--reward-fn", "none.py"], "'none.py' at step 2 returned None"),
    (["--action-space", "broken.json"], "'broken.json' is not valid JSON"),
    (["--action-space", "space.json"], "'space.json'"),
    (["--hyperparams", "hp.json"], "batch_size = -3"),
    (["--track", "nope"], "unknown track 'nope'"),
    (["--track", "track.npy"], "track.npy"),
    (["--car-calibration", "car.json"], "warp_drive"),
    (["--randomization", "dr.json"], "'dr.json': lighting: Input should be a valid number"),
    (["--randomization", "missing.json"], "'missing.json' does not exist"),
    (["--workers", "0"], "Invalid value for '--workers': Input should be greater than or equal to 1 (got '0')"),
    (
        ["--workers", "two"],
        "Invalid value for '--workers': Input should be a valid integer, unable to parse string as an integer "
        "(got 'two')",
    ),
    (["--time-limit", "5parsecs"], "'5parsecs'"),
    (["--no-such-option"], "No such option: --no-such-option"),
    (["--store", "ftp://host/x"], "bad store URI 'ftp://host/x'"),
    (["--store", "s3://"], "bad store URI 's3://'"),
    (["--store", "s3://Bad_Bucket!"], "invalid bucket name 'Bad_Bucket!'"),
    (["--redis", "http://127.0.0.1:1"], "must start with redis://, rediss:// or unix://"),
    (["--redis", "redis://127.0.0.1:1/0"], "cannot reach Redis at redis://127.0.0.1:1/0"),
    (["--resume"], "--resume needs --run-id"),
    (["--resume", "--run-id", "never-ran"], "run 'never-ran' does not exist"),
]

OTHER_CASES = [
    (["worker", "--run-id", "a/b", "--redis", "redis://127.0.0.1:1/0"], "invalid run id 'a/b'"),
    (["eval", "--run-id", "never-ran"], "run 'never-ran' does not exist"),
    (["models", "ls", "--store", "s3://Bad_Bucket!"], "invalid bucket name"),
    (["models", "ls", "--json"], "Option '--json' requires an argument"),
    (["calibrate", "missing.csv"], "missing.csv"),
    (["calibrate", "--apply", "car.json", "broken.json"], "car.json"),
    (["no-such-command"], "No such command 'no-such-command'"),
]


def racer(args: list[str], cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "racer", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **(env or {})},
    )


@pytest.fixture
def workdir(tmp_path: Path) -> Path:
    for name, text in FILES.items():
        (tmp_path / name).write_text(text)
    return tmp_path


def assert_one_line_error(out: subprocess.CompletedProcess, expected: str) -> None:
    assert out.returncode == 2, (out.returncode, out.stdout, out.stderr)
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1, out.stderr
    assert lines[0].startswith("error: ") and expected in lines[0], lines[0]
    assert "Traceback" not in out.stdout + out.stderr


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize(("args", "expected"), TRAIN_CASES, ids=[" ".join(a) for a, _ in TRAIN_CASES])
def test_racer_train_refuses_bad_input_before_starting_anything(workdir, args, expected):
    out = racer(["train", "--time-limit", "60s", *args], workdir)
    assert_one_line_error(out, expected)
    assert not (workdir / "runs").exists(), "nothing may be written for a run that did not start"


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize(("args", "expected"), OTHER_CASES, ids=[" ".join(a) for a, _ in OTHER_CASES])
def test_other_commands_refuse_bad_input_in_one_line(workdir, args, expected):
    assert_one_line_error(racer(args, workdir), expected)


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_missing_bucket_and_missing_credentials_are_one_line(workdir, s3_server):
    store = ["--store", "s3://no-such-bucket-here/x", "--s3-endpoint", s3_server]
    assert_one_line_error(racer(["train", *store], workdir), "bucket 'no-such-bucket-here' does not exist")
    assert not (workdir / "runs").exists()
    no_creds = {
        "AWS_ACCESS_KEY_ID": "",
        "AWS_SECRET_ACCESS_KEY": "",
        "AWS_EC2_METADATA_DISABLED": "true",  # no instance-metadata lookup: this is not an EC2 machine
    }
    ls = ["models", "ls", "--store", f"s3://{S3_BUCKET}", "--s3-endpoint", s3_server]
    assert_one_line_error(racer(ls, workdir, no_creds), "no S3 credentials found")


def test_racer_train_will_not_start_over_an_existing_run(workdir):
    runs = RunStore(open_store(str(workdir)))
    runs.save_checkpoint("taken", 0, b"weights", {"env_steps": 5})
    before = sorted(p.relative_to(workdir) for p in (workdir / "runs").rglob("*"))
    out = racer(["train", "--run-id", "taken", "--time-limit", "60s"], workdir)
    assert_one_line_error(out, f"run 'taken' already exists in {workdir}: add --resume to continue it")
    assert sorted(p.relative_to(workdir) for p in (workdir / "runs").rglob("*")) == before
    assert runs.load_checkpoint("taken", "latest")[0] == b"weights"
