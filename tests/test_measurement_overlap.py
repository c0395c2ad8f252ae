"""Issue 30: a step's centroid, IR reading and record overlap the next steps' moves.

The step's period pays model -> check -> move -> frame; the rest of the step (daemon/run/step.py
``MeasuringStep``) finishes while the next step moves, its result on its own record, the
records committed in step order. Where the next step needs the measurement first (an observer
fuses it into the model; sensor_error_policy "pause" pauses before another move), it waits.
Synchronisation is by gates the fake devices wait at (tests/fakes.py), never by sleeping.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from daemon.run.session import MEASURING_STEPS
from daemon.run.states import RunState
from daemon.service import Daemon
from daemon.storage.recorder import RecorderError, StepRecord
from drivers.errors import DeviceError
from tests.fakes import Gate, Harness, make_settings, params

WAIT_S = 60.0  # bound of every wait: a hang fails, never blocks the suite
GATED_READ = 2  # IR read 2 is step 2's (no reference reads the IR)
# the gated reading must not time out (2 s of wall time by default) however loaded the machine
IR = {"read_timeout_s": WAIT_S}


async def until(condition: Callable[[], bool], timeout_s: float = WAIT_S) -> None:
    async with asyncio.timeout(timeout_s):
        while not condition():  # noqa: ASYNC110 -- the conditions are plain attributes
            await asyncio.sleep(0.001)


async def gated_step(harness: Harness, daemon: Daemon) -> tuple[Gate, int]:
    """Start a run whose step 2 waits at its IR reading; the robot's motion commands then
    (with compensation off the robot is not moved: the frames grabbed say how far it got)."""
    gate = Gate()
    harness.ir.gates[GATED_READ] = gate
    await daemon.start_run(params(daemon.settings, duration_s=30.0))
    async with asyncio.timeout(WAIT_S):
        await gate.reached.wait()
    return gate, len(harness.robot.commands)


async def test_the_next_step_moves_while_a_step_still_measures(tmp_path: Path) -> None:
    # compensation off: the spot drifts with the link, so a record that carried the next
    # step's frame would show a drift ahead of its own step's prediction
    settings = make_settings(tmp_path, compensation={"mode": "off"}, ir=IR)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert daemon.recorder is not None
        gate, _ = await gated_step(harness, daemon)
        # steps 3 and 4 move and take their frames while step 2 waits for its IR reading (and
        # they for step 2's measurement): the reference and steps 0 to 4
        frames = 1 + GATED_READ + MEASURING_STEPS
        await until(lambda: harness.camera.sequence >= frames)
        run = daemon.run
        assert run is not None and run.step == 1  # step 2 is not published before its record
        assert [s.step for s in daemon.recorder.steps(run.id)] == [0, 1]
        assert harness.ir.reads == GATED_READ + 1  # the devices are read in step order
        # and no further: at most MEASURING_STEPS steps measure while the next one moves
        await asyncio.sleep(0.05)
        assert harness.camera.sequence == frames
        gate.open()
        await until(lambda: daemon.run is not None and daemon.run.step >= 6)
        final = await daemon.stop()
        steps = daemon.recorder.steps(final["id"])
    assert final["state"] == "stopped"
    assert [s.step for s in steps] == list(range(len(steps)))  # all of them, in order
    # flag-free, but for a move the stop's hold may have refused in flight (its last step; the
    # race two other tests of the suite met by chance)
    flagged = [(s.step, s.flags) for s in steps if s.flags]
    assert flagged in ([], [(steps[-1].step, "robot-error")]), flagged
    moved = steps[: len(steps) - len(flagged)]
    assert len(moved) >= 7  # steps 0 to 6 were recorded before the stop
    drift = np.array([s.drift_x_um for s in moved])
    predicted = np.array([s.predicted_x_um for s in moved])
    # each record's centroid is its own step's frame: the drift follows the prediction to
    # within the noise-free centroid's error, where one step's growth is ten times that
    np.testing.assert_allclose(drift, predicted - predicted[0], atol=0.05)
    assert np.min(np.diff(predicted)) > 0.4


async def test_a_sensor_error_pauses_before_the_next_move_under_the_pause_policy(
    tmp_path: Path,
) -> None:
    settings = make_settings(tmp_path, scheduler={"sensor_error_policy": "pause"}, ir=IR)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        gate, moves = await gated_step(harness, daemon)
        gate.open(DeviceError("ir", "reading lost"))
        await until(lambda: daemon.run is not None and daemon.run.state is RunState.PAUSED)
        run = daemon.run
        assert run is not None and run.step == 2
        assert run.last_record is not None and "ir-error" in run.last_record["flags"]
        assert len(harness.robot.commands) == moves  # step 3 never moved
        final = await daemon.stop()
    assert final["state"] == "stopped"


async def test_an_observer_gets_the_measurement_before_the_next_prediction(
    tmp_path: Path,
) -> None:
    shaft = {"name": "shaft", "x": 0, "y": 0, "width": 4, "height": 4, "node": "9"}
    settings = make_settings(
        tmp_path, model={"prediction": "model+ir"}, ir={**IR, "regions": [shaft]}
    )
    harness = Harness(settings)
    async with harness.daemon as daemon:
        gate, moves = await gated_step(harness, daemon)
        await asyncio.sleep(0.05)  # time enough for step 3 to move if it did not wait
        assert len(harness.robot.commands) == moves
        gate.open()
        await until(lambda: daemon.run is not None and daemon.run.step >= 4)
        final = await daemon.stop()
    assert final["state"] == "stopped"


async def test_a_stop_while_a_step_measures_keeps_its_record(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, ir=IR)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert daemon.recorder is not None
        gate, _ = await gated_step(harness, daemon)
        stopping = asyncio.create_task(daemon.stop())
        await until(lambda: harness.robot.held)
        gate.open()
        final = await stopping
        steps = daemon.recorder.steps(final["id"])
    assert final["state"] == "stopped" and final["reason"] == "stopped by request"
    assert [s.step for s in steps] == list(range(len(steps)))
    assert len(steps) >= GATED_READ + 1  # step 2's measurement was recorded
    assert steps[GATED_READ].ir_json is not None


async def test_no_record_is_written_after_one_that_failed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # one commit fails (a full disk that then has room again): the steps measuring behind it
    # must not leave a gap in the record
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        recorder = daemon.recorder
        assert recorder is not None
        write_step = recorder.write_step

        def failing_once(record: StepRecord) -> None:
            if record.step == 3:
                raise RecorderError("database or disk is full")
            write_step(record)

        monkeypatch.setattr(recorder, "write_step", failing_once)
        info = await daemon.start_run(params(settings))
        final = await daemon.wait_run()
        steps = recorder.steps(info["id"])
    assert final["state"] == "aborted" and final["reason"] == (
        "recording failed: database or disk is full"
    )
    assert harness.robot.held
    assert [s.step for s in steps] == [0, 1, 2]
