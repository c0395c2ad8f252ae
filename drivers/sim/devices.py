"""The simulated camera and infrared reader: they look at the bench's physical truth.

The camera renders the laser spot where the bench puts it with the generator of the centroid
work (``daemon.vision.render_spot``: spot shape, photon and read noise, bit depth). Drawing
that noise over the whole chip costs ~17 ms a frame, more than the rest of a step together,
so only a window around the spot (``FRESH_WINDOW_SIGMAS`` spot radii, at least
``FRESH_WINDOW_MIN_PX``: wider than the estimator's window and background ring) is drawn fresh
each frame; the rest of the chip, where the frame holds only dark level and read noise, is one
of ``NOISE_BANK_SIZE`` fields drawn once from the same distribution and shifted at random. The IR
reader images the link's true temperature profile with 0.08 degC noise per pixel (the FLIR
A40M's thermal sensitivity, thesis 3.2.2) and a fixed offset within its +-2 degC accuracy.

Both inject the sensor faults of ``bench.camera_faults`` / ``bench.ir_faults`` (issue 10; the
spec and kinds in config/faults.py), counted per grab/read since the device opened:
``no-frame`` never returns (until the caller's timeout cancels it: it does not sleep on the
clock, which a virtual clock would jump forward by the wait), ``late=S`` delivers a
measurement S seconds of the run clock after the exposure it is stamped with (below),
``unreadable`` delivers data that the real drivers' own checks refuse
(``drivers.camera.to_grey``, ``drivers.ir.finite_thermal_frame``), so the sim exercises those
checks. ``faults_applied`` lists what struck: (count, kind).

A late frame is a wait on the clock: the camera is grabbed inside its step, before the next
deadline, so on a virtual clock the jump costs the run its time exactly as a real wait would.
A late IR reading is one exposed S seconds before it is read (the reader's buffer held it),
with no wait: the IR is read while the next steps move (issue 30's overlap), and a wait there
would jump a virtual clock under a step already woken -- where it lands (before that step
begins, between its frame and its age check, after it) would depend on thread timing, and so
would which steps are flagged. What the daemon must do with a late reading depends only on
its age, which this gives exactly; the content is the link's temperatures at the read (the
truth cannot be evaluated in its past), and a stale reading is never used.
"""

from __future__ import annotations

import asyncio
import logging
import math
from types import TracebackType
from typing import Any, Self

import numpy as np
from numpy.typing import NDArray

from config.faults import Fault, SensorFaultKind, parse_sensor_faults
from config.settings import CameraSettings, IrRegion, IrSettings, Settings
from daemon.model import load_network
from daemon.vision import render_spot
from drivers.base import Frame, IrReading
from drivers.camera import to_grey
from drivers.clock import Clock
from drivers.deadline import off_the_clock
from drivers.ir import finite_thermal_frame, region_temperatures
from drivers.sim.bench import Bench

logger = logging.getLogger(__name__)

#: The simulated thermal image: 160 x 120 pixels (a FLIR Lepton's format), the link lying
#: horizontally across it in rows LINK_ROWS, with IR_MARGIN_PX of background at each end.
IR_SHAPE = (120, 160)
LINK_ROWS = (56, 64)
IR_MARGIN_PX = 5
#: Width of the default region around a model node (px).
DEFAULT_REGION_WIDTH_PX = 3


#: Half-width of the freshly rendered window around the spot, in spot radii and at least px.
FRESH_WINDOW_SIGMAS = 16.0
FRESH_WINDOW_MIN_PX = 48
#: Pre-drawn dark-noise fields the rest of the chip is taken from.
NOISE_BANK_SIZE = 4
#: Fault draws (``%P``) have their own streams of ``bench.seed``, beside the bench's camera,
#: IR and robot streams (its children 0-2), so configuring faults never changes the noise.
CAMERA_FAULT_STREAM = 3
IR_FAULT_STREAM = 4


class SensorFaults:
    """The faults configured for one simulated sensor, counted per grab/read (1-based)."""

    def __init__(self, spec: str, seed: int, stream: int, device: str) -> None:
        self.faults = parse_sensor_faults(spec)
        self.device = device
        self._rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(stream,)))
        self.count = 0
        self.applied: list[tuple[int, SensorFaultKind]] = []

    def next(self) -> Fault[SensorFaultKind] | None:
        """Count one more grab/read; the fault that strikes it, if any."""
        self.count += 1
        for fault in self.faults:
            if fault.strikes(self.count, self._rng):
                self.applied.append((self.count, fault.kind))
                logger.info("%s: injecting %s at grab/read %d", self.device, fault.kind, self.count)
                return fault
        return None


