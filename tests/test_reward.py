"""Tests for sim.reward: DeepRacer reward files load unchanged, and every misuse is a clear error."""

from __future__ import annotations

import ast
import math
import pickle
import signal
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sim.reward import (
    DEFAULT_EXAMPLE,
    EXAMPLES,
    PARAM_KEYS,
    RewardFunction,
    RewardFunctionError,
    example_path,
    load_reward_function,
)


def sample_params() -> dict[str, Any]:
    """A plausible DeepRacer params dict with every key of PARAM_KEYS: a car on a 5 m straight track.

    The car is 1.05 m along a track running +x, 2 cm left of the centre line, heading straight
    down it at 1 m/s after one second (15 steps at DeepRacer's 15 Hz); there are no objects.
    """
    waypoints = [(0.5 * i, 0.0) for i in range(11)]
    return {
        "all_wheels_on_track": True,
        "x": 1.05,
        "y": 0.02,
        "heading": 0.0,
        "distance_from_center": 0.02,
        "projection_distance": 1.05,
        "progress": 21.0,
        "steps": 15,
        "speed": 1.0,
        "steering_angle": 0.0,
        "track_width": 0.76,
        "track_length": 5.0,
        "waypoints": waypoints,
        "closest_waypoints": [2, 3],
        "is_left_of_center": True,
        "is_reversed": False,
        "is_crashed": False,
        "is_offtrack": False,
        "closest_objects": [0, 0],
        "objects_location": [],
        "objects_left_of_center": [],
        "object_in_camera": False,
        "objects_speed": [],
        "objects_heading": [],
        "objects_distance_from_center": [],
        "objects_distance": [],
        "sim_time": 1.0,
    }


# racer's own functions with the rewards of the three examples in AWS DeepRacer's developer guide.
AWS_EXAMPLES = ("follow_center_line", "stay_inside_two_borders", "prevent_zig_zag")


def write(tmp_path: Path, source: str, name: str = "my_reward.py") -> Path:
    """Write a reward file into tmp_path and return its path."""
    path = tmp_path / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(source)
    return path


def params(**overrides: object) -> dict:
    """sample_params() with some keys replaced."""
    return {**sample_params(), **overrides}


def load_src(tmp_path: Path, source: str, **kwargs: object) -> RewardFunction:
    return load_reward_function(write(tmp_path, source), **kwargs)


# --- sample params and examples -----------------------------------------------------------------


def test_sample_params_has_every_key_with_plausible_types() -> None:
    p = sample_params()
    assert tuple(p) == PARAM_KEYS
    assert len(set(PARAM_KEYS)) == len(PARAM_KEYS) == 27
    assert isinstance(p["steps"], int) and isinstance(p["all_wheels_on_track"], bool)
    assert 0 <= p["progress"] <= 100 and -180 <= p["heading"] <= 180
    assert p["distance_from_center"] <= p["track_width"] / 2
    wp = p["waypoints"]
    assert all(isinstance(w, tuple) and len(w) == 2 for w in wp)
    assert all(0 <= i < len(wp) for i in p["closest_waypoints"])
    assert sample_params() is not p  # fresh dict each time, callers may mutate it


def test_examples_are_shipped_as_plain_files() -> None:
    assert set(EXAMPLES) == {*AWS_EXAMPLES, DEFAULT_EXAMPLE, "racing_line", "object_avoidance"}  # racer's own two
    for name, path in EXAMPLES.items():
        assert path == example_path(name) and path.is_file() and path.suffix == ".py"
    assert not (example_path("default").parent / "__init__.py").exists()


def test_unknown_example_name() -> None:
    with pytest.raises(RewardFunctionError, match="no_such_example.*follow_center_line"):
        example_path("no_such_example")


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_examples_import_nothing_but_math_and_pass_the_check(name: str) -> None:
    path = example_path(name)
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            pytest.fail(f"{name} uses from-import")
        if isinstance(node, ast.Import):
            assert [a.name for a in node.names] == ["math"]
    load_reward_function(path)(sample_params())


def test_default_is_follow_center_line() -> None:
    def body(name: str) -> str:
        tree = ast.parse(example_path(name).read_text())
        (fn,) = [n for n in tree.body if isinstance(n, ast.FunctionDef)]
        return ast.dump(fn)

    assert body("default") == body("follow_center_line")


