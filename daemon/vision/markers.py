"""Synthetic frames of markers (laser spots, LEDs) seen by a :class:`CameraModel` (issue 20): what
the arm bench renders in every camera.

Each marker is projected (:func:`daemon.vision.multiview.project`) and drawn as the synthetic
spot of :mod:`daemon.vision.synthetic` (pixel-integrated profile, same conventions), the noise
being that module's camera noise (photon, read, quantisation, clipping). A marker behind the
camera or off the chip is not drawn; :func:`marker_pixels` says which are visible. The spot's
size on the chip is a parameter (``sigma_px``), not derived from the marker's distance: the
bench chooses it like ``bench.spot_sigma_px``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from daemon.vision.cameras import CameraModel
from daemon.vision.centroid import CentroidError, measure_centroid
from daemon.vision.multiview import depths_mm, points_array, project
from daemon.vision.synthetic import Profile, camera_noise, expected_spot, full_scale

FloatArray = NDArray[np.float64]

#: Half-width of a rendered window in spot sigmas: the profile is below 1e-12 beyond 7.5 sigma
#: (synthetic._SUPPORT_SIGMAS), so a window of 8 sigma holds the whole spot.
WINDOW_SIGMAS = 8.0
#: Smallest window half-width (px): room for the centroid's window and background ring.
MIN_WINDOW_HALF_PX = 16


def marker_pixels(
    camera: CameraModel, points_mm: ArrayLike
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Pixels (N x 2) of the markers and whether each is visible: in front of the camera and on
    the chip (pixel centres span -0.5 .. size - 0.5)."""
    points = points_array(points_mm)
    pixels = project(camera, points)
    width, height = camera.image_size_px
    visible = (
        (depths_mm(camera, points) > 0)
        & (pixels[:, 0] >= -0.5)
        & (pixels[:, 0] <= width - 0.5)
        & (pixels[:, 1] >= -0.5)
        & (pixels[:, 1] <= height - 0.5)
    )
    return pixels, np.asarray(visible, dtype=np.bool_)


def render_markers(
    camera: CameraModel,
    points_mm: ArrayLike,
    *,
    rng: np.random.Generator | None = None,
    sigma_px: float | tuple[float, float] = 3.0,
    peak_fraction: float | Sequence[float] = 0.5,
    bit_depth: int | None = 16,
    background: float = 0.0,
    read_noise_counts: float = 0.0,
    photon_noise: bool = True,
    gain_e_per_count: float = 1.0,
    profile: Profile = "gaussian",
    flat_top_radius_px: float = 0.0,
) -> NDArray[np.generic]:
    """The whole frame (height x width) of ``camera`` with every visible marker drawn, noise
    from ``rng`` (noise-free without one). ``peak_fraction``: one value or one per marker."""
    points = points_array(points_mm)
    pixels, visible = marker_pixels(camera, points)
    width, height = camera.image_size_px
    white = full_scale(16 if bit_depth is None else bit_depth)
    peaks = np.broadcast_to(np.asarray(peak_fraction, dtype=np.float64), (points.shape[0],))
    frame = np.full((height, width), float(background))
    for (x, y), seen, peak in zip(pixels, visible, peaks, strict=True):
        if seen:
            frame += expected_spot(
                (height, width),
                (float(x), float(y)),
                sigma_px,
                float(peak) * white,
                profile=profile,
                flat_top_radius_px=flat_top_radius_px,
            )
    return camera_noise(
        frame,
        bit_depth=bit_depth,
        rng=rng,
        read_noise_counts=read_noise_counts,
        photon_noise=photon_noise,
        gain_e_per_count=gain_e_per_count,
    )


