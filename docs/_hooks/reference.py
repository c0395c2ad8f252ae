"""The reference pages' generated parts, built from the code at every ``mkdocs build``.

A reference page is written by hand around a marker, ``<!-- generated:NAME -->`` on a line of
its own; this MkDocs hook (``hooks:`` in mkdocs.yml) replaces the marker with what the code
says today, so the reference cannot drift from the code:

- ``cli``: every ``thermocomp`` command and option, from the argparse parser (api/cli.py);
- ``settings``: every setting, from the pydantic settings schema (config/);
- ``openapi``: every REST operation and schema, from the app's OpenAPI description;
- ``websocket``: the WebSocket endpoint, from api/routers/ws.py and api/broadcast.py;
- ``step-columns``, ``step-flags``: the step record, from daemon/storage/step_record.py;
- ``run-states``: the run state machine, from daemon/run/states.py;
- ``fast-path-protocol``: controller/PROTOCOL.md, the fast path's specification, as it is.

An unknown marker, or a page whose marker is missing, fails the build (``mkdocs build --strict``
turns the warning into an error). Nothing here reaches the network.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import logging
import os
import re
import textwrap
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

REPO_ROOT = Path(__file__).resolve().parents[2]
MARKER = re.compile(r"^<!-- generated:([a-z-]+) -->$", re.MULTILINE)
#: argparse wraps usage lines at the terminal's width: a fixed one keeps the pages stable.
USAGE_COLUMNS = "96"

logger = logging.getLogger("mkdocs.hooks.reference")


# --- text helpers -------------------------------------------------------------------------

_ISSUE_REF = re.compile(
    r"\s*\((?:issues? \d+(?:(?:, | and )\d+)*)\)|\s*\bissues? \d+(?:, \d+)*[;:,]?"
)


def clean(text: str) -> str:
    """Docstrings and help texts as a reader of the site can use them: no tracker numbers
    (the reader cannot see the tracker), the console's facts pointing at their page."""
    text = _ISSUE_REF.sub("", text)
    return text.replace("docs/reference/c500c-console.md", "[the C500C console](c500c-console.md)")


def cell(text: str) -> str:
    """Text fit for one Markdown table cell."""
    return " ".join(text.split()).replace("|", "\\|")


def code(text: str) -> str:
    return f"`{text}`" if text else ""


# --- the command line ---------------------------------------------------------------------


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _option_name(action: argparse.Action) -> str:
    if action.option_strings:
        names = ", ".join(action.option_strings)
        if action.nargs == 0:
            return names
        metavar = action.metavar or (action.dest.upper() if action.choices is None else None)
        if metavar is None and action.choices is not None:
            metavar = "{" + ",".join(str(choice) for choice in action.choices) + "}"
        if isinstance(metavar, tuple):
            metavar = " ".join(metavar)
        return f"{names} {metavar}"
    metavar = action.metavar or action.dest
    return str(metavar if not isinstance(metavar, tuple) else " ".join(metavar))


