"""Imports point api -> daemon -> drivers; the pure numeric core imports no I/O layer."""

import ast
from pathlib import Path

import pytest

from tests.helpers import REPO_ROOT

PURE_CORE = ("daemon.model", "daemon.vision", "daemon.analysis")

# What each layer must never import.
FORBIDDEN = {
    "config": ("api", "daemon", "drivers"),
    "drivers": ("api", "daemon"),  # except the pure core, allowed below
    "daemon": ("api",),
}


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def module_name(path: Path) -> str:
    return ".".join(path.relative_to(REPO_ROOT).with_suffix("").parts)


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
