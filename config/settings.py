"""The settings tree of thermocomp: one pydantic model, loaded once in the entry point.

A settings object is built by :func:`load_settings` from a TOML file and
``THERMOCOMP_<SECTION>__<FIELD>`` environment variables (environment wins), and is then
passed down explicitly. There is deliberately no module-level settings instance.

Every section forbids unknown keys, so a typo in a TOML file is an error that names the
key instead of a silently ignored setting.
"""

from __future__ import annotations

import json
import os
import tomllib
from collections.abc import Mapping
from pathlib import Path
from types import UnionType
from typing import Annotated, Any, Literal, Self, Union, get_args, get_origin

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from config.faults import parse_sensor_faults

ENV_PREFIX = "THERMOCOMP_"
ENV_NESTING = "__"

#: Largest settings or network file read (bytes): the biggest preset is a few KiB, so anything
#: this large is the wrong file, refused before it is parsed.
MAX_TOML_BYTES = 4 * 1024 * 1024

#: Baud rates the C500C's `siocfg` and the host serial ports both offer (C500C.md).
SUPPORTED_BAUDRATES = (9600, 19200, 38400, 57600, 115200)

#: Upper bounds of settings that have no natural one: far beyond any real use, low enough that
#: no product, allocation or timer built from them overflows.
MAX_FRAME_PX = 16_384
MAX_HEAT_W = 1_000.0
MAX_TIMEOUT_S = 3_600.0
MAX_DURATION_S = 366 * 86_400.0  # a year of run clock
#: api.max_connections at most: the file-descriptor budget (deploy/thermocomp.service's
#: LimitNOFILE) is sized from it.
MAX_CONNECTIONS_LIMIT = 4_096

PositiveFloat = Annotated[float, Field(gt=0)]
NonNegativeFloat = Annotated[float, Field(ge=0)]


class ConfigError(Exception):
    """The configuration could not be loaded; ``str()`` is the message for the user."""


class _Section(BaseModel):
    # allow_inf_nan=False: every float of every section is finite (TOML's inf/nan, 1e400 and
    # an environment "Infinity" are refused naming the field), so no setting can carry an
    # infinity into a timer, a model step or a division
    model_config = ConfigDict(
        extra="forbid", validate_default=True, frozen=True, allow_inf_nan=False
    )


