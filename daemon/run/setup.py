"""What a run is built from before its first step: the thermal model, the IR observer, the
admissible-scale check (thesis 6.3) and the network snapshot recorded with the run."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from config import Settings
from config.inputs import InputError
from config.settings import IrRegion
from daemon.model import ThermalModel, ThermalNetwork, load_network
from daemon.model.adaptation import adaptation_priors, adapted_parameters
from daemon.model.calibration import Calibration
from daemon.model.compensation import (
    CONSOLE_RESOLUTION_MM,
    MAX_INCREMENT_LOSS_FRACTION,
    check_scale,
    incremental_rounding,
    max_admissible_scale,
    smallest_working_scale,
)
from daemon.model.model import EXACT_NODE_LIMIT
from daemon.model.observer import OFFSET_SIGMA_C, IrObserver, regions_to_nodes
from daemon.run.states import RunParameters, heat_at
from daemon.storage.recorder import Recorder, RunRow

logger = logging.getLogger(__name__)

#: Final states of a run whose recorded drift can serve as a reference (it ran, in part or
#: whole, and its steps are committed).
REFERENCE_STATES = ("finished", "stopped")
SECONDS_PER_HOUR = 3600.0
#: The incremental-mode check follows at most this many steps (a few seconds of model steps).
MAX_CHECKED_STEPS = 200_000


class RunParameterError(InputError):
    """The run's parameters are not admissible (e.g. scale pushes the spot off the chip)."""


#: The check of a run's ``reference_run`` (daemon/run/kinds.py check_reference_run): blocking,
#: RunParameterError when the named run is no reference for this one.
ReferenceCheck = Callable[[Recorder, RunParameters], None]


@dataclass(frozen=True)
class BuiltModel:
    """What :func:`build_model` prepares: the parameters with the heat resolved, the network,
    the controller's model, and where the heat came from (recorded with the run)."""

    parameters: RunParameters
    network: ThermalNetwork
    model: ThermalModel
    heat_source: str


def run_network(settings: Settings, name_or_path: str) -> ThermalNetwork:
    """The run's network: a preset, an identified network saved in the data directory (by
    name), or (command line) a file."""
    try:
        return load_network(name_or_path, settings.storage.data_dir)
    except (ValueError, OSError) as err:
        raise RunParameterError(f"network {name_or_path!r}: {err}") from err


def build_model(settings: Settings, parameters: RunParameters) -> BuiltModel:
    """The controller's thermal model of the run's network (thesis 5.4), stepped at the run's
    step in model time, and the run's parameters with its heat resolved (:func:`resolve_heat`)."""
    network = run_network(settings, parameters.network)
    heat, source = resolve_heat(settings, parameters.heat_w, network)
    if heat != parameters.heat_w:  # validated as a request's would be (0 to 1000 W a node)
        try:
            parameters = RunParameters.model_validate({**dict(parameters), "heat_w": heat})
        except ValidationError as err:
            raise RunParameterError(f"heat_w ({source}): {err.errors()[0]['msg']}") from err
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
    return BuiltModel(parameters, network, model, source)


def resolve_heat(
    settings: Settings, override: Mapping[str, float] | None, network: ThermalNetwork
) -> tuple[dict[str, float], str]:
    """The heat a run's model gets while the heaters are on, by node name, and its source
    (issue 19). Precedence: the run's explicit ``heat_w`` (``--heat``, ``"heat_w"`` of
    ``POST /runs``) > the network file's own heat (an identified network's) > the setting
    ``model.heat_w`` > ``model.heater_power_w`` on each of the network's heater nodes. A key
    naming no node of the network refuses the run (one line naming the key and the nodes)."""
    model_settings = settings.model
    own = network.own_heat_w()
    if override is not None:
        heat, source = dict(override), "the run's heat_w"
    elif own:
        heat, source = own, f"network {network.name!r}"
        if model_settings.heat_w:
            logger.warning(
                "model.heat_w (%s) not used: network %r carries its own heat (%s); give the "
                "run's heat_w (--heat) to override it",
                _listed(model_settings.heat_w),
                network.name,
                _listed(own),
            )
    elif model_settings.heat_w:
        heat, source = dict(model_settings.heat_w), "setting model.heat_w"
    else:
        heat = dict.fromkeys(network.heater_nodes, model_settings.heater_power_w)
        source = "setting model.heater_power_w on the heater nodes"
    try:
        network.heat_by_name(heat)
    except ValueError as err:
        raise RunParameterError(f"{err}; heat from {source}") from err
    return heat, source


