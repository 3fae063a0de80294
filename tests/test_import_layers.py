"""Imports point down the pipeline: no cycles inside a package, no import of a later stage.

Read from the source with :mod:`ast`, module-level and function-level imports alike (a function-level
import of a module that imports you back is still a circle).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import camplace

SRC = Path(camplace.__file__).parent
#: The pipeline's order; a module may import its own stage and earlier ones only.
STAGES = ("instance", "sampling", "visibility", "solver", "plan", "robust", "validation", "report")
LATER_THAN = {s: set(STAGES[i + 1:]) | {"pipeline", "cli"} for i, s in enumerate(STAGES)}


def module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def is_module(name: str) -> bool:
    rel = Path(*name.split("."))
    return (SRC.parent / rel).with_suffix(".py").exists() or (SRC.parent / rel / "__init__.py").exists()


def imports_of(path: Path) -> set[str]:
    """camplace modules imported anywhere in the file (``from pkg import mod`` counts as ``pkg.mod``)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("camplace")}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1] + ([base] if base else []))
            if not base.startswith("camplace"):
                continue
            for a in node.names:
                out.add(f"{base}.{a.name}" if is_module(f"{base}.{a.name}") else base)
    out.discard(name)
    return out


def graph(packages: tuple[str, ...]) -> dict[str, set[str]]:
    files = [p for pkg in packages for p in sorted((SRC / pkg).rglob("*.py"))] if packages else []  # subfolders too
    return {module_name(p): imports_of(p) for p in files}


def cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in g.get(v, ()):
            if w not in g:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def test_the_checker_finds_a_cycle() -> None:
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


@pytest.mark.parametrize("package", ["instance", "sampling", "visibility", "solver", "plan", "robust", "validation", "report"])
def test_no_import_cycles_in(package: str) -> None:
    g = graph((package,))
    assert len(g) > 3
    assert cycles(g) == []


@pytest.mark.parametrize("package", ["instance", "sampling", "visibility", "solver", "plan", "robust", "validation", "report"])
def test_no_import_of_a_later_stage_from(package: str) -> None:
    later = LATER_THAN[package]
    g = graph((package,))
    assert len(g) > 3
    bad = {m: sorted(i for i in deps if i.split(".")[1:2] and i.split(".")[1] in later) for m, deps in g.items()}
    assert {m: d for m, d in bad.items() if d} == {}


def test_geometry_is_at_the_bottom() -> None:
    assert imports_of(SRC / "geometry.py") <= {"camplace.errors"}
