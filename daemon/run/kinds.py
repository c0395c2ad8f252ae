"""The one factory of run kinds (issue 27): the only code that chooses what kind a run is.

- a robot that plays its own program (drivers/base.py OffsetRobot, ``robot.driver =
  "ur-rtde"``): a followed run (daemon/run/followed/kind.py), whose duty cycle is the
  program's;
- a duty cycle in the parameters: an arm run (daemon/run/arm/kind.py);
- otherwise the two-link bench's run (daemon/run/two_link/kind.py).

Adding a kind: its package under daemon/run/, and one branch here (docs/explanation/
architecture.md "Run kinds"). Nothing here changes a run's state or starts it.
"""

from __future__ import annotations

from daemon.run.arm.kind import ArmKind
from daemon.run.followed.kind import FollowedKind
from daemon.run.followed.program_pause import ProgramPause
from daemon.run.followed.setup import followed_model
from daemon.run.kind import RunKind
from daemon.run.start import RunBuilder
from daemon.run.states import RunParameters
from daemon.run.two_link.kind import TwoLinkKind
from daemon.run.two_link.step import StepPipeline
from drivers.base import OffsetRobot, ProgramControl
from drivers.clock import FollowingClock


async def build_kind(builder: RunBuilder, parameters: RunParameters) -> RunKind:
    """The run's kind, built (its row created in the run database); RunParameterError when the
    run is not admissible."""
    devices = builder.devices()
    workers, settings, errors = builder.workers, builder.settings, builder.errors
    robot = devices.robot
    if isinstance(robot, OffsetRobot):  # plays its own program: even with a duty cycle
        model = await workers.step(followed_model, settings, parameters)
        run_id = await builder.create_run(parameters, {"kind": "followed"})
        return FollowedKind(
            run_id,
            parameters,
            robot,
            builder.recorder,
            workers,
            settings,
            errors,
            builder.clock,
            model,
            getattr(devices, "ur_truth", None),
            ProgramPause(
                robot if isinstance(robot, ProgramControl) else None,
                enabled=settings.robot.pause_program_on_hold,
                errors=errors,
            ),
        )
    if parameters.duty_cycle is not None:
        arm_work, arm = await builder.arm_work(parameters)
        # a played duty cycle paces a virtual clock: the run's steps follow it
        clock = builder.clock if arm.player is None else FollowingClock(builder.clock)
        bench = getattr(devices, "arm_bench", None) or getattr(devices, "bench", None)
        return ArmKind(arm_work, arm, bench, workers, settings, errors, clock)
    work = await builder.two_link_work(parameters)
    sensors = builder.sensors
    assert sensors is not None
    pipeline = StepPipeline(
        settings,
        robot=robot,
        sensors=sensors,
        recorder=builder.recorder,
        workers=workers,
        errors=errors,
        clock_now=builder.clock.now,
    )
    bench = getattr(devices, "bench", None)
    return TwoLinkKind(
        work, pipeline, robot, sensors, bench, workers, settings, errors, builder.clock
    )
