"""``racer train``: the whole loop on one machine — Redis, the trainer and N workers as processes."""

from __future__ import annotations

import contextlib
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import redis
from rich.console import Console
from rich.live import Live

from common.bus import Bus
from common.config import RunConfig
from common.redis_util import connect_checked, redact
from model_store import LocalStore, RunStore, open_store
from model_store.runs import local_run_dir, run_prefix
from racer.console import new_console
from racer.embedded_redis import EmbeddedRedis
from racer.lifecycle import USER_ERROR_EXIT, RoleFailed, spawn_role, stop_all
from racer.options import RunOptions
from racer.redis_record import remove_redis_record, write_redis_record


def new_run_id() -> str:
    """A readable, sortable run id: ``run-YYYYmmdd-HHMMSS``."""
    return datetime.now(UTC).strftime("run-%Y%m%d-%H%M%S")


def _time_bar(elapsed_s: float, limit_s: float | None, width: int = 20) -> str:
    """``━━━━━━──────  31 %  4m08s left`` for a run with a time limit; the time trained so far without one."""
    if limit_s is None:
        return f"{_duration(elapsed_s)} trained"
    done = min(max(elapsed_s / limit_s, 0.0), 1.0)
    full = round(done * width)
    return f"{'━' * full}{'─' * (width - full)} {100 * done:3.0f} %  {_duration(limit_s - elapsed_s)} left"


def _duration(seconds: float) -> str:
    """``1h02m``, ``4m08s`` or ``37s``."""
    s = max(int(round(seconds)), 0)
    if s >= 3600:
        return f"{s // 3600}h{s % 3600 // 60:02d}m"
    return f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s"


PROGRESS_EVERY_S = 30.0
"""How often ``racer train`` prints a progress line when its output is not a terminal (a pipe, nohup, CI)."""


def progress_line(elapsed_s: float, limit_s: float | None, status_line: str) -> str:
    """``[1m30s, 3m30s left] iter 4  v4  steps …``: one plain line for a log (``[1m30s] …`` without a limit)."""
    left = "" if limit_s is None else f", {_duration(limit_s - elapsed_s)} left"
    return f"[{_duration(elapsed_s)}{left}] {status_line}"


def _status_line(
    status: dict | None, beat: dict | None, workers: tuple[int, int], evaluation: dict | None = None
) -> str:
    """The live line: what the trainer is doing now (its heartbeat: starting, or a PPO update and for how long),
    its figures (its last status), the workers (alive, of how many) and the last evaluation."""
    alive, total = workers
    doing = ""
    if beat is not None and beat["phase"] in ("starting", "updating"):
        for_s = max(0.0, time.time() - beat["since"])
        doing = (
            f"trainer starting ({for_s:.0f} s)"
            if beat["phase"] == "starting"
            else f"PPO update from v{beat['policy_version']} ({for_s:.0f} s)"
        )
    if not status:
        return f"{doing or 'starting…'} ({alive} of {total} workers running)"
    line = (
        f"iter {status['iteration']}  v{status['policy_version']}  "
        f"trained on {status.get('trained_env_steps', 0):,} of {status['env_steps']:,} steps  "
        f"{status['steps_per_s']:.0f} steps/s  progress {status['mean_progress']:.1f}%  "
        f"reward {status['mean_reward']:.1f}  workers {len(status['workers'])}/{total}"
    )
    if doing:
        line = f"{doing}  {line}"
    if status.get("silent_workers"):
        line += f"  silent: {', '.join(status['silent_workers'])}"
    if evaluation:
        line += f"  eval v{evaluation['version']}: {100 * evaluation['completion_rate']:.0f}% laps"
        line += "" if evaluation.get("best_lap_s") is None else f", best lap {evaluation['best_lap_s']:.2f} s"
    return line


