"""The emulated C500C's `ash` command interpreter: one line in, answer lines out (no I/O).

drivers/sim/emulator.py serves it on a pty or a TCP port. It follows the firmware's texts and
layouts of docs/reference/c500c-console.md through drivers/c500c/protocol.py; what no source
confirms is the ``ASSUMED`` block of drivers/c500c/texts.py. Emulator-only simplifications (not
protocol assumptions): without an arm (EmulatorConfig.joint_arm) there are no kinematics (the PULSES
and JOINTS rows are zeros), the reach check is a sphere of ``REACH_MM`` around the base and `wshift`
adds its angles; with one, the arm lives in joint space (drivers/sim/joint_arm.py: inverse
kinematics, trapezoidal profiles, JOINTS and PULSES from the joints). Relative `w*` moves start
from the actual (not the commanded) pose, so their positioning errors accumulate as the
thesis's incremental commands did (6.4.4). The state it changes (and the emulator's constants)
is drivers/sim/ash_state.py.
"""

from __future__ import annotations

import asyncio
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from drivers.c500c import protocol as proto
from drivers.sim.ash_state import (
    MOTION_WORDS,
    REACH_MM,
    ConsoleCommandError,
    ConsoleState,
    Location,
    MotionRecord,
    as_location,
)

if TYPE_CHECKING:
    from drivers.sim.emulator_config import EmulatorConfig
    from drivers.sim.joint_arm import JointArm


@dataclass(frozen=True, slots=True)
class _Question:
    """A question the console printed instead of a prompt; the next line answers it."""

    text: str
    on_answer: Callable[[str], list[str]]


def _shell_error(text: str) -> str:
    """A shell error as the firmware prints it: `error: ` and the text
    (docs/reference/c500c-console.md "Errors")."""
    return proto.format_error(None, text)


