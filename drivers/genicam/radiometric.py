"""Radiometric thermal cameras over GenICam (``ir.driver = "genicam-radiometric"``): FLIR
A-series / Ax5 on GigE Vision, through the GenICam transport of drivers/genicam/transport.py.

Two ways from counts to temperature, as the camera offers them:

- ``planck``: the camera streams raw detector signal S, and publishes its calibration for the
  current gain mode as the registers R, B, F, O (read after every open, i.e. in the gain mode the
  camera is in). FLIR's formula for a black body seen directly is

      T = B / ln(R / (S - O) + F)                  (kelvin)

  so S - O = W(T) = R / (exp(B / T) - F) is proportional to the radiance the detector gets.
  A real scene adds what the object reflects and what the air and a window emit: FLIR's
  measurement formula (FLIR user manuals, "The measurement formula"; the same chain as
  ExifTool's / Thermimage's raw2temp) in signal units, with emissivity e, atmospheric
  transmission t_a and window transmission t_w (its emissivity 1 - t_w, no reflection):

      W_meas = t_w (e t_a W_obj + (1 - e) t_a W_refl + (1 - t_a) W_atm) + (1 - t_w) W_win

  solved for W_obj, then T_obj from W_obj with the formula above. ExifTool's PlanckR1/R2/O
  give R = R1 / R2 and O = -PlanckO (its formula adds O).
- ``linear``: the camera computes the temperature itself (``TemperatureLinearMode``) and
  streams kelvin / resolution (Ax5: 0.04 K high, 0.4 K low resolution; A50/A70: 0.01 / 0.1 K,
  FLIR support answer 1021 "Temperature linear mode"); the object parameters (emissivity,
  reflected, atmospheric and window temperatures, window transmission) are then written to the
  camera's registers where it has them, since it applies them.

A camera without the R, B, F, O registers cannot be read in Planck mode: one clear line says so.
"""

from __future__ import annotations

import asyncio
import logging
import math
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Self

import numpy as np
from numpy.typing import NDArray

from config.settings import IrSettings
from drivers.base import IrReading, LinkState
from drivers.clock import Clock
from drivers.errors import ProtocolError
from drivers.genicam.transport import (
    GenICamSelection,
    GenICamTransport,
    choose_pixel_format,
    node_value,
    set_node,
)
from drivers.ir import finite_thermal_frame, region_temperatures
from drivers.reconnect import RECONNECT_FIRST_BACKOFF_S

logger = logging.getLogger(__name__)

DEVICE = "ir"
KELVIN_AT_0C = 273.15
PLANCK_REGISTERS = ("R", "B", "F", "O")
#: Pixel formats of radiometric streams, preferred first (A-series Mono16, Ax5 Mono14).
RADIOMETRIC_FORMATS = ("Mono16", "Mono14")
#: Node names of the gain mode (the constants belong to it), reported when present.
GAIN_MODE_NODES = ("SensorGainMode", "GainMode", "CurrentCase")


