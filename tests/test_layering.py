"""The import rule, read from the code's own imports (every one: module level, ``if
TYPE_CHECKING:`` blocks and function-local ones alike).

- Layers, top first: api -> daemon.commands -> the service (daemon.service and the daemon's
  top level) -> daemon.calibration -> daemon.run -> daemon.storage -> the pure core
  (daemon.model, daemon.vision, daemon.analysis, daemon.arm) -> drivers -> config. A module
  imports its own layer and the layers below it, never one above.
- The pure core imports no I/O layer: only itself and config.
- drivers/sim may import the pure core: the simulated bench computes its physics with the
  same model code (docs/explanation/architecture.md, "The layers").
- No import circle among the project's modules.
- A function-local project import is there for start-up time only and says so with a
  ``# lazy: <why>`` comment; any other one hides a circle or a dependency the reader
  cannot see at the top of the file.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.helpers import REPO_ROOT

PROJECT = ("api", "daemon", "drivers", "config")
PURE_CORE = ("daemon.model", "daemon.vision", "daemon.analysis", "daemon.arm")

# Top first. A module belongs to the layer of its longest matching prefix; a module in none
# (a new file at daemon/'s top, say) fails until it is placed here.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("api",),
    ("daemon.commands",),
    ("daemon.service", "daemon.heap", "daemon.systemd"),  # the façade and its process helpers
    ("daemon.calibration",),
    ("daemon.run",),
    ("daemon.storage",),
    PURE_CORE,
    ("drivers",),
    ("config",),
)
# Modules any layer may import: they import nothing of the project (checked below).
LEAVES = {"daemon": "daemon/__init__.py holds the version only"}
# Imports allowed besides the layers below: the simulated bench's physics is the model's, and
# the device factory builds that bench (so it stands on the pure core through drivers.sim
# anyway) and gives the arm's cameras their calibrated models (daemon.vision.cameras).
ALLOWED_UP = {"drivers.sim": PURE_CORE, "drivers.factory": ("daemon.vision",)}
# Imports refused although the layer is below: the pure core does no I/O.
FORBIDDEN_DOWN = {core: ("drivers",) for core in PURE_CORE}

LAZY_MARK = "# lazy:"


@dataclass(frozen=True)
class Import:
    name: str  # absolute module (or module.attribute) name
    line: int
    local: bool  # inside a function


def module_name(path: Path, root: Path = REPO_ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path, root: Path = REPO_ROOT) -> list[Import]:
    """Every import in ``path``, relative imports resolved to absolute names (``from .. api
    import x`` in daemon/y.py is ``api`` and ``api.x``: ``x`` may name a module)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module_name(path, root).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found: list[Import] = []

    def visit(node: ast.AST, local: bool) -> None:
        if isinstance(node, ast.Import):
            found.extend(Import(a.name, node.lineno, local) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module or ""
            else:
                parts = package[: len(package) - (node.level - 1)]
                base = ".".join([*parts, *([node.module] if node.module else [])])
            found.append(Import(base, node.lineno, local))
            found.extend(Import(f"{base}.{a.name}", node.lineno, local) for a in node.names)
        inner = local or isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)
        for child in ast.iter_child_nodes(node):
            visit(child, inner)

    visit(tree, local=False)
    return found


def imported_modules(path: Path, root: Path = REPO_ROOT) -> set[str]:
    return {item.name for item in imports_of(path, root)}


