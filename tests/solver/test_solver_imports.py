"""The solver package imports in one direction: no two of its modules import each other, directly
or through others (imports inside functions included), in every subfolder, and the package's
``__init__`` imports none of its submodules."""

from __future__ import annotations

import ast
from pathlib import Path

import camplace.solver

PACKAGE = "camplace.solver"
ROOT = Path(camplace.solver.__file__).parent


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join((PACKAGE, *parts))


def _imports(path: Path, modules: set[str]) -> set[str]:
    """The package's modules that ``path`` imports anywhere in its body."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name in modules)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module in modules:
                out.add(node.module)
            for alias in node.names:  # from camplace.solver import _bitkernels
                if f"{node.module}.{alias.name}" in modules:
                    out.add(f"{node.module}.{alias.name}")
    return out


def _graph() -> dict[str, set[str]]:
    files = sorted(ROOT.rglob("*.py"))  # every subfolder (engines/, problem/, _support/)
    modules = {_module_name(p) for p in files}
    return {_module_name(p): _imports(p, modules) - {_module_name(p)} for p in files}


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle, or None (depth-first search with colours)."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(u: str) -> list[str] | None:
        state[u] = 1
        stack.append(u)
        for v in sorted(graph.get(u, ())):
            if state.get(v) == 1:
                return stack[stack.index(v):] + [v]
            if v not in state:
                found = visit(v)
                if found:
                    return found
        stack.pop()
        state[u] = 2
        return None

    for u in sorted(graph):
        if u not in state:
            found = visit(u)
            if found:
                return found
    return None


def test_the_checker_finds_a_cycle() -> None:
    assert _cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_no_import_cycle_in_the_solver_package() -> None:
    graph = _graph()
    assert len(graph) > 20 and f"{PACKAGE}.api" in graph  # the checker sees the package
    assert f"{PACKAGE}.routes" in graph[f"{PACKAGE}.api"] and f"{PACKAGE}.choose" in graph[f"{PACKAGE}.routes"]
    assert f"{PACKAGE}.engines.bitset.search" in graph  # ... and its subfolders
    assert _cycle(graph) is None, " -> ".join(_cycle(graph) or [])


def test_package_init_imports_no_submodule() -> None:
    assert _graph()[PACKAGE] == set()
