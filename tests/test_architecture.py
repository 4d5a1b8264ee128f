"""The package's shape, checked from its source: imports point one way (no cycle, counting
imports inside functions), and every function fits on a screen."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "jaxcart"
MAX_FUNCTION_LINES = 80


def _modules() -> dict[str, ast.Module]:
    return {
        f"jaxcart.{p.stem}" if p.stem != "__init__" else "jaxcart": ast.parse(p.read_text())
        for p in sorted(PACKAGE.glob("*.py"))
    }


def import_graph() -> dict[str, set[str]]:
    """module -> the jaxcart modules it imports anywhere (top level, functions, TYPE_CHECKING)."""
    modules = _modules()
    graph: dict[str, set[str]] = {name: set() for name in modules}
    for name, tree in modules.items():
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                # "from jaxcart import rundir" imports the submodule jaxcart.rundir
                subs = [f"{node.module}.{a.name}" for a in node.names]
                targets = [s for s in subs if s in modules] or [node.module]
            graph[name].update(t for t in targets if t in modules and t != name)
    # the package's lazy __getattr__ table is not an import of every module
    graph["jaxcart"] = set()
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as a list of modules, or None."""
    state: dict[str, int] = {}  # 1 visiting, 2 done

    def visit(node: str, path: list[str]) -> list[str] | None:
        state[node] = 1
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt] if nxt in path else [node, nxt]
            if nxt not in state and (cycle := visit(nxt, [*path, nxt])):
                return cycle
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start, [start])):
            return cycle
    return None


def test_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle_in_the_package():
    graph = import_graph()
    assert "jaxcart.lifecycle" in graph["jaxcart.train"]  # the graph is really read
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))


def test_core_does_not_import_the_layers_above_it():
    graph = import_graph()
    above = {"jaxcart.lifecycle", "jaxcart.train", "jaxcart.report", "jaxcart.cli"}
    for core in ("jaxcart.env", "jaxcart.config", "jaxcart.networks", "jaxcart.ppo"):
        assert not graph[core] & (above | {"jaxcart.trainer", "jaxcart.rundir"}), core
    assert "jaxcart.report" not in graph["jaxcart.lifecycle"]  # the lifecycle never prints


@pytest.mark.parametrize("module", sorted(_modules()))
def test_functions_fit_on_a_screen(module):
    tree = _modules()[module]
    long = [
        f"{node.name} ({node.end_lineno - node.lineno + 1} lines)"
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES
    ]
    assert not long, f"{module}: {', '.join(long)}"
