"""The ``[arm]`` section (issue 20): the whole arm, its duty cycle, cameras and limits."""

from __future__ import annotations

from typing import Annotated, Literal, Self

from pydantic import Field, StrictBool, model_validator

from config.device_settings import CameraSettings
from config.section import Section

#: Markers on the tool (issue 20): at most this many, each a point in the tool frame (mm).
MAX_MARKERS = 32
#: Frames averaged per tool measurement at most: 64 frames of 5 MP cameras are seconds.
MAX_FRAMES_PER_MEASUREMENT = 64
#: Arm-run correction limits admit at most this much (a correction is a few tenths of a mm).
MAX_ARM_TRANSLATION_MM = 100.0
MAX_ARM_ROTATION_DEG = 10.0
MAX_ARM_CAMERAS = 16


class ArmSettings(Section):
    """The whole arm (issue 20): a run that names a duty cycle corrects the tool in 6-DOF at
    its measured poses. Disabled (the default), thermocomp is the two-link bench."""

    enabled: StrictBool = Field(
        False, description="Arm runs allowed and, on the bench, the arm bench's devices."
    )
    arm_file: str = Field(
        "crs-a465", description="Arm description: preset name in config/arms or a file path."
    )
    duty_cycle: str | None = Field(
        None, description="Default duty cycle file of arm runs (a run may name its own)."
    )
    cameras_file: str | None = Field(
        None, description="Camera models (intrinsics, distortion, pose) TOML; none: the bench's."
    )
    cameras: Annotated[int, Field(ge=1, le=MAX_ARM_CAMERAS)] = Field(
        3,
        description="Arm bench: cameras at each measured pose (simulated; their models "
        "are the bench's unless arm.cameras_file is set).",
    )
    bench_cameras: StrictBool = Field(
        False,
        description="The UR bench (robot.driver ur-rtde, bench.enabled): simulated tool "
        "cameras, arm.cameras at each measured pose of the program, watching the emulator's true "
        "tool (the A465's arm bench always has them); false: no camera (a followed run by the "
        "model and the joint temperatures).",
    )
    camera_devices: Annotated[tuple[CameraSettings, ...], Field(max_length=MAX_ARM_CAMERAS)] = (
        Field(
            (),
            description="On hardware: the real cameras watching the tool, in the order of "
            "arm.cameras_file's cameras; each a camera section (driver opencv, genicam or "
            'replay, e.g. {driver = "genicam", serial = "..."}).',
        )
    )
    markers_mm: Annotated[
        tuple[tuple[float, float, float], ...], Field(min_length=1, max_length=MAX_MARKERS)
    ] = Field(
        ((60.0, 0.0, 0.0), (0.0, 60.0, 0.0), (-60.0, 0.0, 15.0), (0.0, -60.0, 30.0)),
        description="Markers on the tool, tool frame (mm); >= 3 not in a line give the "
        "orientation (default: a 120 mm cross, two raised).",
    )
    measured_poses: Annotated[tuple[str, ...], Field(max_length=100)] = Field(
        (), description="Duty-cycle poses measured and corrected; empty: those it marks measured."
    )
    frames_per_measurement: Annotated[int, Field(ge=1, le=MAX_FRAMES_PER_MEASUREMENT)] = Field(
        1,
        description="Frames grabbed from every camera per tool measurement; each marker's "
        "centroid is their mean (its noise, and the pose's, divided by sqrt(frames)).",
    )
    reference_frames: Annotated[int, Field(ge=1, le=MAX_FRAMES_PER_MEASUREMENT)] | None = Field(
        None,
        description="Frames of each pose's reference (its zero, measured once before the first "
        "step): its error is in every later drift of that pose, and the meter measures its "
        "cameras' scatter on them; none: arm.frames_per_measurement; at least 4.",
    )
    max_translation_mm: Annotated[float, Field(gt=0, le=MAX_ARM_TRANSLATION_MM)] = Field(
        2.0, description="Largest translation of a pose's correction (mm)."
    )
    max_rotation_deg: Annotated[float, Field(gt=0, le=MAX_ARM_ROTATION_DEG)] = Field(
        0.2, description="Largest rotation of a pose's correction (deg)."
    )
    max_step_translation_mm: Annotated[float, Field(gt=0, le=MAX_ARM_TRANSLATION_MM)] = Field(
        0.5, description="Largest change of a pose's translation between its corrections (mm)."
    )
    max_step_rotation_deg: Annotated[float, Field(gt=0, le=MAX_ARM_ROTATION_DEG)] = Field(
        0.05, description="Largest change of a pose's rotation between its corrections (deg)."
    )
    calibration_max_translation_mm: Annotated[
        float | None, Field(gt=0, le=MAX_ARM_TRANSLATION_MM)
    ] = Field(
        None,
        description="`calibrate cameras --robot`: farthest the pattern may move the tool from "
        "its goal (mm); none: arm.max_translation_mm.",
    )
    calibration_max_rotation_deg: Annotated[float | None, Field(gt=0, le=MAX_ARM_ROTATION_DEG)] = (
        Field(
            None,
            description="`calibrate cameras --robot`: largest turn of the tool from its goal "
            "(deg); none: arm.max_rotation_deg.",
        )
    )
    motion_dt_s: Annotated[float, Field(gt=0, le=10)] = Field(
        0.05, description="Time step of the duty cycle's motion samples for motor heat (s)."
    )
    heat_from: Literal["measured", "duty-cycle"] = Field(
        "measured",
        description="A followed run (robot.driver ur-rtde): the motor heat of the motion the "
        "robot actually made (every RTDE package's joints, speeds, accelerations: paused or "
        "slowed programs heat the model as they heat the arm), or of the taught duty cycle "
        "played without pauses (the arm run's, issue 20). Recorded per step for `calibrate "
        "model`. Other run kinds play the duty cycle themselves: its heat.",
    )
    bending: StrictBool = Field(
        False, description="Links bend from a temperature gradient across them."
    )
    motor_side_share: Annotated[float, Field(ge=0, le=1)] = Field(
        0.5,
        description="With arm.bending: share of each joint's flange conductance on the link's "
        "motor-housing side (the arm's design; 0.5: symmetric, no gradient across a link).",
    )
    adapt: StrictBool | None = Field(
        None,
        description="Estimate each joint's heat, alpha, convection and (arm.bending) the bending "
        "share online from the measured tool and the IR regions, from the preset's or the arm "
        "model's values (daemon/arm/adaptation.py); the compensation uses the adapted links. "
        "none (the default): on when the run's arm model was calibrated on another duty cycle "
        "and is not fully calibrated (it says what holds only for its cycle), else off. A "
        "followed run does not adapt.",
    )
    play_duty_cycle: StrictBool | None = Field(
        None,
        description="The robot plays the whole duty cycle (every pose at its speed, its dwell) "
        "for the whole arm run, the measured poses measured in passing; needs time_scale 1 and "
        "the console driver. false: it moves to the measured poses only (the accelerated "
        "bench). none: played with robot.driver c500c, not on the bench or the fast path.",
    )

    @model_validator(mode="after")
    def _camera_devices_need_models(self) -> Self:
        # the 3-D measurement needs each real camera's calibrated model (intrinsics, pose):
        # they come from the camera file, matched by position (docs/explanation/measurement.md)
        if self.camera_devices and self.cameras_file is None:
            raise ValueError(
                "arm.camera_devices needs arm.cameras_file (the cameras' models, from "
                "`thermocomp calibrate cameras`)"
            )
        simulated = [i for i, cam in enumerate(self.camera_devices) if cam.driver == "sim"]
        if simulated:
            raise ValueError(
                f"arm.camera_devices[{simulated[0]}]: driver 'sim' is the two-link bench's "
                "camera; the arm bench simulates its own (arm.cameras)"
            )
        return self
