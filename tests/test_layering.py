"""The package's layering, checked on the source: core knows no protocol, imports form no cycle.

Modules are found from pyproject.toml's ``package-dir`` (core/ is ``fieldgate``, plugins/ is
``fieldgate.plugins``, conformance/ is ``fieldgate.conformance``), so a new top-level folder
mapped there is checked too.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FORBIDDEN_IN_CORE = ("fieldgate.plugins", "fieldgate.conformance")


@dataclass(frozen=True)
class Module:
    name: str
    path: Path
    is_package: bool


def package_dirs() -> dict[str, Path]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    mapping = config["tool"]["setuptools"]["package-dir"]
    return {package: ROOT / folder for package, folder in mapping.items()}


def owning_package(path: Path, dirs: dict[str, Path]) -> tuple[str, Path]:
    """The mapped package whose folder holds ``path`` most closely (plugins/ is not core/)."""
    holders = [(pkg, d) for pkg, d in dirs.items() if path.is_relative_to(d)]
    return max(holders, key=lambda item: len(item[1].parts))


def discover() -> dict[str, Module]:
    dirs = package_dirs()
    modules: dict[str, Module] = {}
    for folder in dirs.values():
        for path in sorted(folder.rglob("*.py")):
            package, base = owning_package(path, dirs)
            parts = list(path.relative_to(base).with_suffix("").parts)
            is_package = parts[-1] == "__init__"
            if is_package:
                parts = parts[:-1]
            name = ".".join([package, *parts])
            modules[name] = Module(name, path, is_package)
    return modules


def is_type_checking_block(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def imports(module: Module, known: dict[str, Module], *, deferred: bool) -> dict[str, int]:
    """Project modules that ``module`` imports, with the line of the first import of each.

    Module level counts every statement outside a function, including ``if TYPE_CHECKING:``
    blocks (a cycle through annotations is still a cycle between the modules);
    ``deferred=True`` adds imports inside functions, which would only hide a cycle.
    """
    tree = ast.parse(module.path.read_text(), str(module.path))
    if deferred:
        nodes = [n for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom)]
    else:
        nodes = list(_module_level_imports(tree.body))
    here = module.name if module.is_package else module.name.rpartition(".")[0]
    found: dict[str, int] = {}
    for node in nodes:
        for target in _targets(node, here, known):
            if target != module.name:
                found.setdefault(target, node.lineno)
    return found


def _module_level_imports(body: list[ast.stmt]):
    for node in body:
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        elif isinstance(node, ast.If | ast.Try | ast.With):
            yield from _module_level_imports(node.body)
            yield from _module_level_imports(getattr(node, "orelse", []))
            for handler in getattr(node, "handlers", []):
                yield from _module_level_imports(handler.body)
            yield from _module_level_imports(getattr(node, "finalbody", []))


def _targets(node: ast.Import | ast.ImportFrom, here: str, known: dict[str, Module]):
    if isinstance(node, ast.Import):
        for alias in node.names:
            if alias.name in known:
                yield alias.name
        return
    if node.level:
        base = here.split(".")
        if node.level > 1:
            base = base[: -(node.level - 1)]
        source = ".".join(base + ([node.module] if node.module else []))
    else:
        source = node.module or ""
    for alias in node.names:
        submodule = f"{source}.{alias.name}"
        if submodule in known:
            yield submodule  # `from package import module`
        elif source in known:
            yield source


MODULES = discover()


def test_discovery_sees_the_three_trees() -> None:
    # the checks below are only as good as the module list they walk
    assert {
        "fieldgate.image",
        "fieldgate.can.adapter",
        "fieldgate.plugins.canopen.cia301.sdo",
    } <= set(MODULES)
    assert "fieldgate.conformance.catalog" in MODULES
    assert (
        "fieldgate.plugins.canopen.cia301.node" in MODULES
        and "fieldgate.canopen.node" not in MODULES
    )
    assert (
        MODULES["fieldgate.plugins.canopen.cia301.sdo"].path
        == ROOT / "plugins" / "canopen" / "cia301" / "sdo.py"
    )


def core_modules() -> list[Module]:
    return [
        m
        for m in MODULES.values()
        if m.name == "fieldgate"
        or (m.name.startswith("fieldgate.") and not m.name.startswith(FORBIDDEN_IN_CORE))
    ]


def test_core_source_imports_no_plugin_and_not_the_conformance_tool() -> None:
    offenders = [
        f"{m.path.relative_to(ROOT)}:{line} imports {target}"
        for m in core_modules()
        for target, line in imports(m, MODULES, deferred=True).items()
        if target.startswith(FORBIDDEN_IN_CORE)
    ]
    assert len(core_modules()) > 20
    assert offenders == []


def test_importing_every_core_module_loads_no_plugin_and_not_the_conformance_tool() -> None:
    # the run-time view of the check above: also catches importlib and re-exports. The second
    # line, after importing a plugin on purpose, shows that the check sees one.
    names = sorted(m.name for m in core_modules() if not m.name.endswith(".__main__"))
    script = (
        "import importlib, sys\n"
        f"def loaded():\n"
        f"    return ' '.join(sorted(m for m in sys.modules if m.startswith({FORBIDDEN_IN_CORE!r})))\n"
        f"for name in {names!r}:\n"
        "    importlib.import_module(name)\n"
        "print(loaded())\n"
        "importlib.import_module('fieldgate.plugins.canopen.cia301.sdo')\n"
        "print(loaded())\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert run.returncode == 0, run.stderr
    after_core, after_plugin = run.stdout.split("\n")[:2]
    assert after_core == ""
    assert "fieldgate.plugins.canopen.cia301.sdo" in after_plugin.split()


def find_cycles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """Strongly connected components of more than one module (or a module importing itself)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(node: str) -> None:  # Tarjan; the graph has ~150 nodes, recursion is fine
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph[node]:
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return components


