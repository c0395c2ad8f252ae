"""A small arm bench for the end-to-end arm run (tests/test_arm_e2e.py): the C500C emulator in
joint space (drivers/sim/joint_arm.py) over a real pty behind the real console driver, a
thermal truth of the arm, and cameras that render the tool's markers where the truth puts them.

The truth is the arm's thermal model with other parameters than the controller's (a finer
network, 20 % more motor heat, other convection), heated by the duty cycle played in process
on the run clock scaled by ``time_scale`` (what the controller's model assumes the arm does);
the tool's true pose is the warm arm's forward kinematics at the joints the emulator really
has. Each camera renders the markers at that pose with photon, read and quantisation noise
(daemon/vision/markers.py, seeded), so the measurement path is the daemon's own.
"""

from __future__ import annotations

import asyncio
import dataclasses
import re
from collections.abc import AsyncIterator
from contextlib import AsyncExitStack, asynccontextmanager
from pathlib import Path
from typing import Any, Self

import numpy as np

from config import Settings
from daemon.arm.controller import ArmController, ArmModelOptions
from daemon.arm.description import load_arm
from daemon.arm.duty import load_duty_cycle
from daemon.arm.heat import JointHeatProfile
from daemon.arm.kinematics import forward, warm_arm
from daemon.arm.thermal import ArmThermalModel
from daemon.vision.cameras import CameraModel, intrinsic_matrix, look_at
from daemon.vision.markers import render_markers
from drivers.base import Frame, IrReading, RegionTemperature
from drivers.c500c import C500CRobot
from drivers.clock import Clock
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.joint_arm import JointArmConfig

ARM = "crs-a465"
PRESET_DUTY = "a465-pick-and-place"
#: The preset's camera station points the tool straight down (joints 2 + 3 + 5 = 90 deg):
#: z-y-x angles (0, 90, 0), the console's gimbal lock, where the joint-space emulator's `w2`
#: fails; the bench's copy measures there with the wrist turned a little.
CAMERA_JOINTS_DEG = (0.0, 20.0, 70.0, 10.0, 20.0, 10.0)
HEAT_FACTOR = 1.2  # the truth's motors heat 20 % more than the controller's preset says
IMAGE_SIZE = (640, 480)
FOCAL_PX = 2400.0
CAMERA_DISTANCE_MM = 700.0
#: Camera directions about each measured pose (unit-ish vectors from the tool to the camera).
CAMERA_DIRECTIONS = ((1.0, -1.0, 0.8), (1.0, 1.0, 0.8), (-0.3, -1.0, 1.2))
SPOT_SIGMA_PX = 2.0
BIT_DEPTH = 12


class ArmTruth:
    """The physical arm: thermal truth, kinematics, and the joints the emulator has."""

    def __init__(self, settings: Settings, clock: Clock, emulator: C500CEmulator) -> None:
        self.clock = clock
        self.emulator = emulator
        self.time_scale = settings.compensation.time_scale
        arm = load_arm(ARM)
        duty = load_duty_cycle(settings.arm.duty_cycle or PRESET_DUTY)
        nominal = JointHeatProfile.from_duty(arm, duty, resolution_s=0.05)
        heat = dataclasses.replace(nominal, energy_j=HEAT_FACTOR * nominal.energy_j)
        thermal = ArmThermalModel(arm, node_spacing_mm=25.0, dt_s=10.0, convection_scale=0.9)
        self.model = ArmController(
            arm, duty, ArmModelOptions(model_dt_s=10.0), heat=heat, thermal=thermal
        )
        self.arm = arm
        self.start_s: float | None = None
        self.markers_tool = np.array(settings.arm.markers_mm, dtype=np.float64)
        self.duty_cycles: list[str | None] = []

    def start_arm_run(self, t_s: float, *, duty_cycle: str | None) -> None:
        """The session starts the bench with the run: the arm is cold now."""
        self.start_s = t_s
        self.duty_cycles.append(duty_cycle)

    def tool_pose(self) -> np.ndarray:
        """The tool's true pose now: the warm arm at the emulator's joints."""
        if self.start_s is not None:
            self.model.advance_to((self.clock.now() - self.start_s) * self.time_scale)
        q = self.emulator.joint_sample(asyncio.get_running_loop().time()).q_rad
        warm = warm_arm(self.arm, self.model.thermal.link_states())
        pose: np.ndarray = forward(warm, q)
        return pose

    def markers_world(self) -> np.ndarray:
        pose = self.tool_pose()
        world: np.ndarray = self.markers_tool @ pose[:3, :3].T + pose[:3, 3]
        return world


