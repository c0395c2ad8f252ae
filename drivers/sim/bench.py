"""The physical truth of the simulated bench: the heated two-link system, the camera stand, the
robot's real pose, and where all of that puts the laser spot on the camera chip.

- Truth thermal network: by default the thesis geometry at ``bench.truth_node_spacing_mm``
  (2 mm nodes, far finer than the controller's 17-node Table 5.1 model), with its convection
  and heat input scaled by ``bench.truth_convection_scale`` / ``bench.truth_heat_scale`` so that
  the controller's prediction is not trivially perfect.
- Heater schedule: both pads (the shafts, thesis 5.2) on ``bench.heater_on_delay_s`` after the
  run starts, off ``bench.heater_off_delay_s`` after the run's ``heater_off_s``: the truth's own
  timing, which the controller believes to be the run's (both delays 0 by default).
- Ambient: the room's own temperature, ``bench.ambient_c`` (none: ``model.ambient_c``) plus an
  optional linear drift (``ambient_drift_c_per_h``) and sinusoidal swing (``ambient_swing_c``
  over ``ambient_swing_period_h``), in bench time; held for AMBIENT_STEP_S at a time. The
  controller's ``model.ambient_c`` is only its belief (issue 19).
- Moving case (thesis 3.2.4, two-link 5.2): the right link wipes a 30 degree arc about the middle
  shaft; its forced convection is modelled as ``bench.moving_convection_scale`` times the
  still-air convection of every node beyond the middle shaft.
- Camera stand (thesis 4.8): its aluminium plate warms up and shifts the chip by about 2 um in
  x over ~30 min, a first-order lag ``A (1 - exp(-t / tau))``; ``A`` and ``tau`` are drawn from
  the seed, uniformly within +-``stand_drift_spread`` (relative) of ``stand_drift_um`` /
  ``stand_drift_tau_s``, so that identification cannot learn one seed's drift as physics.
- The spot on the chip moves with the true deformation times the deformation scale (thesis
  6.3), plus the robot's actual offset from where it started, plus the stand drift; world x is
  chip x and world z is chip -y (image rows grow downwards), through the physical pixel pitch.

Everything random draws from generators spawned from ``bench.seed``: the same seed gives the same
run, and each device has its own stream, so one device's extra draws never change another's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from config.settings import Settings
from daemon.model import (
    EXACT_NODE_LIMIT,
    ThermalModel,
    ThermalNetwork,
    load_network,
    thesis_two_link_geometry_network,
)
from daemon.model.geometry import TWO_LINK_SHAFTS_MM
from drivers.clock import Clock

#: The preset name whose truth is built from the thesis geometry rather than loaded as is.
GEOMETRY_TRUTH = "thesis-two-link-geometry"
#: The truth is advanced on this grid (s): one precomputed exact step, never a new matrix
#: exponential for an odd remainder; far below the link's time constants (~2,000 s).
TRUTH_STEP_S = 0.5
#: Thesis 5.2: the right link moves about the middle shaft, so nodes beyond it wipe the air.
MOVING_LINK_FROM_MM = TWO_LINK_SHAFTS_MM[1]
#: A drifting room's temperature is held this long (s) between updates of the truth's input:
#: at the largest drift the settings admit (20 degC/h) a 0.06 degC step, against the link's
#: ~2,000 s time constants.
AMBIENT_STEP_S = 10.0
SECONDS_PER_HOUR = 3600.0

PoseSource = Callable[[], Sequence[float]]


def scale_convection(
    network: ThermalNetwork, factor: float, from_mm: float = -math.inf
) -> ThermalNetwork:
    """``network`` with the convection (h, so 1 / R to ambient and through end faces) of the
    nodes at or beyond ``from_mm`` multiplied by ``factor``."""
    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"convection factor must be positive, not {factor}")
    affected = network.positions_mm >= from_mm
    divisor = np.where(affected, factor, 1.0)
    return dataclasses.replace(
        network,
        name=f"{network.name} (convection x{factor:g} from {from_mm:g} mm)",
        r_ambient_c_per_w=network.r_ambient_c_per_w / divisor,
        r_end_c_per_w=network.r_end_c_per_w / divisor,
    )


def truth_network(settings: Settings, procedure: str | None = None) -> ThermalNetwork:
    """The bench's truth network for ``settings`` and the run's ``procedure`` (default:
    scheduler.procedure); see the module's docstring."""
    bench = settings.bench
    procedure = settings.scheduler.procedure if procedure is None else procedure
    if bench.truth_network == GEOMETRY_TRUTH:
        network = thesis_two_link_geometry_network(
            node_spacing_mm=bench.truth_node_spacing_mm,
            convection_scale=bench.truth_convection_scale,
        )
    else:
        network = load_network(bench.truth_network)
        if bench.truth_convection_scale != 1.0:
            network = scale_convection(network, bench.truth_convection_scale)
    if procedure == "moving":
        network = scale_convection(network, bench.moving_convection_scale, MOVING_LINK_FROM_MM)
    return network


