"""The tool's 3-D measurement in an arm run (issue 20; thesis 7.2.2, several cameras): one
frame from every camera, each marker's centroid in a window around where the expected tool
pose puts it, each marker triangulated from the cameras that see it, and the tool's pose from
the markers (orientation from three or more: daemon/vision/multiview.py). When fewer than three
markers are seen by two cameras — one camera watching the tool, the thesis's setup — the pose
comes from the markers' pixels directly (perspective-n-point, daemon/vision/pnp.py: one camera
seeing three or more markers gives the whole pose, its depth along the line of sight poorer).

The centroid is the thesis's robust spot centroid (daemon/vision/centroid.py) on a window of
the frame: the markers are tens of pixels apart on the chip, the window is a few spot widths,
so each window holds one marker (the expected pose is the taught pose: the drift is a fraction
of a millimetre, a pixel or two).
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from config import Settings
from daemon.arm.run import FloatArray, MeasurementError, ToolMeasurement
from daemon.run.workers import Workers
from daemon.vision import CentroidError
from daemon.vision.centroid import measure_centroid
from daemon.vision.multiview import (
    CameraModel,
    MultiviewError,
    project,
    rigid_pose_from_markers,
    triangulate,
)
from daemon.vision.pnp import pose_from_views
from drivers.base import Camera, Frame
from drivers.deadline import bounded

#: Half-width of the window a marker's centroid is measured in (px): 8 spot sigmas of the
#: bench's 3 px spots (daemon/vision/markers.py WINDOW_SIGMAS), room for the drift.
WINDOW_HALF_PX = 24
#: A marker is triangulated from at least this many cameras (one camera sees no depth).
MIN_VIEWS = 2
#: Frames from which an average's 1-sigma also looks at the centroids' scatter.
MIN_FRAMES_FOR_SCATTER = 3
#: Degrees of freedom of a camera's pooled scatter before it replaces the camera model's
#: nominal ``pixel_sigma_px`` as the floor of its centroids' 1-sigma (issue 29): one reference
#: of 4 frames at each of 2 poses, 4 markers, gives 48 (its 1-sigma then known to ~10 %).
MIN_SCATTER_DOF = 20


@dataclass(frozen=True, slots=True)
class MarkerView:
    camera: str
    marker: int
    x_px: float
    y_px: float
    sigma_px: float
    #: the centroid's own 1-sigma (its photons and read noise), before the camera's floor
    centroid_sigma_px: float | None = None


@dataclass(frozen=True, slots=True)
class SensorNoise:
    """What the centroid's 1-sigma needs of a camera's sensor (its [camera] settings); no
    gain: the frame's (the camera's), else measured on the frame."""

    gain_e_per_count: float | None = None
    read_noise_e: float = 5.0


def device_sensors(
    settings: Settings, count: int
) -> tuple[tuple[SensorNoise, ...], tuple[float, ...]]:
    """Each of ``count`` tool cameras' sensor noise and grab timeout (s): on hardware its own
    ``arm.camera_devices`` entry (same order as the camera file), on the arm bench's simulated
    cameras the ``[camera]`` section's."""
    devices = settings.arm.camera_devices
    own = devices if len(devices) == count else (settings.camera,) * count
    return (
        tuple(SensorNoise(d.gain_e_per_count, d.read_noise_e) for d in own),
        tuple(d.grab_timeout_s for d in own),
    )


