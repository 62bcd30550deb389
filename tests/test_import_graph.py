"""No circle among the project's modules: the import graph (grimp's, which also sees the imports
inside functions and under ``TYPE_CHECKING``) has no cycle of two or more modules.

import-linter's layers and forbidden contracts check the packages' directions; a cycle between
two modules of one package (each importing the other, one of them inside a function) is beyond
them, hence this test.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("node", "replay", "simulator", "harness", "bench")


def cycles(edges: Mapping[str, Sequence[str]]) -> list[list[str]]:
    """One shortest cycle per strongly connected component of two or more modules (or a module
    importing itself): [a, b, ..., a], the components in sorted order of their first module.

    ``edges``: each module's directly imported modules.

    >>> cycles({"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]})
    [['a', 'b', 'c', 'a']]
    >>> cycles({"a": ["b"], "b": []})
    []
    """
    out: list[list[str]] = []
    for comp in _components(edges):
        out.append(_shortest_cycle(edges, comp, min(comp)))
    return sorted(out)


def _components(edges: Mapping[str, Sequence[str]]) -> Iterator[set[str]]:
    """The strongly connected components with a cycle (Tarjan's, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, todo = work[-1]
            w = next(todo, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = set()
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.add(w)
                    if w == v:
                        break
                if len(comp) > 1 or v in edges.get(v, ()):
                    yield comp


def _shortest_cycle(edges: Mapping[str, Sequence[str]], comp: set[str], start: str) -> list[str]:
    """A shortest path from ``start`` back to itself inside ``comp``: [start, ..., start]."""
    prev: dict[str, str | None] = {start: None}
    frontier = [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(edges.get(v, ())):
                if w == start:
                    path = [v]
                    while (p := prev[path[-1]]) is not None:
                        path.append(p)
                    return [*path[::-1], start]
                if w in comp and w not in prev:
                    prev[w] = v
                    nxt.append(w)
        frontier = nxt
    raise AssertionError(f"{start} is on no cycle of its component")


def _graph_cycles(packages: Sequence[str]) -> list[str]:
    """Each cycle of ``packages``' import graph, one line per import: ``a -> b (a.py line n)``."""
    graph = grimp.build_graph(*packages, include_external_packages=False)
    edges = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    report = []
    for cyc in cycles(edges):
        lines = []
        for a, b in zip(cyc, cyc[1:]):
            details = graph.get_import_details(importer=a, imported=b)
            where = ", ".join(f"line {d['line_number']}" for d in details)
            lines.append(f"  {a} -> {b} ({where})")
        report.append("\n".join(lines))
    return report


def test_the_cycle_finder_reports_the_shortest_cycle_of_each_component() -> None:
    edges = {"a": ["b", "d"], "b": ["c"], "c": ["a"], "d": ["e"], "e": ["b"], "f": ["f"], "g": ["a"]}
    assert cycles(edges) == [["a", "b", "c", "a"], ["f", "f"]]
    assert cycles({"x": ["y"], "y": ["x"]}) == [["x", "y", "x"]]


def test_an_import_inside_a_function_closes_a_cycle(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pkg = tmp_path / "cycleprobe"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from cycleprobe.b import g\n")
    (pkg / "b.py").write_text("def g():\n    from cycleprobe.a import g as f\n    return f\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    report = _graph_cycles(["cycleprobe"])
    assert report == ["  cycleprobe.a -> cycleprobe.b (line 1)\n  cycleprobe.b -> cycleprobe.a (line 2)"]


def test_no_module_of_the_project_is_on_an_import_cycle(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(ROOT))
    report = _graph_cycles(PACKAGES)
    assert not report, "import cycles among the project's modules:\n" + "\n\n".join(report)
