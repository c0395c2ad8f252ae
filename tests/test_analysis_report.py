"""The run report and the `stats`, `fit` and `report` commands, on a synthetic recorded run.

The synthetic run has the shape of the thesis's absolute-command experiment (143 steps over
4,800 s, a 150 um exponential deformation compensated to an error of S_x ~ 0.9 um) and is
recorded through the real Recorder, so its CSV export is exactly what a daemon run gives.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from api.cli import build_parser, main
from daemon.analysis import steps_from_rows, summarize_run, write_report
from daemon.analysis.plots import envelope
from daemon.storage.recorder import Recorder, StepRecord
from daemon.storage.reports import report_dir
from tests.helpers import run_main

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
STEPS, STEP_S, TAU_S, DEFORMATION_UM = 143, 33.6, 300.0, 150.0


def synthetic_rows(run_id: int = 1, seed: int = 1) -> list[dict[str, Any]]:
    rng = np.random.default_rng(seed)
    rows = []
    for step in range(STEPS):
        t = step * STEP_S
        lateness = 0.002 + rng.exponential(0.001) + (0.3 if step in (40, 41) else 0.0)
        predicted = DEFORMATION_UM * (1 - math.exp(-t / TAU_S))
        offset_mm = -predicted / 1000.0
        residual = float(rng.normal(0.007, 0.92))
        temperatures = {
            "shaft": 22 + 12 * (1 - math.exp(-t / 250)),
            "diode": 22 + 6 * (1 - math.exp(-t / 600)),
        }
        ir = {
            k: {"mean_c": v + rng.normal(0, 0.08), "max_c": v + 0.5}
            for k, v in temperatures.items()
        }
        model = {"2": temperatures["shaft"] + 0.3, "16": temperatures["diode"] - 0.2}
        rows.append(
            {
                "run_id": run_id,
                "step": step,
                "scheduled_s": t,
                "actual_s": t + lateness,
                "lateness_s": lateness,
                "model_time_s": t,
                "predicted_x_um": predicted,
                "predicted_y_um": 0.0,
                "predicted_z_um": 0.0,
                "offset_x_mm": offset_mm,
                "offset_y_mm": 0.0,
                "offset_z_mm": 0.0,
                "pose_x_mm": 500.0 + offset_mm,
                "pose_y_mm": 0.0,
                "pose_z_mm": 300.0,
                "centroid_x_px": 376 + residual / 10.22,
                "centroid_y_px": 291.0,
                "centroid_x_um": 376 * 10.22 + residual,
                "centroid_y_um": 291 * 9.72,
                "drift_x_um": residual,
                "drift_y_um": float(rng.normal(0, 0.1)),
                "residual_um": residual,
                "ir_json": json.dumps(ir),
                "flags": "late" if lateness > 0.1 else "",
                "error": "",
                "model_temperatures_json": json.dumps(model),
            }
        )
    return rows


@pytest.fixture
def recorded_run(tmp_path: Path) -> tuple[Path, int, list[dict[str, Any]]]:
    """A finished run in a real run database, with the summary the daemon records."""
    data_dir = tmp_path / "data"
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run({}, {}, None, "test")
        rows = synthetic_rows(run_id)
        for row in rows:
            recorder.write_step(StepRecord(**row))
        recorder.finish_run(run_id, "completed", dict(summarize_run(rows)), None)
    return data_dir, run_id, rows


def test_run_summary_matches_table_6_1_definitions() -> None:
    rows = synthetic_rows()
    residual = np.array([r["residual_um"] for r in rows])
    summary = summarize_run(rows)
    assert summary["n"] == STEPS
    assert summary["residual_max_um"] == pytest.approx(np.abs(residual).max())
    assert summary["residual_mean_um"] == pytest.approx(residual.mean())
    assert summary["residual_std_um"] == pytest.approx(residual.std(ddof=1))
    assert summary["residual_std_mean_um"] == pytest.approx(residual.std(ddof=1) / math.sqrt(STEPS))
    largest = DEFORMATION_UM * (1 - math.exp(-(STEPS - 1) * STEP_S / TAU_S))
    assert summary["uncompensated_max_um"] == pytest.approx(largest)
    # no uncompensated reference run: the figure is only relative to the prediction
    assert summary["reduction_basis"] == "prediction" and summary["reduction_percent"] is None
    assert summary["reduction_vs_prediction_percent"] == pytest.approx(
        100 * (1 - np.abs(residual).max() / largest)
    )


def test_uncompensated_deformation_is_scaled_like_the_residual() -> None:
    """Thesis 6.3: with the deformation scaled by s, an uncompensated run moves the spot by
    s x the prediction, so its reduction is 0 %, not the -1900 % of mixing scaled residuals
    with unscaled predictions."""
    scale = 20.0
    rows = [
        {
            "step": i,
            "predicted_x_um": d,
            "residual_um": scale * d,
            "deformation_scale": scale,
        }
        for i, d in enumerate([0.0, 5.0, 10.0, 15.0])
    ]
    summary = summarize_run(rows)
    assert summary["uncompensated_max_um"] == pytest.approx(300.0)
    assert summary["reduction_vs_prediction_percent"] == pytest.approx(0.0)
    unscaled = [{k: v for k, v in row.items() if k != "deformation_scale"} for row in rows]
    assert summarize_run(unscaled)["uncompensated_max_um"] == pytest.approx(15.0)


def test_steps_project_on_the_link_axis_whatever_its_direction() -> None:
    """A link along (0, 0.6, 0.8): deformation input +d, compensation -d along that axis."""
    rows = [
        {
            "step": i,
            "predicted_x_um": 0.0,
            "predicted_y_um": 0.6 * d,
            "predicted_z_um": 0.8 * d,
            "offset_x_mm": 0.0,
            "offset_y_mm": -0.6 * d / 1000,
            "offset_z_mm": -0.8 * d / 1000,
        }
        for i, d in enumerate([0.0, 10.0, 20.0])
    ]
    steps = steps_from_rows(rows)
    assert steps.deformation_input_um == pytest.approx([0.0, 10.0, 20.0])
    assert steps.compensation_um == pytest.approx([0.0, -10.0, -20.0])
    assert np.isnan(steps.residual_um).all()
    assert summarize_run(steps)["n"] == 0


@pytest.mark.slow
def test_report_has_every_plot_and_the_html_shows_existing_files(tmp_path: Path) -> None:
    rows = synthetic_rows()
    files = write_report(rows, tmp_path / "report", title="synthetic run")
    assert set(files.plots) == {
        "compensation",
        "compensated_vs_uncompensated",
        "error_histogram",
        "temperatures",
        "lateness",
    }
    for path in files.plots.values():
        content = path.read_bytes()
        assert content.startswith(PNG_MAGIC)
        width, height = int.from_bytes(content[16:20], "big"), int.from_bytes(content[20:24], "big")
        assert width == 1000 and 400 <= height <= 800
    page = files.html.read_text(encoding="utf-8")
    sources = re.findall(r'<img src="([^"]+)"', page)
    assert sorted(sources) == sorted(p.name for p in files.plots.values())
    assert all((files.directory / s).is_file() for s in sources)
    assert "http" not in page and "<script" not in page  # self-contained
    summary = json.loads(files.summary.read_text(encoding="utf-8"))
    assert summary["run_summary"] == pytest.approx(summarize_run(rows))
    assert summary["statistics"]["n"] == STEPS and summary["statistics"]["intervals"] == 15
    chi = summary["statistics"]["chi_squared"]
    assert chi["p_value_upper_tail"] == pytest.approx(1 - chi["thesis_lower_tail_p"])
    assert summary["flags"] == {"late": 2}
    deformation_fit = summary["fits"]["deformation_input_um"]
    assert deformation_fit["tau_s"] == pytest.approx(TAU_S, rel=1e-6)
    assert deformation_fit["final_value"] == pytest.approx(DEFORMATION_UM, rel=1e-6)
    # The numbers on the page are the summary's.
    assert f"{summary['run_summary']['residual_std_um']:.3f}" in page
    assert f"{chi['chi_squared']:.3f}" in page


@pytest.mark.slow
def test_report_of_a_run_without_measurements_still_has_every_figure(tmp_path: Path) -> None:
    rows = [
        {
            "run_id": 2,
            "step": i,
            "scheduled_s": float(i),
            "residual_um": "",
            "ir_json": "",
            "flags": "centroid-error",
            "error": "threshold too high",
        }
        for i in range(5)
    ]
    files = write_report(rows, tmp_path)
    assert all(p.is_file() for p in files.plots.values())
    summary = json.loads(files.summary.read_text(encoding="utf-8"))
    assert summary["run_summary"]["n"] == 0
    assert summary["run_summary"]["residual_mean_um"] is None
    assert "error" in summary["statistics"]
    assert summary["steps_with_error"] == 5


@pytest.mark.slow
def test_embedded_report_is_a_single_file(tmp_path: Path) -> None:
    files = write_report(synthetic_rows(), tmp_path, embed_images=True)
    page = files.html.read_text(encoding="utf-8")
    assert page.count('<img src="data:image/png;base64,') == len(files.plots)


@pytest.mark.slow
def test_report_command_on_a_run_id_agrees_with_the_daemon_summary(
    recorded_run: tuple[Path, int, list[dict[str, Any]]],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    data_dir, run_id, _ = recorded_run
    monkeypatch.setenv("THERMOCOMP_STORAGE__DATA_DIR", str(data_dir))
    assert main(["report", str(run_id)]) == 0
    html_path = Path(capsys.readouterr().out.strip())
    assert html_path == report_dir(data_dir, run_id) / "report.html"
    summary = json.loads((html_path.parent / "summary.json").read_text(encoding="utf-8"))
    with Recorder(data_dir) as recorder:
        run = recorder.run(run_id)
    assert run is not None and run.summary is not None
    for key, value in summary["run_summary"].items():
        assert run.summary[key] == pytest.approx(value), key

    assert main(["report", "99"]) == 1
    assert "no run 99" in capsys.readouterr().err
    assert main(["report", "no-such-file.csv"]) == 2


@pytest.mark.slow
def test_commands_on_the_exported_csv(
    recorded_run: tuple[Path, int, list[dict[str, Any]]],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    data_dir, run_id, rows = recorded_run
    exported = tmp_path / "run.csv"
    with Recorder(data_dir) as recorder:
        recorder.export_csv(run_id, exported)
    residual = np.array([r["residual_um"] for r in rows])

    assert main(["stats", str(exported), "--json"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["column"] == "residual_um" and stats["n"] == STEPS
    assert stats["std"] == pytest.approx(residual.std(ddof=1))
    assert main(["stats", str(exported)]) == 0
    text = capsys.readouterr().out
    assert "p-value (upper tail" in text and "thesis's lower-tail reading" in text

    assert main(["fit", str(exported), "--column", "predicted_x_um", "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)
    assert fit["tau_s"] == pytest.approx(TAU_S, rel=1e-6) and fit["kind"] == "rising"

    assert main(["report", str(exported), "--out", str(tmp_path / "out")]) == 0
    assert (tmp_path / "out" / "report.html").is_file()
    capsys.readouterr()

    assert main(["stats", str(exported), "--column", "nope"]) == 2
    assert "no column 'nope'" in capsys.readouterr().err
    assert main(["fit", str(exported), "--column", "step", "--final-fraction", "2"]) == 2


def test_stats_of_a_plain_list(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    numbers = tmp_path / "errors.txt"
    numbers.write_text("3\n1, 5\n2 4\n", encoding="utf-8")
    assert main(["stats", str(numbers), "--json"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["n"] == 5 and stats["mean"] == pytest.approx(3.0)
    numbers.write_text("7\n", encoding="utf-8")
    assert main(["stats", str(numbers)]) == 1
    assert "at least two" in capsys.readouterr().err


@pytest.mark.slow
def test_the_real_command_lists_the_analysis_commands() -> None:
    help_text = build_parser().format_help()
    for command in ("stats", "fit", "report"):
        assert command in help_text
    bad = run_main(["stats", "/no/such/file"])
    assert bad.returncode == 2 and "cannot read" in bad.stderr and "Traceback" not in bad.stderr


@pytest.mark.slow
async def test_report_after_a_short_bench_run_agrees_with_the_daemon(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Done-when of issue 8: a real run on the simulated bench (virtual clock), then
    `thermocomp report RUN_ID` writes every figure, and its numbers are the daemon's."""
    from config import load_settings
    from daemon.run.states import RunParameters
    from daemon.service import Daemon
    from tests.helpers import REPO_ROOT

    monkeypatch.setenv("THERMOCOMP_STORAGE__DATA_DIR", str(tmp_path))
    monkeypatch.setenv("THERMOCOMP_BENCH__CLOCK", "virtual")
    monkeypatch.setenv("THERMOCOMP_SCHEDULER__DURATION_S", "200")
    monkeypatch.setenv("THERMOCOMP_SCHEDULER__STEP_S", "10")
    settings = load_settings(REPO_ROOT / "config" / "sim.toml")
    async with Daemon(settings) as daemon:
        info = await daemon.start_run(RunParameters.from_settings(settings))
        await daemon.wait_run()
    _check_bench_report(tmp_path, int(info["id"]), capsys)


