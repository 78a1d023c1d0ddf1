"""Shared fixtures: real servers started by the tests (never the machine's own Redis on 6379)."""

import os
import tempfile
import uuid

import boto3
import pytest
import redis
from moto.server import ThreadedMotoServer

from common.tensorboard import tensorboard_without_tensorflow
from racer.embedded_redis import EmbeddedRedis, free_port
from tests.shared_data import HAVE_DEEPRACER_TRACKS, SHARED_TRACKS

# TensorFlow's LLVM and Mesa's (MuJoCo's EGL renderer) cannot share a process (common/tensorboard.py): this process
# reads TensorBoard files without TensorFlow, and the tests that load TensorFlow (tests/deepracer_tf/) run in a
# pytest process of their own, which tests/test_deepracer_formats.py starts with RACER_TF_TESTS=1.
tensorboard_without_tensorflow()
collect_ignore = [] if os.environ.get("RACER_TF_TESTS") else ["deepracer_tf"]

# DeepRacer's tracks by name, for the tests and every process they start: the shared folder's routes read in place
# when it is there, an empty folder otherwise (never the user's own ~/.cache/racer/tracks). Set at import, before
# collection, because some tests parametrize over track names.
os.environ["RACER_TRACKS_DIR"] = (
    str(SHARED_TRACKS) if HAVE_DEEPRACER_TRACKS else tempfile.mkdtemp(prefix="racer-tracks-")
)

S3_BUCKET = "racer-it"


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "slow(reason): over 2 s of real time on a 2-core machine (real processes, trainings, a browser, Docker, "
        "TensorFlow); a bare `pytest` leaves it out, `pytest -m slow` runs it, .ci/run runs both",
    )


def _bare_run(config) -> bool:
    """``pytest`` with neither paths nor ``-m``: the README's test command, the fast tests."""
    return not config.option.markexpr and config.args_source == pytest.Config.ArgsSource.TESTPATHS


def pytest_collection_modifyitems(config, items):
    """A bare run leaves the slow tests out; named files or tests, or any ``-m``, run as asked."""
    if not _bare_run(config):
        return
    slow = [item for item in items if item.get_closest_marker("slow")]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if not item.get_closest_marker("slow")]


def pytest_terminal_summary(terminalreporter, config):
    if _bare_run(config) and terminalreporter.stats.get("deselected"):
        n = len(terminalreporter.stats["deselected"])
        terminalreporter.write_line(f"{n} slow tests left out: `pytest -m slow` runs them (README: Tests)")


@pytest.fixture(scope="session", autouse=True)
def racer_cache_dir(tmp_path_factory):
    """The tests' own cache folder (racer limit's measured car limits), for them and the processes they start:
    never the user's ~/.cache."""
    with pytest.MonkeyPatch.context() as patch:
        folder = tmp_path_factory.mktemp("racer-cache")
        patch.setenv("RACER_CACHE_DIR", str(folder))
        yield folder


@pytest.fixture(autouse=True)
def _trainers_stop_beating(monkeypatch):
    """A Trainer a test starts in this process stops its heartbeat thread when the test ends (``run_trainer`` stops
    it in the product): otherwise each would beat on into the session's Redis for the rest of the session. Only the
    heartbeat: a module's shared trainer goes on training."""
    from trainer.process import Trainer

    started, start = [], Trainer.start

    def recorded(self: Trainer) -> None:
        started.append(self)
        start(self)

    monkeypatch.setattr(Trainer, "start", recorded)
    yield
    for trainer in started:
        trainer.liveness.stop()


@pytest.fixture(scope="session")
def redis_server():
    """A redis-server started for this test session on a free port; stopped at the end."""
    server = EmbeddedRedis(port=free_port())
    yield server
    server.stop()


@pytest.fixture
def redis_url(redis_server):
    """URL of the session's Redis, emptied before each test (it is our own server, so flushing is safe)."""
    redis.Redis.from_url(redis_server.url).flushall()
    return redis_server.url


@pytest.fixture
def run_id():
    """A fresh run id per test."""
    return f"t-{uuid.uuid4().hex[:10]}"


@pytest.fixture(scope="session")
def s3_server():
    """moto's S3 server over HTTP on a free port with one bucket, and fake credentials in the environment."""
    with pytest.MonkeyPatch.context() as mp:
        for name in ("AWS_ENDPOINT_URL", "AWS_ENDPOINT_URL_S3", "AWS_PROFILE", "AWS_SESSION_TOKEN"):
            mp.delenv(name, raising=False)
        mp.setenv("AWS_SHARED_CREDENTIALS_FILE", "/nonexistent/credentials")
        mp.setenv("AWS_CONFIG_FILE", "/nonexistent/config")
        mp.setenv("AWS_ACCESS_KEY_ID", "testing")
        mp.setenv("AWS_SECRET_ACCESS_KEY", "testing-secret")
        mp.setenv("AWS_DEFAULT_REGION", "us-east-1")
        server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
        server.start()
        host, port = server.get_host_and_port()
        endpoint = f"http://{host}:{port}"
        boto3.client("s3", endpoint_url=endpoint).create_bucket(Bucket=S3_BUCKET)
        yield endpoint
        server.stop()
