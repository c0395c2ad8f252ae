"""The device sections: ``[camera]``, ``[ir]`` (with its regions) and ``[robot]``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal, Self

from pydantic import Field, StrictBool, field_validator, model_validator

from config.section import (
    MAX_FRAME_PX,
    MAX_TIMEOUT_S,
    SUPPORTED_BAUDRATES,
    NonNegativeFloat,
    PositiveFloat,
    Section,
)


class CameraSettings(Section):
    """The camera that watches the laser spot (thesis 3.2.3)."""

    driver: Literal["sim", "opencv", "genicam", "replay"] = Field(
        "sim",
        description="sim: the bench's camera; opencv: VideoCapture; genicam: a GigE Vision / "
        "USB3 Vision camera through pypylon (the genicam extra); replay: a folder.",
    )
    device: int | str = Field(0, description="OpenCV device index, path or URL.")
    serial: str | None = Field(
        None, description="GenICam: serial number of the camera; none: any (see user_id)."
    )
    user_id: str | None = Field(
        None, description="GenICam: the camera's DeviceUserID; none: any (the first found)."
    )
    feature_file: Path | None = Field(
        None,
        description="GenICam: a pylon feature file (.pfs, as pylon Viewer saves it) loaded "
        "after each open, before the settings here (which win); none: none.",
    )
    pixel_format: Literal["Mono8", "Mono12", "Mono16"] | None = Field(
        None, description="GenICam PixelFormat; none: Mono<bit_depth>. Must match bit_depth."
    )
    exposure_us: PositiveFloat | None = Field(
        None,
        description="Exposure time (us); none: leave the camera's. OpenCV sends it as "
        "CAP_PROP_EXPOSURE in V4L2's unit of 100 us, with auto exposure off.",
    )
    gain: float | None = Field(
        None,
        description="Gain; none: leave the camera's. GenICam: Gain in dB (SFNC); OpenCV: "
        "CAP_PROP_GAIN in the backend's own unit.",
    )
    offset_x_px: Annotated[int, Field(ge=0)] = Field(
        0, description="GenICam: ROI's left column on the sensor (px); size is width_px."
    )
    offset_y_px: Annotated[int, Field(ge=0)] = Field(
        0, description="GenICam: ROI's top row on the sensor (px); size is height_px."
    )
    trigger: Literal["software", "hardware", "off"] = Field(
        "software",
        description="GenICam: software: each grab triggers one exposure (fresh frame, known "
        "exposure time); hardware: wait for trigger_source; off: free run, newest frame.",
    )
    trigger_source: str = Field("Line1", description="GenICam: TriggerSource of hardware.")
    reconnect_max_backoff_s: PositiveFloat = Field(
        30.0, description="GenICam: longest wait between two reconnection attempts (s)."
    )
    replay_dir: Path | None = Field(None, description="Folder of frames for the replay driver.")
    replay_period_s: PositiveFloat | None = Field(
        None,
        description="Replay time base: frame i belongs to i x period on the run clock and grab() "
        "returns the frame of now; none: each grab() returns the next frame.",
    )
    replay_loop: StrictBool = Field(False, description="Replay: start again after the last frame.")
    width_px: Annotated[int, Field(gt=0, le=MAX_FRAME_PX)] = Field(
        752, description="Frame width requested (px)."
    )
    height_px: Annotated[int, Field(gt=0, le=MAX_FRAME_PX)] = Field(
        582, description="Frame height requested (px)."
    )
    bit_depth: Literal[8, 12, 16] = Field(16, description="Bits per pixel of the frames.")
    pixel_pitch_um: tuple[PositiveFloat, PositiveFloat] = Field(
        (8.6, 8.3), description="Physical pixel pitch (x, y) of the chip (um)."
    )
    um_per_px: tuple[PositiveFloat, PositiveFloat] = Field(
        (8.6, 8.3),
        description="Calibrated micrometres per pixel (x, y). The default is the bench's: its "
        "spot falls on the bare chip, so calibration = pixel pitch. The thesis's optics "
        "measured 10.22, 9.72 (lab.toml).",
    )
    gain_e_per_count: PositiveFloat | None = Field(
        None,
        description="Electrons per count of the sensor, for the centroid's noise model (its "
        "1-sigma and, on 8-bit or saturated frames, its fit's weights). none: the camera's "
        "where it reports one, else measured on each frame by photon transfer "
        "(docs/explanation/measurement-noise.md); set it only from an EMVA 1288 figure or "
        "a photon-transfer series at the camera's gain and pixel format.",
    )
    read_noise_e: NonNegativeFloat = Field(
        5.0,
        description="Read noise (electrons RMS), for the centroid's noise model when the gain "
        "is known (set or the camera's); a measured one takes the background's own noise.",
    )
    centroid_method: Literal["robust", "thesis"] = Field(
        "robust", description="robust: background-subtracted, re-centred; thesis: its replica."
    )
    centroid_low: NonNegativeFloat = Field(
        0.8,
        description="Thesis method: low threshold, fraction of full scale (<= 1) or counts "
        "(> 1); darker pixels count as 0 (A.1 used 80 %).",
    )
    centroid_high: NonNegativeFloat | None = Field(
        None,
        description="Thesis method: high threshold (fraction or counts); brighter pixels "
        "count as white; none: off.",
    )
    centroid_box: Annotated[int, Field(gt=0, le=MAX_FRAME_PX)] = Field(
        400, description="Thesis method: half-size (px) of the box around the brightest pixels."
    )
    centroid_binary: StrictBool = Field(
        False, description="Thesis method: pixels at or above the low threshold count as white."
    )
    max_age_s: PositiveFloat = Field(
        2.0, description="A frame older than this (s) is stale and flagged, never used silently."
    )
    grab_timeout_s: PositiveFloat = Field(
        2.0,
        description="Longest wait for one frame (s, wall time like robot.command_timeout_s): "
        "then the step is flagged camera-error and the run goes on or pauses "
        "(scheduler.sensor_error_policy).",
    )
    rotation_deg: float = Field(
        0.0,
        description="Rotation of the image from the robot's world x / -z axes (degrees; "
        "positive turns world +x towards image +y), from `thermocomp calibrate camera`.",
    )
    calibration_size_mm: PositiveFloat = Field(
        0.5,
        description="`calibrate camera`: half-width of the square pattern of offsets (mm); "
        "its corners must lie within compensation.max_total_offset_mm.",
    )
    calibration_step_mm: PositiveFloat = Field(
        0.25, description="`calibrate camera`: spacing of the pattern's offsets (mm)."
    )

    @model_validator(mode="after")
    def _format_matches_depth(self) -> CameraSettings:
        if self.pixel_format is not None and self.pixel_format != f"Mono{self.bit_depth}":
            raise ValueError(
                f"pixel_format {self.pixel_format} delivers {self.pixel_format[4:]}-bit pixels "
                f"but bit_depth is {self.bit_depth}"
            )
        return self


class IrRegion(Section):
    """A rectangle of the thermal image whose mean/max temperature is reported."""

    name: str
    x: Annotated[int, Field(ge=0, le=MAX_FRAME_PX)]
    y: Annotated[int, Field(ge=0, le=MAX_FRAME_PX)]
    width: Annotated[int, Field(gt=0, le=MAX_FRAME_PX)]
    height: Annotated[int, Field(gt=0, le=MAX_FRAME_PX)]
    node: str | None = Field(None, description="Model node this region measures, if any.")


class IrSettings(Section):
    """The infrared camera that reads the link temperatures."""

    driver: Literal["sim", "opencv", "genicam-radiometric", "replay"] = Field(
        "sim",
        description="sim: the bench's IR reader; opencv: radiometric Y16; genicam-radiometric: "
        "a FLIR A-series / Ax5 over GigE Vision (pypylon, the genicam extra); replay: a folder.",
    )
    device: int | str = Field(1, description="OpenCV device index, path or URL.")
    serial: str | None = Field(
        None, description="GenICam: serial number of the IR camera; none: any (see user_id)."
    )
    user_id: str | None = Field(
        None, description="GenICam: the IR camera's DeviceUserID; none: any (the first found)."
    )
    conversion: Literal["planck", "linear"] = Field(
        "planck",
        description="genicam-radiometric: planck: raw counts S to kelvin with the camera's "
        "R, B, F, O (T = B / ln(R / (S - O) + F)); linear: the camera streams temperature "
        "(TemperatureLinearMode), kelvin = counts x linear_resolution_k.",
    )
    linear_resolution_k: PositiveFloat = Field(
        0.04,
        description="Linear mode: kelvin per count (FLIR Ax5: 0.04 high / 0.4 low resolution; "
        "A50/A70/A400: 0.01 / 0.1).",
    )
    emissivity: Annotated[float, Field(gt=0, le=1)] = Field(
        1.0, description="Planck mode: emissivity of the link's surface."
    )
    reflected_temp_c: float = Field(
        22.0, description="Planck mode: reflected apparent temperature (degC)."
    )
    atmospheric_transmission: Annotated[float, Field(gt=0, le=1)] = Field(
        1.0, description="Planck mode: transmission of the air between link and camera."
    )
    atmospheric_temp_c: float = Field(22.0, description="Planck mode: air temperature (degC).")
    window_transmission: Annotated[float, Field(gt=0, le=1)] = Field(
        1.0, description="Planck mode: transmission of an IR window in front of the lens."
    )
    window_temp_c: float = Field(22.0, description="Planck mode: the window's temperature (degC).")
    reconnect_max_backoff_s: PositiveFloat = Field(
        30.0, description="GenICam: longest wait between two reconnection attempts (s)."
    )
    replay_dir: Path | None = Field(None, description="Folder of thermal frames to replay.")
    replay_period_s: PositiveFloat | None = Field(
        None,
        description="Replay time base: frame i belongs to i x period on the run clock; none: "
        "each read() returns the next frame.",
    )
    replay_loop: StrictBool = Field(False, description="Replay: start again after the last frame.")
    counts_to_celsius: tuple[float, float] = Field(
        (0.01, -273.15),
        description="Linear calibration (scale, offset): T = scale * counts + offset; the "
        "default reads centi-kelvin counts (FLIR Lepton radiometric Y16).",
    )
    noise_c: NonNegativeFloat = Field(
        0.08,
        description="1-sigma pixel noise (degC) as the controller believes it (the observer's "
        "R); the sim's truth uses bench.ir_noise_c (none: this).",
    )
    offset_c: Annotated[float, Field(ge=-50, le=50)] = Field(
        0.5,
        description="Sim truth: the IR camera's fixed offset within its +-2 degC accuracy "
        "(the controller learns it: observer, identification).",
    )
    regions: tuple[IrRegion, ...] = Field(
        (),
        description="Regions of interest: [[ir.regions]] tables (name, x, y, width, height, node).",
    )
    max_age_s: PositiveFloat = Field(
        5.0, description="A reading older than this (s) is stale and flagged, never fused."
    )
    read_timeout_s: PositiveFloat = Field(
        2.0,
        description="Longest wait for one reading (s, wall time like robot.command_timeout_s): "
        "then the step is flagged ir-error and the run goes on or pauses "
        "(scheduler.sensor_error_policy).",
    )


class RobotSettings(Section):
    """The robot: the CRS C500C controller's serial console (docs/reference/c500c-console.md), or a
    Universal Robots e-Series over RTDE (``driver = "ur-rtde"``, issue 31: the settings from
    ``host`` to ``ur_timeout_s``)."""

    driver: Literal["sim", "c500c", "c500c-server", "ur-rtde"] = Field(
        "sim",
        description="sim: the C500C emulator on a pseudo-terminal; c500c: a real port; "
        "c500c-server: the fast path, controller/thermocomp_server.r3 on the controller's second "
        "port (robot.server_port; on the simulated bench, bench.enabled, its emulator on a pty); "
        "ur-rtde: a UR e-Series over RTDE running controller/ur/thermocomp_offset.script "
        "(robot.host; docs/how-to/universal-robots.md).",
    )
    port: str = Field("/dev/ttyS0", description="Serial device of the controller's console.")
    baudrate: int = Field(57600, description="Console baud rate (the C500C default is 57600).")
    bytesize: Literal[7, 8] = Field(8, description="Data bits.")
    parity: Literal["N", "E", "O"] = Field("N", description="Parity: none, even, odd.")
    stopbits: Literal[1, 2] = Field(1, description="Stop bits.")
    flow_control: Literal["none", "rtscts"] = Field(
        "none",
        description="Hardware flow control of the console port (docs/reference/c500c-console.md: "
        "RTS/CTS may not work on the console; the controller's own 115200-baud programs use it).",
    )
    command_timeout_s: Annotated[float, Field(gt=0, le=MAX_TIMEOUT_S)] = Field(
        5.0, description="Timeout of one console command."
    )
    move_timeout_s: Annotated[float, Field(gt=0, le=MAX_TIMEOUT_S)] = Field(
        60.0,
        description="Longest timeout of a move and its finish (s): each move's own timeout "
        "follows from its distance and speed (robot.move_margin_s, robot.min_speed_mm_s), "
        "capped here; a move of unknown length waits this long.",
    )
    move_margin_s: Annotated[float, Field(gt=0, le=MAX_TIMEOUT_S)] = Field(
        3.0,
        description="A move's timeout beyond its motion (s): settling, the controller's own "
        "overhead and the replies on the wire. A compensating step of micrometres gets this.",
    )
    min_speed_mm_s: Annotated[float, Field(gt=0, le=10_000)] = Field(
        20.0,
        description="Slowest tool speed of a move at 100 % speed (mm/s), scaled by the move's "
        "speed percent (a move of unknown speed: 10 %): a move longer than its distance at "
        "this speed plus robot.move_margin_s is a stall (issue 26).",
    )
    min_rotation_deg_s: Annotated[float, Field(gt=0, le=10_000)] = Field(
        10.0,
        description="Slowest tool rotation of a move at 100 % speed (deg/s), as min_speed_mm_s.",
    )
    online: StrictBool = Field(True, description="Use straight-line moves (needs `online on`).")
    application: str = Field("ash", description="Name of the ash application (prompt).")
    reconnect_max_backoff_s: PositiveFloat = Field(
        30.0, description="Longest wait between two reconnection attempts (s)."
    )
    point_of_control_timeout_s: PositiveFloat = Field(
        120.0,
        description="How long a motion command may wait for the operator to press PAUSE/CONTINUE "
        "on the controller (s); then the move fails and motion is held.",
    )
    readback_every: int = Field(
        1,
        ge=1,
        le=1000,
        description="Read the actual pose back (`w2`, ~60 % of a console step's bytes) every N-th "
        "move; a move without read-back records no pose.",
    )
    emulator_paced: StrictBool = Field(
        False, description="Sim: pace the emulator at the baud rate (real link timings)."
    )
    emulator_move_ms: NonNegativeFloat = Field(5.0, description="Sim: time one move takes (ms).")
    server_port: str = Field(
        "/dev/ttyS1",
        description="c500c-server: serial device wired to the controller's second port (sio1).",
    )
    server_baudrate: int = Field(
        115200, description="c500c-server: baud rate of the program's port (the program's 115200)."
    )
    heartbeat_s: PositiveFloat = Field(
        0.25,
        description="c500c-server: a heartbeat is sent when nothing was sent for this long (s); "
        "at most half of server_silence_s.",
    )
    server_silence_s: PositiveFloat = Field(
        1.0,
        description="c500c-server: the program halts and holds after this long without a frame "
        "(s); the emulator uses it, on the controller it is SILENCE_MS in the program.",
    )

    host: str = Field(
        "127.0.0.1",
        description="ur-rtde: the controller's address (the emulator's: 127.0.0.1).",
        min_length=1,
        max_length=253,
    )
    rtde_port: Annotated[int, Field(ge=1, le=65535)] = Field(
        30004, description="ur-rtde: RTDE port (UR's fixed 30004)."
    )
    dashboard_port: Annotated[int, Field(ge=1, le=65535)] = Field(
        29999, description="ur-rtde: Dashboard Server port (UR's fixed 29999)."
    )
    pause_program_on_hold: bool = Field(
        True,
        description="ur-rtde: a hold of a followed run (pause, stop, fault, shutdown) also "
        "pauses the robot's program through the Dashboard Server, after the correction froze; "
        "the run's resume plays again a program this pause paused (a Dashboard failure is "
        "logged and listed in the errors, the hold stands). false: a hold freezes the "
        "correction only and the program keeps playing.",
    )
    rtde_frequency_hz: Annotated[float, Field(gt=0, le=500)] = Field(
        125.0,
        description="ur-rtde: rate of the robot's state packages (Hz; at most the e-Series' "
        "500 Hz controller cycle).",
    )
    register_base: Annotated[int, Field(ge=24, le=41)] = Field(
        24,
        description="ur-rtde: first of the RTDE registers the driver and the robot-side program "
        "share (drivers/ur/registers.py); the upper range 24-41, since 0-23 collide with the "
        "fieldbus adapters. Must equal REG_BASE in the program.",
    )
    correction_limit_mm: Annotated[float, Field(gt=0, le=2.0)] = Field(
        1.0,
        description="ur-rtde: a correction longer than this (mm) is refused before any byte "
        "(the program refuses beyond its own 2 mm, MAX_OFFSET_M).",
    )
    correction_limit_rad: Annotated[float, Field(gt=0, le=0.002)] = Field(
        0.001,
        description="ur-rtde: a correction's rotation larger than this (rad) is refused before "
        "any byte (the program: 2 mrad, MAX_ROTATION_RAD).",
    )
    ur_heartbeat_s: Annotated[float, Field(gt=0, le=0.2)] = Field(
        0.1,
        description="ur-rtde: the registers are written at least this often (s), so the "
        "program's 0.5 s watchdog (WATCHDOG_S) never fires while the daemon runs.",
    )
    ur_timeout_s: Annotated[float, Field(gt=0, le=MAX_TIMEOUT_S)] = Field(
        1.0,
        description="ur-rtde: no state package for this long (s), or a control reply later "
        "than this, is a link fault: the correction is held and the link reconnects.",
    )

    @field_validator("baudrate", "server_baudrate")
    @classmethod
    def _known_baudrate(cls, value: int) -> int:
        if value not in SUPPORTED_BAUDRATES:
            raise ValueError("must be one of " + ", ".join(map(str, SUPPORTED_BAUDRATES)))
        return value

    @model_validator(mode="after")
    def _heartbeat_within_silence(self) -> Self:
        # Two heartbeats per silence period: one late heartbeat must not halt the robot.
        if self.heartbeat_s * 2 > self.server_silence_s:
            raise ValueError("heartbeat_s must be at most half of server_silence_s")
        return self
