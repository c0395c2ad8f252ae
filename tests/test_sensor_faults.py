"""Camera and IR faults (issue 10): the simulated sensors inject no-frame, late and unreadable
faults at a known grab/read while the daemon runs on the bench's virtual clock; the faulted
step, and only it, is flagged with its error, the run goes on or pauses as
scheduler.sensor_error_policy says, and no step record is lost. Also: the fault spec settings
and the OpenCV source's guard against a second read while a timed-out one is still blocked."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import drivers.camera
from config import ConfigError, Settings, load_settings
from config.faults import SENSOR_FAULT_KINDS, Fault, parse_sensor_faults
from daemon.run.states import RunParameters, RunState
from daemon.service import Daemon
from daemon.storage.recorder import StepRecord
from drivers.camera import VideoSource
from drivers.clock import VirtualClock
from drivers.errors import DeviceError, ProtocolError
from drivers.sim.bench import Bench
from drivers.sim.devices import SimCamera, SimIrReader
from drivers.sim.emulator import C500CEmulator

FAULT_STEP = 3
#: The camera's first grab is the run's reference frame (before step 0), so step k is grab k+2;
#: the IR reader's first read is step 0's.
FIRST_GRAB_OF_STEP = {"camera": 2, "ir": 1}
#: Wall time the daemon waits for a frame/reading: ~100x a normal grab of the small test frame.
SENSOR_TIMEOUT_S = 1.0
MAX_AGE_S = 2.0
LATE_S = 5.0  # delivered this late on the run clock: stale (> MAX_AGE_S)
DURATION_S = 12.0  # run clock; a late fault jumps it by LATE_S

#: device -> kind -> (flag, error kind in the daemon's error list, text in the step's error)
EXPECTED = {
    "camera": {
        "no-frame": ("camera-error", "timeout", f"camera: no frame within {SENSOR_TIMEOUT_S:g} s"),
        "late": ("stale-frame", "device", f"camera: stale frame: {LATE_S:g} s old"),
        "unreadable": ("camera-error", "protocol", "camera: unsupported frame shape"),
    },
    "ir": {
        "no-frame": ("ir-error", "timeout", f"ir: no reading within {SENSOR_TIMEOUT_S:g} s"),
        "late": ("stale-ir", "device", f"ir: stale reading: {LATE_S:g} s old"),
        "unreadable": ("ir-error", "protocol", "ir: sim: temperatures must be finite"),
    },
}


def fault_spec(device: str, kind: str, step: int = FAULT_STEP) -> str:
    seconds = f"={LATE_S:g}" if kind == "late" else ""
    return f"{kind}{seconds}@{FIRST_GRAB_OF_STEP[device] + step}"


def bench_settings(tmp_path: Path, policy: str = "continue", **faults: str) -> Settings:
    """The simulated bench on a virtual clock, a small camera frame, a noise-free robot."""
    return Settings.model_validate(
        {
            "bench": {
                "clock": "virtual",
                "robot_noise_um": 0.0,
                "stand_drift_um": 0.0,
                **faults,
            },
            "camera": {
                "width_px": 320,
                "height_px": 240,
                "grab_timeout_s": SENSOR_TIMEOUT_S,
                "max_age_s": MAX_AGE_S,
            },
            "ir": {"read_timeout_s": SENSOR_TIMEOUT_S, "max_age_s": MAX_AGE_S},
            "robot": {"emulator_move_ms": 1.0},
            "compensation": {"mode": "absolute"},
            "scheduler": {
                "duration_s": DURATION_S,
                "step_s": 1.0,
                "sensor_error_policy": policy,
            },
            "storage": {"data_dir": str(tmp_path), "report_at_end": False},
        }
    )


def measured(device: str, step: StepRecord) -> list[Any]:
    if device == "camera":
        return [step.centroid_x_px, step.centroid_y_px, step.drift_x_um, step.residual_um]
    return [step.ir_json]


def check_faulted_run(
    device: str, kind: str, steps: list[StepRecord], faulted_step: int, errors: list[dict[str, Any]]
) -> None:
    flag, error_kind, text = EXPECTED[device][kind]
    assert [s.step for s in steps] == list(range(len(steps)))  # no step lost
    assert [s.step for s in steps if s.flags] == [faulted_step]
    faulted = steps[faulted_step]
    assert faulted.flags == flag and text in faulted.error
    values = measured(device, faulted)
    if kind == "late":
        # a stale measurement is recorded but never used: no drift, no residual
        assert values[0] is not None
        if device == "camera":
            assert faulted.drift_x_um is None and faulted.residual_um is None
    else:
        assert values == [None] * len(values)
    for step in steps:
        if step.step != faulted_step:
            assert step.error == "" and None not in measured(device, step)
        assert step.pose_x_mm is not None  # the compensation moved on every step
    assert [(e["device"], e["kind"]) for e in errors] == [(device, error_kind)]
    assert text in errors[0]["message"]


@pytest.mark.slow
@pytest.mark.parametrize("kind", SENSOR_FAULT_KINDS)
@pytest.mark.parametrize("device", ["camera", "ir"])
async def test_a_sensor_fault_is_flagged_on_its_step_and_the_run_goes_on(
    tmp_path: Path, device: str, kind: str
) -> None:
    settings = bench_settings(tmp_path, **{f"{device}_faults": fault_spec(device, kind)})
    async with Daemon(settings) as daemon:
        emulator = getattr(daemon.devices, "emulator", None)
        sensor = getattr(daemon.devices, device)
        assert isinstance(emulator, C500CEmulator)
        assert isinstance(sensor, SimCamera | SimIrReader)
        info = await daemon.start_run(RunParameters.from_settings(settings))
        async with asyncio.timeout(60.0):
            final = await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
        errors = daemon.recent_errors()
        moved = len(emulator.state.motion_commands())

    assert final["state"] == "finished"
    assert sensor.faults_applied == [(FIRST_GRAB_OF_STEP[device] + FAULT_STEP, kind)]
    check_faulted_run(device, kind, steps, FAULT_STEP, errors)
    # a late frame costs its run time (the camera waits inside its step): the deadlines that
    # passed meanwhile (4 .. 3 + LATE_S - 1) are skipped, the step numbers are not; a late IR
    # reading is one its buffer held (drivers/sim/devices.py), read while later steps move
    lost_deadlines = LATE_S - 1 if (device, kind) == ("camera", "late") else 0
    assert len(steps) == DURATION_S - lost_deadlines
    assert moved == len(steps)  # one compensating move per step, the faulted one included


@pytest.mark.slow
@pytest.mark.parametrize("kind", SENSOR_FAULT_KINDS)
@pytest.mark.parametrize("device", ["camera", "ir"])
async def test_with_the_pause_policy_a_sensor_fault_pauses_the_run_until_resumed(
    tmp_path: Path, device: str, kind: str
) -> None:
    settings = bench_settings(tmp_path, "pause", **{f"{device}_faults": fault_spec(device, kind)})
    flag, error_kind, text = EXPECTED[device][kind]
    async with Daemon(settings) as daemon:
        emulator = getattr(daemon.devices, "emulator", None)
        assert isinstance(emulator, C500CEmulator)
        assert daemon.sensor_states == {"camera": "open", "ir": "open"}  # no grab yet
        info = await daemon.start_run(RunParameters.from_settings(settings))
        async with asyncio.timeout(60.0):
            assert await daemon.wait_state(RunState.PAUSED) is RunState.PAUSED
        # GET /health's view of the sensor: how its last grab/read went
        expected_state = "stale" if kind == "late" else f"{error_kind} error"
        assert daemon.sensor_states[device] == expected_state
        run = daemon.snapshot()["run"]
        assert run["step"] == FAULT_STEP
        assert run["reason"].startswith("sensor error: ") and text in run["reason"]
        parked = len(emulator.state.motion_commands())
        await asyncio.sleep(0.05)  # the loop would have run many virtual steps by now
        assert len(emulator.state.motion_commands()) == parked
        assert daemon.snapshot()["state"] == "paused"

        await daemon.resume()
        async with asyncio.timeout(60.0):
            final = await daemon.wait_run()
        assert daemon.sensor_states == {"camera": "ok", "ir": "ok"}  # good again after resume
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
        errors = daemon.recent_errors()
        moved = len(emulator.state.motion_commands())

    assert final["state"] == "finished"
    check_faulted_run(device, kind, steps, FAULT_STEP, errors)
    assert steps[FAULT_STEP].flags == flag
    assert len(steps) > FAULT_STEP + 1 and moved == len(steps)  # it moved again after resume


def test_a_bad_fault_spec_is_a_configuration_error_naming_the_field(tmp_path: Path) -> None:
    path = tmp_path / "bench.toml"
    path.write_text('[bench]\ncamera_faults = "no-frame@2, x@1"\n')
    with pytest.raises(ConfigError, match=rf"{path}: bench.camera_faults: bad fault 'x@1': "):
        load_settings(path, environ={})
    environ = {"THERMOCOMP_BENCH__IR_FAULTS": "late@3"}
    with pytest.raises(ConfigError, match=r"BENCH__IR_FAULTS \(environment\): bench.ir_faults: "):
        load_settings(None, environ=environ)
    for bad in ("late@3", "no-frame=2@1", "drop@1", "unreadable", "late=1@0", "late=1%2"):
        with pytest.raises(ValueError, match=f"bad fault '{bad}'"):
            parse_sensor_faults(bad)
    assert parse_sensor_faults("no-frame@4, late=2.5@7,unreadable%0.1") == (
        Fault("no-frame", None, 4),
        Fault("late", 2.5, 7),
        Fault("unreadable", None, None, 0.1),
    )
    assert load_settings(None, environ={}).bench.camera_faults == ""


@pytest.mark.slow
async def test_probabilistic_faults_are_seeded_and_leave_the_noise_alone() -> None:
    """``%P`` draws from its own seeded stream: the same seed strikes the same reads, and the
    frames of the reads it spares are those of a bench without faults."""

    async def reads(faults: str, seed: int) -> tuple[list[int], list[int], list[Any]]:
        settings = Settings.model_validate({"bench": {"seed": seed, "ir_faults": faults}})
        clock = VirtualClock()
        reader = SimIrReader(settings, Bench(settings, clock), clock)
        refused, frames = [], []
        for number in range(1, 21):
            await clock.sleep_until(float(number))
            try:
                frames.append((await reader.read()).frame_c)
            except ProtocolError:
                refused.append(number)
                frames.append(None)
        return refused, [n for n, _ in reader.faults_applied], frames

    refused, struck, frames = await reads("unreadable%0.3", seed=7)
    assert refused and refused == struck
    assert (refused, struck) == (await reads("unreadable%0.3", seed=7))[:2]
    assert refused != (await reads("unreadable%0.3", seed=8))[0]
    _, _, clean = await reads("", seed=7)
    for frame, reference in zip(frames, clean, strict=True):
        if frame is not None:
            np.testing.assert_array_equal(frame, reference)


class BlockingCapture:
    """A VideoCapture whose first read blocks (a hung driver) until ``release_read`` is set."""

    def __init__(self) -> None:
        self.release_read = threading.Event()
        self.reads = 0
        self.released = threading.Event()

    def read(self) -> tuple[bool, Any]:
        self.reads += 1
        if self.reads == 1:
            self.release_read.wait(timeout=60.0)
        return True, np.zeros((4, 4), np.uint8)

    def release(self) -> None:
        self.released.set()


async def test_no_second_read_starts_while_a_timed_out_one_is_blocked(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    capture = BlockingCapture()
    monkeypatch.setattr(drivers.camera, "open_video_capture", lambda source, device: capture)
    source = VideoSource("fake", "camera", lambda _: None)
    await source.open()
    try:
        with pytest.raises(TimeoutError):
            async with asyncio.timeout(0.05):
                await source.read()
        assert source.read_pending and capture.reads == 1
        with pytest.raises(DeviceError, match="has not returned") as refused:
            await source.read()
        assert refused.value.device == "camera" and capture.reads == 1  # no thread started
    finally:
        capture.release_read.set()
    async with asyncio.timeout(10.0):
        while source.read_pending:  # noqa: ASYNC110 -- the read's thread returns on its own
            await asyncio.sleep(0.01)
    image = await source.read()  # the device answers again: reads go on
    assert image.shape == (4, 4) and capture.reads == 2
    await source.close()
    assert capture.released.is_set()
