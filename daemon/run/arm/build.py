"""An arm run built (issue 20; daemon/run/kinds.py chose it): the arm's plan, its robot face,
tool meter, played duty cycle and step pipeline (daemon/run/arm/setup.py), its row in the run
database. RunParameterError when the arm run cannot be built."""

from __future__ import annotations

import logging

from daemon.run.arm.kind import ArmKind
from daemon.run.arm.player import ArmPlayer
from daemon.run.arm.prepare import ArmServices
from daemon.run.arm.setup import (
    ArmSetupError,
    arm_robot,
    check_arm_run,
    check_played_run,
    plays_duty_cycle,
)
from daemon.run.arm.step import ArmStepPipeline
from daemon.run.arm.work import ArmRunWork
from daemon.run.setup import ReferenceCheck, RunParameterError
from daemon.run.start import RunBuilder
from daemon.run.states import RunParameters
from drivers.clock import FollowingClock

logger = logging.getLogger(__name__)


async def build_arm(
    builder: RunBuilder, parameters: RunParameters, check_reference: ReferenceCheck
) -> ArmKind:
    """``check_reference``: the factory's check of a reference run (it knows every kind)."""
    work, arm = await arm_work(builder, parameters, check_reference)
    # a played duty cycle paces a virtual clock: the run's steps follow it
    clock = builder.clock if arm.player is None else FollowingClock(builder.clock)
    devices = builder.devices()
    bench = getattr(devices, "arm_bench", None) or getattr(devices, "bench", None)
    return ArmKind(work, arm, bench, builder.workers, builder.settings, builder.errors, clock)


async def arm_work(
    builder: RunBuilder, parameters: RunParameters, check_reference: ReferenceCheck
) -> tuple[ArmRunWork, ArmServices]:
    """An arm run (issue 20): the arm's model and poses, its robot face, tool meter and
    step pipeline; RunParameterError when the arm run cannot be built."""
    workers, recorder = builder.workers, builder.recorder
    try:
        check_arm_run(builder.settings, parameters.duty_cycle)
        assert parameters.duty_cycle is not None
        plan = await workers.step(builder.arm_setup, builder.settings, parameters)
        robot = arm_robot(builder.devices().robot)
        meter = builder.arm_meter(builder.settings, builder.devices(), workers)
    except (ArmSetupError, ValueError, OSError) as err:
        raise RunParameterError(f"arm run: {err}") from err
    if not plan.poses:
        raise RunParameterError("arm run: the duty cycle has no measured pose")
    played = plays_duty_cycle(builder.settings)
    if played:
        try:
            check_played_run(builder.settings, parameters, plan)
        except ArmSetupError as err:
            raise RunParameterError(f"arm run: {err}") from err
    elif builder.settings.robot.driver != "sim":
        logger.warning(
            "arm run: the duty cycle is not played (arm.play_duty_cycle): the robot moves "
            "to its measured poses only; run the cycle's motion on the controller"
        )
    await workers.db(check_reference, recorder, parameters)
    run_id = await builder.create_run(parameters, plan.snapshot, kind=ArmKind.name)
    sensors = builder.sensors
    assert sensors is not None
    permit = builder.devices().robot.permit
    player = ArmPlayer(robot, plan.cycle, builder.clock, run_id, permit) if played else None
    pipeline = ArmStepPipeline(
        builder.settings,
        robot=robot,
        meter=meter,
        sensors=sensors,
        recorder=recorder,
        workers=workers,
        errors=builder.errors,
        clock_now=builder.clock.now,
        player=player,
    )
    work = ArmRunWork(
        run_id, parameters, plan.predictor, plan.poses, cycle=plan.cycle if played else ()
    )
    return work, ArmServices(robot, meter, pipeline, player)