def is_within(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def is_project(name: str) -> bool:
    return any(is_within(name, top) for top in PROJECT)


def is_leaf(name: str) -> bool:
    """``name`` is a leaf module or a name in one (``daemon.__version__``, not ``daemon.run``)."""
    parent = name.rpartition(".")[0]
    path = REPO_ROOT.joinpath(*name.split("."))
    return name in LEAVES or (
        parent in LEAVES and not (path.is_dir() or path.with_suffix(".py").is_file())
    )


def layer_of(name: str) -> int:
    """The index in LAYERS (0 = top) of the longest prefix that ``name`` is within (a leaf's:
    the bottom)."""
    if is_leaf(name):
        return len(LAYERS) - 1
    best, best_len = -1, -1
    for index, prefixes in enumerate(LAYERS):
        for prefix in prefixes:
            if is_within(name, prefix) and len(prefix) > best_len:
                best, best_len = index, len(prefix)
    assert best >= 0, f"{name} is in no layer"
    return best


def import_refused(module: str, name: str) -> str | None:
    """Why ``module`` may not import ``name`` (None: it may)."""
    if not is_project(name) or is_within(name, module):
        return None
    for prefix, bad in FORBIDDEN_DOWN.items():
        if is_within(module, prefix) and any(is_within(name, b) for b in bad):
            return f"{prefix} is pure core: it imports no I/O layer"
    mine, theirs = layer_of(module), layer_of(name)
    if theirs >= mine:
        return None
    for prefix, allowed in ALLOWED_UP.items():
        if is_within(module, prefix) and any(is_within(name, a) for a in allowed):
            return None
    return f"{'/'.join(LAYERS[theirs])} is above {'/'.join(LAYERS[mine])}"


def project_modules(root: Path = REPO_ROOT) -> dict[str, Path]:
    return {
        module_name(path, root): path
        for top in PROJECT
        for path in sorted((root / top).rglob("*.py"))
    }


def import_graph(modules: Mapping[str, Path], root: Path = REPO_ROOT) -> dict[str, set[str]]:
    """Module -> the project modules it imports (``from a.b import c`` is an arrow to a.b.c
    when c is a module, to a.b when c is a name in it)."""

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        targets = {resolve(item.name) for item in imports_of(path, root)}
        graph[module] = {t for t in targets if t is not None and t != module}
    return graph


def cycles(graph: Mapping[str, set[str]]) -> list[list[str]]:
    """One circle (as its path, first module repeated at the end) per strongly connected
    component of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[set[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work: list[tuple[str, Iterator[str]]] = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component: set[str] = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    components.append(component)
    return [circle_in(graph, component) for component in components]


def circle_in(graph: Mapping[str, set[str]], component: set[str]) -> list[str]:
    """A shortest circle through the component's first module (breadth-first)."""
    start = min(component)
    previous: dict[str, str] = {}
    frontier = [start]
    while frontier:
        following: list[str] = []
        for node in frontier:
            for child in sorted(graph[node] & component):
                if child == start:
                    path = [node]
                    while path[-1] != start:
                        path.append(previous[path[-1]])
                    return [*reversed(path), start]
                if child not in previous:
                    previous[child] = node
                    following.append(child)
        frontier = following
    raise AssertionError(f"no circle in {sorted(component)}")


# --- the checker's own tests -------------------------------------------------------------


def test_relative_imports_are_resolved(tmp_path: Path) -> None:
    (tmp_path / "daemon" / "sub").mkdir(parents=True)
    source = tmp_path / "daemon" / "sub" / "thing.py"
    source.write_text("from ...api import app\nfrom . import sibling\nfrom .. import runs\n")
    names = imported_modules(source, tmp_path)
    assert {"api", "api.app", "daemon.sub.sibling", "daemon.runs"} <= names


def test_function_local_and_type_checking_imports_are_seen(tmp_path: Path) -> None:
    (tmp_path / "daemon").mkdir()
    source = tmp_path / "daemon" / "thing.py"
    source.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from daemon.typed import T\n"
        "def f():\n    from daemon.local import g\n"
        "class C:\n    async def m(self):\n        import daemon.method\n"
    )
    found = {(item.name, item.local) for item in imports_of(source, tmp_path)}
    assert {("daemon.typed.T", False), ("daemon.local.g", True), ("daemon.method", True)} <= found


def test_a_circle_is_reported_with_its_path() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"e"}}
    assert cycles(graph) == [["a", "b", "c", "a"]]
    assert cycles({"x": {"y"}, "y": set()}) == []


def test_a_circle_hidden_by_a_function_local_import_is_found(tmp_path: Path) -> None:
    (tmp_path / "daemon" / "commands").mkdir(parents=True)
    (tmp_path / "daemon" / "calibration").mkdir()
    (tmp_path / "daemon" / "commands" / "job.py").write_text("from daemon.calibration import run\n")
    (tmp_path / "daemon" / "calibration" / "run.py").write_text(
        "def f():\n    from daemon.commands.job import x\n"
    )
    modules = project_modules(tmp_path)
    assert cycles(import_graph(modules, tmp_path)) == [
        ["daemon.calibration.run", "daemon.commands.job", "daemon.calibration.run"]
    ]


