"""The physical truth of the simulated arm bench (issue 20): a serial arm warming up from its own
motion, watched by several cameras through markers on its tool and by an IR camera on its links.

What is true here and what the controller believes differ, as on a real arm:

- Kinematics: the arm's true DH table is the preset's with every length (``a``, ``d``) moved
  by a seeded draw of 1-sigma ``dh_length_sigma_mm`` and every angle (``alpha``, ``theta``
  offset) by ``dh_angle_sigma_rad``: the size of a small arm's uncalibrated geometric error
  (an arm's absolute accuracy is "an order of magnitude worse than its repeatability",
  thesis 2.2; the A465's repeatability is +-50 um). The controller keeps the nominal table.
- Thermal: the true model is the preset's :class:`~daemon.arm.thermal.ArmThermalModel` at
  ``node_spacing_mm`` (10 mm, five times finer than the controller's 50 mm default), two rows
  of nodes per link (``across_link``: the temperature across a link bends it, and the tool
  turns; the motor housings on the "+" side, ``plus_share``), with the still-air convection
  times ``convection_scale``, the links' expansion coefficient times
  ``alpha_scale`` (6061-T6 is 23.6e-6 /K in one handbook, 23.4 in another; the truth is
  also its temper and its anodising) and each joint's heat capacity times ``capacity_scale``.
- Motors: each joint's winding resistance and friction are the preset's times a seeded factor
  in ``[1 - heat_spread, 1 + heat_spread]`` (copper at another temperature, a gearbox run in
  or not), unless ``heat_scales`` gives them. The heat comes from the motion the arm really
  performs (drivers.sim.arm_motion: the emulator's joints or a duty cycle played in process).
- Ambient: ``ambient_c`` at the start, a linear drift (``ambient_drift_c_per_h``) and a
  sinusoidal swing (``ambient_swing_c`` amplitude over ``ambient_swing_period_s``; a lab's
  day), the same air for the arm and its heat loss; a room thermometer reads it with its own
  lag, noise and resolution (drivers/sim/arm_room.py, ``room_*``).

:func:`config_from_truth` makes these from a truth file (``bench.arm_truth``,
config/arm_truth.py); the defaults here are that file's defaults.

Everything random comes from seeded generators: the truth's parameters from ``seed``, the
measurements' noise from ``noise_seed`` (default ``seed``), one generator per device (each
camera, the IR reader), so one device's extra draws never change another's, and one arm can be
measured twice with other noise (a calibration cycle, then a run).

- Cameras: ``rig`` (drivers.sim.arm_markers) around the tool at each station
  (``stations_q_rad``, a measured pose of the cycle); each marker's spot is rendered with
  photon and read noise, its centre
  moved by a seeded image-plane jitter of 1-sigma ``jitter_px`` (air turbulence and stand
  vibration: what limits a photogrammetric system at a metre, not the centroid).
- IR regions: the mean of the true nodes within ``ir_half_width_mm`` of a point at a fraction
  along a link, plus a constant per-region offset (1-sigma ``ir_offset_sigma_c``; the FLIR's
  +-2 degC accuracy, thesis 3.2.2, after a rough calibration) and noise ``ir_noise_c``. A
  region named for one face of its link (``<link>-mid.plus``, daemon/arm/ir_regions.py) sees
  that face's row of the truth only.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from config.arm_truth import ArmTruth
from daemon.arm import kinematics
from daemon.arm.description import Arm
from daemon.arm.ir_regions import region_face
from daemon.arm.loading import load_arm
from daemon.arm.thermal import ArmThermalModel
from daemon.arm.types import FloatArray, LinkThermalState
from daemon.vision.multiview import CameraModel
from daemon.vision.tool_pose import ToolMeasurement
from drivers.base import Frame
from drivers.sim.arm_markers import (
    CameraRig,
    MarkerRenderer,
    MarkerWindow,
    markers_world_mm,
    measure_tool,
)
from drivers.sim.arm_motion import JointMotionSource, MotorEnergy, StillMotion
from drivers.sim.arm_physics import motion_power, motion_power_batch, true_arm, true_description
from drivers.sim.arm_room import SimRoomSensor

#: Default markers on the tool (tool frame, mm): four LEDs on a 120 mm cross plate, two raised,
#: so that no three are on a line and the rotation is seen about every axis.
DEFAULT_MARKERS_MM: tuple[tuple[float, float, float], ...] = (
    (60.0, 0.0, 0.0),
    (0.0, 60.0, 0.0),
    (-60.0, 0.0, 15.0),
    (0.0, -60.0, 35.0),
)
#: Default IR regions: (name, link, fraction along the link from its proximal joint).
DEFAULT_IR_REGIONS: tuple[tuple[str, str, float], ...] = ()


@dataclass(frozen=True)
class ArmBenchConfig:
    """What the arm bench is made of (module docstring for the meaning and the defaults)."""

    arm: str = "crs-a465"
    seed: int = 0
    #: the measurement noise's seed (default: ``seed``); the truth's parameters come from
    #: ``seed`` alone, so two benches of one seed and two noise seeds are one arm, measured
    #: twice (a calibration cycle and a run)
    noise_seed: int | None = None
    # truth: kinematics
    dh_length_sigma_mm: float = 0.2
    dh_angle_sigma_rad: float = 2e-4
    # truth: thermal
    node_spacing_mm: float = 10.0
    #: two rows of nodes per link (daemon.arm.thermal ``across_link``): the temperature across
    #: each link, which bends it (kinematics.warm_arm ``bending``)
    across_link: bool = True
    #: share of each joint flange's conductance that reaches the link's "+" side (the motor
    #: housing sits on one side of the link: its heat warms that side first and bends the link)
    plus_share: float = 0.75
    truth_step_s: float = 2.0
    convection_scale: float = 0.8
    alpha_scale: float = 1.05
    capacity_scale: float = 1.1
    heat_scales: tuple[float, ...] | None = None
    heat_spread: float = 0.25
    ambient_c: float = 22.0
    ambient_drift_c_per_h: float = 0.0
    ambient_swing_c: float = 0.0
    ambient_swing_period_s: float = 86_400.0
    # the room thermometer (drivers/sim/arm_room.py)
    room_noise_c: float = 0.02
    room_resolution_c: float = 0.0625
    room_lag_s: float = 120.0
    room_offset_c: float = 0.0
    # motion
    motion_step_s: float = 0.01
    #: carried at the tool point (a duty cycle's gripper and part: DutyCycle.payload_kg)
    payload_kg: float = 0.0
    # cameras and markers
    rig: CameraRig = field(default_factory=CameraRig)
    markers_tool_mm: tuple[tuple[float, float, float], ...] = DEFAULT_MARKERS_MM
    jitter_px: float = 0.03
    #: the configurations the cameras are set up around: one rig per station (default: the
    #: arm's zero configuration)
    stations_q_rad: tuple[tuple[float, ...], ...] = ()
    # IR
    ir_regions: tuple[tuple[str, str, float], ...] = DEFAULT_IR_REGIONS
    ir_half_width_mm: float = 15.0
    ir_noise_c: float = 0.05
    ir_offset_sigma_c: float = 0.3


HOUR_S = 3600.0


def config_from_truth(truth: ArmTruth, seed: int, **rest: Any) -> ArmBenchConfig:
    """The bench's make-up from a truth file (config/arm_truth.py; its seed, else ``seed``)
    and the rest of the bench (``rest``: the arm, stations, markers, rig, IR regions, ...)."""
    kinematics, motors, thermal = truth.kinematics, truth.motors, truth.thermal
    room, measurement = truth.room, truth.measurement
    return ArmBenchConfig(
        seed=seed if truth.seed is None else truth.seed,
        dh_length_sigma_mm=kinematics.dh_length_sigma_mm,
        dh_angle_sigma_rad=kinematics.dh_angle_sigma_rad,
        node_spacing_mm=thermal.node_spacing_mm,
        plus_share=thermal.bending_share,
        convection_scale=thermal.convection_scale,
        alpha_scale=thermal.expansion_scale,
        capacity_scale=thermal.capacity_scale,
        heat_scales=motors.heat_scales,
        heat_spread=motors.heat_spread,
        ambient_c=room.start_c,
        ambient_drift_c_per_h=room.drift_c_per_h,
        ambient_swing_c=room.swing_c,
        ambient_swing_period_s=room.swing_period_h * HOUR_S,
        jitter_px=measurement.jitter_px,
        ir_noise_c=measurement.ir_noise_c,
        ir_offset_sigma_c=measurement.ir_offset_sigma_c,
        room_noise_c=measurement.room_noise_c,
        room_resolution_c=measurement.room_resolution_c,
        room_lag_s=measurement.room_lag_s,
        room_offset_c=measurement.room_offset_c,
        **rest,
    )


class ArmBench:
    """The arm bench's truth, advanced on demand on its own time (s from a cold start)."""

    def __init__(
        self,
        config: ArmBenchConfig | None = None,
        motion: JointMotionSource | None = None,
        *,
        arm: Arm | None = None,
    ) -> None:
        self.config = config = config or ArmBenchConfig()
        self.nominal_arm: Arm = arm if arm is not None else load_arm(config.arm)
        joints = self.nominal_arm.dof
        stations = config.stations_q_rad or ((0.0,) * joints,)
        # The truth's parameters from ``seed``; every device's noise from ``noise_seed``.
        truth_rng = np.random.default_rng(np.random.SeedSequence(config.seed).spawn(1)[0])
        noise_seed = config.seed if config.noise_seed is None else config.noise_seed
        cameras = config.rig.count * len(stations)
        # the room thermometer's stream last: the others are those of before it existed
        streams = np.random.SeedSequence([noise_seed, 1]).spawn(2 + cameras)
        self.ir_rng = np.random.default_rng(streams[0])
        self.room_sensor = SimRoomSensor(
            self.ambient_c,
            np.random.default_rng(streams[1 + cameras]),
            lag_s=config.room_lag_s,
            noise_c=config.room_noise_c,
            resolution_c=config.room_resolution_c,
            offset_c=config.room_offset_c,
        )
        if config.heat_scales is not None:
            if len(config.heat_scales) != joints:
                raise ValueError(f"heat_scales: {joints} joints, {len(config.heat_scales)} given")
            self.heat_scales = np.array(config.heat_scales, dtype=np.float64)
        else:
            spread = config.heat_spread
            self.heat_scales = truth_rng.uniform(1.0 - spread, 1.0 + spread, joints)
        self.true_arm = true_arm(
            self.nominal_arm,
            truth_rng,
            config.dh_length_sigma_mm,
            config.dh_angle_sigma_rad,
            self.heat_scales,
        )
        self.power = motion_power(self.true_arm, config.payload_kg)
        self.thermal = ArmThermalModel(
            true_description(
                self.true_arm, config.alpha_scale, config.capacity_scale, config.plus_share
            ),
            node_spacing_mm=config.node_spacing_mm,
            ambient_c=self.ambient_c,
            dt_s=config.truth_step_s,
            convection_scale=config.convection_scale,
            across_link=config.across_link,
        )
        self.ir_offsets_c = {
            name: float(truth_rng.normal(0.0, config.ir_offset_sigma_c))
            for name, _, _ in config.ir_regions
        }
        self._ir_rows = self._region_rows()
        self.markers_tool_mm = np.array(config.markers_tool_mm, dtype=np.float64)
        self.stations_q_rad = tuple(np.asarray(q, dtype=np.float64) for q in stations)
        #: the cameras of each station (rig.count each), looking at the tool there
        self.station_cameras: tuple[tuple[CameraModel, ...], ...] = tuple(
            tuple(
                dataclasses.replace(camera, name=f"s{s}-{camera.name}")
                for camera in config.rig.cameras(self.tool_pose_cold(q)[:3, 3])
            )
            for s, q in enumerate(self.stations_q_rad)
        )
        self.cameras: tuple[CameraModel, ...] = tuple(
            camera for cameras in self.station_cameras for camera in cameras
        )
        self._renderers = [
            MarkerRenderer(camera, config.rig, np.random.default_rng(stream))
            for camera, stream in zip(self.cameras, streams[1 : 1 + cameras], strict=True)
        ]
        self._sequences = [0] * len(self.cameras)
        self.time_s = 0.0
        # no motion given: the arm rests on its brakes, motors off (no heat)
        self.motion: JointMotionSource = motion or StillMotion(
            self.stations_q_rad[0], holding=False
        )
        self.energy = MotorEnergy(
            self.motion,
            self.power,
            joints,
            config.motion_step_s,
            motion_power_batch(self.true_arm, config.payload_kg),
        )
        self.heat_delivered_j = np.zeros(joints)
        #: the motion's energy at the truth's time (s, J per joint): a truth step starts from
        #: it rather than asking ``energy`` backwards after ``follow_motion`` integrated on
        self._truth_energy: tuple[float, FloatArray] | None = (
            self.thermal.time_s,
            self.energy.energy_j(self.thermal.time_s),
        )

    def station_camera_indices(self, station: int) -> range:
        """Indices (into ``cameras``) of one station's cameras."""
        count = self.config.rig.count
        return range(station * count, (station + 1) * count)

    # -- time ------------------------------------------------------------------------------------

    def ambient_c(self, t_s: float) -> float:
        """The air's temperature at ``t_s`` (degC)."""
        config = self.config
        room = config.ambient_c + config.ambient_drift_c_per_h * t_s / HOUR_S
        if config.ambient_swing_c == 0.0:
            return room
        return room + config.ambient_swing_c * math.sin(
            2.0 * math.pi * t_s / config.ambient_swing_period_s
        )

    def advance_to(self, t_s: float) -> None:
        """Bring the truth to ``t_s`` (never backwards): on the truth's grid, each step with the
        mean motor power over it (the energy of the motion, arm_motion.MotorEnergy)."""
        step = self.config.truth_step_s
        target = math.floor(t_s / step + 1e-9) * step
        start = self.thermal.time_s
        steps = round((target - start) / step)
        if steps > 0:
            known = self._truth_energy
            first = known[1] if known is not None and known[0] == start else None
            energies = [
                first if first is not None else self.energy.energy_j(start),
                *(self.energy.energy_j(start + k * step) for k in range(1, steps + 1)),
            ]
            for k in range(steps):
                watts = (energies[k + 1] - energies[k]) / step
                self.thermal.advance_to(start + (k + 1) * step, watts)
            self._truth_energy = (self.thermal.time_s, energies[-1])
            self.heat_delivered_j = self.heat_delivered_j + energies[-1] - energies[0]
        self.time_s = max(self.time_s, t_s)

    def follow_motion(self, t_s: float) -> None:
        """Bring the truth to ``t_s`` and integrate the motion's energy up to ``t_s``: called
        every few hundredths of a second by a real-time emulator (the UR's controller
        cycle), so that a truth step finds its motion integrated already instead of
        sampling a whole step (200 samples, ~6 ms) inside one controller cycle."""
        self.advance_to(t_s)  # first: the integration must not pass a boundary not stepped
        self.energy.integrate_to(t_s)

    # -- truth -----------------------------------------------------------------------------------

    def link_states(self) -> tuple[LinkThermalState, ...]:
        return self.thermal.link_states()

    def tool_pose_cold(self, q_rad: Sequence[float] | FloatArray) -> FloatArray:
        """The tool's pose (4x4, base frame) of the true arm at ambient."""
        pose: FloatArray = np.asarray(kinematics.forward(self.true_arm, np.asarray(q_rad)))
        return pose

    def tool_pose_true(self, q_rad: Sequence[float] | FloatArray) -> FloatArray:
        """The tool's true pose (4x4, base frame) at ``q_rad`` and the bench's current
        temperatures."""
        warm = kinematics.warm_arm(
            self.true_arm, self.link_states(), bending=self.config.across_link
        )
        pose: FloatArray = np.asarray(kinematics.forward(warm, np.asarray(q_rad)))
        return pose

    def markers_world_mm(self, q_rad: Sequence[float] | FloatArray) -> FloatArray:
        """The markers' true positions (M x 3, world mm) at ``q_rad`` now."""
        return markers_world_mm(self.tool_pose_true(q_rad), self.markers_tool_mm)

    def current_q(self) -> FloatArray:
        return np.asarray(self.motion.joint_sample(self.time_s).q_rad, dtype=np.float64)

    # -- cameras ---------------------------------------------------------------------------------

    def render_windows(
        self, camera_index: int, q_rad: Sequence[float] | FloatArray | None = None
    ) -> list[MarkerWindow]:
        """Each marker's region of interest in camera ``camera_index`` (the arm at ``q_rad``,
        default where the motion has it now)."""
        renderer = self._renderers[camera_index]
        q = self.current_q() if q_rad is None else np.asarray(q_rad, dtype=np.float64)
        return renderer.render_windows(self.markers_world_mm(q), jitter_px=self.config.jitter_px)

    def render(self, camera_index: int, q_rad: Sequence[float] | FloatArray | None = None) -> Frame:
        """A whole frame of camera ``camera_index`` with every marker's spot."""
        renderer = self._renderers[camera_index]
        q = self.current_q() if q_rad is None else np.asarray(q_rad, dtype=np.float64)
        image = renderer.render(self.markers_world_mm(q), jitter_px=self.config.jitter_px)
        sequence = self._sequences[camera_index]
        self._sequences[camera_index] += 1
        return Frame(
            image=image,  # type: ignore[arg-type]
            bit_depth=self.config.rig.bit_depth,
            timestamp_s=self.time_s,
            sequence=sequence,
            timestamp_source="camera",
        )

    def measure_tool(
        self, station: int, q_rad: Sequence[float] | FloatArray | None = None
    ) -> ToolMeasurement:
        """The tool measured by one station's cameras (rendered windows, centroids,
        triangulation, pose fit: drivers.sim.arm_markers.measure_tool)."""
        indices = self.station_camera_indices(station)
        return measure_tool(
            [self.cameras[i] for i in indices],
            [self.render_windows(i, q_rad) for i in indices],
            self.markers_tool_mm,
            self.config.rig,
            self.config.jitter_px,
        )

    # -- IR --------------------------------------------------------------------------------------

    def _region_rows(self) -> dict[str, FloatArray]:
        """Each IR region's weights over the truth's nodes (the mean of the nodes within the
        region's half width of its point)."""
        thermal = self.thermal
        rows: dict[str, FloatArray] = {}
        for name, link, fraction in self.config.ir_regions:
            face = region_face(name)[1]  # a region on one face sees that face only
            nodes = np.asarray(thermal.link_face_node_indices(link, face), dtype=np.intp)
            along = thermal.network.positions_mm[nodes]
            point = along[0] + fraction * (along[-1] - along[0])
            inside = nodes[np.abs(along - point) <= self.config.ir_half_width_mm]
            if inside.size == 0:
                inside = nodes[[int(np.argmin(np.abs(along - point)))]]
            row = np.zeros(thermal.network.node_count)
            row[inside] = 1.0 / inside.size
            rows[name] = row
        return rows

    def room_read(self) -> float:
        """One reading of the room thermometer now (degC; drivers/sim/arm_room.py)."""
        return self.room_sensor.read(self.time_s)

    def ir_true_c(self) -> dict[str, float]:
        """Each region's true mean temperature now (no offset, no noise)."""
        temperatures = self.thermal.temperatures_c
        return {name: float(row @ temperatures) for name, row in self._ir_rows.items()}

    def ir_read(self) -> dict[str, float]:
        """One IR reading: each region's mean (degC) with its offset and noise."""
        noise = self.ir_rng.normal(0.0, self.config.ir_noise_c, len(self._ir_rows))
        return {
            name: value + self.ir_offsets_c[name] + float(n)
            for (name, value), n in zip(self.ir_true_c().items(), noise, strict=True)
        }


__all__ = [
    "DEFAULT_MARKERS_MM",
    "ArmBench",
    "ArmBenchConfig",
    "config_from_truth",
]
