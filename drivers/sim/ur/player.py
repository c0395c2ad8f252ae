"""The emulated UR's taught program: a duty cycle (daemon/arm/duty.py) the robot plays itself,
pose after pose, with `movej`-like synchronised joint moves on the joint-space arm emulator
(drivers/sim/joint_arm.py) and a dwell at each pose.

The program starts at its first pose (the robot was left there); PLAY from STOPPED first moves
to the first pose, then dwells there and goes on as the cycle says. PAUSE (the Dashboard's
pause, a protective stop) halts the arm where it is at once (ASSUMED: a real controller
decelerates along the path within a few hundred ms; the emulator's arm stops instantly, as
the console emulator's halt does) and PLAY resumes the interrupted move or dwell. STOP halts
the arm and resets the program to its start.

The speed slider (``speed_fraction``, RTDE ``speed_slider_fraction`` under its mask) slows
the program's moves as a UR's slider slows the trajectory's time: joint speeds times the
fraction, accelerations times its square; dwells (a taught Wait) keep their length. ASSUMED: a
real controller rescales the move in progress at once; the emulator applies a new fraction
from the next move on (moves last 0.5-2 s).

``at_pose(now)`` is the program's "at measured pose" output: k (1-based) while the robot
dwells at pose k of the cycle and that pose is measured, else 0.

At the end of a measured pose's dwell the program asks ``holds(k, held_s)`` every cycle (the
main program's ``tc_wait_for_frames``: drivers/sim/ur/program.py ``holds_dwell``): while it
says so the robot stays at rest there, ``at_pose`` still k, and the next move starts in the
cycle it lets go. ``held_s``: how long the dwell has been held past its taught length.
"""

from __future__ import annotations

import enum
from collections.abc import Callable

import numpy as np

from daemon.arm.duty import DutyCycle
from daemon.arm.types import FloatArray, JointSample
from drivers.sim.joint_arm import JointArm


class PlayerState(enum.Enum):
    STOPPED = "stopped"
    PLAYING = "playing"
    PAUSED = "paused"


class ProgramPlayer:
    """The taught cycle played on ``arm`` (module docstring). Times are the emulator's (s)."""

    def __init__(self, duty: DutyCycle, arm: JointArm) -> None:
        if not duty.period_s > 0.0:  # a cycle of no time would loop for ever in advance()
            raise ValueError(f"duty cycle {duty.name!r} takes no time")
        self.duty = duty
        self.arm = arm
        self.state = PlayerState.STOPPED
        self._speed = np.asarray(duty.max_speed_rad_s, dtype=np.float64)
        self._accel = np.asarray(duty.max_accel_rad_s2, dtype=np.float64)
        self._poses = [np.asarray(p.q_rad, dtype=np.float64) for p in duty.poses]
        #: the pose the program is at or moving to
        self.index = 0
        #: moving (to ``index``) or dwelling (at ``index``)
        self._moving = False
        #: when the current move or dwell ends (playing), or how long it had left (paused)
        self._until_s = 0.0
        self._left_s = 0.0
        self._at_start = True  # STOPPED at the first pose: PLAY dwells there first
        self.cycles = 0  # completed cycles
        #: (pose k, held_s) -> hold the dwell at measured pose k on (module docstring)
        self.holds: Callable[[int, float], bool] = lambda pose, held_s: False
        #: when the dwell being held for the frames had its taught end (None: not held)
        self._held_from_s: float | None = None
        #: the speed slider (module docstring), in (0, 1]
        self.speed_fraction = 1.0

    # -- controls ----------------------------------------------------------------------------

    def play(self, now_s: float) -> None:
        if self.state is PlayerState.PLAYING:
            return
        if self.state is PlayerState.PAUSED:
            if self._moving:  # the interrupted move, from where the arm halted
                self._until_s = self._move(self.index, now_s)
            else:
                self._until_s = now_s + self._left_s
        elif self._at_start and self._here(0, now_s):
            self.index, self._moving = 0, False
            self._until_s = now_s + self.duty.poses[0].dwell_s
        else:
            self.index, self._moving = 0, True
            self._until_s = self._move(0, now_s)
        self._at_start = False
        self.state = PlayerState.PLAYING

    def pause(self, now_s: float) -> None:
        if self.state is not PlayerState.PLAYING:
            return
        self.advance(now_s)
        self.arm.halt(now_s)
        self._left_s = max(0.0, self._until_s - now_s)
        self.state = PlayerState.PAUSED

    def stop(self, now_s: float) -> None:
        if self.state is PlayerState.STOPPED:
            return
        if self.state is PlayerState.PLAYING:
            self.advance(now_s)
        self.arm.halt(now_s)
        self.state = PlayerState.STOPPED
        self.index, self._moving, self._at_start = 0, False, False
        self._held_from_s = None

    # -- time --------------------------------------------------------------------------------

    def advance(self, now_s: float) -> None:
        """Run the program up to ``now_s``: each ended dwell starts the next move, each ended
        move starts the dwell at its pose."""
        if self.state is not PlayerState.PLAYING:
            return
        while self._until_s <= now_s:
            start_s = self._until_s
            if self._moving:
                self._moving = False
                self._until_s = start_s + self.duty.poses[self.index].dwell_s
            elif self._held(now_s):
                self._until_s = now_s  # at rest this cycle; the next one asks again
                return
            else:
                self._held_from_s = None
                self.index = (self.index + 1) % len(self._poses)
                if self.index == 0:
                    self.cycles += 1
                self._moving = True
                self._until_s = self._move(self.index, start_s)

    def _held(self, now_s: float) -> bool:
        """The ended dwell is held for the PC's frames this cycle (module docstring)."""
        if not self.duty.poses[self.index].measure:
            return False
        if self._held_from_s is None:
            self._held_from_s = self._until_s
        return self.holds(self.index + 1, now_s - self._held_from_s)

    def _move(self, index: int, start_s: float) -> float:
        pose = self.duty.poses[index]
        f = self.speed_fraction
        return self.arm.move_joints(
            self._poses[index],
            start_s,
            self._speed * pose.speed * f,
            self._accel * pose.accel * f * f,
        )

    def _here(self, index: int, now_s: float) -> bool:
        return bool(np.allclose(self.arm.joints_at(now_s), self._poses[index], atol=1e-9))

    # -- outputs -----------------------------------------------------------------------------

    def at_pose(self, now_s: float) -> int:
        """The "at measured pose" output (module docstring)."""
        if self._moving or self.state is PlayerState.STOPPED:
            return 0
        if (
            self.state is PlayerState.PLAYING
            and now_s >= self._until_s
            and self._held_from_s is None
        ):
            return 0
        return self.index + 1 if self.duty.poses[self.index].measure else 0

    def sample(self, t_s: float) -> JointSample:
        return self.arm.sample(t_s)

    def joint_sample(self, t_s: float) -> JointSample:
        """The arm's joints at ``t_s`` (a drivers.sim.arm_motion.JointMotionSource: the
        bench's motor heat comes from the motion the emulated robot really made)."""
        return self.arm.sample(t_s)

    def joints(self, t_s: float) -> FloatArray:
        return self.arm.joints_at(t_s)
