"""The DeepRacer reward-function API: load a user's ``reward_function(params)`` file and call it safely.

A DeepRacer reward file is a plain Python file defining ``reward_function(params) -> float``,
where ``params`` is a dict with the keys in :data:`PARAM_KEYS`. Files written for AWS DeepRacer
run here unchanged. Everything that can go wrong with such a file (missing, not Python, raising,
returning garbage, hanging) is reported as a one-line :class:`RewardFunctionError` naming the
file, and the step when it happened during a call, so a training run fails early and legibly.
"""

from __future__ import annotations

import importlib.util
import inspect
import itertools
import math
import re
import signal
import sys
import threading
import time
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

from common.errors import UserError

PARAM_KEYS: tuple[str, ...] = (
    "all_wheels_on_track",
    "x",
    "y",
    "heading",
    "distance_from_center",
    "projection_distance",
    "progress",
    "steps",
    "speed",
    "steering_angle",
    "track_width",
    "track_length",
    "waypoints",
    "closest_waypoints",
    "is_left_of_center",
    "is_reversed",
    "is_crashed",
    "is_offtrack",
    "closest_objects",
    "objects_location",
    "objects_left_of_center",
    "object_in_camera",
    "objects_speed",
    "objects_heading",
    "objects_distance_from_center",
    "objects_distance",
    "sim_time",
)
"""Every key of the ``params`` dict DeepRacer passes to ``reward_function``, in its documented order."""

DEFAULT_EXAMPLE = "default"
"""Name of the example racer uses when the user gives no reward function."""

_MAX_DETAIL_CHARS = 300
_module_ids = itertools.count()


class RewardFunctionError(UserError, ValueError):
    """A reward function that cannot be used; the one-line message names the file and what is wrong."""


class _RewardTimeout(BaseException):
    """Raised by the SIGALRM handler; a BaseException so a user's ``except Exception`` cannot swallow it."""


def _one_line(text: str) -> str:
    """Collapse whitespace (user messages may be multi-line) and cap the length, for one-line errors."""
    flat = " ".join(str(text).split())
    return flat if len(flat) <= _MAX_DETAIL_CHARS else flat[: _MAX_DETAIL_CHARS - 3] + "..."


def _describe(exc: BaseException) -> str:
    """``Type: message`` for an exception, on one line."""
    detail = _one_line(str(exc))
    return f"{type(exc).__name__}: {detail}" if detail else type(exc).__name__


def _user_line(tb: TracebackType | None, path: Path) -> int | None:
    """The line of ``path`` deepest in a traceback, so errors point into the user's file."""
    line = None
    for frame, lineno in _walk_tb(tb):
        if frame.f_code.co_filename == str(path):
            line = lineno
    return line


def _walk_tb(tb: TracebackType | None) -> list[tuple[FrameType, int]]:
    frames = []
    while tb is not None:
        frames.append((tb.tb_frame, tb.tb_lineno))
        tb = tb.tb_next
    return frames


FIRST_CALL_TIME_LIMIT_S = 30.0
"""Seconds the first call of a loaded reward function may take (it often builds a racing line or a table)."""


def _where(path: Path, step: int | None) -> str:
    return f"reward function {str(path)!r}" + ("" if step is None else f" at step {step}")


