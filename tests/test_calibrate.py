"""Camera calibration (issue 18): the pure fit against analytic oracles, and `thermocomp calibrate
camera` on the bench with a rotated, rescaled sim camera, its safety limits and bad input."""

from __future__ import annotations

import importlib.util
import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from config import Settings, load_settings
from daemon.commands import calibrate as calibrate_cli
from daemon.commands.calibrate import (
    SpotLostError,
    checked_pattern,
    measure_pattern,
    split_move,
    write_camera_keys,
)
from daemon.vision.calibration import (
    CalibrationError,
    camera_to_robot,
    fit_calibration,
    pattern_offsets_um,
)
from drivers.base import MoveResult, Vector3
from drivers.clock import VirtualClock
from drivers.factory import open_devices
from tests.helpers import run_cli, run_in_process, run_main

PITCH = (10.22, 9.72)  # the thesis's calibration (um per px)


def project(
    offsets: list[tuple[float, float]], pitch: tuple[float, float], rotation_deg: float
) -> list[tuple[float, float]]:
    """The forward model written out: centroids of a chip turned by ``rotation_deg``."""
    angle = math.radians(rotation_deg)
    c, s = math.cos(angle), math.sin(angle)
    return [
        (375.5 + (c * u - s * v) / pitch[0], 290.5 + (s * u + c * v) / pitch[1]) for u, v in offsets
    ]


def test_exact_centroids_give_the_exact_calibration() -> None:
    offsets = pattern_offsets_um(500.0, 250.0)
    result = fit_calibration(offsets, project(offsets, PITCH, 3.0))
    assert result.um_per_px == pytest.approx(PITCH, rel=1e-12)
    assert result.rotation_deg == pytest.approx(3.0, abs=1e-10)
    assert result.skew_deg == pytest.approx(0.0, abs=1e-10)
    assert result.residual_px == pytest.approx(0.0, abs=1e-9)
    assert result.points == 25


def test_standard_errors_match_the_analytic_oracle() -> None:
    # Residuals orthogonal to the design (1, u, v) leave the fit unchanged and make the
    # residual variance exactly |e|^2 / (n - 3): then, at rotation 0 on a centred grid,
    # se(p) = p^2 s / sqrt(sum u^2) and se(t) = sqrt(p_x^2 s_x^2 + p_y^2 s_y^2) / (2 sqrt(S)).
    offsets = pattern_offsets_um(500.0, 250.0)
    uv = np.asarray(offsets)
    design = np.column_stack([np.ones(len(uv)), uv])
    projector = np.eye(len(uv)) - design @ np.linalg.pinv(design)
    rng = np.random.default_rng(7)
    e_x = projector @ rng.normal(size=len(uv))
    e_y = projector @ rng.normal(size=len(uv))
    s_x, s_y = 0.05, 0.08  # px
    e_x *= s_x * math.sqrt(len(uv) - 3) / np.linalg.norm(e_x)
    e_y *= s_y * math.sqrt(len(uv) - 3) / np.linalg.norm(e_y)
    exact = np.asarray(project(offsets, PITCH, 0.0))
    noisy = [(x + dx, y + dy) for (x, y), dx, dy in zip(exact, e_x, e_y, strict=True)]
    result = fit_calibration(offsets, noisy)
    sum_u2 = float(np.sum(uv[:, 0] ** 2))  # = sum v^2 on the square grid
    assert result.um_per_px == pytest.approx(PITCH, rel=1e-12)
    assert result.um_per_px_se[0] == pytest.approx(PITCH[0] ** 2 * s_x / math.sqrt(sum_u2))
    assert result.um_per_px_se[1] == pytest.approx(PITCH[1] ** 2 * s_y / math.sqrt(sum_u2))
    expected_t = math.hypot(PITCH[0] * s_x, PITCH[1] * s_y) / (2 * math.sqrt(sum_u2))
    assert result.rotation_se_deg == pytest.approx(math.degrees(expected_t))