@pytest.mark.parametrize("name", ["follow_center_line", "default"])
@pytest.mark.parametrize(
    ("distance", "expected"),
    [(0.0, 1.0), (0.05, 1.0), (0.076, 1.0), (0.15, 0.5), (0.19, 0.5), (0.3, 0.1), (0.38, 0.1), (0.5, 1e-3)],
)
def test_follow_center_line(name: str, distance: float, expected: float) -> None:
    # Markers for width 0.76: 0.076, 0.19, 0.38.
    fn = load_reward_function(example_path(name))
    reward = fn(params(track_width=0.76, distance_from_center=distance))
    assert type(reward) is float
    assert reward == pytest.approx(expected)


@pytest.mark.parametrize(
    ("on_track", "distance", "expected"),
    [
        (True, 0.0, 1.0),
        (True, 0.3, 1.0),  # 0.38 - 0.3 = 0.08 m from the border
        (True, 0.34, 1e-3),  # 0.04 m from the border: too close
        (False, 0.0, 1e-3),
    ],
)
def test_stay_inside_two_borders(on_track: bool, distance: float, expected: float) -> None:
    fn = load_reward_function(example_path("stay_inside_two_borders"))
    reward = fn(params(all_wheels_on_track=on_track, track_width=0.76, distance_from_center=distance))
    assert reward == pytest.approx(expected)


@pytest.mark.parametrize(
    ("distance", "steering", "expected"),
    [
        (0.05, 0.0, 1.0),
        (0.05, 15.0, 1.0),  # at the threshold: no penalty
        (0.05, 20.0, 0.8),
        (0.05, -20.0, 0.8),
        (0.15, 20.0, 0.4),
        (0.3, -30.0, 0.08),
        (0.5, 20.0, 0.8e-3),
    ],
)
def test_prevent_zig_zag(distance: float, steering: float, expected: float) -> None:
    fn = load_reward_function(example_path("prevent_zig_zag"))
    reward = fn(params(track_width=0.76, distance_from_center=distance, steering_angle=steering))
    assert reward == pytest.approx(expected)


def test_user_style_file_with_helper_and_math(tmp_path: Path) -> None:
    fn = load_src(
        tmp_path,
        "import math\n"
        "\n"
        "def heading_error(params):\n"
        "    (x0, y0), (x1, y1) = (params['waypoints'][i] for i in params['closest_waypoints'])\n"
        "    track_dir = math.degrees(math.atan2(y1 - y0, x1 - x0))\n"
        "    return abs(track_dir - params['heading'])\n"
        "\n"
        "def reward_function(params):\n"
        "    return 1.0 if heading_error(params) < 10 else 0.5\n",
    )
    assert fn(params(heading=0.0)) == 1.0
    assert fn(params(heading=30.0)) == 0.5


def test_accepts_python_and_numpy_numbers(tmp_path: Path) -> None:
    for expr, expected in [
        ("2", 2.0),
        ("np.float32(0.5)", 0.5),
        ("np.float64(1.5)", 1.5),
        ("np.int64(3)", 3.0),
    ]:
        rf = RewardFunction(tmp_path / "r.py", lambda p, e=expr: eval(e, {"np": np}))
        reward = rf(sample_params())
        assert type(reward) is float and reward == expected


def test_callable_object_with_defaults_is_accepted(tmp_path: Path) -> None:
    fn = load_src(tmp_path, "def reward_function(params, scale=2.0, *rest):\n    return scale\n")
    assert fn(sample_params()) == 2.0


def test_caller_params_not_mutated(tmp_path: Path) -> None:
    fn = load_src(
        tmp_path,
        "def reward_function(params):\n    params['speed'] = -1\n    params['extra'] = 1\n    return 1.0\n",
    )
    p = sample_params()
    fn(p)
    assert p == sample_params()