@dataclass(frozen=True, slots=True)
class PlanckConstants:
    """A FLIR camera's calibration for one gain mode: T = B / ln(R / (S - O) + F)."""

    r: float
    b: float
    f: float
    o: float

    def signal(self, kelvin: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """W(T) = S - O of a black body at ``kelvin``."""
        return np.asarray(self.r / (np.exp(self.b / np.asarray(kelvin)) - self.f))

    def kelvin(self, signal: NDArray[np.float64]) -> NDArray[np.float64]:
        """The black-body temperature of signal W = S - O (NaN where W <= 0: unphysical)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            result: NDArray[np.float64] = self.b / np.log(self.r / signal + self.f)
        return np.where(signal > 0, result, np.nan)


@dataclass(frozen=True, slots=True)
class SceneCompensation:
    """What lies between the link and the detector (module docstring); temperatures in K."""

    emissivity: float = 1.0
    reflected_k: float = 295.15
    atmospheric_transmission: float = 1.0
    atmospheric_k: float = 295.15
    window_transmission: float = 1.0
    window_k: float = 295.15

    @classmethod
    def from_settings(cls, settings: IrSettings) -> SceneCompensation:
        return cls(
            emissivity=settings.emissivity,
            reflected_k=settings.reflected_temp_c + KELVIN_AT_0C,
            atmospheric_transmission=settings.atmospheric_transmission,
            atmospheric_k=settings.atmospheric_temp_c + KELVIN_AT_0C,
            window_transmission=settings.window_transmission,
            window_k=settings.window_temp_c + KELVIN_AT_0C,
        )


def planck_counts_to_kelvin(
    counts: NDArray[Any], constants: PlanckConstants, scene: SceneCompensation
) -> NDArray[np.float64]:
    """Raw counts S to the object's temperature (K) through FLIR's measurement formula."""
    measured = counts.astype(np.float64) - constants.o
    e, t_a, t_w = scene.emissivity, scene.atmospheric_transmission, scene.window_transmission
    reflected = float(constants.signal(scene.reflected_k))
    atmosphere = float(constants.signal(scene.atmospheric_k))
    window = float(constants.signal(scene.window_k))
    through_window = (measured - (1.0 - t_w) * window) / t_w
    obj = (through_window - (1.0 - e) * t_a * reflected - (1.0 - t_a) * atmosphere) / (e * t_a)
    return constants.kelvin(obj)


def linear_counts_to_kelvin(counts: NDArray[Any], resolution_k: float) -> NDArray[np.float64]:
    """Temperature-linear counts to kelvin: counts x resolution."""
    kelvin: NDArray[np.float64] = counts.astype(np.float64) * resolution_k
    return kelvin


def read_planck_constants(camera: Any, description: str) -> PlanckConstants:
    """R, B, F, O from the camera's registers, or one clear line when it has none."""
    values = {name: node_value(camera, name) for name in PLANCK_REGISTERS}
    missing = [name for name, value in values.items() if value is None]
    if missing:
        raise ProtocolError(
            DEVICE,
            f"{description} has no Planck registers ({', '.join(missing)} missing): not a "
            'radiometric camera; ir.conversion = "linear" reads one that streams temperature',
        )
    r, b, f, o = (float(value) for value in values.values() if value is not None)
    constants = PlanckConstants(r=r, b=b, f=f, o=o)
    if not all(math.isfinite(v) for v in (constants.r, constants.b, constants.f, constants.o)):
        raise ProtocolError(DEVICE, f"{description}: its Planck registers are not finite")
    return constants


class GenICamRadiometricIrReader:
    """The IR camera over GenICam: raw or linear counts to degC, then the regions."""

    def __init__(
        self,
        settings: IrSettings,
        clock: Clock,
        *,
        first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S,
    ) -> None:
        self.settings = settings
        self.clock = clock
        self.scene = SceneCompensation.from_settings(settings)
        self.transport = GenICamTransport(
            GenICamSelection(
                device=DEVICE,
                serial=settings.serial,
                user_id=settings.user_id,
                grab_timeout_s=settings.read_timeout_s,
                reconnect_max_backoff_s=settings.reconnect_max_backoff_s,
                trigger="software",
            ),
            clock,
            self._configure,
            first_backoff_s=first_backoff_s,
        )
        self.constants: PlanckConstants | None = None
        self.gain_mode: str | None = None
        self._sequence = 0
        self._lock = asyncio.Lock()

    def _configure(self, camera: Any) -> None:
        """On the worker thread after each open: format, mode, constants of the gain mode."""
        offered = tuple(camera.PixelFormat.Symbolics)
        wanted = next((name for name in RADIOMETRIC_FORMATS if name in offered), "Mono16")
        camera.PixelFormat.Value = choose_pixel_format(wanted, offered, DEVICE)
        linear = self.settings.conversion == "linear"
        set_node(camera, "TemperatureLinearMode", linear, DEVICE)
        self.gain_mode = next(
            (str(v) for v in (node_value(camera, n) for n in GAIN_MODE_NODES) if v is not None),
            None,
        )
        if linear:
            scene = self.scene
            for name, value in (
                ("ObjectEmissivity", scene.emissivity),
                ("ReflectedTemperature", scene.reflected_k),
                ("AtmosphericTemperature", scene.atmospheric_k),
                ("WindowTransmission", scene.window_transmission),
                ("WindowTemperature", scene.window_k),
            ):
                set_node(camera, name, value, DEVICE)
            self.constants = None
        else:
            self.constants = read_planck_constants(camera, self.transport.description)
            logger.info(
                "ir: Planck constants %s (gain mode %s)", self.constants, self.gain_mode or "-"
            )

    @property
    def link(self) -> LinkState:
        return self.transport.link

    async def __aenter__(self) -> Self:
        await self.transport.open()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self.transport.close()

    def to_celsius(self, counts: NDArray[Any]) -> NDArray[np.float64]:
        if self.constants is None:
            kelvin = linear_counts_to_kelvin(counts, self.settings.linear_resolution_k)
        else:
            kelvin = planck_counts_to_kelvin(counts, self.constants, self.scene)
        return kelvin - KELVIN_AT_0C

    async def read(self) -> IrReading:
        async with self._lock:
            raw = await self.transport.grab()
            frame_c = finite_thermal_frame(
                self.to_celsius(raw.image), self.transport.description or "genicam"
            )
            reading = IrReading(
                regions=region_temperatures(frame_c, self.settings.regions),
                timestamp_s=raw.timestamp_s,
                sequence=self._sequence,
                frame_c=frame_c,
            )
            self._sequence += 1
        return reading
