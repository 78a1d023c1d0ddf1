"""The one error type for what a user must fix, and how such an error is said in one line.

Every error a user can cause or cure (a bad file, option or name; a service that cannot be reached) derives from
:class:`UserError`. The CLI turns it into a one-line message and exit code 2 in one place (``racer/cli.py``);
any other exception is a bug in racer and keeps its traceback.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable


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


def error_location(loc: Iterable[object]) -> str:
    """A pydantic error's ``loc`` as ``a.b.0``; a key that would not print as itself on one line (a newline, a
    control character, an empty key) is quoted as Python writes it, so the error stays one line."""
    return ".".join(str(p) if str(p).isprintable() and str(p) else repr(p) for p in loc)


def validation_error_line(error: dict) -> str:
    """``<key>: <reason> (got <value>)`` for one entry of a ``pydantic.ValidationError``'s ``errors()``."""
    where = error_location(error.get("loc", ())) or "(top level)"
    got = repr(error.get("input"))
    got = got if len(got) <= 60 else got[:57] + "..."
    return f"{where}: {error.get('msg', 'invalid')} (got {got})"


def did_you_mean(given: str, known: Iterable[str], n: int = 3) -> str:
    """``did you mean 'a' or 'b'?`` for the known names closest to a misspelt one, or '' when none is close.

    Compared without case: DeepRacer's names mix it (``reInvent2019_wide``), and users rarely type it right."""
    by_folded: dict[str, str] = {}
    for name in known:
        by_folded.setdefault(name.lower(), name)
    folded = given.lower()
    matches = difflib.get_close_matches(folded, list(by_folded), n=n, cutoff=0.6)
    # A name cut short ("Oval" for Oval_track) is too unlike the whole name for difflib, yet plainly meant.
    matches += [f for f in sorted(by_folded) if len(folded) >= 3 and f.startswith(folded) and f not in matches]
    close = [repr(by_folded[f]) for f in matches[:n]]
    if not close:
        return ""
    head, last = close[:-1], close[-1]
    return f"did you mean {', '.join(head) + ' or ' if head else ''}{last}?"
