"""The API page (docs/api.md): built exactly as .ci/run builds it, into a temporary folder, naming what users import."""

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _ci_pdoc_args() -> list[str]:
    """The arguments after ``-m pdoc`` on .ci/run's pdoc line, so the test builds what CI builds."""
    line = next(line for line in (ROOT / ".ci/run").read_text().splitlines() if " -m pdoc " in line)
    args = shlex.split(line.split(" -m pdoc ", 1)[1])
    out = args.index("-o")
    return args[:out] + args[out + 2 :]  # without .ci/run's output folder


@pytest.mark.slow(reason="starts real racer processes")
def test_the_api_page_builds_and_names_the_env_its_config_the_reward_params_and_entry_points(tmp_path: Path) -> None:
    env = {**os.environ, "PDOC_ALLOW_EXEC": "1", "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-W", "error::UserWarning", "-m", "pdoc", "-o", str(tmp_path), *_ci_pdoc_args()]
    result = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    pages = {p.relative_to(tmp_path).as_posix(): p.read_text() for p in tmp_path.rglob("*.html")}
    expected = {
        "sim.html": ["Racer-v0"],
        "sim/env.html": ["RacerEnv", "make_env"],
        "common/config.html": ["EnvConfig", "RandomizationConfig", "RunConfig"],
        "common/race.html": ["RaceConfig"],
        "common/hyperparams.html": ["Hyperparameters"],
        "sim/reward.html": ["PARAM_KEYS", "all_wheels_on_track", "load_reward_function"],
        "racer/limit.html": ["compute_limit"],
        "racer/evaluate.html": ["run_eval"],
    }
    for page, names in expected.items():
        assert page in pages, sorted(pages)
        missing = [name for name in names if not re.search(rf"\b{re.escape(name)}\b", pages[page])]
        assert not missing, (page, missing)
    # Only the chosen modules get a page: sim's internals (physics, camera, ...) stay out of the user's reference.
    assert "sim/physics.html" not in pages and "racer/launcher.html" not in pages
