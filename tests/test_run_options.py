"""One form for a run's options (``racer/options.py: RunOptions``): flags, a DRfC folder filling only what the
flags left unset, and one deadline that goes from ``racer train --time-limit`` into the trainer role."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from common.deadline import Deadline, parse_duration
from common.defaults import DEFAULT_EVAL_EPISODES, DEFAULT_TRACK, DEFAULT_TRAINER_THREADS, DEFAULT_WORKERS
from common.errors import OptionError
from racer.check import merge_inputs
from racer.cli import app
from racer.options import RunOptions


def drfc_folder(root: Path, run_env: str) -> Path:
    """A DRfC folder with only a run.env (racer's default files for the rest)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "run.env").write_text(run_env)
    return root


def test_the_time_limit_is_parsed_once_into_a_number_and_one_deadline() -> None:
    opts = RunOptions(time_limit_s="5m")
    assert opts.time_limit_s == 300.0 and opts.deadline is None
    before = time.time()
    started = opts.started()
    assert started.deadline is not None and started.deadline.limit_s == 300.0
    assert before + 300.0 <= started.deadline.at <= time.time() + 300.0
    assert started.started() is started  # fixed once: starting again keeps it
    assert RunOptions.model_validate_json(started.model_dump_json()) == started  # JSON, whole
    with pytest.raises(OptionError, match="--time-limit 'soon' is not valid: use a number with s, m or h"):
        RunOptions.from_flags(time_limit_s="soon")
    assert RunOptions().started().deadline is None


def test_a_deadline_counts_down_in_wall_clock_time() -> None:
    past = Deadline(at=time.time() - 1.0, limit_s=10.0)
    assert past.passed() and past.left() < 0 and past.elapsed() > 10.0
    assert not Deadline.after(60.0).passed() and parse_duration("1.5h") == 5400.0


def test_a_duration_needs_its_unit_and_the_error_names_the_option() -> None:
    assert [parse_duration(t) for t in ("90s", "5m", " 1.5h ", "2 m")] == [90.0, 300.0, 5400.0, 120.0]
    with pytest.raises(OptionError, match=r"^--time-limit 5: give a unit: 5s, 5m or 5h$"):
        parse_duration("5", "--time-limit")
    with pytest.raises(OptionError, match=r"^duration 0.5: give a unit: 0.5s, 0.5m or 0.5h$"):
        parse_duration("0.5")
    with pytest.raises(OptionError, match=r"^--time-limit 5: give a unit"):  # from the flag, as train reads it
        RunOptions.from_flags(time_limit_s="5")
    assert RunOptions(time_limit_s=5).time_limit_s == 5.0  # a number is seconds: the options' JSON


def test_drfc_values_fill_only_the_options_left_unset(tmp_path: Path) -> None:
    folder = drfc_folder(tmp_path / "drfc", "DR_EVAL_NUMBER_OF_TRIALS=5\nDR_WORKERS=4\n")
    explicit, _ = merge_inputs(RunOptions(eval_episodes=3, workers=1), folder)
    assert explicit.eval_episodes == 3 and explicit.workers == 1  # an explicit 3 is not a default to override
    unset, drfc = merge_inputs(RunOptions(), folder)
    assert drfc is not None and unset.eval_episodes == 5 and unset.workers == 4
    assert RunOptions().with_defaults().model_dump(include={"track", "workers", "eval_episodes"}) == {
        "track": DEFAULT_TRACK,
        "workers": DEFAULT_WORKERS,
        "eval_episodes": DEFAULT_EVAL_EPISODES,
    }


class _Done:
    """A role process that has already exited (what the fake ``spawn_role`` returns)."""

    def __new__(cls) -> subprocess.Popen:  # type: ignore[misc]
        proc = subprocess.Popen(["true"])
        proc.wait()
        return proc


def _train_through_the_trainer_role(monkeypatch: pytest.MonkeyPatch, args: list[str]) -> dict:
    """``racer train ARGS`` with its roles faked: the trainer role runs in this process, as ``racer trainer`` with
    the arguments the launcher gave it, up to ``run_trainer``; returns what the launcher and that role got."""
    import racer.launcher as launcher
    import trainer.process as process

    seen: dict = {}

    def spawn_role(role_args: list[str], log: Path) -> subprocess.Popen:
        if role_args[0] == "trainer":
            seen["trainer_args"] = role_args
            done = CliRunner().invoke(app, role_args)
            assert done.exit_code == 0, done.output
        return _Done()

    def run_trainer(run, opts, stop=None) -> dict:
        seen["trainer"] = opts
        return {}

    def watch(run, opts, redis_url, *, trainer, workers, console) -> dict:
        seen["launcher"] = opts
        return {}

    monkeypatch.setattr(launcher, "spawn_role", spawn_role)
    monkeypatch.setattr(launcher, "_watch", watch)
    monkeypatch.setattr(process, "run_trainer", run_trainer)
    before = time.time()
    done = CliRunner().invoke(app, ["train", *args])
    assert done.exit_code == 0, done.output
    seen["window"] = (before, time.time())
    return seen


def test_time_limit_goes_from_the_cli_into_the_trainer_role_as_one_deadline(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = str(tmp_path / "store")
    args = ["--time-limit", "90s", "--store", store, "--run-id", "r1", "--workers", "1", "--no-eval", "--device", "cpu"]
    seen = _train_through_the_trainer_role(monkeypatch, args)
    launcher_deadline, trainer_deadline = seen["launcher"].deadline, seen["trainer"].deadline
    assert seen["launcher"].time_limit_s == 90.0
    assert launcher_deadline is not None and launcher_deadline == trainer_deadline  # the very same moment
    assert launcher_deadline.limit_s == 90.0
    before, after = seen["window"]
    assert before + 90.0 <= launcher_deadline.at <= after + 90.0
    # The trainer got it as JSON, not as a text it parses again.
    assert "--options" in seen["trainer_args"] and "--time-limit" not in seen["trainer_args"]


def test_an_explicit_eval_episodes_3_beats_the_drfc_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = drfc_folder(tmp_path / "drfc", "DR_EVAL_NUMBER_OF_TRIALS=5\n")
    common = ["--store", str(tmp_path / "store"), "--workers", "1", "--from-drfc", str(folder), "--device", "cpu"]
    explicit = _train_through_the_trainer_role(monkeypatch, ["--run-id", "a", "--eval-episodes", "3", *common])
    assert explicit["launcher"].eval_episodes == 3
    from_folder = _train_through_the_trainer_role(monkeypatch, ["--run-id", "b", *common])
    assert from_folder["launcher"].eval_episodes == 5


def test_racer_trainer_alone_parses_its_time_limit_once_into_the_deadline(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import trainer.process as process

    seen: dict = {}
    monkeypatch.setattr(process, "run_trainer", lambda run, opts, stop=None: seen.update(run=run, opts=opts))
    args = ["trainer", "--run-id", "alone", "--track", "racer_straight", "--redis", "redis://127.0.0.1:1/0"]
    args += ["--store", str(tmp_path / "store"), "--device", "cpu"]
    before = time.time()
    done = CliRunner().invoke(app, [*args, "--time-limit", "2m"])
    assert done.exit_code == 0, done.output
    deadline = seen["opts"].deadline
    assert deadline.limit_s == 120.0 and before + 120.0 <= deadline.at <= time.time() + 120.0
    assert seen["run"].run_id == "alone" and seen["opts"].torch_threads == DEFAULT_TRAINER_THREADS  # as racer train
    bad = CliRunner().invoke(app, [*args, "--time-limit", "soon"])
    assert bad.exit_code == 2 and "--time-limit 'soon' is not valid" in bad.output


def _parsed(args: list[str]) -> dict:
    """What the real role command (``racer worker|evaluator|trainer``) makes of ``args``: its parameters, as click
    parses them (nothing runs)."""
    import typer.main

    command = typer.main.get_command(app)
    with command.make_context("racer", list(args), resilient_parsing=False) as ctx:
        role = command.get_command(ctx, args[0])
        return role.make_context(args[0], list(args[1:])).params


def test_each_role_s_command_line_is_derived_from_the_run_options_and_parses_back_to_them() -> None:
    """racer train starts its roles with ``RunOptions.worker_args`` / ``evaluator_args`` / ``role_args``: the roles'
    own commands read back every value, non-defaults included."""
    opts = RunOptions(
        run_id="r1",
        redis_url="redis://127.0.0.1:7001/0",
        store="/tmp/store",
        s3_endpoint="http://127.0.0.1:9000",
        envs_per_worker=3,
        eval_every=4,
        eval_episodes=5,
        eval_nice=7,
        eval_tracks=["racer_loop", "racer_wide"],
        eval_both_directions=False,
        device="cpu",
    )
    where = {"run_id": "r1", "redis_url": opts.redis_url, "store": "/tmp/store", "s3_endpoint": opts.s3_endpoint}
    worker = _parsed(opts.worker_args(2))
    assert {k: worker[k] for k in where} == where and (worker["index"], worker["envs_per_worker"]) == (2, 3)
    evaluator = _parsed(opts.evaluator_args())
    assert {k: evaluator[k] for k in where} == where
    assert (evaluator["every"], evaluator["episodes"], evaluator["nice"], evaluator["device"]) == (4, 5, 7, "cpu")
    assert list(evaluator["track"]) == ["racer_loop", "racer_wide"] and evaluator["forward_only"] is True
    trainer = _parsed(["trainer", *opts.role_args()])
    assert {k: trainer[k] for k in where} == where
    # Left unset, the evaluator's starts are the role's own default, the one racer train uses.
    default = _parsed(RunOptions(run_id="r1", redis_url="redis://h:1/0").evaluator_args())
    assert default["episodes"] == DEFAULT_EVAL_EPISODES and default["forward_only"] is False
    with pytest.raises(ValueError, match="run id and the Redis URL"):
        RunOptions().worker_args(0)
