"""Measurements for ``deploy/cluster/check-hosts.sh``: sample a run's Redis and the worker links, wait for states,
report.

``sample`` writes one JSON line every ``--every`` seconds until stopped: the trainer's status, the published policy,
every live worker's heartbeat, the segment stream (length, entries ever added; null while the stream does not
exist) and the byte counters of the given network interfaces (read from /sys/class/net, so it runs in the namespace
that holds them). ``wait`` polls those samples until a named state is reached (exit 1 on timeout). ``report`` reads
the samples and the script's events (``name epoch-seconds`` lines), checks what the script promises, prints the
figures last and exits 0 only if every check held.

Redis is read only through :class:`common.bus.Bus` (the one owner of the key names), imported by ``sample`` alone:
``wait``, ``wait-upload`` and ``report`` need no racer import and start in a fraction of a second.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from common.bus import Bus


def snapshot(bus: Bus, ifaces: list[str]) -> dict:
    """One sample: see the module docstring."""
    out: dict = {"t": time.time(), "trainer": bus.trainer_status()}
    policy = bus.policy()
    out["policy"] = policy.version if policy else None
    beats, _ = bus.heartbeats()
    out["workers"] = {hb.worker_id: {f: getattr(hb, f) for f in HEARTBEAT_FIELDS} for hb in beats}
    stream = bus.segment_stream()
    out["stream"] = None if stream is None else stream._asdict()
    out["redis_version"] = bus.server_version()  # 6.2 counts the stream's entries differently (common/bus.py)
    net = {}
    for name in ifaces:
        stats = Path("/sys/class/net") / name / "statistics"
        with contextlib.suppress(OSError):
            net[name] = {d: int((stats / f"{d}_bytes").read_text()) for d in ("rx", "tx")}
    out["net"] = net
    return out


HEARTBEAT_FIELDS = ("segments", "env_steps", "policy_version", "time")
"""What a sample keeps of each worker's heartbeat."""


def sample(args: argparse.Namespace) -> int:
    if not args.redis:
        raise SystemExit("sample needs --redis or RACER_REDIS_URL")
    import redis  # here, not at the top: wait and wait-upload must start at once

    from common.bus import Bus
    from common.redis_util import connect

    bus = Bus(connect(args.redis), args.run_id)
    ifaces = [i for i in args.ifaces.split(",") if i]
    stop = False

    def on_term(*_):
        nonlocal stop
        stop = True

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    with open(args.out, "a") as out:
        while not stop:
            t0 = time.monotonic()
            try:
                line = snapshot(bus, ifaces)
            except (redis.RedisError, OSError, ValueError, KeyError) as exc:
                line = {"t": time.time(), "error": str(exc)[:200]}
            out.write(json.dumps(line) + "\n")
            out.flush()
            time.sleep(max(0.0, args.every - (time.monotonic() - t0)))
    return 0


def wait_upload(args: argparse.Namespace) -> int:
    """Wait until ``--iface`` receives ``--bytes`` within ``--within`` seconds, then run ``--then`` at once (and note
    ``--event`` with its time in ``--events``). On a worker's link, seen from the server side, such a burst is a
    segment on its way (the largest thing a worker sends: about 50 KB for 32 steps of the default run, 20 ms at
    20 Mbit/s; heartbeats and the other calls are a few hundred bytes): a cut run from here leaves that push half
    sent, the worst moment for losing or doubling a segment."""
    counter = Path("/sys/class/net") / args.iface / "statistics" / "rx_bytes"
    deadline = time.monotonic() + args.timeout
    recent: list[tuple[float, int]] = []
    while time.monotonic() < deadline:
        now, n = time.monotonic(), int(counter.read_text())
        recent = [(t, b) for t, b in recent if now - t <= args.within] + [(now, n)]
        if n - recent[0][1] >= args.bytes:
            break
        time.sleep(0.001)
    else:
        print(f"no upload burst on {args.iface} in {args.timeout:g} s: going on anyway", file=sys.stderr)
    if args.events:
        with open(args.events, "a") as f:
            f.write(f"{args.event} {time.time():.6f}\n")
    return subprocess.run(args.then, check=False).returncode if args.then else 0


