"""``thermocomp devices check``: open every configured device, grab one frame, one IR image and
the robot's pose, print what came back and write the preview
(daemon/run/devices_check.py).

Exit statuses (docs/reference/cli.md): 0 every device answered; 1 a device could not be opened or
failed to answer (each failure one line, the others still described); 2 bad usage or configuration.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from config import Settings, load_settings
from config.cli import EXIT_FAILURE, EXIT_OK, add_config_argument
from drivers.clock import make_clock
from drivers.errors import DeviceError

if TYPE_CHECKING:
    from daemon.run.devices_check import DeviceCheck

# the device and vision modules (OpenCV, SciPy, the drivers) are imported where they are used:
# `thermocomp devices --help` must answer at once (issue 16)

PROG = "thermocomp devices check"
#: What opening a device raises when it is absent, busy or does not answer.
OPEN_ERRORS: tuple[type[Exception], ...] = (DeviceError, OSError)
GRAB_ERRORS: tuple[type[Exception], ...] = (DeviceError, OSError, TimeoutError)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "devices",
        help="bring-up: check that the configured devices answer",
        description="Bring-up of the lab's devices.",
    )
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    check = actions.add_parser(
        "check",
        help="grab one frame, one IR image and the robot pose; write a preview",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_config_argument(check)
    check.add_argument(
        "--preview",
        type=Path,
        metavar="FILE",
        help="write a PNG of the frame with the spot marked beside the thermal image with "
        "every IR region drawn and labelled",
    )
    check.add_argument(
        "--data-dir",
        type=Path,
        help="folder of the saved networks the bench may name (default: storage.data_dir)",
    )
    check.add_argument("--json", action="store_true", help="print the result as JSON")
    check.set_defaults(handler=run_devices_check)


async def _check(settings: Settings) -> DeviceCheck:
    # lazy: the devices (the simulated bench: SciPy, OpenCV) load when the check runs, not
    # for --help (issue 16)
    from daemon.run.devices_check import check_devices
    from drivers.factory import open_devices

    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    async with open_devices(settings, clock) as devices:
        # a UR's tool cameras (arm.camera_devices; the UR bench's) open with it: checked there
        check = await check_devices(devices, settings)
    return check


async def _tool_cameras(settings: Settings, check: DeviceCheck) -> None:
    """One frame of each real tool camera (arm.camera_devices), each opened on its own, after
    a UR's devices did not open together (the robot did not answer): checked here."""
    from daemon.run.devices_check import FOLLOWED_CAMERAS_NOTE  # lazy: OpenCV, not for --help
    from drivers.factory import camera_driver  # lazy: the drivers, not for --help

    devices = settings.arm.camera_devices if settings.arm.enabled else ()
    if devices and FOLLOWED_CAMERAS_NOTE in check.notes:
        check.notes.remove(FOLLOWED_CAMERAS_NOTE)  # they are checked after all
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    for index, device in enumerate(devices):
        name = f"tool camera {index}"
        try:
            async with camera_driver(device, clock, None) as camera:
                frame = await asyncio.wait_for(camera.grab(), device.grab_timeout_s)
                check.tool_frames.append((name, frame))
        except GRAB_ERRORS as err:
            check.errors[name] = _reason("camera", err) if str(err) else "no frame in time"


async def _check_without(settings: Settings, opening: Exception) -> DeviceCheck:
    """The check after the devices did not open together with ``opening``: when the room
    thermometer was what failed, everything else is checked as usual and the room is its one
    failed line; else each device on its own (:func:`_check_each`)."""
    from daemon.run.devices_check import NO_ROOM_NOTE  # lazy: OpenCV, not for --help

    if not (isinstance(opening, DeviceError) and opening.device == "room"):
        return await _check_each(settings, opening)
    no_room = settings.room.model_copy(update={"driver": "none"})
    try:
        check = await _check(settings.model_copy(update={"room": no_room}))
    except OPEN_ERRORS as err:  # another device failed as well
        check = await _check_each(settings, err)
    if NO_ROOM_NOTE in check.notes:
        check.notes.remove(NO_ROOM_NOTE)  # there is one: it failed
    check.errors["room"] = _reason("room", opening)
    return check


async def _room_alone(settings: Settings, check: DeviceCheck) -> None:
    """The 1-Wire room thermometer opened and read on its own (the bench's simulated one
    needs the bench: it is checked with the others or not at all)."""
    from daemon.run.devices_check import probe_room  # lazy: OpenCV, not for --help
    from drivers.room import W1Thermometer  # lazy: the drivers, not for --help

    if settings.room.driver != "w1":
        return
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    try:
        async with W1Thermometer(settings.room, clock) as room:
            await probe_room(room, settings, check)
    except OPEN_ERRORS as err:
        check.errors["room"] = _reason("room", err)


