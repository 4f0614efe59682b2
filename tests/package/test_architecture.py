"""The package's layers: entry points above the application layer above the library, no import cycle
between modules or between subpackages (imports inside functions included), no oversized module."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "torchrl_ahrs"
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
    """A library subpackage (``torchrl_ahrs.value``), an application room (``torchrl_ahrs.app.train``) or an
    entry point."""
    parts = module.split(".")
    if layer(module) == 2:
        return module
    return ".".join(parts[:3]) if parts[1:2] == ["app"] and len(parts) > 2 else ".".join(parts[:2])


SHARED_ROOM, BASE_ROOM = "torchrl_ahrs.app.shared", "torchrl_ahrs.app.train"


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


@pytest.mark.parametrize("room", sorted({subpackage(module) for module in MODULES if layer(module) == 1}))
def test_a_command_room_imports_only_shared_and_train(room):
    """Each command has its room under ``app/``; a room imports what the commands share (``app.shared``) and,
    to read or start what ``train`` writes, ``app.train``; never another room, and ``shared`` no room."""
    allowed = {room, SHARED_ROOM} | ({BASE_ROOM} if room != SHARED_ROOM else set())
    imported = {
        subpackage(target)
        for module in MODULES
        if subpackage(module) == room
        for target in GRAPH[module]
        if layer(target) == 1
    }
    assert imported <= allowed, f"{room} imports the rooms {sorted(imported - allowed)}"


def test_every_app_module_is_in_a_room():
    loose = sorted(m for m in MODULES if m.startswith("torchrl_ahrs.app.") and subpackage(m).count(".") < 2)
    assert loose == [], f"modules in app/ outside a command room or app/shared: {loose}"


def test_no_module_is_oversized():
    sizes = {name: len(path.read_text().splitlines()) for name, path in MODULES.items()}
    assert {name: size for name, size in sizes.items() if size > MAX_LINES} == {}


def test_the_cycle_finder_finds_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


CONFIG_PACKAGES = ("hydra", "omegaconf")


def config_imports(path: Path) -> list[str]:
    """The hydra / omegaconf modules ``path`` imports, at any depth of its syntax tree (``import_module``
    and ``__import__`` calls with a literal name included), as ``line: module``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            function = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
            if function in ("import_module", "__import__") and isinstance(node.args[0].value, str):
                names = [node.args[0].value]
        found += [f"{node.lineno}: {name}" for name in names if name.split(".")[0] in CONFIG_PACKAGES]
    return found


LIBRARY = sorted(module for module in MODULES if layer(module) == 0)


@pytest.mark.parametrize("module", LIBRARY)
def test_the_library_never_reads_config(module):
    """Only the application layer (``app/``) and the entry points read the Hydra tree; the library takes
    typed settings (e.g. ``scheduling/settings.py``), translated in ``app/shared/settings.py``."""
    assert config_imports(MODULES[module]) == [], f"{module} imports hydra/omegaconf"


def test_the_config_import_finder_finds_imports(tmp_path):
    source = tmp_path / "m.py"
    source.write_text(
        "import os\nfrom omegaconf import OmegaConf\ndef f():\n    import hydra.utils\n"
        "    importlib.import_module('omegaconf.dictconfig')\nfrom .omegaconf import x\n"
    )
    assert config_imports(source) == ["2: omegaconf", "4: hydra.utils", "5: omegaconf.dictconfig"]
    assert config_imports(MODULES["torchrl_ahrs.app.shared.settings"])  # the translation reads config
    assert "torchrl_ahrs.scheduling" in LIBRARY and "torchrl_ahrs.envs.registry" in LIBRARY
    assert not any(module.startswith("torchrl_ahrs.app") for module in LIBRARY)
    assert subpackage("torchrl_ahrs.app.train.build") == BASE_ROOM and subpackage("torchrl_ahrs.value.critic") == (
        "torchrl_ahrs.value"
    )
