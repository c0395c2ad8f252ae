"""How the dashboard shows an arm run (daemon/run/kind.py KindView): the tool's 3-D drift and
rotation error per measured pose (poses share no series, so no line zig-zags between them), the
predicted tool error and the commanded correction per pose, the temperatures per link and
joint, over the hours of the arm's warm-up (a run's time scale; thesis chapter 7)."""

from __future__ import annotations

from daemon.run.kind import KindView, PlotSlot

NAME = "arm"

#: The tool's plots, shared with the kinds that measure a tool the same way.
TOOL_PLOTS = (
    PlotSlot(slot="drift3d", title="3-D drift of the tool per measured pose (µm)"),
    PlotSlot(slot="rotation", title="Rotation error of the tool per measured pose (µrad)"),
    PlotSlot(slot="predicted", title="Predicted tool error |translation| per pose (µm)"),
    PlotSlot(slot="offset", title="Commanded correction |translation| per pose (µm)"),
    PlotSlot(
        slot="temperature",
        title="Temperatures (°C): mean per link and joint (model, dashed), IR regions solid",
    ),
)

VIEW = KindView(
    name=NAME,
    form_title="Start an arm run",
    form_fields=("duty_cycle", "arm_model"),
    plots=TOOL_PLOTS,
    series="poses",
    time_axis="model-hours",
    x_label="arm time (h)",
    temperature_x_label="arm time (h)",
    group_temperatures=True,
    rotation_measured=True,
    adaptation=True,
    reference_runs=True,
    reference_kinds=(NAME,),
    what_text="arm: {duty_cycle}",
    model_text=", model {arm_model}",
    doing_text="the arm's {duty_cycle} duty cycle",
    reference_text="{duty_cycle}",
    scaled_time_text="of arm",
)
