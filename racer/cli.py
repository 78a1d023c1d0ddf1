"""The ``racer`` command line: the app, its commands (from ``racer/commands/``) and the one place where an error
becomes what the user reads.

A :class:`common.errors.UserError`, or an error from a library that only a user's input or machine can cause (a
refused Redis connection, a missing file, a config that does not validate), is printed as one line on stderr
with exit code 2. Any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import sys
from typing import Annotated, Any

import typer
from rich.markup import escape
from typer.core import TyperGroup

from common.errors import UserError, one_line
from racer.commands import bench, car_model, deploy, evaluate, models, roles, tracks, train, view
from racer.console import new_console
from racer.help import use_racer_help_layout
from racer.lifecycle import USER_ERROR_EXIT


def _user_errors() -> tuple[type[BaseException], ...]:
    """UserError, and the library errors that only the user's input or machine can cause."""
    import redis
    from pydantic import ValidationError

    return (
        UserError,
        redis.ConnectionError,
        redis.AuthenticationError,
        TimeoutError,
        ValidationError,
        FileNotFoundError,
        IsADirectoryError,
        NotADirectoryError,
        PermissionError,
    )


def _print_error(message: str) -> None:
    # Escaped: a message is plain text (a path, or "pip install 'racer[deepracer]'"), not rich markup.
    new_console(stderr=True).print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)


class _UserErrorsInOneLine(TyperGroup):
    """The root command group: a user error raised by any command becomes one line and exit code 2."""

    def invoke(self, ctx: Any) -> Any:
        try:
            return super().invoke(ctx)
        except _user_errors() as exc:
            _print_error(one_line(exc))
            raise typer.Exit(USER_ERROR_EXIT) from None


app = typer.Typer(cls=_UserErrorsInOneLine, no_args_is_help=True, help="racer: DeepRacer-style RL on MuJoCo.")
use_racer_help_layout()  # option names whole in --help at any width (racer/help.py)


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        new_console().print(f"racer {version('racer')}", highlight=False)
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Show racer's version and exit.")
    ] = False,
) -> None:
    """racer: DeepRacer-style RL on MuJoCo."""


app.command("train")(train.train)
app.command("check")(train.check)
app.command("trainer")(roles.trainer)
app.command("worker")(roles.worker)
app.command("evaluator")(roles.evaluator)
app.command("status")(roles.status)
app.command("eval")(evaluate.evaluate)
app.command("plot")(evaluate.plot)
app.command("export")(deploy.export)
app.command("import")(deploy.import_model)
app.command("car")(deploy.car)
app.command("calibrate")(car_model.calibrate)
app.command("limit")(car_model.limit)
app.command("drive")(tracks.drive)
app.command("view")(view.view)
app.add_typer(models.app, name="models")
app.add_typer(tracks.app, name="tracks")
app.add_typer(bench.app, name="bench")


def _given_value(exc: Exception) -> str:
    """`` (got 'two')`` for a bad option value: typer's conversion messages do not repeat what the user typed."""
    opts = getattr(getattr(exc, "param", None), "opts", None) or []
    argv = sys.argv[1:]
    for i, arg in enumerate(argv):
        for opt in opts:
            if arg == opt and i + 1 < len(argv):
                return f" (got {argv[i + 1]!r})"
            if arg.startswith(f"{opt}="):
                return f" (got {arg.split('=', 1)[1]!r})"
    return ""


def main() -> None:
    """Entry point for ``racer`` and ``python -m racer``: a bad option or argument is one line too, not a box."""
    try:
        code = app(standalone_mode=False)  # a typer.Exit comes back as its exit code here
    except typer.TyperException as exc:  # click's usage errors (typer vendors click)
        ctx = getattr(exc, "ctx", None)
        hint = f" (see {ctx.command_path} --help)" if ctx is not None else ""
        _print_error(f"{exc.format_message()}{_given_value(exc)}{hint}")
        sys.exit(getattr(exc, "exit_code", USER_ERROR_EXIT))
    except typer.Abort:
        new_console(stderr=True).print("aborted")
        sys.exit(130)
    sys.exit(code if isinstance(code, int) else 0)
