"""``thermocomp fit --column ir:<region>`` fits the IR signals of an exported run, which sit
in its ``ir_json`` column as ``{"region": {"mean_c": .., "max_c": ..}}`` (issue 21)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from api.cli import main
from daemon.analysis import summarize_run
from daemon.storage.recorder import Recorder, StepRecord
from tests.helpers import run_main
from tests.test_analysis_report import synthetic_rows

#: The synthetic run's shaft warms as 22 + 12 (1 - exp(-t / 250 s)) degC, read with 0.08 degC
#: noise; the reading's maximum is the true value + 0.5 degC, noiseless.
SHAFT_TAU_S, SHAFT_RISE_C, SHAFT_FINAL_C = 250.0, 12.0, 34.0


@pytest.fixture
def exported(tmp_path: Path) -> Path:
    data_dir, path = tmp_path / "data", tmp_path / "run.csv"
    rows = synthetic_rows()
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run({}, {}, None, "test")
        for row in rows:
            recorder.write_step(StepRecord(**{**row, "run_id": run_id}))
        recorder.finish_run(run_id, "finished", dict(summarize_run(rows)), None)
        recorder.export_csv(run_id, path)
    return path


def test_fit_of_an_ir_regions_mean_and_max(
    exported: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["fit", str(exported), "--column", "ir:shaft", "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)
    assert fit["column"] == "ir:shaft" and fit["kind"] == "rising" and fit["n"] == 143
    assert fit["tau_s"] == pytest.approx(SHAFT_TAU_S, rel=0.05)
    assert fit["final_value"] == pytest.approx(SHAFT_FINAL_C, abs=0.1)

    assert main(["fit", str(exported), "--column", "ir:shaft:max", "--json"]) == 0
    peak = json.loads(capsys.readouterr().out)
    assert peak["tau_s"] == pytest.approx(SHAFT_TAU_S, rel=1e-4)  # noiseless: exact
    assert peak["final_value"] == pytest.approx(SHAFT_FINAL_C + 0.5, rel=1e-5)

    assert main(["stats", str(exported), "--column", "ir:diode", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["n"] == 143


@pytest.mark.slow
def test_an_unknown_region_names_the_ones_there_are(exported: Path) -> None:
    result = run_main(["fit", str(exported), "--column", "ir:elbow"])
    assert result.returncode == 2
    assert "no IR region 'elbow'" in result.stderr
    assert "ir:diode, ir:shaft" in result.stderr and "Traceback" not in result.stderr
    # a plain unknown column lists the columns and, for an export, the IR signals
    result = run_main(["fit", str(exported), "--column", "shaft"])
    assert result.returncode == 2 and "IR regions: ir:diode, ir:shaft" in result.stderr


def test_ir_of_a_file_without_ir_json_is_a_usage_error(tmp_path: Path) -> None:
    numbers = tmp_path / "plain.txt"
    numbers.write_text("1 2 3 4 5\n", encoding="utf-8")
    result = run_main(["fit", str(numbers), "--column", "ir:shaft"])
    assert result.returncode == 2 and "no ir_json column" in result.stderr
