"""What a run is built from before its first step: the thermal model, the IR observer, the
admissible-scale check (thesis 6.3) and the network snapshot recorded with the run."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from config import Settings
from config.settings import IrRegion
from daemon.model import ThermalModel, ThermalNetwork, load_network
from daemon.model.adaptation import adapted_parameters
from daemon.model.compensation import (
    CONSOLE_RESOLUTION_MM,
    MAX_INCREMENT_LOSS_FRACTION,
    check_scale,
    incremental_rounding,
    max_admissible_scale,
    smallest_working_scale,
)
from daemon.model.model import EXACT_NODE_LIMIT
from daemon.model.observer import IrObserver, regions_to_nodes
from daemon.recorder import Recorder
from daemon.runs import RunParameters, heat_at

#: Final states of a run whose recorded drift can serve as a reference (it ran, in part or
#: whole, and its steps are committed).
REFERENCE_STATES = ("finished", "stopped")
SECONDS_PER_HOUR = 3600.0
#: The incremental-mode check follows at most this many steps (a few seconds of model steps).
MAX_CHECKED_STEPS = 200_000


class RunParameterError(ValueError):
    """The run's parameters are not admissible (e.g. scale pushes the spot off the chip)."""


def build_model(
    settings: Settings, parameters: RunParameters
) -> tuple[ThermalNetwork, ThermalModel]:
    """The controller's thermal model of the run's network (thesis 5.4), stepped at the run's
    step in model time."""
    try:
        network = load_network(parameters.network)
    except (ValueError, OSError) as err:
        raise RunParameterError(f"network {parameters.network!r}: {err}") from err
    check_heat_nodes(parameters.heat_w, network)
    model_settings = settings.model
    try:
        model = ThermalModel(
            network,
            stepper=model_settings.stepper,
            dt_s=parameters.step_s * parameters.time_scale,
            ambient_c=model_settings.ambient_c,
            reference_nodes=model_settings.reference_nodes,
            direction=model_settings.direction,
            allow_substeps=True,
        )
    except ValueError as err:
        raise RunParameterError(f"network {parameters.network!r}: {err}") from err
    return network, model


def check_heat_nodes(heat_w: Mapping[str, float], network: ThermalNetwork) -> None:
    """Every heat input must name a node of the run's network (by name, or by its 1-based
    number): a key naming no node would otherwise fail the run at its first step, after the
    goal was taught (issue 19)."""
    for node in heat_w:
        try:
            network.node_index(node)
        except ValueError as err:
            raise RunParameterError(f"heat_w: {err}") from err


def build_observer(
    settings: Settings, model: ThermalModel, reader_regions: Sequence[IrRegion]
) -> IrObserver:
    """The IR Kalman filter of a model+ir run (issue 9): the regions tied to model nodes
    (the reader's own, else the configured ones), each with the noise of its mean."""
    ir_settings = settings.ir
    regions = tuple(reader_regions) or ir_settings.regions
    tied = [region for region in regions if region.node]
    if not tied:
        raise RunParameterError("prediction model+ir needs IR regions tied to model nodes")
    noise = {r.name: ir_settings.noise_c / math.sqrt(r.width * r.height) for r in tied}
    observer = settings.observer
    if not observer.adapt:
        return IrObserver(model, regions_to_nodes(tied), noise)
    try:
        adapted = adapted_parameters(
            model.network,
            observer.adapt_parameters,
            {name: (1.0, observer.prior_sigma) for name in observer.adapt_parameters},
        )
    except ValueError as err:
        raise RunParameterError(f"observer.adapt_parameters: {err}") from err
    return IrObserver(
        model,
        regions_to_nodes(tied),
        noise,
        adapt=adapted,
        parameter_random_walk=observer.random_walk_per_hour**2 / SECONDS_PER_HOUR,
    )


def check_admissible_scale(
    settings: Settings,
    parameters: RunParameters,
    network: ThermalNetwork,
    direction: NDArray[np.float64],
) -> None:
    """Thesis 6.3: the scaled deformation must stay on the camera chip."""
    largest = largest_predicted_deformation_um(settings, parameters, network)
    camera = settings.camera
    extent = (camera.width_px * camera.um_per_px[0], camera.height_px * camera.um_per_px[1])
    try:
        check_scale(
            parameters.deformation_scale,
            largest,
            direction.tolist(),
            extent,
            settings.compensation.spot_size_um,
        )
    except ValueError as err:
        raise RunParameterError(str(err)) from err
    if parameters.compensation == "incremental":
        limit = max_admissible_scale(
            largest, direction.tolist(), extent, settings.compensation.spot_size_um
        )
        check_incremental_resolution(settings, parameters, network, direction, limit)


