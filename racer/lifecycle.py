"""The life of racer's processes, both sides of it: how a launcher starts and stops role processes (trainer,
workers, evaluator), and how a role process stops when asked and says why it exited.

The contract: a role is ``python -m racer <role> …`` in a session of its own (Ctrl-C reaches only the launcher);
SIGTERM or SIGINT sets its stop event, so it finishes the step in hand and exits 0; it exits with
:data:`USER_ERROR_EXIT` on a :class:`common.errors.UserError` (restarting it cannot help) and with another code on
a crash (a launcher may restart it).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from common.errors import UserError

USER_ERROR_EXIT = 2
"""Exit code of a process that stopped on a user error (bad reward function, bad file): restarting won't help."""


class RoleFailed(UserError, RuntimeError):
    """A role process ended the run; the message says which, its last log line and where its log is."""


def setup_logging(verbose: bool = False, simtrace_lines: bool = False) -> None:
    """A role's log format and level (DEBUG with ``-v``); per-step ``SIM_TRACE_LOG`` lines only if asked."""
    from common.simtrace import LOG as SIMTRACE_LOG

    # One line per step (15 a second per env) fills a log fast; the sim-trace CSVs in the store hold the same rows.
    SIMTRACE_LOG.setLevel(logging.INFO if simtrace_lines else logging.WARNING)
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    # Never debug-log the HTTP libraries: botocore's request dumps carry the Authorization header (the access key
    # id and a signature), and -v is what a user pastes into a bug report.
    for name in ("botocore", "boto3", "s3transfer", "urllib3"):
        logging.getLogger(name).setLevel(logging.INFO)


def stop_event_on_signals() -> threading.Event:
    """A threading.Event set by SIGTERM/SIGINT, so a role process finishes its step and exits cleanly."""
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def spawn_role(args: list[str], log_path: Path) -> subprocess.Popen:
    """Start ``racer <args>`` as a role process in its own session, appending its output to ``log_path``."""
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    with log_path.open("ab") as log:
        # start_new_session: Ctrl-C reaches only the launcher, which stops the children in order, trainer last.
        return subprocess.Popen(
            [sys.executable, "-m", "racer", *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            start_new_session=True,
        )


def stop_all(procs: list[subprocess.Popen], grace_s: float = 10.0) -> None:
    """SIGTERM every running process, wait up to ``grace_s`` for all of them together, then kill what is left."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
