"""`thermocomp calibrate cameras` (issue 20): camera poses from marker positions, simulated
(rendered and centroided) or recorded as CSV; the written camera file, its errors and exit
statuses."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from daemon.commands import calibrate as calibrate_cli
from daemon.vision.cameras import load_cameras, write_cameras
from daemon.vision.multiview import CameraModel, intrinsic_matrix, look_at, project
from tests.helpers import run_cli, run_in_process

TARGET = (0.0, 0.0, 400.0)


def true_cameras() -> list[CameraModel]:
    cameras = []
    for index, position in enumerate([(-800.0, -600.0, 500.0), (800.0, -600.0, 450.0)]):
        rvec, tvec = look_at(position, TARGET)
        cameras.append(
            CameraModel(
                name=f"c{index}",
                matrix=intrinsic_matrix((2400.0, 2380.0), (375.5, 290.5)),
                distortion=np.array([-0.1, 0.02, 0.0, 0.0, 0.0]),
                rotation_rad=rvec,
                translation_mm=tvec,
                image_size_px=(752, 582),
                pixel_sigma_px=0.05,
            )
        )
    return cameras


@pytest.fixture
def files(tmp_path: Path) -> tuple[Path, Path]:
    truth, intrinsics = tmp_path / "truth.toml", tmp_path / "cameras.toml"
    cameras = true_cameras()
    write_cameras(truth, cameras)
    write_cameras(intrinsics, [c.with_pose([0.0, 0.0, 0.0], [0.0, 0.0, 1000.0]) for c in cameras])
    return truth, intrinsics


def calibrate(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    return run_in_process(calibrate_cli.register, ["calibrate", "cameras", *argv], capsys)


def test_simulated_moves_recover_every_camera_within_its_standard_errors(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, intrinsics = files
    out_file, rows = tmp_path / "calibrated.toml", tmp_path / "rows.csv"
    argv = ["--cameras", str(intrinsics), "--simulate", str(truth), "--seed", "4"]
    status, out, err = calibrate(
        [*argv, "--write", str(out_file), "--save-observations", str(rows), "--json"], capsys
    )
    assert status == 0, err
    report = json.loads(out)["cameras"]
    assert [entry["camera"] for entry in report] == ["c0", "c1"]
    for entry, camera, fitted in zip(report, true_cameras(), load_cameras(out_file), strict=True):
        assert entry["points"] == 27
        error = np.array(entry["centre_error_mm"])
        assert np.all(np.abs(error) < 4 * np.array(entry["centre_se_mm"]))
        assert np.all(
            np.abs(fitted.rotation_rad - camera.rotation_rad) < 4 * fitted.rotation_se_rad
        )
        assert np.all(
            np.abs(fitted.translation_mm - camera.translation_mm) < 4 * fitted.translation_se_mm
        )
        assert 0.4 < entry["reduced_chi2"] < 2.0  # the centroid's own sigmas are right
    # the recorded rows give the same calibration through --observations
    with rows.open() as handle:
        table = list(csv.DictReader(handle))
    assert len(table) == 54
    status, out, err = calibrate(
        ["--cameras", str(intrinsics), "--observations", str(rows), "--json"], capsys
    )
    assert status == 0, err
    again = json.loads(out)["cameras"]
    for first, second in zip(report, again, strict=True):
        assert second["centre_mm"] == pytest.approx(first["centre_mm"], abs=1e-9)


def test_the_text_output_is_a_camera_file(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, intrinsics = files
    status, out, _ = calibrate(
        ["--cameras", str(intrinsics), "--simulate", str(truth), "--per-axis", "2"], capsys
    )
    assert status == 0
    assert out.startswith("# c0: 8 positions")
    printed = tmp_path / "printed.toml"
    printed.write_text(out)
    assert [c.name for c in load_cameras(printed)] == ["c0", "c1"]


def write_rows(path: Path, rows: list[list[object]]) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["camera", "x_mm", "y_mm", "z_mm", "x_px", "y_px"])
        writer.writerows(rows)


def test_bad_observations_are_one_line_and_exit_2(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, intrinsics = files
    rows = tmp_path / "rows.csv"
    write_rows(rows, [["c0", 1, 2, 3, "four", 5]])
    status, _, err = calibrate(["--cameras", str(intrinsics), "--observations", str(rows)], capsys)
    assert status == 2
    assert err.strip().count("\n") == 0 and "line 2: not a number" in err
    write_rows(rows, [["elsewhere", 1, 2, 3, 4, 5]])
    status, _, err = calibrate(["--cameras", str(intrinsics), "--observations", str(rows)], capsys)
    assert status == 2 and "unknown camera(s): elsewhere" in err
    status, _, err = calibrate(
        ["--cameras", str(tmp_path / "none.toml"), "--observations", str(rows)], capsys
    )
    assert status == 2 and "none.toml: no such file" in err


def test_positions_on_one_line_fail_with_exit_1(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, intrinsics = files
    cameras = true_cameras()
    line = np.array(TARGET) + np.outer(np.linspace(-40.0, 40.0, 6), [1.0, 0.0, 0.0])
    rows: list[list[object]] = []
    for camera in cameras:
        for point, pixel in zip(line, project(camera, line), strict=True):
            rows.append([camera.name, *point, *pixel])
    path = tmp_path / "line.csv"
    write_rows(path, rows)
    status, _, err = calibrate(["--cameras", str(intrinsics), "--observations", str(path)], capsys)
    assert status == 1
    assert "one line" in err


def test_the_command_is_part_of_thermocomp() -> None:
    result = run_cli(["calibrate", "cameras", "--help"])
    assert result.returncode == 0, result.stderr
    assert "--observations CSV" in result.stdout and "--simulate TRUTH" in result.stdout


def test_the_marker_offset_is_fitted_when_the_tool_turns(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, intrinsics = files
    base = ["--cameras", str(intrinsics), "--simulate", str(truth), "--seed", "2", "--turn", "0.3"]
    marker = ["--true-marker", "10,-5,60", "--json"]
    status, out, err = calibrate([*base, *marker, "--fit-marker"], capsys)
    assert status == 0, err
    result = json.loads(out)
    error = np.array(result["marker_mm"]) - [10.0, -5.0, 60.0]
    assert np.all(np.abs(error) < 4 * np.array(result["marker_se_mm"]))
    for entry in result["cameras"]:
        assert np.all(np.abs(entry["centre_error_mm"]) < 4 * np.array(entry["centre_se_mm"]))
    # the same moves with the offset given: each camera on its own, the offset not fitted
    status, out, err = calibrate([*base, *marker, "--marker", "10,-5,60"], capsys)
    assert status == 0, err
    given = json.loads(out)
    assert given["marker_se_mm"] is None
    for entry in given["cameras"]:
        assert np.all(np.abs(entry["centre_error_mm"]) < 4 * np.array(entry["centre_se_mm"]))
    # a tool that never turns cannot show where the marker is on it
    status, _, err = calibrate(
        ["--cameras", str(intrinsics), "--simulate", str(truth), "--fit-marker"], capsys
    )
    assert status == 1 and "never turns" in err
