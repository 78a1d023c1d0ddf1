"""One form for a run's options: what ``racer train`` (or ``racer trainer``) was asked, validated once.

``RunOptions`` is built once from the command's flags, with a DRfC folder filling only what the flags left unset
(``with_drfc``), and racer's defaults last (``with_defaults``). The launcher takes it whole and hands it to the
trainer role as JSON (``racer trainer --options``); ``build_run`` reads the run's files from it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, ValidationInfo, field_validator

from common.config import RunConfig
from common.deadline import Deadline, parse_duration
from common.defaults import (
    DEFAULT_EVAL_EPISODES,
    DEFAULT_EVAL_NICE,
    DEFAULT_TRACK,
    DEFAULT_TRAINER_THREADS,
    DEFAULT_WORKERS,
)
from common.errors import OptionError
from common.hyperparams import check_cooldown
from common.race import RaceConfig
from racer.drfc import DrfcImport, WorkerSettings

_FROM_DRFC = ("track", "reward_fn", "action_space", "hyperparams", "workers", "run_id", "eval_episodes", "pretrained")
"""Options a DRfC folder sets where the user did not (None: unset)."""


_PATHS = ("track", "reward_fn", "action_space", "hyperparams", "randomization", "car_calibration")
"""Options a user may give as a path: kept as text."""


_FLAGS = {"time_limit_s": "--time-limit", "eval_tracks": "--eval-track", "redis_url": "--redis"}
"""The command-line flag of each option whose name differs from its field's."""


def _flag(field: str) -> str:
    """The command-line flag of an option's field."""
    return _FLAGS.get(field, "--" + field.replace("_", "-"))


