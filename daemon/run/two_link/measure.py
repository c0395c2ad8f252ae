"""A two-link step's measurement (thesis 6.2): the frame right after the move, the spot's
centroid and drift, the IR regions; and what an observer learns from them. The step's pipeline
(daemon/run/two_link/step.py) takes the frame before the next move and the rest while later
steps move."""

from __future__ import annotations

import functools
import json
import time
from collections.abc import Callable

import numpy as np

from config import Settings
from daemon.model.network import UM_PER_MM
from daemon.run.events import ErrorLog
from daemon.run.sensors import Sensors
from daemon.run.stage_times import StageTimes
from daemon.run.states import ProcedurePoint
from daemon.run.step import read_infrared
from daemon.run.two_link.work import RunWork
from daemon.run.workers import Workers
from daemon.storage.recorder import StepRecord
from daemon.vision import CentroidError, measure_with_camera_settings
from daemon.vision.calibration import camera_to_robot
from drivers.base import Frame
from drivers.errors import DeviceError


class StepMeasurement:
    """The measuring stages of a two-link step, on the run's sensors; each writes what it
    measured, its flags and its errors into the step's record and lists."""

    def __init__(
        self,
        settings: Settings,
        *,
        sensors: Sensors,
        workers: Workers,
        errors: ErrorLog,
        clock_now: Callable[[], float],
    ) -> None:
        self._settings = settings
        self._sensors = sensors
        self._workers = workers
        self._errors = errors
        self._now = clock_now

    async def grab(
        self, flags: list[str], errors: list[str], stages: StageTimes
    ) -> tuple[Frame | None, float]:
        """The step's frame and its age when taken (its staleness is judged at the grab, not
        when its centroid is computed a step later)."""
        started = time.perf_counter()
        frame: Frame | None = None
        age_s = 0.0
        try:
            frame = await self._sensors.grab()
            age_s = self._now() - frame.timestamp_s
        except DeviceError as err:
            self._errors.note(err)
            flags.append("camera-error")
            errors.append(str(err))
        stages.end("frame", started)
        return frame, age_s

    async def centroid(
        self,
        work: RunWork,
        *,
        point: ProcedurePoint,
        frame: Frame,
        age_s: float,
        record: StepRecord,
        flags: list[str],
        errors: list[str],
    ) -> None:
        camera_settings = self._settings.camera
        if frame.timestamp_source == "host":  # issue 18: say when the time is not exposure's
            flags.append("host-timestamp")
        stale = age_s > camera_settings.max_age_s
        if stale:
            flags.append("stale-frame")
            errors.append(self._sensors.stale("camera", "frame", age_s))
        try:
            result = await self._workers.step(
                functools.partial(
                    measure_with_camera_settings,
                    camera_gain_e_per_count=frame.gain_e_per_count,
                ),
                frame.image,
                camera_settings,
            )
        except CentroidError as err:
            flags.append("centroid-error")
            errors.append(f"centroid: {err}")
            return
        if result.gain_source not in {"config", "camera"}:
            # the noise model was measured on this frame (or could not be): say so
            flags.append("gain-from-frame" if result.gain_source == "frames" else "gain-unknown")
        record.centroid_x_px, record.centroid_y_px = result.x_px, result.y_px
        record.centroid_x_um, record.centroid_y_um = result.x_um, result.y_um
        if stale:  # a stale frame is recorded and flagged, never used
            return
        reference = work.reference_um.setdefault(point.pose_index, (result.x_um, result.y_um))
        record.drift_x_um = result.x_um - reference[0]
        record.drift_y_um = result.y_um - reference[1]
        # the drift in world coordinates (the camera's calibrated rotation, issue 18), along
        # the link: the residual of the compensation (thesis 6.2)
        world_um = camera_to_robot(
            (record.drift_x_um, record.drift_y_um), self._settings.camera.rotation_deg
        )
        record.residual_um = float(np.dot(world_um, work.direction))
        if work.observer is not None:
            # the link's own deformation: the drift with the commanded compensation taken out
            # (daemon.model.identify.measured_deformation_um), for an adapted "alpha" only
            scale = work.parameters.deformation_scale
            offset_um = float(np.dot(work.last_offset_mm, work.direction)) * UM_PER_MM
            work.observer.update_deformation(
                (record.residual_um - offset_um) / scale,
                self._settings.observer.deformation_noise_um / scale,
                scale,
            )

    async def infrared(
        self, work: RunWork, record: StepRecord, flags: list[str], errors: list[str]
    ) -> None:
        reading = await read_infrared(
            self._sensors,
            self._errors,
            self._now,
            self._settings,
            record=record,
            flags=flags,
            errors=errors,
        )
        if reading is not None and work.observer is not None:
            innovation = work.observer.update(
                {name: region.mean_c for name, region in reading.regions.items()}
            )
            if innovation is not None:
                record.innovation_nis = innovation.nis
            record.observer_json = json.dumps(
                {
                    name: [round(value, 6), round(sigma, 6)]
                    for name, (value, sigma) in work.observer.parameter_estimates().items()
                }
            )
            if work.observer.drifting:
                flags.append("model-drifting")
