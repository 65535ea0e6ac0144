"""No import cycle inside scenes/ or edi/, counting imports inside functions (issue 33)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _imports(pkg: str) -> dict[str, set[str]]:
    """module -> the modules of ``pkg`` it imports anywhere in its body (functions included)."""
    graph: dict[str, set[str]] = {}
    for f in sorted((ROOT / pkg).glob("*.py")):
        mod = pkg if f.stem == "__init__" else f"{pkg}.{f.stem}"
        out = graph.setdefault(mod, set())
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level and node.module is None:  # from . import x
                    out.update(f"{pkg}.{a.name}" for a in node.names)
                elif node.level:
                    out.add(f"{pkg}.{node.module}")
                elif node.module and node.module.split(".")[0] == pkg:
                    out.add(node.module)
            elif isinstance(node, ast.Import):
                out.update(a.name for a in node.names if a.name.split(".")[0] == pkg)
    return graph


def _cycle(graph: dict[str, set[str]], pkg: str) -> list[str] | None:
    """A cycle among the package's modules (the package's own __init__ left out: every module
    imports through it only names that its submodules define), or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph.get(m, ())):
            if n == pkg or n not in graph:
                continue
            if state.get(n) == 1:
                return stack[stack.index(n) :] + [n]
            if n not in state and (found := visit(n)) is not None:
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m != pkg and m not in state and (found := visit(m)) is not None:
            return found
    return None


@pytest.mark.parametrize("pkg", ["scenes", "edi"])
def test_no_import_cycle(pkg):
    graph = _imports(pkg)
    assert len(graph) > 5  # the package was found
    assert _cycle(graph, pkg) is None, " -> ".join(_cycle(graph, pkg) or [])


def test_the_cycle_finder_finds_a_cycle():
    graph = {"p": set(), "p.a": {"p.b"}, "p.b": {"p.c", "p"}, "p.c": {"p.a"}}
    assert _cycle(graph, "p") == ["p.a", "p.b", "p.c", "p.a"]
