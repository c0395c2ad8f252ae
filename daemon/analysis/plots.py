"""The report's figures, drawn with matplotlib's object API (no pyplot: no global state, safe
in a worker thread) and rendered by the Agg canvas.

Each figure answers one question a researcher asks after a run, like the thesis's figures:
did the compensation follow the deformation (Figures 6.5-6.7), how much did it remove
(Figure 6.9), are the errors normal (Figure 6.8), how did the link warm up, and did the
steps run on time.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from scipy import stats as scipy_stats

from daemon.analysis.legends import place_legends
from daemon.analysis.statistics import ErrorStatistics
from daemon.analysis.steps import FloatArray, RunSteps

logger = logging.getLogger(__name__)

# Thesis 6.5's colours are not recoverable; these are distinguishable for colour-blind readers.
DEFORMATION_COLOUR = "#d55e00"  # vermilion
COMPENSATION_COLOUR = "#0072b2"  # blue
ERROR_COLOUR = "#000000"
FIT_COLOUR = "#009e73"  # green
FIGURE_SIZE = (10.0, 5.6)  # inches; 100 dpi gives 1000 x 560 px
#: Above twice this many points a time series is drawn as its min/max envelope over this many
#: equal runs of steps: a figure 1000 px wide shows no more, and the extremes (a late step, an
#: error spike) stay visible. Drawing every point of 71,000 steps took 0.2 GiB and seconds
#: per report (benchmarks/bench_run_end.py); an hour at a 20 ms step is 180,000.
PLOT_BUCKETS = 2000


def _figure(rows: int = 1, height: float = FIGURE_SIZE[1]) -> tuple[Figure, list[Axes]]:
    figure = Figure(figsize=(FIGURE_SIZE[0], height), layout="constrained")
    axes = [figure.add_subplot(rows, 1, i + 1) for i in range(rows)]
    for ax in axes:
        ax.grid(True, color="#dddddd", linewidth=0.8)
        ax.tick_params(labelsize=10)
    return figure, axes


def _time_axis(times_s: FloatArray) -> tuple[FloatArray, str]:
    """Seconds for short runs, minutes for long ones: tick labels stay short."""
    span = float(np.nanmax(times_s) - np.nanmin(times_s)) if times_s.size else 0.0
    if span > 2 * 3600:
        return times_s / 3600.0, "time since start (h)"
    if span > 1200:
        return times_s / 60.0, "time since start (min)"
    return times_s, "time since start (s)"


def envelope(
    times: FloatArray, values: FloatArray, buckets: int = PLOT_BUCKETS
) -> tuple[FloatArray, FloatArray]:
    """The points of a series worth drawing: all of them when there are at most
    ``2 * buckets``, else each bucket's smallest and largest value in time order (a bucket
    with no value gives NaN there, so a gap stays a gap)."""
    n = values.size
    if n <= 2 * buckets:
        return times, values
    size = -(-n // buckets)  # steps per bucket, rounded up
    rows = -(-n // size)
    padded = np.concatenate([values, np.full(rows * size - n, np.nan)]).reshape(rows, size)
    finite = np.isfinite(padded)
    # padding and NaN never win; a bucket with no value at all yields its first (NaN) step
    low = np.where(finite, padded, np.inf).argmin(axis=1)
    high = np.where(finite, padded, -np.inf).argmax(axis=1)
    starts = np.arange(rows) * size
    index = np.column_stack([starts + np.minimum(low, high), starts + np.maximum(low, high)])
    chosen = index.ravel()
    return times[chosen], values[chosen]


def _line(ax: Axes, times: FloatArray, values: FloatArray, **style: Any) -> None:
    """A time series on ``ax``: its :func:`envelope`, in the given line style."""
    ax.plot(*envelope(times, values), **style)


def _has_data(*series: FloatArray) -> bool:
    return any(np.isfinite(values).any() for values in series)


def _time_limits(axes: list[Axes], times: FloatArray) -> None:
    """The run's whole time span, even where a series has no value."""
    finite = times[np.isfinite(times)]
    if finite.size and finite.max() > finite.min():
        for ax in axes:
            ax.set_xlim(float(finite.min()), float(finite.max()))