def load(path: str) -> list[dict]:
    """Every whole sample line (the sampler may be writing the last one)."""
    rows = []
    for line in Path(path).read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if "error" not in row:
            rows.append(row)
    return rows


def events(path: str) -> dict[str, float]:
    out = {}
    for line in Path(path).read_text().splitlines():
        name, _, t = line.partition(" ")
        if name:
            out[name] = float(t)
    return out


PROTOCOL_DROPS = {
    "no_header", "bad_header", "schema", "other_run", "missing_array", "bad_dtype", "bad_shape", "bad_length",
    "non_finite", "bad_action", "bad_flag", "bad_lidar", "bad_frames", "corrupt",
}  # fmt: skip
"""The trainer's drop reasons for a malformed segment (common/protocol.py: decode_segment)."""


def segment_drops(trainer: dict) -> dict[str, int]:
    """The trainer's drops of segments, by reason (``bad_heartbeat`` counts heartbeats, not segments)."""
    return {k: v for k, v in trainer.get("dropped", {}).items() if k != "bad_heartbeat"}


def counted(rows: list[dict]) -> dict | None:
    """The last sample that read both the trainer's status and the segment stream, None if none did. The segment
    figures all come from this one sample: a later one may have lost either (the status expires 30 s after the
    trainer stops; a sample taken while the stream is missing has no count of it)."""
    return next((r for r in reversed(rows) if r["trainer"] and r["stream"] is not None), None)


def accounting(row: dict) -> tuple[int, int, int]:
    """(accepted, dropped, added to the stream) in one sample that read both (``counted``)."""
    tr = row["trainer"]
    accepted = sum(tr.get("segments_by_worker", {}).values())
    return accepted, sum(segment_drops(tr).values()), row["stream"]["added"] or 0


def stream_gaps(rows: list[dict]) -> int:
    """Samples without the segment stream after one that had it (0 on a healthy run: nothing deletes it)."""
    first = next((i for i, r in enumerate(rows) if r["stream"] is not None), len(rows))
    return sum(r["stream"] is None for r in rows[first:])


def cut_figures(rows: list[dict], worker: str, cut: float, heal: float) -> dict:
    """What the cut worker did around the cut: its segment count when cut, and how long after the heal it pushed a
    segment again and pushed one acting with the policy that was the trainer's at the heal, or newer (None: not
    seen)."""
    before = [r["workers"][worker]["segments"] for r in rows if r["t"] < heal and worker in r["workers"]]
    at_cut = max(before) if before else None
    back = next(
        (
            r["t"]
            for r in rows
            if r["t"] >= heal
            and worker in r["workers"]
            and at_cut is not None
            and r["workers"][worker]["segments"] > at_cut
        ),
        None,
    )
    # The policy current at the heal, not at each later sample: with a 23 MB checkpoint and an update every few
    # seconds, "as new as the trainer's latest" is a race the worker can lose for minutes on a shaped link while
    # still having caught up on everything it missed during the cut.
    at_heal = [r["trainer"]["policy_version"] for r in rows if r["t"] <= heal and r["trainer"]]
    wanted = max(at_heal) if at_heal else None
    current = next(
        (
            r["t"]
            for r in rows
            if r["t"] >= heal
            and worker in r["workers"]
            and wanted is not None
            and r["workers"][worker]["policy_version"] >= wanted
            and r["workers"][worker]["segments"] > (at_cut or 0)
        ),
        None,
    )
    return {
        "segments_at_cut": at_cut,
        "recovery_s": None if back is None else back - heal,
        "current_policy_s": None if current is None else current - heal,
    }


