"""3-D marker measurement with 2, 3 and 4 cameras: the RMS error against the predicted sigma.

Four cameras (752 x 582 px, f = 2400 px, i.e. a ~21 mm lens on the bench's 8.6 um pixels,
mild barrel distortion) stand about 1 m from the work volume at different azimuths and
heights. A marker is placed at random in a ±50 mm cube about the volume's centre; in every
camera it is rendered as the bench's laser spot (``daemon.vision.markers``: sigma 3 px, peak
at half full scale, photon + 5 e- read noise) and measured by the robust centroid, which
reports its own 1-sigma. The first 2, 3 or all 4 cameras' centroids are triangulated with those
sigmas (``daemon.vision.multiview.triangulate``). Per camera count: the 3-D RMS error from the
truth, the RMS the reported covariances predict (sqrt of the mean trace), their ratio, the mean
squared Mahalanobis distance over 3 (1 when the covariance is right) and the worst axis.

Two sensors: the bench's default (16 bits, 1 e-/count: the [camera] defaults) and an 8-bit
read of the same sensor (257 e-/count), as benchmarks/bench_centroid.py. Fixed seeds; one core.

    .venv/bin/python benchmarks/bench_multiview.py            # 400 markers per sensor
    .venv/bin/python benchmarks/bench_multiview.py --quick    # 60 markers, a smoke run
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.common import print_table, write_results
from daemon.vision.markers import MarkerSpot, centroids_of_markers
from daemon.vision.multiview import (
    CameraModel,
    intrinsic_matrix,
    look_at,
    pose_difference,
    project,
    triangulate,
)
from daemon.vision.tool_pose import measure_tool_pose

CENTRE_MM = np.array([0.0, 0.0, 400.0])
HALF_SIZE_MM = 50.0
POSITIONS_MM = [
    (-800.0, -600.0, 500.0),
    (800.0, -600.0, 450.0),
    (0.0, -700.0, 1100.0),
    (600.0, 700.0, 600.0),
]
#: Four markers on the tool (tool frame, mm): a tetrahedron ~60 mm across.
TOOL_MARKERS_MM = np.array(
    [[0.0, 0.0, 0.0], [60.0, 0.0, 0.0], [0.0, 45.0, 0.0], [20.0, 20.0, 30.0]]
)
SPOT_SIGMA_PX = 3.0  # bench.spot_sigma_px
PEAK_FRACTION = 0.5  # bench.spot_peak_fraction
READ_NOISE_E = 5.0  # camera.read_noise_e


@dataclass(frozen=True)
class Sensor:
    name: str
    bit_depth: int
    gain_e_per_count: float


SENSORS = (Sensor("16-bit (bench default)", 16, 1.0), Sensor("8-bit", 8, 257.0))


def cameras() -> list[CameraModel]:
    rig = []
    for index, position in enumerate(POSITIONS_MM):
        rvec, tvec = look_at(position, CENTRE_MM)
        rig.append(
            CameraModel(
                name=f"c{index}",
                matrix=intrinsic_matrix((2400.0, 2400.0), (375.5, 290.5)),
                distortion=np.array([-0.08, 0.01, 0.0, 0.0, 0.0]),
                rotation_rad=rvec,
                translation_mm=tvec,
                image_size_px=(752, 582),
            )
        )
    return rig


def spot(sensor: Sensor) -> MarkerSpot:
    return MarkerSpot(
        sigma_px=SPOT_SIGMA_PX,
        peak_fraction=PEAK_FRACTION,
        bit_depth=sensor.bit_depth,
        gain_e_per_count=sensor.gain_e_per_count,
        read_noise_e=READ_NOISE_E,
    )


def run_tool(sensor: Sensor, count: int, seed: int) -> list[dict[str, Any]]:
    """The tool's pose from its four markers: translation and rotation errors vs predicted."""
    rig = cameras()
    rng = np.random.default_rng(seed)
    records: dict[int, list[tuple[NDArray[np.float64], NDArray[np.float64]]]] = {
        2: [],
        3: [],
        4: [],
    }
    for _ in range(count):
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_rotvec(rng.uniform(-0.35, 0.35, 3)).as_matrix()
        pose[:3, 3] = CENTRE_MM + rng.uniform(-HALF_SIZE_MM, HALF_SIZE_MM, 3)
        markers = TOOL_MARKERS_MM @ pose[:3, :3].T + pose[:3, 3]
        pixels, sigmas = centroids_of_markers(rig, markers, rng, spot(sensor))
        for views, record in records.items():
            measured = measure_tool_pose(
                rig[:views], TOOL_MARKERS_MM, pixels[:views], sigmas[:views]
            )
            record.append((pose_difference(pose, measured.pose).as_array(), measured.covariance))
    rows = []
    for views, pairs in records.items():
        errors = np.array([e for e, _ in pairs])
        covariances = np.array([c for _, c in pairs])
        translation = math.sqrt(float(np.mean(np.sum(errors[:, :3] ** 2, axis=1))))
        rotation = math.sqrt(float(np.mean(np.sum(errors[:, 3:] ** 2, axis=1))))
        predicted_t = math.sqrt(float(np.mean(np.trace(covariances[:, :3, :3], axis1=1, axis2=2))))
        predicted_r = math.sqrt(float(np.mean(np.trace(covariances[:, 3:, 3:], axis1=1, axis2=2))))
        rows.append(
            {
                "sensor": sensor.name,
                "cameras": views,
                "poses": count,
                "translation_rms_um": 1000 * translation,
                "translation_predicted_um": 1000 * predicted_t,
                "rotation_rms_urad": 1e6 * rotation,
                "rotation_predicted_urad": 1e6 * predicted_r,
            }
        )
    return rows


