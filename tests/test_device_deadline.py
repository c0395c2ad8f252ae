"""Device deadlines on a busy machine (drivers/deadline.py): a grab's wall-clock bound counts
the device's latency, not the simulated bench's computing (a 5 MP render under load used to
fail arm runs with "camera: no frame within 10 s"); a hung device still times out."""

from __future__ import annotations

import asyncio
import time

import pytest

from config import Settings
from daemon.run.events import ErrorLog, EventBus
from daemon.run.sensors import Sensors
from drivers.clock import VirtualClock
from drivers.deadline import bounded, device_deadline, off_the_clock
from drivers.errors import DeviceTimeoutError
from drivers.sim.bench import Bench
from drivers.sim.devices import SimCamera, SimIrReader

#: A deadline far shorter than the computing done under it (s).
SHORT_S = 0.05
#: Blocking work in a thread, several times SHORT_S (s).
WORK_S = 0.3


def _busy(seconds: float) -> str:
    time.sleep(seconds)  # a worker thread's computing (the render's stand-in)
    return "done"


async def test_computing_off_the_clock_does_not_count() -> None:
    async def grab() -> str:
        first = await off_the_clock(_busy, WORK_S)
        second = await off_the_clock(_busy, WORK_S)
        return first + second

    assert await bounded(grab(), "camera", "frame", SHORT_S) == "donedone"


async def test_waiting_still_counts() -> None:
    async def late() -> None:
        await off_the_clock(_busy, WORK_S)  # not counted ...
        await asyncio.sleep(10 * SHORT_S)  # ... but this is: the device is late

    with pytest.raises(DeviceTimeoutError, match=f"camera: no frame within {SHORT_S:g} s"):
        await bounded(late(), "camera", "frame", SHORT_S)


async def test_a_hung_device_times_out_in_wall_time() -> None:
    hung = asyncio.get_running_loop().create_future()
    started = time.monotonic()
    with pytest.raises(DeviceTimeoutError, match="ir: no reading within"):
        await bounded(hung, "ir", "reading", SHORT_S)
    assert time.monotonic() - started >= SHORT_S


async def test_overlapping_computations_count_once_and_tasks_inherit_the_deadline() -> None:
    async def two_cameras() -> list[str]:
        return list(await asyncio.gather(off_the_clock(_busy, WORK_S), _later_work()))

    async def _later_work() -> str:
        await asyncio.sleep(0)
        return await off_the_clock(_busy, 2 * WORK_S)

    assert await bounded(two_cameras(), "camera", "frame", SHORT_S) == ["done", "done"]


async def test_the_device_own_timeout_passes_as_it_is() -> None:
    async def own() -> None:
        raise DeviceTimeoutError("camera", "pylon: grab timed out")

    with pytest.raises(DeviceTimeoutError, match="pylon: grab timed out"):
        await bounded(own(), "camera", "frame", 1.0)


async def test_outside_a_deadline_off_the_clock_is_a_thread() -> None:
    assert await off_the_clock(_busy, 0.0) == "done"
    async with device_deadline(1.0) as scope:
        await asyncio.sleep(0)
    assert not scope.expired()


@pytest.mark.slow
async def test_the_bench_camera_renders_past_a_deadline_shorter_than_its_render() -> None:
    """A full 5 MP frame takes far longer than SHORT_S to draw (more on a loaded machine):
    the step's sensors bound the camera's latency, which on the bench is none."""
    settings = Settings.model_validate(
        {
            "bench": {"clock": "virtual"},
            "camera": {"width_px": 2448, "height_px": 2048, "grab_timeout_s": SHORT_S},
            "ir": {"read_timeout_s": SHORT_S},
        }
    )
    clock = VirtualClock()
    bench = Bench(settings, clock)
    camera = SimCamera(settings.camera, bench, clock)
    ir = SimIrReader(settings, bench, clock)
    sensors = Sensors(settings, camera, ir, ErrorLog(EventBus()))
    async with camera, ir:
        frame = await sensors.grab()
        await sensors.read_ir()
    assert frame.image.shape == (2048, 2448)
    assert sensors.states == {"camera": "ok", "ir": "ok"}