class Console:
    """The `ash` command interpreter: one line in, answer lines out (no I/O)."""

    def __init__(self, config: EmulatorConfig, rng: np.random.Generator) -> None:
        self.joint_arm: JointArm | None = None
        start = as_location(config.start_pose)
        if config.joint_arm is not None:
            # lazy: the kinematics (SciPy) load only for an emulator with an arm
            from drivers.sim.joint_arm import JointArm

            self.joint_arm = JointArm(config.joint_arm)
            start = as_location(self.joint_arm.location_at(0.0))
        self.config = config
        self.rng = rng
        self.state = ConsoleState(
            arm_power=config.arm_power,
            homed=config.homed,
            online=config.online,
            point_of_control=config.point_of_control,
            commanded=start,
            actual=start,
            previous_actual=start,
            in_shell=config.start_in_shell,
        )
        self.question: _Question | None = None
        #: loop time before which the next motion cannot start (the fast-path emulator sets it
        #: to when the request's last byte arrived on the paced line); used once
        self.motion_not_before = 0.0
        self._after_button: str | None = None  # the motion command waiting for the button
        self._button: asyncio.Event | None = None
        #: called each time the motion record (previous_actual, actual, motion_end_s) changes,
        #: before the command that changed it is answered: the emulator in its own process
        #: publishes it for the bench there (drivers/sim/shared_pose.py; issue 30)
        self.on_motion: Callable[[], None] | None = None

    @property
    def prompt(self) -> bytes:
        if self.question is not None:
            return self.question.text.encode("ascii")
        return (
            proto.SHELL_PROMPT if self.state.in_shell else proto.prompt_for(self.config.application)
        )

    def _ask(self, text: str, on_answer: Callable[[str], list[str]]) -> list[str]:
        self.question = _Question(text, on_answer)
        return []

    def _create_it(self, name: str, then: Callable[[], list[str]]) -> list[str]:
        """`here`/`set` to a variable that does not exist [firmware]: "Variable '<name>' not
        found." and "  -- create it? "; "yes" creates it and carries on, "no" does nothing,
        anything else asks "Please answer 'yes' or 'no': "."""

        def answer(text: str) -> list[str]:
            if text in ("yes", "y"):
                self.state.locations[name] = self.state.actual
                return then()
            if text in ("no", "n"):
                return []
            return self._ask("Please answer 'yes' or 'no': ", answer)

        self._ask("  -- create it? ", answer)
        return [f"Variable '{name}' not found."]

    def press_pause_continue(self) -> None:
        """The operator takes the point of control at the controller."""
        self.state.point_of_control = True
        if self._button is not None:
            self._button.set()

    async def wait_for_button(self) -> list[str]:
        """Block until PAUSE/CONTINUE is pressed, then run the motion command that waited."""
        if self._button is None:
            self._button = asyncio.Event()
        while not self.state.point_of_control:
            self._button.clear()
            await self._button.wait()
        line, self._after_button = self._after_button, None
        self.state.awaiting_button = False
        return [] if line is None else await self._execute(line)

    def restart(self) -> None:
        """The controller restarts: every variable is forgotten, online is off, any question or
        waiting motion is gone, and the console is at the system shell."""
        state = self.state
        state.locations.clear()
        state.online = False
        state.in_shell = True
        state.awaiting_button = False
        state.restarts += 1
        self.question = None
        self._after_button = None

    def now(self) -> float:
        """The emulator's clock: its config's clock, else the serving loop's ``time()``."""
        clock = self.config.clock
        return asyncio.get_running_loop().time() if clock is None else clock.now()

    def actual_pose(self, now_s: float) -> Location:
        """Where the arm really is at loop time ``now_s`` (the start pose while moving)."""
        if self.joint_arm is not None:  # where the joints are on their profile
            return as_location(self.joint_arm.location_at(now_s))
        state = self.state
        return state.actual if now_s >= state.motion_end_s else state.previous_actual

    def halt_motion(self, now_s: float) -> None:
        """RAPL-3 `halt()` (the fast-path program): the motion in progress stops now. Without
        an arm the emulated arm is back where the motion started (the emulator's arm jumps to
        its target at the end of the move); with one it stays where its joints are."""
        state = self.state
        if self.joint_arm is not None:
            self.joint_arm.halt(now_s)
            state.actual = state.commanded = self.actual_pose(now_s)
        else:
            state.actual = state.commanded = state.previous_actual
        state.motion_end_s = now_s
        if self.on_motion is not None:
            self.on_motion()

    def shift_location(self, base: Sequence[float], offset: Sequence[float]) -> Location:
        """`wshift`'s arithmetic (the fast-path program's `shift_w` too): with an arm, a
        rotation in the world frame about the location's position (drivers/sim/joint_arm.py);
        without, every value added (the emulator's simplification)."""
        if self.joint_arm is not None:
            # lazy: the kinematics (SciPy) load only for an emulator with an arm
            from drivers.sim.joint_arm import shift_location

            return as_location(shift_location(base, offset))
        return as_location([b + o for b, o in zip(base, offset, strict=True)])

    async def execute(self, line: str) -> list[str]:
        """Run one command line; return the answer lines (errors included). A motion command
        without the point of control answers the PAUSE/CONTINUE request and waits: the caller
        then awaits :meth:`wait_for_button` for the rest of the answer."""
        self.state.log_command(line)
        question = self.question
        if question is not None:
            self.question = None
            return question.on_answer(line.strip())
        return await self._execute(line)

    async def _execute(self, line: str) -> list[str]:
        words = line.strip()
        if not words:
            return []
        if self.state.in_shell:
            return self._shell(words)
        name, _, rest = words.partition(" ")
        try:
            if name == "finish":
                await self._finish()
                return []
            if name in MOTION_WORDS:
                await self._finish()  # a new motion starts when the previous one has ended
            handler = getattr(self, f"_cmd_{name}", None)
            if handler is None:
                raise ConsoleCommandError(proto.format_error(None, "Unrecognized command."))
            if name in MOTION_WORDS and not self.state.point_of_control:
                # docs/reference/c500c-console.md "Point of control": the request, then the wait for
                # the button
                self.state.awaiting_button = True
                self._after_button = line
                return [proto.POINT_OF_CONTROL_MESSAGE]
            answer: list[str] = handler(rest.strip())
            return answer
        except ConsoleCommandError as err:
            return [err.line]

    # --- the system shell ---

    def _shell(self, words: str) -> list[str]:
        parts = words.split()
        if parts[0] != "ash" or len(parts) > 2:
            return [f"{parts[0]}: not found"]
        if len(parts) == 1:  # [firmware]: ash without an argument asks for the application
            self._ask("Application name > ", lambda name: self._start_ash(name.strip()))
            return []
        return self._start_ash(parts[1])

    def _start_ash(self, application: str) -> list[str]:
        if application != self.config.application:
            return [f"{application}: application not found"]
        self.state.in_shell = False
        return []

    # --- helpers ---

    @staticmethod
    def _arguments(rest: str, count: int) -> list[str]:
        parts = [part.strip() for part in rest.split(",")] if rest else []
        if len(parts) < count:
            raise ConsoleCommandError(
                _shell_error("missing comma." if parts else "invalid argument.")
            )
        if len(parts) > count:
            raise ConsoleCommandError(_shell_error("too many arguments."))
        return parts

    @staticmethod
    def _number(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise ConsoleCommandError(_shell_error("missing number.")) from None
        if not math.isfinite(value):
            raise ConsoleCommandError(_shell_error("invalid argument."))
        return value

    def _location(self, name: str) -> Location:
        if name not in self.state.locations:
            raise ConsoleCommandError(_shell_error("variable not found."))
        return self.state.locations[name]

    @staticmethod
    def _variable_name(name: str) -> str:
        if not re.fullmatch(r"[A-Za-z_]\w*", name):
            raise ConsoleCommandError(_shell_error("invalid argument."))
        return name

    def _check_motion(self, straight: bool) -> list[str] | None:
        state = self.state
        if not state.arm_power:
            raise ConsoleCommandError(proto.format_error(7))
        if not state.homed:
            raise ConsoleCommandError(proto.format_error(5))
        if straight and not state.online:
            raise ConsoleCommandError(proto.format_error(43))
        return None

    def _start_motion(self, target: Location) -> None:
        if self.joint_arm is None and math.dist((0.0, 0.0, 0.0), target[:3]) > REACH_MM:
            raise ConsoleCommandError(proto.format_error(3))
        sigma_mm = self.config.noise_um / 1000.0
        noise = self.rng.normal(0.0, sigma_mm, size=3) if sigma_mm > 0 else np.zeros(3)
        state = self.state
        now_s = max(self.now(), self.motion_not_before)
        self.motion_not_before = 0.0
        if self.joint_arm is not None:
            # lazy: the kinematics (SciPy) load only for an emulator with an arm
            from drivers.sim.joint_arm import UnreachableError

            try:
                end_s = self.joint_arm.move_to(
                    target, now_s, noise, speed_percent=state.speed_percent
                )
            except UnreachableError:
                raise ConsoleCommandError(proto.format_error(3)) from None
            start_s = self.joint_arm.last_start_s()
            state.motions.append(MotionRecord(start_s, end_s, target, state.speed_percent))
            state.motion_count += 1
            state.previous_actual = self.actual_pose(now_s)
            state.commanded = target
            state.actual = self.actual_pose(end_s)
            state.motion_end_s = end_s
            return
        state.previous_actual = state.actual
        state.commanded = target
        state.actual = as_location(
            (target[0] + noise[0], target[1] + noise[1], target[2] + noise[2], *target[3:])
        )
        state.motion_end_s = now_s + self.config.move_ms / 1000.0
        state.motions.append(MotionRecord(now_s, state.motion_end_s, target, state.speed_percent))
        state.motion_count += 1
        if self.on_motion is not None:
            self.on_motion()

    async def _finish(self) -> None:
        clock = self.config.clock
        if clock is not None:
            await clock.sleep_until(self.state.motion_end_s)
            return
        remaining = self.state.motion_end_s - asyncio.get_running_loop().time()
        if remaining > 0:
            await asyncio.sleep(remaining)

    def _table(
        self, pose: Location, title: str, joints_rad: NDArray[np.float64] | None
    ) -> list[str]:
        """A `w0`/`w2` table; ``joints_rad`` of an arm fill JOINTS and PULSES (without an arm
        they are zeros: the emulator's simplification)."""
        joints: tuple[float, ...] = (0.0,) * 6
        pulses: tuple[int, ...] = (0,) * 6
        if self.joint_arm is not None and joints_rad is not None:
            joints = tuple(math.degrees(v) for v in joints_rad)
            pulses = self.joint_arm.pulses(joints_rad)
        return proto.format_w_table(pose, joints, pulses, title=title, layout=self.config.layout)

    # --- commands (ash) ---

    def _cmd_w0(self, rest: str) -> list[str]:
        if rest:
            raise ConsoleCommandError(_shell_error("too many arguments."))
        commanded = None if self.joint_arm is None else self.joint_arm.commanded_joints
        return self._table(self.state.commanded, proto.COMMANDED_TITLE, commanded)

    def _cmd_w2(self, rest: str) -> list[str]:
        if rest:
            raise ConsoleCommandError(_shell_error("too many arguments."))
        now_s = self.now()
        joints = None if self.joint_arm is None else self.joint_arm.joints_at(now_s)
        return self._table(self.actual_pose(now_s), proto.ACTUAL_TITLE, joints)

    def _cmd_new(self, rest: str) -> list[str]:
        """`new <name>` makes a location (docs/reference/c500c-console.md: `help new`); ASSUMED 7:
        silent, and an error line when the name exists already (its value is kept)."""
        (name,) = self._arguments(rest, 1)
        if self._variable_name(name) in self.state.locations:
            raise ConsoleCommandError(_shell_error("variable already exists."))
        self.state.locations[name] = self.state.actual
        return []

    def _cmd_here(self, rest: str) -> list[str]:
        (name,) = self._arguments(rest, 1)
        self._variable_name(name)

        def teach() -> list[str]:
            self.state.locations[name] = self.actual_pose(self.now())
            return []

        return teach() if name in self.state.locations else self._create_it(name, teach)

    def _cmd_set(self, rest: str) -> list[str]:
        name, equals, value = rest.partition("=")
        name, value = name.strip(), value.strip()
        if not equals or not value:
            raise ConsoleCommandError(_shell_error("invalid argument."))
        self._variable_name(name)
        if value.startswith("{"):
            if not value.endswith("}"):
                raise ConsoleCommandError(_shell_error("invalid argument."))
            parts = self._arguments(value[1:-1], 6)
            location = as_location([self._number(p) for p in parts])
        else:
            location = self._location(value)

        def assign() -> list[str]:
            self.state.locations[name] = location
            return []

        return assign() if name in self.state.locations else self._create_it(name, assign)

    def _cmd_wshift(self, rest: str) -> list[str]:
        parts = self._arguments(rest, 7)
        base = self._location(parts[0])
        offset = [self._number(p) for p in parts[1:]]
        self.state.locations[parts[0]] = self.shift_location(base, offset)
        return []

    def _move_to(self, rest: str, straight: bool) -> list[str]:
        (name,) = self._arguments(rest, 1)
        target = self._location(name)
        held = self._check_motion(straight)
        if held is not None:
            return held
        self._start_motion(target)
        return []

    def _cmd_move(self, rest: str) -> list[str]:
        return self._move_to(rest, straight=False)

    def _cmd_moves(self, rest: str) -> list[str]:
        return self._move_to(rest, straight=True)

    def _relative(self, rest: str, axis: int, straight: bool) -> list[str]:
        (text,) = self._arguments(rest, 1)
        distance = self._number(text)
        held = self._check_motion(straight)
        if held is not None:
            return held
        start = list(self.state.actual)  # emulator simplification: from the actual pose
        start[axis] += distance
        self._start_motion(as_location(start))
        return []

    def _cmd_wx(self, rest: str) -> list[str]:
        return self._relative(rest, 0, straight=False)

    def _cmd_wy(self, rest: str) -> list[str]:
        return self._relative(rest, 1, straight=False)

    def _cmd_wz(self, rest: str) -> list[str]:
        return self._relative(rest, 2, straight=False)

    def _cmd_wxs(self, rest: str) -> list[str]:
        return self._relative(rest, 0, straight=True)

    def _cmd_wys(self, rest: str) -> list[str]:
        return self._relative(rest, 1, straight=True)

    def _cmd_wzs(self, rest: str) -> list[str]:
        return self._relative(rest, 2, straight=True)

    def _on_off(self, rest: str) -> bool:
        if rest not in ("on", "off"):
            raise ConsoleCommandError(_shell_error("invalid argument."))
        return rest == "on"

    def _cmd_online(self, rest: str) -> list[str]:
        self.state.online = self._on_off(rest)
        return []

    def _cmd_armpower(self, rest: str) -> list[str]:
        self.state.arm_power = self._on_off(rest)
        return []

    def _cmd_home(self, rest: str) -> list[str]:
        if rest:
            raise ConsoleCommandError(_shell_error("too many arguments."))
        if not self.state.arm_power:
            raise ConsoleCommandError(proto.format_error(7))
        self.state.homed = True
        return []

    def _cmd_speed(self, rest: str) -> list[str]:
        if not rest:
            return [f"speed = {self.state.speed_percent}%"]
        value = self._number(rest)
        if not 1 <= value <= 100 or value != int(value):
            raise ConsoleCommandError(proto.format_error(15))
        self.state.speed_percent = int(value)
        return []
