"""Radiometric IR over GenICam (issue 18): FLIR's Planck conversion and measurement formula on
synthetic raw counts with known constants, checked against hand-computed values; the linear
mode and the missing-registers refusal through pylon's emulated camera."""

from __future__ import annotations

import importlib.util
import math
import os
from typing import Any

import numpy as np
import pytest

os.environ.setdefault("PYLON_CAMEMU", "2")  # before pylon starts (as in test_genicam.py)

from config.settings import IrRegion, IrSettings
from drivers.clock import ScaledClock
from drivers.errors import ProtocolError
from drivers.genicam.radiometric import (
    KELVIN_AT_0C,
    GenICamRadiometricIrReader,
    PlanckConstants,
    SceneCompensation,
    linear_counts_to_kelvin,
    planck_counts_to_kelvin,
)

# Public FLIR calibration constants, as ExifTool prints them for a FLIR camera and as the
# Thermimage R package's raw2temp uses by default: PlanckR1 = 21106.77, PlanckR2 = 0.012545258,
# PlanckB = 1501, PlanckF = 1, PlanckO = -7340. In GenICam's form T = B / ln(R / (S - O) + F):
# R = R1 / R2 = 1682450.054..., O = -PlanckO.
FLIR = PlanckConstants(r=21106.77 / 0.012545258, b=1501.0, f=1.0, o=7340.0)
BLACK_BODY = SceneCompensation()


def kelvin(counts: float, scene: SceneCompensation = BLACK_BODY) -> float:
    return float(planck_counts_to_kelvin(np.array([counts]), FLIR, scene)[0])


def test_black_body_counts_match_hand_computed_temperatures() -> None:
    # By hand: S = R / (exp(B / T) - F) + O. For T = 293.15 K: exp(1501 / 293.15) = 167.376...,
    # R / 166.376 = 10112.31, + 7340 = 17452.31; for 323.15 K: 23666.04; for 373.15 K: 38018.61.
    assert kelvin(17452.307454) == pytest.approx(293.15, abs=1e-5)
    assert kelvin(23666.043273) == pytest.approx(323.15, abs=1e-5)
    assert kelvin(38018.606321) == pytest.approx(373.15, abs=1e-5)
    # and the other way: S = 20000 -> T = 1501 / ln(1682450.05 / 12660 + 1)
    #                                    = 1501 / 4.897056 = 306.5107 K
    assert kelvin(20000.0) == pytest.approx(306.510717, abs=1e-5)


def test_emissivity_and_reflection_are_removed() -> None:
    # A link at 50 degC with emissivity 0.95 in a 20 degC room: the detector sees
    # 0.95 W(323.15) + 0.05 W(293.15) + O = 23355.356 counts (by hand from the values above);
    # read as a black body that is colder than the link.
    scene = SceneCompensation(emissivity=0.95, reflected_k=293.15)
    assert kelvin(23355.356482, scene) == pytest.approx(323.15, abs=1e-5)
    assert kelvin(23355.356482) < 323.15 - 0.5


def test_atmosphere_and_window_are_removed() -> None:
    # the measurement formula forward, written out independently of the driver
    def w(t_k: float) -> float:
        return FLIR.r / (math.exp(FLIR.b / t_k) - FLIR.f)

    e, t_a, t_w = 0.9, 0.92, 0.7
    t_obj, t_refl, t_atm, t_win = 340.0, 295.0, 290.0, 300.0
    measured = (
        t_w * (e * t_a * w(t_obj) + (1 - e) * t_a * w(t_refl) + (1 - t_a) * w(t_atm))
        + (1 - t_w) * w(t_win)
        + FLIR.o
    )
    scene = SceneCompensation(e, t_refl, t_a, t_atm, t_w, t_win)
    assert kelvin(measured, scene) == pytest.approx(t_obj, abs=1e-6)


def test_counts_below_the_offset_are_not_a_temperature() -> None:
    assert math.isnan(kelvin(FLIR.o - 1.0))


def test_linear_mode_is_counts_times_resolution() -> None:
    # FLIR Ax5 high resolution: 0.04 K per count; 7500 counts = 300 K = 26.85 degC
    assert linear_counts_to_kelvin(np.array([7500], np.uint16), 0.04)[0] == pytest.approx(300.0)
    assert linear_counts_to_kelvin(np.array([30000], np.uint16), 0.01)[0] == pytest.approx(300.0)


needs_pylon = pytest.mark.skipif(
    importlib.util.find_spec("pypylon") is None,
    reason="pypylon (the genicam extra) is not installed: pip install 'thermocomp[genicam]'",
)


def ir_settings(**overrides: Any) -> IrSettings:
    values: dict[str, Any] = {
        "driver": "genicam-radiometric",
        "serial": "0815-0000",
        "regions": (IrRegion(name="link", x=10, y=20, width=30, height=8, node="2"),),
    }
    return IrSettings(**{**values, **overrides})


@needs_pylon
async def test_a_camera_without_planck_registers_is_one_clear_line() -> None:
    reader = GenICamRadiometricIrReader(ir_settings(), ScaledClock())
    with pytest.raises(ProtocolError) as caught:
        async with reader:
            pass
    message = str(caught.value)
    assert "\n" not in message
    assert "Emulation 0815-0000 has no Planck registers (R, B, F, O missing)" in message
    assert 'ir.conversion = "linear"' in message


@needs_pylon
async def test_linear_mode_through_the_emulated_transport() -> None:
    clock = ScaledClock()
    settings = ir_settings(conversion="linear", linear_resolution_k=0.01)
    async with GenICamRadiometricIrReader(settings, clock) as reader:
        before = clock.now()
        reading = await reader.read()
        second = await reader.read()
    assert reading.frame_c is not None and reading.frame_c.dtype == np.float64
    counts = (reading.frame_c + KELVIN_AT_0C) / 0.01
    assert np.allclose(counts, np.round(counts), atol=1e-6)  # on the 0.01 K grid
    assert counts.min() >= 0 and counts.max() <= 65535  # Mono16 counts
    assert len(np.unique(counts)) > 1  # the emulation's test image, not a constant
    patch = reading.frame_c[20:28, 10:40]
    link = reading.regions["link"]
    assert link.mean_c == pytest.approx(float(patch.mean()))
    assert link.max_c == pytest.approx(float(patch.max())) and link.node == "2"
    assert reading.timestamp_s >= before
    assert (reading.sequence, second.sequence) == (0, 1)
