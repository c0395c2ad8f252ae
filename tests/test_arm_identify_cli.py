"""Identification of a recorded arm run and runs with the identified arm model (issue 20):
``thermocomp identify RUN --save NAME`` on an arm run, ``--arm-model NAME`` in the daemon's arm
setup (the identified factors in the controller's model, the IR observer of ``model+ir``).

The recorded run is written by the real recorder from a known truth: the controller's own arm
model with joint 2's heat x1.3 and IR offsets, plus measurement noise, at the times an arm run
on the bench records (step 10 s at time_scale 240): identification must find 1.3 within its
standard error. The run is the model identification assumes, so this checks the whole path
(what is recorded, how it is read back, the fit, the file) with an exact oracle.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest

from config import Settings
from daemon.arm.arm_model import (
    ArmModel,
    ArmModelNotFoundError,
    arm_model_toml,
    load_arm_model,
    named_arm_model_path,
    saved_arm_models_dir,
)
from daemon.arm.controller import ArmModelOptions
from daemon.arm.controller_loading import load_controller
from daemon.arm.ir_regions import region_nodes, region_point
from daemon.commands import identify as identify_cli
from daemon.run.arm.setup import ArmSetupError, arm_file, default_arm_setup
from daemon.run.states import RunParameters
from daemon.storage.recorder import Recorder, StepRecord
from tests.helpers import run_in_process
from tests.test_arm_run import ArmHarness, FakePredictor, run_to_end
from tests.test_arm_run import arm_settings as run_arm_settings

DUTY = "a465-pick-and-place"
STEPS = 24
STEP_S = 10.0
TIME_SCALE = 120.0  # 24 steps of 10 s: 8 h of the arm
TRUE_HEAT_2 = 1.3
TRUE_OFFSETS_C = {"upper-arm-mid": 0.3, "forearm-mid": -0.2}
NOISE_UM = 1.0
IR_NOISE_C = 0.02
#: The truth's heat: the motor model's mean over each TRUTH_STEP_S of the motion (a controller
#: holds its step's mean over a whole step; the physical arm does not).
TRUTH_STEP_S = 20.0


def arm_settings(data_dir: Path) -> Settings:
    return Settings.model_validate(
        {
            "storage": {"data_dir": str(data_dir)},
            "arm": {"enabled": True, "duty_cycle": DUTY},
        }
    )


def truth_model(settings: Settings, heat_scales: tuple[float, ...]) -> ArmModel:
    return ArmModel(name="truth", arm="CRS A465", heat_scales=heat_scales)


def record_run(data_dir: Path, seed: int = 3) -> int:
    """An uncompensated arm run as the daemon records it, from a known truth (module doc)."""
    settings = arm_settings(data_dir)
    options = ArmModelOptions(
        motion_dt_s=settings.arm.motion_dt_s, ambient_c=settings.model.ambient_c, model_dt_s=20.0
    )
    truth = load_controller(
        arm_file(settings),
        DUTY,
        options,
        truth_model(settings, (1.0, TRUE_HEAT_2, 1.0, 1.0, 1.0, 1.0)),
    )
    poses = truth.measured_poses()
    regions = region_nodes(truth.thermal, TRUE_OFFSETS_C)
    assert set(regions) == set(TRUE_OFFSETS_C)
    rng = np.random.default_rng(seed)
    parameters = RunParameters.from_settings(
        settings,
        compensation="off",
        step_s=STEP_S,
        duration_s=STEP_S * STEPS,
        time_scale=TIME_SCALE,
    )
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run(
            parameters.model_dump(mode="json"), settings.model_dump(mode="json"), {}, "test"
        )
        for step in range(STEPS):
            run_s = step * STEP_S
            while truth.time_s < run_s * TIME_SCALE - 1e-9:  # the heat of each 20 s
                truth.advance_to(truth.time_s + TRUTH_STEP_S)
            pose = poses[step % len(poses)]
            error = truth.tool_error(pose)
            measured = error.translation_mm * 1000.0 + rng.normal(0.0, NOISE_UM, 3)
            temperatures = truth.thermal.temperatures_c
            ir = {
                name: {
                    "mean_c": float(temperatures[list(nodes)].mean())
                    + TRUE_OFFSETS_C[name]
                    + float(rng.normal(0.0, IR_NOISE_C)),
                    "max_c": None,
                }
                for name, nodes in regions.items()
            }
            record = StepRecord(run_id, step, run_s, run_s, 0.0)
            record.arm_pose = pose.name
            record.measured_tx_um, record.measured_ty_um, record.measured_tz_um = (
                float(v) for v in measured
            )
            record.correction_tx_mm = record.correction_ty_mm = record.correction_tz_mm = 0.0
            record.ir_json = json.dumps(ir)
            recorder.write_step(record)
        recorder.finish_run(run_id, "finished", None, None)
    return run_id


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    data_dir = tmp_path_factory.mktemp("arm-identify")
    record_run(data_dir)
    return data_dir


def identify(
    data_dir: Path, capsys: pytest.CaptureFixture[str], *args: str
) -> tuple[int, str, str]:
    return run_in_process(
        identify_cli.register, ["identify", "1", "--data-dir", str(data_dir), *args], capsys
    )


PARAMS = [
    "--params",
    "heat:2",
    "heat:3",
    "convection",
    "offset:upper-arm-mid",
    "offset:forearm-mid",
]


def test_identify_recovers_a_known_heat_factor_and_saves_the_arm_model(
    recorded: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    status, out, err = identify(recorded, capsys, *PARAMS, "--json", "--save", "cal")
    assert status == 0, err
    document = json.loads(out)
    fitted = {p["name"]: p for p in document["all"]["parameters"]}
    heat = fitted["heat:2"]
    assert heat["identifiable"]
    assert 0 < heat["standard_error"] < 0.1
    assert abs(heat["value"] - TRUE_HEAT_2) < 3 * heat["standard_error"], heat
    assert abs(fitted["heat:3"]["value"] - 1.0) < 3 * fitted["heat:3"]["standard_error"]
    offset = fitted["offset:upper-arm-mid"]
    assert abs(offset["value"] - TRUE_OFFSETS_C["upper-arm-mid"]) < 3 * offset["standard_error"]
    assert document["saved_arm_model"] == "cal"
    model = load_arm_model(saved_arm_models_dir(recorded) / "cal.toml")
    assert model.arm == "CRS A465" and model.duty_cycle == DUTY
    assert model.source_runs == ("run 1",) and model.identified_at
    refit = {p["name"]: p for p in document["refit"]["parameters"]}
    assert model.heat_scales[1] == pytest.approx(refit["heat:2"]["value"])
    assert model.heat_scales[0] == 1.0  # not fitted: the preset's
    assert model.ir_offsets_c["upper-arm-mid"] == pytest.approx(
        refit["offset:upper-arm-mid"]["value"]
    )
    saved = {p.name: p for p in model.parameters}
    assert saved["heat:2"].identifiable and saved["heat:2"].standard_error is not None
    # the table without --json, and --out to any file
    status, out, err = identify(recorded, capsys, *PARAMS, "--out", str(recorded / "x.toml"))
    assert status == 0, err
    assert "heat:2" in out and "identifiable" in out
    assert load_arm_model(recorded / "x.toml").name == "run-1"


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("crs-a465", "an arm preset has that name"),
        ("../escape", "not a name"),
        ("a/b", "not a name"),
        ("x.toml", "not a name"),
    ],
)
def test_save_refuses_presets_paths_and_malformed_names(
    recorded: Path, capsys: pytest.CaptureFixture[str], name: str, message: str
) -> None:
    status, _, err = identify(recorded, capsys, "--save", name)
    assert status == 2 and message in err, err
    assert not (recorded / "escape.toml").exists()


def test_save_refuses_a_taken_name(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = saved_arm_models_dir(tmp_path)
    folder.mkdir(parents=True)
    (folder / "taken.toml").write_text("kept", "utf-8")
    record_run(tmp_path)
    status, _, err = identify(tmp_path, capsys, "--save", "taken")
    assert status == 2 and "exists" in err
    assert (folder / "taken.toml").read_text("utf-8") == "kept"


def save_model(data_dir: Path, model: ArmModel) -> None:
    folder = saved_arm_models_dir(data_dir)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{model.name}.toml").write_text(arm_model_toml(model), "utf-8")


def plan_for(data_dir: Path, **overrides: object) -> tuple[object, object]:
    settings = arm_settings(data_dir)
    parameters = RunParameters.from_settings(settings, time_scale=240.0, step_s=10.0, **overrides)
    return settings, default_arm_setup(settings, parameters)


def test_a_run_with_an_arm_model_uses_its_factors(tmp_path: Path) -> None:
    """Heat x2 on every joint and alpha x1.5: the network is linear and starts at ambient, so
    every rise doubles, and the tool error (linear in alpha * rise at these sizes) is 3x the
    preset's."""
    save_model(
        tmp_path,
        ArmModel(name="hot", arm="CRS A465", heat_scales=(2.0,) * 6, alpha_scale=1.5),
    )
    _, preset = plan_for(tmp_path)
    _, identified = plan_for(tmp_path, arm_model="hot")
    for plan in (preset, identified):
        plan.predictor.advance_to(8 * 3600.0)  # type: ignore[attr-defined]
    pose = preset.poses[0]  # type: ignore[attr-defined]
    base = preset.predictor.tool_error(pose).translation_mm  # type: ignore[attr-defined]
    scaled = identified.predictor.tool_error(pose).translation_mm  # type: ignore[attr-defined]
    assert np.linalg.norm(base) > 0.05  # tens of micrometres in 8 h
    np.testing.assert_allclose(scaled, 3.0 * base, rtol=2e-3)
    assert identified.snapshot["arm_model"]["name"] == "hot"  # type: ignore[attr-defined]
    assert preset.snapshot["arm_model"] is None  # type: ignore[attr-defined]


