"""How the dashboard shows a followed run (daemon/run/kind.py KindView): the arm's plots over
the program's hours, one series per measured pose (the program's at-pose register; "tool"
while it moves). The 3-D drift is the tool cameras' residual at the first step of each dwell
and, on the UR bench, the truth's residual at every other step; the rotation error is the
cameras' only (daemon/run/followed/measure.py: a run with no camera leaves it empty). No
adapted factors and no reference run (the model's cold state at the start is the reference:
daemon/run/followed/kind.py ``references``)."""

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
    rotation_measured=True,
    adaptation=False,
    reference_runs=False,
    reference_kinds=(),
    what_text="followed: {duty_cycle}",
    model_text="",
    doing_text="the robot's own program ({duty_cycle} duty cycle), followed",
    reference_text="{duty_cycle}",
    scaled_time_text="of the program",
)