def _listed(heat: Mapping[str, float]) -> str:
    return ", ".join(f"{node} = {watts:g} W" for node, watts in heat.items()) or "none"


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
    calibration = model.network.calibration
    offsets: dict[str, Any] = {}
    if calibration is not None and calibration.ir_offsets_c:
        # An identified network: the filter starts from the identified IR offsets, with their
        # identified uncertainty as prior (issue 19), instead of 0 +- the FLIR's 2 degC.
        offsets = {
            "offsets_c": calibration.ir_offsets_c,
            "offset_sigma_c": offset_prior_sigma_c(calibration, [r.name for r in tied]),
        }
    observer = settings.observer
    if not observer.adapt:
        return IrObserver(model, regions_to_nodes(tied), noise, **offsets)
    # Online adaptation (issue 19): an identified network's factors are the priors, and the
    # ones its identification could not identify stay as the file has them.
    names, priors = adaptation_priors(calibration, observer.adapt_parameters, observer.prior_sigma)
    skipped = [name for name in observer.adapt_parameters if name not in names]
    if skipped:
        logger.info(
            "observer.adapt: %s not identifiable in network %r, not adapted",
            ", ".join(skipped),
            model.network.name,
        )
    try:
        adapted = adapted_parameters(model.network, names, priors)
    except ValueError as err:
        raise RunParameterError(f"observer.adapt_parameters: {err}") from err
    return IrObserver(
        model,
        regions_to_nodes(tied),
        noise,
        adapt=adapted,
        parameter_random_walk=observer.random_walk_per_hour**2 / SECONDS_PER_HOUR,
        stand_drift_tau_s=observer.stand_drift_tau_s,
        **offsets,
    )


def offset_prior_sigma_c(calibration: Calibration, regions: Sequence[str]) -> float:
    """The observer's prior 1-sigma of the IR offsets (one value for every region): the
    largest identified one over ``regions``; the FLIR's +-2 degC (OFFSET_SIGMA_C) when a region
    was not identified or its offset was not identifiable (an unbounded error)."""
    sigmas = [calibration.ir_offset_sigma_c.get(region, math.inf) for region in regions]
    finite = all(math.isfinite(sigma) for sigma in sigmas)
    return max(sigmas) if sigmas and finite else OFFSET_SIGMA_C


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


def reference_row(recorder: Recorder, reference_id: int) -> RunRow:
    """The run named by ``reference_run``: it must exist and have ended (issue 19). Blocking
    (the database). Which kind of run it must be is the kind's (daemon/run/kinds.py
    check_reference_run)."""
    row = recorder.run(reference_id)
    if row is None:
        raise RunParameterError(f"reference_run {reference_id}: no such run")
    if row.state not in REFERENCE_STATES:
        raise RunParameterError(
            f"reference_run {reference_id} is {row.state}: a reference must have ended "
            f"({' or '.join(REFERENCE_STATES)})"
        )
    return row


def check_comparable(
    reference_id: int, reference: Mapping[str, Any], parameters: RunParameters
) -> None:
    """What every kind's reference needs of its parameters ``reference``: uncompensated, at
    this run's deformation scale -- its measured drift is what the summary's reduction compares
    with (issue 19)."""
    compensation = reference.get("compensation")
    if compensation != "off":
        raise RunParameterError(
            f"reference_run {reference_id} was compensated ({compensation}): a reference "
            "must be an uncompensated run (compensation off) measuring the drift"
        )
    scale = reference.get("deformation_scale", 1.0)
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


def network_snapshot(network: ThermalNetwork, heat_source: str | None = None) -> dict[str, Any]:
    """The network as recorded with the run (the model it was compensated with), where its
    heat came from, and what identified it (if anything did)."""
    calibration = network.calibration
    return {
        "heat_source": heat_source,
        "identification": None
        if calibration is None
        else {
            "base_network": calibration.base_network,
            "source_runs": list(calibration.source_runs),
            "identified_at": calibration.identified_at,
            "identifiable": calibration.identifiable,
            "ir_offsets_c": dict(calibration.ir_offsets_c),
        },
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
