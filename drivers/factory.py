"""Settings -> the three devices, real or simulated, opened together and closed together.

``async with open_devices(settings, clock) as devices`` gives ``devices.camera``, ``.ir``,
``.robot`` and, when any device is simulated, ``.bench`` (the physical truth, for tests and
benchmarks) and ``.emulator``. The simulated robot is the real C500C driver talking to the
in-process emulator over a real pseudo-terminal, so the daemon exercises the same code on the
bench as in the lab. ``robot.driver = "c500c-server"`` (the fast path) is likewise the real
server driver talking to the emulated server program on a pty when the bench is enabled.
With ``bench.emulator = "process"`` either emulator runs as a child process instead
(drivers/sim/emulator_process.py; issue 30) and the bench reads its pose from shared memory.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Self

from config import ConfigError, Settings
from config.settings import CameraSettings
from daemon.vision.cameras import CameraFileError, load_cameras
from daemon.vision.multiview import CameraModel
from drivers.base import Camera, Frame, IrReader, IrReading, Robot, RoomThermometer
from drivers.c500c.robot import C500CRobot
from drivers.c500c.server import C500CServerRobot
from drivers.camera import OpenCvCamera, ReplayCamera
from drivers.clock import Clock
from drivers.errors import DeviceError
from drivers.genicam.camera import GenICamCamera
from drivers.genicam.radiometric import GenICamRadiometricIrReader
from drivers.ir import OpenCvIrReader, ReplayIrReader
from drivers.room import W1Thermometer
from drivers.sim.arm_devices import ArmBenchControl, open_arm_bench
from drivers.sim.arm_markers import CameraRig
from drivers.sim.bench import Bench
from drivers.sim.devices import SimCamera, SimIrReader
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.emulator_process import EmulatorProcess
from drivers.sim.server_emulator import C500CServerEmulator, server_emulator_config
from drivers.sim.ur.cameras import ur_bench_cameras
from drivers.sim.ur.controller import URControllerConfig
from drivers.sim.ur.emulator import UREmulator
from drivers.sim.ur.room import SimURRoom
from drivers.sim.ur.truth import URBenchTruth
from drivers.ur.robot import URRobot

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Devices:
    camera: Camera
    ir: IrReader
    robot: Robot
    bench: Bench | None = None  # the simulated bench's truth; None on hardware
    emulator: C500CEmulator | None = None  # the emulated controller behind the sim robot
    #: the emulated controller in its own process instead (bench.emulator = "process")
    emulator_process: EmulatorProcess | None = None
    # the arm bench (issue 20, arm.enabled): the cameras watching the tool, their models,
    # and the truth an arm run starts (drivers/sim/arm_devices.py)
    cameras: tuple[Camera, ...] = ()
    camera_models: tuple[CameraModel, ...] = ()
    arm_bench: ArmBenchControl | None = None
    #: the thermometer in the room's air (issue 29, room.driver); None: none
    room: RoomThermometer | None = None
    #: the UR bench (issue 31): the emulated controller and its truth, for a followed run
    ur_emulator: UREmulator | None = None
    ur_truth: URBenchTruth | None = None


class AbsentDevice:
    """A camera or IR reader a robot that reports its own joint temperatures does without
    (robot.driver ur-rtde: a followed run uses neither); every read is a DeviceError."""

    #: GET /health says "none" for it, not "open" (daemon/run/sensors.py)
    absent = True

    def __init__(self, what: str) -> None:
        self.what = what

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def grab(self) -> Frame:
        raise DeviceError(self.what, f"no {self.what}: robot.driver ur-rtde runs without one")

    async def read(self) -> IrReading:
        raise DeviceError(self.what, f"no {self.what}: robot.driver ur-rtde runs without one")


@contextlib.asynccontextmanager
async def _open_ur(settings: Settings, clock: Clock) -> AsyncIterator[Devices]:
    """A UR (drivers/ur/robot.py) and, with bench.enabled, the UR emulator it talks to over
    loopback TCP (drivers/sim/ur/: the arm plays arm.duty_cycle, its truth seeded by
    bench.seed). No spot camera nor IR reader: the joint temperatures are the thermal input.
    The tool cameras a followed run measures with at the program's measured poses: on
    hardware ``arm.camera_devices`` with their models (arm.cameras_file), opened as the
    A465's; on the bench, with ``arm.bench_cameras`` (config/ur5e-sim.toml), ``arm.cameras``
    simulated cameras at each measured pose watching ``arm.markers_mm`` on the emulator's true
    tool (drivers/sim/ur/cameras.py). Neither: a run with no camera (model + joint
    temperatures). The room thermometer of room.driver (a UR has none of its own): on the
    bench ``sim`` reads the emulator truth's room (drivers/sim/ur/room.py)."""
    robot_settings = settings.robot
    async with contextlib.AsyncExitStack() as stack:
        emulator: UREmulator | None = None
        simulated_room: RoomThermometer | None = None
        cameras: tuple[Camera, ...] = ()
        camera_models: tuple[CameraModel, ...] = ()
        if settings.bench.enabled:
            duty = settings.arm.duty_cycle or URControllerConfig.duty
            emulator = UREmulator(
                URControllerConfig(
                    arm=Path(settings.arm.arm_file).stem,
                    duty=duty,
                    register_base=robot_settings.register_base,
                    seed=settings.bench.seed,
                    camera_rig=CameraRig(count=settings.arm.cameras),
                    markers_tool_mm=settings.arm.markers_mm,
                ),
                host=robot_settings.host,
                rtde_port=robot_settings.rtde_port,
                dashboard_port=robot_settings.dashboard_port,
            )
            await stack.enter_async_context(emulator)
            robot_settings = robot_settings.model_copy(
                update={"rtde_port": emulator.rtde_port, "dashboard_port": emulator.dashboard_port}
            )
            simulated_room = SimURRoom(emulator.controller, clock)
            if _ur_bench_cameras(settings):
                simulated, camera_models = ur_bench_cameras(emulator.controller, clock)
                cameras = tuple([await stack.enter_async_context(c) for c in simulated])
        else:
            cameras, camera_models = await _open_arm_cameras(settings, clock, stack)
        room = await _open_room(settings, clock, stack, simulated_room)
        robot = await stack.enter_async_context(URRobot(robot_settings))
        logger.info(
            "devices open: UR %s%s, %d tool cameras, room thermometer %s",
            robot_settings.host,
            " (emulated)" if emulator else "",
            len(cameras),
            settings.room.driver,
        )
        yield Devices(
            camera=AbsentDevice("camera"),
            ir=AbsentDevice("ir"),
            robot=robot,  # type: ignore[arg-type]  # an OffsetRobot: run kind followed
            cameras=cameras,
            camera_models=camera_models,
            room=room,
            ur_emulator=emulator,
            ur_truth=None if emulator is None else URBenchTruth(emulator.controller),
        )


