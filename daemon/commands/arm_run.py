"""A recorded arm run as identification sees it (daemon/arm/identify.py): what the readers of
an A465 arm run (daemon/commands/arm_identify.py) and of a UR's followed run
(daemon/commands/followed_identify.py) both return."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from config import Settings
from daemon.arm.controller import ArmController, ArmModelOptions
from daemon.arm.identify import ArmModelSpec, ArmRunData

#: The heat record's step for identification (arm time, s): a measurement's time is rounded to
#: it; the links' time constants are tens of minutes (benchmarks/bench_arm.py IDENTIFY_STEP_S).
IDENTIFY_STEP_S = 20.0
#: The tool point: identification fits the measured translation of the tool's origin.
TOOL_POINT_MM = np.zeros((1, 3))


def identify_options(settings: Settings) -> ArmModelOptions:
    """The arm model a recorded run's settings describe, on identification's time step: what
    both readers (and the benchmarks that replay a run) load the run's controller with."""
    return ArmModelOptions(
        motion_dt_s=settings.arm.motion_dt_s,
        ambient_c=settings.model.ambient_c,
        bending=settings.arm.bending,
        motor_side_share=settings.arm.motor_side_share,
        model_dt_s=IDENTIFY_STEP_S,
    )


class ArmRunInputError(Exception):
    """The arm run cannot be read (exit status 1)."""


@dataclass(frozen=True)
class ArmRun:
    name: str
    controller: ArmController
    data: ArmRunData
    spec: ArmModelSpec
    duty_cycle: str
