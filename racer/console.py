"""racer's rich consoles, all made here: piped or redirected, what racer prints is never hard-wrapped.

Rich wraps every line at the console's width, and a pipe has none: rich takes 80 columns for it and split a line
that names a command or a path in two (``racer status --run-id`` ⏎ ``run-…``), which a user copying it or a script
reading it then gets wrong. A console made by :func:`new_console` soft-wraps when its file is not a terminal: each
line goes out whole and the reader (a terminal, a pager) wraps it. In a terminal it wraps at the terminal's width
as rich does.
"""

from __future__ import annotations

from typing import Any

from rich.console import Console


class _SoftWrapWhenPiped(Console):
    """A console whose ``print`` does not hard-wrap lines when its file is not a terminal."""

    def print(self, *objects: Any, soft_wrap: bool | None = None, **kwargs: Any) -> None:
        """Rich's ``print``; a ``soft_wrap`` left unset is True when piped or redirected."""
        if soft_wrap is None:
            # Asked at each print, not once: the file may change (a console made at import time prints to whatever
            # sys.stdout is then, a test runner's capture for one).
            soft_wrap = self.soft_wrap or not self.is_terminal
        super().print(*objects, soft_wrap=soft_wrap, **kwargs)


def new_console(*, stderr: bool = False, **kwargs: Any) -> Console:
    """A rich console on standard output (or standard error): every console racer prints with comes from here.
    ``kwargs`` are rich's ``Console`` arguments."""
    return _SoftWrapWhenPiped(stderr=stderr, **kwargs)