def test_unknown_or_foreign_arm_models_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ArmModelNotFoundError):
        named_arm_model_path("nothing", tmp_path)
    with pytest.raises(ValueError, match="not a name"):
        named_arm_model_path("../x", tmp_path)
    save_model(tmp_path, ArmModel(name="other", arm="UR5e", heat_scales=(1.0,) * 6))
    with pytest.raises(ArmSetupError, match="identified on arm 'UR5e'"):
        plan_for(tmp_path, arm_model="other")
    with pytest.raises(ValueError, match="arm_model is for an arm run"):
        RunParameters(arm_model="other")


@pytest.mark.slow
def test_model_plus_ir_estimates_from_the_regions_and_the_identified_offsets(
    tmp_path: Path,
) -> None:
    """model+ir (issue 29): the IR regions that name a link point feed the model's estimate
    (the adaptation's fit on the IR alone), with the arm model's offsets and their 1-sigma as
    the prior. Oracle: the same model with the shoulder heating 1.6x: its IR regions read
    (plus the offsets) teach the shoulder's factor and the upper arm's rise, which the
    compensation then uses."""
    offsets = {"upper-arm-mid": 0.4, "forearm-mid": -0.1}
    save_model(
        tmp_path,
        ArmModel(
            name="ir",
            arm="CRS A465",
            heat_scales=(1.0,) * 6,
            ir_offsets_c=offsets,
            ir_offset_sigma_c={"upper-arm-mid": 0.05, "forearm-mid": 0.05},
        ),
    )
    save_model(tmp_path, ArmModel("truth", "CRS A465", (1.0, 1.6, 1.0, 1.0, 1.0, 1.0)))
    _, plan = plan_for(tmp_path, arm_model="ir", prediction="model+ir")
    _, truth_plan = plan_for(tmp_path, arm_model="truth")
    controller = plan.predictor  # type: ignore[attr-defined]
    truth = truth_plan.predictor  # type: ignore[attr-defined]
    nodes = region_nodes(controller.thermal, offsets)

    def reading() -> dict[str, float]:
        now = truth.thermal.temperatures_c
        values = {
            name: float(now[list(group)].mean()) + offsets[name] for name, group in nodes.items()
        }
        return {**values, "not-a-link-mid": 99.0}  # a region naming no link point: ignored

    controller.observe(reading())  # the first reading starts the estimate
    adaptation = controller.adaptation
    assert adaptation is not None
    assert {n for n in adaptation.names if n.startswith("offset:")} == {
        f"offset:{r}" for r in offsets
    }
    assert "alpha" not in adaptation.names  # the IR cannot see the expansion
    for minutes in range(10, 8 * 60 + 1, 10):
        controller.advance_to(minutes * 60.0)
        truth.advance_to(minutes * 60.0)
        controller.observe(reading())
    estimates = controller.adaptation_estimates()
    assert estimates["offset:upper-arm-mid"][0] == pytest.approx(0.4, abs=0.02)
    assert estimates["offset:forearm-mid"][0] == pytest.approx(-0.1, abs=0.02)
    assert estimates["heat:2"][0] == pytest.approx(1.6, rel=0.05)
    true_rise = truth.link_states()[1].mean_rise_c
    preset_rise = controller.thermal.link_states()[1].mean_rise_c
    assert true_rise > 1.2 * preset_rise  # the shoulder's heat matters to the upper arm
    assert controller.link_states()[1].mean_rise_c == pytest.approx(true_rise, rel=0.02)
    error = controller.tool_error(plan.poses[0])  # type: ignore[attr-defined]
    assert np.all(np.isfinite(error.translation_mm))


