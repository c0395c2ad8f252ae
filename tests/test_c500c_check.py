"""``thermocomp robot check``: connect, report, read `w2`, move nothing; its transcript is the
exact bytes exchanged and replays through the driver exchange by exchange."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from config import Settings
from drivers.c500c import robot_check
from drivers.c500c.console import Transcript
from drivers.c500c.robot_check import check, run_check
from drivers.c500c.server_check import run_server_check
from drivers.c500c.server_protocol import RequestType
from drivers.sim.emulator import START_POSE, C500CEmulator, EmulatorConfig
from drivers.sim.server_emulator import C500CServerEmulator, server_emulator_config
from tests.c500c_scripted import ScriptedRobot
from tests.helpers import run_in_process


def test_check_on_the_simulated_bench_prints_what_it_parsed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    transcript = tmp_path / "console.jsonl"
    status, out, err = run_in_process(
        robot_check.register, ["robot", "check", "--json", "--transcript", str(transcript)], capsys
    )
    assert status == 0, err
    report = json.loads(out)
    assert report["prompt"] == "ash> " and report["application"] == "ash"
    assert report["link"] == "connected" and report["units"] == "mm"
    assert report["world"] == pytest.approx(START_POSE)
    assert report["pulses"] == [0] * 6
    assert report["arm_power"] is None and report["point_of_control"] is None
    recorded = Transcript.read(transcript)
    assert recorded.sent() == b"\x05tcsync1\rw2\r"  # a probe line and the read-out: no motion
    assert report["bytes_sent"] == len(recorded.sent())
    assert report["bytes_received"] == len(recorded.received())
    assert "transcript:" in err


async def test_check_moves_nothing_and_changes_nothing() -> None:
    emulator = C500CEmulator(EmulatorConfig(paced=False, start_in_shell=True))
    async with emulator:
        report = await run_check(Settings(), port=emulator.device_path, transcript=None)
        assert list(emulator.state.commands) == ["tcsync1", "ash ash", "w2"]
        assert emulator.state.locations == {} and not emulator.state.online
    assert report.world == pytest.approx(START_POSE)
    assert "moved            nothing" in report.text()


async def test_a_transcript_replays_exchange_by_exchange(tmp_path: Path) -> None:
    """What a lab user sends back: the exact bytes; the driver must ask the same things in the
    same order and parse the same answers."""
    recorded = Transcript()
    emulator = C500CEmulator(EmulatorConfig(paced=False, start_in_shell=True, seed=3))
    async with emulator:
        original = await run_check(Settings(), port=emulator.device_path, transcript=recorded)
    path = tmp_path / "lab.jsonl"
    recorded.write(path)

    robot = ScriptedRobot(Transcript.read(path).exchanges(), prepare=False)
    replayed = await check(robot)
    robot.assert_all_used()
    assert replayed.world == original.world and replayed.w2_lines == original.w2_lines
    assert replayed.prompt == original.prompt


async def test_a_real_looking_transcript_with_the_second_prompt_form() -> None:
    """A hand-written transcript as a real controller might answer: the shell after boot, the
    `<app>[<file>]> ` prompt, and the read-out's units line with the values on the next line."""
    values = "        +401.250     -3.500   +612.004     +0.000    +90.000   -45.500"
    lines = [
        '{"t": 0.00, "dir": "host", "data": "\\u0005tcsync1\\r"}',
        '{"t": 0.01, "dir": "console", "data": "\\r\\n$ tcsync1\\r\\n"}',
        '{"t": 0.02, "dir": "console", "data": "tcsync1: not found\\r\\n$ "}',
        '{"t": 0.03, "dir": "host", "data": "ash cell\\r"}',
        '{"t": 0.04, "dir": "console", "data": "ash cell\\r\\ncell[cell.v3]> "}',
        '{"t": 0.05, "dir": "host", "data": "w2\\r"}',
        '{"t": 0.06, "dir": "console", "data": "w2\\r\\nActual Position :\\r\\n\\r\\n'
        "WORLD       (mm)       (mm)       (mm)      (deg)      (deg)      (deg)\\r\\n"
        + values
        + '\\r\\ncell[cell.v3]> "}',
    ]
    robot = ScriptedRobot(
        Transcript.from_lines(lines).exchanges(), prepare=False, application="cell"
    )
    report = await check(robot)
    robot.assert_all_used()
    assert report.prompt == "cell[cell.v3]> " and report.application == "cell"
    assert report.world == (401.25, -3.5, 612.004, 0.0, 90.0, -45.5)
    assert report.joints is None and report.pulses is None


def test_a_broken_transcript_names_the_line() -> None:
    with pytest.raises(ValueError, match="transcript line 2"):
        Transcript.from_lines(['{"t": 0, "dir": "host", "data": "w2\\r"}', '{"dir": "x"}'])


def test_check_of_the_fast_path_on_the_bench_moves_nothing(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("THERMOCOMP_ROBOT__DRIVER", "c500c-server")
    status, out, err = run_in_process(robot_check.register, ["robot", "check", "--json"], capsys)
    assert status == 0, err
    report = json.loads(out)
    assert report["link"] == "connected" and report["program"] == "thermocomp_server"
    assert report["world"] == pytest.approx(START_POSE)
    assert not report["goal_taught"] and not report["moving"] and report["point_of_control"]
    assert report["bytes_sent"] > 0 and report["bytes_received"] > 0


async def test_fast_path_check_sends_only_reads() -> None:
    emulator = C500CServerEmulator(server_emulator_config(paced=False))
    async with emulator:
        report = await run_server_check(Settings(), port=emulator.device_path)
        kinds = {request.type for request in emulator.requests}
    assert kinds <= {RequestType.HEARTBEAT, RequestType.READ_POSE}, kinds
    assert RequestType.READ_POSE in kinds and "moved            nothing" in report.text()


def test_a_transcript_of_the_fast_path_is_refused_with_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("THERMOCOMP_ROBOT__DRIVER", "c500c-server")
    status, _, err = run_in_process(
        robot_check.register,
        ["robot", "check", "--transcript", str(tmp_path / "t.jsonl")],
        capsys,
    )
    assert status == 2 and len(err.strip().splitlines()) == 1 and "binary frames" in err