def test_two_files_with_same_name_are_independent(tmp_path: Path) -> None:
    # Module-level state too: each load gets its own module.
    src = "VALUE = {v}\ncalls = []\n\ndef reward_function(params):\n    calls.append(1)\n    return VALUE\n"
    a = load_reward_function(write(tmp_path / "a", src.format(v=1.0), "reward.py"))
    b = load_reward_function(write(tmp_path / "b", src.format(v=2.0), "reward.py"))
    a_again = load_reward_function(tmp_path / "a" / "reward.py")
    assert (a(sample_params()), b(sample_params()), a_again(sample_params())) == (1.0, 2.0, 1.0)
    assert a.fn.__globals__ is not a_again.fn.__globals__
    assert a.fn.__globals__["calls"] == [1]
    assert a.fn.__module__ not in __import__("sys").modules


def test_dataclass_in_user_file(tmp_path: Path) -> None:
    # dataclasses looks the module up in sys.modules while the file runs.
    fn = load_src(
        tmp_path,
        "from __future__ import annotations\n"
        "from dataclasses import dataclass\n\n"
        "@dataclass\nclass W:\n    w: float = 0.5\n\n"
        "def reward_function(params):\n    return W().w\n",
    )
    assert fn(sample_params()) == 0.5


def test_pickle_reloads_from_file(tmp_path: Path) -> None:
    fn = load_src(tmp_path, "def reward_function(params):\n    return 0.25\n", time_limit_s=3.0)
    copy = pickle.loads(pickle.dumps(fn))
    assert copy.path == fn.path and copy.time_limit_s == 3.0 and copy(sample_params()) == 0.25


# --- load errors --------------------------------------------------------------------------------


def assert_one_line_error(exc_info: pytest.ExceptionInfo, *fragments: str) -> str:
    message = str(exc_info.value)
    assert "\n" not in message
    for fragment in fragments:
        assert fragment in message, message
    return message


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(RewardFunctionError) as info:
        load_reward_function(tmp_path / "nope.py")
    assert_one_line_error(info, "nope.py", "does not exist")


def test_not_a_py_file(tmp_path: Path) -> None:
    for path in (write(tmp_path, "def reward_function(p): return 1\n", "reward.txt"), tmp_path):
        with pytest.raises(RewardFunctionError) as info:
            load_reward_function(path)
        assert_one_line_error(info, path.name, "not a .py file")


def test_syntax_error_names_line(tmp_path: Path) -> None:
    path = write(tmp_path, "def reward_function(params):\n    return 1.0\n\nif x\n    pass\n")
    with pytest.raises(RewardFunctionError) as info:
        load_reward_function(path)
    assert_one_line_error(info, "my_reward.py", "syntax error", "line 4")


def test_indentation_error(tmp_path: Path) -> None:
    with pytest.raises(RewardFunctionError) as info:
        load_src(tmp_path, "def reward_function(params):\nreturn 1.0\n")
    assert_one_line_error(info, "my_reward.py", "line 2")


def test_import_time_exception(tmp_path: Path) -> None:
    with pytest.raises(RewardFunctionError) as info:
        load_src(tmp_path, "import math\nX = 1 / 0\n\ndef reward_function(params):\n    return 1.0\n")
    assert_one_line_error(info, "my_reward.py", "ZeroDivisionError", "imported", "line 2")


def test_import_of_missing_module(tmp_path: Path) -> None:
    with pytest.raises(RewardFunctionError) as info:
        load_src(tmp_path, "import no_such_module_xyz\n\ndef reward_function(params):\n    return 1.0\n")
    assert_one_line_error(info, "my_reward.py", "ModuleNotFoundError", "no_such_module_xyz")


def test_no_reward_function(tmp_path: Path) -> None:
    with pytest.raises(RewardFunctionError) as info:
        load_src(tmp_path, "def reward(params):\n    return 1.0\n")
    assert_one_line_error(info, "my_reward.py", "does not define reward_function")


def test_reward_function_not_callable(tmp_path: Path) -> None:
    with pytest.raises(RewardFunctionError) as info:
        load_src(tmp_path, "reward_function = 1.0\n")
    assert_one_line_error(info, "my_reward.py", "float", "not a function")


@pytest.mark.parametrize(
    "signature",
    ["params, other", "", "*, params", "params, /, other"],
)
def test_wrong_signature(tmp_path: Path, signature: str) -> None:
    with pytest.raises(RewardFunctionError) as info:
        load_src(tmp_path, f"def reward_function({signature}):\n    return 1.0\n")
    assert_one_line_error(info, "my_reward.py", f"reward_function({signature})", "one argument")


