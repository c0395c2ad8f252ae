"""Before an arm run's first step (issue 20): teach every measured pose of the duty cycle as a
named goal, then measure the tool at each goal before any correction: the zero of each pose's
drift (thesis 6.2's reference "at the start at the operational goal", one per pose).

With a played duty cycle (daemon/run/arm/player.py) every pose of the cycle is taught, the
measured ones under their own names.

Teaching an arm pose moves the robot (to the pose's joint angles), unlike the two-link bench's
``here opgoal``: daemon/run/session.py calls this only once motion is allowed (after the start's
resume, and again after a resume from a fault), and the driver refuses every move after a
hold. Nothing here changes the run's state; errors go back to the session.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from config import Settings
from daemon.arm.run import MeasurementError
from daemon.arm.types import Pose6
from daemon.run.arm.player import ArmPlayer
from daemon.run.arm.step import ArmStepPipeline
from daemon.run.arm.work import ArmRobot, ArmRunWork, ToolMeter
from daemon.run.events import ErrorLog
from drivers.errors import DeviceError

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ArmServices:
    """What an arm run uses beside the two-link bench's services."""

    robot: ArmRobot
    meter: ToolMeter
    pipeline: ArmStepPipeline
    player: ArmPlayer | None = None  # a played duty cycle (daemon/run/arm/player.py)


async def teach_poses(work: ArmRunWork, robot: ArmRobot) -> None:
    """Teach each measured pose as the goal of its name, or with a played duty cycle every
    pose of the cycle, in its order (raises DeviceError)."""
    poses = {pose.name: pose for pose in work.poses}
    if work.cycle:
        poses = {entry.pose.name: entry.pose for entry in work.cycle}
    for pose in poses.values():
        work.taught[pose.name] = await robot.teach_pose(pose)
        logger.info("run %d: taught pose %r", work.run_id, pose.name)


#: Frames of each pose's reference at least (issue 29): enough for the meter to measure its
#: cameras' scatter on the still tool before the first step (daemon/run/arm/measure.py
#: ScatterLog: 2 poses x 4 markers x 3 degrees of freedom x 2 axes = 48 per camera, the
#: 1-sigma to ~10 %), the floor of every later measurement's 1-sigma. Each frame of the
#: bench's 5 MP cameras is ~0.16 s of CPU to render: no more than needed.
MIN_REFERENCE_FRAMES = 4


def reference_frames(settings: Settings) -> int:
    """The frames of a reference: arm.reference_frames (none: arm.frames_per_measurement),
    at least MIN_REFERENCE_FRAMES."""
    arm = settings.arm
    asked = arm.reference_frames or arm.frames_per_measurement
    return max(asked, MIN_REFERENCE_FRAMES)


async def measure_references(
    work: ArmRunWork, services: ArmServices, errors: ErrorLog, frames: int | None = None
) -> None:
    """The tool at each taught goal, uncorrected, before the first step, with ``frames`` per
    camera (arm.reference_frames: the reference's error is in every later drift of its pose,
    so it may be worth more frames than a step's). A pose whose markers cannot be measured now
    takes its first step's measurement as its zero instead: never silently (the pose and why
    go to ``work.missing_references``, which the summary reports; that step is flagged
    first-step-reference)."""
    measured = 0
    for pose in work.poses:
        try:
            await services.robot.move_to_goal(pose.name, Pose6.zero())
            measurement = await services.meter.measure(pose.tool_pose, frames)
        except MeasurementError as err:
            _missing(work, pose.name, f"markers: {err}")
            continue
        except DeviceError as err:
            errors.note(err)
            _missing(work, pose.name, str(err))
            if err.device == "robot":  # the robot cannot go on: the session faults
                raise
            continue
        work.reference[pose.name] = measurement.pose
        work.missing_references.pop(pose.name, None)  # measured after all (a resume)
        measured += 1
    if measured == len(work.poses):
        work.reference_source = "each taught goal before the first correction"
    elif measured:
        work.reference_source = "taught goals before the first correction, else first steps"
    else:
        work.reference_source = "each pose's first step (no reference measured)"


def _missing(work: ArmRunWork, pose: str, why: str) -> None:
    logger.warning(
        "run %d: no reference at %r (%s): its first step is its zero", work.run_id, pose, why
    )
    work.missing_references[pose] = why
