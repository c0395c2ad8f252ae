"""How the dashboard shows a followed run (daemon/run/kind.py KindView): the arm's plots over
the program's hours, but no rotation (a UR followed by its joint temperatures: the bench's truth
gives the tool's 3-D drift only), no adapted factors and no reference run (the model's cold
state at the start is the reference: daemon/run/followed/kind.py ``references``)."""

from __future__ import annotations

from daemon.run.arm.view import TOOL_PLOTS
from daemon.run.kind import KindView

NAME = "followed"

VIEW = KindView(
    name=NAME,
    form_title="Start a run following the robot's own program",
    form_fields=("duty_cycle",),
    plots=TOOL_PLOTS,
    series="poses",
    time_axis="model-hours",
    x_label="program time (h)",
    temperature_x_label="program time (h)",
    group_temperatures=True,
    rotation_measured=False,
    adaptation=False,
    reference_runs=False,
    reference_kinds=(),
    what_text="followed: {duty_cycle}",
    model_text="",
    doing_text="the robot's own program ({duty_cycle} duty cycle), followed",
    reference_text="{duty_cycle}",
    scaled_time_text="of the program",
)