def _check_bench_report(data_dir: Path, run_id: int, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(run_id)]) == 0
    html_path = Path(capsys.readouterr().out.strip())
    assert html_path.parent == report_dir(data_dir, run_id)
    # The run's default folder is what the API serves as one page: images embedded.
    page = html_path.read_text(encoding="utf-8")
    # a virtual clock: four figures, and a line instead of an empty lateness figure
    assert page.count('<img src="data:image/png;base64,') == 4
    assert "used a virtual clock" in page
    summary = json.loads((html_path.parent / "summary.json").read_text(encoding="utf-8"))
    assert len(summary["plots"]) == 4 and summary["steps"] == 20
    assert "lateness" not in summary["plots"] and "virtual clock" in summary["notes"]["lateness"]
    for name in summary["plots"].values():
        assert (html_path.parent / name).read_bytes().startswith(PNG_MAGIC)
    with Recorder(data_dir) as recorder:
        run = recorder.run(run_id)
    assert run is not None and run.summary is not None
    assert summary["run_summary"]["n"] == run.summary["n"] == 20
    for key, value in summary["run_summary"].items():
        assert run.summary[key] == pytest.approx(value), key


def test_the_prediction_uncertainty_of_model_plus_ir_runs_is_read() -> None:
    steps = steps_from_rows([{"step": 0, "deformation_sigma_um": 0.4}, {"step": 1}])
    sigma = steps.column("deformation_sigma_um")
    assert sigma[0] == 0.4 and math.isnan(sigma[1])