class RunOptions(BaseModel):
    """A run's options. None means "not set": a DRfC folder, then racer's default, fills it."""

    model_config = ConfigDict(extra="forbid")

    # --- where the run lives ---
    run_id: str | None = None
    store: str = "."
    s3_endpoint: str | None = None
    redis_url: str | None = None
    """None: ``racer train`` starts an embedded Redis for the run."""
    resume: bool = False
    """Continue the run from its latest checkpoint instead of starting it."""

    # --- what defines a new run (``build_run``) ---
    track: str | None = None
    reward_fn: str | None = None
    action_space: str | None = None
    hyperparams: str | None = None
    randomization: str | None = None
    """A randomization JSON file."""
    randomization_update: dict[str, Any] = Field(default_factory=dict)
    """RandomizationConfig fields set on top (from a DRfC run.env)."""
    worker_settings: list[WorkerSettings | None] = Field(default_factory=list)
    """Each worker's own world (``--worker-track``, ``--worker-config``, DRfC's multi-config); None: the run's."""
    seed: int = 0
    car_calibration: str | None = None
    """A car preset's name or a car.json (None: the default car)."""
    max_policy_lag: int = Field(0, ge=0)
    segment_steps: int = Field(32, ge=1)
    pretrained: str | None = None
    """``RUN[:best|latest|N]`` of another run in the store to start from."""
    race: RaceConfig | None = None
    """The race (``--race``/``--race-type`` or a DRfC run.env); None: a time trial."""

    # --- the processes ---
    workers: int | None = Field(None, ge=1)
    envs_per_worker: int = Field(1, ge=1)
    """Envs each worker steps side by side (``racer worker --envs-per-worker``)."""
    time_limit_s: float | None = Field(None, gt=0)
    """Seconds: ``--time-limit``'s text (``90s``, ``5m``, ``2h``; a bare number is refused) is parsed here, and a
    number is taken as seconds (the options' JSON, ``racer trainer --options``); None: until stopped."""
    deadline: Deadline | None = None
    """When the run stops: fixed once from ``time_limit_s`` as the roles start (``started``)."""
    trainer_threads: int = Field(DEFAULT_TRAINER_THREADS, ge=1)
    """PyTorch threads of the trainer (``common.defaults.DEFAULT_TRAINER_THREADS``)."""
    precision: str = "auto"
    """The trainer's PPO update arithmetic: auto, fp32, bf16 or fp16 (``racer trainer --precision``)."""
    device: str = "auto"
    """Where the trainer and the evaluator compute: auto, cpu, cuda or cuda:N (``trainer.device``); the workers
    always act on the CPU."""
    evaluate: bool = True
    """Run the evaluator process beside the trainer."""
    eval_every: int = Field(1, ge=1)
    """Evaluate every N-th policy version."""
    eval_episodes: int | None = Field(None, ge=1)
    """Start positions per direction in each evaluation."""
    eval_tracks: list[str] = Field(default_factory=list)
    """Tracks the evaluator drives (empty = the run's track)."""
    eval_both_directions: bool = True
    """The evaluator also drives every start in the reverse direction (False: as a DeepRacer race, forward only)."""
    eval_nice: int = Field(DEFAULT_EVAL_NICE, ge=0, le=19)
    """The evaluator's nice increment (``common.defaults.DEFAULT_EVAL_NICE``)."""
    stop_when_robust: int | None = Field(None, ge=1)
    """Stop once this many consecutive evaluated checkpoints complete every evaluation lap."""
    worker_restarts: int = Field(3, ge=0)
    """Restarts allowed per worker slot after a crash or kill (not after a user error, exit code 2)."""
    view: tuple[str, int] | None = None
    """Serve ``racer view``'s page of the run on this (host, port) from the launcher (docs/view.md)."""

    @classmethod
    def from_flags(cls, **flags: Any) -> RunOptions:
        """The options of a command's flags; a value they cannot take is an OptionError naming the flag."""
        try:
            return cls(**flags)
        except ValidationError as exc:
            error = exc.errors()[0]
            flag = _flag(str(error["loc"][0])) if error.get("loc") else "options"
            cause = (error.get("ctx") or {}).get("error")
            if isinstance(cause, OptionError) and str(cause).startswith(f"{flag} "):  # it names the flag already
                raise cause from None
            reason = str(error.get("msg", "invalid")).removeprefix("Value error, ")
            raise OptionError(f"{flag} {error.get('input')!r}: {reason}") from None

    @field_validator("time_limit_s", mode="before")
    @classmethod
    def _duration(cls, value: object, info: ValidationInfo) -> object:
        return parse_duration(value, _flag(info.field_name)) if isinstance(value, str) else value

    @field_validator(*_PATHS, mode="before")
    @classmethod
    def _path_text(cls, value: object) -> object:
        return str(value) if isinstance(value, Path) else value

    def with_drfc(self, drfc: DrfcImport | None) -> RunOptions:
        """These options with a DRfC folder's values in the ones left unset (explicit options win)."""
        if drfc is None:
            return self
        if drfc.track_error is not None and self.track is None:
            raise drfc.track_error
        update: dict[str, Any] = {}
        for name in _FROM_DRFC:
            value = getattr(drfc, name)
            if getattr(self, name) is None and value is not None:
                update[name] = str(value) if isinstance(value, Path) else value
        if self.race is None and drfc.race is not None:
            update["race"] = drfc.race
        if not self.randomization_update:
            update["randomization_update"] = dict(drfc.randomization)
        return self.model_copy(update=update)

    def with_defaults(self) -> RunOptions:
        """These options with racer's defaults in the ones still unset."""
        defaults = {"track": DEFAULT_TRACK, "workers": DEFAULT_WORKERS, "eval_episodes": DEFAULT_EVAL_EPISODES}
        return self.model_copy(update={k: v for k, v in defaults.items() if getattr(self, k) is None})

    def started(self) -> RunOptions:
        """These options with the deadline fixed from now (if there is a time limit and no deadline yet)."""
        if self.time_limit_s is None or self.deadline is not None:
            return self
        return self.model_copy(update={"deadline": Deadline.after(self.time_limit_s)})

    # --- each role's command line, derived from these options (racer train's launcher starts the roles with them) ---
    def role_args(self) -> list[str]:
        """The flags every role process takes: the run, its Redis and its store. Needs ``run_id`` and
        ``redis_url`` set (the launcher sets both before it starts a role)."""
        if self.run_id is None or self.redis_url is None:
            raise ValueError("a role needs the run id and the Redis URL")
        args = ["--run-id", self.run_id, "--redis", self.redis_url, "--store", self.store]
        return args + (["--s3-endpoint", self.s3_endpoint] if self.s3_endpoint else [])

    def worker_args(self, index: int) -> list[str]:
        """``racer worker``'s command line for worker ``index`` of the run."""
        return ["worker", *self.role_args(), "--index", str(index), "--envs-per-worker", str(self.envs_per_worker)]

    def evaluator_args(self) -> list[str]:
        """``racer evaluator``'s command line: how often it evaluates, from how many starts, on which tracks and in
        which directions, its nice and its device."""
        args = ["evaluator", *self.role_args(), "--every", str(self.eval_every), "--nice", str(self.eval_nice)]
        args += ["--device", self.device] + [a for t in self.eval_tracks for a in ("--track", t)]
        args += ["--episodes", str(self.eval_episodes)] if self.eval_episodes is not None else []
        return args + ([] if self.eval_both_directions else ["--forward-only"])

    def check_run(self, run: RunConfig) -> None:
        """Refuse what the run's hyperparameters need of these options: a cool-down needs a time limit."""
        check_cooldown(run.hyperparams.lr_cooldown, self.time_limit_s)