async def _never_delivered() -> None:
    """A grab that never returns: waits until the caller gives up and cancels it."""
    await asyncio.get_running_loop().create_future()


async def _late(clock: Clock, exposed_s: float, fault: Fault[SensorFaultKind] | None) -> None:
    """A late delivery: return ``fault.seconds`` of the run clock after the exposure."""
    if fault is not None and fault.kind == "late" and fault.seconds is not None:
        await clock.sleep_until(exposed_s + fault.seconds)


def _late_by_s(fault: Fault[SensorFaultKind] | None) -> float:
    """How long before its read a late reading was exposed (0 for any other fault)."""
    if fault is not None and fault.kind == "late" and fault.seconds is not None:
        return fault.seconds
    return 0.0


class SimCamera:
    """The bench's camera: one rendered frame per grab, at the clock's now."""

    def __init__(self, settings: CameraSettings, bench: Bench, clock: Clock) -> None:
        self.settings = settings
        self.bench = bench
        self.clock = clock
        self._sequence = 0
        self._lock = asyncio.Lock()  # one render at a time: the noise stream stays in order
        self._noise_bank: list[NDArray[np.generic]] = []
        self._faults = SensorFaults(
            bench.settings.bench.camera_faults,
            bench.settings.bench.seed,
            CAMERA_FAULT_STREAM,
            "camera",
        )

    @property
    def faults_applied(self) -> list[tuple[int, SensorFaultKind]]:
        """(grab number, kind) of every fault injected so far."""
        return self._faults.applied

    def _render_kwargs(self) -> dict[str, Any]:
        camera, bench = self.settings, self.bench.settings.bench
        return {
            "sigma_px": bench.spot_sigma_px,
            "bit_depth": camera.bit_depth,
            "rng": self.bench.camera_rng,
            "read_noise_counts": camera.read_noise_e / bench.camera_gain_e_per_count,
            "photon_noise": True,
            "gain_e_per_count": bench.camera_gain_e_per_count,
        }

    def render(self, centre_xy: tuple[float, float]) -> NDArray[np.generic]:
        """One frame with the spot at ``centre_xy`` (blocking: call it in a thread)."""
        shape = (self.settings.height_px, self.settings.width_px)
        rng = self.bench.camera_rng
        if not self._noise_bank:
            self._noise_bank = [
                render_spot(shape=shape, peak_fraction=0.0, **self._render_kwargs())
                for _ in range(NOISE_BANK_SIZE)
            ]
        field = self._noise_bank[int(rng.integers(NOISE_BANK_SIZE))]
        shift = (int(rng.integers(shape[0])), int(rng.integers(shape[1])))
        frame = np.roll(field, shift, axis=(0, 1))
        sigma_px = self.bench.settings.bench.spot_sigma_px
        half = max(FRESH_WINDOW_MIN_PX, math.ceil(FRESH_WINDOW_SIGMAS * sigma_px))
        x, y = centre_xy
        c0, c1 = max(0, math.floor(x) - half), min(shape[1], math.floor(x) + half + 1)
        r0, r1 = max(0, math.floor(y) - half), min(shape[0], math.floor(y) + half + 1)
        if c1 > c0 and r1 > r0:  # else the spot is off the chip: dark frame
            frame[r0:r1, c0:c1] = render_spot(
                shape=(r1 - r0, c1 - c0),
                centre_xy=(x - c0, y - r0),
                peak_fraction=self.bench.settings.bench.spot_peak_fraction,
                **self._render_kwargs(),
            )
        return frame

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        return None

    async def grab(self) -> Frame:
        async with self._lock:
            fault = self._faults.next()
            if fault is not None and fault.kind == "no-frame":
                await _never_delivered()
            t_s = self.clock.now()
            image: NDArray[np.generic]
            if fault is not None and fault.kind == "unreadable":
                # a buffer that is no image (what an undecodable stream frame looks like)
                image = np.zeros(self.settings.width_px * self.settings.height_px, np.uint8)
            else:
                # computing, not the camera's latency: off a grab's deadline
                image = await off_the_clock(self.render, self.bench.spot_centre_px(t_s))
            await _late(self.clock, t_s, fault)
            frame = Frame(
                image=to_grey(image),  # the real driver's check
                bit_depth=self.settings.bit_depth,
                timestamp_s=t_s,
                sequence=self._sequence,
                timestamp_source="camera",  # rendered at its exposure time exactly
                gain_e_per_count=(
                    self.bench.settings.bench.camera_gain_e_per_count
                    if self.bench.settings.bench.camera_reports_gain
                    else None
                ),
            )
            self._sequence += 1
        return frame


