"""No import cycle among the package's modules.

Every import counts: module level, inside functions and under ``TYPE_CHECKING``. An edge runs from a
module to the module it names (``from a.b import c`` reaches ``a.b.c`` when that is a module, else ``a.b``);
the parent packages Python loads on the way are not counted, so a package ``__init__`` that re-exports
its submodules is not a cycle by itself. Dynamic imports (``importlib.import_module``) are not seen.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("deepbbs_ros", "msg_adapters")


def _modules(root: Path, packages=PACKAGES) -> dict[str, Path]:
    """Dotted module name -> file, for every .py file under the packages."""
    out = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _imported(node: ast.AST, name: str, is_package: bool) -> list[str]:
    """Dotted names one import statement reaches, relative ones made absolute."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    base = name if is_package else name.rpartition(".")[0]
    for _ in range(max(node.level - 1, 0)):
        base = base.rpartition(".")[0]
    module = ".".join(p for p in ((base if node.level else ""), node.module or "") if p)
    return [module] + [f"{module}.{a.name}" for a in node.names]


def import_graph(root: Path = ROOT, packages=PACKAGES) -> dict[str, set[str]]:
    """Module -> the package modules it imports (anywhere in its file)."""
    modules = _modules(root, packages)
    graph = {}
    for name, path in modules.items():
        edges = set()
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            reached = _imported(node, name, path.name == "__init__.py")
            if isinstance(node, ast.ImportFrom):
                # `from a import b`: the submodule a.b if there is one, else the module a
                subs = [m for m in reached[1:] if m in modules]
                reached = subs + ([reached[0]] if len(subs) < len(reached) - 1 else [])
            edges |= {m for m in reached if m in modules}
        graph[name] = edges
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle (a, b, ..., a) per strongly connected component that has one (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.add(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph.get(v, ()):
                found.append(_cycle_through(v, component, graph))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _cycle_through(start: str, component: set[str], graph: dict[str, set[str]]) -> list[str]:
    """A shortest path start -> ... -> start inside one strongly connected component."""
    parent, frontier = {start: None}, [start]
    while frontier:
        nxt = []
        for v in frontier:
            for w in sorted(graph[v] & component):
                if w == start:
                    path = [v]
                    while parent[path[-1]] is not None:
                        path.append(parent[path[-1]])
                    return [start, *reversed(path[:-1]), start] if v != start else [start, start]
                if w not in parent:
                    parent[w] = v
                    nxt.append(w)
        frontier = nxt
    raise AssertionError(f"no cycle through {start}")


def test_no_import_cycle():
    graph = import_graph()
    assert len(graph) > 100 and graph["deepbbs_ros.core.localization"], "the import graph looks empty"
    found = cycles(graph)
    assert not found, "import cycles:\n" + "\n".join(" -> ".join(c) for c in found)


def test_a_cycle_is_found_and_named(tmp_path):
    pkg = tmp_path / "deepbbs_ros"
    (pkg / "core").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from deepbbs_ros.core import a\n")  # re-export: not a cycle
    (pkg / "core" / "__init__.py").write_text("")
    (pkg / "core" / "a.py").write_text("from . import b\n")
    (pkg / "core" / "b.py").write_text("def f():\n    from deepbbs_ros.core.c import g\n")
    (pkg / "core" / "c.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from ..core.a import A\n")
    graph = import_graph(tmp_path, ("deepbbs_ros",))
    assert graph["deepbbs_ros"] == {"deepbbs_ros.core.a"}
    assert cycles(graph) == [["deepbbs_ros.core.a", "deepbbs_ros.core.b", "deepbbs_ros.core.c", "deepbbs_ros.core.a"]]
    (pkg / "core" / "c.py").write_text("import deepbbs_ros.core\n")
    assert cycles(import_graph(tmp_path, ("deepbbs_ros",))) == []