@contextlib.contextmanager
def sigterm_as_ctrl_c():  # noqa: ANN201 - a context manager
    """Within, SIGTERM (``kill``, ``docker stop``, systemd) stops ``racer train`` as Ctrl-C does: the roles run in
    their own sessions, so without this a SIGTERM would end the launcher alone and leave the trainer, the workers
    and the evaluator running. Only the main thread can set a handler; elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def run_train(run: RunConfig, opts: RunOptions, run_files: dict[str, bytes], console: Console | None = None) -> dict:
    """Start Redis (unless given), the trainer and the workers; show progress; stop them all at the end.

    ``opts`` were checked against ``run`` (``racer.runconfig.open_run``). The deadline is fixed as the roles start,
    and the trainer gets it with the rest of ``opts`` (``--options``): every process stops at the same moment.
    Returns the trainer's last status. Raises RoleFailed if the trainer fails or every worker has stopped.
    """
    console = console or new_console()
    opts = opts.with_defaults()
    _check_store(opts.store, opts.s3_endpoint)
    if opts.redis_url:
        connect_checked(opts.redis_url).close()  # a wrong URL or password fails here, before any process starts
    with contextlib.ExitStack() as stack:
        stack.enter_context(sigterm_as_ctrl_c())
        redis_url = opts.redis_url or stack.enter_context(EmbeddedRedis()).url
        # Registered after the Redis, so removed before it stops: `racer status` never finds a dead one recorded.
        stack.callback(remove_redis_record, write_redis_record(opts.store, run.run_id, redis_url))
        bus = Bus.connect(redis_url, run.run_id)  # the launcher's one connection: the version, then the live line
        version = bus.server_version()  # racer runs on 6.2 and 7.x: say which
        hint = _status_hint(run.run_id, opts.store)
        console.print(f"Redis {version}: {redact(redis_url)} ({hint})", highlight=False, soft_wrap=True)
        if opts.view is not None:
            from racer.view.server import ViewOptions, ViewServer

            host, port = opts.view
            view = ViewOptions(
                run.run_id, opts.store, s3_endpoint=opts.s3_endpoint, redis_url=redis_url, host=host, port=port, run=run
            )
            console.print(f"racer view: {stack.enter_context(ViewServer(view)).url}", highlight=False, soft_wrap=True)
        work = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="racer-train-")))
        logs = local_run_dir(opts.store, run.run_id) / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        opts = opts.model_copy(update={"redis_url": redis_url, "run_id": run.run_id}).started()
        trainer = spawn_role(trainer_args(run, opts, run_files, work), logs / "trainer.log")
        workers = [spawn_role(opts.worker_args(k), logs / f"worker-{k}.log") for k in range(int(opts.workers or 0))]
        evaluator = [spawn_role(opts.evaluator_args(), logs / "evaluator.log")] if opts.evaluate else []
        try:
            restarts = _Workers(workers, opts, logs)
            return _watch(run, opts, bus, trainer=trainer, workers=restarts, console=console)
        finally:
            stop_all([*workers, *evaluator, trainer])


def trainer_args(run: RunConfig, opts: RunOptions, run_files: dict[str, bytes], work: Path) -> list[str]:
    """``racer trainer``'s arguments under ``racer train``: the run's config, its files and ``opts`` (with the
    deadline) written as JSON into ``work``; the trainer takes its options from that JSON whole."""
    (work / "run.json").write_text(run.model_dump_json())
    (work / "options.json").write_text(opts.model_dump_json())
    for name, data in run_files.items():
        (work / name).write_bytes(data)
    args = ["trainer", "--config", str(work / "run.json"), "--files", str(work), *opts.role_args()]
    return [*args, "--options", str(work / "options.json")]


def check_device_options(device: str, precision: str) -> None:
    """``--device`` and ``--precision`` as the trainer will take them, checked before anything starts: OptionError
    naming the option and the value. Every device runs ``auto`` and ``fp32`` and a CPU runs ``bf16``: those
    pairs are checked by their spelling alone. Any other (a named GPU, ``fp16``, ``bf16`` on ``auto``) needs to know
    the machine's GPUs, and loads torch into this long-lived process (about 1.3 s and 220 MB) to ask."""
    from common.config import check_precision
    from trainer.device import check_device, resolve_device

    check_precision(precision)
    check_device(device)
    runs_anywhere = precision in ("auto", "fp32") and device in ("auto", "cpu")
    if not (runs_anywhere or (device, precision) == ("cpu", "bf16")):
        from trainer.precision import precision_candidates

        precision_candidates(precision, resolve_device(device))