def wait(args: argparse.Namespace) -> int:
    deadline = time.monotonic() + args.timeout
    workers = [w for w in (args.workers or "").split(",") if w]
    while time.monotonic() < deadline:
        rows = load(args.samples)
        last = rows[-1] if rows else None
        if last is not None and done(args, rows, last, workers):
            return 0
        time.sleep(0.25)
    print(f"timed out after {args.timeout:g} s waiting for {args.state}", file=sys.stderr)
    return 1


def done(args: argparse.Namespace, rows: list[dict], last: dict, workers: list[str]) -> bool:
    if args.state == "ready":  # trainer up, a first update done, every worker sending
        return bool(last["trainer"]) and (last["policy"] or 0) >= 1 and all(w in last["workers"] for w in workers)
    if args.state == "recovered":  # the cut worker pushes again, with the policy current at the heal
        ev = events(args.events)
        f = cut_figures(rows, workers[0], ev["cut"], ev["heal"])
        return f["recovery_s"] is not None and f["current_policy_s"] is not None
    if args.state == "settled":  # the workers stopped and the trainer has read every segment they sent
        since = events(args.events)["workers_stopped"]
        row = counted(rows)
        if row is None or row["trainer"]["time"] < since + 1.5:
            return False
        accepted, dropped, added = accounting(row)
        return accepted + dropped >= added
    raise SystemExit(f"unknown state {args.state!r}")


def at(rows: list[dict], t: float) -> dict:
    """The first sample at or after ``t``."""
    return next(r for r in rows if r["t"] >= t)


def window(rows: list[dict], start: float, end: float, ports: dict[str, str]) -> dict:
    """Throughput and bytes per env step over [start, end]; ``ports`` maps worker id → its link's interface on
    the server side (rx = bytes from the worker, tx = bytes to it)."""
    a = at(rows, start)
    b = [r for r in rows if r["t"] <= end][-1]
    dt = b["t"] - a["t"]
    trainer_dt = b["trainer"]["time"] - a["trainer"]["time"]  # its status is written once a second
    trainer_steps = b["trainer"]["env_steps"] - a["trainer"]["env_steps"]
    worker_steps = sum(b["workers"][w]["env_steps"] - a["workers"][w]["env_steps"] for w in ports)
    up = sum(b["net"][i]["rx"] - a["net"][i]["rx"] for i in ports.values())
    down = sum(b["net"][i]["tx"] - a["net"][i]["tx"] for i in ports.values())
    return {
        "seconds": dt,
        "trainer_steps_per_s": trainer_steps / trainer_dt,
        "worker_steps_per_s": worker_steps / dt,
        "versions": b["trainer"]["policy_version"] - a["trainer"]["policy_version"],
        "bytes_per_env_step": (up + down) / worker_steps if worker_steps else None,
        "up_bytes_per_env_step": up / worker_steps if worker_steps else None,
        "down_bytes_per_env_step": down / worker_steps if worker_steps else None,
        "link_mbit_s": 8 * (up + down) / dt / 1e6 / len(ports),
    }


