"""racer's DeepRacer model formats (``tests/deepracer_tf/``), run in a pytest process of their own.

They load TensorFlow, whose LLVM and Mesa's (MuJoCo's EGL renderer, which other tests in this process use) cannot
share a process (``common/tensorboard.py``). To run them alone:
``RACER_TF_TESTS=1 python -m pytest tests/deepracer_tf``.
"""

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow(reason="converts with TensorFlow and OpenVINO")
@pytest.mark.skipif(
    importlib.util.find_spec("tensorflow") is None,
    reason="tensorflow is not installed (pip install 'racer[deepracer]')",
)
def test_the_deepracer_format_tests_pass_in_a_process_of_their_own() -> None:
    env = {**os.environ, "RACER_TF_TESTS": "1"}
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/deepracer_tf"]
    result = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)
    lines = result.stdout.strip().splitlines()
    summary = lines[-1] if lines else ""
    assert result.returncode == 0, result.stdout[-6000:] + result.stderr[-2000:]
    assert "passed" in summary and "failed" not in summary and "error" not in summary, summary
    print(summary)  # in the -rA / -s report: how many ran there


def test_the_pytest_process_keeps_tensorflow_out_of_tensorboard() -> None:
    """What lets MuJoCo's EGL renderer and TensorBoard's readers share this process with TensorFlow installed."""
    code = (
        "import sys; from common.tensorboard import tensorboard_without_tensorflow as f; f();"
        "from torch.utils.tensorboard import SummaryWriter; import tensorboard.compat as c; c.tf.__name__;"
        "sys.exit('tensorflow' in sys.modules)"
    )
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT, timeout=300).returncode == 0