def test_bad_time_limit(tmp_path: Path) -> None:
    for bad in (0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="time_limit_s"):
            RewardFunction(tmp_path / "r.py", lambda p: 1.0, time_limit_s=bad)


# --- call errors --------------------------------------------------------------------------------


def test_raising_inside_names_step_and_line(tmp_path: Path) -> None:
    fn = load_src(tmp_path, "def reward_function(params):\n    return params['no_such_key']\n")
    with pytest.raises(RewardFunctionError) as info:
        fn(sample_params(), step=42)
    assert_one_line_error(info, "my_reward.py", "step 42", "KeyError", "no_such_key", "line 2")
    assert isinstance(info.value.__cause__, KeyError)


def test_multiline_exception_message_stays_one_line(tmp_path: Path) -> None:
    fn = load_src(tmp_path, "def reward_function(params):\n    raise RuntimeError('bad\\nthing')\n")
    with pytest.raises(RewardFunctionError) as info:
        fn(sample_params(), step=3)
    assert_one_line_error(info, "RuntimeError: bad thing", "step 3")


def test_sys_exit_inside_is_an_error(tmp_path: Path) -> None:
    fn = load_src(tmp_path, "import sys\ndef reward_function(params):\n    sys.exit(1)\n")
    with pytest.raises(RewardFunctionError) as info:
        fn(sample_params(), step=1)
    assert_one_line_error(info, "SystemExit")


@pytest.mark.parametrize(
    ("returned", "fragment"),
    [
        ("None", "None"),
        ("'fast'", "str"),
        ("[1.0]", "list"),
        ("np.array([1.0, 2.0])", "ndarray"),
        ("complex(1, 0)", "complex"),
        ("float('nan')", "nan"),
        ("float('inf')", "inf"),
        ("-math.inf", "-inf"),
        ("np.float64('nan')", "nan"),
        ("10 ** 400", "int"),
        ("100000.5", "outside [-100000, 100000]"),
        ("-2e5", "outside [-100000, 100000]"),
    ],
)
def test_bad_return_values(tmp_path: Path, returned: str, fragment: str) -> None:
    fn = load_src(
        tmp_path,
        f"import math\nimport numpy as np\n\ndef reward_function(params):\n    return {returned}\n",
    )
    with pytest.raises(RewardFunctionError) as info:
        fn(sample_params(), step=7)
    assert_one_line_error(info, "my_reward.py", "step 7", "returned", fragment)


def test_error_without_step_has_no_step(tmp_path: Path) -> None:
    fn = load_src(tmp_path, "def reward_function(params):\n    return None\n")
    with pytest.raises(RewardFunctionError) as info:
        fn(sample_params())
    assert "at step" not in str(info.value)


@pytest.mark.parametrize(
    ("returned", "expected"),
    [("True", 1.0), ("np.bool_(False)", 0.0), ("'1.5'", 1.5), ("7", 7.0), ("1e5", 1e5), ("-1e5", -1e5)],
)
def test_returns_taken_as_the_simapp_takes_them(tmp_path: Path, returned: str, expected: float) -> None:
    # simapp rollout_agent_ctrl._judge_action_at_run_phase: reward = float(self._reward_(copy.deepcopy(params))).
    fn = load_src(tmp_path, f"import numpy as np\n\ndef reward_function(params):\n    return {returned}\n")
    reward = fn(sample_params(), step=2)
    assert type(reward) is float and reward == expected


def test_each_call_gets_its_own_copy_of_params(tmp_path: Path) -> None:
    # simapp passes copy.deepcopy(params): mutating a list inside params must not reach the next call.
    fn = load_src(
        tmp_path,
        "seen = []\n"
        "def reward_function(params):\n"
        "    seen.append(len(params['waypoints']))\n"
        "    params['waypoints'].append((0.0, 0.0))\n"
        "    params['closest_waypoints'][0] = -1\n"
        "    params['objects_location'].append([1.0, 1.0])\n"
        "    return 1.0\n",
    )
    p = sample_params()
    before = {k: list(v) for k, v in p.items() if isinstance(v, list)}
    fn(p)
    fn(p)
    assert fn.fn.__globals__["seen"] == [11, 11]
    assert {k: list(v) for k, v in p.items() if isinstance(v, list)} == before


