"""The arm bench's devices (issue 20), opened by drivers/factory.py when ``arm.enabled`` and
the robot is simulated: the C500C emulator in joint space (drivers/sim/joint_arm.py) on a real
pty behind the real console driver, the arm bench's truth (drivers/sim/arm_bench.py), one
simulated camera per bench camera rendering the tool's markers where the truth puts them, and
an IR reader of the bench's regions on several links.

Time: the truth's arm warms up on the run clock times ``compensation.time_scale`` from the
moment an arm run starts it (``start_arm_run``: the arm is cold then), heated by the duty cycle
played in process (drivers/sim/arm_motion.py DutyCycleMotion): on a virtual or accelerated
clock the hours of a duty cycle pass in seconds, which the emulated robot's moves over the pty
cannot, so the emulator performs the run's own moves (to each measured pose and its
correction) and the truth reads the arm's joints from it at every frame. Every camera and the
IR reader advance the truth to the run clock before they measure.

With ``arm.play_duty_cycle`` (config/arm-sim-played.toml, time_scale 1) the robot plays the
whole cycle (daemon/run/arm/player.py): the emulator then runs on the run's clock at the arm's real
joint speeds (the duty cycle's limits at `speed 100`, scaled by each move's `speed N`), and the
truth's motors are heated by the motion the emulator performs (ShiftedMotion over
``emulator.joint_sample``, from the run's start), not by DutyCycleMotion.
"""

from __future__ import annotations

import contextlib
import dataclasses
import threading
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Self

import numpy as np

from config import Settings
from config.arm_truth import ArmTruth, load_arm_truth
from daemon.arm.description import Arm
from daemon.arm.duty import DutyCycle, load_duty_cycle
from daemon.arm.ir_regions import region_name
from daemon.arm.loading import load_arm
from daemon.vision.markers import marker_pixels
from daemon.vision.multiview import CameraModel
from drivers.base import Frame, IrReading, RegionTemperature, RoomReading
from drivers.c500c.robot import C500CRobot
from drivers.clock import Clock
from drivers.deadline import off_the_clock
from drivers.sim.arm_bench import ArmBench, ArmBenchConfig, config_from_truth
from drivers.sim.arm_markers import CameraRig
from drivers.sim.arm_motion import DutyCycleMotion, JointMotionSource, ShiftedMotion
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.joint_arm import DEFAULT_ACCELERATION_DEG_S2, DEFAULT_SPEED_DEG_S, JointArmConfig

#: The emulated arm's joint speed is its real one times this on a virtual clock (a virtual run
#: jumps from deadline to deadline, a move over the pty takes loop time: keep it short).
VIRTUAL_SPEED_FACTOR = 1000.0
#: Where along a link its end regions are (fraction from its proximal joint): 5 %, ~15 mm
#: from the A465 upper arm's flange, the IR region's half width.
IR_END_FRACTION = 0.05
#: IR regions of the arm bench: (link index, fraction along it, face or None for the section's
#: mean). The middle of the upper arm and of the forearm (thesis 3.2.2's regions along the
#: bar: their mean temperature, what grows the link), and both faces of each of them next to
#: its proximal joint (the shoulder, the elbow). What bends a link is the temperature
#: difference across it, and it sits where the joint's housing heats one face first: about
#: 1 degC across the upper arm by the shoulder after 8 h of a task, 0.03 degC at its middle
#: (below the IR's noise). A region on the section's mean cannot see it, and a wrong bending
#: share in the controller's model then stays wrong (issue 29, corner-low truth: the preset
#: with the room and the mean IR removes 65-70 % of the drift, 73-79 % even with every other
#: factor true; docs/explanation/bench-truth.md).
IR_REGIONS: tuple[tuple[int, float, str | None], ...] = (
    (1, 0.5, None),
    (2, 0.5, None),
    (1, IR_END_FRACTION, "plus"),
    (1, IR_END_FRACTION, "minus"),
    (2, IR_END_FRACTION, "plus"),
    (2, IR_END_FRACTION, "minus"),
)


@dataclass(frozen=True, slots=True)
class ArmBenchDevices:
    """What drivers/factory.py yields for the arm bench (its Devices, with the arm's extras)."""

    camera: SimArmCamera
    ir: SimArmIr
    robot: C500CRobot
    bench: ArmBenchControl
    emulator: C500CEmulator
    cameras: tuple[SimArmCamera, ...]
    camera_models: tuple[CameraModel, ...]
    room: SimArmRoom  # its thermometer in the truth's room (used with room.driver sim)


def played(settings: Settings) -> bool:
    """Whether arm runs play the duty cycle through the emulator (arm.play_duty_cycle; on the
    bench only when set: daemon/run/arm/setup.py plays_duty_cycle)."""
    return settings.arm.play_duty_cycle is True


