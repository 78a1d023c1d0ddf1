"""``racer train --teacher``: a privileged teacher first, then a camera student that learns to act as it does.

Both stages are ordinary runs of the same machinery (an embedded Redis or ``--redis``, the trainer, N workers and
the evaluator, ``racer/launcher.py: run_train``), one after the other:

1. **The teacher** (run ``{run_id}-teacher``): the run's reward function, action space and hyperparameters, but the
   env returns the car's state on the track (``EnvConfig.observation`` ``state``, ``common/privileged.py``) and the
   network is a ``StatePolicy``: nothing is rendered. It trains for ``teacher_time_s`` (or until
   ``--stop-when-robust``), evaluated like any run.
2. **The student** (run ``{run_id}``): DeepRacer's network of the user's files (so it exports like any racer model)
   distills the teacher's best checkpoint (its ``latest`` where none was evaluated) for ``DistillConfig.updates``
   versions, then, with ``fine_tune``, goes on with PPO on the reward for the rest of the time limit. The run keeps
   its teacher's checkpoint (``model_store.runs.TEACHER_FILE``).
"""

from __future__ import annotations

import time

from rich.console import Console

from common.config import DistillConfig, RunConfig
from common.errors import OptionError
from model_store import RunStore
from racer.options import RunOptions

TEACHER_SUFFIX = "-teacher"
"""The teacher run's id is the student's with this suffix."""
TEACHER_SHARE_OF_TIME = 1 / 3
"""The teacher's share of ``--time-limit`` when ``--teacher-time`` is not given."""


def teacher_run(run: RunConfig) -> RunConfig:
    """The teacher's run of a run built from the user's options: state observations, no frame stack."""
    env = run.env.model_copy(update={"observation": "state"})
    hp = run.hyperparams.model_copy(update={"stack_size": 1})
    policy = run.policy.model_copy(update={"stack_size": 1})
    return run.model_copy(update={"env": env, "hyperparams": hp, "policy": policy, "distill": None})


def teacher_checkpoint(runs: RunStore, teacher_id: str) -> int:
    """The teacher version the student learns from: its ``best`` (robust evaluation), else its ``latest``."""
    pointer = runs.pointer(teacher_id, "best") or runs.pointer(teacher_id, "latest")
    if pointer is None or int(pointer["version"]) == 0:
        raise OptionError(f"the teacher run {teacher_id!r} trained no checkpoint: give it more time (--teacher-time)")
    return int(pointer["version"])


def split_time(opts: RunOptions, teacher_time_s: float | None) -> float:
    """The teacher's seconds: ``--teacher-time``, else a third of ``--time-limit``; one of them is needed, and the
    teacher's must leave the student time."""
    if teacher_time_s is None:
        if opts.time_limit_s is None:
            raise OptionError("--teacher needs --time-limit or --teacher-time: the teacher's stage must end")
        return opts.time_limit_s * TEACHER_SHARE_OF_TIME
    if opts.time_limit_s is not None and teacher_time_s >= opts.time_limit_s:
        raise OptionError(
            f"--teacher-time {teacher_time_s:g} s: it must be shorter than --time-limit ({opts.time_limit_s:g} s)"
        )
    return teacher_time_s


def train_with_teacher(
    runs: RunStore,
    opts: RunOptions,
    build: tuple[RunConfig, dict[str, bytes]],
    *,
    distill: dict[str, object],
    teacher_time_s: float,
    console: Console,
) -> tuple[dict, dict]:
    """Train the teacher, then the student (module docstring); returns the two stages' last trainer statuses.

    ``build`` is the student run as ``racer.runconfig.open_run`` built it from ``opts`` (a new run) and its files;
    ``distill`` the ``DistillConfig`` fields other than its ``teacher``, the teacher's chosen checkpoint."""
    from racer.launcher import run_train

    run, files = build
    teacher_id = f"{run.run_id}{TEACHER_SUFFIX}"
    if runs.newest_whole(teacher_id) is not None:
        raise OptionError(f"run {teacher_id!r} already exists in {runs.store.uri}: choose another --run-id")
    started = time.monotonic()
    teacher_opts = opts.model_copy(update={"run_id": teacher_id, "time_limit_s": teacher_time_s, "deadline": None})
    console.print(f"teacher [bold]{teacher_id}[/]: the car's state, no camera, for {teacher_time_s:.0f} s")
    teacher_status = run_train(teacher_run(run.model_copy(update={"run_id": teacher_id})), teacher_opts, files, console)
    if teacher_status.get("interrupted"):  # Ctrl-C or SIGTERM stops the whole command, not just its first stage
        console.print(f"stopped in the teacher's stage: no student trained (the teacher is run {teacher_id})")
        return teacher_status, {}
    version = teacher_checkpoint(runs, teacher_id)
    left = None if opts.time_limit_s is None else max(opts.time_limit_s - (time.monotonic() - started), 1.0)
    student = run.model_copy(update={"distill": DistillConfig(teacher=f"{teacher_id}:{version}", **distill)})
    console.print(f"student [bold]{run.run_id}[/]: the camera network learns from {teacher_id} v{version}")
    student_opts = opts.model_copy(update={"time_limit_s": left, "deadline": None})
    return teacher_status, run_train(student, student_opts, files, console)