class SimIrReader:
    """The bench's infrared camera: the truth's temperature profile as a thermal image."""

    def __init__(self, settings: Settings, bench: Bench, clock: Clock) -> None:
        self.settings: IrSettings = settings.ir
        self.bench = bench
        self.clock = clock
        low, high = bench.network.bar_ends_mm or (0.0, 1.0)
        self._origin_mm = low
        self._mm_per_px = (high - low) / (IR_SHAPE[1] - 2 * IR_MARGIN_PX)
        columns = np.arange(IR_SHAPE[1], dtype=np.float64)
        self._column_mm = low + (columns - IR_MARGIN_PX + 0.5) * self._mm_per_px
        self._on_link = (self._column_mm >= low) & (self._column_mm <= high)
        self.regions = settings.ir.regions or self.default_regions(settings)
        self._sequence = 0
        self._lock = asyncio.Lock()  # one read at a time: sequence numbers follow the reads
        self._faults = SensorFaults(
            settings.bench.ir_faults, settings.bench.seed, IR_FAULT_STREAM, "ir"
        )

    @property
    def faults_applied(self) -> list[tuple[int, SensorFaultKind]]:
        """(read number, kind) of every fault injected so far."""
        return self._faults.applied

    def column_of(self, position_mm: float) -> int:
        return int(IR_MARGIN_PX + (position_mm - self._origin_mm) / self._mm_per_px)

    def default_regions(self, settings: Settings) -> tuple[IrRegion, ...]:
        """Without configured regions: one per heater and reference node of the controller's
        network, named ``node-<name>`` and tied to it."""
        network = load_network(settings.model.network, settings.storage.data_dir)
        names = dict.fromkeys((*network.heater_nodes, *network.reference_nodes))
        half = DEFAULT_REGION_WIDTH_PX // 2
        regions = []
        for name in names:
            position = float(network.positions_mm[network.node_index(name)])
            column = min(max(self.column_of(position) - half, 0), IR_SHAPE[1] - 1 - 2 * half)
            regions.append(
                IrRegion(
                    name=f"node-{name}",
                    x=column,
                    y=LINK_ROWS[0],
                    width=DEFAULT_REGION_WIDTH_PX,
                    height=LINK_ROWS[1] - LINK_ROWS[0],
                    node=name,
                )
            )
        return tuple(regions)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        return None

    def frame_c(self, t_s: float) -> NDArray[np.float64]:
        """The thermal image at ``t_s`` in degC, noise and offset included."""
        frame = np.full(IR_SHAPE, self.bench.model.ambient_c, dtype=np.float64)
        profile = self.bench.temperatures_at(self._column_mm[self._on_link], t_s)
        frame[LINK_ROWS[0] : LINK_ROWS[1], self._on_link] = profile
        noise = self.bench.ir_rng.normal(0.0, self.bench.ir_noise_c, size=IR_SHAPE)
        result: NDArray[np.float64] = frame + self.settings.offset_c + noise
        return result

    async def read(self) -> IrReading:
        async with self._lock:
            fault = self._faults.next()
            if fault is not None and fault.kind == "no-frame":
                await _never_delivered()
            t_s = self.clock.now()
            frame = self.frame_c(t_s)
            if fault is not None and fault.kind == "unreadable":
                frame[LINK_ROWS[0] : LINK_ROWS[1]] = np.nan  # rows lost in transfer
            frame = finite_thermal_frame(frame, "sim")  # the real driver's check
            reading = IrReading(
                regions=region_temperatures(frame, self.regions),
                timestamp_s=t_s - _late_by_s(fault),  # held in the buffer: no wait (docstring)
                sequence=self._sequence,
                frame_c=frame,
            )
            self._sequence += 1
        return reading