def speed_factor(settings: Settings) -> float:
    """How much faster than a real arm the emulated one moves, for the bench's clock (a played
    duty cycle: real speed, the emulator on the run clock)."""
    if played(settings):
        return 1.0
    bench = settings.bench
    if bench.clock == "virtual":
        return VIRTUAL_SPEED_FACTOR
    if bench.clock == "accelerated":
        return bench.time_factor
    return 1.0


def bench_config(settings: Settings, arm: Arm, duty: DutyCycle | None, seed: int) -> ArmBenchConfig:
    """The arm bench's make-up from the settings: its truth (``bench.arm_truth``, checked
    when the settings loaded; none: the default truth), the arm file, a camera station of
    ``arm.cameras`` cameras at each measured pose of the default duty cycle (else at the zero
    configuration), the tool's markers, the IR regions of IR_REGIONS."""
    stations: tuple[tuple[float, ...], ...] = ()
    if duty is not None:
        stations = tuple(tuple(pose.q_rad) for pose in duty.measured_poses())
    regions = tuple(
        (region_name(arm.links[i].name, fraction, face), arm.links[i].name, fraction)
        for i, fraction, face in IR_REGIONS
        if i < arm.dof
    )
    name = settings.bench.arm_truth
    truth = ArmTruth() if name is None else load_arm_truth(name)
    return config_from_truth(
        truth,
        seed,
        arm=settings.arm.arm_file,
        noise_seed=settings.bench.noise_seed,
        stations_q_rad=stations,
        markers_tool_mm=settings.arm.markers_mm,
        rig=CameraRig(count=settings.arm.cameras),
        ir_regions=regions,
    )


class ArmBenchControl:
    """The arm bench as an arm run drives it: cold at the run's start, then on the run clock
    (module docstring); the truth is rebuilt cold for each run (same seed: the same arm)."""

    def __init__(
        self,
        settings: Settings,
        clock: Clock,
        emulator: C500CEmulator,
        *,
        config: ArmBenchConfig,
        arm: Arm,
        duty: DutyCycle | None,
    ) -> None:
        self._clock = clock
        self._emulator = emulator
        self._config = config
        self._arm = arm
        self._time_scale = settings.compensation.time_scale
        self._duty = duty
        self._played = played(settings)
        self._lock = threading.Lock()
        self.truth = self._new_truth(duty)
        self.start_s: float | None = None

    def _new_truth(
        self, duty: DutyCycle | None, motion: JointMotionSource | None = None
    ) -> ArmBench:
        """A cold truth following ``duty`` (played in process, unless ``motion`` is given: the
        emulator's) with its payload at the tool (as the controller's model has it:
        daemon/arm/heat.py JointHeatProfile.from_duty)."""
        if duty is None:
            return ArmBench(self._config, motion, arm=self._arm)
        config = dataclasses.replace(self._config, payload_kg=duty.payload_kg)
        return ArmBench(config, motion or DutyCycleMotion(duty), arm=self._arm)

    @property
    def cameras(self) -> tuple[CameraModel, ...]:
        return self.truth.cameras

    def start_run(self, t_s: float, **_: object) -> None:
        """A two-link run on the arm bench: it has no spot camera to measure it with."""
        raise RuntimeError("the arm bench runs arm runs only: name a duty cycle")

    def start_arm_run(self, t_s: float, *, duty_cycle: str | None) -> None:
        """An arm run starts: the arm is cold now and follows ``duty_cycle`` (else the
        settings' one). Blocking (a second): the session calls it on a worker thread."""
        duty = self._duty if duty_cycle is None else load_duty_cycle(duty_cycle)
        # played: the motion the emulator performs from now on heats the truth's motors
        motion = ShiftedMotion(self._emulator, t_s) if self._played else None
        truth = self._new_truth(duty, motion)
        with self._lock:
            self.truth = truth
            self.start_s = t_s

    def sync(self, now_s: float) -> ArmBench:
        """The truth at run clock ``now_s`` (nothing moves before a run starts it). Called from
        worker threads (the cameras grab together): one at a time."""
        with self._lock:
            if self.start_s is not None:
                self.truth.advance_to((now_s - self.start_s) * self._time_scale)
            return self.truth

    def joints(self) -> np.ndarray:
        """Where the emulated arm's joints are now (on its own clock)."""
        now = self._emulator.console.now()
        return np.asarray(self._emulator.joint_sample(now).q_rad, dtype=np.float64)


class _ArmBenchSensor:
    """What the arm bench's sensors share: the bench they read, the run clock that stamps
    them, a sequence number; nothing to open or close (the bench is open_arm_bench's)."""

    def __init__(self, control: ArmBenchControl, clock: Clock) -> None:
        self._control = control
        self._clock = clock
        self._sequence = 0

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None


