"""``thermocomp budget`` (issue 32) on the simulated benches, through the real devices."""

import json
import math
from pathlib import Path

import pytest

from config import load_settings
from daemon.commands import budget
from daemon.vision.synthetic import cramer_rao_bound
from drivers.clock import VirtualClock
from drivers.sim.bench import Bench
from tests.helpers import REPO_ROOT, run_in_process
from tests.test_cli import SERVER_MODULES, imported_modules


def _budget(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict, str]:  # type: ignore[type-arg]
    status, out, err = run_in_process(budget.register, ["budget", "--json", *args], capsys)
    return status, (json.loads(out) if out.strip() else {}), err


@pytest.mark.slow  # half an hour of the bench's camera on its virtual clock
def test_bench_budget_measures_the_camera_drift_the_bench_has(
    capsys: pytest.CaptureFixture[str],
) -> None:
    status, data, err = _budget(
        capsys, "--drift-frames", "30", "--stationary-frames", "20", "--target", "5"
    )
    assert status == 0, err
    rows = {row["key"]: row for row in data["sources"]}
    # the bench's truth: this seed's stand drift, first order (drivers/sim/bench.py)
    truth = Bench(load_settings(), VirtualClock())
    seen = truth.stand_drift_amplitude_um * (1 - math.exp(-1800.0 / truth.stand_drift_tau_s))
    drift = rows["camera-drift"]
    assert drift["evidence"] == "measured"
    assert drift["delta_l_um"] == pytest.approx(seen, rel=0.05)
    assert drift["detail"]["tau_s"] == pytest.approx(truth.stand_drift_tau_s, rel=0.15)
    # the bench's spot does not shake: the scatter is the centroid's own
    centroid, vibration = rows["centroid"], rows["vibration"]
    assert centroid["detail"]["std_x_um"] == pytest.approx(
        centroid["detail"]["bound_x_um"], rel=0.4
    )
    assert vibration["delta_l_um"] < centroid["delta_l_um"]
    # the bound the frames report is the Cramér-Rao bound of the bench's spot (daemon/vision/
    # synthetic.py: 3 px, half of a 16-bit full scale, 5 e read noise, 8.6 um pixels; the gain
    # is the simulated sensor's own, which the camera reports: drivers/sim/devices.py)
    settings = load_settings()
    crb_px, _ = cramer_rao_bound(
        (settings.camera.height_px, settings.camera.width_px),
        ((settings.camera.width_px - 1) / 2, (settings.camera.height_px - 1) / 2),
        settings.bench.spot_sigma_px,
        settings.bench.spot_peak_fraction,
        settings.camera.bit_depth,
        read_noise_counts=settings.camera.read_noise_e / settings.bench.camera_gain_e_per_count,
        gain_e_per_count=settings.bench.camera_gain_e_per_count,
    )
    bound_um = crb_px * settings.camera.um_per_px[0]
    assert centroid["detail"]["bound_x_um"] == pytest.approx(bound_um, rel=0.05)
    # the expected deformation is the controller's model at steady state, 0.5 W per pad
    assert 100 < data["expected_um"] < 200
    assert rows["bending"]["delta_l_um"] == pytest.approx(0.00123, rel=0.02)
    assert rows["diode-hole"]["conditional"] == "if the diode is disturbed"
    assert data["resolves"] is True
    assert data["sources"][0]["key"] == "diode-hole"  # ranked: the largest first


def test_a_target_the_set_up_cannot_resolve_says_so(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, err = run_in_process(
        budget.register, ["budget", "--no-record", "--target", "0.1"], capsys
    )
    assert status == 1, err
    assert "CANNOT RESOLVE the target" in out and "IR temperature noise dominates" in out
    assert "not recorded (--no-record)" in out


def test_a_bad_setup_file_is_one_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    setup = tmp_path / "setup.toml"
    setup.write_text("cantilever_length_mm = -3\n")
    status, out, err = run_in_process(
        budget.register, ["budget", "--no-record", "--setup", str(setup)], capsys
    )
    assert status == 2 and not out
    assert err.count("\n") == 1 and "cantilever_length_mm" in err


def test_the_setup_file_changes_the_rows(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    setup = tmp_path / "setup.toml"
    setup.write_text("play_z_deg = 2.0\ndiode_lever_mm = 150\nheating_pads = false\n")
    _, base, _ = _budget(capsys, "--no-record")
    _, changed, _ = _budget(capsys, "--no-record", "--setup", str(setup))
    before = {row["key"]: row["delta_l_um"] for row in base["sources"]}
    after = {row["key"]: row["delta_l_um"] for row in changed["sources"]}
    assert after["misalignment-z"] == pytest.approx(
        before["misalignment-z"]
        * (1 - math.cos(math.radians(2)))
        / (1 - math.cos(math.radians(0.2))),
        rel=1e-9,
    )
    assert after["diode-hole"] == pytest.approx(2 * before["diode-hole"], rel=1e-6)
    assert "heating-pad" in before and "heating-pad" not in after


@pytest.mark.slow
def test_arm_budget_per_pose(capsys: pytest.CaptureFixture[str]) -> None:
    config = str(REPO_ROOT / "config" / "arm-sim.toml")
    status, data, err = _budget(
        capsys, "--config", config, "--drift-frames", "8", "--stationary-frames", "8"
    )
    assert status in (0, 1), err
    poses = {pose["pose"]: pose for pose in data["poses"]}
    assert poses and all(p["expected_um"] > 10 for p in poses.values())
    assert all(p["measurement_um"] and p["cameras_seeing"] >= 2 for p in poses.values())
    rows = {row["key"]: row for row in data["sources"]}
    assert rows["measurement-3d"]["delta_l_um"] == pytest.approx(
        max(p["measurement_um"] for p in poses.values())
    )
    assert rows["misalignment"]["evidence"] == "not applicable"
    assert rows["vibration"]["evidence"] == "measured"
    assert "centroid" not in rows  # in the 3-D measurement's row


def test_help_imports_no_numeric_stack() -> None:
    for command in ("budget", "cte"):
        heavy = imported_modules(command, "--help") & (SERVER_MODULES | {"scipy", "cv2"})
        assert not heavy, (command, heavy)


def test_save_keeps_the_latest_for_the_api(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from daemon.storage.budgets import read_saved_budget

    status, _, err = run_in_process(
        budget.register,
        ["budget", "--no-record", "--save", "--data-dir", str(tmp_path), "--target", "0.1"],
        capsys,
    )
    assert status == 1 and "budget.json" in err
    saved = read_saved_budget(tmp_path)
    assert saved is not None and saved["recorded"] is False and saved["target_um"] == 0.1
