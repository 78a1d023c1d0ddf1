"""The layers' boundaries, read from the source: the packages below the CLI import nothing from ``racer``, and the
benchmarks use the roles through their public doors only (no bench subclasses a role, reads or writes a private
name of another object, or sets an attribute of a role other than a documented hook)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BENCH = ROOT / "racer" / "bench"
BELOW_CLI = ("common", "sim", "model_store", "trainer", "rollout_worker", "deploy")
ROLE_MODULES = ("trainer", "rollout_worker", "sim")
HOOKS = {"stop_when"}
"""The attributes a bench may set on a role's object: documented public hooks."""


def _modules() -> list[tuple[str, ast.Module]]:
    return [(p.name, ast.parse(p.read_text(), filename=str(p))) for p in sorted(BENCH.glob("*.py"))]


def test_no_package_below_the_cli_imports_racer() -> None:
    """Not even inside a function: ``racer`` imports them, so an import back would be a cycle."""
    found, files = [], 0
    for package in BELOW_CLI:
        for path in sorted((ROOT / package).rglob("*.py")):
            files += 1
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
                names += [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
                found += [f"{path.relative_to(ROOT)}:{node.lineno}: {n}" for n in names if n.split(".")[0] == "racer"]
    assert files > 50 and not found, found


def _role_names(tree: ast.Module) -> set[str]:
    """Names a bench module imports from the roles' packages."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in ROLE_MODULES:
            names |= {a.asname or a.name for a in node.names}
    return names


def test_no_bench_subclasses_a_role() -> None:
    found = []
    for name, tree in _modules():
        roles = _role_names(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                bases = {b.id for b in node.bases if isinstance(b, ast.Name)}
                found += [f"{name}: {node.name}({b})" for b in sorted(bases & roles)]
    assert not found, found


def test_no_bench_touches_another_object_s_private_names() -> None:
    found = []
    for name, tree in _modules():
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and node.attr.startswith("_")
                and not node.attr.startswith("__")
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
            ):
                found.append(f"{name}:{node.lineno}: .{node.attr}")
    assert not found, found


def _role_variables(fn: ast.FunctionDef, roles: set[str]) -> set[str]:
    """Names in ``fn`` that hold a role's object: parameters annotated with a role's class, and names bound to a
    call of one."""
    held = {a.arg for a in fn.args.args + fn.args.kwonlyargs if getattr(a.annotation, "id", None) in roles}
    for node in ast.walk(fn):
        call = node.value if isinstance(node, ast.Assign) else None
        if isinstance(call, ast.Call) and getattr(call.func, "id", None) in roles:
            held |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return held


def test_benches_set_no_attribute_of_a_role_but_a_hook() -> None:
    found, checked = [], 0
    for name, tree in _modules():
        roles = _role_names(tree)
        for fn in (n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)):
            held = _role_variables(fn, roles)
            checked += len(held)
            for node in ast.walk(fn):
                for t in node.targets if isinstance(node, ast.Assign) else []:
                    if isinstance(t, ast.Attribute) and getattr(t.value, "id", None) in held and t.attr not in HOOKS:
                        found.append(f"{name}:{node.lineno}: {t.value.id}.{t.attr} =")
    assert checked > 5 and not found, found  # the benches do hold roles' objects: the check sees them
