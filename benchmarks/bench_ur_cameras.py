"""`thermocomp calibrate cameras --robot` on the UR bench (issue 31) beside the A465's on its
bench (the reference, same run): the fitted cameras against the bench's truth as the
controller's frame sees it, the tool position they then give, and the conditioning of a fit.

Each scenario runs the real command in process (the UR: its emulator over real TCP at its real
500 Hz cycle, the real driver, the bench's cameras; the A465: the C500C emulator over a pty on a
virtual clock) from a camera file perturbed from the truth (a lab's starting guess: each camera
moved by ``--guess-mm`` and turned by ``--guess-mrad``, random directions, seeded), and reports
per camera:

- the fitted centre's error from the truth in the controller's frame (um) and in its own
  standard errors; the fit's reprojection residual (px RMS) and reduced chi2;
- per station, the tool position error its fitted cameras give together: the markers at the
  station's taught pose (where the controller believes the tool is) projected through the true
  cameras without noise, measured with the fitted ones (daemon/run/arm/measure.py tool_pose,
  the meter of a followed run), and with the guess for comparison: the absolute error (um),
  and the error of a 200 um drift with 50 urad of turn (what a followed run records: the pose
  relative to the run's first measurement);
- the conditioning of the fit on the rows it used: the condition number of the weighted
  Jacobian of the pixels in the pose (extrinsics: what is fitted) and in the pose plus the
  intrinsics fx, fy, cx, cy and k1 (a full model), and the full model's 1-sigma of the focal
  length (relative) and of the principal point (px).

Scenarios: the A465's ``--station place`` (reference); the UR's camera-calibration program
(12 s dwells, both stations, 27 offsets of +-0.5 mm); its production program (1 s and 0.5 s
dwells); the calibration program from the truth itself (no perturbation); and one written to
break it: a guess 15 mm and 8 mrad off (markers beyond the 96 px search window).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from config import CONFIG_DIR, load_settings
from daemon.arm.duty import load_duty_cycle
from daemon.arm.kinematics import forward
from daemon.arm.loading import load_arm
from daemon.calibration.camera_observations import Observation, read_observations
from daemon.commands import calibrate as calibrate_cli
from daemon.run.arm.measure import MarkerView, tool_pose
from daemon.vision.cameras import load_cameras, write_cameras
from daemon.vision.multiview import CameraModel, project
from drivers.sim.arm_bench import ArmBench
from drivers.sim.arm_devices import bench_config
from drivers.sim.arm_markers import CameraRig
from drivers.sim.ur.controller import URController, URControllerConfig

DRIFT_MM = np.array([0.12, -0.1, 0.12])  # 200 um
DRIFT_TURN_RAD = np.array([30e-6, -20e-6, 30e-6])  # ~50 urad
PIXEL_SIGMA_PX = 0.03  # the views' 1-sigma for tool_pose (noise-free pixels)


def perturbed(cameras: Sequence[CameraModel], mm: float, mrad: float, seed: int) -> list[Any]:
    rng = np.random.default_rng(seed)
    out = []
    for camera in cameras:
        turn = rng.normal(0.0, 1e-3 * mrad / math.sqrt(3.0), 3)
        shift = rng.normal(0.0, mm / math.sqrt(3.0), 3)
        rotation = Rotation.from_rotvec(turn) * Rotation.from_rotvec(np.array(camera.rotation_rad))
        centre = camera.centre_mm + shift
        out.append(camera.with_pose(rotation.as_rotvec(), -rotation.as_matrix() @ centre))
    return out


def run_command(argv: list[str]) -> tuple[int, str, str, float]:
    parser = argparse.ArgumentParser(prog="thermocomp")
    calibrate_cli.register(parser.add_subparsers(dest="command", required=True))
    out, err = io.StringIO(), io.StringIO()
    start = time.monotonic()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        args = parser.parse_args(["calibrate", "cameras", *argv])
        status = int(args.handler(args))
    return status, out.getvalue(), err.getvalue(), time.monotonic() - start


def ur_lab(directory: Path, host: str, duty: str, guess: Path) -> tuple[Path, Any, Any]:
    """The UR lab file, its true cameras and the duty cycle's stations (name, q)."""
    text = (CONFIG_DIR / "ur5e-sim.toml").read_text(encoding="utf-8")
    text = text.replace('host = "127.0.0.1"', f'host = "{host}"')
    text = text.replace('data_dir = "data-ur"', f'data_dir = "{directory / "data"}"')
    text = text.replace('duty_cycle = "ur5e-pick-and-place"', f'duty_cycle = "{duty}"')
    text = text.replace("[arm]\n", f'[arm]\ncameras_file = "{guess}"\n')
    text = text.replace("[robot]\n", "[robot]\nur_timeout_s = 10.0\n")
    text += "\n[camera]\ngrab_timeout_s = 10.0\n"
    path = directory / "lab.toml"
    path.write_text(text, encoding="utf-8")
    settings = load_settings(path)
    controller = URController(
        URControllerConfig(
            duty=duty,
            seed=settings.bench.seed,
            camera_rig=CameraRig(count=settings.arm.cameras),
            markers_tool_mm=settings.arm.markers_mm,
            autoplay=False,
        )
    )
    stations = [(p.name, np.asarray(p.q_rad)) for p in load_duty_cycle(duty).measured_poses()]
    return path, controller.bench.cameras, stations


