"""The package's layers: entry points above the application layer above the library, no import cycle
between modules or between subpackages (imports inside functions included), no oversized module."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "torchrl_ahrs"
MAX_LINES = 400


def module_names() -> dict[str, Path]:
    names = {}
    for path in PACKAGE.rglob("*.py"):
        parts = ("torchrl_ahrs", *path.relative_to(PACKAGE).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names[".".join(parts)] = path
    return names


def imports_of(path: Path, modules: dict[str, Path]) -> set[str]:
    """Every torchrl_ahrs module ``path`` imports, at any depth of its syntax tree."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names if alias.name.startswith("torchrl_ahrs")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("torchrl_ahrs"):
            for alias in node.names:
                submodule = f"{node.module}.{alias.name}"
                found.add(submodule if submodule in modules else node.module)
    return {name for name in found if name in modules}


def layer(module: str) -> int:
    """0 library, 1 application, 2 entry point (a module at the package root, or a ``__main__``)."""
    parts = module.split(".")
    if len(parts) == 2 and MODULES[module].name != "__init__.py" or parts[-1] == "__main__":
        return 2
    return 1 if parts[1:2] == ["app"] else 0


def subpackage(module: str) -> str:
    parts = module.split(".")
    return module if layer(module) == 2 else ".".join(parts[:2])


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for successor in sorted(graph.get(node, ())):
            if state.get(successor) == 1:
                return stack[stack.index(successor) :] + [successor]
            if successor not in state and (cycle := visit(successor)):
                return cycle
        state[node] = 2
        stack.pop()
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


MODULES = module_names()
GRAPH = {name: imports_of(path, MODULES) - {name} for name, path in MODULES.items()}


def test_no_import_cycle_between_modules():
    assert find_cycle(GRAPH) is None, f"import cycle: {' -> '.join(find_cycle(GRAPH))}"


def test_no_import_cycle_between_subpackages():
    graph: dict[str, set[str]] = {}
    for module, targets in GRAPH.items():
        if module == "torchrl_ahrs":  # the package's public API re-exports the library
            continue
        graph.setdefault(subpackage(module), set()).update(
            subpackage(target) for target in targets if subpackage(target) not in (subpackage(module), "torchrl_ahrs")
        )
    assert find_cycle(graph) is None, f"subpackage cycle: {' -> '.join(find_cycle(graph))}"


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_only_go_down(module):
    upward = sorted(target for target in GRAPH[module] if layer(target) > layer(module))
    assert not upward, f"{module} (layer {layer(module)}) imports the layer above: {upward}"


def test_no_module_is_oversized():
    sizes = {name: len(path.read_text().splitlines()) for name, path in MODULES.items()}
    assert {name: size for name, size in sizes.items() if size > MAX_LINES} == {}


def test_the_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None