def marker_views(
    cameras: Sequence[CameraModel],
    frames: Sequence[Frame],
    markers_world: FloatArray,
    *,
    sensors: Sequence[SensorNoise] | None = None,
    window_half_px: int = WINDOW_HALF_PX,
    floors_px: Mapping[str, float] | None = None,
) -> list[MarkerView]:
    """Every marker's centroid in every camera whose frame shows it near its expected pixel,
    at the frame's own bit depth and the camera's sensor noise (``sensors``, same order). Each
    centroid's 1-sigma is at least its camera's floor: ``floors_px`` (by camera name: the
    scatter the meter measured, :class:`ScatterLog`), else the camera model's nominal
    ``pixel_sigma_px``."""
    views: list[MarkerView] = []
    noises = tuple(sensors) if sensors is not None else (SensorNoise(),) * len(cameras)
    floors = floors_px or {}
    for camera, frame, noise in zip(cameras, frames, noises, strict=True):
        floor = floors.get(camera.name, camera.pixel_sigma_px)
        image = np.asarray(frame.image)
        height, width = image.shape[:2]
        for marker, (x, y) in enumerate(project(camera, markers_world)):
            if not (math.isfinite(x) and math.isfinite(y)):
                continue
            c0, r0 = max(0, int(x) - window_half_px), max(0, int(y) - window_half_px)
            c1 = min(width, int(x) + window_half_px + 1)
            r1 = min(height, int(y) + window_half_px + 1)
            if c1 - c0 < window_half_px or r1 - r0 < window_half_px:
                continue  # off the chip
            try:
                result = measure_centroid(
                    image[r0:r1, c0:c1],
                    bit_depth=frame.bit_depth,
                    gain_e_per_count=noise.gain_e_per_count
                    if noise.gain_e_per_count is not None
                    else frame.gain_e_per_count,
                    read_noise_e=noise.read_noise_e,
                    gain_source="config" if noise.gain_e_per_count is not None else "camera",
                )
            except CentroidError:
                continue
            own = max(result.sigma_x_px, result.sigma_y_px)
            views.append(
                MarkerView(
                    camera.name,
                    marker,
                    result.x_px + c0,
                    result.y_px + r0,
                    max(own, floor),
                    own,
                )
            )
    return views


def mean_views(view_sets: Sequence[Sequence[MarkerView]]) -> list[MarkerView]:
    """Each (camera, marker)'s centroid averaged over the frames that showed it. The mean's
    1-sigma is the single centroid's over sqrt(frames): the larger of the sigma the centroids
    report and, from three frames on, their observed scatter (what moves the spot from frame
    to frame without the centroid knowing: air, vibration) - so a scatter the frames share,
    which averaging cannot remove, is never hidden behind the reported one."""
    grouped: dict[tuple[str, int], list[MarkerView]] = {}
    for views in view_sets:
        for view in views:
            grouped.setdefault((view.camera, view.marker), []).append(view)
    averaged: list[MarkerView] = []
    for (camera, marker), views in grouped.items():
        xs = np.array([view.x_px for view in views])
        ys = np.array([view.y_px for view in views])
        count = len(views)
        variance = float(np.mean([view.sigma_px**2 for view in views]))
        if count >= MIN_FRAMES_FOR_SCATTER:
            scatter = 0.5 * (float(np.var(xs, ddof=1)) + float(np.var(ys, ddof=1)))
            variance = max(variance, scatter)
        averaged.append(
            MarkerView(
                camera, marker, float(xs.mean()), float(ys.mean()), math.sqrt(variance / count)
            )
        )
    return averaged


class ScatterLog:
    """Each camera's centroid scatter from frame to frame, pooled over its markers and every
    averaged measurement (issue 29): what moves a spot between frames of a still tool (air,
    vibration, photon noise) whatever the camera model's nominal ``pixel_sigma_px`` says. Per
    axis, ``sum (x - mean)^2`` over ``frames - 1`` degrees of freedom per marker."""

    def __init__(self) -> None:
        self._sums: dict[str, float] = {}
        self._dof: dict[str, int] = {}

    def add(self, view_sets: Sequence[Sequence[MarkerView]]) -> None:
        """The frames of one measurement of a still tool (three or more: fewer say little)."""
        if len(view_sets) < MIN_FRAMES_FOR_SCATTER:
            return
        grouped: dict[tuple[str, int], list[MarkerView]] = {}
        for views in view_sets:
            for view in views:
                grouped.setdefault((view.camera, view.marker), []).append(view)
        for (camera, _), views in grouped.items():
            if len(views) < 2:
                continue
            xs = np.array([view.x_px for view in views])
            ys = np.array([view.y_px for view in views])
            squares = float(np.sum((xs - xs.mean()) ** 2) + np.sum((ys - ys.mean()) ** 2))
            self._sums[camera] = self._sums.get(camera, 0.0) + squares
            self._dof[camera] = self._dof.get(camera, 0) + 2 * (len(views) - 1)

    def sigma_px(self, camera: str) -> float | None:
        """The camera's measured 1-sigma per centroid axis (px), once MIN_SCATTER_DOF degrees
        of freedom are in; else None."""
        dof = self._dof.get(camera, 0)
        if dof < MIN_SCATTER_DOF:
            return None
        return math.sqrt(self._sums[camera] / dof)

    def floors_px(self) -> dict[str, float]:
        """Every camera's measured 1-sigma that is known."""
        known = {camera: self.sigma_px(camera) for camera in self._dof}
        return {camera: sigma for camera, sigma in known.items() if sigma is not None}