def report(args: argparse.Namespace) -> int:
    rows = load(args.samples)
    ev = events(args.events)
    ports = dict(p.split("=") for p in args.ports.split(","))  # worker id=interface
    cut_worker, other = args.cut_worker, [w for w in ports if w != args.cut_worker]
    checks: list[tuple[str, bool]] = []
    fig: dict = {}

    base = window(rows, ev["unshaped_start"], ev["unshaped_end"], ports)
    shaped = window(rows, ev["shaped_start"], ev["shaped_end"], ports)
    fig["unshaped"], fig["shaped"] = base, shaped
    checks.append(("training ran unshaped and shaped", base["versions"] > 0 and shaped["versions"] > 0))

    before_cut = [r for r in rows if r["t"] <= ev["cut"]][-1]
    before_heal = [r for r in rows if r["t"] <= ev["heal"]][-1]
    fig["cut_s"] = ev["heal"] - ev["cut"]
    fig["versions_during_cut"] = before_heal["trainer"]["policy_version"] - before_cut["trainer"]["policy_version"]
    checks.append(("training went on during the cut", fig["versions_during_cut"] > 0))
    others_during = [
        before_heal["workers"].get(w, {}).get("segments", 0) - before_cut["workers"].get(w, {}).get("segments", 0)
        for w in other
    ]
    checks.append(("the other worker kept sending during the cut", all(n > 0 for n in others_during)))
    # While cut off, the worker's heartbeat key expires: the trainer must not have counted anything from it.
    cut = cut_figures(rows, cut_worker, ev["cut"], ev["heal"])
    fig.update(cut)
    checks.append(
        (
            f"the cut worker pushed again within {args.recovery_limit:g} s of the heal",
            cut["recovery_s"] is not None and cut["recovery_s"] <= args.recovery_limit,
        )
    )
    checks.append(
        ("the cut worker acts with the policy current at the heal (or newer)", cut["current_policy_s"] is not None)
    )

    final = counted(rows)
    if final is None:
        print("FAIL  a sample read both the trainer's status and the segment stream")
        return 1
    last_beats: dict[str, int] = {}
    for r in rows:
        for w, hb in r["workers"].items():
            last_beats[w] = max(last_beats.get(w, 0), hb["segments"])
    accepted, dropped, added = accounting(final)
    drops = segment_drops(final["trainer"])
    copies = drops.get("duplicate", 0)
    sent = sum(last_beats.get(w, 0) for w in ports)
    fig["segments_sent"] = sent
    fig["segments_sent_by_worker"] = {w: last_beats.get(w, 0) for w in ports}
    fig["segments_added_to_stream"] = added
    fig["redis_version"] = final.get("redis_version")
    fig["segments_accepted"] = accepted
    fig["segments_accepted_by_worker"] = final["trainer"]["segments_by_worker"]
    fig["segments_dropped"] = drops
    fig["segments_counted_at"] = final["t"] - ev["start"]
    fig["samples_without_stream"] = stream_gaps(rows)
    # A segment can reach the stream twice (a push cut off mid-way is retried while TCP still delivers the first
    # copy): the trainer must drop every extra copy as a duplicate, and count each segment sent exactly once.
    checks.append(
        ("every segment sent reached the stream (extra copies dropped as duplicates)", added - copies == sent)
    )
    checks.append(
        (
            "every segment sent was counted once: accepted + dropped (not duplicates) == sent",
            accepted + dropped - copies == sent,
        )
    )
    checks.append(("no segment was counted in part (no malformed drops)", not PROTOCOL_DROPS & drops.keys()))
    by_worker = fig["segments_accepted_by_worker"]
    checks.append(
        (
            "no worker had more segments accepted than it sent",
            all(by_worker.get(w, 0) <= fig["segments_sent_by_worker"][w] for w in ports),
        )
    )

    log = Path(args.cut_log).read_text(errors="replace")
    retrying = [line for line in log.splitlines() if re.search(r"unreachable .*retrying", line)]
    again = [line for line in log.splitlines() if "reachable again after" in line]
    fig["cut_worker_log"] = (retrying[:1] + again[:1]) or None
    fig["cut_during"] = cut_during(retrying[0]) if retrying else None
    checks.append(("the cut worker's log says it was retrying", bool(retrying)))
    fig["checkpoint_mb"] = args.checkpoint_bytes / 1e6
    fig["script_s"] = time.time() - ev["start"]
    fig["checks"] = {name: ok for name, ok in checks}

    for name, ok in checks:
        print(f"{'PASS' if ok else 'FAIL'}  {name}")
    if args.json:
        Path(args.json).write_text(json.dumps(fig, indent=2) + "\n")
    print(lines(fig, checks))
    return 0 if all(ok for _, ok in checks) else 1


def cut_during(line: str) -> str | None:
    """What the cut worker was doing when the cut reached it, from its "unreachable while trying to X (...)" log
    line: ``push segments`` when the cut fell mid-push, as the script intends."""
    m = re.search(r"while trying to (.+?) \(", line)
    return m.group(1) if m else None


