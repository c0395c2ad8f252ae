"""Imports point api -> daemon -> drivers; the pure numeric core imports no I/O layer."""

import ast
from pathlib import Path

import pytest

from tests.helpers import REPO_ROOT

PURE_CORE = ("daemon.model", "daemon.vision", "daemon.analysis", "daemon.arm")

# What each layer must never import.
FORBIDDEN = {
    "config": ("api", "daemon", "drivers"),
    "drivers": ("api", "daemon"),  # except the pure core, allowed below
    "daemon": ("api",),
}


def imported_modules(path: Path, root: Path = REPO_ROOT) -> set[str]:
    """Every module ``path`` imports, relative imports resolved to absolute names (``from ..
    api import x`` in daemon/y.py is ``api`` and ``api.x``: it may name a module)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module_name(path, root).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module or ""
            else:
                parts = package[: len(package) - (node.level - 1)]
                base = ".".join([*parts, *([node.module] if node.module else [])])
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


def module_name(path: Path, root: Path = REPO_ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_relative_imports_are_resolved(tmp_path: Path) -> None:
    (tmp_path / "daemon" / "sub").mkdir(parents=True)
    source = tmp_path / "daemon" / "sub" / "thing.py"
    source.write_text("from ...api import app\nfrom . import sibling\nfrom .. import runs\n")
    names = imported_modules(source, tmp_path)
    assert {"api", "api.app", "daemon.sub.sibling", "daemon.runs"} <= names


def is_within(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


SOURCES = sorted(
    path
    for layer in ("config", "drivers", "daemon", "api")
    for path in (REPO_ROOT / layer).rglob("*.py")
)


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(REPO_ROOT)))
def test_imports_point_down(path: Path) -> None:
    module = module_name(path)
    layer = module.split(".")[0]
    pure = any(is_within(module, core) for core in PURE_CORE)
    for name in imported_modules(path):
        if pure:
            assert not any(is_within(name, bad) for bad in ("api", "drivers")), (
                f"{module} is pure core but imports {name}"
            )
            assert not (
                is_within(name, "daemon") and not any(is_within(name, c) for c in PURE_CORE)
            ), f"{module} is pure core but imports {name}"
            continue
        for bad in FORBIDDEN.get(layer, ()):
            if is_within(name, bad) and not any(is_within(name, c) for c in PURE_CORE):
                pytest.fail(f"{module} imports {name}: {layer} must not import {bad}")