def _status_hint(run_id: str, store: str) -> str:
    """The command that shows the run from another shell."""
    return f"racer status --run-id {run_id}" + ("" if store == "." else f" --store {store}")


def robust_streak(summaries: list[dict]) -> int:
    """How many of the most recent evaluations in a row completed every lap."""
    streak = 0
    for s in reversed(summaries):
        if s.get("completion_rate", 0.0) < 1.0:
            break
        streak += 1
    return streak


def _check_store(store: str, endpoint: str | None) -> None:
    """Fail before starting anything on a bad store URI, a missing bucket or missing credentials (StoreError)."""
    opened = open_store(store, endpoint)  # a bad URI fails here
    if not isinstance(opened, LocalStore):  # ask S3 for one key; a local folder is made when first written
        next(iter(opened.list("runs/")), None)


def _last_line(path: Path) -> str:
    lines = path.read_text(errors="replace").strip().splitlines() if path.exists() else []
    return lines[-1] if lines else ""


@dataclass
class _Workers:
    """The worker processes of ``racer train``: report each exit, restart one that crashed or was killed."""

    procs: list[subprocess.Popen]
    """Worker k's current process; the list is the caller's and is updated in place, so that cleanup stops
    restarted workers too."""
    opts: RunOptions
    """The run's options: each worker's command line (``RunOptions.worker_args``) and its restarts allowed."""
    logs: Path
    restarts: dict[int, int] = field(default_factory=dict)
    given_up: set[int] = field(default_factory=set)

    def check(self, console: Console) -> None:
        """Report workers that exited since the last check and restart those allowed."""
        for k, p in enumerate(self.procs):
            if p.poll() is None or k in self.given_up:
                continue
            log = self.logs / f"worker-{k}.log"
            msg = f"worker {k} exited with code {p.returncode}: {_last_line(log)[-200:]} (log: {log})"
            used = self.restarts.get(k, 0)
            if p.returncode == USER_ERROR_EXIT or used >= self.opts.worker_restarts:
                self.given_up.add(k)
                console.print(f"[yellow]{msg}; not restarting", highlight=False, soft_wrap=True)
                continue
            self.restarts[k] = used + 1
            console.print(
                f"[yellow]{msg}; restarting it ({used + 1} of {self.opts.worker_restarts})",
                highlight=False,
                soft_wrap=True,
            )
            self.procs[k] = spawn_role(self.opts.worker_args(k), log)

    @property
    def all_given_up(self) -> bool:
        """Every worker slot has stopped for good: the run cannot make progress."""
        return len(self.given_up) == len(self.procs)

    @property
    def alive(self) -> int:
        """Worker processes running now."""
        return sum(p.poll() is None for p in self.procs)


