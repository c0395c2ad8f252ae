"""The recordings of ``thermocomp budget`` (issue 32), through the configured devices: nothing
moves, the robot is only opened (powered, held where it stands).

First the camera-only recording on a fixed target (thesis 4.8: the camera warms up from the
moment it is switched on, so this comes first, from the devices' opening), then the short
stationary recording (4.6, 4.7). On the simulated bench the heaters stay off for both (the
target must not move; in a lab: switch them off), and the clock is the bench's (a virtual
clock records half an hour in seconds).

A laser spot is measured as a run measures it (daemon/vision/centroid.py with the [camera]
settings); an arm's tool as an arm run does (daemon/run/arm/measure.py) at the pose the robot
reports, the markers' windows placed by that pose.
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass, field
from functools import partial

import numpy as np

from config import Settings
from daemon.analysis.budget_sources import Drift, Scatter, camera_drift, stationary_scatter
from daemon.arm.run import MeasurementError
from daemon.run.arm.measure import device_sensors, marker_views, tool_pose
from daemon.run.arm.robot import pose_matrix
from daemon.vision import CentroidError
from daemon.vision.centroid import measure_with_camera_settings
from daemon.vision.multiview import CameraModel
from drivers.clock import Clock, make_clock
from drivers.errors import DeviceError
from drivers.factory import Devices, open_devices

logger = logging.getLogger(__name__)


@dataclass
class Samples:
    """Measured frames: time (s), position along the measured axes (µm) and the centroid's
    reported 1-sigma (µm); NaN where a frame gave no measurement."""

    t_s: list[float] = field(default_factory=list)
    x_um: list[float] = field(default_factory=list)
    y_um: list[float] = field(default_factory=list)
    z_um: list[float] = field(default_factory=list)
    sigma_x_um: list[float] = field(default_factory=list)
    sigma_y_um: list[float] = field(default_factory=list)
    failures: int = 0

    def add(self, t_s: float, xyz: tuple[float, float, float], sigma: tuple[float, float]) -> None:
        self.t_s.append(t_s)
        self.x_um.append(xyz[0])
        self.y_um.append(xyz[1])
        self.z_um.append(xyz[2])
        self.sigma_x_um.append(sigma[0])
        self.sigma_y_um.append(sigma[1])


@dataclass(frozen=True)
class Recordings:
    drift: Drift | None
    scatter: Scatter | None
    why_not: str = ""
    camera_models: tuple[CameraModel, ...] = ()


def recording_settings(settings: Settings) -> Settings:
    """The simulated bench with its heaters off (the target must stay fixed); hardware as is."""
    if not settings.bench.enabled:
        return settings
    bench = settings.bench.model_copy(update={"heater_power_w": 0.0})
    return settings.model_copy(update={"bench": bench})


async def _spot(
    devices: Devices, settings: Settings
) -> tuple[tuple[float, float, float], tuple[float, float]]:

    frame = await asyncio.wait_for(devices.camera.grab(), settings.camera.grab_timeout_s)
    # the camera's own gain where it reports one, as the run's step does (the centroid's
    # noise model and its reported 1-sigma depend on it: measurement-noise.md)
    result = await asyncio.to_thread(
        partial(measure_with_camera_settings, camera_gain_e_per_count=frame.gain_e_per_count),
        frame.image,
        settings.camera,
    )
    return (result.x_um, result.y_um, 0.0), (result.sigma_x_um, result.sigma_y_um)


async def _tool(
    devices: Devices, settings: Settings
) -> tuple[tuple[float, float, float], tuple[float, float]]:

    models = devices.camera_models
    expected = pose_matrix(await devices.robot.actual_pose())
    sensors, timeouts = device_sensors(settings, len(models))
    frames = await asyncio.gather(
        *(asyncio.wait_for(c.grab(), t) for c, t in zip(devices.cameras, timeouts, strict=True))
    )
    markers = np.array(settings.arm.markers_mm, dtype=np.float64)
    world = markers @ expected[:3, :3].T + expected[:3, 3]

    def solve() -> tuple[tuple[float, float, float], tuple[float, float]]:
        views = marker_views(models, frames, world, sensors=sensors)
        measured = tool_pose(models, views, markers, expected)
        x, y, z = (1000.0 * measured.pose[:3, 3]).tolist()
        # the position's 1-sigma over its three axes (the bound of a 3-D scatter's norm)
        return (x, y, z), (1000.0 * measured.sigma_mm, 0.0)

    return await asyncio.to_thread(solve)


#: The first frame of a simulated camera builds its noise bank (seconds for a 5 MP arm camera
#: on a busy machine): the priming grab, not recorded, may take this many grab timeouts.
PRIME_TIMEOUTS = 10.0


async def _prime(devices: Devices, settings: Settings) -> None:
    """One frame from every camera, not recorded, before the recordings start (what a run's
    reference measurement does): a camera's first frame may be slow."""

    cameras = devices.cameras or (devices.camera,)
    _, timeouts = device_sensors(settings, len(cameras))
    if not devices.cameras:
        timeouts = (settings.camera.grab_timeout_s,)
    await asyncio.gather(
        *(
            asyncio.wait_for(camera.grab(), PRIME_TIMEOUTS * timeout)
            for camera, timeout in zip(cameras, timeouts, strict=True)
        )
    )


