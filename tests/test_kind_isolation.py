"""Adding a run kind touches the factory and the new kind's own files only (issue 27): no module
of the daemon or the API outside daemon/run/kinds.py and the kinds' packages names a specific
kind. Read from the source (ast), like tests/test_layering.py; the kinds themselves are read
from the factory (daemon/run/kinds.py KINDS), so a fourth kind is checked without editing this.

"Names a kind" means what would have to change when a kind is added:

- its class or its work's type, referred to anywhere (an import, an isinstance, a call);
- its name as a value compared with (``==``, ``in``, ``match``) or as a key of a dispatch
  table (a dict literal mapping names to functions or classes: the old ``_SUMMARIES``);
- an isinstance on the robot's kind of protocol (OffsetRobot: what the factory chooses by);
- an import from a kind's package into the kind-neutral run machinery (daemon/run/*.py,
  daemon/service.py) or the API, but for the listed seams below.

Out of scope, said rather than hidden: the pure core (daemon/model, vision, analysis, arm) may
not import the run machinery at all (tests/test_layering.py); its analyses read a run's steps
by their columns (daemon/analysis/arm.py ``is_arm_run``: pose columns), not by a run kind.
The CLI jobs and the calibration (daemon/commands, daemon/calibration) use the arm package's
tools (its tool meter, robot face, arm file): they run no run kind and choose none."""

from __future__ import annotations

import ast
import dataclasses
import re
from collections.abc import Iterator
from pathlib import Path

from daemon.run.kinds import KINDS

REPO = Path(__file__).resolve().parent.parent
FACTORY = REPO / "daemon" / "run" / "kinds.py"
KIND_PACKAGES = frozenset(REPO.joinpath(*kind.__module__.split(".")[:-1]) for kind in KINDS)
PURE_CORE = tuple(REPO / "daemon" / name for name in ("model", "vision", "analysis", "arm"))
#: the kind-neutral run machinery and the API: no import from a kind's package
NEUTRAL = (
    *sorted((REPO / "daemon" / "run").glob("*.py")),
    REPO / "daemon" / "service.py",
    *sorted((REPO / "api").rglob("*.py")),
)
#: imports from a kind's package the neutral machinery keeps, and why; none chooses a kind
SEAMS = {
    # the arm kind's test seams (Daemon(arm_setup=, arm_meter=)), passed to its build
    ("daemon/service.py", "daemon.run.arm.setup"),
    ("daemon/run/start.py", "daemon.run.arm.setup"),
    # the arm file a daemon's settings name, checked before it serves (arm_file: a path)
    ("daemon/run/inputs.py", "daemon.run.arm.setup"),
}
KIND_NAMES = frozenset(kind.name for kind in KINDS)
#: the dashboard: it renders each kind from the kind's view (GET /kinds), naming none
STATIC = REPO / "api" / "static"
DASHBOARD = (*sorted((STATIC / "js").glob("*.js")), STATIC / "index.html", STATIC / "style.css")
#: each kind's class and its work's type (the ``work`` field: a string, annotations deferred)
KIND_TYPES = frozenset(
    {kind.__name__ for kind in KINDS}
    | {str(f.type) for kind in KINDS for f in dataclasses.fields(kind) if f.name == "work"}
)
ROBOT_KINDS = frozenset({"OffsetRobot", "GoalRobot", "SpeedGoalRobot"})


def _outside_the_kinds() -> Iterator[Path]:
    for root in ("daemon", "api"):
        for path in sorted((REPO / root).rglob("*.py")):
            if path == FACTORY or any(package in path.parents for package in KIND_PACKAGES):
                continue
            if any(core in path.parents for core in PURE_CORE):
                continue
            yield path


def _constants(node: ast.expr) -> set[object]:
    if isinstance(node, ast.Constant):
        return {node.value}
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return {e.value for e in node.elts if isinstance(e, ast.Constant)}
    return set()


def kind_mentions(source: str, names: frozenset[str], types: frozenset[str]) -> list[str]:
    """Where ``source`` names a kind (module docstring), as ``line: what``."""
    found: list[str] = []
    for node in ast.walk(ast.parse(source)):
        line = getattr(node, "lineno", 0)
        if isinstance(node, ast.Name) and node.id in types:
            found.append(f"{line}: {node.id}")
        elif isinstance(node, ast.Attribute) and node.attr in types:
            found.append(f"{line}: {node.attr}")
        elif isinstance(node, ast.ImportFrom) and any(a.name in types for a in node.names):
            found.append(f"{line}: import {', '.join(a.name for a in node.names)}")
        elif isinstance(node, ast.Compare):
            compared = set().union(*(_constants(c) for c in (node.left, *node.comparators)))
            if compared & names:
                found.append(f"{line}: {ast.unparse(node)}")
        elif isinstance(node, ast.MatchValue) and _constants(node.value) & names:
            found.append(f"{line}: case {ast.unparse(node.value)}")
        elif isinstance(node, ast.Dict):
            keys = set().union(*(_constants(k) for k in node.keys if k is not None))
            table = all(isinstance(v, ast.Name | ast.Attribute) for v in node.values)
            if keys & names and table:
                found.append(f"{line}: dispatch table {sorted(keys & names)}")
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id == "isinstance"
            and len(node.args) == 2
            and {n.id for n in ast.walk(node.args[1]) if isinstance(n, ast.Name)} & ROBOT_KINDS
        ):
            found.append(f"{line}: {ast.unparse(node)}")
    return found