def _n(x: float | None, fmt: str = ".1f") -> str:
    return "none" if x is None else format(x, fmt)


def lines(fig: dict, checks: list[tuple[str, bool]]) -> str:
    """The figures, ``name: value``, one a line (printed last by the script)."""
    b, s = fig["unshaped"], fig["shaped"]
    return "\n".join(
        [
            f"unshaped_steps_per_s: {_n(b['trainer_steps_per_s'])}",
            f"shaped_steps_per_s: {_n(s['trainer_steps_per_s'])}",
            f"shaped_vs_unshaped: {_n(s['trainer_steps_per_s'] / b['trainer_steps_per_s'], '.2f')}",
            f"unshaped_bytes_per_env_step: {_n(b['bytes_per_env_step'], '.0f')}",
            f"shaped_bytes_per_env_step: {_n(s['bytes_per_env_step'], '.0f')}",
            f"shaped_up_bytes_per_env_step: {_n(s['up_bytes_per_env_step'], '.0f')}",
            f"shaped_down_bytes_per_env_step: {_n(s['down_bytes_per_env_step'], '.0f')}",
            f"shaped_link_mbit_s: {_n(s['link_mbit_s'], '.2f')}",
            f"checkpoint_mb: {_n(fig['checkpoint_mb'])}",
            f"cut_s: {_n(fig['cut_s'])}",
            f"versions_during_cut: {fig['versions_during_cut']}",
            f"recovery_s: {_n(fig['recovery_s'])}",
            f"current_policy_s: {_n(fig['current_policy_s'])}",
            f"cut_during: {fig['cut_during']}",
            f"segments_sent: {fig['segments_sent']}",
            f"segments_added_to_stream: {fig['segments_added_to_stream']}",
            f"segments_accepted: {fig['segments_accepted']}",
            f"segments_dropped: {json.dumps(fig['segments_dropped'], sort_keys=True)}",
            f"redis_version: {fig['redis_version']}",
            f"script_s: {_n(fig['script_s'], '.0f')}",
            f"checks_passed: {sum(ok for _, ok in checks)}/{len(checks)}",
        ]
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("sample", help="write samples until SIGTERM")
    p.add_argument("--redis", default=os.environ.get("RACER_REDIS_URL"), help="default: $RACER_REDIS_URL")
    p.add_argument("--run-id", required=True)
    p.add_argument("--out", required=True)
    p.add_argument("--ifaces", default="")
    p.add_argument("--every", type=float, default=0.25)
    p = sub.add_parser("wait", help="wait for a state in the samples")
    p.add_argument("state", choices=["ready", "recovered", "settled"])
    p.add_argument("--samples", required=True)
    p.add_argument("--events", default="")
    p.add_argument("--workers", default="", help="worker ids (recovered: the cut one)")
    p.add_argument("--timeout", type=float, default=60.0)
    p = sub.add_parser("wait-upload", help="wait for a burst received on an interface (a segment), then run --then")
    p.add_argument("--iface", required=True)
    p.add_argument("--bytes", type=int, default=20_000)
    p.add_argument("--within", type=float, default=0.06)
    p.add_argument("--timeout", type=float, default=60.0)
    p.add_argument("--events", default="", help="file to note the event in")
    p.add_argument("--event", default="cut")
    p.add_argument("--then", nargs=argparse.REMAINDER, default=[], help="command to run at once (the rest)")
    p = sub.add_parser("report", help="check and print the figures")
    p.add_argument("--samples", required=True)
    p.add_argument("--events", required=True)
    p.add_argument("--ports", required=True, help="worker-id=server-side-interface,...")
    p.add_argument("--cut-worker", required=True)
    p.add_argument("--cut-log", required=True)
    p.add_argument("--recovery-limit", type=float, default=10.0)
    p.add_argument("--checkpoint-bytes", type=int, default=0, help="size of one checkpoint (a worker loads each)")
    p.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    return {"sample": sample, "wait": wait, "wait-upload": wait_upload, "report": report}[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
