"""What the run summary's reduction is measured against (issue 19): a measured uncompensated
reference run, else only the model's prediction (and said so); an uncompensated run states
its measured drift and no reduction. Hand-computed cases, the report page and
`thermocomp report --reference`, on a real run database."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from api.cli import main
from daemon.analysis import compensation_of, steps_from_rows, summarize_run, write_report
from daemon.run.kinds import check_reference_run
from daemon.run.setup import RunParameterError
from daemon.run.states import RunParameters
from daemon.storage.recorder import Recorder, StepRecord


def rows(
    residuals: list[float], *, predicted: float = 0.0, offsets: bool = True, step_s: float = 1.0
) -> list[dict[str, Any]]:
    """Steps at 0, step_s, ... with the given residuals; a compensated run's offsets follow a
    prediction that grows linearly to ``predicted`` (um), an uncompensated one's are 0."""
    last = max(1, len(residuals) - 1)
    out = []
    for step, residual in enumerate(residuals):
        prediction = predicted * step / last
        out.append(
            {
                "run_id": 1,
                "step": step,
                "scheduled_s": step * step_s,
                "actual_s": step * step_s,
                "lateness_s": 0.0,
                "predicted_x_um": prediction,
                "predicted_y_um": 0.0,
                "predicted_z_um": 0.0,
                "offset_x_mm": -prediction / 1000.0 if offsets else 0.0,
                "offset_y_mm": 0.0,
                "offset_z_mm": 0.0,
                "residual_um": residual,
            }
        )
    return out


COMPENSATED = [0.0, 1.0, -3.0, 1.0, 0.0, 2.0, 1.0]  # seven steps, 0..6 s: max |error| 3
DRIFT = [2.0 * t for t in range(11)]  # an uncompensated run, 0..10 s: 12 um at 6 s, 20 at 10


def test_without_a_reference_the_figure_is_relative_to_the_prediction() -> None:
    summary = summarize_run(rows(COMPENSATED, predicted=60.0))
    assert summary["reduction_basis"] == "prediction"
    assert summary["reduction_percent"] is None  # nothing measured to reduce from
    assert summary["reduction_vs_prediction_percent"] == pytest.approx(100 * (1 - 3 / 60))
    assert summary["uncompensated_max_um"] == pytest.approx(60.0)
    assert summary["measured_drift_max_um"] is None and summary["reference_run"] is None


def test_an_uncompensated_run_reports_its_measured_drift_not_a_reduction() -> None:
    off = rows(DRIFT, predicted=55.0, offsets=False)
    assert compensation_of(steps_from_rows(off)) == "off"  # inferred from the zero offsets
    for summary in (summarize_run(off), summarize_run(off, compensation="off")):
        assert summary["reduction_basis"] == "drift"
        assert summary["measured_drift_max_um"] == pytest.approx(20.0)
        assert summary["reduction_percent"] is None
        assert summary["reduction_vs_prediction_percent"] is None
        assert summary["uncompensated_max_um"] == pytest.approx(55.0)  # still shown


def test_the_reduction_against_a_reference_run_covers_the_time_both_runs_cover() -> None:
    """The reference drifted 20 um in 10 s, but only 12 um in the 6 s the compensated run
    lasted: 1 - 3/12 = 75 %, not the 85 % of comparing with its whole run."""
    summary = summarize_run(
        rows(COMPENSATED, predicted=60.0),
        compensation="absolute",
        reference=steps_from_rows(rows(DRIFT, offsets=False)),
        reference_run=4,
    )
    assert summary["reduction_basis"] == "reference" and summary["reference_run"] == 4
    assert summary["reference_span_s"] == pytest.approx(6.0)
    assert summary["reference_max_um"] == pytest.approx(12.0)
    assert summary["reduction_percent"] == pytest.approx(75.0)
    assert summary["reduction_vs_prediction_percent"] == pytest.approx(95.0)


def test_a_longer_compensated_run_is_cut_to_the_references_span() -> None:
    """The compensated run's error of 9 um at 8 s lies beyond the 3 s reference."""
    compensated = [0.0, 1.0, 2.0, 1.0, 0.0, 0.0, 0.0, 0.0, 9.0]
    summary = summarize_run(
        rows(compensated, predicted=50.0),
        reference=steps_from_rows(rows([0.0, 4.0, 6.0, 8.0], offsets=False)),
    )
    assert summary["reference_span_s"] == pytest.approx(3.0)
    assert summary["reduction_percent"] == pytest.approx(100 * (1 - 2 / 8))
    assert summary["residual_max_um"] == pytest.approx(9.0)  # Table 6.1 stays the whole run


def test_a_wrong_model_looks_good_against_its_prediction_but_not_against_the_drift() -> None:
    """Issue 19's case: the model predicts 100 um where the link drifts 40 um; the error left
    is 30 um. Against the prediction: 70 %; against the measured drift: 25 %."""
    summary = summarize_run(
        rows([0.0, 10.0, 20.0, 30.0], predicted=100.0),
        reference=steps_from_rows(rows([0.0, 15.0, 30.0, 40.0], offsets=False)),
    )
    assert summary["reduction_vs_prediction_percent"] == pytest.approx(70.0)
    assert summary["reduction_percent"] == pytest.approx(25.0)