def describe(component: list[str], graph: dict[str, dict[str, int]]) -> str:
    edges = [
        f"{MODULES[a].path.relative_to(ROOT)}:{line} -> {b}"
        for a in component
        for b, line in graph[a].items()
        if b in component
    ]
    return "cycle: " + "; ".join(edges)


def test_the_cycle_finder_finds_a_cycle() -> None:
    graph = {"a": {"b": 1}, "b": {"c": 2}, "c": {"a": 3}, "d": {"a": 4}}
    assert find_cycles(graph) == [["a", "b", "c"]]
    assert find_cycles({"a": {"b": 1}, "b": {}}) == []


def test_no_import_cycle_at_module_level() -> None:
    # module level includes `if TYPE_CHECKING:` imports: a cycle in annotations only is still
    # two modules that cannot be understood (or moved) one without the other
    graph = {name: imports(m, MODULES, deferred=False) for name, m in MODULES.items()}
    assert sum(len(edges) for edges in graph.values()) > 300
    assert [describe(c, graph) for c in find_cycles(graph)] == []


def test_no_import_cycle_closed_by_an_import_inside_a_function() -> None:
    # a deferred import hides a cycle from Python's import machinery, not from the design
    graph = {name: imports(m, MODULES, deferred=True) for name, m in MODULES.items()}
    assert [describe(c, graph) for c in find_cycles(graph)] == []


def test_every_package_folder_is_listed_for_the_wheel() -> None:
    """setuptools installs the packages pyproject.toml lists, nothing else: a new sub-package
    left out works from the source tree and fails in an installed gateway (the wheel test
    found fieldgate.isolation missing only in CI)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    listed = set(config["tool"]["setuptools"]["packages"])
    folders = {m.name for m in discover().values() if m.is_package}
    assert folders - listed == set()
    assert "fieldgate.isolation" in folders  # the finder sees sub-packages at all