def render_marker_window(
    camera: CameraModel,
    point_mm: ArrayLike,
    *,
    rng: np.random.Generator | None = None,
    sigma_px: float = 3.0,
    peak_fraction: float = 0.5,
    bit_depth: int | None = 16,
    background: float = 0.0,
    read_noise_counts: float = 0.0,
    photon_noise: bool = True,
    gain_e_per_count: float = 1.0,
    half_width_px: int | None = None,
) -> tuple[NDArray[np.generic], tuple[int, int]] | None:
    """One marker rendered in a window of the frame around its image (fast: what a camera
    with a region of interest delivers): ``(window, (column0, row0))`` — a centroid measured in
    the window plus (column0, row0) is in frame pixels — or None when the marker is not
    visible. The window is clipped to the chip."""
    pixels, visible = marker_pixels(camera, point_mm)
    if not visible[0]:
        return None
    x, y = (float(v) for v in pixels[0])
    half = half_width_px or max(MIN_WINDOW_HALF_PX, math.ceil(WINDOW_SIGMAS * sigma_px))
    width, height = camera.image_size_px
    c0, c1 = max(0, math.floor(x) - half), min(width, math.floor(x) + half + 1)
    r0, r1 = max(0, math.floor(y) - half), min(height, math.floor(y) + half + 1)
    white = full_scale(16 if bit_depth is None else bit_depth)
    signal = background + expected_spot(
        (r1 - r0, c1 - c0), (x - c0, y - r0), sigma_px, peak_fraction * white
    )
    window = camera_noise(
        signal,
        bit_depth=bit_depth,
        rng=rng,
        read_noise_counts=read_noise_counts,
        photon_noise=photon_noise,
        gain_e_per_count=gain_e_per_count,
    )
    return window, (c0, r0)


@dataclass(frozen=True, slots=True)
class MarkerSpot:
    """How a marker looks on the chip and what the sensor adds: the bench's laser spot by
    default (``bench.spot_sigma_px``, ``bench.spot_peak_fraction``, the [camera] defaults:
    16 bits, 1 e-/count, 5 e- read noise)."""

    sigma_px: float = 3.0
    peak_fraction: float = 0.5
    bit_depth: int = 16
    gain_e_per_count: float = 1.0
    read_noise_e: float = 5.0


def centroids_of_markers(
    cameras: Sequence[CameraModel],
    points_mm: ArrayLike,
    rng: np.random.Generator | None,
    spot: MarkerSpot = MarkerSpot(),
) -> tuple[FloatArray, FloatArray]:
    """Every marker rendered alone in a window of every camera (markers lit in turn, as LEDs
    are) and measured by the robust centroid: pixels and their reported 1-sigma, both
    cameras x markers x 2, NaN where a camera does not see a marker (off the chip, behind it,
    or cut by the chip's edge) — the input of :func:`daemon.vision.tool_pose.measure_tool_pose`
    and of :func:`daemon.vision.multiview.triangulate`."""
    points = points_array(points_mm)
    pixels = np.full((len(cameras), points.shape[0], 2), np.nan)
    sigmas = np.full_like(pixels, np.nan)
    for c, camera in enumerate(cameras):
        for m, point in enumerate(points):
            rendered = render_marker_window(
                camera,
                point,
                rng=rng,
                sigma_px=spot.sigma_px,
                peak_fraction=spot.peak_fraction,
                bit_depth=spot.bit_depth,
                read_noise_counts=spot.read_noise_e / spot.gain_e_per_count,
                gain_e_per_count=spot.gain_e_per_count,
            )
            if rendered is None:
                continue
            window, (column0, row0) = rendered
            try:
                result = measure_centroid(
                    window,
                    bit_depth=spot.bit_depth,
                    gain_e_per_count=spot.gain_e_per_count,
                    read_noise_e=spot.read_noise_e,
                )
            except CentroidError:
                continue
            if "edge" in result.flags:
                continue
            pixels[c, m] = (result.x_px + column0, result.y_px + row0)
            sigmas[c, m] = (result.sigma_x_px, result.sigma_y_px)
    return pixels, sigmas
