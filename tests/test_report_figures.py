"""The report's figures hide nothing and read in a person's order (issue 21): no legend box
touches a plotted line, text box or bar; IR regions and model nodes come in natural order
(node-2 before node-16); a virtual clock's flat lateness figure becomes a line saying why;
the page cites only what a reader has."""

from __future__ import annotations

import html
import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.container import BarContainer
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from matplotlib.lines import Line2D

from daemon.analysis import error_statistics, steps_from_rows, summarize_run, write_report
from daemon.analysis.plots import (
    plot_compensated_vs_uncompensated,
    plot_compensation,
    plot_error_histogram,
    plot_lateness,
    plot_temperatures,
)
from daemon.storage.recorder import Recorder, StepRecord
from tests.test_analysis_report import synthetic_rows

#: Points per segment where the check samples a line between its vertices (display pixels
#: are ~1; a legend box is > 20 px tall, so no crossing slips between two samples).
SEGMENT_SAMPLES = 64
REGIONS = ("node-16", "node-2", "node-10", "base")  # alphabetically node-10 < node-16 < node-2


def _figures(rows: list[dict[str, Any]]) -> dict[str, Figure]:
    steps = steps_from_rows(rows)
    stats = error_statistics(steps.residual_um)
    summary = summarize_run(steps)
    return {
        "compensation": plot_compensation(steps, stats),
        "compensated_vs_uncompensated": plot_compensated_vs_uncompensated(steps, summary),
        "error_histogram": plot_error_histogram(stats),
        "temperatures": plot_temperatures(steps),
        "lateness": plot_lateness(steps),
    }


def _display_points(line: Line2D) -> np.ndarray:
    """The line's vertices and points sampled along each segment between finite vertices,
    in display pixels."""
    xy = np.asarray(line.get_xydata(), dtype=float)
    points = line.get_transform().transform(xy)
    finite = np.isfinite(points).all(axis=1)
    samples = [points[finite]]
    if line.get_linestyle() not in ("None", "none", "", " "):
        both = finite[:-1] & finite[1:]
        starts, ends = points[:-1][both], points[1:][both]
        fractions = np.linspace(0.0, 1.0, SEGMENT_SAMPLES)[:, None, None]
        samples.append((starts + fractions * (ends - starts)).reshape(-1, 2))
    return np.concatenate(samples)


def _hidden_by(ax: Axes, legend: Legend) -> list[str]:
    box = legend.get_window_extent()
    hidden = []
    for line in ax.get_lines():
        points = _display_points(line)
        inside = (
            (points[:, 0] >= box.x0)
            & (points[:, 0] <= box.x1)
            & (points[:, 1] >= box.y0)
            & (points[:, 1] <= box.y1)
        )
        if inside.any():
            hidden.append(f"line {line.get_label()!r} ({int(inside.sum())} points)")
    for text in ax.texts:
        if text.get_text() and text.get_window_extent().overlaps(box):
            hidden.append(f"text {text.get_text()[:30]!r}")
    for container in ax.containers:
        if isinstance(container, BarContainer):
            for bar in container.patches:
                if bar.get_window_extent().overlaps(box):
                    hidden.append(f"bar at {bar.get_x():.3g}")
    return hidden


def _noisy_rows() -> list[dict[str, Any]]:
    """A run whose error fills its panel edge to edge and whose curves cross the middle:
    no inside spot is free on the error panel, so the legend must go outside."""
    rows = synthetic_rows(seed=3)
    rng = np.random.default_rng(7)
    for row in rows:
        noise = float(rng.uniform(-3.0, 3.0))
        row["residual_um"] = noise
        row["drift_x_um"] = noise
    return rows


@pytest.mark.slow
@pytest.mark.parametrize("rows", [synthetic_rows(), _noisy_rows()], ids=["thesis", "noisy"])
def test_no_legend_hides_a_line_text_or_bar(rows: list[dict[str, Any]]) -> None:
    figures = _figures(rows)
    legends = 0
    for name, figure in figures.items():
        figure.draw_without_rendering()  # the layout a saved PNG has
        for ax in figure.axes:
            legend = ax.get_legend()
            if legend is None:
                continue
            legends += 1
            assert _hidden_by(ax, legend) == [], f"{name}: legend over {_hidden_by(ax, legend)}"
    assert legends >= 5  # two compensation panels, figure 6.9, histogram, temperatures


