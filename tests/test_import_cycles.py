"""No import cycles inside pliant (issue 26, item 2): every import of a module by a module goes one way.

A pair of sibling modules that import each other only works because one side imports inside a function; the
order of first use then decides whether the program starts. The walk is ``tests/test_layers.py``'s: every
``import`` / ``from ... import`` at any depth (function-level ones included), ``from P import name``
resolved to the submodule ``P.name`` when there is one. A package's ``__init__.py`` is a module of its
package: a submodule importing names from its own package's ``__init__`` (which imports that submodule)
is a cycle too. The layer test already forbids upward imports between sub-packages; this one covers the
imports it allows, those within a layer (sibling modules of one sub-package above all).
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Mapping

from tests.test_layers import ROOT, _imports, _module_name

#: Cycles still present, each the set of its modules, with why it is tolerated. Empty: the last two (the
#: fast mass-spring solver and the implicit step with their adjoints) went with the solvers' sub-packages
#: (issue 26, item 1). A stale entry fails test_allowed_cycles_still_exist.
ALLOWED: tuple[frozenset[str], ...] = ()


def import_graph() -> dict[str, set[str]]:
    """Module → the pliant modules it imports (any depth in the file), self-imports left out."""
    graph: dict[str, set[str]] = {}
    for path in sorted(ROOT.rglob("*.py")):
        me = _module_name(path)
        graph.setdefault(me, set()).update(t for _, t in _imports(path, type_checking=False) if t != me)
    return graph


def cycles(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """One cycle ``[a, b, ..., a]`` per strongly connected component of more than one module (Tarjan's
    algorithm, iterative), components in sorted order, each cycle starting at its smallest module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    succ = {n: sorted(set(ms) - {n}) for n, ms in graph.items()}  # a self-import is no cycle
    for root in sorted(succ):
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            node, i = work.pop()
            if i == 0:
                index[node] = low[node] = len(index)
                stack.append(node)
                on_stack.add(node)
            nexts = succ.get(node, [])
            if i < len(nexts):
                work.append((node, i + 1))
                m = nexts[i]
                if m not in index:
                    work.append((m, 0))
                elif m in on_stack:
                    low[node] = min(low[node], index[m])
                continue
            if work:  # returning to the caller: pass the lowest link up
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == node:
                        break
                if len(comp) > 1:
                    components.append(sorted(comp))
    return [_cycle_in(comp, succ) for comp in sorted(components)]


def _cycle_in(comp: list[str], succ: Mapping[str, list[str]]) -> list[str]:
    """A shortest cycle through ``comp[0]`` inside the component (breadth-first), as ``[a, ..., a]``."""
    inside = set(comp)
    start = comp[0]
    parent: dict[str, str] = {}
    frontier = [start]
    while frontier:
        nxt = []
        for n in frontier:
            for m in succ.get(n, []):
                if m not in inside:
                    continue
                if m == start:
                    path = [n]
                    while path[-1] != start:
                        path.append(parent[path[-1]])
                    return [start, *reversed(path[:-1]), start]
                if m not in parent:
                    parent[m] = n
                    nxt.append(m)
        frontier = nxt
    raise AssertionError(f"{comp} is not strongly connected")


def _where(graph_lines: Mapping[str, list[tuple[int, str]]], a: str, b: str) -> str:
    lines = sorted({line for line, t in graph_lines.get(a, []) if t == b})
    return f"{a} imports {b} (line {', '.join(map(str, lines))})"


def test_no_import_cycles():
    """No cycle of imports among pliant's modules, function-level imports included (beyond ALLOWED)."""
    lines = {_module_name(p): _imports(p, type_checking=False) for p in ROOT.rglob("*.py")}
    found = [c for c in cycles(import_graph()) if frozenset(c) not in ALLOWED]
    msg = [
        " -> ".join(c) + ":\n" + "\n".join(f"    {_where(lines, a, b)}" for a, b in zip(c, c[1:]))
        for c in found
    ]
    assert not found, (
        "import cycles (move what both sides need into a lower module, then import at module top):\n"
        + "\n".join(msg)
    )


def test_allowed_cycles_still_exist():
    """Each tolerated cycle still exists: a stale entry would hide a new cycle among those modules."""
    present = {frozenset(c) for c in cycles(import_graph())}
    stale = [sorted(a) for a in ALLOWED if a not in present]
    assert not stale, f"these cycles are gone: remove them from ALLOWED: {stale}"


def test_the_cycle_finder_reports_a_cycle():
    """The finder on a synthetic graph: a three-module cycle and a two-module one are reported as paths
    (a self-import and an acyclic branch are not), each once."""
    graph = {
        "p.a": {"p.b", "p.d"},
        "p.b": {"p.c"},
        "p.c": {"p.a", "p.d"},
        "p.d": {"p.e"},
        "p.e": set(),
        "q.x": {"q.y", "q.x"},
        "q.y": {"q.x"},
    }
    found = cycles(graph)
    assert found == [["p.a", "p.b", "p.c", "p.a"], ["q.x", "q.y", "q.x"]], found
    assert cycles({k: v - {"p.a"} for k, v in graph.items() if not k.startswith("q")}) == []


def test_the_walk_sees_a_function_level_sibling_cycle(tmp_path, monkeypatch):
    """On files: two sibling modules closing a cycle with a function-level import, and a submodule
    importing from its own package's ``__init__`` (which imports it), are both found."""
    import tests.test_layers as layers

    fake = tmp_path / "pliant"
    (fake / "scene").mkdir(parents=True)
    (fake / "__init__.py").write_text("")
    (fake / "scene" / "__init__.py").write_text("from ._c import C\nX = 1\n")
    (fake / "scene" / "_a.py").write_text("from ._b import g\n\ndef f():\n    return g()\n")
    (fake / "scene" / "_b.py").write_text("def g():\n    from . import _a\n    return _a\n")
    (fake / "scene" / "_c.py").write_text("from . import X as C\n")
    monkeypatch.setattr(layers, "ROOT", fake)
    monkeypatch.setattr(sys.modules[__name__], "ROOT", fake)
    assert cycles(import_graph()) == [
        ["pliant.scene", "pliant.scene._c", "pliant.scene"],
        ["pliant.scene._a", "pliant.scene._b", "pliant.scene._a"],
    ]


def test_annotation_only_imports_close_no_cycle():
    """Imports under ``if TYPE_CHECKING:`` never run, so they are not edges of the import graph (the layer
    test still checks their direction): model/_worlds names the Model in annotations only."""
    import ast

    from tests.test_layers import _type_checking_lines

    src = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ._model import Model\nimport os\n"
    assert _type_checking_lines(ast.parse(src)) == {3}
    assert "pliant.model._model" not in import_graph()["pliant.model._worlds"]
