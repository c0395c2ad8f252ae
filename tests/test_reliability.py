"""Reliability of a whole run (issue 10): serial faults injected by the C500C emulator over the
real pseudo-terminal while the daemon runs on the simulated bench, and a database that fills
up under the real Recorder."""

from __future__ import annotations

import asyncio
import math
import sqlite3
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from config import Settings
from daemon.model import ThermalModel
from daemon.run.states import RunParameters, RunState
from daemon.service import Daemon
from drivers.c500c.robot import C500CRobot
from drivers.sim.emulator import FAULT_KINDS, C500CEmulator, FaultKind

# As in tests/test_c500c_link.py: a fault outlasts the command timeout by a wide margin, and
# ordinary replies of the in-process emulator never come near it on a loaded machine.
COMMAND_TIMEOUT_S = 1.0
FAULT_S = 2.5 * COMMAND_TIMEOUT_S
STEPS_BEFORE_FAULT = 3
STEPS_AFTER_RESUME = 5
CONSOLE_GRAIN_MM = 0.001  # the console prints poses to 0.001 mm


def bench_settings(tmp_path: Path) -> Settings:
    """The simulated bench on a virtual clock: the run goes as fast as the pty allows, a small
    camera frame keeps the steps cheap, and a noise-free robot makes the pose an oracle."""
    return Settings.model_validate(
        {
            "bench": {"clock": "virtual", "robot_noise_um": 0.0, "stand_drift_um": 0.0},
            "camera": {"width_px": 320, "height_px": 240},
            "robot": {
                "command_timeout_s": COMMAND_TIMEOUT_S,
                "move_timeout_s": 2.0,
                "reconnect_max_backoff_s": 0.2,
                "emulator_move_ms": 1.0,
            },
            "compensation": {"mode": "absolute"},
            "scheduler": {"duration_s": 3600.0, "step_s": 1.0},
            "storage": {"data_dir": str(tmp_path), "report_at_end": False},
        }
    )


async def wait_for_step(daemon: Daemon, step: int, timeout_s: float = 20.0) -> None:
    """Until the run has recorded ``step`` (events, no polling)."""
    with daemon.subscribe(kinds=frozenset({"step"})) as subscription:
        async with asyncio.timeout(timeout_s):
            while daemon.run is None or daemon.run.step < step:
                await subscription.get()


@pytest.mark.slow
@pytest.mark.parametrize("kind", FAULT_KINDS)
async def test_a_serial_fault_mid_run_parks_it_until_resumed_with_absolute_targets(
    tmp_path: Path, kind: FaultKind
) -> None:
    settings = bench_settings(tmp_path)
    async with Daemon(settings) as daemon:
        emulator = getattr(daemon.devices, "emulator", None)
        robot = daemon.devices.robot
        recorder = daemon.recorder
        assert isinstance(emulator, C500CEmulator) and isinstance(robot, C500CRobot)
        assert recorder is not None
        info = await daemon.start_run(RunParameters.from_settings(settings))
        await wait_for_step(daemon, STEPS_BEFORE_FAULT)

        emulator.inject(kind, FAULT_S if kind in ("delay", "stall") else None)
        async with asyncio.timeout(30.0):
            assert await daemon.wait_state(RunState.FAULT) is RunState.FAULT
        snapshot = daemon.snapshot()
        assert snapshot["state"] == "fault" and snapshot["run"]["reason"]
        assert snapshot["errors"][-1]["device"] == "robot"

        # the link comes back on its own, the motion does not
        await robot.wait_connected(10.0)
        parked_motions = len(emulator.state.motion_commands())
        await asyncio.sleep(0.3)  # many step periods of the virtual clock
        assert len(emulator.state.motion_commands()) == parked_motions
        assert daemon.snapshot()["state"] == "fault"
        faulted_at = daemon.run.step if daemon.run is not None else -1

        await daemon.resume()
        await wait_for_step(daemon, faulted_at + STEPS_AFTER_RESUME)
        await daemon.stop()
        assert len(emulator.state.motion_commands()) > parked_motions
        goal = robot.goal
        assert goal is not None
        steps = recorder.steps(info["id"])

    assert [k for _, k in emulator.faults_applied] == [kind]
    assert [s.step for s in steps] == list(range(len(steps)))  # no step record lost
    assert len(steps) >= faulted_at + STEPS_AFTER_RESUME
    faulted = [s for s in steps if s.error]
    assert len(faulted) == 1 and "robot" in faulted[0].flags
    # after the resume each move went to goal + offset (absolute), not to wherever it drifted
    after = [s for s in steps if s.step > faulted[0].step]
    assert after
    for step in after:
        assert step.offset_x_mm is not None and step.pose_x_mm is not None
        assert step.pose_x_mm == pytest.approx(goal.x + step.offset_x_mm, abs=CONSOLE_GRAIN_MM)
        assert step.pose_z_mm == pytest.approx(goal.z + (step.offset_z_mm or 0.0), abs=0.0011)


