"""How the dashboard shows a two-link run (daemon/run/kind.py KindView): the spot's measured
error and the model's per-axis prediction and offset over the run clock (thesis 6.2), the 17
nodes of the thesis network one series each."""

from __future__ import annotations

from daemon.run.kind import KindView, PlotSlot

NAME = "two-link"

VIEW = KindView(
    name=NAME,
    form_title="Start a two-link run",
    form_fields=("procedure", "network", "deformation_scale", "heater_off_s"),
    plots=(
        PlotSlot(
            slot="residual",
            title="Measured error of the tool, compensated (µm)",
            title_uncompensated="Measured drift of the tool, compensation off (µm)",
        ),
        PlotSlot(slot="predicted", title="Predicted deformation (µm)"),
        PlotSlot(slot="offset", title="Commanded compensation (µm)"),
        PlotSlot(
            slot="temperature",
            title="Temperatures (°C): model nodes dashed, IR regions solid",
        ),
    ),
    series="axes",
    time_axis="run",
    x_label="run time (s)",
    temperature_x_label="run time (s)",
    group_temperatures=False,
    rotation_measured=False,
    adaptation=False,
    reference_runs=True,
    reference_kinds=(NAME,),
    what_text="two-link: {procedure}",
    model_text=", {network}",
    doing_text="a {procedure} two-link run",
    reference_text="{procedure}",
    scaled_time_text=None,
)
