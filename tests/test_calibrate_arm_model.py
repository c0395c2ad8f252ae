"""``thermocomp calibrate model`` on an arm (issue 20), end to end on the simulated arm bench
(config/arm-sim.toml: the C500C emulator in joint space on a pty, three cameras, virtual
clock), shortened to 4 steps of 10 s (2 h 40 min of the arm's time at time_scale 240): an
uncompensated calibration run -> the arm's identification saved as an arm model -> a validation
run with ``--arm-model`` measured against the calibration run's drift, and the refusals that
come before anything runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from daemon.arm.arm_model import load_arm_model, saved_arm_models_dir
from daemon.commands import calibrate as calibrate_cli
from daemon.commands.calibrate_arm_model import _print
from daemon.storage.recorder import Recorder
from tests.helpers import REPO_ROOT, run_in_process

CONFIG = str(REPO_ROOT / "config" / "arm-sim.toml")
#: Without convection the fit's responses are computed once: identification takes ~1 s.
PARAMS = ["heat:2", "heat:3", "alpha", "offset:upper-arm-mid", "offset:forearm-mid"]


@pytest.fixture(autouse=True)
def _no_reports(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("THERMOCOMP_STORAGE__REPORT_AT_END", "false")


def calibrate(
    data_dir: Path, capsys: pytest.CaptureFixture[str], *args: str
) -> tuple[int, str, str]:
    argv = ["calibrate", "model", "--config", CONFIG, "--data-dir", str(data_dir), *args]
    return run_in_process(calibrate_cli.register, argv, capsys)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--save", "crs-a465"], "an arm preset has that name"),
        (["--save", "../x"], "is not a name"),
        (["--save", "x", "--scale", "20"], "--scale is for the two-link bench"),
        (["--save", "x", "--network", "thesis-two-link"], "--network is for the two-link"),
    ],
)
def test_refused_before_anything_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    status, _, err = calibrate(tmp_path / "data", capsys, *args)
    assert status == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "data").exists()


def test_an_arm_without_a_duty_cycle_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "arm.toml"
    config.write_text("[arm]\nenabled = true\n")
    argv = ["calibrate", "model", "--config", str(config), "--data-dir", str(tmp_path / "d")]
    status, _, err = run_in_process(calibrate_cli.register, [*argv, "--save", "x"], capsys)
    assert status == 2 and "give --duty-cycle NAME|PATH or set arm.duty_cycle" in err, err
    assert not (tmp_path / "d").exists()


@pytest.mark.slow
def test_calibration_identification_and_validation_on_the_arm_bench(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = tmp_path / "data"
    # the task's own cycle as the calibration cycle (--calibration-cycle): the reduction is
    # then against the calibration run's drift, as before issue 29's calibration program
    status, out, err = calibrate(
        data, capsys, "--duration", "40", "--save", "cal", "--params", *PARAMS, "--json",
        "--calibration-cycle", "a465-pick-and-place",
    )  # fmt: skip
    assert status == 0, err
    outcome = json.loads(out)
    calibration = outcome["calibration_run"]
    assert (calibration["id"], calibration["state"]) == (1, "finished")
    assert calibration["reduction_basis"] == "drift" and calibration["arm_n"] == 4
    assert calibration["drift_3d_rms_um"] > 50.0  # the arm warms: tens of um in 2 h 40 min
    # the saved arm model is the refit of the table printed
    model = load_arm_model(saved_arm_models_dir(data) / "cal.toml")
    assert (model.arm, model.source_runs) == ("CRS A465", ("run 1",))
    refit = {p["name"]: p["value"] for p in outcome["identified"]["refit"]["parameters"]}
    assert model.heat_scales[1] == pytest.approx(refit["heat:2"])
    assert model.alpha_scale == pytest.approx(refit["alpha"])
    assert model.heat_scales[0] == 1.0  # not fitted: the preset's
    assert [p.name for p in model.parameters] == PARAMS
    # the validation run used it and removed most of the calibration run's drift
    validation = outcome["validation_run"]
    assert (validation["id"], validation["state"]) == (2, "finished")
    assert (validation["reduction_basis"], validation["reference_run"]) == ("reference", 1)
    assert validation["reduction_3d_percent"] > 80.0
    assert validation["reduction_3d_rms_percent"] > 80.0
    sigma = validation["measurement_sigma_um"]
    assert validation["rms_over_noise"] == pytest.approx(validation["drift_3d_rms_um"] / sigma)
    assert validation["rms_over_noise"] < 3.0
    with Recorder(data) as recorder:
        row = recorder.run(2)
        assert row is not None and row.parameters["arm_model"] == "cal"
        assert row.parameters["compensation"] == "absolute"
    # the validation run's thermal displacement predicted offline by both models
    prediction = outcome["prediction"]
    assert prediction["run"] == "run 2"
    assert prediction["identified"]["marker_samples"] == 3 * 4
    assert prediction["identified"]["marker_rms_mm"] < prediction["preset"]["marker_rms_mm"]


@pytest.mark.slow
def test_no_validate_prints_the_identification_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    status, out, err = calibrate(
        tmp_path / "data", capsys, "--duration", "30", "--save", "t", "--params", *PARAMS,
        "--no-validate", "--calibration-cycle", "a465-pick-and-place",
        # a 3-step calibration whose cold references time out under load (the first step is
        # then the zero) can fit alpha outside its physical range: this test is about the
        # table; the refusal has its own tests (tests/test_arm_model_warnings.py)
        "--force",
    )  # fmt: skip
    assert status == 0, err
    assert "1. calibration run 1" in out and "3-D drift max" in out
    assert "saved as arm model 't'" in out and "heat:2" in out and "identifiable" in out
    assert "3. validation skipped (--no-validate)" in out
    with Recorder(tmp_path / "data") as recorder:
        assert [run.id for run in recorder.runs(10, 0)] == [1]


def _outcome(reference_run: int | None) -> dict[str, object]:
    validation = {
        "id": 4,
        "drift_3d_max_um": 5.32,
        "drift_3d_rms_um": 3.76,
        "rms_over_noise": 1.43,
        "measurement_sigma_um": 2.64,
        "reference_run": reference_run,
        "reduction_3d_percent": None if reference_run is None else 97.1,
        "reduction_3d_rms_percent": None if reference_run is None else 97.5,
        "rotation_error_rms_urad": 62.5,
    }
    return {
        "calibration_run": {"id": 3, "duty_cycle": "cal.toml", "drift_3d_max_um": 106.0,
                            "drift_3d_rms_um": 71.7},
        "arm_model": "a465-cal",
        "arm_model_file": "/d/arm-models/a465-cal.toml",
        "validation_run": validation,
        "prediction": {"identified": {"marker_rms_mm": 0.0022},
                       "preset": {"marker_rms_mm": 0.00343}},
    }  # fmt: skip


def test_a_validation_without_a_reference_says_how_to_measure_the_reduction(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The calibration program is not the task: the validation run has no reference run, and
    the summary says so and how to measure one, never "run None: - %"."""
    _print(_outcome(None), "table")
    out = capsys.readouterr().out
    assert "None" not in out and "- %" not in out, out
    assert "no reduction measured" in out
    assert "thermocomp run --arm-model a465-cal --reference-run RUN" in out
    _print(_outcome(3), "table")
    out = capsys.readouterr().out
    assert "reduction of the drift of run 3: 97.1 % (largest), 97.5 % (RMS)" in out