async def test_a_full_database_stops_the_run_safely(tmp_path: Path) -> None:
    """A real SQLITE_FULL from the real Recorder (the page limit stands in for the disk):
    the run ends, the robot holds, the error is reported, every committed step stays."""
    settings = bench_settings(tmp_path)
    async with Daemon(settings) as daemon:
        robot = daemon.devices.robot
        recorder = daemon.recorder
        assert recorder is not None
        info = await daemon.start_run(RunParameters.from_settings(settings))
        await wait_for_step(daemon, STEPS_BEFORE_FAULT)
        connection: sqlite3.Connection = recorder._db  # private: the disk's stand-in
        with recorder._lock:
            pages = connection.execute("PRAGMA page_count").fetchone()[0]
            connection.execute(f"PRAGMA max_page_count = {pages}")
        async with asyncio.timeout(30.0):
            final: dict[str, Any] = await daemon.wait_run()
        errors = daemon.snapshot()["errors"]
        held = robot.status().motion_held
        with recorder._lock:
            connection.execute("PRAGMA max_page_count = 1073741823")
        steps = recorder.steps(info["id"])
    assert final["state"] == "aborted" and "full" in final["reason"]
    assert held
    assert errors[-1]["device"] == "storage" and "full" in errors[-1]["message"]
    assert [s.step for s in steps] == list(range(len(steps))) and len(steps) > STEPS_BEFORE_FAULT


MAX_STEP_MM = 0.05
MAX_TOTAL_MM = 0.2
POISONED_FROM_S = 2.0  # steps 0 and 1 see the real prediction, later steps the drawn one

hostile_um = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324]),
    st.floats(-1000.0, 1000.0),  # around both limits (um; scale 1)
)


def wshift_offsets(commands: list[str]) -> list[tuple[float, float, float]]:
    """The offsets of every absolute move written to the console (`wshift cur,dx,dy,dz,...`)."""
    offsets = []
    for command in commands:
        if command.startswith("wshift "):
            dx, dy, dz = (float(v) for v in command.split(" ", 1)[1].split(",")[1:4])
            offsets.append((dx, dy, dz))
    return offsets


@pytest.mark.slow
@settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(predicted=st.tuples(hostile_um, hostile_um, hostile_um))
async def test_unsafe_targets_never_reach_the_serial_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, predicted: tuple[float, float, float]
) -> None:
    """Whatever the model predicts (NaN, infinities, huge, beyond the envelope or the step
    limit), the console of the emulator only ever receives finite offsets within the limits."""
    data_dir = Path(tempfile.mkdtemp(dir=tmp_path))  # one database per example
    base = bench_settings(data_dir)
    limits = {"max_step_change_mm": MAX_STEP_MM, "max_total_offset_mm": MAX_TOTAL_MM}
    config = base.model_copy(update={"compensation": base.compensation.model_copy(update=limits)})
    real = ThermalModel.deformation_um

    def drawn(model: ThermalModel) -> np.ndarray:
        return np.array(predicted) if model.time_s >= POISONED_FROM_S else real(model)

    monkeypatch.setattr(ThermalModel, "deformation_um", drawn)
    async with Daemon(config) as daemon:
        emulator = getattr(daemon.devices, "emulator", None)
        assert isinstance(emulator, C500CEmulator)
        await daemon.start_run(RunParameters.from_settings(config, duration_s=6.0))
        async with asyncio.timeout(30.0):  # refused: paused with the reason; else it ends
            await daemon.wait_state(RunState.PAUSED, RunState.FAULT)
        commands = list(emulator.state.commands)

    offsets = wshift_offsets(commands)
    assert len(offsets) >= 2  # the steps before the drawn prediction moved
    previous = (0.0, 0.0, 0.0)
    for offset in offsets:
        assert all(math.isfinite(v) and abs(v) <= MAX_TOTAL_MM + 1e-9 for v in offset)
        assert all(
            abs(v - p) <= MAX_STEP_MM + CONSOLE_GRAIN_MM
            for v, p in zip(offset, previous, strict=True)
        )
        previous = offset
    assert not any("nan" in c.lower() or "inf" in c.lower() for c in commands)