def _no_data(ax: Axes, message: str) -> None:
    ax.text(
        0.5,
        0.5,
        message,
        ha="center",
        va="center",
        transform=ax.transAxes,
        fontsize=12,
        color="#666666",
    )


def plot_compensation(steps: RunSteps, stats: ErrorStatistics | None) -> Figure:
    """Figures 6.5-6.7: deformation input (+), compensation (-) and the error over time.

    The error is a hundred times smaller than the deformation, so it also gets its own panel
    with its mean and +-S_x band, where its shape is visible.
    """
    figure, (top, bottom) = _figure(rows=2, height=7.5)
    times, time_label = _time_axis(steps.time_s)
    deformation, compensation, error = (
        steps.deformation_input_um,
        steps.compensation_um,
        steps.residual_um,
    )
    _line(
        top,
        times,
        deformation,
        color=DEFORMATION_COLOUR,
        linewidth=2,
        label="deformation input (model prediction)",
    )
    _line(
        top,
        times,
        compensation,
        color=COMPENSATION_COLOUR,
        linewidth=2,
        label="compensation (commanded offset)",
    )
    _line(top, times, error, color=ERROR_COLOUR, linewidth=1, label="error (measured residual)")
    top.axhline(0.0, color="#888888", linewidth=0.8)
    if not _has_data(deformation, compensation, error):
        _no_data(top, "no deformation, compensation or error recorded")
    _time_limits([top, bottom], times)
    top.set_title("Deformation, compensation and error along the link axis", fontsize=13)
    top.set_ylabel("displacement (µm)", fontsize=11)
    top.set_xlabel(time_label, fontsize=11)

    sigma = steps.numeric.get("deformation_sigma_um")
    if sigma is not None and np.isfinite(sigma).any():
        # prediction "model+ir" (issue 9): the filter's 1-sigma of the predicted deformation
        for sign, label in ((1.0, "prediction ±1σ (IR observer)"), (-1.0, None)):
            _line(
                bottom,
                times,
                sign * sigma,
                color=DEFORMATION_COLOUR,
                linewidth=1.5,
                linestyle="--",
                label=label,
            )
    _line(
        bottom,
        times,
        error,
        color=ERROR_COLOUR,
        linewidth=1,
        marker=".",
        markersize=3,
        label="error (measured residual)",
    )
    if stats is not None:
        bottom.axhline(
            stats.mean, color=FIT_COLOUR, linewidth=1.5, label=f"mean {stats.mean:+.3f} µm"
        )
        bottom.axhspan(
            stats.mean - stats.std,
            stats.mean + stats.std,
            color=FIT_COLOUR,
            alpha=0.12,
            label=f"mean ± S_x ({stats.std:.3f} µm)",
        )
    else:
        _no_data(bottom, "no measured error in this run")
    bottom.set_title("Error alone (zoomed)", fontsize=12)
    bottom.set_ylabel("error (µm)", fontsize=11)
    bottom.set_xlabel(time_label, fontsize=11)
    place_legends(figure, [top, bottom])
    return figure


