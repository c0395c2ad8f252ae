"""A fake that does not pass the Robot contract goes (issue 26): the suite's robot fakes are the
contract's (tests/contract/adapters.py CONTRACT_FAKES, each with an adapter), and no other
module of tests/ defines a class that looks like a robot.

"Looks like a robot": the class defines one of the robot's calls (drivers/base.py Robot,
GoalRobot and OffsetRobot, ``stop`` aside: a thread or a server stops too), or subclasses one of
the contract's fakes. A subclass of a real driver that replaces only its transport (tests/
c500c_scripted.py ScriptedRobot) keeps the driver's calls and is not one. To record what a test
sends to a robot, wrap the real call (``monkeypatch.setattr(robot, "move_absolute", ...)``)
rather than writing a class."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.contract.adapters import ADAPTERS, CONTRACT_FAKES

TESTS = Path(__file__).resolve().parent.parent
CONTRACT = TESTS / "contract"

#: the calls of drivers/base.py's robot protocols a fake would have to implement
ROBOT_CALLS = frozenset(
    {
        "teach_goal",
        "move_absolute",
        "move_incremental",
        "actual_pose",
        "resume",
        "set_correction",
        "apply_correction",
        "follow_program",
        "robot_state",
        "read_state",
    }
)


def robot_like_classes(source: str, fakes: frozenset[str]) -> list[tuple[int, str]]:
    """(line, name) of each class of ``source`` that looks like a robot (module docstring)."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.ClassDef):
            continue
        defined = {
            item.name
            for item in node.body
            if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef)
        }
        bases = {ast.unparse(base).rsplit(".", 1)[-1] for base in node.bases}
        if defined & ROBOT_CALLS or bases & fakes:
            found.append((node.lineno, node.name))
    return found


def _where(cls: type) -> tuple[Path, str]:
    module = cls.__module__.split(".")
    return TESTS.parent.joinpath(*module).with_suffix(".py"), cls.__name__


def test_every_robot_like_class_of_the_tests_is_a_contract_fake() -> None:
    fakes = frozenset(cls.__name__ for cls in CONTRACT_FAKES)
    allowed = {_where(cls) for cls in CONTRACT_FAKES}
    seen: set[tuple[Path, str]] = set()
    outside: list[str] = []
    for path in sorted(TESTS.rglob("*.py")):
        for line, name in robot_like_classes(path.read_text(encoding="utf-8"), fakes):
            seen.add((path, name))
            if (path, name) not in allowed and CONTRACT not in path.parents:
                outside.append(f"{path.relative_to(TESTS.parent)}:{line} {name}")
    assert outside == [], "robot fakes outside the Robot contract (put them under it)"
    assert allowed <= seen  # the check sees the contract's own fakes: it is not vacuous


async def test_every_contract_fake_has_an_adapter() -> None:
    """Each fake in CONTRACT_FAKES is, exactly, the robot of one of the contract's adapters."""
    opened: set[type] = set()
    for adapter in ADAPTERS.values():
        async with adapter() as subject:
            opened.add(type(getattr(subject.robot, "robot", subject.robot)))  # under a façade
    assert set(CONTRACT_FAKES) <= opened


def test_the_check_sees_a_hand_written_fake_and_a_subclass() -> None:
    source = (
        "class Spy:\n"
        "    async def move_absolute(self, offset_mm): ...\n"
        "class Quiet(FakeRobot):\n"
        "    def _pose(self): ...\n"
        "class Flood:\n"
        "    def stop(self): ...\n"
        "class Scripted(C500CRobot):\n"
        "    async def _open_port(self): ...\n"
    )
    assert robot_like_classes(source, frozenset({"FakeRobot"})) == [(1, "Spy"), (3, "Quiet")]
