"""A followed run built (daemon/run/kinds.py chose it: the robot plays its own program): the
arm's model of that program (daemon/run/followed/setup.py), the run's row in the run database,
the bench truth when the UR bench is simulated, and the pause of the robot's program on a
hold (robot.pause_program_on_hold: daemon/run/followed/program_pause.py). RunParameterError
when it cannot be built."""

from __future__ import annotations

from daemon.run.followed.kind import FollowedKind, FollowedWork
from daemon.run.followed.program_pause import ProgramPause
from daemon.run.followed.setup import followed_model
from daemon.run.start import RunBuilder
from daemon.run.states import RunParameters
from drivers.base import OffsetRobot, ProgramControl


async def build_followed(
    builder: RunBuilder, parameters: RunParameters, robot: OffsetRobot
) -> FollowedKind:
    model = await builder.workers.step(followed_model, builder.settings, parameters)
    run_id = await builder.create_run(
        parameters, {"kind": FollowedKind.name}, kind=FollowedKind.name
    )
    return FollowedKind(
        FollowedWork(run_id, parameters),
        robot,
        builder.recorder,
        builder.workers,
        builder.settings,
        builder.errors,
        builder.clock,
        model,
        getattr(builder.devices(), "ur_truth", None),
        ProgramPause(
            robot if isinstance(robot, ProgramControl) else None,
            enabled=builder.settings.robot.pause_program_on_hold,
            errors=builder.errors,
        ),
    )
