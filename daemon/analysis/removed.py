"""How much drift a run has removed so far (issue 28): the dashboard's headline, from the
steps recorded until now. Pure.

It is the end-of-run summary's own reduction (thesis 6.7: ``100 (1 - max error / max
uncompensated)``; :func:`daemon.analysis.steps.summarize_run` for a two-link run,
:func:`daemon.analysis.arm.summarize_arm_run` for an arm run) over the steps so far, so the
headline at a run's last step is the figure its summary gives. It is called a *removed*
drift only against a measured uncompensated reference run; without one the figure is the
model's prediction's, and a negative or noise-level figure is said in words, never printed as
a negative "removal".
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from daemon.analysis.arm import is_arm_run, summarize_arm_run
from daemon.analysis.steps import NUMERIC_COLUMNS, RunSteps, summarize_run

#: What the figure reads of the steps: the numeric columns (the JSON ones cost the most).
REMOVED_COLUMNS: tuple[str, ...] = (*NUMERIC_COLUMNS, "run_id", "flags", "error")

#: A drift below this many measurement sigmas is noise: no reduction is stated against it.
NOISE_SIGMAS = 2.0


def _f(value: object) -> float | None:
    """A finite number, else None (JSON has no NaN)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def drift_removed(
    steps: RunSteps,
    *,
    compensation: str | None,
    poses: Sequence[str | None] = (),
    reference: RunSteps | None = None,
    reference_run: int | None = None,
    so_far: bool = True,
) -> dict[str, object]:
    """The run's figures so far: ``kind`` (arm, two-link), ``basis`` (reference: against a
    measured uncompensated run; prediction: only against the model; drift: this run is
    uncompensated), ``residual_max_um`` (the largest |error| so far: the 3-D drift on an
    arm), ``reference_max_um`` over the time both runs cover, ``removed_percent`` (only on
    the reference basis), ``vs_prediction_percent``, the arm's rotation figures and noise,
    and ``headline``: one sentence a person reads."""
    result: dict[str, object] = {
        "run_id": steps.run_id,
        "steps": steps.n_steps,
        "compensation": compensation,
        "reference_run": reference_run if reference is not None else None,
    }
    if is_arm_run(steps):
        arm = summarize_arm_run(
            steps,
            poses,
            compensation=compensation,
            reference=reference,
            reference_run=reference_run,
        )
        basis = str(arm["reduction_basis"])
        result.update(
            kind="arm",
            basis="prediction" if basis == "none" else basis,
            measured=arm["arm_n"],
            span_s=_f(arm["reference_span_s"]),
            residual_max_um=_f(arm["drift_3d_max_um"]),
            reference_max_um=_f(arm["reference_drift_3d_max_um"]),
            removed_percent=_f(arm["reduction_3d_percent"]),
            predicted_max_um=_f(arm["predicted_3d_max_um"]),
            vs_prediction_percent=None,
            noise_um=_f(arm["measurement_sigma_um"]),
            rotation={
                "max_urad": _f(arm["rotation_error_max_urad"]),
                "reference_max_urad": _f(arm["reference_rotation_max_urad"]),
                "removed_percent": _f(arm["reduction_rotation_percent"]),
                "noise_urad": _f(arm["measurement_rotation_sigma_urad"]),
            },
        )
    else:
        summary = summarize_run(
            steps, compensation=compensation, reference=reference, reference_run=reference_run
        )
        result.update(
            kind="two-link",
            basis=str(summary["reduction_basis"]),
            measured=summary["n"],
            span_s=_f(summary["reference_span_s"]),
            residual_max_um=_f(summary["residual_max_um"]),
            reference_max_um=_f(summary["reference_max_um"]),
            removed_percent=_f(summary["reduction_percent"]),
            predicted_max_um=_f(summary["uncompensated_max_um"]),
            vs_prediction_percent=_f(summary["reduction_vs_prediction_percent"]),
            noise_um=None,
            rotation=None,
        )
    result["headline"] = headline(result, so_far=so_far)
    return result


def _um(value: float) -> str:
    return f"{value:.1f} µm" if abs(value) >= 10 else f"{value:.2f} µm"


def headline(figures: dict[str, object], *, so_far: bool = True) -> str:
    """One sentence: what the compensation removed (so far, while the run goes on), against
    what it is measured."""
    text = _headline(figures)
    return text if so_far else text.replace(" so far", "")


def _headline(figures: dict[str, object]) -> str:
    residual = _f(figures.get("residual_max_um"))
    basis = figures.get("basis")
    error = "3-D drift" if figures.get("kind") == "arm" else "error"
    if residual is None:
        return "No measured error yet."
    if basis == "drift":
        return f"Compensation off: the measured drift so far is {_um(residual)} at most."
    reference = _f(figures.get("reference_max_um"))
    if basis == "reference" and reference is not None:
        run = figures.get("reference_run")
        noise = _f(figures.get("noise_um"))
        if noise is not None and reference < NOISE_SIGMAS * noise:
            return (
                f"Run {run}'s uncompensated drift so far ({_um(reference)}) is within the "
                f"measurement noise (1σ {_um(noise)}): nothing to compare yet; largest "
                f"{error} {_um(residual)}."
            )
        removed = _f(figures.get("removed_percent"))
        if removed is None or removed < 0:
            return (
                f"Not removing drift so far: the largest {error} ({_um(residual)}) exceeds "
                f"the uncompensated run {run}'s measured drift ({_um(reference)})."
            )
        return (
            f"{removed:.0f} % of the measured drift removed so far: largest {error} "
            f"{_um(residual)} against {_um(reference)} measured without compensation "
            f"(run {run})."
        )
    predicted = _f(figures.get("predicted_max_um"))
    text = f"Largest {error} so far {_um(residual)}"
    if predicted is not None:
        text += f"; the model predicted {_um(predicted)} of drift"
    return (
        text + ". No uncompensated reference run named: what was removed is not measured "
        "(name one as the reference run)."
    )
