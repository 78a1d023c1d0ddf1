"""No call in racer's production code passes more than five arguments by position to racer's own functions or
classes: past that, a call site names what it passes (a ``*`` in the signature, or ``KW_ONLY`` / ``kw_only=True`` for a
dataclass, makes the callee keyword-only beyond its first few parameters).

A callee is recognised by its name (``f(...)``, ``obj.f(...)``): a name that a function or class of the production
packages defines. Calls through a name imported from outside those packages (``np.stack``, ``cv2.line``, a
``from x import f`` of a library) are not ours and are skipped; ``cls(...)`` in a class counts as that class, and
``partial(f, ...)`` as a call to ``f``. A method of a third-party object that shares a name with one of ours is still
counted: it then takes keywords too.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sim", "trainer", "rollout_worker", "common", "model_store", "deploy", "racer")
MAX_POSITIONAL = 5


def _trees() -> dict[Path, ast.Module]:
    files = sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*.py"))
    return {p: ast.parse(p.read_text(encoding="utf-8"), filename=str(p)) for p in files}


def defined_names(trees: list[ast.Module]) -> set[str]:
    """Names of every function, method and class the modules define."""
    kinds = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)
    return {node.name for tree in trees for node in ast.walk(tree) if isinstance(node, kinds)}


def _foreign_imports(tree: ast.Module) -> set[str]:
    """Names the module binds by importing from outside racer's packages (``np``, ``cv2``, ``partial``)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names if not _ours(a.name)}
        elif isinstance(node, ast.ImportFrom) and not (node.level or _ours(node.module or "")):
            names |= {a.asname or a.name for a in node.names}
    return names


def _ours(module: str) -> bool:
    return module.split(".")[0] in PACKAGES


def _callee(func: ast.expr, foreign: set[str], cls: str | None) -> str | None:
    """The name a call goes to, or None where it is not (or cannot be) one of racer's."""
    if isinstance(func, ast.Name):
        if func.id == "cls":
            return cls
        return None if func.id in foreign else func.id
    if isinstance(func, ast.Attribute):
        root = func.value
        while isinstance(root, ast.Attribute):
            root = root.value
        return None if isinstance(root, ast.Name) and root.id in foreign else func.attr
    return None


def long_calls(tree: ast.Module, ours: set[str]) -> Iterator[tuple[int, str, int]]:
    """(line, callee, positional arguments) of each call in ``tree`` to a name in ``ours`` with more than
    :data:`MAX_POSITIONAL` positional arguments (``*args`` splats not counted)."""
    foreign = _foreign_imports(tree)

    def visit(node: ast.AST, cls: str | None) -> Iterator[tuple[int, str, int]]:
        if isinstance(node, ast.ClassDef):
            cls = node.name
        if isinstance(node, ast.Call):
            func, args = node.func, node.args
            if _callee(func, set(), None) == "partial" and args:  # partial(f, a, b, ...) binds f's arguments
                func, args = args[0], args[1:]
            name = _callee(func, foreign, cls)
            count = sum(not isinstance(a, ast.Starred) for a in args)
            if name in ours and count > MAX_POSITIONAL:
                yield node.lineno, name, count
        for child in ast.iter_child_nodes(node):
            yield from visit(child, cls)

    yield from visit(tree, None)


def test_the_check_counts_calls_to_racers_names_only() -> None:
    tree = ast.parse(
        "import numpy as np\n"
        "from functools import partial\n"
        "from sim.track import nearest_segment as near\n"
        "near(1, 2, 3, 4, 5, 6)\n"
        "np.linalg.near(1, 2, 3, 4, 5, 6)\n"
        "near(*a, 1, 2, 3, 4, 5)\n"
        "partial(near, 1, 2, 3, 4, 5, 6)\n"
        "near(1, 2, 3, 4, 5, x=6)\n"
        "class Near:\n"
        "    @classmethod\n"
        "    def of(cls):\n"
        "        return cls(1, 2, 3, 4, 5, 6)\n"
    )
    assert list(long_calls(tree, {"near", "Near"})) == [(4, "near", 6), (7, "near", 6), (12, "Near", 6)]


def test_no_call_passes_more_than_five_arguments_by_position_to_racers_own_code() -> None:
    trees = _trees()
    ours = defined_names(list(trees.values()))
    found = [
        f"{path.relative_to(ROOT)}:{line} {name} {count}"
        for path, tree in trees.items()
        for line, name, count in long_calls(tree, ours)
    ]
    assert not found, (
        f"{len(found)} calls pass more than {MAX_POSITIONAL} arguments by position; pass the rest by keyword "
        "(and make the callee keyword-only past its first few parameters):\n" + "\n".join(found)
    )