def _help_text(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    if action.help is None or action.help == argparse.SUPPRESS:
        return ""
    formatter = parser._get_formatter()
    text: str = formatter._expand_help(action)
    if action.choices is not None and action.option_strings and action.metavar is not None:
        text += " (one of: " + ", ".join(str(choice) for choice in action.choices) + ")"
    return text


def _command_section(path: list[str], parser: argparse.ArgumentParser, lines: list[str]) -> None:
    subcommands = _subparsers(parser)
    title = " ".join(path)
    depth = min(len(path), 4)
    lines.append(f"{'#' * (depth + 1)} `{title}` {{#{'-'.join(path)}}}")
    lines.append("")
    if parser.description:
        lines.extend([clean(parser.description.strip()), ""])
    lines.extend(["```text", parser.format_usage().strip(), "```", ""])
    rows = [
        action
        for action in parser._actions
        if not isinstance(action, argparse._SubParsersAction | argparse._HelpAction)
        and action.help != argparse.SUPPRESS
    ]
    if rows:
        lines.extend(["| argument | meaning |", "| --- | --- |"])
        for action in rows:
            lines.append(
                f"| `{cell(_option_name(action))}` | {cell(clean(_help_text(parser, action)))} |"
            )
        lines.append("")
    if parser.epilog:
        lines.extend([clean(parser.epilog.strip()), ""])
    for name, child in subcommands.items():
        _command_section([*path, name], child, lines)


def cli_reference() -> str:
    """Every command of ``thermocomp``, its usage and its options, from the real parser."""
    from api.cli import COMMANDS, build_parser

    os.environ["COLUMNS"] = USAGE_COLUMNS
    parser = build_parser()
    lines = ["| command | what it does |", "| --- | --- |"]
    lines.extend(
        f"| [`thermocomp {c.name}`](#thermocomp-{c.name}) | {cell(c.help)} |" for c in COMMANDS
    )
    lines.append("")
    _command_section(["thermocomp"], parser, lines)
    return "\n".join(lines)


# --- the settings -------------------------------------------------------------------------


def settings_reference() -> str:
    """Every setting, section by section, from the settings schema."""
    from pydantic import BaseModel

    from config.settings import Settings
    from config.settings import settings_reference as rows

    by_section: dict[str, list[tuple[str, str, str, str]]] = {}
    for key, type_name, default, description in rows():
        by_section.setdefault(key.split(".", 1)[0], []).append(
            (key, type_name, default, description)
        )
    lines: list[str] = []
    for section, field in Settings.model_fields.items():
        model = field.annotation
        assert isinstance(model, type) and issubclass(model, BaseModel)
        lines.extend([f"## `[{section}]` {{#{section}}}", ""])
        if model.__doc__:
            lines.extend([clean(" ".join(model.__doc__.split())), ""])
        lines.extend(["| key | type | default | meaning |", "| --- | --- | --- | --- |"])
        for key, type_name, default, description in by_section.get(section, []):
            meaning = cell(clean(description))
            kind = cell(type_name.replace("\\|", "|"))  # the schema's own text escapes it
            lines.append(f"| `{key}` | {kind} | {code(cell(default))} | {meaning} |")
        lines.append("")
    return "\n".join(lines)


# --- the REST API -------------------------------------------------------------------------


def _schema_type(schema: dict[str, Any]) -> str:
    if "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[-1]
        return f"[{name}](#schema-{name.lower()})"
    if "anyOf" in schema:
        return " or ".join(_schema_type(part) for part in schema["anyOf"])
    if "enum" in schema:
        return " | ".join(f"`{json.dumps(value)}`" for value in schema["enum"])
    if "const" in schema:
        return f"`{json.dumps(schema['const'])}`"
    kind = schema.get("type", "any")
    if kind == "array":
        items = schema.get("items")
        if isinstance(items, dict) and items:
            return f"array of {_schema_type(items)}"
        prefix = schema.get("prefixItems")
        if prefix:
            return "[" + ", ".join(_schema_type(item) for item in prefix) + "]"
        return "array"
    if kind == "object" and isinstance(schema.get("additionalProperties"), dict):
        return f"object of {_schema_type(schema['additionalProperties'])}"
    return str(kind)


_BOUNDS = (
    ("minimum", ">="),
    ("exclusiveMinimum", ">"),
    ("maximum", "<="),
    ("exclusiveMaximum", "<"),
    ("minLength", "length >="),
    ("maxLength", "length <="),
    ("minItems", "items >="),
    ("maxItems", "items <="),
    ("pattern", "matches"),
)


def _constraints(schema: dict[str, Any]) -> str:
    parts = [f"{word} `{schema[key]}`" for key, word in _BOUNDS if key in schema]
    for part in schema.get("anyOf", []):
        parts.extend(f"{word} `{part[key]}`" for key, word in _BOUNDS if key in part)
    if "default" in schema:
        parts.append(f"default `{json.dumps(schema['default'])}`")
    return ", ".join(parts)


def _operations(openapi: dict[str, Any]) -> Iterator[tuple[str, str, dict[str, Any]]]:
    for path, item in openapi["paths"].items():
        for method, operation in item.items():
            if method in {"get", "post", "put", "patch", "delete"}:
                yield path, method.upper(), operation


def _access(operation: dict[str, Any]) -> str:
    security = operation.get("security")
    if not security:
        return "no token"
    if {} in security:
        return "read token, or none where anonymous reads are on (by default on loopback)"
    return "control token (`Authorization: Bearer <api.control_token>`)"


def openapi_reference() -> str:
    """Every operation and schema of the REST API, from the app's own OpenAPI description."""
    from api.app import create_app
    from config.settings import Settings

    openapi = create_app(Settings()).openapi()
    lines: list[str] = []
    for path, method, operation in _operations(openapi):
        lines.extend([f"### `{method} {path}`", ""])
        description = clean(operation.get("description") or operation.get("summary", ""))
        lines.extend([description.strip(), "", f"Access: {_access(operation)}.", ""])
        parameters = operation.get("parameters", [])
        if parameters:
            lines.extend(
                [
                    "| parameter | in | type | required | meaning |",
                    "| --- | --- | --- | --- | --- |",
                ]
            )
            for parameter in parameters:
                schema = parameter.get("schema", {})
                meaning = clean(parameter.get("description") or schema.get("description") or "")
                meaning = meaning.strip().rstrip(".")
                extra = _constraints(schema)
                lines.append(
                    f"| `{parameter['name']}` | {parameter['in']} | {cell(_schema_type(schema))} | "
                    f"{'yes' if parameter.get('required') else 'no'} | "
                    f"{cell(meaning)}{'; ' if meaning and extra else ''}{cell(extra)} |"
                )
            lines.append("")
        body = operation.get("requestBody")
        if body:
            for media, content in body.get("content", {}).items():
                lines.extend(
                    [f"Body ({code(media)}): {_schema_type(content.get('schema', {}))}.", ""]
                )
        lines.extend(["| status | meaning | body |", "| --- | --- | --- |"])
        for status, response in sorted(operation.get("responses", {}).items()):
            kinds = [
                f"{code(media)} {_schema_type(content.get('schema', {}))}".strip()
                for media, content in response.get("content", {}).items()
            ]
            meaning = cell(clean(response.get("description", "")))
            lines.append(f"| {status} | {meaning} | {cell(', '.join(kinds))} |")
        lines.append("")
    lines.extend(["## Schemas", ""])
    for name, schema in sorted(openapi.get("components", {}).get("schemas", {}).items()):
        lines.extend([f"### {name} {{#schema-{name.lower()}}}", ""])
        if schema.get("description"):
            lines.extend([clean(" ".join(schema["description"].split())), ""])
        properties = schema.get("properties", {})
        if properties:
            required = set(schema.get("required", []))
            lines.extend(["| field | type | required | meaning |", "| --- | --- | --- | --- |"])
            for field_name, field in properties.items():
                meaning = clean(field.get("description", "")).strip().rstrip(".")
                extra = _constraints(field)
                lines.append(
                    f"| `{field_name}` | {cell(_schema_type(field))} | "
                    f"{'yes' if field_name in required else 'no'} | "
                    f"{cell(meaning)}{'; ' if meaning and extra else ''}{cell(extra)} |"
                )
            lines.append("")
    return "\n".join(lines)


def websocket_reference() -> str:
    """The WebSocket endpoint: its module's contract and the topics the hub serves."""
    from api.broadcast import MESSAGE_TYPE, TOPICS
    from api.routers import ws

    lines = [clean(ws.__doc__ or "").strip().replace("``", "`"), ""]
    lines.extend(["| topic | message type | default |", "| --- | --- | --- |"])
    for topic in TOPICS:
        default = "yes" if topic in ws.DEFAULT_TOPICS else "no"
        lines.append(f"| `{topic}` | `{MESSAGE_TYPE[topic]}` | {default} |")
    lines.extend(
        [
            "",
            f"Subprotocol: `{ws.PROTOCOL}`; the token as `{ws.BEARER_PROTOCOL_PREFIX}<base64url>`. "
            f"Close codes: {ws.CLOSE_POLICY_VIOLATION} (policy violation, after "
            f"{ws.MAX_INVALID_MESSAGES} invalid messages), {ws.CLOSE_TOO_BIG} (message too big).",
        ]
    )
    return "\n".join(lines)


# --- the step record ----------------------------------------------------------------------

_AXIS_FAMILY = re.compile(r"^(?P<head>.*?_?)(?P<axis>t?r?[xyz])(?P<tail>_[a-z]+)$")


def _family(name: str) -> str | None:
    match = _AXIS_FAMILY.match(name)
    if match is None or not match.group("head").endswith("_"):
        return None
    axis = match.group("axis")
    return f"{match.group('head')}{axis[:-1]}{{x,y,z}}{match.group('tail')}"


@dataclasses.dataclass
class ColumnDoc:
    names: list[str]
    type_name: str
    meaning: str
    group: str


def step_columns() -> list[ColumnDoc]:
    """The steps table's columns in order, with the comments daemon/storage/step_record.py gives
    them (a comment on the line, or on the lines just above; ``# --- ... ---`` starts a group)."""
    from daemon.storage.step_record import STEP_COLUMNS, StepRecord

    source = (REPO_ROOT / "daemon" / "storage" / "step_record.py").read_text(encoding="utf-8")
    source_lines = source.splitlines()
    tree = ast.parse(source)
    (record_class,) = [
        node
        for node in tree.body
        if isinstance(node, ast.ClassDef) and node.name == StepRecord.__name__
    ]
    docs: list[ColumnDoc] = []
    group = "every run"
    previous_end = record_class.body[0].end_lineno or 0
    for node in record_class.body:
        if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
            previous_end = node.end_lineno or previous_end
            continue
        above: list[str] = []
        for line in source_lines[previous_end : node.lineno - 1]:
            text = line.strip().removeprefix("#").strip()
            if text.startswith("---"):
                group = text.strip("- ").strip()
                above = []
            elif text:
                above.append(text)
        line = source_lines[node.lineno - 1]
        trailing = line.split("#", 1)[1].strip() if "#" in line else ""
        meaning = " ".join([*above, trailing]).strip()
        type_name = ast.unparse(node.annotation)
        name = node.target.id
        family = _family(name)
        last = docs[-1] if docs else None
        if (
            last is not None
            and family is not None
            and _family(last.names[-1]) == family
            and last.type_name == type_name
            and last.group == group
            and not above
        ):
            last.names.append(name)
            if meaning:
                last.meaning = f"{last.meaning} {meaning}".strip()
        else:
            docs.append(ColumnDoc([name], type_name, meaning, group))
        previous_end = node.end_lineno or node.lineno
    documented = [name for doc in docs for name in doc.names]
    assert tuple(documented) == STEP_COLUMNS, "step_record.py changed shape: update this parser"
    return docs


_SQL = {"int": "integer", "float": "number", "str": "text"}


def step_columns_reference() -> str:
    lines: list[str] = []
    group = None
    for doc in step_columns():
        if doc.group != group:
            group = doc.group
            lines.extend(["", f"**{clean(group)[:1].upper() + clean(group)[1:]}**", ""])
            lines.extend(["| column | type | meaning |", "| --- | --- | --- |"])
        base = doc.type_name.split("|")[0].strip()
        kind = _SQL.get(base, base) + (" or empty" if "None" in doc.type_name else "")
        names = ", ".join(f"`{name}`" for name in doc.names)
        lines.append(f"| {names} | {kind} | {cell(clean(doc.meaning))} |")
    return "\n".join(lines).strip()


def step_flags_reference() -> str:
    from daemon.storage.step_record import STEP_FLAGS

    lines = ["| flag | meaning |", "| --- | --- |"]
    lines.extend(f"| `{flag}` | {cell(clean(meaning))} |" for flag, meaning in STEP_FLAGS.items())
    return "\n".join(lines)


# --- the run states -----------------------------------------------------------------------


def run_states_reference() -> str:
    from daemon.run import states as runs
    from daemon.run.states import RUN_STATE_MEANINGS, TRANSITIONS, RunState

    diagram = (runs.__doc__ or "").split("::", 1)[1].split("\n\n", 2)[1]
    lines = ["```text", textwrap.dedent(diagram).rstrip()]
    lines.extend(
        ["```", "", "| state | kind | next states | meaning |", "| --- | --- | --- | --- |"]
    )
    for state in RunState:
        kind = "final" if state.is_terminal else "active" if state.is_active else "idle"
        targets = ", ".join(
            f"`{target.value}`" for target in RunState if target in TRANSITIONS[state]
        )
        meaning = cell(clean(RUN_STATE_MEANINGS[state]))
        lines.append(f"| `{state.value}` | {kind} | {targets or '—'} | {meaning} |")
    return "\n".join(lines)


# --- the fast path's protocol -------------------------------------------------------------


def fast_path_protocol() -> str:
    """controller/PROTOCOL.md under the page's own title: its headings one level down."""
    text = (REPO_ROOT / "controller" / "PROTOCOL.md").read_text(encoding="utf-8")
    body = text.split("\n", 1)[1] if text.startswith("# ") else text
    body = re.sub(r"^(#+) ", r"#\1 ", body, flags=re.MULTILINE)
    return clean(body).strip()


GENERATORS: dict[str, Callable[[], str]] = {
    "cli": cli_reference,
    "settings": settings_reference,
    "openapi": openapi_reference,
    "websocket": websocket_reference,
    "step-columns": step_columns_reference,
    "step-flags": step_flags_reference,
    "run-states": run_states_reference,
    "fast-path-protocol": fast_path_protocol,
}


def expand(markdown: str, page: str) -> str:
    """The page with every marker replaced by its generated text; a warning (an error under
    ``--strict``) for a marker nothing generates."""

    def replace(match: re.Match[str]) -> str:
        name = match.group(1)
        generator = GENERATORS.get(name)
        if generator is None:
            logger.warning("%s: no generator for marker 'generated:%s'", page, name)
            return match.group(0)
        return generator()

    return MARKER.sub(replace, markdown)


# --- the MkDocs hooks ---------------------------------------------------------------------


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    return expand(markdown, page.file.src_uri)


def on_config(config: Any) -> Any:
    """Drop from the nav the pages named in ``extra.pending_pages`` that do not exist yet
    (pages written on other branches); every other missing page stays an error."""
    pending = set(config.get("extra", {}).get("pending_pages", []))
    docs_dir = Path(config["docs_dir"])

    def keep(item: Any) -> Any:
        if isinstance(item, dict):
            ((title, value),) = item.items()
            kept = keep(value)
            return None if kept in (None, []) else {title: kept}
        if isinstance(item, list):
            return [kept for kept in (keep(entry) for entry in item) if kept is not None]
        if isinstance(item, str) and item in pending and not (docs_dir / item).exists():
            logger.info("nav: %s is not written yet; left out", item)
            return None
        return item

    if config.get("nav") is not None:
        config["nav"] = keep(config["nav"])
    return config