@pytest.mark.slow
def test_the_report_states_what_its_figure_is_measured_against(tmp_path: Path) -> None:
    files = write_report(rows(COMPENSATED, predicted=60.0), tmp_path / "prediction")
    page = files.html.read_text(encoding="utf-8")
    assert "relative to the largest predicted deformation (not a measured reduction)" in page
    assert "No uncompensated reference run was named" in page
    assert "measured against the reference run" not in page

    files = write_report(rows(DRIFT, offsets=False), tmp_path / "off")
    page = files.html.read_text(encoding="utf-8")
    assert "Largest measured drift (compensation off)" in page
    assert "not compensated" in page and "Reduction" not in page
    assert json.loads(files.summary.read_text())["run_summary"]["reduction_basis"] == "drift"

    files = write_report(
        rows(COMPENSATED, predicted=60.0),
        tmp_path / "reference",
        reference=steps_from_rows(rows(DRIFT, offsets=False)),
        reference_run=3,
    )
    page = files.html.read_text(encoding="utf-8")
    assert "measured against the reference run" in page and "reference run 3" in page
    run_summary = json.loads(files.summary.read_text())["run_summary"]
    assert run_summary["reduction_percent"] == pytest.approx(75.0)


def _record(recorder: Recorder, parameters: dict[str, Any], steps: list[dict[str, Any]]) -> int:
    run_id = recorder.create_run(parameters, {}, None, "test")
    for row in steps:
        recorder.write_step(StepRecord(**{**row, "run_id": run_id}))
    recorder.finish_run(run_id, "finished", {}, None)
    return run_id


@pytest.fixture
def database(tmp_path: Path) -> tuple[Path, int, int]:
    """A run database: run 1 uncompensated (the drift), run 2 compensated naming it."""
    data_dir = tmp_path / "data"
    with Recorder(data_dir) as recorder:
        off = _record(recorder, {"compensation": "off"}, rows(DRIFT, offsets=False))
        compensated = _record(
            recorder,
            {"compensation": "absolute", "reference_run": off},
            rows(COMPENSATED, predicted=60.0),
        )
    return data_dir, off, compensated


def _report_summary(out: Path) -> dict[str, Any]:
    summary = json.loads((out / "summary.json").read_text())["run_summary"]
    assert isinstance(summary, dict)
    return summary


@pytest.mark.slow
def test_report_command_measures_against_the_named_or_recorded_reference(
    database: tuple[Path, int, int], tmp_path: Path
) -> None:
    data_dir, off, compensated = database
    config = tmp_path / "settings.toml"
    config.write_text(f'[storage]\ndata_dir = "{data_dir}"\n')
    common = ["--config", str(config)]
    # the run's own reference_run parameter
    assert main(["report", str(compensated), "--out", str(tmp_path / "a"), *common]) == 0
    assert _report_summary(tmp_path / "a")["reduction_percent"] == pytest.approx(75.0)
    # named on the command line
    assert (
        main(["report", str(compensated), "--reference", str(off), "--out", str(tmp_path / "b")])
        == 1  # default settings: another data_dir, no such database there
    )
    out = tmp_path / "c"
    assert (
        main(["report", str(compensated), "--reference", str(off), "--out", str(out), *common]) == 0
    )
    assert _report_summary(out)["reference_run"] == off
    # the off run itself: its drift
    assert main(["report", str(off), "--out", str(tmp_path / "d"), *common]) == 0
    assert _report_summary(tmp_path / "d")["measured_drift_max_um"] == pytest.approx(20.0)
    # a compensated run is no reference; nor is text a run number
    bad = ["report", str(off), "--reference", str(compensated), "--out", str(tmp_path / "e")]
    assert main([*bad, *common]) == 1
    assert main(["report", str(off), "--reference", "run-one", *common]) == 2


def test_a_run_can_only_name_an_ended_uncompensated_run_at_its_scale(
    database: tuple[Path, int, int],
) -> None:
    data_dir, off, compensated = database
    with Recorder(data_dir) as recorder:
        check_reference_run(recorder, RunParameters(reference_run=off))  # admissible
        check_reference_run(recorder, RunParameters())  # none named: nothing to check
        refusals = [
            (RunParameters(reference_run=99), "no such run"),
            (RunParameters(reference_run=compensated), "must be an uncompensated run"),
            (RunParameters(reference_run=off, deformation_scale=28.0), "not comparable"),
        ]
        running = recorder.create_run({"compensation": "off"}, {}, None, "test")
        refusals.append((RunParameters(reference_run=running), "must have ended"))
        for parameters, message in refusals:
            with pytest.raises(RunParameterError, match=message):
                check_reference_run(recorder, parameters)
