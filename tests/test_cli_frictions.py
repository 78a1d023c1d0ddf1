"""What new users tripped over on the command line, each through the real CLI: piped output cut into 80-column
lines, option names cut in ``--help``, a time limit without its unit read as seconds, and a store path that does not
exist read as an empty store."""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
import typer.main
from typer.testing import CliRunner

from model_store import RunStore, open_store
from racer.cli import app

ROOT = Path(__file__).resolve().parent.parent


def invoke(*args: str, **env: str):
    """``racer ARGS`` in this process, its output captured as a pipe captures it (not a terminal), 80 columns."""
    return CliRunner().invoke(app, list(args), env={"COLUMNS": "80", **env})


def assert_one_line_error(result, *expected: str) -> None:
    """Exit code 2 and one line on stderr holding every ``expected`` text."""
    assert result.exit_code == 2, (result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert all(text in lines[0] for text in expected), lines[0]


# --- piped output is not hard-wrapped --------------------------------------------------------------------------------


def test_piped_output_keeps_a_line_longer_than_80_columns_whole(tmp_path: Path) -> None:
    """``racer status`` piped printed ``racer status --run-id`` ⏎ ``run-…``: rich wrapped it at 80 columns."""
    run_id = "a-run-with-a-long-name-" + "x" * 40
    RunStore(open_store(str(tmp_path))).save_checkpoint(run_id, 1, b"weights", {"env_steps": 1})
    result = invoke("models", "prune", "--store", str(tmp_path), "--dry-run")
    assert result.exit_code == 0, result.output
    line = f"{run_id}: would free 0.0 MB (0 checkpoints, 0 optimizer states)"
    assert len(line) > 80 and line in result.stdout.splitlines(), result.stdout


# --- --help never cuts an option name -------------------------------------------------------------------------------


def _commands(command, path: list[str]) -> Iterator[tuple[list[str], object]]:
    yield path, command
    for name, sub in getattr(command, "commands", {}).items():
        yield from _commands(sub, [*path, name])


COMMANDS = list(_commands(typer.main.get_command(app), []))


def _names(command) -> list[str]:
    """Every option name and env var name the command declares."""
    names = [name for p in command.params for name in (*p.opts, *p.secondary_opts) if name.startswith("-")]
    envvars = [getattr(p, "envvar", None) for p in command.params]
    return names + [e for e in envvars if isinstance(e, str)]


@pytest.mark.parametrize(("path", "command"), COMMANDS, ids=[" ".join(p) or "racer" for p, _ in COMMANDS])
def test_help_at_80_columns_shows_every_option_and_env_var_name_whole(path: list[str], command) -> None:
    """``--both-directio…``, ``--car,--car-cal…`` and ``RACER_ENVS_PER_WORK…`` were cut to fit 80 columns."""
    result = invoke(*path, "--help")
    assert result.exit_code == 0, result.output
    assert all(len(line) <= 80 for line in result.output.splitlines())
    whole = [n for n in _names(command) if re.search(rf"(?<![\w-]){re.escape(n)}(?![\w-])", result.output)]
    assert whole == _names(command), result.output


# --- a duration without a unit is refused -----------------------------------------------------------------------------

BARE = "5"
"""A duration without a unit: five seconds to racer once, five minutes to the user who typed it."""


def test_train_refuses_a_time_limit_without_a_unit_before_anything_is_made(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    store = tmp_path / "store"
    result = invoke("train", "--time-limit", BARE, "--store", str(store), "--run-id", "r1")
    assert_one_line_error(result, "--time-limit 5: give a unit: 5s, 5m or 5h")
    assert list(tmp_path.iterdir()) == [], "no store, no run id taken, nothing written"


ROLE = ["--run-id", "r1", "--redis", "redis://127.0.0.1:1/0"]
"""A role's required options (the error comes before it connects)."""


@pytest.mark.parametrize(
    ("args", "env", "expected"),
    [
        (["worker", *ROLE, "--outage-timeout", BARE], {}, "--outage-timeout 5: give a unit"),
        (["worker", *ROLE], {"RACER_OUTAGE_TIMEOUT": "90"}, "--outage-timeout 90: give a unit: 90s, 90m or 90h"),
        (["trainer", *ROLE], {"RACER_TIME_LIMIT": "1.5"}, "--time-limit 1.5: give a unit: 1.5s, 1.5m or 1.5h"),
        (["bench", "loop", "--duration", BARE], {}, "--duration 5: give a unit"),
        (["bench", "soak", "--duration", BARE], {}, "--duration 5: give a unit"),
        (["bench", "train", "--time-limit", BARE], {}, "--time-limit 5: give a unit"),
    ],
    ids=[
        "worker --outage-timeout",
        "RACER_OUTAGE_TIMEOUT",
        "RACER_TIME_LIMIT",
        "bench loop",
        "bench soak",
        "bench train",
    ],
)
def test_every_duration_flag_and_env_var_refuses_a_bare_number(args: list[str], env: dict, expected: str) -> None:
    assert_one_line_error(invoke(*args, **env), expected)


DURATION = r"(--time-limit|--duration|--outage-timeout|RACER_TIME_LIMIT|RACER_OUTAGE_TIMEOUT)"
BARE_DURATION = [
    # shell, compose, .env; not the refusal quoted ("--time-limit 5: give a unit")
    re.compile(DURATION + r"""[ =:]+["']?\d+(\.\d+)?["']?(?![\w.:])"""),
    re.compile(DURATION + r"""["'],\s*["']\d+(\.\d+)?["']"""),  # a Python argument list
]


def _repository_text_files() -> Iterator[Path]:
    """The repository's docs, compose and env files, scripts and Python."""
    for folder, dirs, files in os.walk(ROOT):
        dirs[:] = [d for d in dirs if d not in {".venv", ".git", ".ruff_cache", "racer.egg-info", "__pycache__"}]
        for name in files:
            path = Path(folder, name)
            if path.suffix in {".md", ".py", ".yml", ".yaml", ".env", ".sh", ".example"} or ".ci" in path.parts:
                yield path


def test_no_command_in_the_docs_compose_files_or_tests_gives_a_bare_duration() -> None:
    files = list(_repository_text_files())
    assert ROOT / "README.md" in files and ROOT / "docker-compose.yml" in files
    bare = [
        f"{f.relative_to(ROOT)}: {m.group(0)}"
        for f in files
        for pattern in BARE_DURATION
        for m in pattern.finditer(f.read_text(errors="replace"))
    ]
    assert bare == []


# --- a store to read must exist -----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "args",
    [["models", "ls"], ["models", "prune"], ["export", "--run-id", "r1", "-o", "model.onnx"]],
    ids=lambda a: " ".join(a[:2]),
)
def test_a_command_that_reads_a_store_refuses_one_that_does_not_exist(tmp_path: Path, args: list[str]) -> None:
    missing = tmp_path / "nonexistent"
    assert_one_line_error(invoke(*args, "--store", str(missing)), f"--store {missing}: no such directory")
    assert not missing.exists()
    a_file = tmp_path / "file"
    a_file.write_text("")
    assert_one_line_error(invoke(*args, "--store", str(a_file)), f"--store {a_file}: is not a directory")
    assert_one_line_error(invoke(*args, **{"RACER_STORE": str(missing)}), f"--store {missing}")


def test_an_empty_store_is_listed_as_empty_and_train_may_make_its_store(tmp_path: Path) -> None:
    assert invoke("models", "ls", "--store", str(tmp_path)).exit_code == 0
    new = tmp_path / "new"
    # train makes its store when it starts: what stops this one is the track, not the missing folder
    assert_one_line_error(invoke("train", "--store", str(new), "--track", "nope"), "unknown track 'nope'")