# --- time limit ---------------------------------------------------------------------------------


def test_slow_function_times_out_quickly(tmp_path: Path) -> None:
    fn = load_src(
        tmp_path,
        "import time\ndef reward_function(params):\n    time.sleep(5)\n    return 1.0\n",
        time_limit_s=0.2,
        first_call_time_limit_s=None,
    )
    started = time.monotonic()
    with pytest.raises(RewardFunctionError) as info:
        fn(sample_params(), step=9)
    assert time.monotonic() - started < 2.0
    assert_one_line_error(info, "my_reward.py", "took longer than 0.2 s at step 9")


def test_the_first_call_may_take_longer_as_in_deepracer(tmp_path: Path) -> None:
    # Racing-line functions build their line on the first call; DeepRacer bounds no call, racer bounds the rest.
    fn = load_src(
        tmp_path,
        "import time\nCALLS = []\ndef reward_function(params):\n"
        "    CALLS.append(1)\n    time.sleep(0.5 if len(CALLS) < 3 else 0.0)\n    return 1.0\n",
        time_limit_s=0.2,
        first_call_time_limit_s=2.0,
    )
    assert fn(sample_params(), step=2) == 1.0
    with pytest.raises(RewardFunctionError, match="took longer than 0.2 s at step 3"):
        fn(sample_params(), step=3)
    assert fn(sample_params(), step=4) == 1.0


def test_timeout_not_swallowed_by_user_except(tmp_path: Path) -> None:
    fn = load_src(
        tmp_path,
        "def reward_function(params):\n"
        "    try:\n"
        "        while True:\n"
        "            pass\n"
        "    except Exception:\n"
        "        return 1.0\n",
        time_limit_s=0.1,
        first_call_time_limit_s=None,
    )
    with pytest.raises(RewardFunctionError, match="took longer than 0.1 s"):
        fn(sample_params(), step=1)


def test_timeout_caught_by_bare_except_still_reported(tmp_path: Path) -> None:
    fn = load_src(
        tmp_path,
        "import time\n"
        "def reward_function(params):\n"
        "    try:\n"
        "        time.sleep(5)\n"
        "    except:\n"
        "        pass\n"
        "    return 1.0\n",
        time_limit_s=0.1,
        first_call_time_limit_s=None,
    )
    with pytest.raises(RewardFunctionError, match="took longer than 0.1 s at step 2"):
        fn(sample_params(), step=2)


@pytest.mark.skipif(not hasattr(signal, "setitimer"), reason="needs setitimer")
def test_timer_and_handler_restored(tmp_path: Path) -> None:
    fired: list[int] = []

    def outer(signum: int, frame: object) -> None:
        fired.append(signum)

    previous = signal.signal(signal.SIGALRM, outer)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.5)
        ok = RewardFunction(tmp_path / "r.py", lambda p: 1.0, time_limit_s=0.1)
        slow = RewardFunction(
            tmp_path / "r.py", lambda p: time.sleep(1), time_limit_s=0.1, first_call_time_limit_s=None
        )
        assert ok(sample_params()) == 1.0
        with pytest.raises(RewardFunctionError):
            slow(sample_params())
        assert signal.getsignal(signal.SIGALRM) is outer
        remaining, _ = signal.getitimer(signal.ITIMER_REAL)
        assert 0 < remaining < 0.5  # the outer timer is still armed, minus the time spent
        time.sleep(remaining + 0.2)
        assert fired == [signal.SIGALRM]
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def test_no_time_limit_off_main_thread_or_when_none(tmp_path: Path) -> None:
    slowish = load_src(
        tmp_path,
        "import time\ndef reward_function(params):\n    time.sleep(0.3)\n    return 1.0\n",
        time_limit_s=0.05,
    )
    results: list[object] = []

    def run() -> None:
        try:
            results.append(slowish(sample_params(), step=1))
        except RewardFunctionError as exc:  # pragma: no cover - reported by the assert below
            results.append(exc)

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    assert results == [1.0]
    unlimited = RewardFunction(slowish.path, slowish.fn, time_limit_s=None)
    assert unlimited(sample_params()) == 1.0
