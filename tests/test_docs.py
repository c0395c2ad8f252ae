"""The documentation site (mkdocs.yml, docs/): its generated reference covers what the code
has, the README stays one page with the two commands, and every page the site lists exists.
The site itself is built with warnings as errors by `make docs` (part of `make test`)."""

from __future__ import annotations

import argparse
import ast
import importlib.util
import re
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
import yaml

from tests.helpers import REPO_ROOT

DOCS = REPO_ROOT / "docs"


def load_reference() -> ModuleType:
    """docs/_hooks/reference.py, the MkDocs hook that generates the reference pages."""
    spec = importlib.util.spec_from_file_location(
        "docs_reference", DOCS / "_hooks" / "reference.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks its module up there
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def reference() -> ModuleType:
    return load_reference()


def commands(
    parser: argparse.ArgumentParser, path: tuple[str, ...]
) -> list[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    found = [(path, parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                found.extend(commands(child, (*path, name)))
    return found


def test_cli_reference_has_every_command_and_option(reference: ModuleType) -> None:
    from api.cli import build_parser

    page = reference.cli_reference()
    found = commands(build_parser(), ("thermocomp",))
    assert len(found) > 15  # every command's real parser, not the stubs
    for path, parser in found:
        heading = f"## `{' '.join(path)}` {{#{'-'.join(path)}}}"
        assert heading in page, path
        section = page.split(heading, 1)[1].split("\n#", 1)[0]
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction | argparse._SubParsersAction):
                continue
            names = action.option_strings or [str(action.metavar or action.dest)]
            assert f"| `{reference.cell(names[0])}" in section, (path, names)


def test_settings_reference_has_every_setting(reference: ModuleType) -> None:
    from config.settings import settings_reference

    page = reference.settings_reference()
    for key, _type, _default, _description in settings_reference():
        assert f"| `{key}` |" in page, key


def test_openapi_reference_has_every_operation_and_schema(reference: ModuleType) -> None:
    from api.app import create_app
    from config.settings import Settings

    openapi = create_app(Settings()).openapi()
    page = reference.openapi_reference()
    operations = [
        f"### `{method.upper()} {path}`"
        for path, item in openapi["paths"].items()
        for method in item
        if method in {"get", "post", "put", "patch", "delete"}
    ]
    assert len(operations) >= 18
    for heading in operations:
        assert heading in page, heading
    for name in openapi["components"]["schemas"]:
        assert f"### {name} {{#schema-{name.lower()}}}" in page, name
    # every schema link the page makes lands on a schema it lists
    for target in set(re.findall(r"\(#(schema-[a-z0-9_]+)\)", page)):
        assert f"{{#{target}}}" in page, target


def test_websocket_reference_lists_every_topic(reference: ModuleType) -> None:
    from api.broadcast import TOPICS

    page = reference.websocket_reference()
    for topic in TOPICS:
        assert f"| `{topic}` |" in page


def test_step_reference_lists_every_column_with_a_meaning(reference: ModuleType) -> None:
    from daemon.storage.step_record import STEP_COLUMNS

    documented = [name for doc in reference.step_columns() for name in doc.names]
    assert tuple(documented) == STEP_COLUMNS
    page = reference.step_columns_reference()
    for column in STEP_COLUMNS:
        assert f"`{column}`" in page
    undocumented = [doc.names for doc in reference.step_columns() if not doc.meaning]
    assert undocumented == [], (
        f"columns without a comment in daemon/storage/step_record.py: {undocumented}"
    )


def appended_flags(path: Path) -> set[str]:
    """The flags a module appends to a step's ``flags`` list: string literals, or names of
    module-level string constants, passed to ``flags.append``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    constants = {
        target.id: node.value.value
        for node in tree.body
        if isinstance(node, ast.Assign)
        and isinstance(node.value, ast.Constant)
        and isinstance(node.value.value, str)
        for target in node.targets
        if isinstance(target, ast.Name)
    }
    flags: set[str] = set()
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr == "append"
            and isinstance(node.func.value, ast.Name)
            and node.func.value.id == "flags"
            and len(node.args) == 1
        ):
            (arg,) = node.args
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                flags.add(arg.value)
            elif isinstance(arg, ast.Name) and arg.id in constants:
                flags.add(constants[arg.id])
    return flags


def test_every_step_flag_is_documented() -> None:
    from daemon.storage.step_record import STEP_FLAGS

    # every module of the run machinery: the run kinds' steps and whatever they delegate to
    step_modules = sorted((REPO_ROOT / "daemon" / "run").rglob("*.py"))
    found = set().union(*(appended_flags(path) for path in step_modules))
    assert {"late", "unsafe-target", "camera-error", "marker-error"} <= found  # the scan works
    assert found <= set(STEP_FLAGS), f"undocumented step flags: {sorted(found - set(STEP_FLAGS))}"


def test_run_states_reference_has_every_state(reference: ModuleType) -> None:
    from daemon.run.states import RunState

    page = reference.run_states_reference()
    assert "idle -> starting -> running" in page  # the diagram of daemon/run/states.py
    for state in RunState:
        assert f"| `{state.value}` |" in page


def test_an_unknown_marker_is_reported(reference: ModuleType, caplog: Any) -> None:
    text = "# page\n\n<!-- generated:nothing-by-that-name -->\n"
    assert reference.expand(text, "page.md") == text
    assert "no generator for marker 'generated:nothing-by-that-name'" in caplog.text


def test_generated_text_names_no_tracker_issue(reference: ModuleType) -> None:
    for name, generate in reference.GENERATORS.items():
        assert not re.search(r"\bissues? \d", generate()), name


def nav_files(item: Any) -> list[str]:
    if isinstance(item, dict):
        return [file for value in item.values() for file in nav_files(value)]
    if isinstance(item, list):
        return [file for entry in item for file in nav_files(entry)]
    return [item]


def site_config() -> dict[str, Any]:
    class Loader(yaml.SafeLoader):
        pass

    config: dict[str, Any] = yaml.load(
        (REPO_ROOT / "mkdocs.yml").read_text(encoding="utf-8"), Loader=Loader
    )
    return config


def test_every_page_is_in_the_nav_and_every_nav_entry_exists() -> None:
    config = site_config()
    listed = nav_files(config["nav"])
    pending = set(config["extra"]["pending_pages"])
    pages = {
        str(path.relative_to(DOCS))
        for path in DOCS.rglob("*.md")
        if not path.relative_to(DOCS).parts[0].startswith("_")
    }
    assert pages - set(listed) == set(), "pages missing from mkdocs.yml's nav"
    assert {page for page in listed if page not in pages} <= pending


def test_no_page_cites_a_tracker_issue_or_a_file_outside_the_repository() -> None:
    for path in DOCS.rglob("*.md"):
        text = path.read_text(encoding="utf-8")
        assert not re.search(r"\bissues? \d", text), path
        assert "shared/" not in text and "DESIGN.md" not in text, path


def test_readme_is_a_page_with_the_two_commands() -> None:
    text = (REPO_ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) < 100
    quick_start = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    (block,) = re.findall(r"```sh\n(.*?)```", quick_start, flags=re.DOTALL)
    commands = [line.split("#", 1)[0].strip() for line in block.splitlines()]
    assert commands == ["make run", "make test"]
    assert "Safety" in text and not re.search(r"\bissues? \d", text)
    for link in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", text):
        assert (REPO_ROOT / link).exists(), link


def test_no_code_cites_the_console_facts_outside_the_repository() -> None:
    """The console's facts are docs/reference/c500c-console.md; code cites that page."""
    assert (DOCS / "reference" / "c500c-console.md").exists()
    offenders = []
    for folder in ("api", "daemon", "drivers", "config", "controller", "tests", "benchmarks"):
        for path in (REPO_ROOT / folder).rglob("*"):
            if path.suffix in {".py", ".md", ".r3", ".js", ".toml"} and path.is_file():
                text = path.read_text(encoding="utf-8")
                if re.search(r"(?<![\w/-])C500C\.md", text):
                    offenders.append(str(path.relative_to(REPO_ROOT)))
    assert offenders == []


@pytest.mark.parametrize("page", ["LICENSE", "CHANGELOG.md"])
def test_licence_and_changelog_exist(page: str) -> None:
    text = (REPO_ROOT / page).read_text(encoding="utf-8")
    if page == "LICENSE":
        assert text.startswith("MIT License") and "thermocomp developers" in text
    else:
        assert "## [Unreleased]" in text and "## [0.1.0]" in text