def tool_pose(
    cameras: Sequence[CameraModel],
    views: Sequence[MarkerView],
    markers_tool: FloatArray,
    expected_pose: FloatArray,
) -> ToolMeasurement:
    """The tool's pose from the marker views. Three or more markers triangulated (each seen by
    two cameras): their rigid fit. Fewer: the pose from the views' pixels (one camera is
    enough, :func:`pnp_pose`); failing that, with one or two triangulated markers the
    orientation is the expected one and only the position is measured (``oriented`` False);
    with none, MeasurementError."""
    by_name = {camera.name: camera for camera in cameras}
    points: list[FloatArray] = []
    covariances: list[FloatArray] = []
    seen: list[int] = []
    for marker in range(markers_tool.shape[0]):
        mine = [view for view in views if view.marker == marker]
        if len(mine) < MIN_VIEWS:
            continue
        try:
            point, covariance = triangulate(
                [by_name[view.camera] for view in mine],
                [(view.x_px, view.y_px) for view in mine],
                [view.sigma_px for view in mine],
            )
        except MultiviewError:
            continue
        points.append(point)
        covariances.append(covariance)
        seen.append(marker)
    centroids: dict[str, list[tuple[float, float]]] = {}
    for view in views:
        centroids.setdefault(view.camera, []).append((view.x_px, view.y_px))
    frozen = {name: tuple(values) for name, values in centroids.items()}
    if len(seen) < 3:
        try:
            return pnp_pose(cameras, views, markers_tool, expected_pose, frozen)
        except MultiviewError as err:
            if not seen:
                raise MeasurementError(
                    f"no marker seen by {MIN_VIEWS} cameras, and no pose from the views: {err}"
                ) from err
    if len(seen) >= 3:
        try:
            pose, covariance6 = rigid_pose_from_markers(
                markers_tool[seen], np.array(points), np.array(covariances)
            )
            sigma_mm, sigma_rad = pose_sigmas(covariance6)
            return ToolMeasurement(pose, sigma_mm, True, frozen, sigma_rad)
        except MultiviewError:
            pass  # markers in a line: position only
    rotation = np.asarray(expected_pose, dtype=np.float64)[:3, :3]
    translations = [p - rotation @ markers_tool[m] for p, m in zip(points, seen, strict=True)]
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = np.mean(translations, axis=0)
    variance = float(np.mean([np.trace(c) for c in covariances])) / len(seen)
    return ToolMeasurement(pose, math.sqrt(variance), False, frozen)


def pose_sigmas(covariance6: FloatArray) -> tuple[float, float]:
    """The 1-sigma of a pose's position (mm) and orientation (rad) from its 6x6 covariance of
    [translation (mm), rotation vector (rad)]: the square roots of the blocks' traces."""
    covariance = np.asarray(covariance6, dtype=np.float64)
    return (
        math.sqrt(float(np.trace(covariance[:3, :3]))),
        math.sqrt(float(np.trace(covariance[3:, 3:]))),
    )


def pnp_pose(
    cameras: Sequence[CameraModel],
    views: Sequence[MarkerView],
    markers_tool: FloatArray,
    expected_pose: FloatArray,
    centroids: dict[str, tuple[tuple[float, float], ...]],
) -> ToolMeasurement:
    """The tool's pose from the views' pixels (daemon/vision/pnp.py; the expected pose picks
    the branch when no camera sees four markers); MultiviewError when they cannot give it."""
    index = {camera.name: k for k, camera in enumerate(cameras)}
    pixels = np.full((len(cameras), markers_tool.shape[0], 2), np.nan)
    sigmas = np.full_like(pixels, np.nan)
    for view in views:
        pixels[index[view.camera], view.marker] = (view.x_px, view.y_px)
        sigmas[index[view.camera], view.marker] = view.sigma_px
    fit = pose_from_views(cameras, markers_tool, pixels, sigmas, expected_pose=expected_pose)
    sigma_mm, sigma_rad = pose_sigmas(fit.covariance)
    return ToolMeasurement(fit.pose, sigma_mm, True, centroids, sigma_rad)


