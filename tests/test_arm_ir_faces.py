"""IR regions on one face of a link and what the arm's model+ir learns from them (issue 29).

What bends a link is the temperature difference across it, next to the joint whose housing
heats one face first. A region on the section's mean cannot see it; regions on both faces can,
and model+ir then estimates the bending share the controller believed wrong (corner-low truth:
the preset with the room and the IR removed 65 % of the drift, 82-84 % now)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from config import Settings
from daemon.arm.arm_model import ArmModel
from daemon.arm.controller import ArmController
from daemon.arm.ir_regions import region_face, region_name, region_nodes, region_point
from daemon.arm.loading import load_arm
from daemon.arm.thermal import ArmThermalModel
from daemon.model.calibration import CalibratedParameter
from daemon.run.arm.setup import ArmPlan, default_arm_setup
from daemon.run.states import RunParameters
from drivers.sim.arm_bench import ArmBench, ArmBenchConfig
from tests.test_arm_identify_cli import DUTY, save_model

LINKS = ("turret", "upper-arm", "forearm")


def test_region_names_with_a_face() -> None:
    assert region_face("upper-arm-mid.plus") == ("upper-arm-mid", "plus")
    assert region_face("upper-arm@0.05.minus") == ("upper-arm@0.05", "minus")
    assert region_face("upper-arm@0.05") == ("upper-arm@0.05", None)
    assert region_face("upper-arm-mid.side") == ("upper-arm-mid.side", None)
    assert region_point("upper-arm@0.05.minus", LINKS) == ("upper-arm", 0.05)
    assert region_point("forearm-mid.plus", LINKS) == ("forearm", 0.5)
    assert region_point("forearm-mid.side", LINKS) is None
    for link, fraction, face in (("forearm", 0.5, None), ("upper-arm", 0.05, "plus")):
        name = region_name(link, fraction, face)
        assert region_point(name, LINKS) == (link, fraction)
        assert region_face(name)[1] == face


def test_a_face_region_sees_that_faces_row_only() -> None:
    model = ArmThermalModel(load_arm("crs-a465"), across_link=True, node_spacing_mm=50.0)
    both = set(model.link_node_indices("upper-arm").tolist())
    plus = set(model.link_face_node_indices("upper-arm", "plus").tolist())
    minus = set(model.link_face_node_indices("upper-arm", "minus").tolist())
    assert plus | minus == both and not plus & minus and len(plus) == len(minus)
    nodes = region_nodes(
        model, ["upper-arm@0.05.plus", "upper-arm@0.05.minus", "upper-arm-mid", "bogus.plus"]
    )
    assert set(nodes) == {"upper-arm@0.05.plus", "upper-arm@0.05.minus", "upper-arm-mid"}
    assert len(nodes["upper-arm@0.05.plus"]) == 1 and set(nodes["upper-arm@0.05.plus"]) <= plus
    assert len(nodes["upper-arm@0.05.minus"]) == 1
    assert set(nodes["upper-arm@0.05.minus"]) <= minus
    assert set(nodes["upper-arm-mid"]) & plus and set(nodes["upper-arm-mid"]) & minus
    chain = ArmThermalModel(load_arm("crs-a465"), node_spacing_mm=50.0)  # one row: no faces
    chain_nodes = region_nodes(chain, ["forearm-mid.plus", "forearm-mid"])
    assert chain_nodes["forearm-mid.plus"] == chain_nodes["forearm-mid"]
    with pytest.raises(ValueError, match="face"):
        model.link_face_node_indices("upper-arm", "top")


def test_the_bench_reads_the_motor_housings_face_warmer_by_the_shoulder() -> None:
    """The truth with its motor housings' share 0.9: after an hour of a held heat the "+" face
    by the shoulder reads warmer than the "-" face; with share 0.5 both alike."""
    regions = (
        ("upper-arm@0.05.plus", "upper-arm", 0.05),
        ("upper-arm@0.05.minus", "upper-arm", 0.05),
    )
    differences = []
    for share in (0.9, 0.5):
        config = ArmBenchConfig(
            plus_share=share, ir_regions=regions, ir_noise_c=0.0, ir_offset_sigma_c=0.0,
            node_spacing_mm=25.0, heat_scales=(1.0,) * 6,
        )  # fmt: skip
        bench = ArmBench(config)
        heat = np.zeros(bench.thermal.joint_count)
        heat[1] = 20.0  # the shoulder's motor
        bench.thermal.advance_to(3600.0, heat)
        reading = bench.ir_true_c()
        differences.append(reading["upper-arm@0.05.plus"] - reading["upper-arm@0.05.minus"])
    assert differences[0] > 0.3
    assert abs(differences[1]) < 0.05 * differences[0]


def plan_for(data_dir: Path, **overrides: object) -> ArmPlan:
    """The daemon's controller of an arm run that bends its links (config/arm-sim.toml's
    belief: the motor housings' share 0.75)."""
    settings = Settings.model_validate(
        {
            "storage": {"data_dir": str(data_dir)},
            "arm": {
                "enabled": True, "duty_cycle": DUTY, "bending": True, "motor_side_share": 0.75,
            },
        }
    )  # fmt: skip
    parameters = RunParameters.from_settings(settings, time_scale=240.0, step_s=10.0, **overrides)
    return default_arm_setup(settings, parameters)


