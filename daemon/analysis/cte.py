"""Coefficient of thermal expansion from measured runs (thesis 2.2.4, Eqs. 2.1-2.3).

Chapter 2 estimated alpha from one run's temperature rise and deformation, then predicted the
deformation of two other runs with it and compared (Table 2.7). Eq. 2.3 itself lives in
daemon.model (``projected_length_change_m``, ``cte_estimate_per_k``); this module applies it
to runs: the start-to-end changes of a run, the table of predicted against measured
deformation, and alpha fitted over every step of a recorded run.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from daemon.analysis.steps import FloatArray, RunSteps
from daemon.model import cte_estimate_per_k, projected_length_change_m

logger = logging.getLogger(__name__)

UM_PER_M = 1e6


@dataclass(frozen=True)
class Links:
    """The links of Eq. 2.2: effective lengths and the angles projecting them (Table 2.5)."""

    lengths_m: tuple[float, ...]
    angles_deg: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.lengths_m) != len(self.angles_deg) or not self.lengths_m:
            raise ValueError("one projection angle per link length, at least one link")


@dataclass(frozen=True)
class Camera:
    """A camera's view of the deformation: Eq. 2.3's angles phi and theta."""

    name: str
    phi_deg: float = 0.0
    theta_deg: float = 0.0


@dataclass(frozen=True)
class RunChange:
    """What one run changed (a row of Table 2.4): per-link temperature rise (end - start) and
    the deformation each camera measured (um).

    ``start_offset_k``: how much warmer each link started than the calibration run did. The
    thesis's Run 2 started 1 degC warm; Table 2.7 adds that offset to the temperature rise of
    the prediction and the deformation it would have caused to the measured value (2.2.4).
    """

    name: str
    delta_t_k: tuple[float, ...]
    deformation_um: Mapping[str, float]
    start_offset_k: tuple[float, ...] | None = None


def _deformation_um(alpha_per_k: float, links: Links, camera: Camera, dt: Sequence[float]) -> float:
    return UM_PER_M * projected_length_change_m(
        alpha_per_k=alpha_per_k,
        link_lengths_m=links.lengths_m,
        link_angles_deg=links.angles_deg,
        delta_t_k=dt,
        phi_deg=camera.phi_deg,
        theta_deg=camera.theta_deg,
    )


def estimate_cte(links: Links, camera: Camera, run: RunChange) -> float:
    """alpha (1/K) from one run as seen by one camera: Eq. 2.3 solved for alpha."""
    try:
        measured = run.deformation_um[camera.name]
    except KeyError:
        raise ValueError(
            f"run {run.name!r} has no deformation for camera {camera.name!r}"
        ) from None
    return cte_estimate_per_k(
        length_change_m=measured / UM_PER_M,
        link_lengths_m=links.lengths_m,
        link_angles_deg=links.angles_deg,
        delta_t_k=run.delta_t_k,
        phi_deg=camera.phi_deg,
        theta_deg=camera.theta_deg,
    )


@dataclass(frozen=True)
class PredictionRow:
    """One cell pair of Table 2.7."""

    alpha_label: str  # e.g. "alpha_A" or "mean alpha"
    alpha_per_k: float
    camera: str
    run: str
    predicted_um: float
    measured_um: float  # adjusted for the start offset, as the thesis did

    @property
    def percent_error(self) -> float:
        """(predicted - measured) / measured, in % (Table 2.7's sign: negative = under)."""
        return 100.0 * (self.predicted_um - self.measured_um) / self.measured_um


@dataclass(frozen=True)
class CteTable:
    """Alpha per camera from the calibration run, their mean, and Table 2.7's predictions."""

    calibration: str
    alpha_per_camera: dict[str, float]
    mean_alpha_per_k: float
    rows: tuple[PredictionRow, ...] = field(default_factory=tuple)

    def to_text(self) -> str:
        """The table laid out like Table 2.7 (um, % error = (predicted - measured)/measured)."""
        lines = [
            f"alpha from {self.calibration}: "
            + ", ".join(f"{name} {a * 1e6:.2f}e-6/K" for name, a in self.alpha_per_camera.items())
            + f"; mean {self.mean_alpha_per_k * 1e6:.2f}e-6/K",
            f"{'alpha':<12}{'camera':<8}{'run':<10}{'predicted um':>14}{'measured um':>13}"
            f"{'% error':>9}",
        ]
        lines += [
            f"{r.alpha_label:<12}{r.camera:<8}{r.run:<10}{r.predicted_um:>14.2f}"
            f"{r.measured_um:>13.2f}{r.percent_error:>9.2f}"
            for r in self.rows
        ]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, object]:
        return {
            "calibration": self.calibration,
            "alpha_per_camera_per_k": self.alpha_per_camera,
            "mean_alpha_per_k": self.mean_alpha_per_k,
            "rows": [
                {
                    "alpha": row.alpha_label,
                    "alpha_per_k": row.alpha_per_k,
                    "camera": row.camera,
                    "run": row.run,
                    "predicted_um": row.predicted_um,
                    "measured_um": row.measured_um,
                    "percent_error": row.percent_error,
                }
                for row in self.rows
            ],
        }