def plot_compensated_vs_uncompensated(
    steps: RunSteps,
    summary: Mapping[str, float | int | str | None],
    reference: RunSteps | None = None,
) -> Figure:
    """Figure 6.9: where the tool would have gone without compensation against where it went.
    The uncompensated curve is *measured* (the uncompensated ``reference`` run's error, on
    its own time axis) when there is one; otherwise it is the model's prediction, and its
    label says so (the thesis plotted the prediction; a wrong model then looks good)."""
    figure, (ax,) = _figure()
    times, time_label = _time_axis(steps.time_s)
    if reference is not None:
        reference_times, _ = _time_axis(reference.time_s)
        if times.size and np.isfinite(steps.time_s).any():  # the same unit as this run's axis
            reference_times = reference.time_s * (
                np.nanmax(times) / np.nanmax(steps.time_s) if np.nanmax(steps.time_s) else 1.0
            )
        _line(
            ax,
            reference_times,
            reference.residual_um,
            color=DEFORMATION_COLOUR,
            linewidth=2,
            label=f"uncompensated (measured: run {summary.get('reference_run')}, compensation off)",
        )
        _line(
            ax,
            times,
            steps.deformation_input_um,
            color="#888888",
            linewidth=1,
            linestyle="--",
            label="the model's predicted deformation",
        )
    else:
        _line(
            ax,
            times,
            steps.deformation_input_um,
            color=DEFORMATION_COLOUR,
            linewidth=2,
            label="uncompensated (predicted by the model: no reference run)",
        )
    _line(
        ax,
        times,
        steps.residual_um,
        color=COMPENSATION_COLOUR,
        linewidth=1.5,
        label="compensated (measured error)",
    )
    ax.axhline(0.0, color="#888888", linewidth=0.8)
    if not _has_data(steps.deformation_input_um, steps.residual_um):
        _no_data(ax, "no predicted deformation or measured error recorded")
    _time_limits([ax], times)
    lines = []
    if summary.get("uncompensated_max_um") is not None:
        lines.append(f"predicted max: {summary['uncompensated_max_um']:.1f} µm")
    if summary.get("reduction_basis") == "drift":
        if summary.get("measured_drift_max_um") is not None:
            lines.append(f"measured drift max (off): {summary['measured_drift_max_um']:.2f} µm")
    elif summary.get("residual_max_um") is not None:
        lines.append(f"compensated max |error|: {summary['residual_max_um']:.2f} µm")
    if summary.get("reference_max_um") is not None:
        lines.append(
            f"run {summary.get('reference_run')} (off) drift max: "
            f"{summary['reference_max_um']:.2f} µm"
        )
    if summary.get("reduction_percent") is not None:
        lines.append(f"reduction (measured): {summary['reduction_percent']:.1f} %")
    if summary.get("reduction_vs_prediction_percent") is not None:
        lines.append(f"vs prediction: {summary['reduction_vs_prediction_percent']:.1f} %")
    if lines:
        ax.text(
            0.98,
            0.5,
            "\n".join(lines),
            transform=ax.transAxes,
            ha="right",
            va="center",
            fontsize=11,
            bbox={"facecolor": "white", "edgecolor": "#999999"},
        )
    ax.set_title("Deformation of the compensated and uncompensated system", fontsize=13)
    ax.set_ylabel("displacement of the tool (µm)", fontsize=11)
    ax.set_xlabel(time_label, fontsize=11)
    place_legends(figure, [ax])
    return figure


def plot_error_histogram(stats: ErrorStatistics | None) -> Figure:
    """Figure 6.8: the error histogram over K intervals with the fitted normal curve."""
    figure, (ax,) = _figure()
    ax.set_title("Distribution of the compensation error", fontsize=13)
    ax.set_xlabel("error (µm)", fontsize=11)
    ax.set_ylabel("number of steps", fontsize=11)
    if stats is None:
        _no_data(ax, "no measured error in this run")
        return figure
    test = stats.chi_squared
    if test is None:
        _no_data(ax, f"no histogram: {stats.note}")
        return figure
    edges = np.asarray(test.edges)
    widths = np.diff(edges)
    ax.bar(
        edges[:-1],
        test.observed,
        width=widths,
        align="edge",
        color="#a6cee3",
        edgecolor="#1f4e79",
        label="observed count n_j",
    )
    centres = edges[:-1] + widths / 2
    ax.plot(
        centres,
        test.expected,
        linestyle="none",
        marker="o",
        color=DEFORMATION_COLOUR,
        label="expected count n'_j (normal)",
    )
    x = np.linspace(edges[0] - widths[0], edges[-1] + widths[-1], 300)
    density = scipy_stats.norm.pdf(x, stats.mean, stats.std) * stats.n * float(widths.mean())
    ax.plot(
        x,
        density,
        color=DEFORMATION_COLOUR,
        linewidth=1.5,
        label="normal curve, sample mean and S_x",
    )
    verdict = "consistent with normal" if test.p_value >= 0.05 else "NOT normal (p < 0.05)"
    text = (
        f"N = {stats.n}, K = {stats.intervals}\n"
        f"mean = {stats.mean:+.3f} µm\n"
        f"S_x = {stats.std:.3f} µm, S_x/√N = {stats.std_of_mean:.3f} µm\n"
        f"χ² = {test.chi_squared:.2f}, ν = {test.degrees_of_freedom}\n"
        f"p (upper tail) = {test.p_value:.3f}: {verdict}\n"
        f"thesis's lower-tail reading: {test.thesis_lower_tail_p:.3f}"
    )
    ax.text(
        0.02,
        0.97,
        text,
        transform=ax.transAxes,
        ha="left",
        va="top",
        fontsize=10,
        bbox={"facecolor": "white", "edgecolor": "#999999"},
    )
    # Headroom above the tallest bar keeps the text box and legend off the bars.
    tallest = max(*test.observed, float(density.max()))
    ax.set_ylim(0, 1.5 * tallest)
    place_legends(figure, [ax])
    return figure


