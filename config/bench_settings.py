"""The ``[bench]`` section: the simulated bench's truth and its clock
(docs/explanation/simulated-benches.md, "The two-link bench: truth and beliefs")."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, StrictBool, field_validator

from config.arm_truth import ArmTruthError, load_arm_truth
from config.faults import parse_sensor_faults
from config.section import MAX_DURATION_S, MAX_HEAT_W, NonNegativeFloat, PositiveFloat, Section


class BenchSettings(Section):
    """The simulated bench and the clock every component shares."""

    enabled: StrictBool = Field(True, description="Use the simulated bench instead of hardware.")
    clock: Literal["real", "accelerated", "virtual"] = Field(
        "virtual",
        description="real: wall time; accelerated: wall time x time_factor; virtual: jump to "
        "the next deadline (an hour in seconds).",
    )
    emulator: Literal["inline", "process"] = Field(
        "inline",
        description="Where the emulated C500C controller runs (robot.driver sim or "
        "c500c-server): inline in the daemon's process (tests' virtual clocks), or process: "
        "its own process at the control loop's real-time priority, like the real controller "
        "(timing measurements; needs clock real).",
    )
    time_factor: Annotated[float, Field(gt=0, le=1e6)] = Field(
        100.0, description="Speed-up of the accelerated clock (bench seconds per wall second)."
    )
    seed: Annotated[int, Field(ge=0, le=2**63 - 1)] = Field(
        1, description="Seed of every random part of the bench."
    )
    noise_seed: Annotated[int, Field(ge=0, le=2**63 - 1)] | None = Field(
        None,
        description="Arm bench: seed of the measurement noise only (none: bench.seed), so "
        "one arm can be measured twice (a calibration run, then a run).",
    )
    heater_power_w: Annotated[float, Field(ge=0, le=MAX_HEAT_W)] = Field(
        0.5,
        description="Truth: power of each heater pad on the bench (W); the controller "
        "believes model.heater_power_w (or the network's heat).",
    )
    heater_off_s: NonNegativeFloat | None = Field(
        None,
        description="Run time at which the procedure switches the heaters off (s), the "
        "default of a run's heater_off_s; none: stay on.",
    )
    heater_on_delay_s: Annotated[float, Field(ge=0, le=MAX_DURATION_S)] = Field(
        0.0,
        description="Truth: the pads really heat this long after the run starts (s); the "
        "controller believes they start with the run. 0: they do.",
    )
    heater_off_delay_s: Annotated[float, Field(ge=-MAX_DURATION_S, le=MAX_DURATION_S)] = Field(
        0.0,
        description="Truth: the pads really stop this long after the run's heater_off_s "
        "(s; negative: before it). 0: when the controller believes.",
    )
    ambient_c: Annotated[float, Field(ge=-60, le=150)] | None = Field(
        None,
        description="Truth: the room's temperature at bench time 0 (degC); none: "
        "model.ambient_c (the controller's belief is then right at the start).",
    )
    ambient_drift_c_per_h: Annotated[float, Field(ge=-20, le=20)] = Field(
        0.0, description="Truth: linear drift of the room's temperature (degC per hour); 0: none."
    )
    ambient_swing_c: Annotated[float, Field(ge=0, le=20)] = Field(
        0.0,
        description="Truth: amplitude of a sinusoidal swing of the room's temperature (degC), "
        "zero at bench time 0; 0: none.",
    )
    ambient_swing_period_h: Annotated[float, Field(gt=0, le=1000)] = Field(
        24.0, description="Truth: period of the room's temperature swing (hours)."
    )
    ir_noise_c: NonNegativeFloat | None = Field(
        None,
        description="Truth: 1-sigma pixel noise of the sim IR camera (degC); none: ir.noise_c "
        "(the controller's belief is then right).",
    )
    direction: tuple[float, float, float] | None = Field(
        None,
        description="Truth: the link's axis in world coordinates; none: model.direction.",
    )
    truth_network: str = Field(
        "thesis-two-link-geometry",
        description="The bench's physical truth: thesis-two-link-geometry (the thesis geometry "
        "at truth_node_spacing_mm, finer than any preset), or a network preset name or file "
        "(thesis-two-link: truth equal to the controller's Table 5.1 model).",
    )
    truth_heat_scale: PositiveFloat = Field(
        1.0, description="Truth heat input / model heat input (1 = model is right)."
    )
    truth_convection_scale: PositiveFloat = Field(
        1.0, description="Truth convection / model convection (1 = model is right)."
    )
    stand_drift_um: Annotated[float, Field(ge=-1000, le=1000)] = Field(
        2.0,
        description="Camera-stand warm-up drift amplitude (um), thesis 4.8 (1.90-2.05 um); "
        "the centre of the seed's draw (stand_drift_spread); 0 = off.",
    )
    stand_drift_tau_s: PositiveFloat = Field(
        600.0,
        description="Time constant of the camera-stand drift (s): settled within ~30 min "
        "(3 tau), thesis 4.8; the centre of the seed's draw.",
    )
    stand_drift_spread: Annotated[float, Field(ge=0, le=0.9)] = Field(
        0.25,
        description="The stand drift's amplitude and time constant are drawn from bench.seed "
        "uniformly within +-this fraction of stand_drift_um / stand_drift_tau_s, so that runs "
        "of different seeds do not repeat one drift; 0: exactly those (seed 1: 1.61 um, 706 s).",
    )
    robot_noise_um: NonNegativeFloat = Field(
        0.9,
        description="1-sigma positioning error of the emulated robot (um); 0.9 reproduces the "
        "thesis's absolute-command S_x (Table 6.1).",
    )
    truth_node_spacing_mm: PositiveFloat = Field(
        2.0,
        description="Node spacing of the bench's truth network built from the thesis geometry "
        "(mm), finer than the controller's model.",
    )
    moving_convection_scale: PositiveFloat = Field(
        2.0,
        description="Moving case (scheduler.procedure = moving): convection on the wiping "
        "link / at rest (thesis 3.2.4; assumed, the thesis gives no h).",
    )
    spot_sigma_px: PositiveFloat = Field(
        3.0, description="1-sigma radius of the simulated laser spot on the chip (px)."
    )
    spot_peak_fraction: PositiveFloat = Field(
        0.5, description="Peak of the simulated spot as a fraction of full scale (> 1 saturates)."
    )
    camera_faults: str = Field(
        "",
        description="Sim camera faults, KIND[=SECONDS][@N|%P],... (as the emulator's): "
        "no-frame (the grab never returns), late=S (delivered S after its exposure), "
        "unreadable (a frame the driver refuses); @N: the N-th grab since the camera opened "
        "(the run's reference frame is one), %P: per grab with probability P (seeded); "
        "'': none.",
    )
    ir_faults: str = Field(
        "",
        description="Sim IR reader faults, as camera_faults: no-frame, late=S (a reading "
        "exposed S before it is read, with no wait: the IR is read while the next steps "
        "move), unreadable (a thermal frame that is not finite); @N: the N-th read since it "
        "opened.",
    )

    camera_gain_e_per_count: PositiveFloat = Field(
        1.0, description="Truth: electrons per count of the sim camera's sensor."
    )
    camera_reports_gain: StrictBool = Field(
        True,
        description="The sim camera reports its gain with each frame (a camera that knows "
        "its sensor); false: it does not, as a GenICam camera, and the centroid measures it.",
    )
    camera_rotation_deg: float = Field(
        0.0,
        description="Sim camera: rotation of the image from the robot's world x / -z axes "
        "(degrees; positive turns world +x towards image +y, i.e. down the rows), for "
        "`calibrate camera`.",
    )
    camera_scale: PositiveFloat = Field(
        1.0,
        description="Sim camera: optical magnification (chip um per um at the spot): the true "
        "calibration is pixel_pitch_um / camera_scale.",
    )

    arm_truth: str | None = Field(
        None,
        max_length=4096,
        description="Arm bench: the truth of the simulated arm, a preset in config/truths "
        "(e.g. hot-motors) or a TOML file (docs/explanation/bench-truth.md); none: the "
        "default truth. The two-link bench's truth settings do not apply to the arm bench.",
    )

    @field_validator("arm_truth")
    @classmethod
    def _valid_arm_truth(cls, value: str | None) -> str | None:
        if value is not None:
            try:
                load_arm_truth(value)
            except ArmTruthError as err:
                raise ValueError(str(err)) from err
        return value

    @field_validator("camera_faults", "ir_faults")
    @classmethod
    def _valid_fault_spec(cls, value: str) -> str:
        parse_sensor_faults(value)  # ValueError names the bad item
        return value


#: The two-link bench's truth: none of it reaches the arm bench, whose truth is bench.arm_truth
#: (a setting given here on an arm config would be silently ignored: it is refused instead).
TWO_LINK_TRUTH_SETTINGS = (
    "heater_power_w",
    "heater_on_delay_s",
    "heater_off_delay_s",
    "ambient_c",
    "ambient_drift_c_per_h",
    "ambient_swing_c",
    "ambient_swing_period_h",
    "ir_noise_c",
    "direction",
    "truth_network",
    "truth_heat_scale",
    "truth_convection_scale",
    "stand_drift_um",
    "stand_drift_tau_s",
    "stand_drift_spread",
    "truth_node_spacing_mm",
    "moving_convection_scale",
    "spot_sigma_px",
    "spot_peak_fraction",
    "camera_faults",
    "ir_faults",
    "camera_rotation_deg",
    "camera_scale",
)


def two_link_settings_given(bench: BenchSettings) -> list[str]:
    """The two-link bench's truth settings that differ from their defaults."""
    fields = BenchSettings.model_fields
    return [
        name
        for name in TWO_LINK_TRUTH_SETTINGS
        if getattr(bench, name) != fields[name].get_default(call_default_factory=True)
    ]