def a465_lab(directory: Path, guess: Path) -> tuple[Path, Any, Any]:
    text = (CONFIG_DIR / "arm-sim.toml").read_text(encoding="utf-8")
    text = text.replace('data_dir = "data-arm"', f'data_dir = "{directory / "data"}"')
    text = text.replace("[arm]\n", f'[arm]\ncameras_file = "{guess}"\n')
    path = directory / "lab.toml"
    path.write_text(text, encoding="utf-8")
    settings = load_settings(path)
    assert settings.arm.duty_cycle is not None
    arm = load_arm(settings.arm.arm_file)
    duty = load_duty_cycle(settings.arm.duty_cycle)
    bench = ArmBench(bench_config(settings, arm, duty, settings.bench.seed), arm=arm)
    stations = [(p.name, np.asarray(p.q_rad)) for p in duty.measured_poses()]
    return path, bench.cameras, stations


def reference_of(camera: CameraModel, fit: dict[str, Any]) -> CameraModel:
    """The truth in the controller's frame, from the fit and its reported errors."""
    rotation = np.array(fit["rotation_rad"]) - np.array(fit["rotation_error_rad"])
    centre = np.array(fit["centre_mm"]) - np.array(fit["centre_error_mm"])
    return camera.with_pose(rotation, -Rotation.from_rotvec(rotation).as_matrix() @ centre)


def views(cameras: Sequence[CameraModel], markers_world: np.ndarray) -> list[MarkerView]:
    out = []
    for camera in cameras:
        width, height = camera.image_size_px
        for k, (x, y) in enumerate(project(camera, markers_world)):
            if 0 <= x < width and 0 <= y < height:
                out.append(MarkerView(camera.name, k, float(x), float(y), PIXEL_SIGMA_PX))
    return out


def tool_errors(
    measured_with: Sequence[CameraModel],
    truth: Sequence[CameraModel],
    markers: np.ndarray,
    believed: np.ndarray,
) -> tuple[float, float]:
    """(absolute position error, drift error) in um (module docstring)."""
    drifted = believed.copy()
    drifted[:3, :3] = Rotation.from_rotvec(DRIFT_TURN_RAD).as_matrix() @ believed[:3, :3]
    drifted[:3, 3] = believed[:3, 3] + DRIFT_MM
    poses = []
    for pose in (believed, drifted):
        world = markers @ pose[:3, :3].T + pose[:3, 3]
        poses.append(tool_pose(measured_with, views(truth, world), markers, believed).pose)
    absolute = float(np.linalg.norm(poses[0][:3, 3] - believed[:3, 3]))
    drift = float(np.linalg.norm((poses[1][:3, 3] - poses[0][:3, 3]) - DRIFT_MM))
    return 1000.0 * absolute, 1000.0 * drift


