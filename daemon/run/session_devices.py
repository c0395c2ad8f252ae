"""What a run's session does to the devices outside a step: teach the run's goals, start the
simulated bench cold, take the two-link bench's reference frame, start and stop a played duty
cycle -- for the two-link bench and for an arm run (issue 20; its poses: daemon/run/arm/prepare.py).

RunSession (daemon/run/session.py) calls these at the points of its prepare -> loop -> finish and
decides what their errors do: nothing here changes the run's state (issue 15). They may change
the run's work (its goal, its references), which is data, not state.
"""

from __future__ import annotations

import functools
import logging

from daemon.run.arm.prepare import teach_poses
from daemon.run.arm.step import ArmRunWork
from daemon.run.services import SessionServices
from daemon.run.two_link.step import RunWork
from daemon.vision import CentroidError, measure_with_camera_settings
from drivers.errors import DeviceError
from drivers.permit import Ticket

logger = logging.getLogger(__name__)


async def teach_goals(
    work: RunWork | ArmRunWork, services: SessionServices, *, moving: bool
) -> None:
    """Teach the run's goals: the two-link bench's goal where the robot stands (no motion:
    before the start's resume); an arm run's measured poses, each reached by a move (so
    after the resume, and refused by the driver after any hold). Raises DeviceError."""
    if isinstance(work, ArmRunWork):
        if moving:
            await teach_poses(work, services.arm_services().robot)
    elif not moving:
        work.goal = await services.robot.teach_goal()


async def start_bench(work: RunWork | ArmRunWork, services: SessionServices) -> None:
    """The simulated bench, when there is one, starts cold with this run."""
    parameters = work.parameters
    if isinstance(work, ArmRunWork):
        # the simulated arm (drivers/sim/arm_bench.py), built on a worker thread: it takes a
        # second
        start = getattr(services.bench, "start_arm_run", None)
        if start is not None:
            await services.workers.step(
                functools.partial(start, services.clock.now(), duty_cycle=parameters.duty_cycle)
            )
    elif services.bench is not None:
        # the simulated links start cold with this run, at its scale and procedure: the truth
        # built on a worker thread (0.25-0.55 s under load, which on the event loop held up
        # every hold behind it; issue 26), the spot aligned on the loop, where the emulated
        # robot lives. Nothing reads the bench until the reference frame.
        bench = services.bench
        start = functools.partial(
            bench.start_run,
            services.clock.now(),
            deformation_scale=parameters.deformation_scale,
            procedure=parameters.procedure,
            heater_off_s=parameters.heater_off_s,
        )
        build, align = getattr(bench, "build_run", None), getattr(bench, "align_spot", None)
        if build is None or align is None:
            start()  # a bench with no split (a test's)
            return
        await services.workers.step(functools.partial(build, *start.args, **start.keywords))
        align()


async def capture_reference(work: RunWork, services: SessionServices) -> None:
    """The spot at the operational goal before the first move: the zero of every drift.

    Thesis 6.2 sets the centroid "at the start at the operational goal". Taken here, the
    robot has not moved since the goal was taught, so the reference carries no positioning
    error. If no frame can be had, step 0's centroid is used."""
    try:
        frame = await services.sensors.grab()
        result = await services.workers.step(
            measure_with_camera_settings, frame.image, services.settings.camera
        )
    except (DeviceError, CentroidError) as err:
        if isinstance(err, DeviceError):
            services.errors.note(err)
        logger.warning("run %d: no reference frame (%s): step 0 is the reference", work.run_id, err)
        return
    work.reference_um[0] = (result.x_um, result.y_um)
    work.reference_source = "goal before the first move"


def play_duty_cycle(services: SessionServices, grant: Ticket) -> None:
    """Start a played duty cycle (daemon/run/arm/player.py; from the pose after the last one
    reached) on behalf of the request that holds ``grant``: it plays until a hold comes after
    that request. The player changes no state: its errors come back through the next step."""
    arm = services.arm
    player = None if arm is None else arm.player
    if player is not None:
        player.start(grant)


async def stop_duty_cycle(services: SessionServices) -> None:
    """Stop a played duty cycle: the run pauses, faults or ends."""
    arm = services.arm
    player = None if arm is None else arm.player
    if player is not None:
        await player.stop(services.settings.scheduler.stop_grace_s)