class Bench:
    """The physical truth shared by the simulated camera, IR reader and robot."""

    def __init__(
        self, settings: Settings, clock: Clock, robot_pose: PoseSource | None = None
    ) -> None:
        self.settings = settings
        self.clock = clock
        bench = settings.bench
        # Children 0-2 are the streams the bench always had (same seed, same frames); the
        # stand's draw has its own fourth stream.
        streams = np.random.SeedSequence(bench.seed).spawn(4)
        camera_seed, ir_seed, robot_seed, stand_seed = streams
        self.camera_rng = np.random.default_rng(camera_seed)
        self.ir_rng = np.random.default_rng(ir_seed)
        #: Seed of the emulated robot's positioning noise (drawn from ``bench.seed``).
        self.robot_seed = int(robot_seed.generate_state(1)[0])
        amplitude_u, tau_u = np.random.default_rng(stand_seed).uniform(-1.0, 1.0, 2)
        spread = bench.stand_drift_spread
        #: This seed's camera-stand drift: amplitude (um) and time constant (s), each drawn
        #: uniformly within +-spread (relative) of the nominal: bounded, never changing sign.
        self.stand_drift_amplitude_um = bench.stand_drift_um * (1.0 + spread * float(amplitude_u))
        self.stand_drift_tau_s = bench.stand_drift_tau_s * (1.0 + spread * float(tau_u))
        #: The truth's IR pixel noise (degC) and room temperature at bench time 0.
        self.ir_noise_c = settings.ir.noise_c if bench.ir_noise_c is None else bench.ir_noise_c
        self.ambient0_c = settings.model.ambient_c if bench.ambient_c is None else bench.ambient_c
        self._ambient_varies = bench.ambient_drift_c_per_h != 0.0 or bench.ambient_swing_c != 0.0
        self.deformation_scale = settings.compensation.deformation_scale
        self._run_start_s = 0.0
        self._heater_off_s = bench.heater_off_s
        self._build_truth(settings.scheduler.procedure)
        self._robot_pose: PoseSource | None = None
        self._robot_start = np.zeros(3)
        if robot_pose is not None:
            self.attach_robot(robot_pose)

    def attach_robot(self, robot_pose: PoseSource) -> None:
        """Follow the robot's actual pose; where it is now is where the spot was aligned."""
        self._robot_pose = robot_pose
        self._robot_start = np.asarray(robot_pose()[:3], dtype=np.float64)

    def _build_truth(self, procedure: str) -> None:
        bench = self.settings.bench
        self.network = truth_network(self.settings, procedure)
        ambient = self.ambient_at(self._run_start_s)
        self.model = ThermalModel(
            self.network,
            stepper="exact" if self.network.node_count <= EXACT_NODE_LIMIT else "implicit",
            dt_s=TRUTH_STEP_S,
            ambient_c=ambient,
            direction=self.settings.model.direction if bench.direction is None else bench.direction,
        )
        self._heaters_on = False
        self._set_heaters(self._heaters_due(0.0))

    def ambient_at(self, t_s: float) -> float:
        """The room's true temperature (degC) at bench time ``t_s``."""
        bench = self.settings.bench
        hours = t_s / SECONDS_PER_HOUR
        swing = bench.ambient_swing_c * math.sin(
            2.0 * math.pi * hours / bench.ambient_swing_period_h
        )
        return self.ambient0_c + bench.ambient_drift_c_per_h * hours + swing

    def _heaters_due(self, run_s: float) -> bool:
        """Whether the pads really heat at run time ``run_s`` (the truth's own timing)."""
        bench = self.settings.bench
        if bench.heater_power_w <= 0 or run_s < bench.heater_on_delay_s:
            return False
        off_s = self._truth_off_s()
        return off_s is None or run_s < off_s

    def _truth_off_s(self) -> float | None:
        if self._heater_off_s is None:
            return None
        return max(self._heater_off_s + self.settings.bench.heater_off_delay_s, 0.0)

    def start_run(
        self,
        t_s: float,
        *,
        deformation_scale: float | None = None,
        procedure: str | None = None,
        heater_off_s: float | None = None,
    ) -> None:
        """A fresh cold start of the links at bench time ``t_s`` (a run begins): the truth
        back at ambient with the heaters on, off ``heater_off_s`` after ``t_s`` (none: stay on),
        the run's deformation scale and procedure, and the spot aligned where the robot is now.
        The camera stand keeps warming on its own time: it started with the camera."""
        self.build_run(
            t_s, deformation_scale=deformation_scale, procedure=procedure, heater_off_s=heater_off_s
        )
        self.align_spot()

    def build_run(
        self,
        t_s: float,
        *,
        deformation_scale: float | None = None,
        procedure: str | None = None,
        heater_off_s: float | None = None,
    ) -> None:
        """:meth:`start_run` but the spot's alignment: the truth model's build (0.25-0.55 s
        under load), which a run does on a worker thread (issue 26: never on the event loop),
        then :meth:`align_spot` on the loop (the emulated robot lives there)."""
        if deformation_scale is not None:
            self.deformation_scale = deformation_scale
        self._run_start_s = t_s
        self._heater_off_s = heater_off_s
        self._build_truth(self.settings.scheduler.procedure if procedure is None else procedure)

    def align_spot(self) -> None:
        """The spot aligned where the robot is now."""
        if self._robot_pose is not None:
            self.attach_robot(self._robot_pose)

    def _set_heaters(self, on: bool) -> None:
        watts = self.settings.bench.heater_power_w * self.settings.bench.truth_heat_scale
        self.model.set_heat({node: watts for node in self.network.heater_nodes} if on else {})
        self._heaters_on = on

    def advance_to(self, t_s: float) -> None:
        """Bring the truth to bench time ``t_s`` (on the TRUTH_STEP_S grid; never backwards),
        switching the heaters at their own times exactly and holding a drifting room's
        temperature for AMBIENT_STEP_S at a time (its value at the middle of the hold)."""
        run_s = max(t_s - self._run_start_s, 0.0)
        target = math.floor(run_s / TRUTH_STEP_S + 1e-9) * TRUTH_STEP_S
        switches = [self.settings.bench.heater_on_delay_s, self._truth_off_s()]
        while True:
            now = self.model.time_s
            due = self._heaters_due(now)
            if due != self._heaters_on:
                self._set_heaters(due)
            if now >= target:
                return
            stop = min([target, *(s for s in switches if s is not None and now < s < target)])
            if self._ambient_varies:
                stop = min(stop, (math.floor(now / AMBIENT_STEP_S + 1e-9) + 1) * AMBIENT_STEP_S)
                self.model.set_ambient(self.ambient_at(self._run_start_s + (now + stop) / 2))
            self.model.advance_to(stop)

    # --- ground truth ---

    def true_deformation_um(self, t_s: float) -> NDArray[np.float64]:
        """The links' true deformation (µm, world x, y, z) at bench time ``t_s``: unscaled
        ground truth, zero at the start of the run."""
        self.advance_to(t_s)
        return np.asarray(self.model.deformation_um(), dtype=np.float64)

    def temperatures_at(self, positions_mm: NDArray[np.float64], t_s: float) -> NDArray[np.float64]:
        """True temperatures (degC) along the link at ``positions_mm``, interpolated."""
        self.advance_to(t_s)
        order = np.argsort(self.network.positions_mm)
        return np.interp(
            positions_mm,
            self.network.positions_mm[order],
            self.model.temperatures_c[order],
        )

    def stand_drift_um(self, t_s: float) -> float:
        """Camera-stand warm-up drift along chip x (µm), first order (thesis 4.8), with this
        seed's amplitude and time constant."""
        lag = 1.0 - math.exp(-max(t_s, 0.0) / self.stand_drift_tau_s)
        return self.stand_drift_amplitude_um * lag

    def robot_offset_um(self) -> NDArray[np.float64]:
        """The robot's actual position minus where it started (µm, world x, y, z)."""
        if self._robot_pose is None:
            return np.zeros(3)
        position = np.asarray(self._robot_pose()[:3], dtype=np.float64)
        return (position - self._robot_start) * 1000.0

    def spot_offset_um(self, t_s: float) -> tuple[float, float]:
        """Where physics puts the spot on the chip relative to its start (µm, chip x, y)."""
        world = self.deformation_scale * self.true_deformation_um(t_s) + self.robot_offset_um()
        return float(world[0]) + self.stand_drift_um(t_s), -float(world[2])

    def spot_centre_px(self, t_s: float) -> tuple[float, float]:
        """The spot's centre on the chip (x = column, y = row), starting at the chip's centre."""
        camera, bench = self.settings.camera, self.settings.bench
        x_um, y_um = self.spot_offset_um(t_s)
        if bench.camera_rotation_deg != 0.0 or bench.camera_scale != 1.0:
            # The optics image the spot's motion turned and magnified (bench.camera_rotation_deg,
            # camera_scale: what `calibrate camera` recovers); the stand moves the chip itself.
            drift_um = self.stand_drift_um(t_s)
            u_um, v_um = x_um - drift_um, y_um
            angle = math.radians(bench.camera_rotation_deg)
            cos, sin = math.cos(angle), math.sin(angle)
            x_um = bench.camera_scale * (cos * u_um - sin * v_um) + drift_um
            y_um = bench.camera_scale * (sin * u_um + cos * v_um)
        pitch_x, pitch_y = camera.pixel_pitch_um
        return (
            (camera.width_px - 1) / 2.0 + x_um / pitch_x,
            (camera.height_px - 1) / 2.0 + y_um / pitch_y,
        )
