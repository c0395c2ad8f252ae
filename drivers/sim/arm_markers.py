"""The arm bench's cameras and markers: where the cameras stand, and frames of the tool's markers.

Cameras (``daemon.vision.multiview.CameraModel``) stand on a circle around a reference point
(the tool at its first measured pose), at ``distance_mm``, raised by ``elevation_rad``, evenly
spread in azimuth over ``spread_rad`` and looking at the point: the several-camera setup of
thesis 7.2.2. Markers (LEDs or laser spots on the tool) are points fixed in the tool frame.

A frame is rendered as the single-spot simulated camera does (drivers.sim.devices.SimCamera):
the sensor's noise field from a bank of pre-rendered dark frames, rolled by a random shift, and
each marker's spot rendered fresh (photon and read noise, daemon.vision.synthetic.render_spot)
in a window around its projected centre. :func:`render_windows` gives the windows alone (a
camera's region-of-interest read-out): what the benchmark measures, at a fraction of the cost.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from daemon.arm.types import FloatArray
from daemon.vision.centroid import CentroidError, measure_centroid
from daemon.vision.multiview import CameraModel, intrinsic_matrix, look_at, project
from daemon.vision.synthetic import render_spot
from daemon.vision.tool_pose import ToolMeasurement, measure_tool_pose

#: Windows rendered fresh around a spot: at least this many px either side, or this many sigmas.
WINDOW_MIN_PX = 8
WINDOW_SIGMAS = 6.0
#: Dark frames pre-rendered for a camera's noise field (as drivers.sim.devices.SimCamera).
NOISE_BANK_SIZE = 4


@dataclass(frozen=True)
class CameraRig:
    """The cameras of the bench (defaults: three 5 MP machine-vision cameras with 16 mm lenses
    and 3.45 um pixels, f = 4,640 px, 700 mm from the tool, 30 degrees above it, 120 degrees
    apart; spots 2 px wide at 60 % of a 12-bit full scale)."""

    count: int = 3
    distance_mm: float = 700.0
    elevation_rad: float = math.radians(30.0)
    spread_rad: float = math.radians(240.0)
    azimuth_rad: float = math.radians(-120.0)
    focal_px: float = 4640.0
    width_px: int = 2448
    height_px: int = 2048
    pixel_sigma_px: float = 0.05
    spot_sigma_px: float = 2.0
    spot_peak_fraction: float = 0.6
    bit_depth: int = 12
    gain_e_per_count: float = 2.5
    read_noise_e: float = 6.0

    def cameras(self, target_mm: Sequence[float] | FloatArray) -> tuple[CameraModel, ...]:
        """The rig's cameras looking at ``target_mm`` (world mm)."""
        target = np.asarray(target_mm, dtype=np.float64)
        step = self.spread_rad / max(self.count - 1, 1) if self.count > 1 else 0.0
        cameras = []
        for k in range(self.count):
            azimuth = self.azimuth_rad + k * step
            offset = self.distance_mm * np.array(
                [
                    math.cos(self.elevation_rad) * math.cos(azimuth),
                    math.cos(self.elevation_rad) * math.sin(azimuth),
                    math.sin(self.elevation_rad),
                ]
            )
            rvec, tvec = look_at(target + offset, target)
            cameras.append(
                CameraModel(
                    name=f"arm-{k}",
                    matrix=intrinsic_matrix(
                        (self.focal_px, self.focal_px),
                        ((self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0),
                    ),
                    distortion=np.zeros(5),
                    rotation_rad=rvec,
                    translation_mm=tvec,
                    image_size_px=(self.width_px, self.height_px),
                    pixel_sigma_px=self.pixel_sigma_px,
                )
            )
        return tuple(cameras)


def markers_world_mm(tool_pose: FloatArray, markers_tool_mm: FloatArray) -> FloatArray:
    """The markers (M x 3, tool frame) in the world for the tool's 4x4 pose."""
    world: FloatArray = markers_tool_mm @ tool_pose[:3, :3].T + tool_pose[:3, 3]
    return world


@dataclass(frozen=True)
class MarkerWindow:
    """One marker's region of interest: ``image`` whose pixel (0, 0) is the frame's pixel
    (``row0``, ``column0``)."""

    marker: int
    row0: int
    column0: int
    image: NDArray[np.generic]


class MarkerRenderer:
    """Frames of one camera; every random draw from ``rng`` (the camera's own stream).
    ``bank``: a list of dark frames shared with other renderers of the same rig and image size
    (filled by the first that renders; its noise drawn from that one's stream): each frame is
    a bank frame rolled by a random shift of the camera's own, so sharing keeps every camera's
    noise statistics and makes the bank once instead of once per camera."""

    def __init__(
        self,
        camera: CameraModel,
        rig: CameraRig,
        rng: np.random.Generator,
        bank: list[NDArray[np.generic]] | None = None,
    ) -> None:
        self.camera = camera
        self.rig = rig
        self.rng = rng
        self._bank: list[NDArray[np.generic]] = [] if bank is None else bank

    def _kwargs(self) -> dict[str, object]:
        rig = self.rig
        return {
            "sigma_px": rig.spot_sigma_px,
            "bit_depth": rig.bit_depth,
            "rng": self.rng,
            "read_noise_counts": rig.read_noise_e / rig.gain_e_per_count,
            "photon_noise": True,
            "gain_e_per_count": rig.gain_e_per_count,
        }

    @property
    def half_window_px(self) -> int:
        return max(WINDOW_MIN_PX, math.ceil(WINDOW_SIGMAS * self.rig.spot_sigma_px))

    def _window(self, centre_xy: FloatArray) -> tuple[int, int, int, int]:
        width, height = self.camera.image_size_px
        half = self.half_window_px
        x, y = float(centre_xy[0]), float(centre_xy[1])
        c0, c1 = max(0, math.floor(x) - half), min(width, math.floor(x) + half + 1)
        r0, r1 = max(0, math.floor(y) - half), min(height, math.floor(y) + half + 1)
        return r0, r1, c0, c1

    def render_windows(self, points_mm: FloatArray, jitter_px: float = 0.0) -> list[MarkerWindow]:
        """Each marker's window with its spot (markers off the chip are left out); each spot's
        centre moved by a Gaussian image-plane jitter of 1-sigma ``jitter_px``."""
        pixels = project(self.camera, points_mm)
        if jitter_px > 0.0:
            pixels = pixels + self.rng.normal(0.0, jitter_px, pixels.shape)
        windows = []
        for k, centre in enumerate(pixels):
            r0, r1, c0, c1 = self._window(centre)
            if r1 - r0 < 3 or c1 - c0 < 3:
                continue
            image = render_spot(
                shape=(r1 - r0, c1 - c0),
                centre_xy=(float(centre[0]) - c0, float(centre[1]) - r0),
                peak_fraction=self.rig.spot_peak_fraction,
                **self._kwargs(),  # type: ignore[arg-type]
            )
            windows.append(MarkerWindow(k, r0, c0, image))
        return windows

    def render(self, points_mm: FloatArray, jitter_px: float = 0.0) -> NDArray[np.generic]:
        """A whole frame with every marker's spot (blocking: call it in a thread)."""
        width, height = self.camera.image_size_px
        shape = (height, width)
        if not self._bank:  # filled in place: a shared bank is filled for every renderer
            self._bank.extend(
                render_spot(shape=shape, peak_fraction=0.0, **self._kwargs())  # type: ignore[arg-type]
                for _ in range(NOISE_BANK_SIZE)
            )
        field = self._bank[int(self.rng.integers(NOISE_BANK_SIZE))]
        shift = (int(self.rng.integers(shape[0])), int(self.rng.integers(shape[1])))
        frame = np.roll(field, shift, axis=(0, 1))
        for window in self.render_windows(points_mm, jitter_px):
            rows, columns = window.image.shape
            frame[window.row0 : window.row0 + rows, window.column0 : window.column0 + columns] = (
                window.image
            )
        return frame


def marker_pixels(
    windows: Sequence[Sequence[MarkerWindow]], markers: int, rig: CameraRig, jitter_px: float = 0.0
) -> tuple[FloatArray, FloatArray]:
    """Each marker's centroid in each camera (cameras x markers x 2, NaN where a camera has no
    usable spot of it) and its 1-sigma (the robust method of daemon.vision.centroid, its own
    sigma widened by the image-plane jitter): what
    :func:`daemon.vision.tool_pose.measure_tool_pose` takes."""
    pixels = np.full((len(windows), markers, 2), np.nan)
    sigmas = np.ones((len(windows), markers, 2))
    for index, camera_windows in enumerate(windows):
        for window in camera_windows:
            try:
                spot = measure_centroid(
                    window.image,
                    bit_depth=rig.bit_depth,
                    method="robust",
                    gain_e_per_count=rig.gain_e_per_count,
                    read_noise_e=rig.read_noise_e,
                )
            except CentroidError:
                continue
            pixels[index, window.marker] = (spot.x_px + window.column0, spot.y_px + window.row0)
            sigmas[index, window.marker] = (
                math.hypot(spot.sigma_x_px, jitter_px),
                math.hypot(spot.sigma_y_px, jitter_px),
            )
    return pixels, sigmas


def measure_tool(
    cameras: Sequence[CameraModel],
    windows: Sequence[Sequence[MarkerWindow]],
    markers_tool_mm: FloatArray,
    rig: CameraRig,
    jitter_px: float = 0.0,
) -> ToolMeasurement:
    """The tool's pose from each camera's marker windows: centroids (:func:`marker_pixels`),
    then daemon.vision.tool_pose.measure_tool_pose (triangulation, pose fit)."""
    pixels, sigmas = marker_pixels(windows, markers_tool_mm.shape[0], rig, jitter_px)
    return measure_tool_pose(tuple(cameras), markers_tool_mm, pixels, sigmas)


__all__ = [
    "CameraRig",
    "MarkerRenderer",
    "MarkerWindow",
    "marker_pixels",
    "markers_world_mm",
    "measure_tool",
]
