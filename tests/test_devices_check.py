"""`thermocomp devices check` through the real CLI on the bench (what it prints, the preview PNG
with the spot and the regions drawn, failures one line each) and GET /devices/preview through
a real uvicorn server (a PNG while idle, 409 during a run)."""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from api.app import create_app
from daemon.service import Daemon
from daemon.vision.preview import GAP_PX, HEADER_PX, REGION_COLOUR, SPOT_COLOUR, SPOT_RING_PX
from drivers.sim.devices import IR_SHAPE
from tests.helpers import REPO_ROOT, run_cli, run_main
from tests.test_api_runs import CONTROL_HEADERS, bench_settings, wait_state
from tests.test_api_server import serve

SIM = str(REPO_ROOT / "config" / "sim.toml")
CHIP = (582, 752)  # the bench camera's default frame (rows, columns)


def write_config(tmp_path: Path, extra: str) -> Path:
    path = tmp_path / "check.toml"
    path.write_text(Path(SIM).read_text() + "\n" + extra)
    return path


def colour_mask(image: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    mask: np.ndarray = np.all(image == np.array(colour, np.uint8), axis=2)
    return mask


@pytest.mark.slow
def test_check_on_the_bench_prints_every_device_and_draws_the_preview(tmp_path: Path) -> None:
    config = write_config(
        tmp_path,
        '[[ir.regions]]\nname = "shaft"\nx = 20\ny = 50\nwidth = 10\nheight = 20\nnode = "2"\n',
    )
    preview = tmp_path / "preview.png"
    result = run_main(["devices", "check", "--config", str(config), "--preview", str(preview)])
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert "camera: 752x582 px, uint16, 16-bit" in out
    spot = re.search(r"camera: spot found at \(([\d.]+), ([\d.]+)\) px", out)
    assert spot is not None, out
    x, y = float(spot.group(1)), float(spot.group(2))
    # the bench starts with the spot at the chip's centre (drivers/sim/bench.py)
    assert x == pytest.approx((CHIP[1] - 1) / 2, abs=0.3)
    assert y == pytest.approx((CHIP[0] - 1) / 2, abs=0.3)
    assert "ir: 160x120 px" in out
    assert re.search(r"ir: region shaft \(node 2\): mean [\d.]+ degC, max [\d.]+ degC", out)
    assert re.search(r"robot: connected, pose x [\d.-]+ y [\d.-]+ z [\d.-]+ mm", out)

    image = cv2.imread(str(preview), cv2.IMREAD_COLOR)
    assert image is not None
    factor = CHIP[0] // IR_SHAPE[0]
    assert image.shape == (HEADER_PX + CHIP[0], CHIP[1] + GAP_PX + IR_SHAPE[1] * factor, 3)
    # the ring around the centroid: red pixels at its radius, none far from it
    camera = image[HEADER_PX:, : CHIP[1]].astype(int)  # BGR; anti-aliased red on grey
    assert SPOT_COLOUR == (0, 0, 255)
    red = np.argwhere(camera[:, :, 2] - np.maximum(camera[:, :, 0], camera[:, :, 1]) > 60)
    assert len(red) > 20
    distances = np.hypot(red[:, 1] - x, red[:, 0] - y)
    assert distances.max() <= 2 * SPOT_RING_PX + 2
    assert np.any(np.abs(distances - SPOT_RING_PX) < 1.0)
    # the region's rectangle on the enlarged thermal image
    ir = image[HEADER_PX:, CHIP[1] + GAP_PX :]
    box = colour_mask(ir, REGION_COLOUR)
    assert box[50 * factor, 20 * factor : 30 * factor].all()  # its top edge
    assert box[70 * factor - 1, 20 * factor : 30 * factor].all()  # its bottom edge
    assert not box[60 * factor, 25 * factor]  # inside: the image, not the frame


@pytest.mark.slow
def test_json_output_and_a_failing_device_named_in_one_line(tmp_path: Path) -> None:
    # a region beyond the 160 x 120 thermal image: the IR read fails, the rest is described
    config = write_config(
        tmp_path, '[[ir.regions]]\nname = "off"\nx = 150\ny = 0\nwidth = 20\nheight = 5\n'
    )
    result = run_main(["devices", "check", "--config", str(config), "--json"])
    assert result.returncode == 1
    data = json.loads(result.stdout)
    assert data["camera"]["width_px"] == CHIP[1] and data["camera"]["spot"] is not None
    assert data["ir"] is None and data["robot"]["link"] == "connected"
    assert "lies outside the 160x120 thermal frame" in data["errors"]["ir"]
    failures = [line for line in result.stderr.splitlines() if "devices check: ir:" in line]
    assert len(failures) == 1


@pytest.mark.slow
@pytest.mark.skipif(
    importlib.util.find_spec("pypylon") is None,
    reason="pypylon (the genicam extra) is not installed: pip install 'thermocomp[genicam]'",
)
def test_a_missing_camera_is_one_line_and_exit_status_1(tmp_path: Path) -> None:
    config = write_config(tmp_path, "")
    text = config.read_text().replace(
        '[camera]\ndriver = "sim"', '[camera]\ndriver = "genicam"\nserial = "21999999"'
    )
    config.write_text(text)
    result = run_cli(["devices", "check", "--config", str(config)], env={"PYLON_CAMEMU": "1"})
    assert result.returncode == 1
    # the other devices are still checked and described (issue 28)
    assert "ir: 160x120 px" in result.stdout and "robot: connected" in result.stdout
    errors = [line for line in result.stderr.splitlines() if "devices check" in line]
    assert errors == [
        "thermocomp devices check: camera: no GenICam camera with serial '21999999' "
        "(found: Emulation 0815-0000)"
    ]


def test_a_robot_that_does_not_answer_leaves_the_cameras_checked(tmp_path: Path) -> None:
    """Bring-up (issue 28): the robot's serial adapter is not plugged in yet; the camera and
    the IR camera are still opened, grabbed from and described, the robot is one line, exit 1
    (before: "cannot open the devices" and nothing checked)."""
    config = write_config(tmp_path, "")
    text = config.read_text().replace(
        '[robot]\ndriver = "sim"', '[robot]\ndriver = "c500c"\nport = "/dev/ttyNOSUCH7"'
    )
    assert 'port = "/dev/ttyNOSUCH7"' in text
    config.write_text(text)
    result = run_main(["devices", "check", "--config", str(config)])
    assert result.returncode == 1, result.stderr
    assert "camera: 752x582 px" in result.stdout and "camera: spot found at" in result.stdout
    assert "ir: 160x120 px" in result.stdout
    assert "robot: FAILED:" in result.stdout and "/dev/ttyNOSUCH7" in result.stdout
    errors = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and errors[0].startswith("thermocomp devices check: robot: ")
    assert "Traceback" not in result.stderr


@pytest.mark.slow
async def test_preview_endpoint_while_idle_and_refused_during_a_run(tmp_path: Path) -> None:
    app = create_app(bench_settings(tmp_path / "data"), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        response = await client.get("/api/v1/devices/preview")
        assert response.status_code == 200
        assert response.headers["content-type"] == "image/png"
        image = cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_COLOR)
        assert image is not None and image.shape[0] == HEADER_PX + CHIP[0]
        x, y = (float(v) for v in response.headers["x-thermocomp-spot-px"].split(","))
        # near the centre: the accelerated bench's camera stand has drifted a little since
        assert (x, y) == (pytest.approx(375.5, abs=2), pytest.approx(290.5, abs=2))

        body = {"duration_s": 3600, "step_s": 1.0, "compensation": "off"}
        started = await client.post("/api/v1/runs", json=body, headers=CONTROL_HEADERS)
        assert started.status_code == 201, started.text
        await wait_state(client, "running")
        refused = await client.get("/api/v1/devices/preview")
        assert refused.status_code == 409
        assert "while idle" in refused.json()["message"]
        stop = await client.post(
            f"/api/v1/runs/{started.json()['id']}/stop", headers=CONTROL_HEADERS
        )
        assert stop.status_code in (200, 202), stop.text


@pytest.mark.slow
@pytest.mark.skipif(
    importlib.util.find_spec("pypylon") is None,
    reason="pypylon (the genicam extra) is not installed: pip install 'thermocomp[genicam]'",
)
def test_check_through_emulated_genicam_camera_and_ir(tmp_path: Path) -> None:
    config = tmp_path / "genicam.toml"
    config.write_text(
        '[camera]\ndriver = "genicam"\nserial = "0815-0000"\nbit_depth = 12\n'
        'exposure_us = 1000.0\n[ir]\ndriver = "genicam-radiometric"\nserial = "0815-0001"\n'
        'conversion = "linear"\nlinear_resolution_k = 0.01\n'
    )
    result = run_cli(["devices", "check", "--config", str(config)], env={"PYLON_CAMEMU": "2"})
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == (
        "camera: 752x582 px, uint16, 12-bit, counts 0..4080, frame time from trigger"
    )
    assert lines[1].startswith("camera: no spot:")  # the emulation's test image has none
    # the whole emulated sensor in Mono16, read as 0.01 K counts: 0 .. 65280 -> -273.15 .. 379.65
    assert lines[2] == "ir: 1024x1040 px, -273.15..379.65 degC"
    assert "ir: no regions configured ([[ir.regions]]): place them on the preview" in lines
    # planck mode on the same emulated camera: it has no R, B, F, O
    config.write_text(config.read_text().replace('"linear"', '"planck"'))
    refused = run_cli(["devices", "check", "--config", str(config)], env={"PYLON_CAMEMU": "2"})
    assert refused.returncode == 1
    # the camera and the robot are still checked and described (issue 28)
    assert refused.stdout.startswith("camera: 752x582 px") and "robot: connected" in refused.stdout
    assert (
        "thermocomp devices check: ir: Emulation 0815-0001 has no Planck registers (R, B, F, O "
        "missing)"
    ) in refused.stderr