def _share_learned(tmp_path: Path, regions: list[str]) -> tuple[dict[str, list[float]], float]:
    """model+ir (the preset believes share 0.75) along 8 h of IR readings of the same model
    with share 0.55 and its shoulder heating 1.3x (the oracle): the estimates and the upper
    arm's across-link gradient error left (fraction of the truth's)."""
    save_model(
        tmp_path,
        ArmModel("truth", "CRS A465", (1.0, 1.3, 1.0, 1.0, 1.0, 1.0), bending_shares=(0.55,) * 6),
    )
    plan = plan_for(tmp_path, prediction="model+ir")
    truth_plan = plan_for(tmp_path, arm_model="truth")
    controller, truth = plan.predictor, truth_plan.predictor
    assert isinstance(controller, ArmController) and isinstance(truth, ArmController)
    offsets = {name: 0.1 * (k - 1) for k, name in enumerate(regions)}
    nodes = region_nodes(truth.thermal, regions)

    def reading() -> dict[str, float]:
        now = truth.thermal.temperatures_c
        return {
            name: float(now[list(group)].mean()) + offsets[name] for name, group in nodes.items()
        }

    controller.observe(reading())
    for minutes in range(10, 8 * 60 + 1, 10):
        controller.advance_to(minutes * 60.0)
        truth.advance_to(minutes * 60.0)
        controller.observe(reading())
    true_gradient = np.array(truth.link_states()[1].gradient_c_per_mm)
    gradient = np.array(controller.link_states()[1].gradient_c_per_mm)
    error = float(np.linalg.norm(gradient - true_gradient) / np.linalg.norm(true_gradient))
    return controller.adaptation_estimates(), error


@pytest.mark.slow
def test_model_plus_ir_learns_the_bending_share_from_both_faces(tmp_path: Path) -> None:
    faces = [
        region_name(link, 0.05, face)
        for link in ("upper-arm", "forearm")
        for face in ("plus", "minus")
    ]
    estimates, error = _share_learned(tmp_path / "faces", ["upper-arm-mid", "forearm-mid", *faces])
    assert estimates["share"][0] == pytest.approx(0.55, abs=0.02)
    assert estimates["heat:2"][0] == pytest.approx(1.3, rel=0.05)
    assert error < 0.1
    # the section's mean alone: the share stays the preset's belief within its prior, and
    # the upper arm's bend stays wrong (what the corner-low truth showed)
    estimates, error = _share_learned(tmp_path / "mean", ["upper-arm-mid", "forearm-mid"])
    assert abs(estimates["share"][0] - 0.55) > 0.1
    assert error > 0.5


@pytest.mark.slow
def test_model_plus_ir_holds_what_the_arm_model_identified(tmp_path: Path) -> None:
    """An identified model's factors were fitted to the tool: the IR estimate keeps them
    (the waist's heat x2, far from every IR region, and the shoulder's x1.5, identified) and
    only teaches the offsets, so on readings of that very model the compensation's links are
    the model's own (a held factor must still be carried: one left out of the estimate's
    parameters would fall back to 1)."""
    parameters = (
        CalibratedParameter("heat:1", 2.0, 0.02, 0.01),
        CalibratedParameter("heat:2", 1.5, 0.015, 0.01),
        CalibratedParameter("convection", 1.2, 0.012, 0.01),
        CalibratedParameter("share", 0.7, 0.004),
    )
    model = ArmModel(
        "identified", "CRS A465", (2.0, 1.5, 1.0, 1.0, 1.0, 1.0), convection_scale=1.2,
        bending_shares=(0.7,) * 6, parameters=parameters,
    )  # fmt: skip
    save_model(tmp_path, model)
    plan = plan_for(tmp_path, arm_model="identified", prediction="model+ir")
    truth_plan = plan_for(tmp_path, arm_model="identified")
    controller, truth = plan.predictor, truth_plan.predictor
    assert isinstance(controller, ArmController) and isinstance(truth, ArmController)
    regions = ["upper-arm-mid", *(region_name("upper-arm", 0.05, f) for f in ("plus", "minus"))]
    nodes = region_nodes(truth.thermal, regions)

    def reading() -> dict[str, float]:
        now = truth.thermal.temperatures_c
        return {name: float(now[list(group)].mean()) + 0.2 for name, group in nodes.items()}

    controller.observe(reading())
    for minutes in range(20, 4 * 60 + 1, 20):
        controller.advance_to(minutes * 60.0)
        truth.advance_to(minutes * 60.0)
        controller.observe(reading())
    estimates = controller.adaptation_estimates()
    assert estimates["heat:1"][0] == pytest.approx(2.0, rel=1e-3)
    assert estimates["heat:2"][0] == pytest.approx(1.5, rel=1e-3)
    assert estimates["share"][0] == pytest.approx(0.7, abs=1e-3)
    assert estimates["offset:upper-arm-mid"][0] == pytest.approx(0.2, abs=0.02)
    for adapted, own in zip(controller.link_states(), truth.link_states(), strict=True):
        assert adapted.mean_rise_c == pytest.approx(own.mean_rise_c, rel=0.02, abs=1e-3)
