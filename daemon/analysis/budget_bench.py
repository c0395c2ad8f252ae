"""The error budget's rows for a laser spot on one camera: the two-link bench (thesis 4.3-4.9,
issue 32). Pure: the set-up's facts, the model's expectations and the recordings' statistics
in, :class:`~daemon.analysis.budget.Source` rows out; the rows shared with an arm (the
recordings, the IR) are here too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from daemon.analysis.budget import COVERAGE, Source
from daemon.analysis.budget_sources import (
    G_M_PER_S2,
    Drift,
    Scatter,
    cantilever_deflection_m,
    diode_tilt_rad,
    foreshortening_m,
    hole_expansion_m,
    misalignment_y_m,
    misalignment_z_m,
    second_moment_m4,
    tilt_shift_m,
)

UM_PER_M = 1e6
MM = 1e-3


@dataclass(frozen=True)
class SpotSetup:
    """The mechanical facts of a laser-spot set-up that no setting holds (config/budget/*.toml;
    the defaults are the thesis's apparatus, each with its section)."""

    name: str = "thesis two-link bench"
    #: 4.3: the overhanging link, from the held shaft to the diode (two-link: 622.3 - 330.2 mm
    #: of Table 5.1's positions; the single link of 4.3.2 was 292.0 mm)
    cantilever_length_mm: float = 292.1
    link_width_mm: float = 25.4  # 3.2.1, 5.2.1
    link_thickness_mm: float = 6.35  # 3.2.1 prints 6.4; Table 5.1's area uses 6.35
    youngs_modulus_gpa: float = 70.0  # 6061-T6 (DESIGN.md: 4.3.2's "MPa" is a misprint)
    cantilever_mass_kg: float = 0.2  # 4.3.2: link and diode together, all at the free end
    #: Table 4.2: mechanical play about x (gamma), y (beta), z (theta), degrees
    play_x_deg: float = 0.4
    play_y_deg: float = 0.1
    play_z_deg: float = 0.2
    diode_hole_mm: float = 19.0  # 3.2.1
    diode_diameter_mm: float = 19.0  # 4.5.3: a snug fit when cold
    diode_alpha_per_k: float = 53e-6  # 4.5: ABS
    diode_rise_k: float = 0.0  # 4.5: the ABS diode stayed at room temperature
    diode_lever_mm: float = 75.0  # 4.5.3: link's mid-width to the chip
    heating_pads: bool = True  # 4.9 applies to a set-up heated by pads


def bending_source(setup: SpotSetup) -> Source:
    """4.3: the free end's deflection under the link's and the diode's weight, and the
    shortening along the link that it makes."""
    length = setup.cantilever_length_mm * MM
    moment = second_moment_m4(setup.link_thickness_mm * MM, setup.link_width_mm * MM)
    force = setup.cantilever_mass_kg * G_M_PER_S2
    deflection = cantilever_deflection_m(force, length, setup.youngs_modulus_gpa * 1e9, moment)
    shortening = foreshortening_m(length, deflection)
    return Source(
        key="bending",
        name="Cantilever bending",
        section="4.3",
        evidence="analytic",
        delta_l_um=shortening * UM_PER_M,
        effect="the link's end sags under its own and the diode's weight",
        remedy="none needed (Table 4.5: insignificant)",
        basis=(
            f"Eq. 4.1, {setup.cantilever_mass_kg:g} kg at the end of {setup.cantilever_length_mm:g}"
            f" mm, E {setup.youngs_modulus_gpa:g} GPa, {setup.link_thickness_mm:g} x "
            f"{setup.link_width_mm:g} mm: sag δL_y {deflection * UM_PER_M:.3g} µm, shortening "
            f"δL_x = L - sqrt(L² - δL_y²)"
        ),
        detail={"deflection_y_um": deflection * UM_PER_M, "force_n": force},
    )


def misalignment_sources(setup: SpotSetup, expected_um: float) -> list[Source]:
    """4.4: cosine errors of the link's play about z and y (x moves the spot across, 4.4.1)."""
    delta = expected_um / UM_PER_M
    theta, beta = math.radians(setup.play_z_deg), math.radians(setup.play_y_deg)
    remedy = "check and correct the link's alignment before each run (4.4.2)"
    common = f"Table 4.2 play, ΔL {expected_um:.3g} µm"
    return [
        Source(
            key="misalignment-z",
            name="Link misalignment about z",
            section="4.4",
            evidence="analytic",
            delta_l_um=misalignment_z_m(delta, theta) * UM_PER_M,
            effect="the deformation is seen at an angle θ in the chip's plane",
            remedy=remedy,
            basis=f"δL_x = ΔL (1 - cos θ), θ {setup.play_z_deg:g}°, {common}",
            detail={"angle_deg": setup.play_z_deg},
        ),
        Source(
            key="misalignment-y",
            name="Link misalignment about y",
            section="4.4",
            evidence="analytic",
            delta_l_um=misalignment_y_m(delta, beta) * UM_PER_M,
            effect="the chip sees the deformation on a plane tilted by β",
            remedy=remedy,
            basis=f"|δL_x| = ΔL (1/cos β - 1), β {setup.play_y_deg:g}°, {common}",
            detail={"angle_deg": setup.play_y_deg},
        ),
        Source(
            key="misalignment-x",
            name="Link misalignment about x",
            section="4.4",
            evidence="analytic",
            delta_l_um=0.0,
            effect="moves the spot across the measured axis only",
            remedy="none needed",
            basis=f"γ {setup.play_x_deg:g}° tips the beam vertically: δL_x = 0 (4.4.1)",
            detail={"angle_deg": setup.play_x_deg},
        ),
    ]


def diode_hole_source(setup: SpotSetup, link_alpha_per_k: float, link_rise_k: float) -> Source:
    """4.5: the hole grows with the link's temperature at the diode, the (cooler) diode does
    not; in the play, a disturbed diode can tip by Eq. 4.2's angle and move the spot."""
    growth = hole_expansion_m(link_alpha_per_k, setup.diode_hole_mm * MM, link_rise_k)
    diode_growth = hole_expansion_m(
        setup.diode_alpha_per_k, setup.diode_diameter_mm * MM, setup.diode_rise_k
    )
    hole = setup.diode_hole_mm * MM + growth
    diode = setup.diode_diameter_mm * MM + diode_growth
    tilt = diode_tilt_rad(setup.link_thickness_mm * MM, hole, diode)
    shift = tilt_shift_m(setup.diode_lever_mm * MM, tilt)
    return Source(
        key="diode-hole",
        name="Expansion of the diode hole",
        section="4.5",
        evidence="analytic",
        delta_l_um=shift * UM_PER_M,
        effect="the diode can tip in its grown hole and swing the beam",
        remedy="tighten the diode's set screw before each run; isolate the link and the "
        "diode's cable from disturbances (4.5.3)",
        basis=(
            f"hole +{growth * UM_PER_M:.3g} µm (α {link_alpha_per_k * 1e6:.3g}e-6/K, link "
            f"+{link_rise_k:.3g} K at the diode), diode +{diode_growth * UM_PER_M:.3g} µm: "
            f"Eq. 4.2 tilt {math.degrees(tilt):.3g}° through {setup.link_thickness_mm:g} mm, "
            f"x {setup.diode_lever_mm:g} mm to the chip"
        ),
        conditional="if the diode is disturbed",
        detail={
            "hole_growth_um": growth * UM_PER_M,
            "clearance_um": (hole - diode) * UM_PER_M,
            "tilt_deg": math.degrees(tilt),
            "link_rise_k": link_rise_k,
        },
    )


def heating_pad_source() -> Source:
    return Source(
        key="heating-pad",
        name="Heating pad flexibility",
        section="4.9",
        evidence="not quantified",
        delta_l_um=None,
        effect="uneven heat input: an error of the temperatures, not of the spot",
        remedy="a flexible pad wrapped tight round the shaft (4.9.1)",
        basis="the thesis judged it by the air temperature round the shaft only (4.9.2)",
    )


def recording_sources(
    scatter: Scatter | None,
    axis: int = 0,
    why_not: str = "",
    *,
    centroid: bool = True,
    along: str | None = None,
) -> list[Source]:
    """4.6 and 4.7 from a stationary recording: the centroid at its Cramér-Rao bound, and the
    scatter the bound does not explain (the robot idling, anything else moving the spot).
    ``centroid`` False (an arm: the centroids are in its 3-D measurement's row): 4.6 only,
    the scatter of the tool's position against the pose fit's own 1-sigma."""
    return [
        s
        for s in _recording_sources(scatter, axis, why_not, along or f"along {'xy'[axis]}")
        if centroid or s.key != "centroid"
    ]


def _recording_sources(
    scatter: Scatter | None, axis: int, why_not: str, along: str
) -> list[Source]:
    vibration_remedy = "hold the robot still with its power off for stationary measurements (4.6)"
    centroid_remedy = "a larger, brighter spot; the robust centroid (4.7); average frames"
    if scatter is None:
        reason = why_not or "no stationary recording"
        return [
            Source(
                "vibration", "Idle-induced robot vibration", "4.6", "not quantified", None,
                "the idling robot shakes the link and the diode", vibration_remedy, reason,
            ),
            Source(
                "centroid", "Centroid extraction", "4.7", "not quantified", None,
                "the spot's centroid scatters with photon and read noise", centroid_remedy, reason,
            ),
        ]  # fmt: skip
    names = "xy"
    detail: dict[str, float | str | None] = {
        "frames": scatter.frames,
        "duration_s": scatter.duration_s,
        "std_x_um": scatter.std_um[0],
        "std_y_um": scatter.std_um[1],
        "bound_x_um": scatter.bound_um[0],
        "bound_y_um": scatter.bound_um[1],
        "excess_x_um": scatter.excess_um[0],
        "excess_y_um": scatter.excess_um[1],
    }
    return [
        Source(
            key="vibration",
            name="Idle-induced robot vibration",
            section="4.6",
            evidence="measured",
            delta_l_um=COVERAGE * scatter.excess_um[axis],
            effect="the idling robot shakes the link and the diode",
            remedy=vibration_remedy,
            basis=(
                f"{scatter.frames} frames over {scatter.duration_s:.0f} s, robot powered and "
                f"held: scatter {along} {scatter.std_um[axis]:.3g} µm less the "
                f"measurement's own 1-sigma {scatter.bound_um[axis]:.3g} µm in quadrature, "
                f"x {COVERAGE:g}"
            ),
            detail=detail,
        ),
        Source(
            key="centroid",
            name="Centroid extraction",
            section="4.7",
            evidence="measured",
            delta_l_um=COVERAGE * scatter.bound_um[axis],
            effect="the spot's centroid scatters with photon and read noise",
            remedy=centroid_remedy,
            basis=(
                f"the frames' Cramér-Rao bound along {names[axis]}, median "
                f"{scatter.bound_um[axis]:.3g} µm, x {COVERAGE:g}"
            ),
            detail=detail,
        ),
    ]


def camera_drift_source(drift: Drift | None, why_not: str = "") -> Source:
    """4.8: the camera's own warm-up moves the chip under a fixed spot."""
    remedy = "warm the camera up first (30 min); fins, a rubber gasket, insulation (4.8.1)"
    effect = "the camera's warm-up moves its mount, and the chip under the spot"
    if drift is None:
        return Source(
            "camera-drift", "Thermal drift of the camera", "4.8", "not quantified", None,
            effect, remedy, why_not or "no recording on a fixed target",
        )  # fmt: skip
    tau = f", τ {drift.tau_s:.0f} s" if drift.tau_s is not None and drift.resolved else ""
    limit = COVERAGE * drift.change_se_um
    seen = (
        f"change {drift.change_um:+.3g} ± {drift.change_se_um:.2g} µm "
        f"({'first-order fit' if drift.how == 'fit' else 'ends'}{tau})"
    )
    if not drift.resolved:
        seen = (
            f"no drift resolved ({seen}): the recording's limit, {COVERAGE:g} x its standard error"
        )
    return Source(
        key="camera-drift",
        name="Thermal drift of the camera",
        section="4.8",
        evidence="measured",
        delta_l_um=abs(drift.change_um) if drift.resolved else limit,
        effect=effect,
        remedy=remedy,
        basis=(
            f"{drift.frames} frames of a fixed target over {drift.duration_s:.0f} s: {seen}, "
            f"scatter {drift.residual_std_um:.3g} µm"
        ),
        detail={
            "change_um": drift.change_um,
            "change_se_um": drift.change_se_um,
            "resolved": str(drift.resolved).lower(),
            "tau_s": drift.tau_s,
            "residual_std_um": drift.residual_std_um,
            "how": drift.how,
        },
    )


def ir_source(
    alpha_per_k: float, length_mm: float, noise_c: float, pixels: int, used_by: str
) -> Source:
    """The IR's noise through Eq. 2.3: a region's mean temperature carries ``σ / sqrt(n)``;
    a deformation computed from it, ``α L T``, carries ``α L σ / sqrt(n)``."""
    sigma_mean = noise_c / math.sqrt(max(pixels, 1))
    value = COVERAGE * alpha_per_k * length_mm * MM * sigma_mean * UM_PER_M
    return Source(
        key="ir",
        name="IR temperature noise",
        section="4.9",
        evidence="model",
        delta_l_um=value,
        effect=f"noise of the measured temperatures ({used_by})",
        remedy="larger IR regions; average readings",
        basis=(
            f"pixel noise {noise_c:g} °C over {pixels} px: {sigma_mean:.3g} °C per region "
            f"mean, x α {alpha_per_k * 1e6:.3g}e-6/K x {length_mm:.4g} mm x {COVERAGE:g}"
        ),
        detail={"region_sigma_c": sigma_mean, "pixels": pixels},
    )