def conditioning(camera: CameraModel, rows: Sequence[Observation]) -> dict[str, float]:
    """Condition numbers of the weighted, column-scaled Jacobian (pose; pose + fx, fy, cx, cy,
    k1) on the rows, and the full model's 1-sigma of f (relative) and of the principal point."""
    points = np.array([r.position_mm for r in rows])  # the markers' (arm.markers_mm given)
    sigmas = np.array([r.sigma_px or (0.03, 0.03) for r in rows]).reshape(-1)
    _, jacobian = cv2.projectPoints(
        points.reshape(-1, 1, 3),
        camera.rotation_rad,
        camera.translation_mm,
        camera.matrix,
        camera.distortion,
    )
    weighted = jacobian / sigmas[:, None]
    pose = weighted[:, :6]
    full = weighted[:, :11]  # r, t, fx, fy, cx, cy, k1

    def cond(matrix: np.ndarray) -> float:
        scaled = matrix / np.linalg.norm(matrix, axis=0)
        values = np.linalg.svd(scaled, compute_uv=False)
        return float(values[0] / values[-1])

    covariance = np.linalg.pinv(full.T @ full)
    se = np.sqrt(np.diag(covariance))
    focal = float(camera.matrix[0, 0])
    return {
        "cond_pose": cond(pose),
        "cond_full": cond(full),
        "full_f_rel_sigma": float(se[6]) / focal,
        "full_c_sigma_px": float(max(se[8], se[9])),
    }


@dataclass(frozen=True)
class Plan:
    name: str
    kind: str  # "a465" or "ur"
    duty: str | None
    guess_mm: float
    guess_mrad: float
    extra: tuple[str, ...] = ()


