"""Reports a person can read (issue 28): the two-link report's uncompensated curve is measured
when a reference run exists and labelled predicted when not; the arm report leads with the
whole arm, in hours of the arm's warm-up, with noise bands, and leaves out what does not apply
(Table 6.1 at N = 0 with dashes, figures saying there is no measured error)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.collections import PolyCollection

from daemon.analysis import steps_from_rows, summarize_run, write_report
from daemon.analysis.arm_plots import draw_arm_error
from daemon.analysis.plots import plot_compensated_vs_uncompensated
from tests.test_analysis_reduction import COMPENSATED, DRIFT, rows

TIME_SCALE = 240.0  # arm-sim.toml: 10 s of run are 40 min of the arm


def arm_rows(drifts: list[float], *, rotation: float = 40.0, run_id: int = 2) -> list[Any]:
    """An arm run at two alternating poses, 10 s a step, the drift along x."""
    out = []
    for step, drift in enumerate(drifts):
        out.append(
            {
                "run_id": run_id,
                "step": step,
                "scheduled_s": 10.0 * step,
                "actual_s": 10.0 * step,
                "lateness_s": 0.0,
                "model_time_s": 10.0 * step * TIME_SCALE,
                "arm_pose": "camera" if step % 2 == 0 else "place",
                "predicted_tx_um": 20.0 * step,
                "predicted_ty_um": 0.0,
                "predicted_tz_um": 0.0,
                "predicted_rx_urad": 5.0,
                "predicted_ry_urad": 0.0,
                "predicted_rz_urad": 0.0,
                "measured_tx_um": drift,
                "measured_ty_um": 0.0,
                "measured_tz_um": 0.0,
                "drift_3d_um": abs(drift),
                "rotation_error_urad": rotation,
                "measured_sigma_um": 2.0,
                "measured_rotation_sigma_urad": 90.0,
                "model_temperatures_json": json.dumps(
                    {"upper-arm.1+": 22.0 + step, "upper-arm.1-": 22.0 + step / 2, "elbow": 23.0}
                ),
            }
        )
    return out


def labels(figure: Any) -> list[str]:
    return [line.get_label() for ax in figure.axes for line in ax.get_lines()]


def test_the_uncompensated_curve_is_measured_when_a_reference_exists() -> None:
    run = steps_from_rows(rows(COMPENSATED, predicted=60.0))
    reference = steps_from_rows(rows(DRIFT, offsets=False))
    summary = summarize_run(run, reference=reference, reference_run=1)
    figure = plot_compensated_vs_uncompensated(run, summary, reference)
    measured = "uncompensated (measured: run 1, compensation off)"
    assert measured in labels(figure)
    line = next(line for line in figure.axes[0].get_lines() if line.get_label() == measured)
    assert list(line.get_ydata()) == DRIFT  # the reference run's own error, not the model's
    # without one: the prediction, and it says so
    alone = plot_compensated_vs_uncompensated(run, summarize_run(run))
    assert "uncompensated (predicted by the model: no reference run)" in labels(alone)
    assert not any("measured: run" in label for label in labels(alone))


def test_a_two_link_run_with_no_measured_error_has_no_table_of_dashes(tmp_path: Path) -> None:
    empty = [{**row, "residual_um": None} for row in rows(COMPENSATED, predicted=60.0)]
    page = write_report(empty, tmp_path).html.read_text(encoding="utf-8")
    assert "Table 6.1" not in page
    assert "No step measured an error (N = 0)" in page


def test_the_arm_report_leads_with_the_whole_arm_in_hours(tmp_path: Path) -> None:
    drifts = [1.0, 8.0, 3.0, 6.0, 2.0, 5.0]
    reference = steps_from_rows(arm_rows([0.0, 40.0, 70.0, 90.0, 100.0, 110.0], run_id=1))
    files = write_report(
        arm_rows(drifts),
        tmp_path,
        compensation="absolute",
        reference=reference,
        reference_run=1,
    )
    page = files.html.read_text(encoding="utf-8")
    # the headline first, then the whole-arm table; nothing of the two-link report
    headline = page.index("% of the measured drift removed")
    assert headline < page.index("Whole arm") < page.index('alt="arm_drift"')
    assert "Table 6.1" not in page and "Chi-squared" not in page
    # (a lateness of exactly 0 s is a virtual clock's: one line instead of a flat figure)
    assert set(files.plots) == {"arm_drift", "arm_rotation", "arm_temperatures"}
    assert "No lateness figure" in page
    assert "no measured error" not in page
    # every row of the whole-arm table has a value: none is a dash
    table = page[page.index("Whole arm") : page.index("</table>", page.index("Whole arm"))]
    assert "<td>–</td>" not in table
    # the rotation's reference (40 urad) is within its noise (1 sigma 90): no figure claimed
    assert "not stated: the reference's 40.0 is within the measurement's noise" in table
    assert "Per measured pose" in page


def test_the_arm_figures_are_per_pose_with_noise_bands_in_arm_hours() -> None:
    steps = steps_from_rows(arm_rows([1.0, 8.0, 3.0, 6.0]))
    reference = steps_from_rows(arm_rows([0.0, 40.0, 70.0, 90.0], run_id=1))
    for what in ("drift", "rotation"):
        figure = draw_arm_error(steps, what=what, reference=reference, reference_run=1)
        (ax,) = figure.axes
        assert ax.get_xlabel() == "time of the arm's warm-up (h)"
        bands = [c for c in ax.collections if isinstance(c, PolyCollection)]
        assert len(bands) == 2  # one noise band per pose
        names = labels(figure)
        assert "camera: measured" in names and "place: measured" in names
        assert "camera: run 1 uncompensated (measured)" in names
        camera = next(line for line in ax.get_lines() if line.get_label() == "camera: measured")
        # the camera pose's own steps (0 and 2), at 0 and 20 s of run = 0 and 1.33 h of arm
        assert np.allclose(camera.get_xdata(), [0.0, 20.0 * TIME_SCALE / 3600])