class RewardFunction:
    """A loaded user ``reward_function``: call it with a params dict (and the step) to get a float.

    ``time_limit_s`` bounds each call (``None``: no bound), except the first, which may take up to
    ``first_call_time_limit_s`` (``None``: the same bound): reward functions commonly build a racing line or
    a lookup table on their first call, and DeepRacer, which bounds no call, runs them. The bound is enforced with
    SIGALRM, so only when called from the main thread on a platform with ``signal.setitimer``; elsewhere calls are
    unbounded. Python code is interrupted between bytecodes, so a long call into C is cut only
    when it returns.
    """

    def __init__(
        self,
        path: str | Path,
        fn: Callable[[dict], Any],
        time_limit_s: float | None = 1.0,
        first_call_time_limit_s: float | None = FIRST_CALL_TIME_LIMIT_S,
    ) -> None:
        for name, value in (("time_limit_s", time_limit_s), ("first_call_time_limit_s", first_call_time_limit_s)):
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds or None, got {value!r}")
        self.path = Path(path)
        self.fn = fn
        self.time_limit_s = time_limit_s
        self.first_call_time_limit_s = first_call_time_limit_s
        self._called = False

    def __repr__(self) -> str:
        return f"RewardFunction({str(self.path)!r}, time_limit_s={self.time_limit_s!r})"

    def __reduce__(self) -> tuple[Any, ...]:
        # The user's module is not in sys.modules, so the function itself cannot be pickled;
        # reload it from its file instead (e.g. when handing it to a spawned rollout worker).
        return (load_reward_function, (self.path, self.time_limit_s, self.first_call_time_limit_s))

    def __call__(self, params: dict, step: int | None = None) -> float:
        """Return the user's reward for ``params`` as a float; raise RewardFunctionError on any failure.

        Like the simapp (``rollout_agent_ctrl.judge_action`` calls ``reward_function(copy.deepcopy(params))``),
        every call gets its own copy of ``params``, containers included: a function that changes
        ``params['waypoints']`` cannot change what the next step sees.
        """
        where = _where(self.path, step)
        limit = self._limit()
        try:
            value = self._call_limited(fresh_params(params), limit)
        except _RewardTimeout:
            suffix = "" if step is None else f" at step {step}"
            raise RewardFunctionError(
                f"reward function {str(self.path)!r} took longer than {limit} s{suffix}"
            ) from None
        except (Exception, SystemExit) as exc:
            line = _user_line(exc.__traceback__, self.path)
            at_line = "" if line is None else f" (line {line})"
            raise RewardFunctionError(f"{where} raised {_describe(exc)}{at_line}") from exc
        return _to_reward(value, where)

    def _limit(self) -> float | None:
        """This call's time limit: the first call of a loaded function gets the larger one."""
        first, self._called = not self._called, True
        if first and self.time_limit_s is not None and self.first_call_time_limit_s is not None:
            return max(self.time_limit_s, self.first_call_time_limit_s)
        return self.time_limit_s

    def _call_limited(self, params: dict, limit: float | None) -> Any:
        """Call the function, under a SIGALRM timer of ``limit`` seconds when that is possible here."""
        if (
            limit is None
            or not hasattr(signal, "setitimer")
            or threading.current_thread() is not threading.main_thread()
        ):
            return self.fn(params)

        fired = False

        def on_alarm(signum: int, frame: FrameType | None) -> None:
            nonlocal fired
            fired = True
            raise _RewardTimeout

        previous_handler = signal.signal(signal.SIGALRM, on_alarm)
        previous_delay, previous_interval = signal.setitimer(signal.ITIMER_REAL, limit)
        started = time.monotonic()
        try:
            try:
                result = self.fn(params)
            finally:
                # Disarm before anything else; if the alarm lands right here the outer handler
                # still sees _RewardTimeout, which is right: the call did use up its time.
                signal.setitimer(signal.ITIMER_REAL, 0)
        finally:
            # signal.signal returns None for a handler not installed from Python; SIG_DFL is
            # the closest thing we can put back.
            signal.signal(signal.SIGALRM, signal.SIG_DFL if previous_handler is None else previous_handler)
            if previous_delay > 0:
                # Re-arm an outer timer with what is left of it (a tiny delay if it is already
                # due, so it still fires rather than being lost).
                remaining = max(previous_delay - (time.monotonic() - started), 1e-6)
                signal.setitimer(signal.ITIMER_REAL, remaining, previous_interval)
        if fired:
            # The user caught the timeout with a bare ``except:`` and returned anyway.
            raise _RewardTimeout
        return result


REWARD_LIMIT = 1e5
"""The simapp stops a run whose reward function returns a value outside [-1e5, 1e5]."""


def fresh_params(params: dict) -> dict:
    """A copy of ``params`` whose lists and dicts are new: the same result as ``copy.deepcopy`` for the params
    dict (its tuples hold only numbers, so they can be shared), at a fraction of its cost per step."""
    return {key: _fresh(value) for key, value in params.items()}


def _fresh(value: Any) -> Any:
    if isinstance(value, list):
        # params' lists are homogeneous: a list of tuples or numbers (waypoints: hundreds of them, every step)
        # needs only a new list; a list of lists (objects_location) is copied a level deeper.
        if not value or not isinstance(value[0], list | dict):
            return value.copy()
        return [_fresh(v) for v in value]
    if isinstance(value, dict):
        return {k: _fresh(v) for k, v in value.items()}
    return value


def _to_reward(value: object, where: str) -> float:
    """The reward as the simapp takes it: ``float(value)``, so bools, ints and numpy scalars are accepted.

    Refused: what ``float()`` refuses (None, lists, a non-numeric string), a value outside
    [-REWARD_LIMIT, REWARD_LIMIT] (the simapp stops there too), and NaN, which the simapp's range check lets
    through but which would poison every advantage in the batch.
    """
    try:
        reward = float(value)  # type: ignore[arg-type]
    except (OverflowError, ValueError, TypeError) as exc:
        return_desc = _one_line(repr(value))
        raise RewardFunctionError(
            f"{where} returned {return_desc} ({type(value).__name__}), which float() refuses: {_describe(exc)}"
        ) from None
    if math.isnan(reward):
        raise RewardFunctionError(f"{where} returned {reward}; the reward must be a number")
    if not -REWARD_LIMIT <= reward <= REWARD_LIMIT:
        raise RewardFunctionError(
            f"{where} returned {reward}, outside [-{REWARD_LIMIT:g}, {REWARD_LIMIT:g}] where DeepRacer stops the run"
        )
    return reward


