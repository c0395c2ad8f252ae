"""A recorded arm run as identification sees it (daemon/arm/identify.py): what the readers of
an A465 arm run (daemon/commands/arm_identify.py) and of a UR's followed run
(daemon/commands/followed_identify.py) both return."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from config import Settings
from daemon.arm.controller import ArmController, ArmModelOptions
from daemon.arm.identify import ArmModelSpec, ArmRunData, marker_sensitivity
from daemon.arm.room import ambient_series, readings_of
from daemon.arm.types import FloatArray

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


@dataclass(frozen=True)
class RunRows:
    """What a reader walked out of a recorded run's steps, in step order: each kept step's
    arm time (s), the index of its measured pose (into ``pose_q_rad``), its measured tool
    displacement (N x 1 x 3 mm; NaN: a step with a thermal reading only), its thermal
    readings by region (degC), and every step's room reading (arm time, degC or None)."""

    times_s: Sequence[float]
    pose_index: Sequence[int]
    displacement_mm: FloatArray
    readings: Sequence[Mapping[str, float]]
    rooms: Sequence[tuple[float | None, float | None]]


def assemble_arm_run(
    name: str,
    controller: ArmController,
    rows: RunRows,
    *,
    options: ArmModelOptions,
    settings: Settings,
    regions: Mapping[str, Sequence[int]],
    pose_q_rad: Sequence[FloatArray],
    duty_cycle: str,
    reference_fitted: bool = False,
) -> ArmRun:
    """The run as identification sees it, from what a reader walked out of its steps: the
    motor heat of the run's duty cycle on identification's step up to the last kept step, the
    room's readings as the ambient (none: ``model.ambient_c``), and the sensitivities of the
    tool point at the measured poses' joints. One assembly for both readers (the A465's arm
    run and a UR's followed run: daemon/commands/arm_identify.py, followed_identify.py).
    ``reference_fitted``: each pose's displacements are relative to one camera measurement
    there, whose error the fit takes as unknown (ArmRunData.reference_fitted)."""
    steps = math.ceil(max(rows.times_s) / IDENTIFY_STEP_S) + 1
    heat = np.array(
        [
            controller.mean_heat_w(k * IDENTIFY_STEP_S, (k + 1) * IDENTIFY_STEP_S)
            for k in range(steps)
        ]
    )
    data = ArmRunData(
        heat_step_s=IDENTIFY_STEP_S,
        joint_heat_w=heat,
        ambient_c=ambient_series(
            *readings_of(rows.rooms), IDENTIFY_STEP_S, steps, settings.model.ambient_c
        ),
        time_s=np.array([round(t / IDENTIFY_STEP_S) * IDENTIFY_STEP_S for t in rows.times_s]),
        pose_index=np.array(rows.pose_index, dtype=np.intp),
        marker_displacement_mm=rows.displacement_mm,
        region_c={
            r: np.array([reading.get(r, math.nan) for reading in rows.readings]) for r in regions
        },
        name=name,
        reference_fitted=reference_fitted,
    )
    spec = ArmModelSpec(
        description=controller.thermal.description,
        node_spacing_mm=controller.thermal.node_spacing_mm,
        regions=regions,
        sensitivities=[
            marker_sensitivity(controller.arm, np.asarray(q), TOOL_POINT_MM, options.bending)
            for q in pose_q_rad
        ],
        across_link=controller.thermal.across_link,
    )
    return ArmRun(name, controller, data, spec, duty_cycle)