class BenchSettings(_Section):
    """The simulated bench and the clock every component shares."""

    enabled: bool = Field(True, description="Use the simulated bench instead of hardware.")
    clock: Literal["real", "accelerated", "virtual"] = Field(
        "virtual",
        description="real: wall time; accelerated: wall time x time_factor; virtual: jump to "
        "the next deadline (an hour in seconds).",
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
        description="Sim IR reader faults, as camera_faults: no-frame, late=S, unreadable "
        "(a thermal frame that is not finite); @N: the N-th read since it opened.",
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

    @field_validator("camera_faults", "ir_faults")
    @classmethod
    def _valid_fault_spec(cls, value: str) -> str:
        parse_sensor_faults(value)  # ValueError names the bad item
        return value


class CameraSettings(_Section):
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
    replay_loop: bool = Field(False, description="Replay: start again after the last frame.")
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
    gain_e_per_count: PositiveFloat = Field(
        1.0, description="Electrons per count, for the centroid's uncertainty estimate."
    )
    read_noise_e: NonNegativeFloat = Field(
        5.0, description="Read noise (electrons RMS), for the centroid's uncertainty estimate."
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
    centroid_binary: bool = Field(
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


class IrRegion(_Section):
    """A rectangle of the thermal image whose mean/max temperature is reported."""

    name: str
    x: Annotated[int, Field(ge=0, le=MAX_FRAME_PX)]
    y: Annotated[int, Field(ge=0, le=MAX_FRAME_PX)]
    width: Annotated[int, Field(gt=0, le=MAX_FRAME_PX)]
    height: Annotated[int, Field(gt=0, le=MAX_FRAME_PX)]
    node: str | None = Field(None, description="Model node this region measures, if any.")


class IrSettings(_Section):
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
    replay_loop: bool = Field(False, description="Replay: start again after the last frame.")
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


class RobotSettings(_Section):
    """The CRS C500C controller's serial console (C500C.md)."""

    driver: Literal["sim", "c500c", "c500c-server"] = Field(
        "sim",
        description="sim: the C500C emulator on a pseudo-terminal; c500c: a real port; "
        "c500c-server: the fast path, controller/thermocomp_server.r3 on the controller's second "
        "port (robot.server_port; on the simulated bench, bench.enabled, its emulator on a pty).",
    )
    port: str = Field("/dev/ttyS0", description="Serial device of the controller's console.")
    baudrate: int = Field(57600, description="Console baud rate (the C500C default is 57600).")
    bytesize: Literal[7, 8] = Field(8, description="Data bits.")
    parity: Literal["N", "E", "O"] = Field("N", description="Parity: none, even, odd.")
    stopbits: Literal[1, 2] = Field(1, description="Stop bits.")
    flow_control: Literal["none", "rtscts"] = Field(
        "none",
        description="Hardware flow control of the console port (C500C.md: RTS/CTS may not work "
        "on the console; the controller's own 115200-baud programs use it).",
    )
    command_timeout_s: Annotated[float, Field(gt=0, le=MAX_TIMEOUT_S)] = Field(
        5.0, description="Timeout of one console command."
    )
    move_timeout_s: Annotated[float, Field(gt=0, le=MAX_TIMEOUT_S)] = Field(
        60.0, description="Timeout of a move and its finish."
    )
    online: bool = Field(True, description="Use straight-line moves (needs `online on`).")
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
    emulator_paced: bool = Field(
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


class ModelSettings(_Section):
    """The controller's thermal model (thesis 5.4)."""

    network: str = Field(
        "thesis-two-link",
        description="Preset name in config/networks, an identified network saved in "
        "storage.data_dir/networks (identify --save NAME), or a TOML file path.",
    )
    stepper: Literal["exact", "explicit", "implicit"] = Field(
        "exact", description="exact: zero-order hold (any dt); explicit: Eq. 5.1; implicit: sparse."
    )
    ambient_c: Annotated[float, Field(ge=-60, le=150)] = Field(
        22.0,
        description="Ambient temperature the controller's model assumes (degC); the sim "
        "bench's real room is bench.ambient_c (none: this).",
    )
    heat_w: dict[str, Annotated[float, Field(ge=0, le=MAX_HEAT_W)]] = Field(
        default_factory=dict,
        description="Heat input per node NAME (W) for a network that carries no heat of its "
        "own; a key naming no node of the run's network refuses the run. Precedence: the "
        "run's heat_w (--heat) > the network file's heat > this > heater_power_w.",
    )
    heater_power_w: Annotated[float, Field(ge=0, le=MAX_HEAT_W)] = Field(
        0.5,
        description="The controller's belief of each heater pad's power (W): the heat of "
        "every heater node of a network with no heat of its own when heat_w is empty.",
    )
    reference_nodes: tuple[str, str] | None = Field(
        None, description="Deformation between these nodes; none: the network's default."
    )
    direction: tuple[float, float, float] = Field(
        (1.0, 0.0, 0.0),
        description="Unit vector of the link's axis in world coordinates, as the controller "
        "believes it (the sim truth's: bench.direction).",
    )
    prediction: Literal["model", "model+ir"] = Field(
        "model",
        description="model: open loop (the thesis); model+ir: a Kalman filter corrects the "
        "model each step from the IR regions tied to its nodes (issue 9).",
    )


class ObserverSettings(_Section):
    """The IR observer of prediction model+ir (daemon.model.observer) and its online
    adaptation (issue 19, daemon.model.adaptation)."""

    adapt: bool = Field(
        False,
        description="model+ir: also estimate the adapt_parameters scale factors online with the "
        "temperatures (augmented-state EKF), so a wrong model converges without a calibration "
        "run; an identified network's values and errors are the priors.",
    )
    adapt_parameters: tuple[str, ...] = Field(
        ("heat", "convection", "alpha"),
        description="What adaptation estimates: heat (every heat input x one factor), "
        "heat:NODE (that node's), convection (every node's conductance to ambient), from the IR "
        "regions; alpha (the predicted deformation x one factor), from the measured spot drift "
        "alone.",
    )
    stand_drift_tau_s: PositiveFloat | None = Field(
        600.0,
        description="alpha: the measured drift also carries the camera stand's warm-up, "
        "A (1 - exp(-t / tau)) of unknown A, estimated beside alpha and never compensated "
        "(thesis 4.8: the camera warmed up within ~25 min); none: no stand drift state.",
    )
    deformation_noise_um: Annotated[float, Field(gt=0, le=1000)] = Field(
        1.0,
        description="1-sigma of one measured residual (um, scaled) as adaptation of alpha "
        "weighs it: the robot's repeatability and the centroid (thesis Table 6.1: S_x 0.92).",
    )
    prior_sigma: Annotated[float, Field(gt=0, le=3)] = Field(
        0.5,
        description="1-sigma of the log of an adapted factor that no identification gave "
        "(0.5: a factor 1.65 either way).",
    )
    random_walk_per_hour: Annotated[float, Field(ge=0, le=1)] = Field(
        0.05,
        description="How far an adapted factor's log may wander per hour (1-sigma): the "
        "factors of a coarse model are effective values, nearly constant.",
    )


class CompensationSettings(_Section):
    """How a predicted deformation becomes a robot move (thesis 6.3, 6.4.4)."""

    mode: Literal["off", "absolute", "incremental"] = Field(
        "absolute", description="absolute: goal + offset (6.4.4); incremental: thesis comparison."
    )
    deformation_scale: PositiveFloat = Field(
        1.0, description="Scale factor on the deformation (thesis 6.3); checked against the chip."
    )
    time_scale: PositiveFloat = Field(1.0, description="Time scale of the procedure (thesis 6.3).")
    max_step_change_mm: PositiveFloat = Field(
        0.5, description="Largest change of the offset between two steps (mm)."
    )
    max_total_offset_mm: PositiveFloat = Field(
        5.0, description="Largest offset from the operational goal (mm)."
    )
    latency_s: NonNegativeFloat = Field(
        0.0, description="Predict this far ahead: when the move is expected to execute (s)."
    )
    spot_size_um: NonNegativeFloat = Field(
        200.0,
        description="Laser spot size on the chip (um), for the admissible-scale check (6.3).",
    )


class SchedulerSettings(_Section):
    """The fixed-step control loop (thesis chapter 6)."""

    procedure: Literal["stationary", "moving", "repeatability"] = Field(
        "stationary", description="What the robot does during the run (thesis 3.2.4, 2.2.2)."
    )
    step_s: Annotated[float, Field(ge=0.01, le=600)] = Field(
        1.0, description="Step period (s), 10 ms to 10 min."
    )
    duration_s: Annotated[float, Field(gt=0, le=MAX_DURATION_S)] = Field(
        3600.0, description="Run length (s of run clock)."
    )
    warmup_wait_s: Annotated[float, Field(ge=0, le=MAX_TIMEOUT_S)] = Field(
        0.0, description="Camera warm-up wait before the first step (s)."
    )
    precise_wake_ms: Annotated[float, Field(ge=0, le=10)] = Field(
        1.5,
        description="Wall clocks: wake this long before a deadline and yield until it "
        "(asyncio sleeps end up to 1 ms late); 0 = plain sleep.",
    )
    stop_grace_s: Annotated[float, Field(gt=0, le=60)] = Field(
        5.0,
        description="On stop, wait this long for the step in progress, then abandon it (s).",
    )
    sensor_error_policy: Literal["continue", "pause"] = Field(
        "continue",
        description="On a sensor error (flags camera-error, ir-error, centroid-error, and "
        "stale-frame/stale-ir: a late measurement is a missing one): flag the step and go on, "
        "or pause the run with the reason (the step's compensating move was already made).",
    )


class StorageSettings(_Section):
    """Where runs are recorded (SQLite, WAL)."""

    data_dir: Path = Field(Path("data"), description="Folder of the run database and frames.")
    archive_every: Annotated[int, Field(ge=0, le=2**31)] = Field(
        0, description="Archive every N-th frame as a 16-bit PNG; 0 = none."
    )
    report_at_end: bool = Field(
        True,
        description="Write the run's report (HTML + figures) under data_dir/reports at its end.",
    )


class ApiSettings(_Section):
    """The REST/WebSocket server."""

    host: str = Field("127.0.0.1", description="Address the API binds to.")
    port: Annotated[int, Field(ge=0, le=65535)] = Field(8000, description="TCP port; 0: any.")
    control_token: str | None = Field(None, description="Bearer token of the `control` scope.")
    read_token: str | None = Field(None, description="Bearer token of the `read` scope.")
    anonymous_read: bool | None = Field(
        None, description="Allow reads without a token; none: only when bound to loopback."
    )
    allowed_hosts: tuple[str, ...] = Field(
        (),
        description="Host names (or addresses) clients may use to reach the API, besides the "
        "loopback names and the bound address: any other Host header is refused with 400 "
        '(DNS rebinding). E.g. ["lab-pc.example.org"].',
    )
    allowed_origins: tuple[str, ...] = Field(
        (),
        description="Origins allowed to open the WebSocket besides those of the allowed hosts "
        '(e.g. "http://lab-pc:8000").',
    )
    max_connections: Annotated[int, Field(ge=8, le=MAX_CONNECTIONS_LIMIT)] = Field(
        256,
        description="Connections served at once (HTTP and WebSocket): requests beyond get 503, "
        "connections beyond this plus a small margin are closed on accept.",
    )
    request_timeout_s: Annotated[float, Field(gt=0, le=300)] = Field(
        5.0,
        description="Longest time a client may take to send a whole request (headers and body) "
        "from connecting or from its first byte; then the connection is dropped (slowloris).",
    )
    control_rate_per_s: PositiveFloat = Field(
        2.0, description="Average control requests per second per client (429 beyond)."
    )
    control_burst: Annotated[int, Field(ge=1, le=10_000)] = Field(
        10, description="Control requests a client may make at once before the rate applies."
    )
    max_body_bytes: Annotated[int, Field(ge=1024, le=64 * 2**20)] = Field(
        65536, description="Largest request body accepted (bytes; 413 beyond)."
    )
    ws_max_message_bytes: Annotated[int, Field(ge=64, le=2**20)] = Field(
        4096, description="Largest WebSocket message accepted from a client (bytes)."
    )
    ws_queue_messages: Annotated[int, Field(ge=1, le=100_000)] = Field(
        256, description="Messages queued per WebSocket client; a slow client loses the oldest."
    )
    ws_max_clients: Annotated[int, Field(ge=1, le=MAX_CONNECTIONS_LIMIT)] = Field(
        100, description="WebSocket clients served at once; more are refused."
    )
    ws_frame_interval_s: PositiveFloat = Field(
        1.0, description="Shortest interval between two WebSocket frame thumbnails (s)."
    )

    @model_validator(mode="after")
    def _room_beside_websockets(self) -> ApiSettings:
        if self.ws_max_clients >= self.max_connections:
            raise ValueError(
                f"ws_max_clients ({self.ws_max_clients}) must be below max_connections "
                f"({self.max_connections}): requests, the robot hold among them, need room"
            )
        return self


#: Markers on the tool (issue 20): at most this many, each a point in the tool frame (mm).
MAX_MARKERS = 32
#: Frames averaged per tool measurement at most: 64 frames of 5 MP cameras are seconds.
MAX_FRAMES_PER_MEASUREMENT = 64
#: Arm-run correction limits admit at most this much (a correction is a few tenths of a mm).
MAX_ARM_TRANSLATION_MM = 100.0
MAX_ARM_ROTATION_DEG = 10.0
MAX_ARM_CAMERAS = 16


class ArmSettings(_Section):
    """The whole arm (issue 20): a run that names a duty cycle corrects the tool in 6-DOF at
    its measured poses. Disabled (the default), thermocomp is the two-link bench."""

    enabled: bool = Field(
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
    bending: bool = Field(False, description="Links bend from a temperature gradient across them.")
    motor_side_share: Annotated[float, Field(ge=0, le=1)] = Field(
        0.5,
        description="With arm.bending: share of each joint's flange conductance on the link's "
        "motor-housing side (the arm's design; 0.5: symmetric, no gradient across a link).",
    )
    play_duty_cycle: bool | None = Field(
        None,
        description="The robot plays the whole duty cycle (every pose at its speed, its dwell) "
        "for the whole arm run, the measured poses measured in passing; needs time_scale 1 and "
        "the console driver. false: it moves to the measured poses only (the accelerated "
        "bench). none: played with robot.driver c500c, not on the bench or the fast path.",
    )

    @model_validator(mode="after")
    def _camera_devices_need_models(self) -> Self:
        # the 3-D measurement needs each real camera's calibrated model (intrinsics, pose):
        # they come from the camera file, matched by position (README "Measuring in 3-D")
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


class Settings(_Section):
    """Everything thermocomp can be told, one section per part of the product."""

    @model_validator(mode="after")
    def _playable_duty_cycle(self) -> Self:
        # a real arm cannot be accelerated, and the fast path's frames carry no speed
        if self.arm.play_duty_cycle:
            if self.robot.driver == "c500c-server":
                raise ValueError(
                    "arm.play_duty_cycle needs robot.driver c500c: the fast path's moves "
                    "carry no speed (controller/PROTOCOL.md)"
                )
            if self.compensation.time_scale != 1.0:
                raise ValueError(
                    "arm.play_duty_cycle needs compensation.time_scale 1: a played cycle "
                    "moves the arm in real time"
                )
        return self

    bench: BenchSettings = BenchSettings()
    camera: CameraSettings = CameraSettings()
    ir: IrSettings = IrSettings()
    robot: RobotSettings = RobotSettings()
    model: ModelSettings = ModelSettings()
    observer: ObserverSettings = ObserverSettings()
    compensation: CompensationSettings = CompensationSettings()
    scheduler: SchedulerSettings = SchedulerSettings()
    storage: StorageSettings = StorageSettings()
    api: ApiSettings = ApiSettings()
    arm: ArmSettings = ArmSettings()


#: Setting names whose value is a secret: never stored (run rows) nor served (GET /config),
#: only whether they are set.
SECRET_SUFFIXES = ("token", "password", "secret")
REDACTED = "<redacted>"


def redact_secrets(value: Any) -> Any:
    """``value`` (a settings dump, or any JSON-like tree) with every secret's value replaced
    by ``"<redacted>"``; an unset secret stays null."""
    if isinstance(value, dict):
        return {
            key: (
                REDACTED
                if isinstance(key, str)
                and key.lower().endswith(SECRET_SUFFIXES)
                and item is not None
                else redact_secrets(item)
            )
            for key, item in value.items()
        }
    if isinstance(value, list | tuple):
        return [redact_secrets(item) for item in value]
    return value


def _env_value(raw: str) -> Any:
    """An environment value: JSON when it parses (numbers, lists, objects), else the string."""
    try:
        return json.loads(raw)
    except ValueError:
        return raw


def _apply_environment(data: dict[str, Any], environ: Mapping[str, str]) -> dict[str, str]:
    """Merge ``THERMOCOMP_SECTION__FIELD`` variables into ``data``; return the ones used."""
    used: dict[str, str] = {}
    for name, raw in sorted(environ.items()):
        if not name.startswith(ENV_PREFIX) or ENV_NESTING not in name:
            continue
        path = name[len(ENV_PREFIX) :].lower().split(ENV_NESTING)
        node = data
        for key in path[:-1]:
            child = node.setdefault(key, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{name}: {'.'.join(path)}: {key} is not a section")
            node = child
        node[path[-1]] = _env_value(raw)
        used[".".join(path)] = name
    return used


def _describe(error: ValidationError, source: str, env_used: dict[str, str]) -> str:
    lines = []
    for item in error.errors():
        path = ".".join(str(part) for part in item["loc"])
        reason = str(item["msg"]).removeprefix("Value error, ")
        if item["type"] == "extra_forbidden":
            reason = "unknown setting"
        origin = f"{env_used[path]} (environment)" if path in env_used else source
        lines.append(f"{origin}: {path}: {reason}")
    return "\n".join(lines)


def read_toml(path: Path, error: type[Exception]) -> dict[str, Any]:
    """A TOML file's tables; any failure is ``error("<path>: <why>")`` (missing, not TOML,
    unreadable), so settings and network files report bad files the same way."""
    try:
        with open(path, "rb") as handle:
            raw = handle.read(MAX_TOML_BYTES + 1)
    except FileNotFoundError as err:
        raise error(f"{path}: no such file") from err
    except IsADirectoryError as err:
        raise error(f"{path}: is a folder, not a TOML file") from err
    except OSError as err:
        raise error(f"{path}: cannot read: {err.strerror}") from err
    if len(raw) > MAX_TOML_BYTES:
        raise error(f"{path}: over {MAX_TOML_BYTES // 1024} KiB: not a settings or network file")
    if b"\0" in raw:
        raise error(f"{path}: a binary file, not TOML text")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise error(f"{path}: not UTF-8 text (byte {err.start}): save it as UTF-8") from err
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise error(f"{path}: not valid TOML: {err}") from err


def load_settings(path: Path | None = None, environ: Mapping[str, str] | None = None) -> Settings:
    """Build the settings from an optional TOML file and the environment.

    Raises :class:`ConfigError` with ``<file>: <field.path>: <reason>`` lines.
    """
    environ = os.environ if environ is None else environ
    data: dict[str, Any] = {}
    source = "defaults"
    if path is not None:
        source = str(path)
        data = read_toml(path, ConfigError)
    env_used = _apply_environment(data, environ)
    try:
        return Settings.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_describe(err, source, env_used)) from err


def _type_name(annotation: Any) -> str:
    """A reader's name for a field type: choices spelled out, Optional as "| none"."""
    origin, args = get_origin(annotation), get_args(annotation)
    if origin is Literal:
        return " \\| ".join(json.dumps(arg) for arg in args)
    if origin in (Union, UnionType):
        return " \\| ".join("none" if arg is type(None) else _type_name(arg) for arg in args)
    if origin is Annotated:
        return _type_name(args[0])
    if origin is not None:
        inner = ", ".join("..." if arg is Ellipsis else _type_name(arg) for arg in args)
        return f"{getattr(origin, '__name__', str(origin))}[{inner}]"
    return getattr(annotation, "__name__", str(annotation))


def settings_reference() -> list[tuple[str, str, str, str]]:
    """(key, type, default, description) of every setting, for the README's reference."""
    rows: list[tuple[str, str, str, str]] = []
    for section_name, section_field in Settings.model_fields.items():
        section_type = section_field.annotation
        assert isinstance(section_type, type) and issubclass(section_type, BaseModel)
        for name, field in section_type.model_fields.items():
            annotation = _type_name(field.annotation)
            default = field.get_default(call_default_factory=True)
            default_text = json.dumps(default, default=str) if default is not None else "none"
            rows.append(
                (f"{section_name}.{name}", annotation, default_text, field.description or "")
            )
    return rows


README_BEGIN = (
    "<!-- settings-reference:begin (generated by `python -m config --readme README.md`) -->"
)
README_END = "<!-- settings-reference:end -->"


def settings_reference_markdown() -> str:
    """The configuration reference as a Markdown table (kept in README.md)."""
    lines = [
        "| key | type | default | meaning |",
        "| --- | --- | --- | --- |",
    ]
    for key, type_name, default, description in settings_reference():
        cells = (key, type_name, default.replace("|", "\\|"), description.replace("|", "\\|"))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