async def _check_each_ur(settings: Settings, opening: Exception) -> DeviceCheck:
    """A UR's check after its devices did not open: the robot alone (or, on the bench, the
    emulator's error), then the tool cameras, each failure its own line."""
    from daemon.run.devices_check import (  # lazy: OpenCV and NumPy, not for --help
        FOLLOWED_CAMERAS_NOTE,
        DeviceCheck,
        probe_described,
    )
    from drivers.ur.robot import URRobot  # lazy: the drivers, not for --help

    check = DeviceCheck(notes=[FOLLOWED_CAMERAS_NOTE])
    if settings.bench.enabled:  # the UR emulator itself did not open (its ports taken?)
        check.errors["robot"] = f"the UR emulator: {_reason('robot', opening)}"
    else:
        try:
            async with URRobot(settings.robot) as robot:
                await probe_described(robot, check)
        except OPEN_ERRORS as err:
            check.errors["robot"] = _reason("robot", err)
    await _tool_cameras(settings, check)
    await _room_alone(settings, check)
    return check


async def _check_each(settings: Settings, opening: Exception) -> DeviceCheck:
    """Each device opened on its own, after opening them together failed with ``opening``
    (issue 28: during bring-up the cameras are checked while the robot does not answer yet):
    every device is described or named with its own error, one line each."""
    from daemon.run.devices_check import (  # lazy: OpenCV and NumPy, not for --help
        DeviceCheck,
        probe_camera,
        probe_ir,
        probe_robot,
    )
    from drivers.factory import (  # lazy: the drivers and the bench, not for --help
        bench_for,
        camera_driver,
        ir_driver,
        robot_driver,
    )

    if settings.robot.driver == "ur-rtde":
        return await _check_each_ur(settings, opening)
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    check = DeviceCheck(regions=settings.ir.regions)
    bench = bench_for(settings, clock)
    # the robot, the spot camera and the IR reader, each in a stack of its own
    try:
        async with contextlib.AsyncExitStack() as stack:
            robot, _ = await robot_driver(settings, bench, stack)
            await stack.enter_async_context(robot)
            await probe_robot(robot, check)
    except OPEN_ERRORS as err:
        check.errors["robot"] = _reason("robot", err)
    try:
        async with camera_driver(settings.camera, clock, bench) as camera:
            await probe_camera(camera, settings, check)
    except OPEN_ERRORS as err:
        check.errors["camera"] = _reason("camera", err)
    try:
        async with ir_driver(settings, clock, bench) as ir:
            regions = getattr(ir, "regions", None)
            if isinstance(regions, tuple) and regions:
                check.regions = regions
            await probe_ir(ir, settings, check)
    except OPEN_ERRORS as err:
        check.errors["ir"] = _reason("ir", err)
    await _tool_cameras(settings, check)
    await _room_alone(settings, check)
    if not check.errors:  # each opened alone: say what failed when they were opened together
        check.errors["devices"] = f"cannot open them together: {opening}"
    return check


def _reason(device: str, err: Exception) -> str:
    """``err`` without the device's name it starts with (the line names the device)."""
    text = str(err)
    return text[len(device) + 2 :] if text.startswith(f"{device}: ") else text


def run_devices_check(args: argparse.Namespace) -> int:
    # lazy: OpenCV (the preview PNG) loads when the check runs, not for --help (issue 16)
    from daemon.run.devices_check import describe, preview_png

    settings = load_settings(args.config)
    if args.data_dir is not None:
        storage = settings.storage.model_copy(update={"data_dir": args.data_dir})
        settings = settings.model_copy(update={"storage": storage})
    try:
        check = asyncio.run(_check(settings))
    except OPEN_ERRORS as err:  # one device did not open: check every device on its own
        check = asyncio.run(_check_without(settings, err))
    if args.json:
        print(json.dumps(check.as_dict(), indent=2))
    else:
        for line in describe(check):
            print(line)
    if args.preview is not None:
        try:
            args.preview.write_bytes(preview_png(check))
        except (DeviceError, OSError, ValueError) as err:
            print(f"{PROG}: no preview written: {err}", file=sys.stderr)
            return EXIT_FAILURE
        print(f"preview written to {args.preview}", file=sys.stderr)
    for device, error in check.errors.items():
        print(f"{PROG}: {device}: {error}", file=sys.stderr)
    return EXIT_OK if check.ok else EXIT_FAILURE