def test_region_names() -> None:
    links = ("turret", "upper-arm")
    assert region_point("upper-arm-mid", links) == ("upper-arm", 0.5)
    assert region_point("turret@0.2", links) == ("turret", 0.2)
    assert region_point("turret@1.5", links) is None
    assert region_point("node-3", links) is None


class ObservingPredictor(FakePredictor):
    """The fake model of tests/test_arm_run.py, with the observer's entry point."""

    def __init__(self) -> None:
        super().__init__()
        self.readings: list[dict[str, float]] = []

    def observe(self, reading_c: Mapping[str, float]) -> None:
        self.readings.append(dict(reading_c))


async def test_each_arm_step_feeds_its_ir_reading_to_the_model(tmp_path: Path) -> None:
    """daemon/run/arm/step.py: the IR regions read at a step reach the model's observe() (the
    arm's observer with model+ir; a no-op otherwise), as recorded in the step's ir_json."""
    predictors: list[ObservingPredictor] = []

    def make() -> ObservingPredictor:
        predictors.append(ObservingPredictor())
        return predictors[-1]

    harness = ArmHarness(run_arm_settings(tmp_path), make)
    async with harness.daemon:
        final, steps = await run_to_end(harness, compensation="off")
    assert final["state"] == "finished"
    readings = predictors[0].readings
    assert len(readings) == len(steps) > 0
    for reading, step in zip(readings, steps, strict=True):
        recorded = json.loads(step["ir_json"])
        assert reading == {name: value["mean_c"] for name, value in recorded.items()}


