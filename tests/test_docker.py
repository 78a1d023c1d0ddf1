"""docker-compose.yml for real: deploy/cluster/check-compose.sh (docker compose, from nothing: image builds, 3 then 5
workers, a killed worker, racer models ls, down and up again) and deploy/cluster/check-swarm.sh (docker stack deploy
on a one-node swarm, docker service scale). Minutes each; skipped where no Docker daemon answers (CI may have none).
The swarm check reuses the images the compose check built; everything is removed at the end."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TAG = f"pytest-{os.getpid()}"
BASE = os.environ.get("RACER_TEST_BASE", "racer-base:bookworm")
IMAGES = [f"racer-test:{TAG}", *(f"racer-standin-{s}:{TAG}" for s in ("s3", "redis", "python"))]


def why_no_docker() -> str | None:
    if shutil.which("docker") is None:
        return "docker is not installed"
    try:
        info = subprocess.run(["docker", "info"], capture_output=True, text=True, timeout=30)
    except subprocess.TimeoutExpired:
        return "docker info did not answer in 30 s"
    if info.returncode != 0:
        return "no Docker daemon answers (docker info failed): " + (info.stderr.strip().splitlines() or ["?"])[-1]
    return None


NO_DOCKER = why_no_docker()
pytestmark = [
    pytest.mark.skipif(NO_DOCKER is not None, reason=str(NO_DOCKER)),
    pytest.mark.slow(reason="builds images and runs compose and a swarm on a real Docker engine"),
]


def image_exists(image: str) -> bool:
    return subprocess.run(["docker", "image", "inspect", image], capture_output=True).returncode == 0


@pytest.fixture(scope="module")
def images():
    """The images both checks use; removed afterwards (the base too, unless it was there before)."""
    base_was_there = image_exists(BASE)
    yield
    for image in IMAGES + ([] if base_was_there else [BASE]):
        subprocess.run(["docker", "image", "rm", "-f", image], capture_output=True)


def run(script: str, *args: str) -> str:
    proc = subprocess.run(
        ["bash", str(ROOT / "deploy" / "cluster" / script), "--tag", TAG, *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        timeout=1800,
    )
    print(proc.stdout)  # the figures, in pytest's report of this test
    assert proc.returncode == 0, proc.stdout[-6000:]
    assert proc.stdout.rstrip().endswith("all checks passed")
    return proc.stdout


def test_compose_from_nothing(images):
    out = run("check-compose.sh", "--keep-images")
    assert "resumed at v" in out and "killed worker" in out


def test_swarm(images):
    state = subprocess.run(["docker", "info", "--format", "{{.Swarm.LocalNodeState}}"], capture_output=True, text=True)
    if state.stdout.strip() != "inactive":
        pytest.skip("this Docker node is already in a swarm: check-swarm.sh does not touch it")
    out = run("check-swarm.sh", "--reuse-images")
    assert "replicas:" in out and "5/5" in out