def _ur_bench_cameras(settings: Settings) -> bool:
    """The UR bench renders tool cameras when the settings ask for them (arm.bench_cameras:
    config/ur5e-sim.toml); without, it is the bench of a run with no camera."""
    return settings.arm.enabled and settings.arm.bench_cameras


def _arm_bench(settings: Settings) -> bool:
    """The arm bench replaces the two-link bench when the arm is enabled on the bench."""
    return settings.arm.enabled and settings.bench.enabled and settings.robot.driver == "sim"


def _simulated(settings: Settings) -> list[str]:
    return [
        name
        for name, driver in (
            ("camera", settings.camera.driver),
            ("ir", settings.ir.driver),
            ("robot", settings.robot.driver),
        )
        if driver == "sim"
    ]


def _emulated_server(settings: Settings) -> bool:
    """The fast path on the bench: its program is emulated (on hardware: the real port)."""
    return settings.robot.driver == "c500c-server" and settings.bench.enabled


def emulated_server(settings: Settings, *, seed: int) -> C500CServerEmulator:
    """The fast path's program, emulated as the settings configure it (not yet started)."""
    robot_settings = settings.robot
    return C500CServerEmulator(
        server_emulator_config(
            seed=seed,
            noise_um=settings.bench.robot_noise_um,
            move_ms=robot_settings.emulator_move_ms,
            baudrate=robot_settings.server_baudrate,
            paced=robot_settings.emulator_paced,
            silence_timeout_s=robot_settings.server_silence_s,
        )
    )