def predict(
    alpha_per_k: float, alpha_label: str, links: Links, camera: Camera, run: RunChange
) -> PredictionRow:
    """Predicted against measured deformation of ``run`` for one camera (thesis 2.2.4)."""
    rise = list(run.delta_t_k)
    measured = run.deformation_um[camera.name]
    if run.start_offset_k is not None:
        # The run started warmer than the calibration: the prediction covers the whole rise
        # from the calibration's start, and the measurement missed the offset's share.
        rise = [r + o for r, o in zip(rise, run.start_offset_k, strict=True)]
        measured += _deformation_um(alpha_per_k, links, camera, run.start_offset_k)
    return PredictionRow(
        alpha_label=alpha_label,
        alpha_per_k=alpha_per_k,
        camera=camera.name,
        run=run.name,
        predicted_um=_deformation_um(alpha_per_k, links, camera, rise),
        measured_um=measured,
    )


def cte_table(
    links: Links,
    cameras: Sequence[Camera],
    calibration: RunChange,
    verifications: Sequence[RunChange],
    *,
    digits: int | None = None,
) -> CteTable:
    """Table 2.7 from any runs: alpha of each camera from ``calibration``, then each camera's
    own alpha and the mean alpha predicting every verification run for every camera.

    ``digits``: round alpha to this many decimals of 1e-6/K before predicting, as the thesis
    carried 21.87, 21.63 and 21.75 (``digits=2``); None keeps full precision.
    """
    if not cameras:
        raise ValueError("need at least one camera")

    def rounded(alpha: float) -> float:
        return alpha if digits is None else round(alpha * 1e6, digits) / 1e6

    alphas = {camera.name: rounded(estimate_cte(links, camera, calibration)) for camera in cameras}
    mean_alpha = rounded(sum(alphas.values()) / len(alphas))
    rows = [
        predict(alphas[camera.name], f"alpha_{camera.name}", links, camera, run)
        for camera in cameras
        for run in verifications
    ]
    if len(cameras) > 1:
        rows += [
            predict(mean_alpha, "mean alpha", links, camera, run)
            for camera in cameras
            for run in verifications
        ]
    return CteTable(
        calibration=calibration.name,
        alpha_per_camera=alphas,
        mean_alpha_per_k=mean_alpha,
        rows=tuple(rows),
    )


# --- recorded runs ----------------------------------------------------------------------