def plot_temperatures(steps: RunSteps) -> Figure:
    """Measured region temperatures (thick, in the legend) and, when recorded, the model's
    nodes (thin dashed, coloured by their order along the link, with a colour bar)."""
    figure, (ax,) = _figure()
    times, time_label = _time_axis(steps.time_s)
    regions = {r: v for r, v in steps.ir_mean_c.items() if np.isfinite(v).any()}
    nodes = {n: v for n, v in steps.model_temperatures_c.items() if np.isfinite(v).any()}
    region_colours = ("#000000", "#d55e00", "#0072b2", "#009e73", "#cc79a7", "#e69f00")
    for i, (region, series) in enumerate(regions.items()):
        colour = region_colours[i % len(region_colours)]
        _line(ax, times, series, color=colour, linewidth=2.5, label=f"IR region {region} (mean)")
    if nodes:
        # Many nodes: a sequential colour map shows where along the link each one is.
        colour_map = colormaps["viridis"]
        norm = Normalize(vmin=1, vmax=max(len(nodes), 2))
        for i, series in enumerate(nodes.values(), start=1):
            _line(ax, times, series, color=colour_map(norm(i)), linewidth=1, linestyle="--")
        bar = figure.colorbar(ScalarMappable(norm=norm, cmap=colour_map), ax=ax, pad=0.01)
        names = list(nodes)
        ticks = sorted({1, len(names), *range(1, len(names) + 1, max(1, len(names) // 8))})
        bar.set_ticks(ticks, labels=[names[t - 1] for t in ticks])
        bar.set_label("model node (dashed lines)", fontsize=10)
    if not regions and not nodes:
        _no_data(ax, "no temperatures recorded in this run")
    _time_limits([ax], times)
    ax.set_title("Link temperatures", fontsize=13)
    ax.set_ylabel("temperature (°C)", fontsize=11)
    ax.set_xlabel(time_label, fontsize=11)
    place_legends(figure, [ax])
    return figure


def plot_lateness(steps: RunSteps) -> Figure:
    """How late each step started after its scheduled time; late-flagged steps in red."""
    figure, (ax,) = _figure(height=4.5)
    times, time_label = _time_axis(steps.time_s)
    lateness = steps.numeric.get("lateness_s")
    ax.set_title("Step lateness (start after the scheduled time)", fontsize=13)
    ax.set_xlabel(time_label, fontsize=11)
    if lateness is None or not np.isfinite(lateness).any():
        ax.set_ylabel("lateness (ms)", fontsize=11)
        _no_data(ax, "no step timing recorded")
        return figure
    _time_limits([ax], times)
    lateness_ms = lateness * 1000.0
    late = np.array(["late" in flags for flags in steps.flags], dtype=bool)
    _line(
        ax,
        times,
        lateness_ms,
        color=COMPENSATION_COLOUR,
        linewidth=1,
        marker=".",
        markersize=3,
        label="lateness",
    )
    if late.any():
        _line(
            ax,
            times[late],
            lateness_ms[late],
            linestyle="none",
            marker="o",
            color="#cc0000",
            label=f"flagged late ({int(late.sum())} steps)",
        )
    finite = lateness_ms[np.isfinite(lateness_ms)]
    ax.axhline(
        float(np.median(finite)),
        color="#888888",
        linestyle=":",
        label=f"median {float(np.median(finite)):.2f} ms",
    )
    ax.set_ylabel("lateness (ms)", fontsize=11)
    place_legends(figure, [ax])
    return figure