def test_collinear_offsets_are_a_singular_fit() -> None:
    offsets = [(u, 0.5 * u) for u in (-200.0, -100.0, 0.0, 100.0, 200.0)]
    with pytest.raises(CalibrationError, match="singular fit: the offsets do not span"):
        fit_calibration(offsets, project(offsets, PITCH, 0.0))
    with pytest.raises(CalibrationError, match="at least 4"):
        fit_calibration(offsets[:3], project(offsets[:3], PITCH, 0.0))
    still = [(0.0, 0.0)] * 5
    with pytest.raises(CalibrationError, match="singular"):
        fit_calibration(pattern_offsets_um(200, 100)[:5], still)


def test_camera_to_robot_inverts_the_camera_model() -> None:
    # a robot offset along x (u) and z (-v) seen on a chip turned by 5 degrees
    angle = math.radians(5.0)
    u, v = 30.0, -12.0  # um: robot x = 30, z = +12
    drift = (math.cos(angle) * u - math.sin(angle) * v, math.sin(angle) * u + math.cos(angle) * v)
    assert camera_to_robot(drift, 5.0) == pytest.approx((30.0, 0.0, 12.0))
    assert camera_to_robot((7.0, -3.0), 0.0) == pytest.approx((7.0, 0.0, 3.0))


def test_the_pattern_is_a_serpentine_grid_within_the_limits() -> None:
    offsets = pattern_offsets_um(500.0, 250.0)
    assert sorted(offsets) == sorted(
        (u, v) for u in (-500, -250, 0, 250, 500) for v in (-500, -250, 0, 250, 500)
    )
    steps = [math.dist(a, b) for a, b in itertools.pairwise(offsets)]
    assert max(steps) == pytest.approx(250.0)
    with pytest.raises(calibrate_cli.PatternError, match=r"reaches 1\.414 mm .* = 1 mm"):
        checked_pattern(
            Settings.model_validate({"compensation": {"max_total_offset_mm": 1.0}}), 1.0, 0.5
        )


def test_long_moves_are_split_on_the_straight_line() -> None:
    points = split_move((0.0, 0.0, 0.0), (0.5, 0.0, -0.2), 0.2)
    assert points[-1] == (0.5, 0.0, -0.2) and len(points) == 3
    assert all(
        abs(b[0] - a[0]) <= 0.2 + 1e-12 for a, b in zip([(0, 0, 0), *points], points, strict=False)
    )


def bench_settings(tmp_path: Path, **camera: Any) -> Path:
    lines = [
        "[bench]",
        "camera_rotation_deg = -4.0",
        "camera_scale = 1.15",
        "[camera]",
        'driver = "sim"',
        *(f"{key} = {json.dumps(value)}" for key, value in camera.items()),
        "[compensation]",
        "max_step_change_mm = 0.2",
    ]
    path = tmp_path / "bench.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.slow