def test_the_factory_knows_every_kind_and_each_package_is_its_own() -> None:
    assert len(KINDS) == len(KIND_NAMES) == len(KIND_PACKAGES) >= 3
    assert {"two-link", "arm", "followed"} <= KIND_NAMES
    assert {"TwoLinkKind", "RunWork", "ArmRunWork", "FollowedWork"} <= KIND_TYPES


def test_nothing_outside_the_factory_and_the_kinds_names_a_kind() -> None:
    found = [
        f"{path.relative_to(REPO)}:{mention}"
        for path in _outside_the_kinds()
        for mention in kind_mentions(path.read_text(encoding="utf-8"), KIND_NAMES, KIND_TYPES)
    ]
    assert found == []


def test_the_neutral_run_machinery_and_the_api_import_no_kind_package() -> None:
    packages = {".".join(p.relative_to(REPO).parts) for p in KIND_PACKAGES}
    found: set[tuple[str, str]] = set()
    for path in NEUTRAL:
        if path == FACTORY:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            modules = (
                [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else []
            )
            for module in modules:
                if any(module == p or module.startswith(p + ".") for p in packages):
                    found.add((str(path.relative_to(REPO)), module))
    assert found - SEAMS == set()
    assert SEAMS - found == set(), "a seam no longer used: drop it from SEAMS"


def test_the_check_sees_each_way_of_naming_a_kind() -> None:
    """The check on the code before this change (summary.py's table, the kinds' isinstance),
    and what it must not take for a kind (a settings section named like one)."""
    source = (
        "from daemon.run.arm.kind import ArmKind\n"  # 1
        'SUMMARIES = {"two-link": two_link_summary, "arm": arm_summary}\n'  # 2
        "if isinstance(work, RunWork): pass\n"  # 3
        'if basis["kind"] == "followed": pass\n'  # 4
        'if kind.name in ("arm", "two-link"): pass\n'  # 5
        "if isinstance(robot, OffsetRobot): pass\n"  # 6
        "match name:\n"
        '    case "arm": pass\n'  # 8
        'settings = {"arm": {"enabled": True}, "model": model}\n'  # 9: a section, no kind
        'print("an arm run")\n'  # 10: words, no kind
    )
    lines = {
        int(m.split(":")[0])
        for m in kind_mentions(source, frozenset({"two-link", "arm", "followed"}), KIND_TYPES)
    }
    assert lines == {1, 2, 3, 4, 5, 6, 8}


#: every kind's own run parameters (KindBase.own_parameters): what tells its runs apart
OWN_PARAMETERS = frozenset(name for kind in KINDS for name in kind.own_parameters)
#: where a kind's own parameter is tested outside the kinds, and why; none builds a run
PARAMETER_SEAMS = {
    # the identification CLI reads a recorded run back and picks the arm's or the two-link
    # bench's identification by it: it chooses an analysis, not a run kind (module docstring)
    "daemon/commands/arm_identify.py",
}


def _is_parameters(node: ast.expr) -> bool:
    """``parameters``, ``row.parameters``, ``self.parameters``: a run's parameters, not its
    settings (``settings.arm.duty_cycle`` is the arm section's, read by the CLI jobs)."""
    return (isinstance(node, ast.Name) and node.id == "parameters") or (
        isinstance(node, ast.Attribute) and node.attr == "parameters"
    )


def _parameter_read(node: ast.expr, own: frozenset[str]) -> str | None:
    """The kind's own parameter ``node`` reads from a run's parameters, if it does one."""
    if isinstance(node, ast.Attribute) and node.attr in own and _is_parameters(node.value):
        return node.attr
    if isinstance(node, ast.Subscript) and _is_parameters(node.value):
        key = node.slice
        if isinstance(key, ast.Constant) and key.value in own:
            return str(key.value)
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "get"
        and _is_parameters(node.func.value)
        and node.args
        and isinstance(node.args[0], ast.Constant)
        and node.args[0].value in own
    ):
        return str(node.args[0].value)
    return None


def parameter_tests(source: str, own: frozenset[str]) -> list[str]:
    """Where ``source`` tells kinds apart by a kind's own parameter: compares it (``is None``,
    ``==``) or tests it (``if parameters.duty_cycle:``), as ``line: what``."""
    found: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            tested = [node.left, *node.comparators]
        elif isinstance(node, ast.If | ast.IfExp | ast.While):
            tested = [node.test]
        elif isinstance(node, ast.BoolOp):
            tested = list(node.values)
        elif isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.Not):
            tested = [node.operand]
        else:
            continue
        for expr in tested:
            if _parameter_read(expr, own) is not None:
                found.append(f"{expr.lineno}: {ast.unparse(node).splitlines()[0]}")
    return found


