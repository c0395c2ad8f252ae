"""``thermocomp budget`` at work (issue 32): the configured set-up's error budget, its rows from
the pure core (daemon/analysis/budget*.py), the expected deformation from the controller's
model, the measured rows from daemon/commands/budget_record.py's recordings.

The two-link bench: ΔL is the controller's network at its steady state under the configured
heat (thesis 4.2's "expected steady state deformation"); the diode's hole grows with that
state's temperature at the spot's node. An arm: ΔL is the tool drift the arm model predicts at
each measured pose after a run of the configured length (``scheduler.duration_s`` x
``compensation.time_scale`` of the duty cycle from cold), the largest over the poses.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import math
import sys
import tomllib
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from config import CONFIG_DIR, ConfigError, Settings, load_settings
from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from daemon.analysis.budget import COVERAGE, Budget, PoseBudget, Source
from daemon.analysis.budget_arm import (
    drift_sigma_um,
    model_uncertainty,
    predicted_measurement,
    tool_drifts_um,
)
from daemon.analysis.budget_bench import (
    SpotSetup,
    bending_source,
    camera_drift_source,
    diode_hole_source,
    heating_pad_source,
    ir_source,
    misalignment_sources,
    recording_sources,
)
from daemon.arm.arm_model import (
    ArmModelError,
    ArmModelNotFoundError,
    load_arm_model,
    named_arm_model_path,
)
from daemon.arm.controller import ArmModelOptions
from daemon.arm.controller_loading import load_controller
from daemon.commands.budget_record import Recordings, record
from daemon.model import NetworkError, load_network, steady_state_c
from daemon.run.arm.setup import arm_file
from daemon.run.setup import resolve_heat
from daemon.storage.budgets import save_budget
from daemon.vision.cameras import load_cameras
from drivers.errors import DeviceError
from drivers.sim.arm_markers import CameraRig
from drivers.sim.devices import DEFAULT_REGION_WIDTH_PX, LINK_ROWS

if TYPE_CHECKING:
    from daemon.arm.run import MeasuredPose

PROG = "thermocomp budget"
DEFAULT_SETUP = CONFIG_DIR / "budget" / "thesis-two-link.toml"


class BudgetError(Exception):
    """The budget cannot be made (a bad set-up file, an arm with no duty cycle); ``str()`` is
    the one line for the user."""


def load_setup(path: Path | None) -> SpotSetup:
    """A set-up file's facts over :class:`SpotSetup`'s (the thesis's); unknown keys, wrong
    types and non-positive lengths are refused naming the key."""
    chosen = DEFAULT_SETUP if path is None else path
    try:
        data = tomllib.loads(chosen.read_text(encoding="utf-8"))
    except OSError as err:
        raise BudgetError(f"{chosen}: cannot read: {err.strerror or err}") from err
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise BudgetError(f"{chosen}: not valid TOML: {err}") from err
    fields = {f.name: f for f in dataclasses.fields(SpotSetup)}
    values: dict[str, Any] = {}
    for key, value in data.items():
        if key not in fields:
            raise BudgetError(f"{chosen}: {key}: unknown key; known: {', '.join(fields)}")
        default = getattr(SpotSetup(), key)
        if isinstance(default, bool | str):
            if type(value) is not type(default):
                raise BudgetError(f"{chosen}: {key}: expected a {type(default).__name__}")
        elif isinstance(value, bool) or not isinstance(value, int | float):
            raise BudgetError(f"{chosen}: {key}: expected a number")
        elif not math.isfinite(value) or value < 0 or (value == 0 and key.endswith("_mm")):
            raise BudgetError(f"{chosen}: {key}: must be a finite positive number, got {value}")
        values[key] = float(value) if isinstance(default, float) else value
    return dataclasses.replace(SpotSetup(), **values)


# --- the two-link bench ----------------------------------------------------------------------


def _ir_pixels(settings: Settings) -> int:
    regions = settings.ir.regions
    if regions:
        return min(region.width * region.height for region in regions)

    return DEFAULT_REGION_WIDTH_PX * (LINK_ROWS[1] - LINK_ROWS[0])


def bench_budget(
    settings: Settings,
    setup: SpotSetup,
    target_um: float,
    recordings: Recordings | None,
    why_not: str,
) -> Budget:

    network = load_network(settings.model.network, settings.storage.data_dir)
    heat, heat_source = resolve_heat(settings, None, network)
    ambient = settings.model.ambient_c
    temperatures = steady_state_c(network, network.heat_by_name(heat), ambient)
    references = settings.model.reference_nodes or network.reference_nodes
    weights = network.deformation_weights_um_per_c(references)
    expected = float(weights @ (temperatures - ambient))
    near, spot = (network.node_index(name) for name in references)
    rise = float(temperatures[spot] - ambient)
    alpha = float(network.alpha_per_c[spot])
    length_mm = abs(float(network.positions_mm[spot] - network.positions_mm[near]))
    sources: list[Source] = [
        bending_source(setup),
        *misalignment_sources(setup, expected),
        diode_hole_source(setup, alpha, rise),
    ]
    if setup.heating_pads and network.heater_nodes:
        sources.append(heating_pad_source())
    scatter = recordings.scatter if recordings else None
    drift = recordings.drift if recordings else None
    sources += recording_sources(scatter, 0, why_not)
    sources.append(camera_drift_source(drift, why_not))
    used = (
        "model+ir: the observer's input"
        if settings.model.prediction == "model+ir"
        else ("the cte analysis and identification use them; the open-loop model does not")
    )
    sources.append(ir_source(alpha, length_mm, settings.ir.noise_c, _ir_pixels(settings), used))
    return Budget(
        setup=f"{setup.name}, network {network.name}",
        expected_um=expected,
        expected_basis=f"steady state of the controller's model, heat from {heat_source}: "
        + ", ".join(f"{node} {watts:g} W" for node, watts in heat.items()),
        target_um=target_um,
        sources=tuple(sources),
        notes=_recording_notes(recordings, settings),
    )


def _recording_notes(recordings: Recordings | None, settings: Settings) -> tuple[str, ...]:
    notes = []
    if recordings is not None and recordings.why_not:
        notes.append(recordings.why_not)
    if recordings is not None and settings.bench.enabled:
        notes.append("recorded on the simulated bench with its heaters off, on its own clock")
    return tuple(notes)


# --- an arm ----------------------------------------------------------------------------------


def configured_cameras(settings: Settings, poses: Sequence[MeasuredPose]) -> tuple[Any, ...]:
    """The arm's camera models without opening a device: the camera file's, else on the arm
    bench its rig at each measured pose as drivers/sim/arm_devices.py sets it up (aimed at the
    controller's tool pose there, which is the truth's to a fraction of a millimetre)."""
    if settings.arm.cameras_file is not None:
        return tuple(load_cameras(settings.arm.cameras_file))
    if not settings.bench.enabled:
        return ()

    rig = CameraRig(count=settings.arm.cameras)
    return tuple(camera for pose in poses for camera in rig.cameras(pose.tool_pose[:3, 3]))


def _not_applicable(key: str, name: str, section: str, why: str) -> Source:
    return Source(key, name, section, "not applicable", None, why, "-", why)


def arm_budget(
    settings: Settings,
    target_um: float,
    *,
    arm_model: str | None,
    data_dir: Path,
    recordings: Recordings | None,
    why_not: str,
) -> Budget:

    if settings.arm.duty_cycle is None:
        raise BudgetError("an arm's budget needs its duty cycle: set arm.duty_cycle")
    end_s = settings.scheduler.duration_s * settings.compensation.time_scale
    options = ArmModelOptions(
        motion_dt_s=settings.arm.motion_dt_s,
        ambient_c=settings.model.ambient_c,
        bending=settings.arm.bending,
        motor_side_share=settings.arm.motor_side_share,
        model_dt_s=end_s,
    )
    identified = None
    if arm_model is not None:
        path = Path(arm_model)
        if not path.is_file():
            path = named_arm_model_path(arm_model, data_dir)
        identified = load_arm_model(path)
    controller = load_controller(arm_file(settings), settings.arm.duty_cycle, options, identified)
    poses = controller.measured_poses(settings.arm.measured_poses)
    drifts = tool_drifts_um(
        controller.arm,
        controller.duty,
        poses,
        end_s=end_s,
        options=options,
        identified=identified,
        heat=controller.heat,
    )
    expected = np.linalg.norm(drifts, axis=1)
    recorded_models = recordings.camera_models if recordings is not None else ()
    models = recorded_models or configured_cameras(settings, poses)
    markers = np.array(settings.arm.markers_mm, dtype=np.float64)
    frames = settings.arm.frames_per_measurement
    reference = settings.arm.reference_frames or frames
    uncertainty = (
        model_uncertainty(
            controller.arm,
            controller.duty,
            poses,
            end_s=end_s,
            options=options,
            identified=identified,
        )
        if identified is not None
        else None
    )
    rows = []
    for index, pose in enumerate(poses):
        predicted = predicted_measurement(models, markers, pose.tool_pose) if models else None
        sigma = (
            None
            if predicted is None or predicted.sigma_mm is None
            else COVERAGE * drift_sigma_um(predicted.sigma_mm, frames, reference)
        )
        rows.append(
            PoseBudget(
                pose=pose.name,
                expected_um=float(expected[index]),
                measurement_um=sigma,
                model_um=None if uncertainty is None else COVERAGE * uncertainty.sigma_um[index],
                cameras_seeing=None if predicted is None else predicted.cameras_seeing,
            )
        )
    worst = max(rows, key=lambda r: r.measurement_um or 0.0) if rows else None
    cameras = f"{len(models)} cameras" if models else "no camera models"
    held = ""
    if recordings is not None and recordings.scatter is not None:
        still = recordings.scatter
        held = (
            f"; checked where the robot is held: one measurement's scatter "
            f"{still.std_um[0]:.3g} µm over {still.frames} frames, the fit's own 1-sigma "
            f"{still.bound_um[0]:.3g} µm"
        )
    sources: list[Source] = [
        Source(
            key="measurement-3d",
            name="3-D measurement (cameras, markers)",
            section="7.2.2",
            evidence="model" if worst and worst.measurement_um is not None else "not quantified",
            delta_l_um=None if worst is None else worst.measurement_um,
            effect="the centroids' noise through the cameras' geometry and the marker layout",
            remedy="more or closer cameras at wider angles, a wider marker layout, more frames "
            "per measurement (arm.frames_per_measurement, arm.reference_frames)",
            basis=(
                f"worst pose {worst.pose}: {len(markers)} markers in {cameras}, each camera's "
                f"pixel_sigma_px, {frames} frame(s) per measurement and {reference} for the "
                f"reference, x {COVERAGE:g}{held}"
                if worst and worst.measurement_um is not None
                else f"no pose measurable from {cameras}"
            ),
        ),
    ]
    if uncertainty is not None and identified is not None:
        at = int(np.argmax(uncertainty.sigma_um)) if uncertainty.sigma_um else 0
        shares = ", ".join(
            f"{name} {COVERAGE * values[at]:.3g}"
            for name, values in sorted(
                uncertainty.contributions_um.items(), key=lambda item: -item[1][at]
            )
        )
        sources.append(
            Source(
                key="model-parameters",
                name="Identified model's parameters",
                section="-",
                evidence="model",
                delta_l_um=COVERAGE * max(uncertainty.sigma_um, default=0.0),
                effect="the compensation follows a model known to its parameters' errors",
                remedy="identify on a longer or more varied run; validate on another "
                "(`identify --validate`)",
                basis=f"arm model {identified.name}, worst pose {poses[at].name}: "
                f"{shares or 'no parameter with a standard error'} µm",
            )
        )
    scatter = recordings.scatter if recordings else None
    drift = recordings.drift if recordings else None
    sources += recording_sources(
        scatter, 0, why_not, centroid=False, along="of the tool's position"
    )
    sources.append(camera_drift_source(drift, why_not))
    reason = "a 3-D measurement sees every component: no projection to be short of"
    sources += [
        _not_applicable("misalignment", "Link misalignment", "4.4", reason),
        _not_applicable(
            "bending",
            "Cantilever bending",
            "4.3",
            "gravity's sag is in the taught pose and its reference alike (the model's thermal "
            "bending is in the expected drift)",
        ),
        _not_applicable("diode-hole", "Expansion of the diode hole", "4.5", "no diode: markers"),
    ]
    largest = int(np.argmax(expected)) if len(expected) else 0
    return Budget(
        setup=f"arm {controller.arm.name}, duty cycle {controller.duty.name}, {cameras}",
        expected_um=float(expected[largest]) if len(expected) else 0.0,
        expected_basis=f"the arm model's tool drift after {end_s:g} s of the duty cycle from "
        f"cold, largest at pose {poses[largest].name if poses else '-'}"
        + (f", arm model {identified.name}" if identified else ", the preset's model"),
        target_um=target_um,
        sources=tuple(sources),
        poses=tuple(rows),
        notes=_recording_notes(recordings, settings),
    )


# --- saved budgets (the API serves the latest) ----------------------------------------------


def live_budget(settings: Settings, target_um: float | None) -> Budget:
    """The budget the daemon can make without its devices (the API's): the analytic and
    model rows; the measured ones say how to get them."""
    why = "not recorded here: `thermocomp budget --save` records it and the API then serves it"
    target = target_um or settings.compensation.target_um
    if settings.arm.enabled:
        return arm_budget(
            settings,
            target,
            arm_model=None,
            data_dir=settings.storage.data_dir,
            recordings=None,
            why_not=why,
        )
    return bench_budget(settings, load_setup(None), target, None, why)


# --- the command -----------------------------------------------------------------------------


def make_budget(settings: Settings, args: argparse.Namespace) -> Budget:

    target = args.target or settings.compensation.target_um
    arm = settings.arm.enabled
    recordings: Recordings | None = None
    why_not = "not recorded (--no-record)"
    if not args.no_record:
        recordings = asyncio.run(
            record(
                settings,
                drift_s=args.drift_s,
                drift_frames=args.drift_frames,
                stationary_s=args.stationary_s,
                stationary_frames=args.stationary_frames,
            )
        )
        why_not = recordings.why_not or "not measured"
    if arm:
        data_dir = args.data_dir or settings.storage.data_dir
        return arm_budget(
            settings,
            target,
            arm_model=args.arm_model,
            data_dir=data_dir,
            recordings=recordings,
            why_not=why_not,
        )
    return bench_budget(settings, load_setup(args.setup), target, recordings, why_not)


def run_budget(args: argparse.Namespace) -> int:

    settings = load_settings(args.config)
    try:
        budget = make_budget(settings, args)
    except (BudgetError, NetworkError, ArmModelError, ArmModelNotFoundError, ValueError) as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_USAGE
    except ConfigError:
        raise
    except DeviceError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_FAILURE
    if args.save:
        data_dir = args.data_dir or settings.storage.data_dir
        try:
            where = save_budget(data_dir, budget, recorded=not args.no_record)
        except OSError as err:
            print(f"{PROG}: cannot save in {data_dir}: {err.strerror or err}", file=sys.stderr)
            return EXIT_FAILURE
        print(f"# saved as {where} (GET /api/v1/budget serves it)", file=sys.stderr)
    if args.json:
        print(json.dumps(budget.to_dict(), indent=2))
    else:
        print(budget.to_text())
    return EXIT_OK if budget.resolves else EXIT_FAILURE
