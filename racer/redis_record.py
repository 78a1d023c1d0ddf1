"""Where a running ``racer train`` keeps its Redis: ``runs/<id>/redis.json`` in the run's local folder.

``racer train`` starts a private Redis (a unix socket in a temporary folder nobody else can guess) or uses
``--redis URL``; other commands of the same user on the same machine (``racer status``, ``racer view``) find it
here from the run id, or from the store alone. The launcher writes the record once its Redis answers and removes it
when the run stops::

    {"url": "unix:///tmp/racer-redis-…/redis.sock", "pid": <the launcher's pid>, "started": <epoch seconds>}

A record whose launcher is gone (killed before it could remove it) is stale and ignored. The file is readable by
its owner only: a ``--redis`` URL may hold a password (the role processes already get it on their command lines).
"""

from __future__ import annotations

import difflib
import json
import numbers
import os
import time
from pathlib import Path

from common.errors import OptionError
from common.keys import RUN_ID
from model_store.runs import local_run_dir, local_runs_dir

REDIS_RECORD = "redis.json"
"""The record's file name in the run's local folder."""


def redis_record_path(store: str, run_id: str) -> Path:
    """``runs/<id>/redis.json`` in the run's local folder (``model_store.runs.local_run_dir``)."""
    return local_run_dir(store, run_id) / REDIS_RECORD


def write_redis_record(store: str, run_id: str, url: str) -> Path:
    """Record that this process runs ``run_id`` with its Redis at ``url``; returns the file (owner-only, replaced
    whole so that a reader never sees half of it)."""
    path = redis_record_path(store, run_id)
    path.parent.mkdir(parents=True, exist_ok=True)
    temp = path.with_name(f".{REDIS_RECORD}.{os.getpid()}")
    fd = os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        json.dump({"url": url, "pid": os.getpid(), "started": time.time()}, f)
    os.replace(temp, path)
    return path


def remove_redis_record(path: Path) -> None:
    """Remove the record at ``path`` if this process wrote it (not one a later launcher of the run wrote)."""
    record = read_redis_record(path)
    if record is not None and record["pid"] == os.getpid():
        path.unlink(missing_ok=True)


def read_redis_record(path: Path) -> dict | None:
    """The record at ``path`` (``url``, ``pid``, ``started``), or None when it is missing or malformed."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not isinstance(data.get("url"), str):
        return None
    pid, started = data.get("pid"), data.get("started")
    if isinstance(pid, bool) or not isinstance(pid, int) or pid <= 0:
        return None
    if isinstance(started, bool) or not isinstance(started, numbers.Real):
        return None
    return {"url": data["url"], "pid": pid, "started": float(started)}


def live_redis_record(store: str, run_id: str) -> dict | None:
    """The record of ``run_id`` if its launcher is still running, else None."""
    record = read_redis_record(redis_record_path(store, run_id))
    return record if record is not None and _alive(record["pid"]) else None


def newest_live_run(store: str) -> tuple[str, dict] | None:
    """(run id, record) of the run started last among those with a live record in the store's local runs folder."""
    found: list[tuple[float, str, dict]] = []
    for path in local_runs_dir(store).glob(f"*/{REDIS_RECORD}"):
        run_id = path.parent.name
        record = read_redis_record(path) if RUN_ID.match(run_id) else None
        if record is not None and _alive(record["pid"]):
            found.append((record["started"], run_id, record))
    if not found:
        return None
    _, run_id, record = max(found, key=lambda item: item[0])
    return run_id, record


def locate_run(store: str, run_id: str | None, redis_url: str | None) -> tuple[str, str]:
    """(run id, Redis URL) of the run a command looks at: both as given; else the run's live record; else, given
    neither, the newest live record in the store's local folder. OptionError, in one line, when there is none."""
    if redis_url:
        if not run_id:
            raise OptionError("--redis needs --run-id: the run whose keys to read")
        return run_id, redis_url
    if run_id:
        record = live_redis_record(store, run_id)
        if record is None:
            raise OptionError(_not_running(store, run_id))
        return run_id, record["url"]
    newest = newest_live_run(store)
    if newest is None:
        raise OptionError(
            f"no running racer train found in {local_runs_dir(store)} (no runs/<id>/{REDIS_RECORD} of a live "
            "launcher): give --store where it trains, or --redis URL and --run-id"
        )
    return newest[0], newest[1]["url"]


def _not_running(store: str, run_id: str) -> str:
    """Why ``run_id`` has no live record: a run of this store that has stopped, or no such run here (with the
    closest run ids, for a misspelt one)."""
    runs = local_runs_dir(store)
    if (runs / run_id).is_dir():
        return (
            f"--run-id {run_id}: its racer train is not running any more (finished or killed: "
            f"{redis_record_path(store, run_id)} is gone or its launcher has stopped); its checkpoints: racer models "
            f"ls --store {store} --run-id {run_id}; --redis URL for a run started another way"
        )
    known = sorted(p.name for p in runs.glob("*") if p.is_dir() and RUN_ID.match(p.name)) if runs.is_dir() else []
    close = difflib.get_close_matches(run_id, known, n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    return (
        f"--run-id {run_id}: no such run in {runs}{hint}; give --store where it trains, or --redis URL for a run "
        "started another way"
    )


def _alive(pid: int) -> bool:
    """True if process ``pid`` exists (another user's counts: signal 0 is then refused, not unanswered)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
