"""The arm bench's truth as a file (issue 29): ``bench.arm_truth`` names a TOML file (a preset in
config/truths or a path) that says what the simulated arm really is, where the controller only
believes. Every key is optional; its default is the truth the arm bench had before the file
existed (drivers/sim/arm_bench.py ArmBenchConfig), so a run without the setting reproduces
today's results to the bit. docs/explanation/bench-truth.md documents every key.

Two sets of bounds: the hard ones below refuse a file (a value no arm could have, or one
that breaks the simulation), one line naming the key; the issue's *plausible* ranges
(:data:`PLAUSIBLE`, :func:`implausible`) only say whether the compensation targets are
expected to hold on that truth (benchmarks/bench_arm_scenarios.py reports both).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Self

from pydantic import Field, ValidationError, model_validator

from config.section import Section
from config.toml_file import read_toml

#: Preset truths: ``bench.arm_truth = "hot-motors"`` is config/truths/hot-motors.toml.
TRUTHS_DIR = Path(__file__).resolve().parent / "truths"
#: One heat factor per joint at most (a 6- or 7-axis arm; a little room).
MAX_JOINTS = 12
HOURS_S = 3600.0

Factor = Annotated[float, Field(gt=0.05, le=20.0)]
HeatScales = Annotated[tuple[Factor, ...], Field(min_length=1, max_length=MAX_JOINTS)]


class ArmTruthError(ValueError):
    """A truth file that cannot be used; ``str()`` is one line naming the file and the key."""


class KinematicsTruth(Section):
    """The true arm's geometry: the preset's DH table moved by seeded draws."""

    dh_length_sigma_mm: Annotated[float, Field(ge=0, le=10)] = Field(
        0.2, description="1-sigma of the draw added to every DH length a, d (mm)."
    )
    dh_angle_sigma_rad: Annotated[float, Field(ge=0, le=0.05)] = Field(
        2e-4, description="1-sigma of the draw added to every DH alpha and theta offset (rad)."
    )


class MotorTruth(Section):
    """Each joint's motor heat for the same motion, as a factor of the preset's."""

    heat_scales: HeatScales | None = Field(
        None,
        description="Per joint: winding resistance and friction x this (the heat x about "
        "this); none: each drawn from the seed in [1 - heat_spread, 1 + heat_spread].",
    )
    heat_spread: Annotated[float, Field(ge=0, le=0.95)] = Field(
        0.25, description="Half-width of the seeded draw of the heat factors (no heat_scales)."
    )


class ThermalTruth(Section):
    """The true arm's thermal network against the preset's."""

    expansion_scale: Annotated[float, Field(ge=0.5, le=2.0)] = Field(
        1.05, description="Every link's expansion coefficient x this."
    )
    convection_scale: Annotated[float, Field(ge=0.1, le=5.0)] = Field(
        0.8, description="Every surface's convection coefficient x this."
    )
    capacity_scale: Annotated[float, Field(ge=0.2, le=5.0)] = Field(
        1.1, description="Every joint's (motor and gearbox) heat capacity x this."
    )
    bending_share: Annotated[float, Field(ge=0.0, le=1.0)] = Field(
        0.75,
        description="Share of each joint flange's conductance reaching the link's motor-housing "
        "side (0.5: both sides alike, no bending).",
    )
    node_spacing_mm: Annotated[float, Field(ge=2.0, le=100.0)] = Field(
        10.0, description="Node spacing of the truth's network (mm; the controller's: 50)."
    )


class RoomTruth(Section):
    """The air the arm stands in: a start, a linear drift and a sinusoidal swing."""

    start_c: Annotated[float, Field(ge=-20.0, le=60.0)] = Field(
        22.0, description="The room at the run's start (degC)."
    )
    drift_c_per_h: Annotated[float, Field(ge=-10.0, le=10.0)] = Field(
        0.0, description="Linear drift (degC per hour)."
    )
    swing_c: Annotated[float, Field(ge=0.0, le=20.0)] = Field(
        0.0, description="Amplitude of a sinusoidal swing, zero at the start (degC)."
    )
    swing_period_h: Annotated[float, Field(gt=0.0, le=1000.0)] = Field(
        24.0, description="Period of the swing (hours)."
    )

    def at_c(self, t_s: float) -> float:
        """The room's temperature ``t_s`` after the start (degC)."""
        hours = t_s / HOURS_S
        swing = self.swing_c * math.sin(2.0 * math.pi * hours / self.swing_period_h)
        return self.start_c + self.drift_c_per_h * hours + swing


class MeasurementTruth(Section):
    """The bench's sensors as they really are."""

    jitter_px: Annotated[float, Field(ge=0.0, le=5.0)] = Field(
        0.03, description="1-sigma image-plane jitter of every marker's spot (px)."
    )
    ir_noise_c: Annotated[float, Field(ge=0.0, le=5.0)] = Field(
        0.05, description="1-sigma noise of each IR region's reading (degC)."
    )
    ir_offset_sigma_c: Annotated[float, Field(ge=0.0, le=10.0)] = Field(
        0.3, description="1-sigma of each IR region's constant offset, drawn from the seed."
    )
    room_noise_c: Annotated[float, Field(ge=0.0, le=5.0)] = Field(
        0.02, description="Simulated room thermometer: 1-sigma noise of a reading (degC)."
    )
    room_resolution_c: Annotated[float, Field(ge=0.0, le=1.0)] = Field(
        0.0625,
        description="Simulated room thermometer: the reading's step (degC; a DS18B20 at 12 "
        "bits: 0.0625; 0: none).",
    )
    room_lag_s: Annotated[float, Field(ge=0.0, le=7200.0)] = Field(
        120.0,
        description="Simulated room thermometer: its first-order time constant in the air (s; "
        "a TO-92 DS18B20 in still air: a minute or two).",
    )
    room_offset_c: Annotated[float, Field(ge=-5.0, le=5.0)] = Field(
        0.0, description="Simulated room thermometer: constant error of its readings (degC)."
    )


