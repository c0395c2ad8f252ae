"""The controller's model of the arm during a duty cycle (issue 20): the ArmPredictor of an arm
run (daemon/run/arm/step.py). Pure.

Each advance takes the motor heat of the duty cycle's *commanded* motion over the interval
(the duty cycle's joint positions, speeds and accelerations on ``motion_dt_s``, the joint
torques they need, each joint's motor and gearbox losses: daemon/arm/motors.py, integrated
once per cycle by daemon/arm/heat.py JointHeatProfile), holds its mean power over the
interval (a zero-order hold of the interval's mean: it carries the interval's energy
exactly) and advances the arm's thermal network (daemon/arm/thermal.py). The tool error at
a measured pose is kinematics.tool_error at that pose's joint angles with the links' current
thermal states.

With an identified arm model (daemon/arm/arm_model.py, ``--arm-model NAME``) each joint's heat,
the convection and the links' expansion are the model's factors (1.0, the preset's, where not
identified). ``model+ir`` estimates from the IR what it can see (:meth:`ArmController.observe`);
a UR's joint temperatures go through a Kalman filter (:meth:`ArmController.attach_observer`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from daemon.arm.adaptation import (
    ArmAdaptation,
    adapted_names,
    ir_observed_names,
)
from daemon.arm.arm_model import ArmModel, check_fits
from daemon.arm.arm_network import describe_arm
from daemon.arm.controller_priors import (
    DEFAULT_OFFSET_SIGMA_C,
    adaptation_priors,
    observer_adapted,
)
from daemon.arm.description import Arm
from daemon.arm.duty import DutyCycle
from daemon.arm.goal_names import goal_names
from daemon.arm.heat import HeatSource, JointHeatProfile
from daemon.arm.identify_response import factored_description
from daemon.arm.ir_regions import region_nodes
from daemon.arm.kinematics import forward, tool_error, tool_errors
from daemon.arm.response import ArmModelSpec, marker_sensitivity
from daemon.arm.run import CyclePose, FloatArray, MeasuredPose
from daemon.arm.thermal import ArmThermalModel
from daemon.arm.types import LinkThermalState, Pose6
from daemon.model.adaptation import adapted_parameters
from daemon.model.observer import IrObserver

#: The prior 1-sigma (a log factor's, or a share's) of a factor the IR estimate holds at the
#: model's value (ArmController._ir_unknowns).
HELD_SIGMA = 1e-4
#: The adaptation's heat record step (s of arm time; identification's IDENTIFY_STEP_S).
ADAPTATION_STEP_S = 20.0


@dataclass(frozen=True, slots=True)
class ArmModelOptions:
    motion_dt_s: float = 0.05  # the duty cycle's motion samples for motor heat (s)
    ambient_c: float = 22.0
    bending: bool = False
    #: with ``bending``: the motor housings' side of each link (arm_network.describe_arm's
    #: ``plus_share``); the model then resolves the temperature across each link
    motor_side_share: float = 0.5
    node_spacing_mm: float = 50.0
    model_dt_s: float = 1.0  # the thermal model's step (its stepper is exact: any dt)


class ArmController:
    """The arm's model advanced by the duty cycle's motion (module docstring)."""

    def __init__(
        self,
        arm: Arm,
        duty: DutyCycle,
        options: ArmModelOptions = ArmModelOptions(),
        *,
        heat: HeatSource | None = None,
        thermal: ArmThermalModel | None = None,
        identified: ArmModel | None = None,
    ) -> None:
        self.arm = arm
        self.duty = duty
        self.options = options
        self.identified = identified
        joints = len(arm.joints)
        self.heat_scales: FloatArray = np.ones(joints)
        self.alpha_scale = 1.0
        convection = 1.0
        if identified is not None:
            check_fits(identified, identified.arm, joints)  # the arm's name: by the caller
            self.heat_scales = np.array(identified.heat_scales, dtype=np.float64)
            self.alpha_scale = identified.alpha_scale
            convection = identified.convection_scale
        #: the motor heat (the duty cycle's; a followed run's measured motion: a HeatSource)
        self.heat: HeatSource = heat or JointHeatProfile.from_duty(
            arm, duty, resolution_s=options.motion_dt_s
        )
        description = describe_arm(arm, plus_share=options.motor_side_share)
        if identified is not None:  # issue 29: identified capacity and bending shares
            description = factored_description(
                description, identified.capacity_scale, identified.bending_shares or None
            )
        self.thermal = thermal or ArmThermalModel(
            description if options.bending or identified is not None else arm,
            across_link=options.bending,
            node_spacing_mm=options.node_spacing_mm,
            ambient_c=options.ambient_c,
            dt_s=options.model_dt_s,
            convection_scale=convection,
        )
        self.last_heat_w: FloatArray = np.zeros(joints)
        self.observer: IrObserver | None = None
        self._observer_args: tuple[dict[str, Sequence[int]], float, float, float] = ({}, 0, 0, 0)
        self._observer_noise_c: float | None = None
        self.description = description
        self.adaptation: ArmAdaptation | None = None
        self._adapt_poses: dict[str, int] = {}
        self._adapt_sensitivities: list[FloatArray] = []
        self._adapted_links: tuple[float, tuple[LinkThermalState, ...]] | None = None
        #: the room thermometer's last two readings (degC): the ambient of the next advance
        #: is their mean (follow_room); None: no thermometer, options.ambient_c throughout
        self._room_last: float | None = None
        self._room_next: float | None = None
        #: the ambient the model held over each advance: (start s, end s, degC), for the
        #: adaptation's record of the air (it follows the room as the model does)
        self._ambient_held: list[tuple[float, float, float]] = []
        self._ambient_start_c = options.ambient_c

    def attach_observer(
        self,
        regions: Mapping[str, Sequence[int]],
        ir_noise_c: float,
        offset_sigma_c: float = DEFAULT_OFFSET_SIGMA_C,
        initial_sigma_c: float = 0.0,
    ) -> IrObserver:
        """A Kalman filter on the model's nodes fed by the IR regions (``regions``: each
        region's node indices, daemon/arm/ir_regions.py), from the identified offsets with
        their 1-sigma as prior (the largest over the regions; ``offset_sigma_c`` when the
        model gives none); ``initial_sigma_c``: the nodes' own prior (0: the model's start is
        exact)."""
        self._observer_args = (dict(regions), ir_noise_c, offset_sigma_c, initial_sigma_c)
        names = self.thermal.node_names
        offsets: Mapping[str, float] = {}
        sigma = offset_sigma_c
        if self.identified is not None and self.identified.ir_offsets_c:
            offsets = self.identified.ir_offsets_c
            sigmas = [self.identified.ir_offset_sigma_c.get(r, np.inf) for r in regions]
            largest = max(sigmas, default=np.inf)
            sigma = float(largest) if np.isfinite(largest) else DEFAULT_OFFSET_SIGMA_C
        model = self.thermal.thermal_model
        self.observer = IrObserver(
            model,
            {region: tuple(names[i] for i in group) for region, group in regions.items()},
            ir_noise_c,
            offsets_c=offsets,
            offset_sigma_c=sigma,
            initial_sigma_c=initial_sigma_c,
            adapt=adapted_parameters(
                model.network, *observer_adapted(self.identified, self.thermal.joint_node_names)
            ),
        )
        return self.observer

    @property
    def time_s(self) -> float:
        return float(self.thermal.time_s)

    # -- online adaptation (issue 29, daemon/arm/adaptation.py) ---------------------------------

    def enable_adaptation(
        self, poses: Sequence[MeasuredPose], marker_sigma_mm: float, ir_noise_c: float
    ) -> None:
        """Adapt the factors online (arm.adapt): the adaptation starts at the first measured
        tool (:meth:`adapt`), with the IR regions of that step, from this model's factors (the
        preset's, or the arm model's with its standard errors) as the prior."""
        self._adapt_poses = {pose.name: k for k, pose in enumerate(poses)}
        self._adapt_sensitivities = [
            marker_sensitivity(self.arm, pose.q_rad, np.zeros((1, 3)), self.options.bending)
            for pose in poses
        ]
        self._adapt_noise = (float(marker_sigma_mm), float(ir_noise_c))

    @property
    def adapting(self) -> bool:
        return bool(self._adapt_poses)

    def adapt(
        self, pose: MeasuredPose, displacement_mm: FloatArray, reading_c: Mapping[str, float]
    ) -> None:
        """One measurement into the adaptation: the tool's thermal displacement at ``pose``
        (measured drift less the correction commanded, mm) and the IR regions' means."""
        if pose.name not in self._adapt_poses:
            return
        if self.adaptation is None:
            regions = region_nodes(self.thermal, reading_c)
            names = adapted_names(len(self.arm.joints), self.options.bending)
            self._new_adaptation(
                regions,
                self._adapt_sensitivities,
                [*names, *(f"offset:{region}" for region in regions)],
                marker_sigma_mm=self._adapt_noise[0],
                temperature_sigma_c=self._adapt_noise[1],
            )
        assert self.adaptation is not None
        self.adaptation.observe(self._adapt_poses[pose.name], displacement_mm, reading_c)
        self._adapted_links = None

    def _feed_adaptation(self, t_s: float) -> None:
        adaptation = self.adaptation
        if adaptation is None:
            return
        while adaptation.time_s + ADAPTATION_STEP_S <= t_s + 1e-9:
            start = adaptation.time_s
            adaptation.add_heat(
                self.mean_heat_w(start, start + ADAPTATION_STEP_S),
                self._ambient_at(start + ADAPTATION_STEP_S / 2.0),
            )

    def _ambient_at(self, t_s: float) -> float:
        """The ambient the model held at ``t_s`` (its start's before the first advance)."""
        for start, end, ambient in reversed(self._ambient_held):
            if start <= t_s <= end:
                return ambient
        return self._ambient_start_c

    def adaptation_estimates(self) -> dict[str, list[float]]:
        """The adapted factors now: name -> [value, 1-sigma] (empty before the first)."""
        if self.adaptation is None:
            return {}
        return {e.name: [e.value, e.sigma] for e in self.adaptation.estimates()}

    def mean_heat_w(self, start_s: float, end_s: float) -> FloatArray:
        """Each joint's mean motor heat (W) over ``[start_s, end_s]`` of the duty cycle."""
        return self.heat.step_power_w(start_s, end_s)

    def follow_room(self, room_c: float) -> None:
        """A reading of the room thermometer, taken now (before the next advance): the arm
        model's ambient follows the room instead of ``options.ambient_c``. The first reading,
        before the model has moved, is the cold arm's temperature and reference (it stood in
        that room); each advance then holds the mean of the readings at its two ends (the
        trapezoid rule: a room changing linearly is followed exactly). The first also sets
        the air the links' radiation is linearised at (ArmThermalModel.start_at)."""
        if not np.isfinite(room_c):
            raise ValueError(f"room temperature must be finite, got {room_c}")
        if self._room_last is None and self.time_s == 0.0:
            model = self.thermal.thermal_model
            self.thermal.start_at(room_c)  # its radiation linearised at this room
            if self.observer is not None and self.thermal.thermal_model is not model:
                self.attach_observer(*self._observer_args)  # on the new network
            self._room_last = room_c
            self._ambient_start_c = room_c
        self._room_next = room_c

    @property
    def follows_room(self) -> bool:
        """Whether a room thermometer's readings drive the model's ambient."""
        return self._room_next is not None

    def advance_to(self, t_s: float) -> None:
        start = self.time_s
        if t_s <= start:
            return
        ambient = self._ambient_held[-1][2] if self._ambient_held else self._ambient_start_c
        if self._room_next is not None:
            last = self._room_next if self._room_last is None else self._room_last
            ambient = 0.5 * (last + self._room_next)
            self.thermal.set_ambient(ambient)
            self._room_last = self._room_next
        self._ambient_held.append((start, t_s, ambient))
        self.last_heat_w = self.mean_heat_w(start, t_s) * self.heat_scales
        self.thermal.advance_to(t_s, self.last_heat_w)
        self._feed_adaptation(t_s)
        if self.observer is not None:  # the covariance follows the model's step
            self.observer.predict(self.thermal.time_s)

    def enable_observer(self, ir_noise_c: float) -> None:
        """Prediction ``model+ir``: from the first IR reading on, the regions it carries that
        name a point of a link (daemon/arm/ir_regions.py) estimate the model's factors
        (:meth:`observe`)."""
        self._observer_noise_c = ir_noise_c

    def observe(self, reading_c: Mapping[str, float]) -> None:
        """An IR reading (region -> mean degC) into the model (no ``model+ir``: nothing).

        The IR estimates what it can see of the model's factors during the run: each joint's
        heat, the convection, the bending share (with regions on both faces of a link next to
        a joint: the temperature across it) and each region's offset, by the adaptation's MAP
        fit (daemon/arm/adaptation.py) on the IR alone, from this model's factors as the
        prior. The compensation then uses the estimated model's links. Why not the Kalman
        filter on the node temperatures (:meth:`attach_observer`): it corrects the
        temperatures it sees, never the share that splits a joint's heat between a link's
        faces, so a wrong share comes back between two readings (issue 29, corner-low truth
        with regions on both faces: 70 % of the drift removed with the filter, 84 % with the
        share estimated). With ``arm.adapt`` the adaptation already takes the IR with the
        tool (:meth:`adapt`): nothing more here. A filter attached explicitly
        (:meth:`attach_observer`: a UR's joint temperatures, daemon/arm/joint_temperatures.py)
        still takes the reading."""
        if self.observer is not None:
            self.observer.update(reading_c)
            return
        if self._observer_noise_c is None or self.adapting:
            return
        if self.adaptation is None:
            regions = region_nodes(self.thermal, reading_c)
            if not regions:
                return
            self.adaptation = self._new_adaptation(
                regions,
                # one pose for the spec's sake: no tool is measured here
                [
                    marker_sensitivity(
                        self.arm, np.zeros(self.arm.dof), np.zeros((1, 3)), self.options.bending
                    )
                ],
                [
                    n
                    for n in adapted_names(len(self.arm.joints), self.options.bending)
                    if n != "alpha"
                ]
                + [f"offset:{region}" for region in regions],
                marker_sigma_mm=1.0,  # no tool measurement: its residuals are all missing
                temperature_sigma_c=self._ir_sigma_c(self._observer_noise_c),
                free=self._ir_unknowns(regions),
            )
        self.adaptation.observe(0, np.full(3, np.nan), reading_c)
        self._adapted_links = None

    def _ir_unknowns(self, regions: Mapping[str, tuple[int, ...]]) -> list[str]:
        """What the IR estimates: what it can see (adaptation.ir_observed_names) that the arm
        model did not identify. An identified factor was fitted to the tool itself; the IR
        alone would move it to what fits the regions, where the model's structure (50-mm
        nodes against the steep temperature by a joint) leaves ~0.2 degC, and the tool would
        pay (issue 29, corner-high task A: identified + IR 95.0 % removed with the identified
        factors re-estimated, 97.3 % with the identified model alone)."""
        names = ir_observed_names(
            len(self.arm.joints), self.options.bending, list(regions), self._region_links(regions)
        )
        known = set()
        if self.identified is not None:
            known = {p.name for p in self.identified.parameters if p.identifiable}
        return [n for n in names if n.startswith("offset:") or n not in known]

    def _region_links(self, regions: Mapping[str, Sequence[int]]) -> list[int]:
        """The indices of the links the IR regions sit on."""
        links = self.thermal.node_links
        names = self.thermal.link_names
        return sorted({names.index(links[i]) for nodes in regions.values() for i in nodes})

    def _ir_sigma_c(self, noise_c: float) -> float:
        """The 1-sigma an IR reading is weighed by against this model: the camera's noise, or
        what the identification's fit left of the regions where that is more (the model's own
        structure: 50-mm nodes against a link's steep temperature by the joint). Without it
        the IR alone pulls an identified model's factors away from what fitted the tool
        (issue 29, corner-high task A: identified + IR 95.0 % removed, identified alone
        97.3 %)."""
        fitted = None if self.identified is None else self.identified.temperature_rms_c
        if fitted is None or not math.isfinite(fitted):
            return noise_c
        return max(noise_c, float(fitted))

    def _new_adaptation(
        self,
        regions: Mapping[str, tuple[int, ...]],
        sensitivities: list[FloatArray],
        names: list[str],
        *,
        marker_sigma_mm: float,
        temperature_sigma_c: float,
        free: Sequence[str] | None = None,
    ) -> ArmAdaptation:
        """An adaptation of ``names`` on this model, fed the heat and the air so far; with
        ``free``, the others are held at this model's values (a prior of HELD_SIGMA: the
        adaptation's model must still carry them, e.g. an identified joint's heat)."""
        priors = {
            k: v
            for k, v in adaptation_priors(
                self.identified, self.heat_scales, self.alpha_scale, regions
            ).items()
            if k in names
        }
        if free is not None:
            priors = {k: (v[0], v[1] if k in free else HELD_SIGMA) for k, v in priors.items()}
            for name in names:
                if name == "share" and name not in free and name not in priors:
                    shares = [joint.plus_share for joint in self.description.joints]
                    priors[name] = (float(np.mean(shares)), HELD_SIGMA)
        spec = ArmModelSpec(
            self.description,
            self.thermal.node_spacing_mm,
            dict(regions),
            sensitivities,
            across_link=self.options.bending,
        )
        adaptation = ArmAdaptation(
            spec,
            ADAPTATION_STEP_S,
            self._ambient_start_c,
            names,
            priors,
            marker_sigma_mm=marker_sigma_mm,
            temperature_sigma_c=temperature_sigma_c,
        )
        self.adaptation = adaptation
        self._feed_adaptation(self.time_s)
        return adaptation

    def link_states(self) -> tuple[LinkThermalState, ...]:
        """The links' thermal states the tool error is computed from (adapted or not)."""
        return self._link_states()

    def _link_states(self) -> tuple[LinkThermalState, ...]:
        adaptation = self.adaptation
        if adaptation is not None and adaptation.updates > 0:  # the adapted model's links
            if self._adapted_links is None or self._adapted_links[0] != adaptation.time_s:
                states = adaptation.link_states()
                if self.alpha_scale != 1.0 and "alpha" not in adaptation.names:
                    # the IR cannot see the expansion: the model's own factor stays
                    states = tuple(
                        dataclasses.replace(s, alpha_per_c=s.alpha_per_c * self.alpha_scale)
                        for s in states
                    )
                self._adapted_links = (adaptation.time_s, states)
            return self._adapted_links[1]
        states = tuple(self.thermal.link_states())
        if self.alpha_scale != 1.0:
            states = tuple(
                dataclasses.replace(s, alpha_per_c=s.alpha_per_c * self.alpha_scale) for s in states
            )
        return states

    def tool_error(self, pose: MeasuredPose) -> Pose6:
        return tool_error(self.arm, pose.q_rad, self._link_states(), bending=self.options.bending)

    def tool_errors(self, poses: Sequence[MeasuredPose]) -> list[Pose6]:
        """The tool error at each of ``poses`` (a played cycle's every pose) for the model's
        current state, the arm warmed once (kinematics.tool_errors)."""
        return tool_errors(
            self.arm,
            [pose.q_rad for pose in poses],
            self._link_states(),
            bending=self.options.bending,
        )

    def temperatures_c(self) -> Mapping[str, float]:
        return dict(zip(self.thermal.node_names, self.thermal.temperatures_c.tolist(), strict=True))

    def measured_poses(self, names: tuple[str, ...] = ()) -> tuple[MeasuredPose, ...]:
        """The duty cycle's measured poses (``names``: these poses instead, in that order),
        each with the cold arm's tool pose at its joint angles."""
        by_name = {pose.name: pose for pose in self.duty.poses}
        if names:
            unknown = [name for name in names if name not in by_name]
            if unknown:
                raise ValueError(
                    f"arm.measured_poses names {unknown}, not poses of the duty cycle "
                    f"({', '.join(by_name)})"
                )
            chosen = [by_name[name] for name in names]
        else:
            chosen = list(self.duty.measured_poses())
        return tuple(
            MeasuredPose(pose.name, np.array(pose.q_rad), forward(self.arm, pose.q_rad))
            for pose in chosen
        )

    def cycle_poses(self, measured: Sequence[MeasuredPose]) -> tuple[CyclePose, ...]:
        """Every pose of the duty cycle in its order, as the robot plays it (daemon/
        arm_player.py): each taught as a goal (a measured pose as its ``measured`` entry, the
        others under a valid goal name made from theirs: :func:`goal_names`), its move's speed
        fraction as the console's whole percentage (at least 1 %), its dwell."""
        by_name = {pose.name: pose for pose in measured}
        names = goal_names([pose.name for pose in self.duty.poses], set(by_name))
        cycle = []
        for taught, goal in zip(self.duty.poses, names, strict=True):
            pose = by_name.get(taught.name) or MeasuredPose(
                goal, np.array(taught.q_rad), forward(self.arm, taught.q_rad)
            )
            percent = min(100, max(1, round(taught.speed * 100.0)))
            cycle.append(
                CyclePose(taught.name, pose, percent, taught.dwell_s, taught.name in by_name)
            )
        return tuple(cycle)


#: A goal name: a letter, then letters, digits or underscores, 14 at most (drivers/goals.py
#: GOAL_NAME; the pure core does not import drivers).