def test_the_layers_read_as_the_rule() -> None:
    assert import_refused("daemon.commands.run", "daemon.service") is None
    assert import_refused("daemon.service", "daemon.commands.run") is not None
    assert import_refused("daemon.calibration.x", "daemon.commands.y") is not None
    assert import_refused("daemon.run.session", "daemon.storage.recorder") is None
    assert import_refused("daemon.storage.recorder", "daemon.run.states") is not None
    assert import_refused("daemon.arm.kinematics", "drivers.clock") is not None
    assert import_refused("daemon.arm.kinematics", "config.settings") is None
    assert import_refused("drivers.sim.bench", "daemon.model.network") is None
    assert import_refused("drivers.camera", "daemon.model.network") is not None
    assert import_refused("drivers.sim.bench", "daemon.run.states") is not None
    assert import_refused("config.settings", "drivers.clock") is not None
    assert import_refused("api.app", "daemon.commands.run") is None
    assert import_refused("daemon.run.x", "numpy") is None
    assert import_refused("daemon.run.start", "daemon.__version__") is None  # a leaf
    assert import_refused("drivers.goals", "daemon.arm.types") is not None


# --- the project --------------------------------------------------------------------------

MODULES = project_modules()


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_point_down(module: str) -> None:
    refused = [
        f"line {item.line}: imports {item.name}: {why}"
        for item in imports_of(MODULES[module])
        if (why := import_refused(module, item.name)) is not None
    ]
    assert not refused, f"{module}:\n  " + "\n  ".join(refused)


@pytest.mark.parametrize("leaf", sorted(LEAVES))
def test_a_leaf_imports_nothing_of_the_project(leaf: str) -> None:
    assert not [item.name for item in imports_of(MODULES[leaf]) if is_project(item.name)]


def test_no_import_circle() -> None:
    found = cycles(import_graph(MODULES))
    assert not found, "import circles:\n  " + "\n  ".join(" -> ".join(c) for c in found)


def unexplained_local_imports(path: Path) -> list[int]:
    """Lines of function-local project imports with no ``# lazy:`` comment: on the statement's
    own lines, or on the comment lines right above the run of import statements it is in."""
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()

    def marked(first: int, last: int) -> bool:
        above = first - 2  # the line above ``first`` (1-based)
        while above >= 0 and lines[above].strip().startswith("#"):
            if LAZY_MARK in lines[above]:
                return True
            above -= 1
        return any(LAZY_MARK in line for line in lines[first - 1 : last])

    def project_import(node: ast.stmt) -> bool:
        if isinstance(node, ast.ImportFrom):
            return node.level > 0 or is_project(node.module or "")
        return isinstance(node, ast.Import) and any(is_project(a.name) for a in node.names)

    found: list[int] = []

    def visit(node: ast.AST, local: bool) -> None:
        for field in ("body", "orelse", "finalbody", "handlers"):
            block = getattr(node, field, None)
            if not (isinstance(block, list) and block and isinstance(block[0], ast.AST)):
                continue
            run_start: ast.stmt | None = None
            for statement in block:
                is_import = isinstance(statement, ast.Import | ast.ImportFrom)
                if not is_import:
                    run_start = None
                elif run_start is None:
                    run_start = statement
                if local and is_import and project_import(statement):
                    assert run_start is not None
                    end = statement.end_lineno or statement.lineno
                    if not (marked(run_start.lineno, end) or marked(statement.lineno, end)):
                        found.append(statement.lineno)
        for child in ast.iter_child_nodes(node):
            inner = local or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef)
            visit(child, inner)

    visit(ast.parse(source), local=False)
    return sorted(set(found))


def test_the_lazy_check_reads_comments_over_a_run_of_imports(tmp_path: Path) -> None:
    source = tmp_path / "thing.py"
    source.write_text(
        "def f():\n"
        "    # lazy: SciPy, for --help\n"
        "    from daemon.a import x\n"
        "    from daemon.b import (\n        y,\n    )\n"
        "    x()\n"
        "    from daemon.c import z\n"
        "    import daemon.d  # lazy: OpenCV\n"
        "    import json\n"
        "from daemon.e import w\n"
    )
    assert unexplained_local_imports(source) == [8]


@pytest.mark.parametrize("module", sorted(MODULES))
def test_a_function_local_import_says_why_it_is_lazy(module: str) -> None:
    unexplained = unexplained_local_imports(MODULES[module])
    assert not unexplained, (
        f"{module}: function-local imports without a '{LAZY_MARK} <why>' comment at lines "
        f"{unexplained}: import at the top, or say what start-up time it saves"
    )