def test_nothing_outside_the_factory_and_the_kinds_tells_kinds_by_their_parameters() -> None:
    assert OWN_PARAMETERS  # the arm's duty cycle at least
    found = [
        f"{path.relative_to(REPO)}:{mention}"
        for path in _outside_the_kinds()
        if str(path.relative_to(REPO)) not in PARAMETER_SEAMS
        for mention in parameter_tests(path.read_text(encoding="utf-8"), OWN_PARAMETERS)
    ]
    assert found == []
    used = {
        seam
        for seam in PARAMETER_SEAMS
        if parameter_tests((REPO / seam).read_text(encoding="utf-8"), OWN_PARAMETERS)
    }
    assert used == PARAMETER_SEAMS, "a seam no longer used: drop it from PARAMETER_SEAMS"


def test_the_check_sees_each_way_of_testing_a_kind_parameter() -> None:
    """The check on the code before this change (daemon/run/setup.py check_reference_run told
    an arm reference from a two-link one by its duty cycle), and what it must not take for it
    (the arm section of the settings, a parameter passed on untested)."""
    source = (
        'reference_duty = row.parameters.get("duty_cycle")\n'  # 1: read, not tested
        "if (reference_duty is None) != (parameters.duty_cycle is None): pass\n"  # 2
        'this = "arm" if parameters.duty_cycle is not None else "two-link"\n'  # 3
        "if parameters.duty_cycle: pass\n"  # 4
        'if row.parameters["duty_cycle"] == "x": pass\n'  # 5
        'ok = not self.parameters.get("duty_cycle")\n'  # 6
        "if settings.arm.duty_cycle is None: pass\n"  # 7: the settings' arm section
        "load(parameters.duty_cycle)\n"  # 8: used, not tested
        "if parameters.compensation == 'off': pass\n"  # 9: every kind's parameter
    )
    lines = {int(m.split(":")[0]) for m in parameter_tests(source, frozenset({"duty_cycle"}))}
    assert lines == {2, 3, 4, 5, 6}


_COMMENTS = re.compile(r"/\*.*?\*/|<!--.*?-->|(?<![:\\])//[^\n]*", re.DOTALL)
_QUOTED = re.compile(r"""(["'`])((?:\\.|(?!\1)[^\\\n])*)\1""")


def page_kind_mentions(source: str, names: frozenset[str]) -> list[str]:
    """Where a dashboard file (JavaScript, HTML, CSS) names a kind, as ``line: what``: a quoted
    value that is a kind's name (a string compared with or keying a table, an attribute value,
    a CSS attribute selector), or a kind's name as an object key (``arm: [...]``). Comments
    and words in sentences ("the arm's model") are no kind."""
    found: list[str] = []
    keys = [re.compile(rf"(?:^|[{{,\s]){re.escape(n)}\s*:(?!:)") for n in names if n.isidentifier()]
    for number, line in enumerate(_COMMENTS.sub("", source).splitlines(), start=1):
        quoted = {m.group(2) for m in _QUOTED.finditer(line)} & names
        keyed = {k.pattern for k in keys if k.search(_QUOTED.sub('""', line))}
        if quoted or keyed:
            found.append(f"{number}: {line.strip()}")
    return found


def test_the_dashboard_names_no_kind() -> None:
    """The page's switches on a kind (its plots, form, runs table, headline, references) are
    the kind's view (daemon/run/kind.py KindView, GET /kinds): a new kind edits no page file."""
    found = [
        f"{path.relative_to(REPO)}:{mention}"
        for path in DASHBOARD
        for mention in page_kind_mentions(path.read_text(encoding="utf-8"), KIND_NAMES)
    ]
    assert found == []


def test_the_page_check_sees_each_way_the_old_dashboard_named_a_kind() -> None:
    """Lines of the dashboard before the kinds' views (each named a kind), and what the check
    must not take for one: comments, sentences, a field named like a kind."""
    source = (
        'return p.duty_cycle ? "arm" : "two-link";\n'  # 1
        "const SLOTS = {\n"
        '  "two-link": ["residual"],\n'  # 3
        '  arm: ["drift3d"],\n'  # 4
        "};\n"
        'if (this.kind === "arm") {\n'  # 6
        '<label data-kind="two-link">procedure\n'  # 7
        'body[data-kind="arm"] #frame-canvas { display: none; }\n'  # 8
        "const what = kind === 'followed' ? 1 : 2;\n"  # 9
        "// an arm run: the 3-D drift and rotation\n"  # 10: a comment
        '/* the two-link bench\'s "arm" */\n'  # 11: a comment
        "const text = `arm ${model.arm}, duty cycle`;\n"  # 12: words and a field
        'say("an arm run: its model");\n'  # 13: a sentence
        "const url = `${scheme}://${host}/arm`;\n"  # 14: no kind
    )
    lines = {
        int(m.split(":")[0])
        for m in page_kind_mentions(source, frozenset({"two-link", "arm", "followed"}))
    }
    assert lines == {1, 3, 4, 6, 7, 8, 9}