class SimArmCamera(_ArmBenchSensor):
    """One of the arm bench's cameras: a whole frame of the tool's markers (rendered in a
    worker thread: a 5 MP frame)."""

    def __init__(self, control: ArmBenchControl, index: int, clock: Clock) -> None:
        super().__init__(control, clock)
        self.index = index

    async def grab(self) -> Frame:
        now = self._clock.now()
        q = self._control.joints()
        self._sequence += 1
        # a 5 MP render: computing, not the camera's latency (off a grab's deadline)
        image, bit_depth = await off_the_clock(self._render, now, q)
        return Frame(image, bit_depth, now, self._sequence, "camera")

    def _render(self, now_s: float, q: np.ndarray) -> tuple[np.ndarray, int]:
        """On a worker thread: the truth at ``now_s``, the markers at joints ``q``."""
        truth = self._control.sync(now_s)
        model = truth.cameras[self.index]
        _, visible = marker_pixels(model, truth.markers_world_mm(q))
        if not visible.any():
            # the tool is at another station: a dark frame, not 5 MP of rendered noise
            width, height = model.image_size_px
            return np.zeros((height, width), dtype=np.uint16), truth.config.rig.bit_depth
        frame = truth.render(self.index, q)
        return np.asarray(frame.image), frame.bit_depth


class SimArmIr(_ArmBenchSensor):
    """The IR regions of the arm bench (mean of the true nodes there, offset and noise)."""

    async def read(self) -> IrReading:
        now = self._clock.now()
        values = await off_the_clock(self._read, now)
        self._sequence += 1
        regions = {
            name: RegionTemperature(name, value, value, None) for name, value in values.items()
        }
        return IrReading(regions, now, self._sequence)

    def _read(self, now_s: float) -> dict[str, float]:
        return self._control.sync(now_s).ir_read()


class SimArmRoom(_ArmBenchSensor):
    """The arm bench's room thermometer (drivers/sim/arm_room.py: the truth's room with the
    sensor's lag, offset, noise and resolution)."""

    async def read(self) -> RoomReading:
        now = self._clock.now()
        value = await off_the_clock(self._read, now)
        self._sequence += 1
        return RoomReading(value, now, "sim")

    def _read(self, now_s: float) -> float:
        return self._control.sync(now_s).room_read()


@contextlib.asynccontextmanager
async def open_arm_bench(
    settings: Settings, clock: Clock, seed: int
) -> AsyncIterator[ArmBenchDevices]:
    """The arm bench's devices, opened together and closed together."""
    arm = load_arm(settings.arm.arm_file)
    duty = None if settings.arm.duty_cycle is None else load_duty_cycle(settings.arm.duty_cycle)
    factor = speed_factor(settings)
    robot_settings = settings.robot
    joint_arm = JointArmConfig(
        arm=arm,
        speed_deg_s=DEFAULT_SPEED_DEG_S * factor,
        acceleration_deg_s2=DEFAULT_ACCELERATION_DEG_S2 * factor * factor,
    )
    if played(settings) and duty is not None:
        # the controller's joint limits at `speed 100`: the duty cycle's (the arm's published
        # maxima, config/duty); its acceleration is its own (no console command sets it)
        joint_arm = dataclasses.replace(
            joint_arm,
            max_speed_deg_s=tuple(np.degrees(duty.max_speed_rad_s).tolist()),
            max_accel_deg_s2=tuple(np.degrees(duty.max_accel_rad_s2).tolist()),
            cache_solutions=True,
        )
    async with contextlib.AsyncExitStack() as stack:
        emulator = C500CEmulator(
            EmulatorConfig(
                application=robot_settings.application,
                seed=seed,
                noise_um=settings.bench.robot_noise_um,
                move_ms=robot_settings.emulator_move_ms,
                baudrate=robot_settings.baudrate,
                paced=robot_settings.emulator_paced,
                joint_arm=joint_arm,
                clock=clock if played(settings) else None,
            )
        )
        await stack.enter_async_context(emulator)
        control = ArmBenchControl(
            settings,
            clock,
            emulator,
            config=bench_config(settings, arm, duty, seed),
            arm=arm,
            duty=duty,
        )
        robot = C500CRobot(robot_settings, port=emulator.device_path)
        cameras = tuple(SimArmCamera(control, k, clock) for k in range(len(control.cameras)))
        ir = SimArmIr(control, clock)
        await stack.enter_async_context(robot)
        yield ArmBenchDevices(
            camera=cameras[0],
            ir=ir,
            robot=robot,
            bench=control,
            emulator=emulator,
            cameras=cameras,
            camera_models=control.cameras,
            room=SimArmRoom(control, clock),
        )