async def _record(
    devices: Devices,
    settings: Settings,
    clock: Clock,
    *,
    start_s: float,
    duration_s: float,
    count: int,
) -> Samples:

    samples = Samples()
    measure = _tool if devices.camera_models else _spot
    every = duration_s / max(count - 1, 1)
    for index in range(count):
        await clock.sleep_until(start_s + index * every)
        t = clock.now()
        try:
            xyz, sigma = await measure(devices, settings)
        except (CentroidError, MeasurementError) as err:
            samples.failures += 1
            logger.info("budget recording: frame at %.1f s not measured: %s", t, err)
            nan = float("nan")
            xyz, sigma = (nan, nan, nan), (nan, nan)
        samples.add(t, xyz, sigma)
    return samples


def _along_drift(samples: Samples, arm: bool) -> list[float]:
    """An arm's positions projected on the direction of their overall change (a 3-D drift as
    one number); a spot's x as it is (the chip's x is the measured axis)."""
    if not arm:
        return list(samples.x_um)
    points = np.column_stack([samples.x_um, samples.y_um, samples.z_um])
    good = np.isfinite(points).all(axis=1)
    if good.sum() < 2:
        return [float("nan")] * len(samples.t_s)
    first, last = points[good][0], points[good][-1]
    direction = last - first
    norm = float(np.linalg.norm(direction))
    unit = direction / norm if norm > 0 else np.array([1.0, 0.0, 0.0])
    projected: list[float] = ((points - first) @ unit).tolist()
    return projected


def _scatter(samples: Samples, arm: bool) -> Scatter:
    if not arm:
        return stationary_scatter(
            samples.t_s, samples.x_um, samples.y_um, samples.sigma_x_um, samples.sigma_y_um
        )
    # an arm: the scatter of the 3-D position (root of the three axes' variances) against
    # the pose fit's own 1-sigma of the position
    parts = [
        stationary_scatter(samples.t_s, axis, axis, samples.sigma_x_um, samples.sigma_x_um)
        for axis in (samples.x_um, samples.y_um, samples.z_um)
    ]
    std = float(np.sqrt(sum(p.std_um[0] ** 2 for p in parts)))
    spread = float(np.sqrt(sum(p.range_um[0] ** 2 for p in parts)))
    return Scatter(
        parts[0].frames, parts[0].duration_s, (std, 0.0), (spread, 0.0), (parts[0].bound_um[0], 0.0)
    )


async def record(
    settings: Settings,
    *,
    drift_s: float,
    drift_frames: int,
    stationary_s: float,
    stationary_frames: int,
) -> Recordings:
    """The two recordings (module docstring); a device that fails ends them with the reason."""
    chosen = recording_settings(settings)
    clock = make_clock(chosen.bench.clock, chosen.bench.time_factor)
    async with open_devices(chosen, clock) as devices:
        models = devices.camera_models
        arm = bool(models)
        start = clock.now()
        try:
            await _prime(devices, chosen)
            drifting = await _record(
                devices, chosen, clock, start_s=start, duration_s=drift_s, count=drift_frames
            )
            still = await _record(
                devices,
                chosen,
                clock,
                start_s=clock.now(),
                duration_s=stationary_s,
                count=stationary_frames,
            )
        except (DeviceError, TimeoutError) as err:
            reason = str(err) or "a camera gave no frame in time"
            return Recordings(None, None, f"the recording stopped: {reason}", models)
    notes = []
    try:
        drift: Drift | None = camera_drift(drifting.t_s, _along_drift(drifting, arm))
    except ValueError as err:
        drift = None
        notes.append(f"camera drift: {err} ({drifting.failures} frames not measured)")
    try:
        scatter: Scatter | None = _scatter(still, arm)
    except ValueError as err:
        scatter = None
        notes.append(f"stationary: {err} ({still.failures} frames not measured)")
    return Recordings(drift, scatter, "; ".join(notes), models)