@pytest.mark.slow
def test_a_legend_with_no_free_corner_goes_outside_the_axes() -> None:
    figure = _figures(_noisy_rows())["compensation"]
    figure.draw_without_rendering()
    error_panel = figure.axes[1]
    legend = error_panel.get_legend()
    assert legend is not None
    # the noise spans the whole panel, so the legend sits right of it, not over it
    assert legend.get_window_extent().x0 >= error_panel.get_window_extent().x1


def _region_rows(n: int = 40) -> list[dict[str, Any]]:
    rows = []
    for step in range(n):
        t = step * 30.0
        ir = {
            r: {"mean_c": 22 + (i + 1) * (1 - math.exp(-t / 300)), "max_c": 30.0}
            for i, r in enumerate(REGIONS)
        }
        model = {str(node): 22 + node * (1 - math.exp(-t / 300)) for node in (16, 2, 10, 1)}
        rows.append(
            {
                "run_id": 1,
                "step": step,
                "scheduled_s": t,
                "lateness_s": 0.0,
                "predicted_x_um": 100 * (1 - math.exp(-t / 300)),
                "residual_um": math.sin(step),
                "ir_json": json.dumps(ir),
                "model_temperatures_json": json.dumps(model),
            }
        )
    return rows


@pytest.mark.slow
def test_ir_regions_and_nodes_come_in_natural_order(tmp_path: Path) -> None:
    steps = steps_from_rows(_region_rows())
    natural = ["base", "node-2", "node-10", "node-16"]
    assert list(steps.ir_mean_c) == natural
    assert list(steps.ir_max_c) == natural
    assert list(steps.model_temperatures_c) == ["1", "2", "10", "16"]
    legend = plot_temperatures(steps).axes[0].get_legend()
    assert legend is not None
    labels = [text.get_text() for text in legend.get_texts()]
    assert labels == [f"IR region {r} (mean)" for r in natural]
    files = write_report(_region_rows(), tmp_path)
    summary = json.loads(files.summary.read_text(encoding="utf-8"))
    fitted = [k for k in summary["fits"] if k.startswith("ir_")]
    assert fitted == [f"ir_{r}_mean_c" for r in natural]


@pytest.mark.slow
def test_a_zero_lateness_run_gets_a_line_not_an_empty_figure(tmp_path: Path) -> None:
    files = write_report(_region_rows(), tmp_path)
    assert "lateness" not in files.plots and not (tmp_path / "lateness.png").exists()
    page = files.html.read_text(encoding="utf-8")
    assert re.search(r'<p class="note">Every step started exactly.*virtual clock', page)
    # a measured lateness keeps its figure, unless the settings say the clock was virtual
    rows = synthetic_rows()
    assert "lateness" in write_report(rows, tmp_path / "real").plots
    virtual = write_report(rows, tmp_path / "virtual", clock="virtual")
    assert "lateness" not in virtual.plots
    assert 'bench.clock = "virtual"' in html.unescape(virtual.html.read_text(encoding="utf-8"))


@pytest.mark.slow
def test_the_report_command_reads_the_runs_clock_from_its_settings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from api.cli import main

    data_dir = tmp_path / "data"
    rows = synthetic_rows()  # a measured lateness: only the recorded settings say "virtual"
    with Recorder(data_dir) as recorder:
        ids = []
        for clock in ("virtual", "real"):
            run_id = recorder.create_run({}, {"bench": {"clock": clock}}, None, "test")
            for row in rows:
                recorder.write_step(StepRecord(**{**row, "run_id": run_id}))
            recorder.finish_run(run_id, "finished", dict(summarize_run(rows)), None)
            ids.append(run_id)
    monkeypatch.setenv("THERMOCOMP_STORAGE__DATA_DIR", str(data_dir))
    pages = []
    for run_id in ids:
        assert main(["report", str(run_id)]) == 0
        page = Path(capsys.readouterr().out.strip()).read_text(encoding="utf-8")
        pages.append(html.unescape(page))
    assert 'bench.clock = "virtual"' in pages[0] and pages[0].count("<img ") == 4
    assert "virtual" not in pages[1] and pages[1].count("<img ") == 5


@pytest.mark.slow
def test_the_page_cites_only_what_a_reader_has(tmp_path: Path) -> None:
    page = write_report(synthetic_rows(), tmp_path).html.read_text(encoding="utf-8")
    assert "DESIGN.md" not in page
    cited = set(re.findall(r"\b[\w./-]+\.(?:md|py|toml)\b", page))
    assert cited <= {"README.md"}, cited