def _watch(
    run: RunConfig,
    opts: RunOptions,
    bus: Bus,
    *,
    trainer: subprocess.Popen,
    workers: _Workers,
    console: Console,
) -> dict:
    started = time.monotonic()
    deadline = opts.deadline
    status: dict | None = None
    evals: list[dict] = []
    line = ""
    # In a terminal, a live display. Elsewhere (a pipe, nohup, CI) Live draws nothing until it stops, so a plain
    # progress line every PROGRESS_EVERY_S instead.
    interactive = console.is_interactive
    next_line = started + PROGRESS_EVERY_S
    # Transient: the last status is printed once after the display stops (a non-terminal Live leaves its last
    # render without a newline, and the next line ran into it).
    live = Live(console=console, refresh_per_second=4, transient=True) if interactive else None
    with live or contextlib.nullcontext():
        try:
            while deadline is None or not deadline.passed():
                if trainer.poll() is not None:
                    if trainer.returncode == 0:
                        break  # finished by its own termination condition
                    log = workers.logs / "trainer.log"
                    raise RoleFailed(
                        f"the trainer exited with code {trainer.returncode}: {_last_line(log)} (log: {log})"
                    )
                workers.check(console)
                if workers.all_given_up:
                    tail = _last_line(workers.logs / "worker-0.log")
                    raise RoleFailed(f"every worker has stopped (worker 0: {tail.removeprefix('error: ')})")
                try:
                    status = bus.trainer_status() or status
                    beat = bus.trainer_beat()
                    evals = [e.model_dump() for e in bus.evaluations()[0]]
                    line = _status_line(
                        status,
                        None if beat is None else beat.model_dump(),
                        (workers.alive, len(workers.procs)),
                        evals[-1] if evals else None,
                    )
                except redis.RedisError as exc:  # the roles ride out the outage; so does the display
                    where = redact(str(opts.redis_url))
                    line = f"Redis at {where} unreachable ({type(exc).__name__}); the roles are retrying"
                elapsed = time.monotonic() - started
                if live is not None:
                    live.update(f"{_time_bar(elapsed, opts.time_limit_s)}\n{line}")
                elif time.monotonic() >= next_line:
                    console.print(progress_line(elapsed, opts.time_limit_s, line), highlight=False, soft_wrap=True)
                    next_line += PROGRESS_EVERY_S
                if opts.stop_when_robust and robust_streak(evals) >= opts.stop_when_robust:
                    console.print(f"robust: {opts.stop_when_robust} checkpoints in a row completed every lap")
                    status = {**(status or {}), "stopped_robust": True}
                    break
                time.sleep(0.25)
        except KeyboardInterrupt:
            console.print("stopping (Ctrl-C or SIGTERM)…")
            status = {**(status or {}), "interrupted": True}
    if line:
        last = line if live is not None else progress_line(time.monotonic() - started, opts.time_limit_s, line)
        console.print(last, highlight=False, soft_wrap=True)
    return {**(status or {}), "trained_s": time.monotonic() - started}


def done_line(runs: RunStore, run_id: str, trained_s: float) -> str:
    """``done: 2 iterations, 2,304 env steps in 61 s``, from the run's metrics.jsonl once every process has stopped:
    the trainer's last status seen while it ran can predate its last update (a run of 60 s said 0 iterations and 864
    env steps, and its metrics 1 and 1,152)."""
    rows = runs.read_metrics(run_id, missing_ok=True)
    last = rows[-1] if rows else {}
    iterations, env_steps = int(last.get("iteration", 0)), int(last.get("env_steps", 0))
    return f"done: {iterations} iterations, trained on {env_steps:,} env steps in {trained_s:.0f} s"


def run_summary(run_id: str, runs: RunStore, store: str, s3_endpoint: str | None) -> list[str]:
    """What a finished ``racer train`` tells its user: the best checkpoint with its evaluation, where the run's
    files are, and the commands that come next."""
    where = ("" if store == "." else f" --store {store}") + (f" --s3-endpoint {s3_endpoint}" if s3_endpoint else "")
    lines = [f"run files: {runs.store.key_uri(run_prefix(run_id))}"]
    best = runs.pointer(run_id, "best")
    latest = runs.pointer(run_id, "latest")
    if latest is None:
        lines.append("no checkpoint was written: train for longer (--time-limit)")
        return lines
    pick = ""
    if best is None:  # the evaluator has not finished with a trained checkpoint (v0 is never evaluated)
        lines.append(f"no checkpoint evaluated yet: train for longer; latest checkpoint: v{latest['version']}")
        pick = " --checkpoint latest"
    elif (version := best["version"]) in runs.evaluation_versions(run_id):
        e = runs.read_evaluation(run_id, version)
        laps = e.get("lap_times_s") or []
        lap = f", mean lap {sum(laps) / len(laps):.2f} s, best {min(laps):.2f} s" if laps else ""
        lines.append(
            f"best checkpoint: v{version}, robust evaluation {100 * e['completion_rate']:.0f} % of "
            f"{e['episodes']} laps completed{lap}"
        )
    else:
        lines.append(f"best checkpoint: v{version} (not evaluated)")
    lines += [
        "next:",
        f"  racer eval --run-id {run_id}{where}{pick} --video lap.mp4",
        f"  racer export --run-id {run_id}{where}{pick} -o model.onnx",
        f"  racer plot {run_id}{where}",
        f"  racer models ls{where}",
    ]
    return lines