def load_reward_function(
    path: str | Path, time_limit_s: float | None = 1.0, first_call_time_limit_s: float | None = FIRST_CALL_TIME_LIMIT_S
) -> RewardFunction:
    """Load ``reward_function`` from a user's ``.py`` file, as a fresh module each time.

    Raises RewardFunctionError if the file is missing, not a readable ``.py`` file, has a syntax
    error, raises while being imported, or lacks a ``reward_function`` callable with one argument.
    """
    path = Path(path)
    name = f"reward function file {str(path)!r}"
    if not path.exists():
        raise RewardFunctionError(f"{name} does not exist")
    if not path.is_file() or path.suffix != ".py":
        raise RewardFunctionError(f"{name} is not a .py file")
    try:
        source = path.read_bytes()
    except OSError as exc:
        raise RewardFunctionError(f"{name} cannot be read: {_describe(exc)}") from exc
    try:
        # Compiling ourselves (rather than spec.loader.exec_module) separates the user's syntax
        # errors from ones raised while running it, and writes no __pycache__ into their folder.
        code = compile(source, str(path), "exec", dont_inherit=True)
    except SyntaxError as exc:
        raise RewardFunctionError(f"{name} has a syntax error at line {exc.lineno}: {_one_line(exc.msg)}") from exc
    except ValueError as exc:  # undecodable bytes or NUL bytes, depending on the Python version
        raise RewardFunctionError(f"{name} is not valid Python source: {_describe(exc)}") from exc

    module = _new_module(path)
    # Some library code run at import (dataclasses, typing) looks the module up in sys.modules,
    # so it is there while the file runs, then removed: each load stays independent.
    sys.modules[module.__name__] = module
    try:
        exec(code, module.__dict__)
    except (Exception, SystemExit) as exc:
        line = _user_line(exc.__traceback__, path)
        at_line = "" if line is None else f" (line {line})"
        raise RewardFunctionError(f"{name} raised {_describe(exc)} while being imported{at_line}") from exc
    finally:
        sys.modules.pop(module.__name__, None)

    if not hasattr(module, "reward_function"):
        raise RewardFunctionError(f"{name} does not define reward_function(params)")
    fn = module.reward_function
    if not callable(fn):
        raise RewardFunctionError(f"{name} defines reward_function as a {type(fn).__name__}, not a function")
    _check_signature(fn, name)
    return RewardFunction(path, fn, time_limit_s, first_call_time_limit_s)


def _new_module(path: Path) -> Any:
    """An empty module for ``path`` with a name unique to this load, so two reward.py files don't clash."""
    stem = re.sub(r"\W", "_", path.stem)
    spec = importlib.util.spec_from_file_location(f"_racer_reward_{next(_module_ids)}_{stem}", path)
    if spec is None:  # only for suffixes importlib does not know; .py is checked above
        raise RewardFunctionError(f"reward function file {str(path)!r} cannot be loaded as a module")
    return importlib.util.module_from_spec(spec)


def _check_signature(fn: Callable[..., Any], name: str) -> None:
    """Raise RewardFunctionError unless ``fn`` can be called as ``fn(params)``."""
    try:
        signature = inspect.signature(fn)
    except (TypeError, ValueError):
        return  # some builtins have no introspectable signature; the first call will tell
    try:
        signature.bind(object())
    except TypeError as exc:
        raise RewardFunctionError(
            f"{name} defines reward_function{signature}, which cannot be called with one argument "
            f"(params): {_one_line(str(exc))}"
        ) from None


def _example_files() -> dict[str, Path]:
    # The examples are plain files (no __init__.py) shipped as package data, so list the folder.
    folder = resources.files("sim") / "reward_examples"
    files = (p for p in folder.iterdir() if p.name.endswith(".py") and not p.name.startswith("_"))
    return {p.name[:-3]: Path(str(p)) for p in sorted(files, key=lambda p: p.name)}


EXAMPLES: dict[str, Path] = _example_files()
"""Shipped example reward files by name: racer's ``default``, its versions of DeepRacer's documented examples (the
same rewards, racer's own code), ``racing_line`` and ``object_avoidance``."""


def example_path(name: str) -> Path:
    """Path of the shipped example reward file ``name``; RewardFunctionError if there is none."""
    try:
        return EXAMPLES[name]
    except KeyError:
        known = ", ".join(EXAMPLES)
        raise RewardFunctionError(f"no reward example named {name!r}; known: {known}") from None
