"""The one error type for what a user must fix, and how such an error is said in one line.

Every error a user can cause or cure (a bad file, option or name; a service that cannot be reached) derives from
:class:`UserError`. The CLI turns it into a one-line message and exit code 2 in one place (``racer/cli.py``);
any other exception is a bug in racer and keeps its traceback.
"""

from __future__ import annotations


class UserError(Exception):
    """Something the user gave or runs racer against that racer cannot honour; the message names it."""


class OptionError(UserError, ValueError):
    """A command-line option or setting with a value racer cannot honour (a duration, a run id, a version…)."""


def one_line(exc: BaseException) -> str:
    """The error as one line: a pydantic error names the model, the key and the bad value; others their first line."""
    if callable(getattr(exc, "errors", None)) and hasattr(exc, "title"):  # pydantic's, without importing pydantic
        return f"{exc.title}: {first_validation_error(exc)}"
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def first_validation_error(exc: Exception) -> str:
    """``<key>: <reason> (got <value>)`` for the first error of a ``pydantic.ValidationError``."""
    return validation_error_line(exc.errors()[0])  # type: ignore[attr-defined]


def validation_error_line(error: dict) -> str:
    """``<key>: <reason> (got <value>)`` for one entry of a ``pydantic.ValidationError``'s ``errors()``."""
    where = ".".join(str(part) for part in error.get("loc", ())) or "(top level)"
    got = repr(error.get("input"))
    got = got if len(got) <= 60 else got[:57] + "..."
    return f"{where}: {error.get('msg', 'invalid')} (got {got})"