def test_series_are_read_in_one_pass_and_padded_where_a_step_lacks_them() -> None:
    """Rows are streamed (a one-shot iterator), and a region, node or column first seen at a
    later step is NaN at the steps before it and wherever a step lacks it."""
    rows = iter(
        [
            {
                "run_id": 3,
                "step": 0,
                "residual_um": 1.0,
                "ir_json": json.dumps({"a": {"mean_c": 20.0, "max_c": 21.0}}),
                "flags": "late",
            },
            {
                "run_id": 3,
                "step": 1,
                "model_temperatures_json": json.dumps({"10": 30.0, "2": 25.0}),
                "ir_json": json.dumps({"b": {"mean_c": 22.0}, "a": {"mean_c": 20.5}}),
                "flags": "late",
            },
            {"run_id": 3, "step": 2, "residual_um": "", "centroid_x_px": 5.0, "flags": "x, late"},
        ]
    )
    steps = steps_from_rows(rows)
    nan = np.nan
    assert steps.run_id == "3" and steps.n_steps == 3
    np.testing.assert_array_equal(steps.column("step"), [0, 1, 2])
    np.testing.assert_array_equal(steps.residual_um, [1.0, nan, nan])
    np.testing.assert_array_equal(steps.column("centroid_x_px"), [nan, nan, 5.0])
    assert "pose_x_mm" not in steps.numeric  # no row has it: absent, not an all-NaN column
    assert list(steps.ir_mean_c) == ["a", "b"]
    np.testing.assert_array_equal(steps.ir_mean_c["a"], [20.0, 20.5, nan])
    np.testing.assert_array_equal(steps.ir_max_c["a"], [21.0, nan, nan])
    np.testing.assert_array_equal(steps.ir_mean_c["b"], [nan, 22.0, nan])
    assert list(steps.model_temperatures_c) == ["2", "10"]  # thesis node order
    np.testing.assert_array_equal(steps.model_temperatures_c["10"], [nan, 30.0, nan])
    assert steps.flags == (("late",), ("late",), ("x", "late"))
    assert steps.flag_count("late") == 3