def scenario(plan: Plan, host: str) -> dict[str, Any]:
    name, kind, duty, mm, mrad = plan.name, plan.kind, plan.duty, plan.guess_mm, plan.guess_mrad
    with tempfile.TemporaryDirectory(prefix="bench-urcam-") as tmp:
        directory = Path(tmp)
        guess = directory / "guess.toml"
        lab, truth, stations = (
            ur_lab(directory, host, duty or "", guess)
            if kind == "ur"
            else a465_lab(directory, guess)
        )
        write_cameras(guess, perturbed(truth, mm, mrad, seed=5) if mm or mrad else list(truth))
        written, moves = directory / "cameras.toml", directory / "moves.csv"
        argv = ["--robot", "--config", str(lab), "--json", "--write", str(written)]
        argv += ["--save-observations", str(moves), *plan.extra]
        status, out, err, wall_s = run_command(argv)
        result: dict[str, Any] = {"scenario": name, "status": status, "wall_s": wall_s}
        if status != 0:
            result["error"] = err.strip().splitlines()[-1] if err.strip() else "?"
            return result
        data = json.loads(out)
        settings = load_settings(lab)
        markers = np.array(settings.arm.markers_mm)
        nominal = load_arm(settings.arm.arm_file)
        fitted = {c.name: c for c in load_cameras(written)}
        guessed = {c.name: c for c in load_cameras(guess)}
        rows = read_observations(moves)
        cameras, references = [], {}
        for fit in data["cameras"]:
            own = fitted[fit["camera"]]
            references[fit["camera"]] = reference_of(own, fit)
            error = np.array(fit["centre_error_mm"])
            se = np.array(fit["centre_se_mm"])
            mine = [r for r in rows if r.camera == fit["camera"]]
            cameras.append(
                {
                    "camera": fit["camera"],
                    "points": fit["points"],
                    "centre_error_um": float(1000.0 * np.linalg.norm(error)),
                    "error_sigmas": float(np.max(np.abs(error) / se)),
                    "residual_px": fit["residual_px"],
                    "reduced_chi2": fit["reduced_chi2"],
                    **conditioning(own, mine),
                }
            )
        tools = []
        for index, (station, q) in enumerate(stations):
            names = [n for n in references if n.startswith(f"s{index}-")]
            if not names:
                continue
            believed = np.asarray(forward(nominal, q))
            truth_set = [references[n] for n in names]
            absolute, drift = tool_errors([fitted[n] for n in names], truth_set, markers, believed)
            guess_abs, guess_drift = tool_errors(
                [guessed[n] for n in names], truth_set, markers, believed
            )
            tools.append(
                {
                    "station": station,
                    "cameras": len(names),
                    "tool_error_um": absolute,
                    "drift_error_um": drift,
                    "guess_tool_error_um": guess_abs,
                    "guess_drift_error_um": guess_drift,
                }
            )
        result |= {
            "poses": data["poses"],
            "retried_dwells": data.get("retried_dwells"),
            "not_fitted": data["not_fitted"],
            "cameras": cameras,
            "tool": tools,
        }
        return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--guess-mm", type=float, default=3.0)
    parser.add_argument("--guess-mrad", type=float, default=2.0)
    parser.add_argument("--quick", action="store_true", help="the A465 and one UR scenario")
    parser.add_argument("--host", default="127.0.37.20")
    args = parser.parse_args()
    g_mm, g_mrad = args.guess_mm, args.guess_mrad
    plans = [
        Plan(
            "A465 --station place (reference)", "a465", None, g_mm, g_mrad, ("--station", "place")
        ),
        Plan("UR calibration program", "ur", "ur5e-camera-calibration", g_mm, g_mrad),
    ]
    if not args.quick:
        plans += [
            Plan("UR production program", "ur", "ur5e-pick-and-place", g_mm, g_mrad),
            Plan("UR calibration program, guess = truth", "ur", "ur5e-camera-calibration", 0, 0),
            Plan("UR guess 15 mm, 8 mrad (to break)", "ur", "ur5e-camera-calibration", 15, 8),
        ]
    load_before = os.getloadavg()
    results = [scenario(plan, args.host) for plan in plans]
    load_after = os.getloadavg()
    rows, tool_rows = [], []
    for result in results:
        if result["status"] != 0:
            rows.append([result["scenario"], "-", f"exit {result['status']}: {result['error']}"])
            continue
        for camera in result["cameras"]:
            rows.append(
                [
                    result["scenario"],
                    camera["camera"],
                    camera["points"],
                    camera["centre_error_um"],
                    camera["error_sigmas"],
                    camera["residual_px"],
                    camera["reduced_chi2"],
                    camera["cond_pose"],
                    camera["cond_full"],
                    camera["full_f_rel_sigma"],
                    camera["full_c_sigma_px"],
                ]
            )
        for tool in result["tool"]:
            tool_rows.append(
                [
                    result["scenario"],
                    tool["station"],
                    tool["cameras"],
                    tool["tool_error_um"],
                    tool["drift_error_um"],
                    tool["guess_tool_error_um"],
                    tool["guess_drift_error_um"],
                ]
            )
    headers = [
        "scenario", "camera", "views", "centre err um", "err/sigma", "resid px", "chi2r",
        "cond pose", "cond full", "full sf/f", "full sc px",
    ]  # fmt: skip
    print_table(headers, [r + [""] * (len(headers) - len(r)) for r in rows])
    print()
    print_table(
        ["scenario", "station", "cameras", "tool err um", "drift err um", "guess tool um",
         "guess drift um"],
        tool_rows,
    )  # fmt: skip
    for result in results:
        print(
            f"# {result['scenario']}: exit {result['status']}, {result['wall_s']:.1f} s wall, "
            f"{result.get('poses', '-')} poses, retried dwells {result.get('retried_dwells')}"
        )
    print(f"# load average before {load_before[0]:.2f}, after {load_after[0]:.2f}")
    write_results(
        "bench_ur_cameras",
        {"load_before": load_before, "load_after": load_after, "scenarios": results},
    )


if __name__ == "__main__":
    main()
