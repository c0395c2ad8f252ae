"""A recorded arm run as identification sees it (daemon/arm/identify.py): what the readers of
an A465 arm run (daemon/commands/arm_identify.py) and of a UR's followed run
(daemon/commands/followed_identify.py) both return."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from daemon.arm.controller import ArmController
from daemon.arm.identify import ArmModelSpec, ArmRunData

#: The heat record's step for identification (arm time, s): a measurement's time is rounded to
#: it; the links' time constants are tens of minutes (benchmarks/bench_arm.py IDENTIFY_STEP_S).
IDENTIFY_STEP_S = 20.0
#: The tool point: identification fits the measured translation of the tool's origin.
TOOL_POINT_MM = np.zeros((1, 3))


class ArmRunInputError(Exception):
    """The arm run cannot be read (exit status 1)."""


@dataclass(frozen=True)
class ArmRun:
    name: str
    controller: ArmController
    data: ArmRunData
    spec: ArmModelSpec
    duty_cycle: str