def test_the_bench_calibration_recovers_pitch_and_rotation(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = bench_settings(tmp_path)
    status, out, err = run_in_process(
        calibrate_cli.register, ["calibrate", "camera", "--config", str(config), "--json"], capsys
    )
    assert status == 0, err
    result = json.loads(out)
    truth = (8.6 / 1.15, 8.3 / 1.15)  # the sim camera's pitch over its magnification
    assert result["bench_truth"] == {"um_per_px": pytest.approx(list(truth)), "rotation_deg": -4.0}
    for axis in (0, 1):
        assert result["um_per_px"][axis] == pytest.approx(truth[axis], rel=0.005)
        assert 0 < result["um_per_px_se"][axis] < 0.002 * truth[axis]
    assert result["rotation_deg"] == pytest.approx(-4.0, abs=0.1)
    assert 0 < result["rotation_se_deg"] < 0.05
    assert result["points"] == 25


def test_write_sets_the_camera_keys_and_keeps_the_rest(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = bench_settings(tmp_path, um_per_px=[1.0, 1.0])
    status, out, err = run_in_process(
        calibrate_cli.register,
        ["calibrate", "camera", "--config", str(config), "--write", str(config)],
        capsys,
    )
    assert status == 0, err
    assert "um_per_px = [" in out and "rotation_deg = " in out
    settings = load_settings(config, environ={})
    assert settings.camera.um_per_px == pytest.approx((8.6 / 1.15, 8.3 / 1.15), rel=0.005)
    assert settings.camera.rotation_deg == pytest.approx(-4.0, abs=0.1)
    assert settings.bench.camera_scale == 1.15 and settings.compensation.max_step_change_mm == 0.2
    assert config.read_text().count("um_per_px") == 1


def test_write_camera_keys_adds_a_table_when_there_is_none(tmp_path: Path) -> None:
    path = tmp_path / "lab.toml"
    path.write_text('# lab\n[robot]\nport = "/dev/ttyS0"\n')
    write_camera_keys(path, {"rotation_deg": "1.5"})
    assert load_settings(path, environ={}).camera.rotation_deg == 1.5
    assert path.read_text().startswith("# lab\n[robot]")


def test_a_pattern_beyond_the_limits_moves_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = bench_settings(tmp_path)
    status, out, err = run_in_process(
        calibrate_cli.register,
        ["calibrate", "camera", "--config", str(config), "--size", "4", "--step", "2"],
        capsys,
    )
    assert status == 2 and out == ""
    assert err.strip().count("\n") == 0
    assert "beyond compensation.max_total_offset_mm = 5 mm" in err


async def test_a_spot_leaving_the_chip_stops_and_returns_to_the_goal(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # a 752 x 582 px chip of 8.6 x 8.3 um: +-3.2 x 2.4 mm; a 3 mm pattern leaves it
    settings = Settings.model_validate(
        {"camera": {"driver": "sim"}, "compensation": {"max_total_offset_mm": 10.0}}
    )
    offsets = checked_pattern(settings, 3.0, 1.5)
    sent: list[Vector3] = []  # every offset commanded to the real driver (a spy, no fake)
    async with open_devices(settings, VirtualClock()) as devices:
        move = devices.robot.move_absolute

        async def recorded(offset_mm: Vector3, *args: Any, **kwargs: Any) -> MoveResult:
            sent.append(offset_mm)
            result: MoveResult = await move(offset_mm, *args, **kwargs)
            return result

        monkeypatch.setattr(devices.robot, "move_absolute", recorded)
        with pytest.raises(SpotLostError, match=r"offset \(-3000\.0, -3000\.0\) um") as caught:
            await measure_pattern(devices, settings, offsets)
        pose = await devices.robot.actual_pose()
        goal = sent[-1]
    assert "\n" not in str(caught.value)
    assert goal == (0.0, 0.0, 0.0)  # back at the goal
    limit = 3.0 + 1e-9
    assert all(abs(x) <= limit and y == 0 and abs(z) <= limit for x, y, z in sent)
    assert all(
        max(abs(b[i] - a[i]) for i in range(3)) <= settings.compensation.max_step_change_mm + 1e-9
        for a, b in zip([(0.0, 0.0, 0.0), *sent], sent, strict=False)
    )
    assert pose is not None


@pytest.mark.slow
@pytest.mark.skipif(
    importlib.util.find_spec("pypylon") is None,
    reason="pypylon (the genicam extra) is not installed: pip install 'thermocomp[genicam]'",
)
def test_a_missing_camera_is_one_line_and_nothing_moves(tmp_path: Path) -> None:
    config = tmp_path / "missing.toml"
    config.write_text('[camera]\ndriver = "genicam"\nserial = "21999999"\n')
    result = run_cli(["calibrate", "camera", "--config", str(config)], env={"PYLON_CAMEMU": "1"})
    assert result.returncode == 1 and result.stdout == ""
    errors = [line for line in result.stderr.splitlines() if "calibrate camera" in line]
    assert errors == [
        "thermocomp calibrate camera: camera: no GenICam camera with serial '21999999' "
        "(found: Emulation 0815-0000)"
    ]


def test_an_unsupported_pixel_format_is_a_configuration_error(tmp_path: Path) -> None:
    config = tmp_path / "format.toml"
    config.write_text('[camera]\ndriver = "genicam"\npixel_format = "Mono12p"\n')
    result = run_main(["calibrate", "camera", "--config", str(config)])
    assert result.returncode == 2 and result.stdout == ""
    assert f"{config}: camera.pixel_format: Input should be 'Mono8', 'Mono12' or 'Mono16'" in (
        result.stderr
    )