def test_the_recorders_streamed_series_equal_the_series_of_its_records(
    recorded_run: tuple[Path, int, list[dict[str, Any]]],
) -> None:
    data_dir, run_id, rows = recorded_run
    with Recorder(data_dir) as recorder:
        streamed = recorder.run_steps(run_id)
        from_records = steps_from_rows(r.as_dict() for r in recorder.steps(run_id))
    assert streamed.n_steps == len(rows) > 0
    assert streamed.numeric.keys() == from_records.numeric.keys()
    for name, values in from_records.numeric.items():
        np.testing.assert_array_equal(streamed.numeric[name], values)
    for name, values in from_records.model_temperatures_c.items():
        np.testing.assert_array_equal(streamed.model_temperatures_c[name], values)
    assert streamed.ir_mean_c.keys() == from_records.ir_mean_c.keys()
    assert streamed.flags == from_records.flags and streamed.errors == from_records.errors


def test_long_series_are_drawn_as_their_min_max_envelope() -> None:
    rng = np.random.default_rng(5)
    n, buckets = 10_007, 100
    times = np.arange(n, dtype=float) * 0.02
    values = rng.normal(0.0, 1.0, n)
    values[4321] = 50.0  # one spike (a late step) must survive
    values[700:900] = np.nan  # two whole buckets without a value stay a gap
    drawn_t, drawn_v = envelope(times, values, buckets)
    size = -(-n // buckets)
    assert drawn_v.size <= 2 * buckets
    assert np.all(np.diff(drawn_t) >= 0)  # still in time order
    assert 50.0 in drawn_v and np.nanmin(values) in drawn_v
    for b, start in enumerate(range(0, n, size)):  # brute force, bucket by bucket
        chunk = values[start : start + size]
        pair = drawn_v[2 * b : 2 * b + 2]
        if np.isfinite(chunk).any():
            assert sorted(pair) == [np.nanmin(chunk), np.nanmax(chunk)]
        else:
            assert np.isnan(pair).all()
    short_t, short_v = envelope(times[:200], values[:200], buckets)
    assert np.array_equal(short_t, times[:200])
    assert np.array_equal(short_v, values[:200], equal_nan=True)
