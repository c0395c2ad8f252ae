"""The emulated UR e-Series controller without its network: registers, modes, the robot-side
program (drivers/sim/ur/program.py) run every 2 ms controller cycle, the taught cycle played
on the UR5e joint arm (drivers/sim/ur/player.py), and the RTDE outputs by name.

The arm's joints are the played program's plus the path offset: the program's offset
(metres, rotation vector, base frame, as path_offset_set type 1) turned into joint angles
through the Jacobian, ``dq = J(q)^-1 [1000 d; r]`` (the arm's kinematics are in mm). The
Jacobian (also for ``actual_TCP_speed``) is recomputed when the joints moved more than
JACOBIAN_REUSE_RAD since the last one
(the offset's joint delta is then off by <= 0.5 % of itself: 0.5 um of a 100 um correction;
exact at the poses where the program dwells and the tool is measured). ``actual_TCP_pose`` is
the forward kinematics of those joints (the nominal arm: what the controller believes).

``actual_current`` is each joint motor's current for the motion the emulated arm makes, on the
bench truth's arm (its motors, friction and payload: drivers/sim/arm_physics.py
motor_current): the current whose copper loss heats the truth's joints, as a real UR's
"Actual joint currents" are its motors' (ASSUMED: the RTDE guide says no more). Computed at
the program's nominal joints (the offset's joint delta, microradians, changes no torque), and
only for a recipe that asks for it: ~0.4 ms per package while the arm moves (the torque of
one sample through daemon/arm/motors.py), reused while it rests.

The speed slider (RTDE inputs ``speed_slider_mask`` = 1 and ``speed_slider_fraction``, as
ur-rtde's ``setSpeedSlider`` writes them) slows the played program (drivers/sim/ur/player.py);
``speed_scaling`` and ``target_speed_fraction`` report it.

Joint temperatures come from the arm bench's thermal truth (drivers/sim/arm_bench.py) heated
by the motion the emulated arm really made, read like a sensor: Gaussian noise of
TEMPERATURE_NOISE_C and a resolution of TEMPERATURE_RESOLUTION_C (both ESTIMATES: UR publishes
neither).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from daemon.arm import kinematics
from daemon.arm.duty import DutyCycle, load_duty_cycle
from daemon.arm.loading import load_arm
from daemon.arm.types import FloatArray
from drivers.sim.arm_bench import DEFAULT_MARKERS_MM, ArmBench, ArmBenchConfig
from drivers.sim.arm_markers import CameraRig
from drivers.sim.arm_motion import PowerFunction
from drivers.sim.arm_physics import motor_current
from drivers.sim.joint_arm import JointArm, JointArmConfig
from drivers.sim.ur.player import PlayerState, ProgramPlayer
from drivers.sim.ur.program import OffsetProgram, ProgramInputs, ProgramLimits, holds_dwell
from drivers.ur import rtde_variables as names
from drivers.ur.modes import (
    ROBOT_STATUS_POWER_ON,
    ROBOT_STATUS_PROGRAM_RUNNING,
    SAFETY_STATUS_BIT,
    RobotMode,
    RuntimeState,
    SafetyMode,
)
from drivers.ur.registers import RegisterMap
from drivers.ur.rtde_protocol import CONTROLLER_CYCLE_S, DataType, Value

JACOBIAN_REUSE_RAD = 5e-3
#: The slowest the speed slider plays the program (a fraction of 0 would never end a move).
MIN_SPEED_FRACTION = 0.01
#: Every this many controller cycles (0.1 s) the thermal truth follows the arm's motion
#: (ArmBench.follow_motion: ~0.7 ms for 10 motion samples), so that its 2-s step never
#: samples a whole step of motion inside one 2-ms cycle (~6 ms: three cycles late, and every
#: correction written meanwhile applied late; benchmarks/bench_ur.py).
TRUTH_FOLLOW_CYCLES = 50
TEMPERATURE_NOISE_C = 0.05  # ESTIMATE
TEMPERATURE_RESOLUTION_C = 0.0625  # ESTIMATE: a 1/16 degC digital sensor
#: The emulated controller's software version (PolyScope >= 5.6: path_offset_set exists).
DEFAULT_VERSION = (5, 15, 0, 0)


@dataclass(frozen=True)
class URControllerConfig:
    arm: str = "ur5e"
    duty: str = "ur5e-pick-and-place"
    register_base: int = 24
    limits: ProgramLimits = field(default_factory=ProgramLimits)
    seed: int = 0
    version: tuple[int, int, int, int] = DEFAULT_VERSION
    program_name: str = "thermocomp.urp"
    #: the program plays from the start (a cell in production); else it waits for PLAY
    autoplay: bool = True
    #: a fieldbus adapter (EtherNet/IP...) is enabled: input registers 0-23 are IN_USE
    fieldbus: bool = False
    #: the thermal truth's node spacing (mm): coarser than the arm bench's 10 mm so that an
    #: emulator starts in well under a second
    node_spacing_mm: float = 25.0
    temperature_noise_c: float = TEMPERATURE_NOISE_C
    temperature_resolution_c: float = TEMPERATURE_RESOLUTION_C
    #: the bench's tool cameras (drivers/sim/ur/cameras.py): ``camera_rig.count`` cameras
    #: set up around each measured pose of the duty cycle, as the A465's arm bench
    #: (drivers/sim/arm_devices.py bench_config), watching these markers (tool frame, mm)
    camera_rig: CameraRig = field(default_factory=CameraRig)
    markers_tool_mm: tuple[tuple[float, float, float], ...] = DEFAULT_MARKERS_MM
    #: the taught program calls tc_wait_for_frames(k) after the Wait of each measured pose
    #: (controller/ur/README.md): it holds the dwell while the PC takes its frames
    #: (drivers/sim/ur/program.py holds_dwell); False: a program taught without it, whose
    #: dwells end on time whatever the PC does
    waits_for_frames: bool = True


class URController:
    """One emulated controller; ``cycle(t)`` runs one 2 ms cycle at emulator time ``t``."""

    def __init__(self, config: URControllerConfig | None = None) -> None:
        self.config = config = config or URControllerConfig()
        self.registers = RegisterMap(config.register_base)
        arm = load_arm(config.arm)
        self.arm = arm
        self.duty: DutyCycle = load_duty_cycle(config.duty)
        start = tuple(math.degrees(v) for v in self.duty.poses[0].q_rad)
        self.joint_arm = JointArm(JointArmConfig(arm, start_joints_deg=start))
        self.player = ProgramPlayer(self.duty, self.joint_arm)
        self.program = OffsetProgram(config.limits)
        self.bench = ArmBench(
            ArmBenchConfig(
                arm=config.arm,
                seed=config.seed,
                node_spacing_mm=config.node_spacing_mm,
                payload_kg=self.duty.payload_kg,
                # the cameras stand at the program's measured poses (the A465 bench's rule)
                stations_q_rad=tuple(tuple(p.q_rad) for p in self.duty.measured_poses()),
                rig=config.camera_rig,
                markers_tool_mm=config.markers_tool_mm,
            ),
            motion=self.player,
            arm=arm,
        )
        self._noise = np.random.default_rng(np.random.SeedSequence([config.seed, 31]))
        self.inputs: dict[str, Value] = {
            name: _zero(t) for name, t in names.INPUTS.items() if "register" in name
        }
        # the speed slider (module docstring): at full speed until a client sets it
        self.inputs.update(speed_slider_mask=0, speed_slider_fraction=1.0)
        self.outputs: dict[str, Value] = {
            name: _zero(names.OUTPUTS[name]) for name in self.registers.outputs
        }
        #: how many times each input register was written (what reached the controller)
        self.writes: Counter[str] = Counter()
        #: True: the program's thread does not run (fault injection: a program that stopped
        #: accepting corrections while the taught program plays on)
        self.program_frozen = False
        self.robot_mode = RobotMode.RUNNING
        self.safety_mode = SafetyMode.NORMAL
        self.time_s = 0.0
        self.cycles = 0
        self._jacobian_q: FloatArray | None = None
        self._jacobian: FloatArray = np.eye(6)
        self._state_t: float | None = None
        self._state: tuple[FloatArray, FloatArray, FloatArray] = (np.zeros(6),) * 3
        self._current: tuple[tuple[float, ...] | None, tuple[float, ...]] = (None, ())
        self._current_of: tuple[ArmBench | None, PowerFunction | None] = (None, None)
        self._temperatures_t = -math.inf
        self._temperatures: tuple[float, ...] = (self.bench.config.ambient_c,) * 6
        #: config.waits_for_frames, switchable while it runs (a test's program taught without)
        self.waits_for_frames = config.waits_for_frames
        self.player.holds = self._holds_dwell
        if config.autoplay:
            self.player.play(0.0)

    # -- program and modes -------------------------------------------------------------------

    @property
    def runtime_state(self) -> RuntimeState:
        return {
            PlayerState.PLAYING: RuntimeState.PLAYING,
            PlayerState.PAUSED: RuntimeState.PAUSED,
            PlayerState.STOPPED: RuntimeState.STOPPED,
        }[self.player.state]

    def play(self, now_s: float) -> bool:
        """The Dashboard's play: False when the robot cannot (not running, safety stop)."""
        if self.robot_mode is not RobotMode.RUNNING or self.safety_mode is not SafetyMode.NORMAL:
            return False
        if self.player.state is PlayerState.STOPPED:
            self.program = OffsetProgram(self.config.limits)  # a program starts afresh
        self.player.play(now_s)
        return True

    def pause(self, now_s: float) -> bool:
        if self.player.state is not PlayerState.PLAYING:
            return False
        self.player.pause(now_s)
        return True

    def stop(self, now_s: float) -> bool:
        if self.player.state is PlayerState.STOPPED:
            return False
        self.player.stop(now_s)
        return True

    def protective_stop(self, now_s: float) -> None:
        """A protective stop: the arm halts, the program pauses (fault injection)."""
        self.safety_mode = SafetyMode.PROTECTIVE_STOP
        self.player.pause(now_s)

    def unlock_protective_stop(self) -> bool:
        if self.safety_mode is not SafetyMode.PROTECTIVE_STOP:
            return False
        self.safety_mode = SafetyMode.NORMAL
        return True

    # -- the controller cycle ----------------------------------------------------------------

    def _holds_dwell(self, pose: int, held_s: float) -> bool:
        """The taught program's tc_wait_for_frames(pose) waits on this cycle."""
        if not self.waits_for_frames:
            return False
        frames = self.inputs[self.registers.frames]
        assert isinstance(frames, int)
        return holds_dwell(pose, frames, self.program.pc_silent, held_s, self.config.limits)

    def write_input(self, name: str, value: Value) -> None:
        """An RTDE client's input (already checked against the recipe's type)."""
        self.inputs[name] = value
        self.writes[name] += 1

    def cycle(self, t_s: float) -> None:
        """One controller cycle at ``t_s``: the program thread reads the registers, steps,
        applies the offset and writes its output registers; the taught program runs on."""
        self.time_s = t_s
        self.cycles += 1
        regs = self.registers
        fraction = self.inputs.get("speed_slider_fraction")
        if self.inputs.get("speed_slider_mask") == 1 and isinstance(fraction, float):
            # the guide: with its mask set, the fraction is the speed slider's
            self.player.speed_fraction = min(1.0, max(MIN_SPEED_FRACTION, fraction))
        if self.player.state is PlayerState.PLAYING:
            self.player.advance(t_s)
        if self.cycles % TRUTH_FOLLOW_CYCLES == 0:
            self.bench.follow_motion(t_s)
        if self.player.state is PlayerState.PLAYING and not self.program_frozen:
            sequence = self.inputs[regs.sequence]
            hold = self.inputs[regs.hold]
            assert isinstance(sequence, int) and isinstance(hold, int)
            target = tuple(float(self.inputs[name]) for name in regs.target)  # type: ignore[arg-type]
            self.program.step(ProgramInputs(sequence, hold, target))
        program = self.program
        self.outputs[regs.at_pose] = self.player.at_pose(t_s)
        self.outputs[regs.accepted_sequence] = program.accepted_sequence
        self.outputs[regs.status] = program.status
        self.outputs[regs.instance] = program.instance
        for name, value in zip(regs.applied, program.applied, strict=True):
            self.outputs[name] = value

    # -- outputs -----------------------------------------------------------------------------

    def joint_state(self, t_s: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Actual joints (nominal + the offset's), their speeds, and the nominal joints."""
        if self._state_t == t_s:
            return self._state
        sample = self.player.sample(t_s)
        q = np.asarray(sample.q_rad, dtype=np.float64)
        applied = self.program.applied
        dq = np.zeros(6)
        if any(applied):
            twist = np.array([*(1000.0 * v for v in applied[:3]), *applied[3:]])
            dq = np.linalg.solve(self._jacobian_at(q), twist)
        self._state_t = t_s
        self._state = (q + dq, np.asarray(sample.qd_rad_s, dtype=np.float64), q)
        return self._state

    def _jacobian_at(self, q: FloatArray) -> FloatArray:
        """The Jacobian at ``q``, reused while the joints stay within JACOBIAN_REUSE_RAD of
        where it was computed (module docstring: the offset's joints and the TCP speed are
        then off by <= 0.5 % of themselves; the Jacobian is most of a package's cost)."""
        reused = self._jacobian_q
        if reused is None or np.max(np.abs(q - reused)) > JACOBIAN_REUSE_RAD:
            self._jacobian = kinematics.jacobian(self.arm, q)
            self._jacobian_q = q.copy()
        return self._jacobian

    def tcp_pose(self, t_s: float) -> tuple[float, ...]:
        """actual_TCP_pose: x, y, z (m) and a rotation vector (rad), base frame."""
        q, _, _ = self.joint_state(t_s)
        pose = kinematics.forward(self.arm, q)
        # assume_valid: a product of rotations is orthonormal to rounding; SciPy's check
        # (an orthogonalisation) was three quarters of this call's time at 500 Hz
        rotvec = Rotation.from_matrix(pose[:3, :3], assume_valid=True).as_rotvec()
        return (*(float(v) / 1000.0 for v in pose[:3, 3]), *(float(v) for v in rotvec))

    def tcp_speed(self, t_s: float) -> tuple[float, ...]:
        q, qd, _ = self.joint_state(t_s)
        if not np.any(qd):
            return (0.0,) * 6
        twist = self._jacobian_at(q) @ qd
        return (*(float(v) / 1000.0 for v in twist[:3]), *(float(v) for v in twist[3:]))

    def joint_currents(self, t_s: float) -> tuple[float, ...]:
        """actual_current: each joint motor's current (A) now (module docstring), on the
        truth's arm (a bench replaced after the start, benchmarks/ur_recorded.py: its own);
        the last value again while the arm's motion sample is the same (at rest)."""
        sample = self.player.sample(t_s)
        key = (*sample.q_rad, *sample.qd_rad_s, *sample.qdd_rad_s2)
        bench, current = self._current_of
        if bench is not self.bench or current is None:
            current = motor_current(self.bench.true_arm, self.bench.config.payload_kg)
            self._current_of = (self.bench, current)
            self._current = (None, ())
        if self._current[0] == key:
            return self._current[1]
        values = tuple(float(v) for v in current(sample))
        self._current = (key, values)
        return values

    def joint_temperatures(self, t_s: float) -> tuple[float, ...]:
        """The joints' temperatures as the controller's sensors read them (degC)."""
        step = self.bench.config.truth_step_s
        if t_s - self._temperatures_t >= step:
            self.bench.advance_to(t_s)
            true_c = self.bench.thermal.joint_temperatures_c()
            noisy = true_c + self._noise.normal(0.0, self.config.temperature_noise_c, true_c.size)
            resolution = self.config.temperature_resolution_c
            self._temperatures = tuple(float(round(v / resolution) * resolution) for v in noisy)
            self._temperatures_t = t_s
        return self._temperatures

    def room_temperature(self, t_s: float) -> float:
        """The lab's room thermometer beside the robot, read at ``t_s`` (degC): not an RTDE
        output (a UR has no air sensor) but the DS18B20 a lab adds (room.driver), reading
        the bench truth's room with its lag, noise and resolution (drivers/sim/arm_room.py)."""
        return self.bench.room_sensor.read(t_s)

    def value(self, name: str, t_s: float) -> Value:
        """The RTDE output ``name`` at ``t_s`` (a name in rtde_variables.OUTPUTS)."""
        if name in self.outputs:
            return self.outputs[name]
        if name in self.inputs:
            return self.inputs[name]
        getter = _GETTERS.get(name)
        if getter is not None:
            return getter(self, t_s)
        return _zero(names.OUTPUTS[name])


def _zero(data_type: DataType) -> Value:
    if data_type.width > 1:
        return (0.0,) * data_type.width if data_type.format[-1] == "d" else (0,) * data_type.width
    if data_type is DataType.DOUBLE:
        return 0.0
    if data_type is DataType.BOOL:
        return False
    return 0


def _vector(values: Sequence[float] | FloatArray) -> tuple[float, ...]:
    return tuple(float(v) for v in values)


def _safety_bits(c: URController) -> int:
    return 1 << SAFETY_STATUS_BIT.get(c.safety_mode, 10)


def _robot_bits(c: URController) -> int:
    running = c.player.state is PlayerState.PLAYING
    return ROBOT_STATUS_POWER_ON | (ROBOT_STATUS_PROGRAM_RUNNING if running else 0)


Getter = Callable[["URController", float], Value]

_GETTERS: dict[str, Getter] = {
    "timestamp": lambda c, t: t,
    "actual_q": lambda c, t: _vector(c.joint_state(t)[0]),
    "target_q": lambda c, t: _vector(c.joint_state(t)[0]),
    "actual_qd": lambda c, t: _vector(c.joint_state(t)[1]),
    "actual_current": lambda c, t: c.joint_currents(t),
    "target_qd": lambda c, t: _vector(c.joint_state(t)[1]),
    "target_qdd": lambda c, t: _vector(c.player.sample(t).qdd_rad_s2),
    "actual_TCP_pose": lambda c, t: c.tcp_pose(t),
    "target_TCP_pose": lambda c, t: c.tcp_pose(t),
    "actual_TCP_speed": lambda c, t: c.tcp_speed(t),
    "target_TCP_speed": lambda c, t: c.tcp_speed(t),
    "joint_temperatures": lambda c, t: c.joint_temperatures(t),
    "robot_mode": lambda c, t: int(c.robot_mode),
    "safety_mode": lambda c, t: int(c.safety_mode),
    "safety_status": lambda c, t: int(c.safety_mode),
    "runtime_state": lambda c, t: int(c.runtime_state),
    "robot_status_bits": lambda c, t: _robot_bits(c),
    "safety_status_bits": lambda c, t: _safety_bits(c),
    "speed_scaling": lambda c, t: c.player.speed_fraction,
    "target_speed_fraction": lambda c, t: c.player.speed_fraction,
    "actual_execution_time": lambda c, t: 0.1,
    "joint_mode": lambda c, t: (253,) * 6,  # JOINT_RUNNING_MODE
    "actual_main_voltage": lambda c, t: 48.0,
    "actual_robot_voltage": lambda c, t: 48.0,
    "actual_joint_voltage": lambda c, t: (48.0,) * 6,
    "payload": lambda c, t: c.duty.payload_kg,
    "actual_tool_accelerometer": lambda c, t: (0.0, 0.0, -9.81),
}

__all__ = ["CONTROLLER_CYCLE_S", "DEFAULT_VERSION", "URController", "URControllerConfig"]
