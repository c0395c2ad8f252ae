"""The robot-side program's rules (drivers/sim/ur/program.py, the step the emulator runs every
controller cycle) and that controller/ur/thermocomp_offset.script carries the same constants."""

from __future__ import annotations

import math
import re

import pytest

from drivers.sim.ur import program as prog
from drivers.sim.ur.program import OffsetProgram, ProgramInputs, ProgramLimits
from drivers.ur import registers
from tests.helpers import REPO_ROOT

SCRIPT = REPO_ROOT / "controller" / "ur" / "thermocomp_offset.script"
CYCLE = ProgramLimits().cycle_s
STEP_M = prog.MAX_SPEED_M_S * CYCLE  # the most the offset moves in one cycle


def run(program: OffsetProgram, inputs: ProgramInputs, cycles: int) -> None:
    for _ in range(cycles):
        program.step(inputs)


def test_waits_at_zero_until_the_first_target() -> None:
    program = OffsetProgram()
    run(program, ProgramInputs(0, 0, (1e-4, 0, 0, 0, 0, 0)), 1000)  # sequence 0: no target
    assert program.applied == prog.ZERO_OFFSET
    assert program.status == registers.STATUS_WAITING


def test_rate_limit_moves_at_most_the_limit_per_cycle_then_reaches_the_target() -> None:
    program = OffsetProgram()
    target = (3e-4, -4e-4, 0.0, 0.0, 1e-4, 0.0)  # 0.5 mm, 0.1 mrad
    previous = program.applied
    for seq in range(1, 1000):
        applied = program.step(ProgramInputs(seq, 0, target))
        moved = math.dist(applied[:3], previous[:3])
        assert moved <= STEP_M * (1 + 1e-12)
        assert (
            math.dist(applied[3:], previous[3:]) <= prog.MAX_ANGULAR_SPEED_RAD_S * CYCLE * 1.000001
        )
        previous = applied
        if applied == target:
            break
    # 0.5 mm at 1 mm/s is 0.5 s = 250 cycles (+1: 250 sums of 2 um may fall short by an ulp)
    assert 250 <= seq <= 251
    assert program.status == 0 and program.accepted_sequence == seq
    assert program.step(ProgramInputs(seq + 1, 0, target)) == target


def test_hold_freezes_where_it_is_and_releasing_goes_on() -> None:
    program = OffsetProgram()
    target = (1e-3, 0, 0, 0, 0, 0)
    for seq in range(1, 101):
        program.step(ProgramInputs(seq, 0, target))
    frozen = program.applied
    assert 0 < frozen[0] < 1e-3
    for seq in range(101, 400):
        assert program.step(ProgramInputs(seq, 1, (0, 0, 0, 0, 0, 0))) == frozen
    assert program.status == registers.STATUS_HELD
    assert program.accepted_sequence == 100  # held targets are not accepted
    program.step(ProgramInputs(400, 0, target))
    assert program.applied[0] == pytest.approx(frozen[0] + STEP_M)


def test_silence_freezes_never_back_to_zero() -> None:
    program = OffsetProgram()
    target = (2e-4, 0, 0, 0, 0, 0)
    for seq in range(1, 201):
        program.step(ProgramInputs(seq, 0, target))
    assert program.applied == target
    # the PC goes silent: the same sequence for ever (its last values stay in the registers)
    silent = ProgramInputs(200, 0, (0.0, 0, 0, 0, 0, 0))
    watchdog = ProgramLimits().watchdog_cycles
    assert watchdog == round(prog.WATCHDOG_S / CYCLE) == 250
    for _ in range(watchdog - 1):
        program.step(ProgramInputs(200, 0, target))
    assert program.status == 0
    for _ in range(5000):
        assert program.step(silent) == target  # frozen at the last offset, not zero
    assert program.status == registers.STATUS_SILENT
    program.step(ProgramInputs(201, 0, (0.0, 0, 0, 0, 0, 0)))  # the PC is back
    assert program.applied[0] == pytest.approx(2e-4 - STEP_M)


@pytest.mark.parametrize(
    "target",
    [
        (2.1e-3, 0, 0, 0, 0, 0),  # over 2 mm
        (1.5e-3, 1.5e-3, 0, 0, 0, 0),  # each under, the length over
        (0, 0, 0, 0, 0, 2.5e-3),  # over 2 mrad
        (math.nan, 0, 0, 0, 0, 0),
        (0, 0, 0, math.inf, 0, 0),
        (0, 0, -math.inf, 0, 0, 0),
    ],
)
def test_over_limit_or_non_finite_targets_are_refused_frozen(target: tuple[float, ...]) -> None:
    program = OffsetProgram()
    run(program, ProgramInputs(1, 0, (1e-4, 0, 0, 0, 0, 0)), 100)
    before = program.applied
    assert program.step(ProgramInputs(2, 0, target)) == before
    assert program.status == registers.STATUS_REFUSED
    assert program.accepted_sequence == 1


def test_the_scripts_constants_are_the_programs() -> None:
    text = SCRIPT.read_text()

    def constant(name: str) -> float:
        match = re.search(rf"^global {name} = ([0-9.e-]+)$", text, re.MULTILINE)
        assert match, name
        return float(match.group(1))

    assert constant("MAX_OFFSET_M") == prog.MAX_OFFSET_M
    assert constant("MAX_ROTATION_RAD") == prog.MAX_ROTATION_RAD
    assert constant("MAX_SPEED_M_S") == prog.MAX_SPEED_M_S
    assert constant("MAX_ANGULAR_SPEED_RAD_S") == prog.MAX_ANGULAR_SPEED_RAD_S
    assert constant("WATCHDOG_S") == prog.WATCHDOG_S
    assert constant("FRAMES_TIMEOUT_S") == prog.FRAMES_TIMEOUT_S
    assert constant("CYCLE_S") == CYCLE
    assert constant("REG_BASE") == registers.DEFAULT_REGISTER_BASE
    # the status values the script writes are the register map's bits
    for value in (
        registers.STATUS_WAITING,
        registers.STATUS_REFUSED,
        registers.STATUS_RATE_LIMITED,
    ):
        assert f"status = {value}" in text
    assert "status = status + 1" in text and registers.STATUS_HELD == 1
    assert "status = status + 2" in text and registers.STATUS_SILENT == 2
    assert "path_offset_set(p[ap[0], ap[1], ap[2], ap[3], ap[4], ap[5]], 1)" in text  # BASE
    assert "path_offset_enable()" in text


def test_the_pc_side_limits_are_within_the_programs() -> None:
    from config.settings import RobotSettings

    fields = RobotSettings.model_fields
    assert fields["correction_limit_mm"].default <= prog.MAX_OFFSET_M * 1000
    assert fields["correction_limit_rad"].default <= prog.MAX_ROTATION_RAD
    # two heartbeats per watchdog period at least
    assert fields["ur_heartbeat_s"].default * 2 <= prog.WATCHDOG_S
