"""A followed run's displacements are relative to ONE camera measurement of each pose (its
reference, daemon/run/followed/measure.py), whose error is in every later sample of that pose.
Identification takes that error as unknown (ArmRunData.reference_fitted, a constant per pose
and axis eliminated from the tool's residuals): taken as the exact cold tool, its part along
the drift was read as a scale, and the UR5e's expansion factor came out 1.3-2.5 % high.

Oracle: a recorded followed run as ``calibrate model`` reads it (its heat, poses, timing and
sensitivities), its tool displacements and joint readings replaced by the model's own
prediction at known factors plus a reference error per pose; the fit must return the factors
it was made with."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from daemon.arm.identify import _ArmProblem, identify_arm
from daemon.arm.identify_parameters import parse_parameters
from daemon.commands.arm_identify import load_arm_run
from daemon.model.identify_uncertainty import central_jacobian
from tests.test_ur_calibrate_model import recorded_run

#: The factors the displacements are made with (the UR bench truth's alpha, 1.05).
TRUTH = {"heat:1": 1.1, "heat:2": 0.9, "heat:3": 1.05, "alpha": 1.05, "convection": 0.8}
#: Each measured pose's reference error (mm, x y z): the sizes one camera measurement had on
#: the UR bench (seed 1's two references, measured against the truth: 0.3-3 um).
REFERENCE_ERROR_MM = np.array([[2.23, 1.19, 2.97], [1.55, -0.25, 0.84]]) * 1e-3


@pytest.mark.slow
def test_a_reference_error_is_not_read_as_expansion(tmp_path: Path) -> None:
    run_id = recorded_run(tmp_path, 1.0)
    run = load_arm_run(tmp_path, run_id)
    names = list(TRUTH)
    specs = parse_parameters(names, 6, run.spec.regions, run.spec.across_link)
    truth = np.log(list(TRUTH.values()))
    made_by = _ArmProblem(run.data, run.spec, specs)
    markers, regions = made_by.predictions(truth)
    measured = run.data.marker_displacement_mm.reshape(markers.shape)
    poses = run.data.pose_index
    assert set(poses[np.isfinite(measured[:, 0])]) == {0, 1}
    made = np.where(np.isfinite(measured), markers + REFERENCE_ERROR_MM[poses], np.nan)
    data = dataclasses.replace(
        run.data,
        marker_displacement_mm=made.reshape(run.data.marker_displacement_mm.shape),
        region_c={
            name: np.where(np.isfinite(run.data.region_c[name]), regions[:, k], np.nan)
            for k, name in enumerate(made_by.region_names)
        },
    )
    fit = identify_arm(data, run.spec, names)
    for name, value in TRUTH.items():
        assert fit.parameter(name).value == pytest.approx(value, rel=1e-4), name
    assert run.data.reference_fitted  # the followed reader says its references are measured
    # the same data with the reference taken as the exact cold tool (the A465's reading):
    # the error is read as the arm's drift, alpha off by far more than its standard error
    exact = identify_arm(dataclasses.replace(data, reference_fitted=False), run.spec, names)
    alpha = exact.parameter("alpha")
    assert abs(alpha.value - TRUTH["alpha"]) > 3.0 * alpha.standard_error, alpha
    assert abs(alpha.value / TRUTH["alpha"] - 1.0) > 0.005, alpha
    # the projected problem's analytic Jacobian is its central difference
    problem = _ArmProblem(data, run.spec, specs)
    values = truth + 0.05
    numeric = central_jacobian(problem.weighted, values, 1e-5, relative=False)
    np.testing.assert_allclose(problem.jacobian(values), numeric, rtol=2e-4, atol=1e-6)
