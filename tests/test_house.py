"""The house: no import cycle between files, no source file over 500 lines, and the layers point one way.

The import graph is read from the source (``ast``), module by module, over ``fe_core``, ``mrgp_core``,
``strategies``, ``tasks`` and ``flows``: an edge for every import of another module of these packages (a
package's ``__init__`` is a module of its own). Layers, bottom up: the two cores side by side (``fe_core`` and
``mrgp_core`` never import each other), ``strategies`` (the ask-tell loops, using both cores), ``tasks``,
``flows``; no package imports one above it; ``fe_core.solvers`` imports nothing of the closure or the
inference rooms; the strategies' task modules never import each other.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("fe_core", "mrgp_core", "strategies", "tasks", "flows")
#: Each package may import only the packages listed for it (and itself).
ALLOWED = {"fe_core": set(), "mrgp_core": set(), "strategies": {"fe_core", "mrgp_core"},
           "tasks": {"fe_core", "mrgp_core", "strategies"}, "flows": {"fe_core", "mrgp_core", "strategies", "tasks"}}
MAX_LINES = 500
#: The stage modules (the one driver of every strategy, the intervals), which share helpers through tasks.common,
#: fe_runs, record, problem, context.
STRATEGY_TASKS = ("tasks.driver", "tasks.intervals")


def _modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            if path.name == "__main__.py":
                continue
            name = ".".join(path.relative_to(REPO).with_suffix("").parts)
            out[name[: -len(".__init__")] if name.endswith(".__init__") else name] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        for target in targets:
            while target and target not in modules:
                target = target.rsplit(".", 1)[0] if "." in target else ""
            if target and target != name:
                found.add(target)
    return found


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, on, stack, out, counter = {}, {}, set(), [], [], [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
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
    return out


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_between_files(graph):
    assert _cycles(graph) == []


def test_no_source_file_is_over_500_lines():
    long = {str(p.relative_to(REPO)): n for p in _modules().values()
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}


def test_the_layers_point_one_way(graph):
    wrong = []
    for name, targets in graph.items():
        top = name.split(".")[0]
        for t in targets:
            t_top = t.split(".")[0]
            if t_top != top and t_top not in ALLOWED[top]:
                wrong.append((name, t))
            if name.startswith("fe_core.solvers") and t.startswith(("fe_core.closure", "fe_core.inference")):
                wrong.append((name, t))
            if name in STRATEGY_TASKS and t in STRATEGY_TASKS:
                wrong.append((name, t))
    assert wrong == []


def test_the_layer_check_sees_a_core_importing_the_other(graph):
    """The check is not vacuous: an edge from one core into the other is refused."""
    top, other = "fe_core", "mrgp_core"
    assert other not in ALLOWED[top] and top not in ALLOWED[other]
    assert any(n.startswith("strategies.") and any(t.startswith("mrgp_core") for t in ts) for n, ts in graph.items())
    assert any(n.startswith("strategies.") and any(t.startswith("fe_core") for t in ts) for n, ts in graph.items())