class ArmTruth(Section):
    """What the simulated arm really is (module docstring)."""

    description: str = Field("", max_length=2000, description="What this truth is for.")
    seed: Annotated[int, Field(ge=0, le=2**63 - 1)] | None = Field(
        None,
        description="Seed of the truth's draws (DH errors, heat factors, IR offsets); "
        "none: bench.seed.",
    )
    kinematics: KinematicsTruth = KinematicsTruth()
    motors: MotorTruth = MotorTruth()
    thermal: ThermalTruth = ThermalTruth()
    room: RoomTruth = RoomTruth()
    measurement: MeasurementTruth = MeasurementTruth()

    @model_validator(mode="after")
    def _sane(self) -> Self:
        # a swing faster than a few minutes is not a room (and steps of the truth miss it)
        if self.room.swing_c > 0.0 and self.room.swing_period_h < 0.1:
            raise ValueError("room.swing_period_h: a room's swing takes at least 0.1 h")
        return self


#: The issue's plausible ranges (issue 29 "Targets"): the targets are promised on a truth
#: whose every factor lies within them. Heats x0.5-2, expansion +-10 %, convection
#: x0.5-1.5, capacity +-30 %, bending share 0.5-0.9, a room within 3 degC over 8 h.
PLAUSIBLE: dict[str, tuple[float, float]] = {
    "motors.heat": (0.5, 2.0),
    "thermal.expansion_scale": (0.9, 1.1),
    "thermal.convection_scale": (0.5, 1.5),
    "thermal.capacity_scale": (0.7, 1.3),
    "thermal.bending_share": (0.5, 0.9),
}
#: The room's plausible excursion from its start over an 8-hour run (degC).
PLAUSIBLE_ROOM_EXCURSION_C = 3.0
PLAUSIBLE_RUN_S = 8 * HOURS_S


def room_excursion_c(room: RoomTruth, duration_s: float = PLAUSIBLE_RUN_S) -> float:
    """The room's largest distance from its start within ``duration_s`` (degC; sampled every
    minute, finer than any plausible swing)."""
    samples = max(2, int(duration_s / 60.0) + 1)
    return max(
        abs(room.at_c(duration_s * k / (samples - 1)) - room.start_c) for k in range(samples)
    )


def implausible(truth: ArmTruth) -> list[str]:
    """What of ``truth`` lies outside the plausible ranges (empty: the targets apply)."""
    out: list[str] = []
    motors = truth.motors
    heats = motors.heat_scales or (1.0 - motors.heat_spread, 1.0 + motors.heat_spread)
    low, high = PLAUSIBLE["motors.heat"]
    if min(heats) < low or max(heats) > high:
        out.append(f"motors: heat factors {min(heats):g}-{max(heats):g} outside {low:g}-{high:g}")
    for key in ("expansion_scale", "convection_scale", "capacity_scale", "bending_share"):
        value = float(getattr(truth.thermal, key))
        low, high = PLAUSIBLE[f"thermal.{key}"]
        if not low <= value <= high:
            out.append(f"thermal.{key} {value:g} outside {low:g}-{high:g}")
    excursion = room_excursion_c(truth.room)
    if excursion > PLAUSIBLE_ROOM_EXCURSION_C + 1e-9:
        out.append(
            f"room: {excursion:.2f} degC from its start within 8 h (plausible: "
            f"{PLAUSIBLE_ROOM_EXCURSION_C:g})"
        )
    return out


def truth_path(name: str | Path) -> Path:
    """A preset's file in config/truths (``name`` without a suffix), else ``name`` as a path."""
    text = str(name)
    preset = TRUTHS_DIR / f"{text}.toml"
    return preset if "/" not in text and preset.exists() else Path(text)


def _first_error(error: ValidationError) -> str:
    item = error.errors()[0]
    path = ".".join(str(part) for part in item["loc"]) or "(file)"
    reason = str(item["msg"]).removeprefix("Value error, ")
    if item["type"] == "extra_forbidden":
        reason = "unknown key"
    more = len(error.errors()) - 1
    given = "" if item["type"] == "extra_forbidden" else f" (given {item.get('input')!r})"
    return f"{path}: {reason}{given}" + (f" (and {more} more)" if more else "")


def parse_arm_truth(data: dict[str, Any], source: str) -> ArmTruth:
    """A truth from a TOML file's tables; ArmTruthError naming ``source`` and the key."""
    try:
        return ArmTruth.model_validate(data)
    except ValidationError as err:
        raise ArmTruthError(f"arm truth {source}: {_first_error(err)}") from err


def load_arm_truth(name: str | Path) -> ArmTruth:
    """The truth file ``name`` (a preset in config/truths or a path): ArmTruthError, one line,
    when it is missing, not TOML, or any key is unknown, out of range or not finite."""
    path = truth_path(name)
    data = read_toml(path, ArmTruthError)
    return parse_arm_truth(data, str(path))


__all__ = [
    "PLAUSIBLE",
    "TRUTHS_DIR",
    "ArmTruth",
    "ArmTruthError",
    "KinematicsTruth",
    "MeasurementTruth",
    "MotorTruth",
    "RoomTruth",
    "ThermalTruth",
    "implausible",
    "load_arm_truth",
    "parse_arm_truth",
    "room_excursion_c",
    "truth_path",
]
