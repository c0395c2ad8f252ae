"""An arm run's report figures (issue 28): the tool's 3-D drift and rotation error per
measured pose over the hours of the arm's warm-up, each with its measurement noise band and,
when a reference run is named, that uncompensated run's measured drift beside it; and the
temperatures as one mean per link and joint. Matplotlib's object API (no pyplot: safe in a
worker thread).

Each pose is its own series: the poses share no line, since the drift at one pose says nothing
about the drift at the next (the arm's configuration differs), and joining them zig-zags.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from daemon.analysis.legends import place_legends
from daemon.analysis.steps import FloatArray, RunSteps

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

#: One colour per measured pose (Okabe-Ito: distinguishable for colour-blind readers).
POSE_COLOURS = ("#0072b2", "#d55e00", "#009e73", "#cc79a7", "#e69f00", "#56b4e9", "#000000")
#: The measured IR regions: dark and thick, apart from the model's dashed colours.
IR_COLOURS = ("#000000", "#7f7f7f", "#5b3a29")
SECONDS_PER_HOUR = 3600.0
#: The noise band: this many measurement sigmas each side of a measured point.
NOISE_BAND_SIGMAS = 1.0


def arm_time(steps: RunSteps) -> tuple[FloatArray, str]:
    """The hours of the arm's warm-up (the model's clock: run time x time scale), else run
    seconds when the model time was not recorded."""
    model = steps.numeric.get("model_time_s")
    if model is not None and np.isfinite(model).any():
        hours: FloatArray = model / SECONDS_PER_HOUR
        return hours, "time of the arm's warm-up (h)"
    return steps.time_s, "run time (s)"


def _column(steps: RunSteps, name: str) -> FloatArray:
    return steps.numeric.get(name, np.full(steps.n_steps, np.nan))


def _pose_masks(steps: RunSteps) -> list[tuple[str, np.ndarray]]:
    names = steps.poses if len(steps.poses) == steps.n_steps else ("tool",) * steps.n_steps
    labels = np.array([name or "tool" for name in names], dtype=object)
    return [(str(pose), labels == pose) for pose in dict.fromkeys(labels.tolist())]


def _norm(steps: RunSteps, prefix: str, unit: str, axes: Sequence[str]) -> FloatArray:
    columns = [steps.numeric.get(f"{prefix}_{axis}_{unit}") for axis in axes]
    present = [column for column in columns if column is not None]
    if len(present) != len(columns):
        return np.full(steps.n_steps, np.nan)
    norms: FloatArray = np.linalg.norm(np.column_stack(present), axis=1)
    return norms


def _figure(height: float = 5.0) -> tuple[Figure, Axes]:
    from matplotlib.figure import Figure

    figure = Figure(figsize=(10.0, height), layout="constrained")
    ax = figure.add_subplot(1, 1, 1)
    ax.grid(True, color="#dddddd", linewidth=0.8)
    return figure, ax


def draw_arm_error(
    steps: RunSteps,
    *,
    what: str,
    reference: RunSteps | None = None,
    reference_run: int | str | None = None,
) -> Figure:
    """``what`` "drift" (the 3-D drift, µm) or "rotation" (the rotation error, µrad): per
    measured pose, the points joined in time, a ±1σ band of the measurement's own noise, the
    reference run's measured drift at the same pose dashed, and (drift) the model's predicted
    tool error dotted."""
    column, sigma, unit, title = {
        "drift": ("drift_3d_um", "measured_sigma_um", "µm", "3-D drift of the tool"),
        "rotation": (
            "rotation_error_urad",
            "measured_rotation_sigma_urad",
            "µrad",
            "Rotation error of the tool",
        ),
    }[what]
    figure, ax = _figure()
    hours, label = arm_time(steps)
    values, noise = _column(steps, column), _column(steps, sigma)
    predicted = (
        _norm(steps, "predicted", "um", ("tx", "ty", "tz"))
        if what == "drift"
        else _norm(steps, "predicted", "urad", ("rx", "ry", "rz"))
    )
    colours: dict[str, str] = {}
    for k, (pose, mask) in enumerate(_pose_masks(steps)):
        colour = colours.setdefault(pose, POSE_COLOURS[k % len(POSE_COLOURS)])
        x, y, s = hours[mask], values[mask], noise[mask] * NOISE_BAND_SIGMAS
        ax.plot(x, y, "o-", color=colour, linewidth=2, markersize=4, label=f"{pose}: measured")
        if np.isfinite(s).any():
            ax.fill_between(x, y - s, y + s, color=colour, alpha=0.15, linewidth=0)
        if np.isfinite(predicted[mask]).any():
            ax.plot(x, predicted[mask], ":", color=colour, linewidth=1.2)
    if reference is not None:
        ref_hours, _ = arm_time(reference)
        ref_values = _column(reference, column)
        for k, (pose, mask) in enumerate(_pose_masks(reference)):
            colour = colours.get(pose, POSE_COLOURS[k % len(POSE_COLOURS)])
            ax.plot(
                ref_hours[mask],
                ref_values[mask],
                "s--",
                color=colour,
                linewidth=1.2,
                markersize=3,
                label=f"{pose}: run {reference_run} uncompensated (measured)",
            )
    ax.axhline(0.0, color="#888888", linewidth=0.8)
    ax.set_title(
        f"{title} per measured pose; band: ±1σ of the measurement"
        + ("; dotted: the model's prediction" if what == "drift" else ""),
        fontsize=12,
    )
    ax.set_ylabel(f"{'|drift|' if what == 'drift' else '|rotation error|'} ({unit})")
    ax.set_xlabel(label)
    place_legends(figure, [ax])
    return figure


def draw_arm_temperatures(steps: RunSteps) -> Figure:
    """One line per link and joint (the mean of its model nodes, dashed; an arm's ~70 nodes
    are named link.segment±) and every IR region (thick)."""
    figure, ax = _figure(height=4.6)
    hours, label = arm_time(steps)
    groups: dict[str, list[FloatArray]] = {}
    for node, series in steps.model_temperatures_c.items():
        groups.setdefault(node.split(".")[0], []).append(series)
    for k, (group, members) in enumerate(groups.items()):
        stacked = np.vstack(members)
        counts = np.isfinite(stacked).sum(axis=0)
        sums = np.nan_to_num(stacked).sum(axis=0)
        mean = np.divide(sums, counts, out=np.full(counts.shape, np.nan), where=counts > 0)
        colour = POSE_COLOURS[k % len(POSE_COLOURS)]
        style = "-." if k >= len(POSE_COLOURS) else "--"
        ax.plot(hours, mean, style, color=colour, linewidth=1.2, label=group)
    for k, (region, series) in enumerate(steps.ir_mean_c.items()):
        colour = IR_COLOURS[k % len(IR_COLOURS)]
        ax.plot(hours, series, "-", color=colour, linewidth=2.5, label=f"IR {region}")
    ax.set_title("Temperatures: mean per link and joint (model), IR regions (measured)")
    ax.set_ylabel("temperature (°C)")
    ax.set_xlabel(label)
    place_legends(figure, [ax], fontsize=8)
    return figure