def measured_deformation_um(steps: RunSteps) -> FloatArray:
    """The link's own deformation at each step along its axis (um).

    The spot moved by the deformation plus the compensation the robot made, and that is the
    recorded error: deformation = residual - compensation. With compensation off the
    compensation is zero and the residual is the deformation itself. Steps with no offset
    recorded count as uncompensated.
    """
    compensation = np.nan_to_num(steps.compensation_um, nan=0.0)
    deformation: FloatArray = steps.residual_um - compensation
    return deformation


def run_change(
    steps: RunSteps,
    regions: Sequence[str],
    *,
    name: str | None = None,
    camera: str = "camera",
    edge_samples: int = 5,
) -> RunChange:
    """A recorded run as a Table 2.4 row: each region's mean temperature rise and the
    measured deformation, end minus start (each the mean of ``edge_samples`` steps, to
    average the sensor noise the thesis's single start/end images carried)."""
    deformation = measured_deformation_um(steps)

    def change(series: FloatArray) -> float:
        finite = series[np.isfinite(series)]
        if finite.size < 2:
            raise ValueError("not enough recorded values for a start-to-end change")
        edge = max(1, min(edge_samples, finite.size // 2))
        return float(finite[-edge:].mean() - finite[:edge].mean())

    missing = [r for r in regions if r not in steps.ir_mean_c]
    if missing:
        known = ", ".join(sorted(steps.ir_mean_c)) or "none"
        raise ValueError(f"no temperatures of region(s) {', '.join(missing)}; recorded: {known}")
    return RunChange(
        name=name or str(steps.run_id),
        delta_t_k=tuple(change(steps.ir_mean_c[r]) for r in regions),
        deformation_um={camera: change(deformation)},
    )


@dataclass(frozen=True)
class RunCteFit:
    """alpha fitted over every step of a run: deformation = c + alpha s(t), s from Eq. 2.3."""

    alpha_per_k: float
    alpha_stderr_per_k: float
    endpoint_alpha_per_k: float  # the thesis's start-to-end estimate from the same run
    n: int


def cte_from_run(
    steps: RunSteps, regions: Sequence[str], links: Links, camera: Camera | None = None
) -> RunCteFit:
    """alpha from a recorded run's region temperatures and measured deformation.

    Each region is one link of ``links`` (same order). At every step, Eq. 2.3 with alpha = 1
    gives s(t) from the regions' rise since the first step; alpha is the least-squares slope
    of the deformation against s(t), with its standard error.
    """
    view = camera or Camera("camera")
    if len(regions) != len(links.lengths_m):
        raise ValueError("one region per link")
    missing = [r for r in regions if r not in steps.ir_mean_c]
    if missing:
        raise ValueError(f"no temperatures of region(s) {', '.join(missing)}")
    temperatures = np.column_stack([steps.ir_mean_c[r] for r in regions])
    deformation = measured_deformation_um(steps)
    usable = np.isfinite(temperatures).all(axis=1) & np.isfinite(deformation)
    if usable.sum() < 3:
        raise ValueError("need at least three steps with temperatures and a measurement")
    temperatures, deformation = temperatures[usable], deformation[usable]
    rises = temperatures - temperatures[0]
    per_alpha = np.array([_deformation_um(1.0, links, view, list(rise)) for rise in rises])
    # Slope with an intercept: the first step's noise must not set the zero of either axis.
    centred_s = per_alpha - per_alpha.mean()
    centred_d = deformation - deformation.mean()
    denominator = float(centred_s @ centred_s)
    if denominator == 0:
        raise ValueError("the temperatures did not change: alpha cannot be estimated")
    alpha = float(centred_s @ centred_d) / denominator
    residuals = centred_d - alpha * centred_s
    n = int(per_alpha.size)
    stderr = math.sqrt(float(residuals @ residuals) / (n - 2) / denominator)
    endpoint = estimate_cte(links, view, run_change(steps, regions, camera=view.name))
    return RunCteFit(
        alpha_per_k=alpha, alpha_stderr_per_k=stderr, endpoint_alpha_per_k=endpoint, n=n
    )
