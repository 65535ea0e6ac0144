"""No import cycle in any package, counting imports inside functions, and the packages'
dependencies pointing one way (DESIGN.md: ``ebad`` uses the other three, ``scenes`` may use ``edi``,
``splat_cpu`` and ``edi`` use neither).

The graph is read from the source with ``ast``: every ``import``/``from ... import`` anywhere in a
module (inside functions too), except under ``if TYPE_CHECKING:``. Run it alone with
``python -m pytest tests/test_imports.py``; a failure prints each cycle as a chain of modules.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("splat_cpu", "edi", "scenes", "ebad")
MAY_USE = {"splat_cpu": set(), "edi": set(), "scenes": {"edi"}, "ebad": {"splat_cpu", "edi", "scenes"}}


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the project's packages, by dotted name (a package by its own name)."""
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = path
    return mods


def _is_type_checking(node: ast.If) -> bool:
    t = node.test
    return (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
        isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.AST):
    """Import nodes of a module, skipping ``if TYPE_CHECKING:`` bodies (their ``else`` counts)."""
    stack = [tree]
    while stack:
        node = stack.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            stack.extend(node.orelse)
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        stack.extend(ast.iter_child_nodes(node))


def import_graph(mods: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the project modules it imports (``from P import name`` counts as ``P.name`` when
    that is a module, else as ``P``)."""
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        is_pkg = path.name == "__init__.py"
        base = mod.split(".") if is_pkg else mod.split(".")[:-1]
        for node in _imports(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                if node.level:
                    anchor = base[: len(base) - (node.level - 1)]
                    stem = ".".join(anchor + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                targets = [f"{stem}.{a.name}" if f"{stem}.{a.name}" in mods else stem for a in node.names]
            for t in targets:
                while t and t not in mods:  # "ebad.losses.ssim_map" -> "ebad.losses"
                    t = t.rpartition(".")[0]
                if t and t != mod:
                    graph[mod].add(t)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _chain(graph: dict[str, set[str]], comp: list[str]) -> str:
    """One cycle through the component's first module, as 'a -> b -> a'."""
    inside = set(comp)
    start = comp[0]
    path, seen = [start], {start}
    node = start
    while True:
        nxt = sorted(graph[node] & inside)
        back = [n for n in nxt if n == start]
        if back and len(path) > 1:
            return " -> ".join(path + [start])
        fresh = [n for n in nxt if n not in seen]
        if not fresh:
            return " <-> ".join(comp)
        node = fresh[0]
        path.append(node)
        seen.add(node)


def test_no_import_cycle():
    graph = import_graph(module_files())
    found = cycles(graph)
    assert not found, "import cycles (imports inside functions count):\n" + "\n".join(_chain(graph, c) for c in found)


def test_packages_depend_one_way():
    graph = import_graph(module_files())
    wrong = sorted(
        f"{m} imports {t}"
        for m, ts in graph.items()
        for t in ts
        if t.split(".")[0] != m.split(".")[0] and t.split(".")[0] not in MAY_USE[m.split(".")[0]]
    )
    assert not wrong, "DESIGN.md's package order broken:\n" + "\n".join(wrong)


def _write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_checker_finds_a_cycle_hidden_in_a_function(tmp_path):
    _write(
        tmp_path,
        {
            "ebad/__init__.py": "",
            "ebad/a.py": "from .b import f\n",
            "ebad/b.py": "def f():\n    from .c import g\n    return g\n",
            "ebad/c.py": "import ebad.a\n",
            "ebad/d.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .a import x\n",
            "ebad/e.py": "from . import d\n",
        },
    )
    graph = import_graph(module_files(tmp_path))
    assert graph["ebad.b"] == {"ebad.c"}
    assert graph["ebad.d"] == set()  # under TYPE_CHECKING: not a runtime import
    assert graph["ebad.e"] == {"ebad.d"}
    found = cycles(graph)
    assert found == [["ebad.a", "ebad.b", "ebad.c"]]
    assert _chain(graph, found[0]) == "ebad.a -> ebad.b -> ebad.c -> ebad.a"


def test_checker_sees_a_package_imported_the_wrong_way(tmp_path):
    _write(
        tmp_path, {"edi/__init__.py": "def f():\n    import scenes.x\n", "scenes/__init__.py": "", "scenes/x.py": ""}
    )
    graph = import_graph(module_files(tmp_path))
    assert graph["edi"] == {"scenes.x"}


@pytest.mark.parametrize("pkg", PACKAGES)
def test_every_package_is_read(pkg):
    mods = module_files()
    assert pkg in mods and sum(m.startswith(pkg + ".") for m in mods) >= 3
