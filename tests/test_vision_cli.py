"""``thermocomp centroid``: files, folders and globs in natural order, JSON and CSV output,
a time base with drift, and one named error per bad file while the batch goes on."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from api.cli import build_parser
from config.settings import CameraSettings
from daemon.vision import render_spot
from daemon.vision.cli import collect_files, natural_key
from tests.helpers import run_main

SHAPE = (96, 128)
UM_PER_PX = (10.22, 9.72)  # the thesis's calibration, given explicitly where it matters


def centroid(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """Run the command in-process; (exit status, stdout, stderr)."""
    parsed = build_parser().parse_args(["centroid", *args])
    status = parsed.handler(parsed)
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def write_spot(path: Path, centre: tuple[float, float], seed: int) -> None:
    image = render_spot(
        SHAPE,
        centre,
        3.0,
        0.6,
        rng=np.random.default_rng(seed),
        background=50,
        read_noise_counts=5,
    )
    assert cv2.imwrite(str(path), image)


@pytest.fixture
def frames(tmp_path: Path) -> dict[str, tuple[float, float]]:
    """image1, image2, image10 with known centres (written out of natural order)."""
    centres = {
        "image10.png": (70.25, 40.5),
        "image2.png": (60.5, 45.75),
        "image1.png": (50.0, 50.0),
    }
    for seed, (name, centre) in enumerate(centres.items()):
        write_spot(tmp_path / name, centre, seed)
    return centres


def test_natural_order() -> None:
    names = [Path(n) for n in ("image10.png", "image2.png", "Image1.png", "image1b.png")]
    assert sorted(names, key=natural_key) == [
        Path("Image1.png"),
        Path("image1b.png"),
        Path("image2.png"),
        Path("image10.png"),
    ]


def test_files_folders_and_globs_are_collected_once(
    tmp_path: Path, frames: dict[str, tuple[float, float]]
) -> None:
    (tmp_path / "notes.txt").write_text("not a frame")
    by_folder = collect_files([str(tmp_path)])
    assert [p.name for p in by_folder] == ["image1.png", "image2.png", "image10.png"]
    mixed = collect_files([str(tmp_path / "image1*.png"), str(tmp_path / "image10.png")])
    assert [p.name for p in mixed] == ["image1.png", "image10.png"]


def test_json_reports_every_frame_in_natural_order(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, frames: dict[str, tuple[float, float]]
) -> None:
    status, out, _ = centroid(capsys, str(tmp_path), "--json")
    assert status == 0
    records = json.loads(out)
    assert [Path(r["file"]).name for r in records] == ["image1.png", "image2.png", "image10.png"]
    default_um_per_px = CameraSettings().um_per_px  # no --um-per-px: the settings' value
    for record in records:
        x, y = frames[Path(record["file"]).name]
        assert record["error"] is None
        assert record["x_px"] == pytest.approx(x, abs=0.01)
        assert record["y_px"] == pytest.approx(y, abs=0.01)
        assert record["x_um"] == pytest.approx(record["x_px"] * default_um_per_px[0])
        assert record["y_um"] == pytest.approx(record["y_px"] * default_um_per_px[1])
        assert len(record["histogram"]) == 10
        assert record["peak"] > 0.5 * 65535


def test_csv_matches_json(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, frames: dict[str, tuple[float, float]]
) -> None:
    _, as_json, _ = centroid(capsys, str(tmp_path), "--json", "--um-per-px", "2", "3")
    status, as_csv, _ = centroid(capsys, str(tmp_path), "--csv", "--um-per-px", "2", "3")
    assert status == 0
    rows = list(csv.DictReader(io.StringIO(as_csv)))
    for row, record in zip(rows, json.loads(as_json), strict=True):
        assert row["file"] == record["file"]
        assert float(row["x_um"]) == pytest.approx(record["x_px"] * 2)
        assert float(row["y_um"]) == pytest.approx(record["y_px"] * 3)
        assert [int(row[f"histogram_{i}"]) for i in range(10)] == record["histogram"]
        assert row["error"] == ""


def test_time_base_gives_drift_from_the_first_frame(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, frames: dict[str, tuple[float, float]]
) -> None:
    scale = ("--um-per-px", *map(str, UM_PER_PX))
    status, out, _ = centroid(capsys, str(tmp_path), "--json", "--interval", "120", *scale)
    assert status == 0
    records = json.loads(out)
    assert [r["t_s"] for r in records] == [0, 120, 240]
    first = records[0]
    for record in records:
        assert record["drift_x_um"] == pytest.approx(record["x_um"] - first["x_um"])
        assert record["drift_y_um"] == pytest.approx(record["y_um"] - first["y_um"])
    # image10 moved (20.25, -9.5) px from image1
    assert records[2]["drift_x_um"] == pytest.approx(20.25 * UM_PER_PX[0], abs=0.2)
    assert records[2]["drift_y_um"] == pytest.approx(-9.5 * UM_PER_PX[1], abs=0.2)

    times = tmp_path / "time.txt"
    times.write_text("0.0\n3.5\n9.25\n")
    _, out, _ = centroid(capsys, str(tmp_path / "*.png"), "--csv", "--times", str(times))
    assert [float(row["t_s"]) for row in csv.DictReader(io.StringIO(out))] == [0.0, 3.5, 9.25]


def test_thesis_method_from_the_command_line(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, frames: dict[str, tuple[float, float]]
) -> None:
    status, out, _ = centroid(
        capsys,
        str(tmp_path / "image1.png"),
        "--json",
        "--method",
        "thesis",
        "--low",
        "0.05",
        "--box",
        "20",
    )
    record = json.loads(out)[0]
    assert status == 0 and record["method"] == "thesis"
    assert record["x_px"] == pytest.approx(50.0, abs=0.05)
    status, out, _ = centroid(
        capsys, str(tmp_path / "image1.png"), "--json", "--method", "thesis", "--low", "65000"
    )
    assert status == 1
    assert json.loads(out)[0]["error"].startswith("threshold too high")


def test_each_bad_file_gets_its_own_error_and_the_batch_goes_on(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    write_spot(tmp_path / "f1.png", (60.0, 50.0), 1)
    assert cv2.imwrite(str(tmp_path / "f2.png"), np.zeros(SHAPE, np.uint16))
    noise = render_spot(
        SHAPE, peak_fraction=0.0, rng=np.random.default_rng(2), background=80, read_noise_counts=5
    )
    assert cv2.imwrite(str(tmp_path / "f3.png"), noise)
    assert cv2.imwrite(str(tmp_path / "f4.png"), render_spot(SHAPE, (0.5, 50.0), 3.0, 0.5))
    (tmp_path / "f5.png").write_bytes(b"this is not a PNG")
    assert cv2.imwrite(str(tmp_path / "f6.png"), render_spot((64, 64), (30.0, 30.0), 3.0))
    colour = np.zeros((*SHAPE, 3), np.uint8)
    colour[:, :, 2] = render_spot(SHAPE, (70.0, 40.0), 3.0, 0.6, bit_depth=8)  # red channel
    assert cv2.imwrite(str(tmp_path / "f7.png"), colour)
    write_spot(tmp_path / "f8.png", (65.0, 52.0), 3)

    status, out, err = centroid(capsys, str(tmp_path), "--json")
    assert status == 1
    assert "5 of 8 frames failed" in err
    errors = {Path(r["file"]).name: r["error"] for r in json.loads(out)}
    assert errors["f1.png"] is None and errors["f8.png"] is None
    assert errors["f2.png"].startswith("blank frame")
    assert errors["f3.png"].startswith("no spot above the noise")
    assert errors["f4.png"].startswith("spot cut by the frame edge")
    assert errors["f5.png"] == "unreadable or not an image file"
    assert errors["f6.png"].startswith("wrong dimensions: expected 128x96 px, got 64x64")
    assert errors["f7.png"] is None  # a colour file is measured on its red channel


def test_usage_errors_exit_2(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    status, _, err = centroid(capsys, str(tmp_path / "nothing*.png"))
    assert status == 2 and "no file matches" in err
    write_spot(tmp_path / "a.png", (60.0, 50.0), 1)
    short = tmp_path / "time.txt"
    short.write_text("")
    status, _, err = centroid(capsys, str(tmp_path / "a.png"), "--times", str(short))
    assert status == 2 and "0 finite times for 1 frames" in err
    with pytest.raises(SystemExit) as both:
        centroid(capsys, str(tmp_path), "--json", "--csv")
    assert both.value.code == 2 and "not allowed with" in capsys.readouterr().err
    with pytest.raises(SystemExit) as helped:
        centroid(capsys, "--help")
    assert helped.value.code == 0 and "natural order" in capsys.readouterr().out


def test_the_installed_command_exits_2_on_bad_paths_without_a_traceback(tmp_path: Path) -> None:
    result = run_main(["centroid", str(tmp_path / "missing.png")])
    assert result.returncode == 2
    assert "no such file or folder" in result.stderr and "Traceback" not in result.stderr


def test_the_light_options_agree_with_the_methods() -> None:
    from daemon.commands.centroid_options import METHOD_CHOICES
    from daemon.vision import METHODS

    assert METHOD_CHOICES == METHODS
