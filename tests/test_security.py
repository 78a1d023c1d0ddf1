"""Untrusted data and credentials: Redis with a password and over TLS, credentials kept out of output and logs,
and a checkpoint that would run code when unpickled refused end to end."""

from __future__ import annotations

import datetime
import io
import ipaddress
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import redis
import torch
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from common.defaults import STRAIGHT_TRACK
from common.keys import Keys
from common.protocol import PolicyVersion
from common.redis_util import RedisUrlError, connect_checked, redact
from common.weights import CheckpointError
from model_store import RunStore, open_store
from racer.embedded_redis import EmbeddedRedis, free_port
from racer.runconfig import build_run
from rollout_worker.worker import RolloutWorker, WorkerOptions
from tests.conftest import S3_BUCKET
from tests.faults import FAST_HP, trainer_and_worker

PASSWORD = "s3cret-Pw-123"


def racer(*args: str, cwd: Path, timeout: float = 120, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "racer", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
    )


def self_signed(tmp: Path) -> tuple[str, str]:
    """A certificate for 127.0.0.1 (its own CA) and its key, as PEM files."""
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "127.0.0.1")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=1))
        .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), False)
        .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
        .sign(key, hashes.SHA256())
    )
    cert_path, key_path = tmp / "redis.crt", tmp / "redis.key"
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_path.write_bytes(
        key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    )
    return str(cert_path), str(key_path)


@pytest.mark.parametrize("tls", [False, True], ids=["password", "password+tls"])
def test_roles_work_with_a_password_and_tls(tmp_path, caplog, tls):
    server = EmbeddedRedis(port=free_port(), password=PASSWORD, tls=self_signed(tmp_path) if tls else None)
    try:
        assert server.url.startswith("rediss://" if tls else "redis://")
        trainer, worker = trainer_and_worker(server.url, str(tmp_path / "store"), tmp_path, "secure")
        worker.push(worker.collect())
        assert trainer.read(block_ms=2000) == 1, "a segment went through the secured Redis"
        trainer.write_status()
        assert [w["worker_id"] for w in trainer.status()["workers"]] == [worker.worker_id]
        worker.close()
        assert PASSWORD not in caplog.text
    finally:
        server.stop()


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_wrong_or_missing_password_is_one_line_naming_the_url_without_the_password(tmp_path):
    server = EmbeddedRedis(port=free_port(), password=PASSWORD)
    try:
        wrong = f"redis://:not-{PASSWORD}@127.0.0.1:{server.port}/0"
        with pytest.raises(RedisUrlError) as err:
            connect_checked(wrong)
        assert f"127.0.0.1:{server.port}" in str(err.value) and PASSWORD not in str(err.value)
        with pytest.raises(RedisUrlError, match="refused the connection"):
            connect_checked(f"redis://127.0.0.1:{server.port}/0")
        out = racer("worker", "--run-id", "x", "--redis", wrong, cwd=tmp_path, timeout=60)
        assert out.returncode == 2
        lines = out.stderr.strip().splitlines()
        assert len(lines) == 1 and "redis://:***@127.0.0.1" in lines[0], out.stderr
        assert PASSWORD not in out.stdout + out.stderr and "Traceback" not in out.stderr
    finally:
        server.stop()


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_tls_url_to_a_plain_port_fails_in_one_line(tmp_path, redis_server):
    url = f"rediss://127.0.0.1:{redis_server.port}/0"
    with pytest.raises(RedisUrlError, match="cannot reach Redis at rediss://127.0.0.1"):
        connect_checked(url, wait_s=0.5)


def test_redact_hides_passwords_everywhere():
    assert redact("redis://:pw@h:1/0") == "redis://:***@h:1/0"
    assert redact("rediss://user:pw@h/0?ssl_ca_certs=/c.pem") == "rediss://user:***@h/0?ssl_ca_certs=/c.pem"
    assert redact("unix:///run/r.sock?password=pw&db=1") == "unix:///run/r.sock?password=***&db=1"
    assert redact("redis://h:6379/0") == "redis://h:6379/0"


@pytest.mark.slow(reason="over 2 s of real time on a 2-core machine")
def test_s3_credentials_never_appear_in_logs_or_models_ls(tmp_path, redis_url, s3_server):
    """A trainer with -v (debug logging) on S3, then racer models ls: neither shows the key id or the secret."""
    key_id, secret = "AKIARACERTESTKEY0001", "racer/test+Secret/value0123456789"
    env = {"AWS_ACCESS_KEY_ID": key_id, "AWS_SECRET_ACCESS_KEY": secret}
    store = f"s3://{S3_BUCKET}/creds"
    (tmp_path / "hp.json").write_text(json.dumps(FAST_HP))
    args = ["--store", store, "--s3-endpoint", s3_server]
    out = racer(
        "trainer", "--run-id", "creds", "--track", STRAIGHT_TRACK, "--hyperparams", "hp.json", "--redis", redis_url,
        "--time-limit", "3s", "-v", *args, cwd=tmp_path, env=env,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    listed = racer("models", "ls", "--json", "-", *args, cwd=tmp_path, env=env)
    assert listed.returncode == 0 and json.loads(listed.stdout)[0]["run_id"] == "creds"
    for text in (out.stdout + out.stderr, listed.stdout + listed.stderr):
        assert key_id not in text and secret not in text
    assert "creds" in out.stderr  # the log was there to read


class _Bomb:
    """Creates a directory when unpickled: any loader that unpickles arbitrary objects would run it."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.makedirs, (str(self.marker),))


def plant_bomb(store: str, run_id: str, marker: Path) -> None:
    """A run whose checkpoint 0 is a pickle that runs code, with valid metadata and pointers."""
    runs = RunStore(open_store(store))
    run, files = build_run(run_id, track=STRAIGHT_TRACK)
    for name, data in files.items():
        runs.write_file(run_id, name, data)
    runs.write_file(run_id, "config.json", run.model_dump_json())
    buf = io.BytesIO()
    torch.save({"model": {"w": _Bomb(marker)}, "optimizer": None}, buf)
    runs.save_checkpoint(run_id, 0, buf.getvalue(), {"env_steps": 0})
    runs.set_pointer(run_id, "best", 0)


@pytest.mark.slow(reason="a real trainer and worker over Redis")
def test_pickle_bomb_checkpoint_is_refused_by_racer_eval_and_by_a_worker(tmp_path, redis_url):
    marker = tmp_path / "bomb-went-off"
    store = str(tmp_path / "store")
    plant_bomb(store, "bombed", marker)
    out = racer("eval", "--run-id", "bombed", "--store", store, "--episodes", "1", cwd=tmp_path)
    assert out.returncode == 2
    # The refusal is one line, the last: what comes before it is racer eval's progress (which checkpoint, what it
    # is about to drive), said before the weights are read.
    *progress, refusal = out.stderr.strip().splitlines()
    assert "refused to load checkpoint" in refusal and "Traceback" not in out.stderr, out.stderr
    assert progress[0].startswith("checkpoint v0 of run bombed") and len(progress) == 2, out.stderr
    assert not marker.exists()

    # A worker told to act with it refuses it too.
    r = redis.Redis.from_url(redis_url)
    r.set(
        Keys("bombed").policy,
        PolicyVersion(version=0, checkpoint_key="runs/bombed/checkpoints/000000000.pt", created=0.0).to_json(),
    )
    worker = RolloutWorker(WorkerOptions("bombed", redis_url, store, worker_index=0, policy_wait_s=5))
    with pytest.raises(CheckpointError, match="refused"):
        worker.start()
    worker.close()
    assert not marker.exists()