def test_validate_predicts_another_run_with_the_identified_model_and_the_preset(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``identify 1 --validate 2`` on two recordings of the same truth (other noise): the
    identified model predicts run 2's tool translation to its noise (NOISE_UM per component:
    72 values, the sample RMS within ~25 % of it) and its IR regions to theirs (IR_NOISE_C);
    the preset (joint 2's heat x1.0, no IR offset) misses both by far more."""
    record_run(tmp_path, seed=3)
    record_run(tmp_path, seed=4)
    status, out, err = identify(tmp_path, capsys, *PARAMS, "--validate", "2", "--json")
    assert status == 0, err
    validation = json.loads(out)["validation"]
    assert validation["run"] == "run 2" and validation["duty_cycle"] == DUTY
    identified, preset = validation["identified"], validation["preset"]
    assert identified["marker_samples"] == 3 * STEPS
    assert 0.75 * NOISE_UM < 1000 * identified["marker_rms_mm"] < 1.25 * NOISE_UM
    assert 0.75 * IR_NOISE_C < identified["temperature_rms_c"] < 1.25 * IR_NOISE_C
    assert 1000 * preset["marker_rms_mm"] > 3 * NOISE_UM
    assert preset["temperature_rms_c"] > 0.1  # the offsets alone are 0.3 and -0.2 degC
    # saved with the model, and printed in the table
    status, out, err = identify(tmp_path, capsys, *PARAMS, "--validate", "2", "--save", "v")
    assert status == 0, err
    assert "validation on run 2" in out and "preset tool translation RMS" in out
    model = load_arm_model(saved_arm_models_dir(tmp_path) / "v.toml")
    assert model.validation_runs == ("run 2",)
    assert model.validation_marker_rms_um == pytest.approx(1000 * identified["marker_rms_mm"])
    assert model.validation_preset_marker_rms_um == pytest.approx(1000 * preset["marker_rms_mm"])


@pytest.mark.parametrize(
    ("validate", "status", "message"),
    [
        ("run.csv", 2, "validated on a recorded arm run, by its number"),
        ("9", 1, "no run 9"),
    ],
)
def test_validate_refuses_what_is_not_a_recorded_arm_run(
    recorded: Path, capsys: pytest.CaptureFixture[str], validate: str, status: int, message: str
) -> None:
    code, _, err = identify(recorded, capsys, "--validate", validate)
    assert code == status and message in err, err
    assert len(err.strip().splitlines()) == 1
