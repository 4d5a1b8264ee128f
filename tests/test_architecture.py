"""The package's shape, checked from its source: direction and cycles only.

- Layers as folders: a module imports only from its own layer and the layers below it
  (:data:`LAYERS`), counting imports inside functions and under ``TYPE_CHECKING``.
- No import cycle between modules.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jaxcart"

LAYERS: dict[str, int] = {
    "core": 0,  # env, network, PPO math, config, the definition of solved: no I/O
    "engine": 1,  # compile, devices, the chunk loop, signals
    "analysis": 1,  # statistics over arrays: no run directories
    "rundir": 2,  # the run directory: names, the one writer, the one reader
    "run": 3,  # a run's lifecycle: training, evaluation, waves, sweeps, loggers
    "gym": 1,  # the Gymnasium adapter: jaxcart's env behind Gymnasium's API
    "results": 3,  # finished runs read back: comparisons, compare.png, GIFs
    "": 4,  # the package face and the commands (argparse -> library -> printing)
}
"""Layer of each subpackage (``""`` is the top level). Equal numbers may not import each other."""


def _modules() -> dict[str, ast.Module]:
    modules = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = ["jaxcart", *path.relative_to(PACKAGE).with_suffix("").parts]
        if parts[-1] == "__init__":
            parts.pop()
        modules[".".join(parts)] = ast.parse(path.read_text())
    return modules


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
                # "from jaxcart.rundir import layout" imports the module jaxcart.rundir.layout
                subs = [f"{node.module}.{a.name}" for a in node.names]
                targets = [s for s in subs if s in modules] or [node.module]
            graph[name].update(t for t in targets if t in modules and t != name)
    # the package's lazy __getattr__ table is not an import of every module
    graph["jaxcart"] = set()
    return graph


def layer_of(module: str) -> tuple[str, int]:
    """``jaxcart.run.lifecycle`` -> ``("run", 3)``; top-level modules are layer ``""``."""
    parts = module.split(".")
    sub = parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in LAYERS) else ""
    return sub, LAYERS[sub]


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
    assert "jaxcart.run.lifecycle" in graph["jaxcart.train"]  # the graph is really read
    assert find_cycle(graph) is None, " -> ".join(find_cycle(graph))


def test_every_subpackage_has_a_layer():
    subpackages = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    assert subpackages == set(LAYERS) - {""}
    assert len(subpackages) >= 5


def test_imports_point_down_the_layers():
    wrong = []
    for module, imports in import_graph().items():
        sub, level = layer_of(module)
        for target in imports:
            target_sub, target_level = layer_of(target)
            if target_sub != sub and target_level >= level:
                wrong.append(f"{module} -> {target}")
    assert not wrong, "imports that point up or sideways:\n" + "\n".join(sorted(wrong))


def test_layer_rules_catch_an_upward_import():
    assert layer_of("jaxcart.core.ppo") == ("core", 0)
    assert layer_of("jaxcart.train") == ("", 4)
    assert layer_of("jaxcart.run.lifecycle")[1] > layer_of("jaxcart.rundir.layout")[1]


def test_the_lifecycle_never_prints():
    assert "jaxcart.report" not in import_graph()["jaxcart.run.lifecycle"]