def check_incremental_resolution(
    settings: Settings,
    parameters: RunParameters,
    network: ThermalNetwork,
    direction: NDArray[np.float64],
    largest_admissible_scale: float,
) -> None:
    """Thesis 6.3: refuse an incremental run whose moves the console's 0.001 mm would mostly
    round away (issue 19: at a 1 s step the robot never moved), naming the whole scale that
    would work at this step, or saying that none on the chip does."""
    predicted = step_deformations_um(settings, parameters, network) * direction
    rounding = incremental_rounding(predicted, parameters.deformation_scale)
    if rounding.admissible:
        return
    working = smallest_working_scale(predicted, largest_admissible_scale)
    remedy = (
        f"deformation scale {working} would work"
        if working is not None
        else f"no scale the camera chip admits (up to {largest_admissible_scale:.1f}) works: "
        "use a longer step or absolute compensation"
    )
    raise RunParameterError(
        f"incremental compensation at a {parameters.step_s:g} s step and deformation scale "
        f"{parameters.deformation_scale:g}: the console rounds every move to "
        f"{CONSOLE_RESOLUTION_MM} mm; {rounding.lost_steps} of the run's {rounding.steps} "
        f"moves (largest {rounding.largest_move_um:.3f} um) would round to no motion, and the "
        f"rounding would leave {rounding.largest_error_um:.1f} um of the "
        f"{rounding.largest_deformation_um:.1f} um scaled deformation uncompensated "
        f"({100 * rounding.loss_fraction:.0f} %, more than "
        f"{100 * MAX_INCREMENT_LOSS_FRACTION:.0f} %); {remedy}"
    )


def step_deformations_um(
    settings: Settings, parameters: RunParameters, network: ThermalNetwork
) -> NDArray[np.float64]:
    """The deformation (µm, along the link) the model expects at each step of the run, at
    most :data:`MAX_CHECKED_STEPS` of them (the first)."""
    steps = min(parameters.step_count, MAX_CHECKED_STEPS)
    model = ThermalModel(
        network,
        stepper="exact" if network.node_count <= EXACT_NODE_LIMIT else "implicit",
        dt_s=parameters.step_s * parameters.time_scale,
        ambient_c=settings.model.ambient_c,
        reference_nodes=settings.model.reference_nodes,
    )
    values = np.zeros(steps)
    for k in range(1, steps):
        model.set_heat(heat_at(parameters, (k - 1) * parameters.step_s))
        model.advance_to(k * parameters.step_s * parameters.time_scale)
        values[k] = model.deformation_um_scalar()
    return values[:, None]


def largest_predicted_deformation_um(
    settings: Settings, parameters: RunParameters, network: ThermalNetwork, samples: int = 400
) -> float:
    """The largest |deformation| the model predicts over the run (for the scale check)."""
    model = ThermalModel(
        network,
        stepper="exact" if network.node_count <= EXACT_NODE_LIMIT else "implicit",
        dt_s=parameters.duration_s * parameters.time_scale / samples,
        ambient_c=settings.model.ambient_c,
        reference_nodes=settings.model.reference_nodes,
    )
    largest = 0.0
    for k in range(1, samples + 1):
        run_time = parameters.duration_s * k / samples
        model.set_heat(heat_at(parameters, run_time - parameters.duration_s / samples))
        model.advance_to(run_time * parameters.time_scale)
        largest = max(largest, abs(float(model.deformation_um_scalar())))
    return largest


def check_reference_run(recorder: Recorder, parameters: RunParameters) -> None:
    """The run named by ``reference_run`` must be an ended, uncompensated run at the same
    deformation scale: its measured drift is what the summary's reduction compares with
    (issue 19). Blocking (the database): call it on the database worker."""
    reference_id = parameters.reference_run
    if reference_id is None:
        return
    row = recorder.run(reference_id)
    if row is None:
        raise RunParameterError(f"reference_run {reference_id}: no such run")
    if row.state not in REFERENCE_STATES:
        raise RunParameterError(
            f"reference_run {reference_id} is {row.state}: a reference must have ended "
            f"({' or '.join(REFERENCE_STATES)})"
        )
    compensation = row.parameters.get("compensation")
    if compensation != "off":
        raise RunParameterError(
            f"reference_run {reference_id} was compensated ({compensation}): a reference "
            "must be an uncompensated run (compensation off) measuring the drift"
        )
    scale = row.parameters.get("deformation_scale", 1.0)
    if not math.isclose(float(scale), parameters.deformation_scale):
        raise RunParameterError(
            f"reference_run {reference_id} ran at deformation scale {scale}, this run at "
            f"{parameters.deformation_scale}: their drifts are not comparable"
        )


def unit_vector(vector: tuple[float, float, float]) -> NDArray[np.float64]:
    array = np.asarray(vector, dtype=np.float64)
    norm = float(np.linalg.norm(array))
    if not math.isfinite(norm) or norm == 0:
        raise RunParameterError(f"model.direction must be a non-zero vector, not {vector}")
    return array / norm


def network_snapshot(network: ThermalNetwork) -> dict[str, Any]:
    """The network as recorded with the run (the model it was compensated with)."""
    return {
        "name": network.name,
        "node_names": list(network.node_names),
        "positions_mm": network.positions_mm.tolist(),
        "capacitance_j_per_c": network.capacitance_j_per_c.tolist(),
        "alpha_per_c": network.alpha_per_c.tolist(),
        "r_ambient_c_per_w": [_finite_or_none(v) for v in network.r_ambient_c_per_w.tolist()],
        "r_end_c_per_w": [_finite_or_none(v) for v in network.r_end_c_per_w.tolist()],
        "resistances": [[r.a, r.b, r.r_c_per_w] for r in network.resistances],
        "reference_nodes": list(network.reference_nodes),
        "heater_nodes": list(network.heater_nodes),
        "direction": network.direction.tolist(),
    }


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None