def run(sensor: Sensor, count: int, seed: int) -> list[dict[str, Any]]:
    rig = cameras()
    rng = np.random.default_rng(seed)
    records: dict[int, list[tuple[NDArray[np.float64], NDArray[np.float64]]]] = {
        2: [],
        3: [],
        4: [],
    }
    centroid_errors, centroid_sigmas = [], []
    started = time.perf_counter()
    for _ in range(count):
        truth = CENTRE_MM + rng.uniform(-HALF_SIZE_MM, HALF_SIZE_MM, 3)
        found, reported = centroids_of_markers(rig, truth, rng, spot(sensor))
        pixels, sigmas = found[:, 0], reported[:, 0]
        errors = pixels - np.array([project(camera, truth)[0] for camera in rig])
        centroid_errors.append(errors)
        centroid_sigmas.append(sigmas)
        for views, record in records.items():
            point, covariance = triangulate(
                rig[:views], pixels[:views], [tuple(s) for s in sigmas[:views]]
            )
            record.append((point - truth, covariance))
    elapsed = time.perf_counter() - started
    centroid_rms = float(np.sqrt(np.mean(np.array(centroid_errors) ** 2)))
    centroid_reported = float(np.sqrt(np.mean(np.array(centroid_sigmas) ** 2)))
    rows = []
    for views, pairs in records.items():
        errors = np.array([e for e, _ in pairs])
        covariances = np.array([c for _, c in pairs])
        rms = math.sqrt(float(np.mean(np.sum(errors**2, axis=1))))
        predicted = math.sqrt(float(np.mean(np.trace(covariances, axis1=1, axis2=2))))
        mahalanobis = np.einsum("ni,nij,nj->n", errors, np.linalg.inv(covariances), errors)
        axis_rms = np.sqrt(np.mean(errors**2, axis=0))
        rows.append(
            {
                "sensor": sensor.name,
                "cameras": views,
                "markers": count,
                "centroid_rms_px": centroid_rms,
                "centroid_reported_px": centroid_reported,
                "rms_3d_um": 1000 * rms,
                "predicted_3d_um": 1000 * predicted,
                "ratio": rms / predicted,
                "mahalanobis_over_3": float(np.mean(mahalanobis)) / 3.0,
                "worst_axis_um": 1000 * float(axis_rms.max()),
                "time_per_marker_ms": 1000 * elapsed / count,
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="60 markers per sensor")
    parser.add_argument("--markers", type=int, default=None, help="markers per sensor")
    parser.add_argument("--seed", type=int, default=20)
    args = parser.parse_args()
    count = args.markers or (60 if args.quick else 400)
    cv2.setNumThreads(1)
    load_before = os.getloadavg()
    rows = []
    for index, sensor in enumerate(SENSORS):
        rows += run(sensor, count, args.seed + index)
    headers = [
        "sensor",
        "cameras",
        "centroid px (rms/reported)",
        "3-D RMS um",
        "predicted um",
        "ratio",
        "Mahalanobis/3",
        "worst axis um",
        "ms/marker",
    ]
    print_table(
        headers,
        [
            [
                r["sensor"],
                r["cameras"],
                f"{r['centroid_rms_px']:.4f}/{r['centroid_reported_px']:.4f}",
                r["rms_3d_um"],
                r["predicted_3d_um"],
                r["ratio"],
                r["mahalanobis_over_3"],
                r["worst_axis_um"],
                r["time_per_marker_ms"],
            ]
            for r in rows
        ],
    )
    tool_rows = run_tool(SENSORS[0], max(20, count // 4), args.seed + 10)
    print()
    print_table(
        ["sensor", "cameras", "translation RMS/predicted um", "rotation RMS/predicted urad"],
        [
            [
                r["sensor"],
                r["cameras"],
                f"{r['translation_rms_um']:.3f}/{r['translation_predicted_um']:.3f}",
                f"{r['rotation_rms_urad']:.2f}/{r['rotation_predicted_urad']:.2f}",
            ]
            for r in tool_rows
        ],
    )
    write_results(
        "bench_multiview",
        {
            "markers_per_sensor": count,
            "seed": args.seed,
            "load_average_1min": [load_before[0], os.getloadavg()[0]],
            "rows": rows,
            "tool_rows": tool_rows,
        },
    )


if __name__ == "__main__":
    main()
