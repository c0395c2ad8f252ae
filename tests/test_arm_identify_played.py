"""Issue 20: ``thermocomp identify`` reads a PLAYED arm run (config/arm-sim-played.toml's
make-up: the duty cycle played by the console driver through the C500C emulator in joint space
on a pty, time_scale 1, virtual clock) as it was recorded: each measurement at the step's run
time (the arm's own time, nothing scaled), and the thermal displacement as the measured drift
minus the correction the robot arrived with at that pose (the player's, recorded by the step).
The oracle is the run's own database, read independently of daemon/commands/arm_identify.py."""

from __future__ import annotations

import asyncio
import sqlite3
from contextlib import closing
from pathlib import Path

import numpy as np
import pytest

from daemon.commands.arm_identify import load_arm_run
from daemon.commands.arm_run import IDENTIFY_STEP_S
from daemon.run.states import RunParameters
from daemon.service import Daemon
from daemon.storage.recorder import DATABASE_NAME
from drivers.clock import make_clock
from tests.test_arm_player import WAIT_S, settings_for

DURATION_S = 80.0  # four steps of 20 s: the two measured poses twice


@pytest.mark.slow
async def test_a_played_compensated_run_is_read_at_its_own_time_minus_its_arrived_correction(
    tmp_path: Path,
) -> None:
    data = tmp_path / "data"
    settings = settings_for(data, duration_s=DURATION_S)
    async with Daemon(settings, clock=make_clock("virtual")) as daemon:
        info = await daemon.start_run(RunParameters.from_settings(settings))
        async with asyncio.timeout(WAIT_S):
            final = await daemon.wait_run()
    assert final["state"] == "finished", final
    with closing(sqlite3.connect(data / DATABASE_NAME)) as db:
        rows = list(
            db.execute(
                "SELECT actual_s, measured_tx_um, measured_ty_um, measured_tz_um, "
                "correction_tx_mm, correction_ty_mm, correction_tz_mm FROM steps "
                "WHERE run_id = ? ORDER BY step",
                (info["id"],),
            )
        )
    assert len(rows) == 4
    recorded = np.array(rows, dtype=float)
    correction_mm = recorded[:, 4:7]
    # compensated: the player moved with them (the first step's model, at the run's start, is
    # still cold: no correction)
    assert np.all(np.abs(correction_mm[1:]) > 0.0)

    run = await asyncio.to_thread(load_arm_run, data, int(info["id"]))

    # the arm's time is the run's (time_scale 1): on the 20-s heat grid, within the run
    expected_s = np.round(recorded[:, 0] / IDENTIFY_STEP_S) * IDENTIFY_STEP_S
    np.testing.assert_array_equal(run.data.time_s, expected_s)
    assert run.data.time_s.max() <= DURATION_S
    assert run.data.joint_heat_w.shape[0] == round(run.data.time_s.max() / IDENTIFY_STEP_S) + 1
    # the thermal displacement: the measured drift minus the correction the robot arrived with
    displacement = run.data.marker_displacement_mm[:, 0, :]
    np.testing.assert_allclose(displacement, recorded[:, 1:4] / 1000.0 - correction_mm)