@contextlib.asynccontextmanager
async def open_devices(settings: Settings, clock: Clock) -> AsyncIterator[Devices]:
    """Open camera, IR reader and robot as the settings say; close them all on exit."""
    if settings.robot.driver == "ur-rtde":
        async with _open_ur(settings, clock) as devices:
            yield devices
        return
    simulated = _simulated(settings)
    if simulated and not settings.bench.enabled:
        raise ConfigError(
            f"bench.enabled is false but {', '.join(f'{n}.driver' for n in simulated)} "
            "is 'sim': choose real drivers or enable the bench"
        )
    if _arm_bench(settings):
        async with contextlib.AsyncExitStack() as arm_stack:
            arm = await arm_stack.enter_async_context(
                open_arm_bench(settings, clock, settings.bench.seed)
            )
            room = await _open_room(settings, clock, arm_stack, arm.room)
            logger.info("devices open: the arm bench, %d cameras", len(arm.cameras))
            yield Devices(
                camera=arm.camera,
                ir=arm.ir,
                robot=arm.robot,
                emulator=arm.emulator,
                cameras=arm.cameras,
                camera_models=arm.camera_models,
                arm_bench=arm.bench,
                room=room,
            )
        return
    async with contextlib.AsyncExitStack() as stack:
        bench = bench_for(settings, clock)
        robot, controller = await robot_driver(settings, bench, stack)
        emulator = controller if isinstance(controller, C500CEmulator) else None
        process = controller if isinstance(controller, EmulatorProcess) else None
        camera = camera_driver(settings.camera, clock, bench)
        ir = ir_driver(settings, clock, bench)

        await stack.enter_async_context(robot)
        await stack.enter_async_context(camera)
        await stack.enter_async_context(ir)
        cameras, camera_models = await _open_arm_cameras(settings, clock, stack)
        room = await _open_room(settings, clock, stack, None)
        logger.info(
            "devices open: camera=%s ir=%s robot=%s arm cameras=%d",
            settings.camera.driver,
            settings.ir.driver,
            settings.robot.driver,
            len(cameras),
        )
        yield Devices(
            camera=camera,
            ir=ir,
            robot=robot,
            bench=bench,
            emulator=emulator,
            emulator_process=process,
            cameras=cameras,
            camera_models=camera_models,
            room=room,
        )


def bench_for(settings: Settings, clock: Clock) -> Bench | None:
    """The simulated bench's truth when a device is simulated (or the fast path emulated)."""
    return Bench(settings, clock) if _simulated(settings) or _emulated_server(settings) else None


def emulator_arguments(settings: Settings, *, seed: int) -> list[str]:
    """``thermocomp emulate c500c``'s arguments for the emulator the settings configure (the
    inline one's: :func:`emulated_server` and the console's EmulatorConfig below)."""
    robot = settings.robot
    common = [
        "--seed",
        str(seed),
        "--noise-um",
        repr(settings.bench.robot_noise_um),
        "--move-ms",
        repr(robot.emulator_move_ms),
        *([] if robot.emulator_paced else ["--no-pacing"]),
    ]
    if robot.driver == "sim":
        return [*common, "--baud", str(robot.baudrate), "--application", robot.application]
    return [
        "--server",
        *common,
        "--baud",
        str(robot.server_baudrate),
        "--silence-s",
        repr(robot.server_silence_s),
    ]