def cameras_around(targets_mm: list[np.ndarray]) -> tuple[CameraModel, ...]:
    """Three cameras looking at each target from CAMERA_DISTANCE_MM."""
    width, height = IMAGE_SIZE
    matrix = intrinsic_matrix((FOCAL_PX, FOCAL_PX), ((width - 1) / 2, (height - 1) / 2))
    cameras = []
    for t, target in enumerate(targets_mm):
        for c, direction in enumerate(CAMERA_DIRECTIONS):
            unit = np.asarray(direction) / np.linalg.norm(direction)
            rvec, tvec = look_at(target + CAMERA_DISTANCE_MM * unit, target)
            cameras.append(
                CameraModel(
                    f"cam{t}{c}", matrix, np.zeros(5), rvec.ravel(), tvec.ravel(), IMAGE_SIZE
                )
            )
    return tuple(cameras)


class SimMarkerCamera:
    """One camera of the bench: a full frame of the markers where the truth has them."""

    def __init__(self, model: CameraModel, truth: ArmTruth, clock: Clock, seed: int) -> None:
        self.model = model
        self.truth = truth
        self.clock = clock
        self.rng = np.random.default_rng(seed)
        self.sequence = 0

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def grab(self) -> Frame:
        image = render_markers(
            self.model,
            self.truth.markers_world(),
            rng=self.rng,
            sigma_px=SPOT_SIGMA_PX,
            bit_depth=BIT_DEPTH,
            read_noise_counts=2.0,
        )
        self.sequence += 1
        return Frame(image, BIT_DEPTH, self.clock.now(), self.sequence, "camera")  # type: ignore[arg-type]


class QuietIr:
    def __init__(self, clock: Clock) -> None:
        self.clock = clock

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def read(self) -> IrReading:
        region = RegionTemperature("upper-arm", 22.0, 22.5, None)
        return IrReading({"upper-arm": region}, self.clock.now(), 0)


@dataclasses.dataclass
class ArmDevices:
    camera: Any
    ir: QuietIr
    robot: C500CRobot
    bench: ArmTruth
    emulator: C500CEmulator
    cameras: tuple[SimMarkerCamera, ...]
    camera_models: tuple[CameraModel, ...]


@asynccontextmanager
async def open_arm_devices(
    settings: Settings, clock: Clock, seed: int
) -> AsyncIterator[ArmDevices]:
    """The arm bench's devices (the factory's job once drivers/sim/arm_bench.py lands)."""
    arm = load_arm(ARM)
    async with AsyncExitStack() as stack:
        emulator = C500CEmulator(
            EmulatorConfig(
                seed=seed,
                noise_um=0.5,
                move_ms=0.0,
                paced=False,
                joint_arm=JointArmConfig(
                    arm=arm, speed_deg_s=20_000.0, acceleration_deg_s2=2_000_000.0
                ),
            )
        )
        await stack.enter_async_context(emulator)
        robot = C500CRobot(settings.robot, port=emulator.device_path)
        await stack.enter_async_context(robot)
        truth = ArmTruth(settings, clock, emulator)
        duty = load_duty_cycle(settings.arm.duty_cycle or PRESET_DUTY)
        targets = [forward(arm, pose.q_rad)[:3, 3] for pose in duty.measured_poses()]
        models = cameras_around(targets)
        cameras = tuple(
            SimMarkerCamera(model, truth, clock, seed * 100 + k) for k, model in enumerate(models)
        )
        yield ArmDevices(
            camera=cameras[0],
            ir=QuietIr(clock),
            robot=robot,
            bench=truth,
            emulator=emulator,
            cameras=cameras,
            camera_models=models,
        )


def write_duty_cycle(folder: Path) -> Path:
    """The preset duty cycle with its camera station at CAMERA_JOINTS_DEG (see there)."""
    from daemon.arm.duty import duty_dir

    text = (duty_dir() / f"{PRESET_DUTY}.toml").read_text(encoding="utf-8")
    station = re.compile(r'(name = "camera".*?\njoints_deg = )\[[^\]]*\]', re.S)
    text, count = station.subn(rf"\g<1>{list(CAMERA_JOINTS_DEG)}", text, count=1)
    assert count == 1, "the preset has no camera station"
    path = folder / "bench-pick-and-place.toml"
    path.write_text(text, "utf-8")
    return path
