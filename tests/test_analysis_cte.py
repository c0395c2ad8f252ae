"""CTE estimation from runs (thesis 2.2.4): the worked example, Table 2.7, recorded runs."""

import json
import math

import numpy as np
import pytest

from daemon.analysis import steps_from_rows
from daemon.analysis.cte import (
    Camera,
    Links,
    RunChange,
    cte_from_run,
    cte_table,
    estimate_cte,
    run_change,
)

# Table 2.5 effective link lengths, Eq. 2.2's projection angles.
KUKA_LINKS = Links(lengths_m=(0.70, 0.78), angles_deg=(17.55, 55.57))
# Eq. 2.3's camera angles: Pose A 11.31/2.56 deg, Pose B 10.317/2.039 deg (2.2.4).
CAMERAS = (Camera("A", 11.31, 2.56), Camera("B", 10.317, 2.039))
# Table 2.4: temperature rise of links 2 and 3, deformation seen by cameras A and B.
RUN_1 = RunChange("Run 1", (4.70, 6.75), {"A": 131.0, "B": 130.0})
RUN_2 = RunChange("Run 2", (4.00, 6.30), {"A": 120.0, "B": 120.0}, start_offset_k=(1.0, 1.0))
RUN_3 = RunChange("Run 3", (-1.20, -2.20), {"A": -40.0, "B": -41.0})
# Table 2.7 as printed: (alpha, camera, run) -> (predicted, measured, % error).
TABLE_2_7 = {
    ("alpha_A", "A", "Run 2"): (140.46, 143.75, -2.29),
    ("alpha_A", "A", "Run 3"): (-37.94, -40.00, -5.15),
    ("alpha_B", "B", "Run 2"): (139.44, 143.57, -2.88),
    ("alpha_B", "B", "Run 3"): (-37.67, -41.00, -8.12),
    ("mean alpha", "A", "Run 2"): (139.69, 143.62, -2.74),
    ("mean alpha", "A", "Run 3"): (-37.74, -40.00, -5.65),
    ("mean alpha", "B", "Run 2"): (140.21, 143.70, -2.43),
    ("mean alpha", "B", "Run 3"): (-37.88, -41.00, -7.61),
}


def test_worked_example_alpha_a() -> None:
    # DESIGN.md: alpha_A = 21.87e-6 /K from Tables 2.4/2.5 with phi 11.31, theta 2.56.
    assert estimate_cte(KUKA_LINKS, CAMERAS[0], RUN_1) * 1e6 == pytest.approx(21.87, abs=0.005)
    assert estimate_cte(KUKA_LINKS, CAMERAS[1], RUN_1) * 1e6 == pytest.approx(21.63, abs=0.005)


def test_two_runs_reproduce_table_2_7() -> None:
    table = cte_table(KUKA_LINKS, CAMERAS, RUN_1, [RUN_2, RUN_3], digits=2)
    assert table.alpha_per_camera == pytest.approx({"A": 21.87e-6, "B": 21.63e-6})
    assert table.mean_alpha_per_k == pytest.approx(21.75e-6)
    rows = {(r.alpha_label, r.camera, r.run): r for r in table.rows}
    assert set(rows) == set(TABLE_2_7)
    for key, (predicted, measured, percent) in TABLE_2_7.items():
        row = rows[key]
        assert row.predicted_um == pytest.approx(predicted, abs=0.015), key
        assert row.measured_um == pytest.approx(measured, abs=0.015), key
        # The thesis took the % error of its rounded deformations.
        assert 100 * (round(row.predicted_um, 2) - measured) / measured == pytest.approx(
            percent, abs=0.011
        ), key
        assert row.percent_error == pytest.approx(percent, abs=0.03), key
    assert json.dumps(table.to_dict())  # serialisable for summary files
    text = table.to_text()
    assert "alpha_A     A       Run 2             140.47       143.75    -2.28" in text


def _recorded_run(alpha_per_k: float, compensated: bool) -> list[dict[str, object]]:
    """One straight link (300 mm shaft side, 300 mm diode side) warming exponentially; the
    camera sees its growth, minus the compensation when the robot compensates."""
    rng = np.random.default_rng(2)
    rows = []
    for step in range(200):
        t = step * 10.0
        shaft = 22.0 + 12.0 * (1 - math.exp(-t / 300))
        diode = 22.0 + 6.0 * (1 - math.exp(-t / 500))
        growth_um = alpha_per_k * (0.3 * (shaft - 22.0) + 0.3 * (diode - 22.0)) * 1e6
        offset_mm = -growth_um / 1000 if compensated else 0.0
        residual = growth_um + offset_mm * 1000 + rng.normal(0, 0.3)
        ir = {
            "shaft": {"mean_c": shaft + rng.normal(0, 0.05)},
            "diode": {"mean_c": diode + rng.normal(0, 0.05)},
        }
        rows.append(
            {
                "run_id": 4,
                "step": step,
                "scheduled_s": t,
                "predicted_x_um": growth_um,
                "offset_x_mm": offset_mm,
                "residual_um": residual,
                "ir_json": json.dumps(ir),
            }
        )
    return rows


@pytest.mark.parametrize("compensated", [False, True])
def test_alpha_from_a_recorded_run(compensated: bool) -> None:
    alpha = 23.6e-6  # 6061-T6
    steps = steps_from_rows(_recorded_run(alpha, compensated))
    links = Links(lengths_m=(0.3, 0.3), angles_deg=(0.0, 0.0))
    fit = cte_from_run(steps, ["shaft", "diode"], links)
    assert fit.n == 200
    assert fit.alpha_per_k == pytest.approx(alpha, rel=0.01)
    assert abs(fit.alpha_per_k - alpha) < 4 * fit.alpha_stderr_per_k
    assert fit.endpoint_alpha_per_k == pytest.approx(alpha, rel=0.03)
    change = run_change(steps, ["shaft", "diode"], name="bench")
    # Start and end are the means of the first and last five steps (t = 0..40, 1950..1990 s).
    t = np.arange(200) * 10.0
    shaft, diode = 12 * (1 - np.exp(-t / 300)), 6 * (1 - np.exp(-t / 500))
    expected = (shaft[-5:].mean() - shaft[:5].mean(), diode[-5:].mean() - diode[:5].mean())
    assert change.delta_t_k == pytest.approx(expected, abs=0.1)


def test_recorded_run_without_the_regions_is_a_clear_error() -> None:
    steps = steps_from_rows(_recorded_run(23.6e-6, False))
    with pytest.raises(ValueError, match="elbow"):
        run_change(steps, ["elbow"])
    with pytest.raises(ValueError, match="one region per link"):
        cte_from_run(steps, ["shaft"], Links((0.3, 0.3), (0.0, 0.0)))