class MultiCameraMeter:
    """The ToolMeter of an arm run: ``cameras`` are the devices, ``models`` their calibrated
    CameraModels (same order), ``markers_mm`` the markers in the tool frame."""

    def __init__(
        self,
        settings: Settings,
        cameras: Sequence[Camera],
        models: Sequence[CameraModel],
        workers: Workers,
    ) -> None:
        if len(cameras) != len(models):
            raise ValueError(f"{len(cameras)} cameras but {len(models)} camera models")
        self._settings = settings
        self._cameras = tuple(cameras)
        self._models = tuple(models)
        self._workers = workers
        self._markers: NDArray[np.float64] = np.array(settings.arm.markers_mm, dtype=np.float64)
        self._sensors, self._timeouts_s = device_sensors(settings, len(models))
        self._frames = settings.arm.frames_per_measurement
        #: the cameras' measured scatter (owned by the step's worker: _views and _solve)
        self.scatter = ScatterLog()

    async def measure(
        self, expected_pose: FloatArray, frames: int | None = None
    ) -> ToolMeasurement:
        """``frames`` (default ``arm.frames_per_measurement``) frames from every camera (the
        cameras together, one frame after the other), each marker's centroid averaged over
        them, then the pose."""
        expected = np.asarray(expected_pose, dtype=np.float64)
        view_sets: list[list[MarkerView]] = []
        grabbed: Sequence[Frame] = ()
        for _ in range(self._frames if frames is None else frames):
            grabbed = await self._grab_all()
            view_sets.append(await self._workers.step(self._views, grabbed, expected))
        measurement = await self._workers.step(self._solve, view_sets, expected)
        # the last frames, for the live views (no copy: the images are not written to again)
        # (none grabbed when frames == 0)
        images = {m.name: f.image for m, f in zip(self._models, grabbed, strict=False)}
        return replace(measurement, images=images)

    def _views(self, frames: Sequence[Frame], expected: FloatArray) -> list[MarkerView]:
        markers_world = self._markers @ expected[:3, :3].T + expected[:3, 3]
        return marker_views(
            self._models,
            frames,
            markers_world,
            sensors=self._sensors,
            floors_px=self.scatter.floors_px(),
        )

    def _solve(
        self, view_sets: Sequence[Sequence[MarkerView]], expected: FloatArray
    ) -> ToolMeasurement:
        """The pose from the frames' views; several frames of the still tool first teach the
        cameras' scatter (:class:`ScatterLog`), the floor of every later centroid's 1-sigma
        (their own views were floored by what was known before: floored again by the new)."""
        self.scatter.add(view_sets)
        floors = self.scatter.floors_px()
        view_sets = [
            [
                dataclasses.replace(
                    view,
                    sigma_px=max(
                        view.sigma_px if view.centroid_sigma_px is None else view.centroid_sigma_px,
                        floors[view.camera],
                    ),
                )
                if view.camera in floors
                else view
                for view in views
            ]
            for views in view_sets
        ]
        views = list(view_sets[0]) if len(view_sets) == 1 else mean_views(view_sets)
        return tool_pose(self._models, views, self._markers, expected)

    async def _grab_all(self) -> list[Frame]:
        """One frame from every camera, together. A camera that fails (its timeout, its
        error) ends the others' grabs before the error goes up: a bare gather would leave them
        running after the measurement has failed (seen: a grab still pending when the step
        went on)."""
        grabs = [
            asyncio.ensure_future(self._grab(camera, timeout_s))
            for camera, timeout_s in zip(self._cameras, self._timeouts_s, strict=True)
        ]
        try:
            return await asyncio.gather(*grabs)
        except BaseException:
            for grab in grabs:
                grab.cancel()
            await asyncio.gather(*grabs, return_exceptions=True)
            raise

    async def _grab(self, camera: Camera, timeout_s: float) -> Frame:
        # the bench's render does not count against the timeout (drivers/deadline.py)
        return await bounded(camera.grab(), "camera", "frame", timeout_s)
