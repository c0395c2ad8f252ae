"""The two-link bench's run built (daemon/run/kinds.py chose it): its model, checked scale,
reference run and observer (daemon/run/setup.py), its row in the run database, its step
pipeline. RunParameterError when the run is not admissible."""

from __future__ import annotations

import logging

from daemon.run.setup import (
    ReferenceCheck,
    build_model,
    build_observer,
    check_admissible_scale,
    network_snapshot,
    unit_vector,
)
from daemon.run.start import RunBuilder
from daemon.run.states import RunParameters
from daemon.run.two_link.kind import TwoLinkKind
from daemon.run.two_link.step import StepPipeline
from daemon.run.two_link.work import RunWork

logger = logging.getLogger(__name__)


async def build_two_link(
    builder: RunBuilder, parameters: RunParameters, check_reference: ReferenceCheck
) -> TwoLinkKind:
    """``check_reference``: the factory's check of a reference run (it knows every kind)."""
    work = await two_link_work(builder, parameters, check_reference)
    sensors = builder.sensors
    assert sensors is not None
    robot = builder.devices().robot
    pipeline = StepPipeline(
        builder.settings,
        robot=robot,
        sensors=sensors,
        recorder=builder.recorder,
        workers=builder.workers,
        errors=builder.errors,
        clock_now=builder.clock.now,
    )
    bench = getattr(builder.devices(), "bench", None)
    return TwoLinkKind(
        work,
        pipeline,
        robot,
        sensors,
        bench,
        builder.workers,
        builder.settings,
        builder.errors,
        builder.clock,
    )


async def two_link_work(
    builder: RunBuilder, parameters: RunParameters, check_reference: ReferenceCheck
) -> RunWork:
    """The two-link bench's run: its model, checked scale, reference run and observer."""
    workers, recorder = builder.workers, builder.recorder
    built = await workers.step(build_model, builder.settings, parameters)
    parameters, network, model = built.parameters, built.network, built.model
    logger.info("run heat: %s (from %s)", parameters.heat_w, built.heat_source)
    direction = unit_vector(builder.settings.model.direction)
    await workers.step(check_admissible_scale, builder.settings, parameters, network, direction)
    await workers.db(check_reference, recorder, parameters)
    observer = None
    if parameters.prediction == "model+ir":
        reader_regions = tuple(getattr(builder.devices().ir, "regions", ()) or ())
        observer = build_observer(builder.settings, model, reader_regions)
    run_id = await builder.create_run(
        parameters, network_snapshot(network, built.heat_source), kind=TwoLinkKind.name
    )
    return RunWork(run_id, parameters, model, direction, observer)