async def robot_driver(
    settings: Settings, bench: Bench | None, stack: contextlib.AsyncExitStack
) -> tuple[Robot, C500CEmulator | EmulatorProcess | None]:
    """The robot driver (not yet opened) and, on the bench, its emulated controller (started
    in ``stack``, its pose attached to the bench): in this process, or in its own with
    ``bench.emulator = "process"`` (drivers/sim/emulator_process.py); ``sim`` and the emulated
    fast path need the bench. ``thermocomp devices check`` opens each device with these on
    its own."""
    emulator: C500CEmulator | None = None
    robot_settings = settings.robot
    if settings.bench.emulator == "process" and (
        _emulated_server(settings) or robot_settings.driver == "sim"
    ):
        assert bench is not None
        process = EmulatorProcess(
            emulator_arguments(settings, seed=bench.robot_seed),
            realtime_priority=settings.scheduler.realtime_priority,
        )
        await stack.enter_async_context(process)
        bench.attach_robot(process.actual_pose)
        if robot_settings.driver == "sim":
            return C500CRobot(robot_settings, port=process.device_path), process
        return C500CServerRobot(robot_settings, port=process.device_path), process
    if _emulated_server(settings):
        assert bench is not None
        emulator = emulated_server(settings, seed=bench.robot_seed)
        await stack.enter_async_context(emulator)
        bench.attach_robot(emulator.actual_pose)
        return C500CServerRobot(robot_settings, port=emulator.device_path), emulator
    if robot_settings.driver == "c500c-server":
        return C500CServerRobot(robot_settings), None
    if robot_settings.driver == "sim":
        assert bench is not None
        emulator = C500CEmulator(
            EmulatorConfig(
                application=robot_settings.application,
                seed=bench.robot_seed,
                noise_um=settings.bench.robot_noise_um,
                move_ms=robot_settings.emulator_move_ms,
                baudrate=robot_settings.baudrate,
                paced=robot_settings.emulator_paced,
            )
        )
        await stack.enter_async_context(emulator)
        bench.attach_robot(emulator.actual_pose)
        return C500CRobot(robot_settings, port=emulator.device_path), emulator
    return C500CRobot(robot_settings), None


def ir_driver(settings: Settings, clock: Clock, bench: Bench | None) -> IrReader:
    """The IR reader of the settings (not yet opened); ``sim`` needs the bench."""
    if settings.ir.driver == "sim":
        assert bench is not None
        return SimIrReader(settings, bench, clock)
    if settings.ir.driver == "opencv":
        return OpenCvIrReader(settings.ir, clock)
    if settings.ir.driver == "genicam-radiometric":
        return GenICamRadiometricIrReader(settings.ir, clock)
    return ReplayIrReader(settings.ir, clock)


async def _open_room(
    settings: Settings,
    clock: Clock,
    stack: contextlib.AsyncExitStack,
    simulated: RoomThermometer | None,
) -> RoomThermometer | None:
    """The room thermometer of room.driver, opened in ``stack``: the arm bench's or the UR
    bench's simulated one (``simulated``), a 1-Wire sensor, or none."""
    driver = settings.room.driver
    if driver == "none":
        return None
    if driver == "sim":
        assert simulated is not None  # Settings' validator: sim only on the arm bench
        return simulated
    return await stack.enter_async_context(W1Thermometer(settings.room, clock))


def camera_driver(camera: CameraSettings, clock: Clock, bench: Bench | None) -> Camera:
    """The camera driver of one camera section (not yet opened); ``sim`` needs the bench."""
    if camera.driver == "sim":
        assert bench is not None
        return SimCamera(camera, bench, clock)
    if camera.driver == "opencv":
        return OpenCvCamera(camera, clock)
    if camera.driver == "genicam":
        return GenICamCamera(camera, clock)
    return ReplayCamera(camera, clock)


async def _open_arm_cameras(
    settings: Settings, clock: Clock, stack: contextlib.AsyncExitStack
) -> tuple[tuple[Camera, ...], tuple[CameraModel, ...]]:
    """On hardware, the real cameras watching the arm's tool (arm.camera_devices), opened in
    ``stack``, with their calibrated models from arm.cameras_file, matched by position."""
    devices = settings.arm.camera_devices
    if not settings.arm.enabled or not devices:
        return (), ()
    assert settings.arm.cameras_file is not None  # ArmSettings' validator
    try:
        models = load_cameras(settings.arm.cameras_file)
    except CameraFileError as err:
        raise ConfigError(f"arm.cameras_file: {err}") from err
    if len(models) != len(devices):
        raise ConfigError(
            f"arm.camera_devices lists {len(devices)} cameras but arm.cameras_file "
            f"{settings.arm.cameras_file} has {len(models)}: one device per camera, same order"
        )
    cameras: list[Camera] = []
    for device in devices:
        camera = camera_driver(device, clock, None)
        await stack.enter_async_context(camera)
        cameras.append(camera)
    return tuple(cameras), models
